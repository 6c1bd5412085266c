"""ROS 2-style node parameters, their remote services, and ``-p name:=value`` parsing.

Semantics follow rclpy: a parameter must be declared before use; the type of its
default fixes its type (an int is accepted where a double was declared, nothing
else converts); overrides given to ``Node(parameter_overrides=...)`` (from
``-p name:=value`` or a launch file) replace the default at declare time;
``set_parameters`` sets each parameter on its own and returns one
SetParametersResult per parameter; on-set callbacks see the new values first and
may refuse them (also at declare time, as in rclpy).

Every node serves ``~/list_parameters``, ``~/get_parameters``,
``~/set_parameters`` and ``~/describe_parameters`` (Zenoh keys
``@srv/<ns>/<node>/<service>``), run on the node's executor like any service:
``zenoh-robot param`` and :class:`ParameterClient` use them.
"""
from __future__ import annotations

import enum
import math
import threading
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Callable, Iterable, Sequence

import yaml

from .message import Message, message, ros_field
from .qos import HistoryPolicy, QoSError, QoSProfile, ReliabilityPolicy

if TYPE_CHECKING:
    from .node import Node


class ParameterType(enum.IntEnum):
    """rcl_interfaces/ParameterType values."""
    NOT_SET = 0
    BOOL = 1
    INTEGER = 2
    DOUBLE = 3
    STRING = 4
    BYTE_ARRAY = 5   # listed for rclpy compatibility; not supported as a parameter type
    BOOL_ARRAY = 6
    INTEGER_ARRAY = 7
    DOUBLE_ARRAY = 8
    STRING_ARRAY = 9

    @property
    def label(self) -> str:
        return self.name.lower()


class ParameterError(Exception):
    """Base of the parameter errors."""


class ParameterNotDeclaredError(ParameterError):
    pass


class ParameterAlreadyDeclaredError(ParameterError):
    pass


class InvalidParameterTypeError(ParameterError, TypeError):
    pass


class InvalidParameterValueError(ParameterError, ValueError):
    pass


_ARRAY_OF = {ParameterType.BOOL_ARRAY: ParameterType.BOOL, ParameterType.INTEGER_ARRAY: ParameterType.INTEGER,
             ParameterType.DOUBLE_ARRAY: ParameterType.DOUBLE, ParameterType.STRING_ARRAY: ParameterType.STRING}


def _scalar_type(v: Any) -> ParameterType | None:
    if isinstance(v, bool):
        return ParameterType.BOOL
    if isinstance(v, int):
        return ParameterType.INTEGER
    if isinstance(v, float):
        return ParameterType.DOUBLE
    if isinstance(v, str):
        return ParameterType.STRING
    return None


def infer_type(value: Any) -> ParameterType:
    """The parameter type of a Python value; NOT_SET for None. Raises for what no type holds."""
    if value is None:
        return ParameterType.NOT_SET
    t = _scalar_type(value)
    if t is not None:
        return t
    if isinstance(value, (list, tuple)):
        kinds = {_scalar_type(v) for v in value}
        if not value:
            raise InvalidParameterTypeError("an empty list has no element type; pass type_=")
        if None in kinds:
            raise InvalidParameterTypeError(f"list {value!r} holds a value that is not bool, int, float or str")
        if kinds == {ParameterType.BOOL}:
            return ParameterType.BOOL_ARRAY
        if kinds == {ParameterType.INTEGER}:
            return ParameterType.INTEGER_ARRAY
        if kinds <= {ParameterType.INTEGER, ParameterType.DOUBLE}:
            return ParameterType.DOUBLE_ARRAY
        if kinds == {ParameterType.STRING}:
            return ParameterType.STRING_ARRAY
        raise InvalidParameterTypeError(f"list {value!r} mixes element types")
    raise InvalidParameterTypeError(
        f"{type(value).__name__} is not a parameter type (bool, int, float, str or a list of one of them)")


def _coerce_scalar(value: Any, want: ParameterType) -> Any:
    got = _scalar_type(value)
    if got is want:
        return value
    if want is ParameterType.DOUBLE and got is ParameterType.INTEGER:
        return float(value)
    raise InvalidParameterTypeError(f"expected {want.label}, got {type(value).__name__} {value!r}")


