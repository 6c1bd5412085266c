"""The four parameter services every node serves, and their wire types (rcl_interfaces' shapes).

``~/list_parameters``, ``~/get_parameters``, ``~/set_parameters`` and
``~/describe_parameters`` (Zenoh keys ``@srv/<ns>/<node>/<service>``) run on the
node's executor like any service; ``zenoh-robot param`` and ParameterClient use them.

Who writes: a set request carries the caller's ``client_id`` (a claim, as every id a peer
sends; the secure profile's ACL decides who may reach the service at all). A node that cares
installs a write guard (``Node.set_parameter_write_guard``): it sees the names and the caller
before anything is checked or set and may refuse the whole request. On-set callbacks run by a
remote set read the caller with :func:`current_caller`. Without a guard, rclpy's behaviour.
"""
from __future__ import annotations

import contextvars
import logging
from collections.abc import Callable
from dataclasses import field
from typing import Any, ClassVar

from ..message import Message, message, ros_field
from .store import ParameterStore
from .types import InvalidParameterTypeError, Parameter, ParameterError, ParameterType, SetParametersResult


# -- wire types of the parameter services (rcl_interfaces' shapes) ---------------------------
@message(name="zenoh_robot/ParameterValue")
class ParameterValue(Message):
    type: int = ros_field("uint8", default=0)
    bool_value: bool = False
    integer_value: int = 0
    double_value: float = 0.0
    string_value: str = ""
    bool_array_value: list[bool] = field(default_factory=list)
    integer_array_value: list[int] = field(default_factory=list)
    double_array_value: list[float] = field(default_factory=list)
    string_array_value: list[str] = field(default_factory=list)

    _SLOT: ClassVar[dict[ParameterType, str]] = {
             ParameterType.BOOL: "bool_value", ParameterType.INTEGER: "integer_value",
             ParameterType.DOUBLE: "double_value", ParameterType.STRING: "string_value",
             ParameterType.BOOL_ARRAY: "bool_array_value", ParameterType.INTEGER_ARRAY: "integer_array_value",
             ParameterType.DOUBLE_ARRAY: "double_array_value", ParameterType.STRING_ARRAY: "string_array_value"}

    @classmethod
    def of(cls, type_: ParameterType, value: Any) -> "ParameterValue":
        out = cls(type=int(type_))
        if value is not None and type_ in cls._SLOT:
            setattr(out, cls._SLOT[type_], value)
        return out

    def to_python(self) -> tuple[ParameterType, Any]:
        try:
            t = ParameterType(self.type)
        except ValueError:
            raise InvalidParameterTypeError(f"unknown parameter type code {self.type}") from None
        slot = self._SLOT.get(t)
        return t, (getattr(self, slot) if slot else None)


@message(name="zenoh_robot/Parameter")
class ParameterMsg(Message):
    name: str = ""
    value: ParameterValue = field(default_factory=ParameterValue)


@message(name="zenoh_robot/SetParametersResult")
class SetParametersResultMsg(Message):
    successful: bool = False
    reason: str = ""


@message(name="zenoh_robot/ParameterDescriptor")
class ParameterDescriptorMsg(Message):
    name: str = ""
    type: int = ros_field("uint8", default=0)
    description: str = ""
    read_only: bool = False


@message(name="zenoh_robot/ListParameters_Request")
class ListParametersRequest(Message):
    prefixes: list[str] = field(default_factory=list)


@message(name="zenoh_robot/ListParameters_Response")
class ListParametersResponse(Message):
    names: list[str] = field(default_factory=list)


@message(name="zenoh_robot/GetParameters_Request")
class GetParametersRequest(Message):
    names: list[str] = field(default_factory=list)


@message(name="zenoh_robot/GetParameters_Response")
class GetParametersResponse(Message):
    values: list[ParameterValue] = field(default_factory=list)


@message(name="zenoh_robot/SetParameters_Request")
class SetParametersRequest(Message):
    parameters: list[ParameterMsg] = field(default_factory=list)
    client_id: str = ""      # who asks (ParameterClient: the GCS id, user@host by default)


@message(name="zenoh_robot/SetParameters_Response")
class SetParametersResponse(Message):
    results: list[SetParametersResultMsg] = field(default_factory=list)


@message(name="zenoh_robot/DescribeParameters_Request")
class DescribeParametersRequest(Message):
    names: list[str] = field(default_factory=list)


@message(name="zenoh_robot/DescribeParameters_Response")
class DescribeParametersResponse(Message):
    descriptors: list[ParameterDescriptorMsg] = field(default_factory=list)


# (names of the request, caller's client_id) -> "" to let the request through, else why not.
WriteGuard = Callable[[list[str], str], str]

