"""Another node's parameters, read and changed through its parameter services."""
from __future__ import annotations

import builtins
import getpass
import re
import socket
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

from .service import (
    PARAMETER_SERVICES,
    DescribeParametersRequest,
    GetParametersRequest,
    ListParametersRequest,
    ListParametersResponse,
    ParameterMsg,
    ParameterValue,
    SetParametersRequest,
)
from .types import Parameter, ParameterDescriptor, ParameterError, ParameterType, SetParametersResult

if TYPE_CHECKING:
    from ..node import Node
    from ..services import Client


def default_client_id() -> str:
    """``user@host``, reduced to the characters a client id may hold: the id a GCS uses unless told."""
    raw = f"{getpass.getuser()}@{socket.gethostname()}"
    return re.sub(r"[^A-Za-z0-9_.@:+-]", "_", raw)[:64]


class ParameterClient:
    """Read and change another node's parameters through its parameter services.

    Set requests carry ``client_id`` (default: :func:`default_client_id`), which the node's write
    guard may judge (a node that controls a vehicle lets only its operator change safety limits).
    """

    def __init__(self, node: "Node", target: str, timeout: float = 3.0, client_id: str | None = None) -> None:
        self.target = target if target.startswith("/") else "/" + target
        self.timeout = timeout
        self.client_id = default_client_id() if client_id is None else client_id
        self._clients: dict[str, Client[Any, Any]] = {name: node.create_client(f"{self.target}/{name}", req, resp)
                         for name, (req, resp) in PARAMETER_SERVICES.items()}

    def wait_for_node(self, timeout: float | None = None) -> bool:
        return self._clients["list_parameters"].wait_for_service(self.timeout if timeout is None else timeout)

    def list(self, prefixes: Sequence[str] = ()) -> builtins.list[str]:
        resp: ListParametersResponse = self._clients["list_parameters"].call(
            ListParametersRequest(builtins.list(prefixes)), self.timeout)
        return resp.names

    def get(self, names: Sequence[str]) -> builtins.list[Parameter | None]:
        """One Parameter per name, None where the node has no such parameter."""
        resp = self._clients["get_parameters"].call(GetParametersRequest(list(names)), self.timeout)
        out: builtins.list[Parameter | None] = []
        if len(resp.values) != len(names):   # a peer's reply: the count is checked, not trusted
            raise ParameterError(f"{self.target}: {len(resp.values)} values for {len(names)} names")
        for name, pv in zip(names, resp.values, strict=True):
            t, v = pv.to_python()
            out.append(None if t is ParameterType.NOT_SET else Parameter(name, t, v))
        return out

    def set(self, parameters: Sequence[Parameter]) -> builtins.list[SetParametersResult]:
        msgs = [ParameterMsg(p.name, ParameterValue.of(p.type_, p.value)) for p in parameters]
        resp = self._clients["set_parameters"].call(SetParametersRequest(msgs, self.client_id), self.timeout)
        return [SetParametersResult(r.successful, r.reason) for r in resp.results]

    def describe(self, names: Sequence[str]) -> builtins.list[ParameterDescriptor | None]:
        resp = self._clients["describe_parameters"].call(DescribeParametersRequest(list(names)), self.timeout)
        out: builtins.list[ParameterDescriptor | None] = []
        for d in resp.descriptors:
            t = ParameterType(d.type)
            out.append(None if t is ParameterType.NOT_SET
                       else ParameterDescriptor(d.name, t, d.description, d.read_only))
        return out