def coerce(value: Any, want: ParameterType) -> Any:
    """``value`` as a value of type ``want`` (int -> float only), or InvalidParameterTypeError."""
    if want in _ARRAY_OF:
        if not isinstance(value, (list, tuple)):
            raise InvalidParameterTypeError(f"expected {want.label}, got {type(value).__name__} {value!r}")
        try:
            return [_coerce_scalar(v, _ARRAY_OF[want]) for v in value]
        except InvalidParameterTypeError as exc:
            raise InvalidParameterTypeError(f"expected {want.label}: element {exc}") from None
    if want in (ParameterType.NOT_SET, ParameterType.BYTE_ARRAY):
        raise InvalidParameterTypeError(f"parameters of type {want.label} are not supported")
    return _coerce_scalar(value, want)


class Parameter:
    """rclpy's Parameter: ``Parameter(name, Parameter.Type.INTEGER, 5)`` or ``Parameter(name, value=5)``.

    As a convenience ``Parameter(name, 5)`` also works: a second argument that is no
    ParameterType is taken as the value.
    """
    Type = ParameterType

    def __init__(self, name: str, type_: ParameterType | Any = None, value: Any = None) -> None:
        if not isinstance(name, str) or not name:
            raise InvalidParameterValueError(f"parameter name must be a non-empty string, got {name!r}")
        if type_ is not None and not isinstance(type_, ParameterType) and value is None:
            type_, value = None, type_
        if type_ is None:
            type_ = infer_type(value)
        else:
            type_ = ParameterType(type_)
            if value is not None:
                value = coerce(value, type_)
        self.name = name
        self.type_ = type_
        self.value = value if not isinstance(value, tuple) else list(value)

    def get_parameter_value(self) -> Any:
        return self.value

    def __eq__(self, other: object) -> bool:
        return (isinstance(other, Parameter) and self.name == other.name and self.type_ == other.type_
                and self.value == other.value)

    def __repr__(self) -> str:
        return f"Parameter({self.name!r}, {self.type_!r}, {self.value!r})"


@dataclass
class SetParametersResult:
    successful: bool
    reason: str = ""


@dataclass
class ParameterDescriptor:
    name: str
    type: ParameterType
    description: str = ""
    read_only: bool = False