log = logging.getLogger("zenoh_robot.parameters")
_CALLER: contextvars.ContextVar[str] = contextvars.ContextVar("zenoh_robot_parameter_caller", default="")


def current_caller() -> str:
    """The ``client_id`` of the remote set request this thread is serving; "" for a local set."""
    return _CALLER.get()


PARAMETER_SERVICES = {
    "list_parameters": (ListParametersRequest, ListParametersResponse),
    "get_parameters": (GetParametersRequest, GetParametersResponse),
    "set_parameters": (SetParametersRequest, SetParametersResponse),
    "describe_parameters": (DescribeParametersRequest, DescribeParametersResponse),
}


class ParameterService:
    """Serves a :class:`ParameterStore` over the four parameter services (rclpy's ParameterService).

    ``create_service(name, request_type, response_type, handler)`` is the node's. The write guard
    (optional) runs on the executor thread that serves the request, before the store is touched.
    """

    def __init__(self, store: ParameterStore, create_service: Callable[..., Any]) -> None:
        self._store = store
        self._guard: WriteGuard | None = None
        handlers: dict[str, Callable[[Any], Message]] = {
            "list_parameters": self._list, "get_parameters": self._get,
            "set_parameters": self._set, "describe_parameters": self._describe}
        self.services = [create_service(f"~/{name}", req, resp, handlers[name])
                         for name, (req, resp) in PARAMETER_SERVICES.items()]

    def set_write_guard(self, guard: WriteGuard | None) -> None:
        """Judge every remote set request by its names and caller (None: accept as rclpy does)."""
        self._guard = guard

    def _list(self, req: ListParametersRequest) -> ListParametersResponse:
        return ListParametersResponse(self._store.list_parameters(req.prefixes))

    def _get(self, req: GetParametersRequest) -> GetParametersResponse:
        values = []
        for name in req.names:
            decl = self._store.lookup(name)
            values.append(ParameterValue() if decl is None else ParameterValue.of(decl[0].type, decl[1]))
        return GetParametersResponse(values)

    def _set(self, req: SetParametersRequest) -> SetParametersResponse:
        why = self._guarded([pm.name for pm in req.parameters], req.client_id)
        if why:   # the whole request: a caller refused for one name is refused for all
            return SetParametersResponse([SetParametersResultMsg(False, why) for _ in req.parameters])
        token = _CALLER.set(req.client_id)
        try:
            return self._set_each(req)
        finally:
            _CALLER.reset(token)

    def _guarded(self, names: list[str], caller: str) -> str:
        guard = self._guard
        if guard is None:
            return ""
        try:
            why = guard(names, caller)
        except Exception as exc:  # noqa: BLE001  (a broken guard refuses: it never lets a write through)
            log.exception("parameter write guard raised")
            return f"write guard raised {type(exc).__name__}: {exc}"
        if not isinstance(why, str):
            return f"write guard returned {why!r}, not a reason"
        return why

    def _set_each(self, req: SetParametersRequest) -> SetParametersResponse:
        results = []
        for pm in req.parameters:
            try:
                t, v = pm.value.to_python()
                res = self._store.set_parameters([Parameter(pm.name, v)])[0] if t is not ParameterType.NOT_SET \
                    else self._delete(pm.name)
            except ParameterError as exc:
                res = SetParametersResult(False, str(exc))
            results.append(SetParametersResultMsg(res.successful, res.reason))
        return SetParametersResponse(results)

    def _delete(self, name: str) -> SetParametersResult:
        """rcl's rule: set to NOT_SET undeclares (``ros2 param delete``). A peer must not take away a
        parameter the node still reads (its next get would raise): only a node whose on-set callbacks
        all accept ``Parameter(name, NOT_SET)`` lets it go; with no callback the answer is no."""
        store = self._store
        with store._param_lock:
            decl = store.lookup(name)
            if decl is None:
                return SetParametersResult(False, f"parameter {name!r} is not declared")
            if decl[0].read_only:
                return SetParametersResult(False, f"parameter {name!r} is read-only")
            if not store._on_set_callbacks:
                return SetParametersResult(False, f"parameter {name!r}: this node accepts no remote deletion "
                                                  "(no on-set callback agreed to it)")
            result = store._run_on_set_callbacks([Parameter(name, ParameterType.NOT_SET)])
            if result.successful:
                store.undeclare_parameter(name)
            return result

    def _describe(self, req: DescribeParametersRequest) -> DescribeParametersResponse:
        out = []
        for name in req.names:
            decl = self._store.lookup(name)
            if decl is None:
                out.append(ParameterDescriptorMsg(name, int(ParameterType.NOT_SET)))
            else:
                d = decl[0]
                out.append(ParameterDescriptorMsg(d.name, int(d.type), d.description, d.read_only))
        return DescribeParametersResponse(out)
