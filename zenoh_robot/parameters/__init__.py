"""ROS 2-style node parameters: values and rules (types), a node's store (store), the parameter
services and their wire types (service), another node's parameters (client), ``-p name:=value``
(args). Every name this package ever exported is importable from ``zenoh_robot.parameters``.
"""
from __future__ import annotations

from .args import add_param_argument, format_param_value, params_from_args, parse_param_args, parse_param_value
from .client import ParameterClient, default_client_id
from .service import (
                      PARAMETER_SERVICES,
                      DescribeParametersRequest,
                      DescribeParametersResponse,
                      GetParametersRequest,
                      GetParametersResponse,
                      ListParametersRequest,
                      ListParametersResponse,
                      ParameterDescriptorMsg,
                      ParameterMsg,
                      ParameterService,
                      ParameterValue,
                      SetParametersRequest,
                      SetParametersResponse,
                      SetParametersResultMsg,
                      WriteGuard,
                      current_caller,
)
from .store import ParameterStore, SetCallback, qos_from_parameters
from .types import (
                      InvalidParameterTypeError,
                      InvalidParameterValueError,
                      Parameter,
                      ParameterAlreadyDeclaredError,
                      ParameterDescriptor,
                      ParameterError,
                      ParameterNotDeclaredError,
                      ParameterType,
                      SetParametersResult,
                      coerce,
                      infer_type,
)

__all__ = [
    "ParameterType", "Parameter", "ParameterDescriptor", "SetParametersResult", "ParameterError",
    "ParameterNotDeclaredError", "ParameterAlreadyDeclaredError", "InvalidParameterTypeError",
    "InvalidParameterValueError", "infer_type", "coerce",
    "ParameterStore", "SetCallback", "qos_from_parameters",
    "ParameterService", "PARAMETER_SERVICES", "ParameterValue", "ParameterMsg", "SetParametersResultMsg",
    "ParameterDescriptorMsg", "ListParametersRequest", "ListParametersResponse", "GetParametersRequest",
    "GetParametersResponse", "SetParametersRequest", "SetParametersResponse", "DescribeParametersRequest",
    "DescribeParametersResponse", "WriteGuard", "current_caller",
    "ParameterClient", "default_client_id",
    "parse_param_value", "parse_param_args", "add_param_argument", "params_from_args", "format_param_value",
]
