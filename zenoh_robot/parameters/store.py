"""A node's declared parameters: declare, get, set (each or all at once), on-set callbacks.

Semantics follow rclpy: a parameter must be declared before use; the type of its
default fixes its type (an int is accepted where a double was declared, nothing
else converts); overrides given to ``Node(parameter_overrides=...)`` (from
``-p name:=value`` or a launch file) replace the default at declare time;
``set_parameters`` sets each parameter on its own and returns one
SetParametersResult per parameter; on-set callbacks see the new values first and
may refuse them (also at declare time, as in rclpy).
"""
from __future__ import annotations

import threading
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any, Protocol

from ..qos import HistoryPolicy, QoSError, QoSProfile, ReliabilityPolicy
from .types import (
    InvalidParameterTypeError,
    InvalidParameterValueError,
    Parameter,
    ParameterAlreadyDeclaredError,
    ParameterDescriptor,
    ParameterNotDeclaredError,
    ParameterType,
    SetParametersResult,
    coerce,
    infer_type,
)


@dataclass
class _Declared:
    descriptor: ParameterDescriptor
    value: Any


SetCallback = Callable[[list[Parameter]], "SetParametersResult | bool"]


class ParameterStore:
    """One node's declared parameters (the node owns one and delegates rclpy's parameter API to it).

    Thread safe: the parameter services set values on the executor while the user may
    read them from any thread.
    """

    def __init__(self, overrides: dict[str, Any] | None = None) -> None:
        self._parameter_overrides = dict(overrides or {})
        self._parameters: dict[str, _Declared] = {}
        self._param_lock = threading.RLock()
        self._on_set_callbacks: list[SetCallback] = []

    # -- declaring -------------------------------------------------------------------------
    def declare_parameter(self, name: str, default: Any = None, description: str = "",
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

    def declare_parameters(self, namespace: str,
                           parameters: Iterable[tuple[Any, ...]] | dict[str, Any]) -> list[Parameter]:
        """rclpy's form: ``[(name, default), (name, default, description), ...]`` or ``{name: default}``."""
        items = parameters.items() if isinstance(parameters, dict) else parameters
        out = []
        for item in items:
            name, default, *rest = item
            full = f"{namespace}.{name}" if namespace else name
            out.append(self.declare_parameter(full, default, *rest))
        return out

    def undeclare_parameter(self, name: str) -> None:
        with self._param_lock:
            decl = self._get_declared(name)
            if decl.descriptor.read_only:
                raise InvalidParameterValueError(f"parameter {name!r} is read-only")
            del self._parameters[name]

    # -- reading ---------------------------------------------------------------------------
    def _get_declared(self, name: str) -> _Declared:
        try:
            return self._parameters[name]
        except KeyError:
            raise ParameterNotDeclaredError(f"parameter {name!r} is not declared") from None

    def lookup(self, name: str) -> tuple[ParameterDescriptor, Any] | None:
        """(descriptor, value) of ``name``, or None if it is not declared."""
        with self._param_lock:
            decl = self._parameters.get(name)
            return None if decl is None else (decl.descriptor, decl.value)

    def has_parameter(self, name: str) -> bool:
        with self._param_lock:
            return name in self._parameters

    def get_parameter(self, name: str) -> Parameter:
        with self._param_lock:
            decl = self._get_declared(name)
            return Parameter(name, decl.descriptor.type, decl.value)

    def get_parameters(self, names: Iterable[str]) -> list[Parameter]:
        return [self.get_parameter(n) for n in names]

    def get_parameter_value(self, name: str) -> Any:
        return self.get_parameter(name).value

    def get_parameter_or(self, name: str, alternative: Any = None) -> Any:
        with self._param_lock:
            decl = self._parameters.get(name)
            return alternative if decl is None or decl.value is None else decl.value

    def describe_parameter(self, name: str) -> ParameterDescriptor:
        with self._param_lock:
            return self._get_declared(name).descriptor

    def list_parameters(self, prefixes: Iterable[str] = ()) -> list[str]:
        prefixes = list(prefixes)
        with self._param_lock:
            names = sorted(self._parameters)
        if not prefixes:
            return names
        return [n for n in names if any(n == p or n.startswith(p + ".") for p in prefixes)]

    # -- setting ---------------------------------------------------------------------------
    def add_on_set_parameters_callback(self, callback: SetCallback) -> None:
        """``callback(list[Parameter]) -> SetParametersResult``: refuse with successful=False and a reason."""
        with self._param_lock:
            self._on_set_callbacks.insert(0, callback)   # rclpy calls the newest first

    def remove_on_set_parameters_callback(self, callback: SetCallback) -> None:
        with self._param_lock:
            self._on_set_callbacks.remove(callback)

    def _run_on_set_callbacks(self, params: list[Parameter]) -> SetParametersResult:
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

    def _check_set(self, param: Parameter) -> tuple[Parameter | None, str]:
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

    def set_parameters(self, parameters: Iterable[Parameter]) -> list[SetParametersResult]:
        """Set each parameter on its own; one result per parameter, in order."""
        return [self.set_parameters_atomically([p]) for p in parameters]

    def set_parameters_atomically(self, parameters: Iterable[Parameter]) -> SetParametersResult:
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


# -- QoS from parameters (as the thesis's nodes do) -----------------------------------------------
class _DeclaresParameters(Protocol):
    def has_parameter(self, name: str) -> bool: ...

    def declare_parameter(self, name: str, default: Any = ..., description: str = ...) -> Parameter: ...

    def get_parameter_value(self, name: str) -> Any: ...


def qos_from_parameters(node: _DeclaresParameters, base_profile: QoSProfile, prefix: str = "") -> QoSProfile:
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
