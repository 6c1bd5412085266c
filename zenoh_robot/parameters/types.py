"""Parameter values and their rules: types, coercion (int -> float only), results, descriptors, errors."""
from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import Any


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
