"""zenoh-robot: ROS 2-style nodes, typed messages and QoS over Zenoh.

This package is the library a robot developer imports: nodes and their entities, executors,
QoS (profiles, compatibility, the Zenoh mapping), events, the graph, services, parameters,
messages and the ``.msg`` loader, session configuration and topic statistics. It loads no tool:
the CLI, launch, bench, experiments and recorders live in ``zenoh_robot.tools`` and are imported
only on purpose. The layers are described in docs/architecture.md.
"""
from __future__ import annotations

from . import msgs, qos
from .events import (
    IncompatibleTypeInfo,
    MatchedInfo,
    PublisherEventCallbacks,
    QoSLivelinessChangedInfo,
    QoSLivelinessLostInfo,
    QoSMessageLostInfo,
    QoSOfferedDeadlineMissedInfo,
    QoSOfferedIncompatibleQoSInfo,
    QoSRequestedDeadlineMissedInfo,
    QoSRequestedIncompatibleQoSInfo,
    SubscriptionEventCallbacks,
)
from .executor import Executor, MultiThreadedExecutor, Timer
from .graph import EndpointType, NodeInfo, TopicEndpointInfo
from .message import Message, array, message, ros_field
from .msg_loader import load_msg
from .names import InvalidNameError
from .node import Node
from .parameters import (
    Parameter,
    ParameterDescriptor,
    ParameterType,
    SetParametersResult,
    parse_param_args,
    qos_from_parameters,
)
from .publisher import Publisher
from .qos import (
    Durability,
    DurabilityPolicy,
    History,
    HistoryPolicy,
    Liveliness,
    LivelinessPolicy,
    Priority,
    QoSError,
    QoSProfile,
    Reliability,
    ReliabilityPolicy,
)
from .qos_compat import Compatibility, PolicyKind, check_compatibility
from .services import Client, RetryPolicy, Service, ServiceCallError, ServiceError, ServiceTimeout, ServiceUnavailable
from .session_config import SessionConfig, SessionConfigError
from .subscription import MessageInfo, Subscription
from .topic_statistics import TopicStatisticsOptions

__version__ = "0.6.0"

__all__ = [
    # nodes, entities, executors
    "Node", "Publisher", "Subscription", "MessageInfo", "Timer", "Executor", "MultiThreadedExecutor",
    "Service", "Client", "RetryPolicy", "ServiceCallError", "ServiceError", "ServiceTimeout", "ServiceUnavailable",
    # messages
    "Message", "message", "array", "ros_field", "load_msg", "msgs",
    # QoS
    "qos", "QoSProfile", "QoSError", "Reliability", "ReliabilityPolicy", "Durability", "DurabilityPolicy",
    "History", "HistoryPolicy", "Liveliness", "LivelinessPolicy", "Priority",
    "Compatibility", "PolicyKind", "check_compatibility",
    # events
    "PublisherEventCallbacks", "SubscriptionEventCallbacks", "QoSRequestedDeadlineMissedInfo",
    "QoSOfferedDeadlineMissedInfo", "QoSLivelinessChangedInfo", "QoSLivelinessLostInfo",
    "QoSRequestedIncompatibleQoSInfo", "QoSOfferedIncompatibleQoSInfo", "QoSMessageLostInfo",
    "IncompatibleTypeInfo", "MatchedInfo",
    # graph, parameters, sessions, statistics
    "EndpointType", "NodeInfo", "TopicEndpointInfo",
    "Parameter", "ParameterType", "ParameterDescriptor", "SetParametersResult", "parse_param_args",
    "qos_from_parameters", "SessionConfig", "SessionConfigError", "InvalidNameError", "TopicStatisticsOptions",
]
