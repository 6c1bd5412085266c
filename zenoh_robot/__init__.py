"""zenoh-robot: ROS 2-style nodes, typed messages and QoS over Zenoh."""
from __future__ import annotations

from . import msgs, qos
from .executor import Executor, MultiThreadedExecutor, Timer
from .message import Message, array, message, ros_field
from .msg_loader import load_msg
from .names import InvalidNameError
from .node import Node
from .publisher import Publisher
from .qos import (Durability, DurabilityPolicy, History, HistoryPolicy, Liveliness, LivelinessPolicy,
                  Priority, QoSError, QoSProfile, Reliability, ReliabilityPolicy)
from .session_config import SessionConfig, SessionConfigError
from .subscription import MessageInfo, Subscription

__version__ = "0.1.0"
__all__ = [
    "Node", "Publisher", "Subscription", "MessageInfo", "Timer", "Executor", "MultiThreadedExecutor",
    "Message", "message", "array", "ros_field", "load_msg", "msgs", "qos", "QoSProfile", "QoSError",
    "Reliability", "ReliabilityPolicy", "Durability", "DurabilityPolicy", "History", "HistoryPolicy",
    "Liveliness", "LivelinessPolicy", "Priority", "SessionConfig", "SessionConfigError", "InvalidNameError",
]

# Services, parameters and launch (appended; imported after the core names above).
from .launch import LaunchError, LaunchRunner  # noqa: E402
from .parameters import (Parameter, ParameterDescriptor, ParameterType, SetParametersResult,  # noqa: E402
                         parse_param_args, qos_from_parameters)
from .services import (Client, Service, ServiceCallError, ServiceError, ServiceTimeout,  # noqa: E402
                       ServiceUnavailable)

__all__ += [
    "Parameter", "ParameterType", "ParameterDescriptor", "SetParametersResult", "parse_param_args",
    "qos_from_parameters", "Service", "Client", "ServiceCallError", "ServiceError", "ServiceTimeout",
    "ServiceUnavailable", "LaunchRunner", "LaunchError",
]

# QoS events, compatibility and the graph.
from .events import (IncompatibleTypeInfo, MatchedInfo, PublisherEventCallbacks,  # noqa: E402
                     QoSLivelinessChangedInfo, QoSLivelinessLostInfo, QoSMessageLostInfo,
                     QoSOfferedDeadlineMissedInfo, QoSOfferedIncompatibleQoSInfo,
                     QoSRequestedDeadlineMissedInfo, QoSRequestedIncompatibleQoSInfo, SubscriptionEventCallbacks)
from .graph import EndpointType, NodeInfo, TopicEndpointInfo  # noqa: E402
from .qos_compat import Compatibility, PolicyKind, check_compatibility  # noqa: E402

__all__ += [
    "PublisherEventCallbacks", "SubscriptionEventCallbacks", "QoSRequestedDeadlineMissedInfo",
    "QoSOfferedDeadlineMissedInfo", "QoSLivelinessChangedInfo", "QoSLivelinessLostInfo",
    "QoSRequestedIncompatibleQoSInfo", "QoSOfferedIncompatibleQoSInfo", "QoSMessageLostInfo",
    "IncompatibleTypeInfo", "MatchedInfo", "EndpointType", "NodeInfo", "TopicEndpointInfo",
    "Compatibility", "PolicyKind", "check_compatibility",
]
from .topic_statistics import StatisticsRecorder, TopicStatisticsOptions  # noqa: E402

__all__ += ["StatisticsRecorder", "TopicStatisticsOptions"]
