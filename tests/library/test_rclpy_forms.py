"""rclpy's service forms (issue #40): ``create_service(srv_type, name, callback(request, response))`` and
``create_client(srv_type, name)`` beside the project's ``(name, Req, Resp, handler)``, so ROS 2 code
ports by changing its imports; ``wait_for_service(timeout_sec=...)``."""
from __future__ import annotations

import pytest
from conftest import spinning_nodes

from zenoh_robot import Message, message
from zenoh_robot.ros2 import ros2_service_type
from zenoh_robot.services import ServiceError

pytestmark = pytest.mark.fast   # in-process sessions only


@message(name="test_rclpy_forms/AddTwoInts_Request")
class AddRequest(Message):
    a: int = 0
    b: int = 0


@message(name="test_rclpy_forms/AddTwoInts_Response")
class AddResponse(Message):
    sum: int = 0


class AddTwoInts:
    """What ``from example_interfaces.srv import AddTwoInts`` gives an rclpy program."""
    Request = AddRequest
    Response = AddResponse


def add_two_ints(request, response):    # rclpy's callback: fill the fresh response and return it
    if request.a < 0:
        raise ValueError("a must be >= 0")
    response.sum = request.a + request.b
    return response


@pytest.mark.parametrize("srv_type", [AddTwoInts, ros2_service_type("example_interfaces/srv/AddTwoInts")],
                         ids=["rclpy-class", "ros2_service_type"])
def test_rclpy_forms_serve_and_call(ns: str, srv_type: object) -> None:
    with spinning_nodes(ns) as (server_node, client_node):
        server = server_node.create_service(srv_type, "add_two_ints", add_two_ints)
        assert server.request_type is srv_type.Request                         # type: ignore[attr-defined]
        client = client_node.create_client(srv_type, "add_two_ints")
        assert client.wait_for_service(timeout_sec=10.0)
        req = srv_type.Request(a=2, b=3)                                       # type: ignore[attr-defined]
        assert client.call(req, timeout=5.0).sum == 5
        assert client.call_async(srv_type.Request(a=40, b=2)).result(5.0).sum == 42   # type: ignore[attr-defined]
        with pytest.raises(ServiceError, match="a must be >= 0"):
            client.call(srv_type.Request(a=-1, b=0), timeout=5.0)             # type: ignore[attr-defined]
        # The project's own form reaches the same service.
        own = client_node.create_client("add_two_ints", srv_type.Request, srv_type.Response)  # type: ignore[attr-defined]
        assert own.call(req, timeout=5.0).sum == 5


def test_a_wrong_first_argument_is_one_clear_error(ns: str) -> None:
    with spinning_nodes(ns) as (node, _):
        with pytest.raises(TypeError, match="a service name .* or a service type with Request and Response"):
            node.create_service(object(), "x", add_two_ints)
        with pytest.raises(TypeError, match="a service name"):
            node.create_client(42, "x")
        with pytest.raises(TypeError, match="callback is not callable"):
            node.create_service(AddTwoInts, "x", None)