# -- wire types of the parameter services (rcl_interfaces' shapes) ---------------------------
@message(name="zenoh_robot/ParameterValue")
class ParameterValue(Message):
    type: int = ros_field("uint8", 0)
    bool_value: bool = False
    integer_value: int = 0
    double_value: float = 0.0
    string_value: str = ""
    bool_array_value: list[bool] = field(default_factory=list)
    integer_array_value: list[int] = field(default_factory=list)
    double_array_value: list[float] = field(default_factory=list)
    string_array_value: list[str] = field(default_factory=list)

    _SLOT = {ParameterType.BOOL: "bool_value", ParameterType.INTEGER: "integer_value",
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
    type: int = ros_field("uint8", 0)
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


@message(name="zenoh_robot/SetParameters_Response")
class SetParametersResponse(Message):
    results: list[SetParametersResultMsg] = field(default_factory=list)


@message(name="zenoh_robot/DescribeParameters_Request")
class DescribeParametersRequest(Message):
    names: list[str] = field(default_factory=list)


@message(name="zenoh_robot/DescribeParameters_Response")
class DescribeParametersResponse(Message):
    descriptors: list[ParameterDescriptorMsg] = field(default_factory=list)


PARAMETER_SERVICES = {
    "list_parameters": (ListParametersRequest, ListParametersResponse),
    "get_parameters": (GetParametersRequest, GetParametersResponse),
    "set_parameters": (SetParametersRequest, SetParametersResponse),
    "describe_parameters": (DescribeParametersRequest, DescribeParametersResponse),
}


# -- command line -----------------------------------------------------------------------------
def parse_param_value(text: str) -> Any:
    """A ``-p`` value as YAML reads it: ``5`` int, ``0.5`` float, ``true`` bool, ``[1, 2]`` list, else str."""
    if text.strip() == "":
        return ""
    try:
        value = yaml.safe_load(text)
    except yaml.YAMLError:
        return text
    if value is None:
        return text
    if isinstance(value, dict):
        raise InvalidParameterValueError(f"parameter value {text!r} is a mapping; use one value or a list")
    if isinstance(value, list):
        infer_type(value)  # refuse nested or mixed lists here, with the reason
    elif _scalar_type(value) is None:
        return text   # dates and other YAML extras stay text
    return value


def parse_param_args(argv: Sequence[str]) -> dict[str, Any]:
    """``["-p", "a:=1", "--param", "b:=x", "c:=true"]`` -> ``{"a": 1, "b": "x", "c": True}``."""
    out: dict[str, Any] = {}
    items = list(argv)
    i = 0
    while i < len(items):
        item = items[i]
        if item in ("-p", "--param"):
            if i + 1 >= len(items):
                raise InvalidParameterValueError(f"{item} needs NAME:=VALUE")
            item = items[i + 1]
            i += 1
        elif item.startswith(("-p=", "--param=")):
            item = item.split("=", 1)[1]
        name, sep, value = item.partition(":=")
        if not sep or not name.strip():
            raise InvalidParameterValueError(f"bad parameter argument {item!r}: expected NAME:=VALUE")
        out[name.strip()] = parse_param_value(value)
        i += 1
    return out


def add_param_argument(parser: Any) -> None:
    """Add ``-p/--param NAME:=VALUE`` (repeatable) to an argparse parser; read it with params_from_args."""
    parser.add_argument("-p", "--param", action="append", default=[], metavar="NAME:=VALUE",
                        help="set a node parameter (repeatable), e.g. -p depth:=5")


def params_from_args(args: Any) -> dict[str, Any]:
    return parse_param_args(getattr(args, "param", None) or [])


def format_param_value(value: Any) -> str:
    """The ``-p`` form of a value (inverse of parse_param_value): strings that would read back
    as something else (``'5'``, ``'true'``, ``''``) are quoted."""
    if isinstance(value, str):
        try:
            same = value != "" and value.strip() == value and parse_param_value(value) == value
        except InvalidParameterValueError:
            same = False
        if same:
            return value
    elif isinstance(value, float) and not math.isfinite(value):
        return ".nan" if math.isnan(value) else (".inf" if value > 0 else "-.inf")
    return yaml.safe_dump(value, default_flow_style=True, width=1 << 20).strip().removesuffix("...").strip()


# -- the node side ---------------------------------------------------------------------------
@dataclass
class _Declared:
    descriptor: ParameterDescriptor
    value: Any


SetCallback = Callable[[list[Parameter]], "SetParametersResult | bool"]


class ParametersMixin:
    """Node methods: declare/get/set parameters, on-set callbacks, the parameter services."""

    def _init_parameters(self: Any, overrides: dict[str, Any]) -> None:
        self._parameter_overrides = dict(overrides)
        self._parameters: dict[str, _Declared] = {}
        self._param_lock = threading.RLock()
        self._on_set_callbacks: list[SetCallback] = []
        for srv_name, (req, resp) in PARAMETER_SERVICES.items():
            self.create_service(f"~/{srv_name}", req, resp, getattr(self, f"_srv_{srv_name}"))

    # -- declaring -------------------------------------------------------------------------
    def declare_parameter(self: Any, name: str, default: Any = None, description: str = "",
                          read_only: bool = False, *, type_: ParameterType | None = None) -> Parameter:
        """Declare ``name``; an override given to the node wins over ``default``.

        Raises ParameterAlreadyDeclaredError, InvalidParameterTypeError (override of the wrong
        type) or InvalidParameterValueError (refused by an on-set callback).
        """
        if not isinstance(name, str) or not name:
            raise InvalidParameterValueError(f"parameter name must be a non-empty string, got {name!r}")
        with self._param_lock:
            if name in self._parameters:
                raise ParameterAlreadyDeclaredError(f"parameter {name!r} is already declared")
            if type_ is None:
                if default is None and name not in self._parameter_overrides:
                    raise InvalidParameterTypeError(
                        f"parameter {name!r}: give a default value or type_= to fix its type")
                try:
                    type_ = infer_type(default if default is not None else self._parameter_overrides[name])
                except InvalidParameterTypeError as exc:
                    raise InvalidParameterTypeError(f"parameter {name!r}: {exc}") from None
            type_ = ParameterType(type_)
            value = default
            source = "default"
            if name in self._parameter_overrides:
                value, source = self._parameter_overrides[name], "override"
            if value is not None:
                try:
                    value = coerce(value, type_)
                except InvalidParameterTypeError as exc:
                    raise InvalidParameterTypeError(f"parameter {name!r} ({source}): {exc}") from None
                result = self._run_on_set_callbacks([Parameter(name, type_, value)])
                if not result.successful:
                    raise InvalidParameterValueError(
                        f"parameter {name!r}: {source} value {value!r} refused: {result.reason}")
            self._parameters[name] = _Declared(ParameterDescriptor(name, type_, description, read_only), value)
            return Parameter(name, type_, value)

    def declare_parameters(self: Any, namespace: str,
                           parameters: Iterable[tuple[Any, ...]] | dict[str, Any]) -> list[Parameter]:
        """rclpy's form: ``[(name, default), (name, default, description), ...]`` or ``{name: default}``."""
        items = parameters.items() if isinstance(parameters, dict) else parameters
        out = []
        for item in items:
            name, default, *rest = item
            full = f"{namespace}.{name}" if namespace else name
            out.append(self.declare_parameter(full, default, *rest))
        return out

    def undeclare_parameter(self: Any, name: str) -> None:
        with self._param_lock:
            decl = self._get_declared(name)
            if decl.descriptor.read_only:
                raise InvalidParameterValueError(f"parameter {name!r} is read-only")
            del self._parameters[name]

    # -- reading ---------------------------------------------------------------------------
    def _get_declared(self: Any, name: str) -> _Declared:
        try:
            return self._parameters[name]
        except KeyError:
            raise ParameterNotDeclaredError(f"parameter {name!r} is not declared") from None

    def has_parameter(self: Any, name: str) -> bool:
        with self._param_lock:
            return name in self._parameters

    def get_parameter(self: Any, name: str) -> Parameter:
        with self._param_lock:
            decl = self._get_declared(name)
            return Parameter(name, decl.descriptor.type, decl.value)

    def get_parameters(self: Any, names: Iterable[str]) -> list[Parameter]:
        return [self.get_parameter(n) for n in names]

    def get_parameter_value(self: Any, name: str) -> Any:
        return self.get_parameter(name).value

    def get_parameter_or(self: Any, name: str, alternative: Any = None) -> Any:
        with self._param_lock:
            decl = self._parameters.get(name)
            return alternative if decl is None or decl.value is None else decl.value

    def describe_parameter(self: Any, name: str) -> ParameterDescriptor:
        with self._param_lock:
            return self._get_declared(name).descriptor

    def list_parameters(self: Any, prefixes: Iterable[str] = ()) -> list[str]:
        prefixes = list(prefixes)
        with self._param_lock:
            names = sorted(self._parameters)
        if not prefixes:
            return names
        return [n for n in names if any(n == p or n.startswith(p + ".") for p in prefixes)]

    # -- setting ---------------------------------------------------------------------------
    def add_on_set_parameters_callback(self: Any, callback: SetCallback) -> None:
        """``callback(list[Parameter]) -> SetParametersResult``: refuse with successful=False and a reason."""
        with self._param_lock:
            self._on_set_callbacks.insert(0, callback)   # rclpy calls the newest first

    def remove_on_set_parameters_callback(self: Any, callback: SetCallback) -> None:
        with self._param_lock:
            self._on_set_callbacks.remove(callback)

    def _run_on_set_callbacks(self: Any, params: list[Parameter]) -> SetParametersResult:
        for cb in list(self._on_set_callbacks):
            try:
                result = cb(params)
            except Exception as exc:
                return SetParametersResult(False, f"on-set callback raised {type(exc).__name__}: {exc}")
            if isinstance(result, bool):
                result = SetParametersResult(result, "" if result else "refused by an on-set callback")
            if not isinstance(result, SetParametersResult):
                return SetParametersResult(False, f"on-set callback returned {result!r}, "
                                                  "not a SetParametersResult")
            if not result.successful:
                return result
        return SetParametersResult(True)

    def _check_set(self: Any, param: Parameter) -> tuple[Parameter | None, str]:
        decl = self._parameters.get(param.name)
        if decl is None:
            return None, f"parameter {param.name!r} is not declared"
        if decl.descriptor.read_only:
            return None, f"parameter {param.name!r} is read-only"
        want = decl.descriptor.type
        if param.value is None:
            return None, f"parameter {param.name!r}: cannot unset a declared parameter"
        try:
            value = coerce(param.value, want)
        except InvalidParameterTypeError as exc:
            return None, f"parameter {param.name!r}: {exc}"
        return Parameter(param.name, want, value), ""

    def set_parameters(self: Any, parameters: Iterable[Parameter]) -> list[SetParametersResult]:
        """Set each parameter on its own; one result per parameter, in order."""
        return [self.set_parameters_atomically([p]) for p in parameters]

    def set_parameters_atomically(self: Any, parameters: Iterable[Parameter]) -> SetParametersResult:
        """All or nothing: one result for the lot."""
        params = list(parameters)
        with self._param_lock:
            checked: list[Parameter] = []
            for p in params:
                if not isinstance(p, Parameter):
                    return SetParametersResult(False, f"{p!r} is not a Parameter")
                ok, reason = self._check_set(p)
                if ok is None:
                    return SetParametersResult(False, reason)
                checked.append(ok)
            result = self._run_on_set_callbacks(checked)
            if result.successful:
                for p in checked:
                    self._parameters[p.name].value = p.value
            return result

    # -- the parameter services (run on the executor) ---------------------------------------
    def _srv_list_parameters(self: Any, req: ListParametersRequest) -> ListParametersResponse:
        return ListParametersResponse(self.list_parameters(req.prefixes))

    def _srv_get_parameters(self: Any, req: GetParametersRequest) -> GetParametersResponse:
        values = []
        with self._param_lock:
            for name in req.names:
                decl = self._parameters.get(name)
                values.append(ParameterValue() if decl is None
                              else ParameterValue.of(decl.descriptor.type, decl.value))
        return GetParametersResponse(values)

    def _srv_set_parameters(self: Any, req: SetParametersRequest) -> SetParametersResponse:
        results = []
        for pm in req.parameters:
            try:
                t, v = pm.value.to_python()
                res = self.set_parameters([Parameter(pm.name, v)])[0] if t is not ParameterType.NOT_SET \
                    else SetParametersResult(False, f"parameter {pm.name!r}: no value given")
            except ParameterError as exc:
                res = SetParametersResult(False, str(exc))
            results.append(SetParametersResultMsg(res.successful, res.reason))
        return SetParametersResponse(results)

    def _srv_describe_parameters(self: Any, req: DescribeParametersRequest) -> DescribeParametersResponse:
        out = []
        with self._param_lock:
            for name in req.names:
                decl = self._parameters.get(name)
                if decl is None:
                    out.append(ParameterDescriptorMsg(name, int(ParameterType.NOT_SET)))
                else:
                    d = decl.descriptor
                    out.append(ParameterDescriptorMsg(d.name, int(d.type), d.description, d.read_only))
        return DescribeParametersResponse(out)


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


# -- QoS from parameters (as the thesis's nodes do) -----------------------------------------------
def qos_from_parameters(node: "Node", base_profile: QoSProfile, prefix: str = "") -> QoSProfile:
    """Declare ``reliability``, ``history`` and ``depth`` (under ``prefix.`` if given) with
    ``base_profile``'s values as defaults, and return ``base_profile`` with the values in force.

    Set them with ``-p reliability:=best_effort -p depth:=1`` or from a launch file.
    Raises QoSError naming the parameter for a value that is no policy.
    """
    def full(n: str) -> str:
        return f"{prefix}.{n}" if prefix else n

    defaults = {"reliability": base_profile.reliability.name.lower(),
                "history": base_profile.history.name.lower(), "depth": base_profile.depth}
    values: dict[str, Any] = {}
    for short, default in defaults.items():
        name = full(short)
        if not node.has_parameter(name):
            node.declare_parameter(name, default, f"QoS {short} of the node's streams (read at start)")
        values[short] = node.get_parameter_value(name)
    try:
        reliability = ReliabilityPolicy.parse(values["reliability"])
    except ValueError as exc:
        raise QoSError(f"parameter {full('reliability')}: {exc}") from None
    try:
        history = HistoryPolicy.parse(values["history"])
    except ValueError as exc:
        raise QoSError(f"parameter {full('history')}: {exc}") from None
    try:
        return base_profile.replace(reliability=reliability, history=history, depth=values["depth"])
    except QoSError as exc:
        raise QoSError(f"parameters {full('history')}/{full('depth')}: {exc}") from None
