"""Another node's parameters, read and changed through its parameter services."""
from __future__ import annotations

from typing import TYPE_CHECKING, Sequence

from .service import (PARAMETER_SERVICES, DescribeParametersRequest, GetParametersRequest, ListParametersRequest,
                      ParameterMsg, ParameterValue, SetParametersRequest)
from .types import Parameter, ParameterDescriptor, ParameterType, SetParametersResult

if TYPE_CHECKING:
    from ..node import Node


class ParameterClient:
    """Read and change another node's parameters through its parameter services."""

    def __init__(self, node: "Node", target: str, timeout: float = 3.0) -> None:
        self.target = target if target.startswith("/") else "/" + target
        self.timeout = timeout
        self._clients = {name: node.create_client(f"{self.target}/{name}", req, resp)
                         for name, (req, resp) in PARAMETER_SERVICES.items()}

    def wait_for_node(self, timeout: float | None = None) -> bool:
        return self._clients["list_parameters"].wait_for_service(self.timeout if timeout is None else timeout)

    def list(self, prefixes: Sequence[str] = ()) -> list[str]:
        return self._clients["list_parameters"].call(ListParametersRequest(list(prefixes)), self.timeout).names

    def get(self, names: Sequence[str]) -> list[Parameter | None]:
        """One Parameter per name, None where the node has no such parameter."""
        resp = self._clients["get_parameters"].call(GetParametersRequest(list(names)), self.timeout)
        out: list[Parameter | None] = []
        for name, pv in zip(names, resp.values):
            t, v = pv.to_python()
            out.append(None if t is ParameterType.NOT_SET else Parameter(name, t, v))
        return out

    def set(self, parameters: Sequence[Parameter]) -> list[SetParametersResult]:
        msgs = [ParameterMsg(p.name, ParameterValue.of(p.type_, p.value)) for p in parameters]
        resp = self._clients["set_parameters"].call(SetParametersRequest(msgs), self.timeout)
        return [SetParametersResult(r.successful, r.reason) for r in resp.results]

    def describe(self, names: Sequence[str]) -> list[ParameterDescriptor | None]:
        resp = self._clients["describe_parameters"].call(DescribeParametersRequest(list(names)), self.timeout)
        out: list[ParameterDescriptor | None] = []
        for d in resp.descriptors:
            t = ParameterType(d.type)
            out.append(None if t is ParameterType.NOT_SET
                       else ParameterDescriptor(d.name, t, d.description, d.read_only))
        return out
