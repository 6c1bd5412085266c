"""Services over Zenoh queryables: typed calls and each way a call can fail."""
from __future__ import annotations

import threading
import time
from concurrent.futures import Future

import pytest
from cli_helpers import CLI_ARGS
from conftest import python_proc, wait_ready

from zenoh_robot import Message, Node, message
from zenoh_robot.services import ServiceCallError, ServiceError, ServiceTimeout, ServiceUnavailable, service_key


@message(name="test_services/AddRequest")
class AddRequest(Message):
    a: int = 0
    b: int = 0


@message(name="test_services/AddResponse")
class AddResponse(Message):
    total: int = 0


@message(name="test_services/OtherRequest")
class OtherRequest(Message):
    text: str = ""


def add(req: AddRequest) -> AddResponse:
    if req.a < 0:
        raise ValueError(f"a must be >= 0, got {req.a}")
    return AddResponse(req.a + req.b)


@pytest.fixture
def server(ns):
    """A node serving `add` in namespace `ns`, spinning on its own thread."""
    node = Node("server", namespace=ns)
    node.create_service("add", AddRequest, AddResponse, add)
    thread = threading.Thread(target=node.spin, daemon=True)
    thread.start()
    yield node
    node.shutdown()
    thread.join(timeout=5)
    node.close()


@pytest.fixture
def client_node(ns):
    with Node("client", namespace=ns) as node:
        yield node


def test_key_format(ns):
    assert service_key("arm", "uav1") == "@srv/uav1/arm"
    assert service_key("~/get_parameters", "uav1", "companion") == "@srv/uav1/companion/get_parameters"
    assert service_key("/abs/x", "uav1") == "@srv/abs/x"


def test_typed_round_trip(server, client_node):
    client = client_node.create_client("add", AddRequest, AddResponse)
    assert client.wait_for_service(5.0)
    response = client.call(AddRequest(2, 40), timeout=3.0)
    assert isinstance(response, AddResponse)
    assert response.total == 42
    future = client.call_async(AddRequest(1, 2), timeout=3.0)
    assert isinstance(future, Future)
    assert future.result(5.0).total == 3


def test_handler_exception_is_an_error_reply_and_server_keeps_serving(server, client_node):
    client = client_node.create_client("add", AddRequest, AddResponse)
    assert client.wait_for_service(5.0)
    with pytest.raises(ServiceError) as err:
        client.call(AddRequest(-1, 2), timeout=3.0)
    assert err.value.kind == "handler"
    assert "ValueError" in str(err.value) and "a must be >= 0, got -1" in str(err.value)
    assert client.call(AddRequest(5, 6), timeout=3.0).total == 11
    assert server.services[-1].errors == 1


def test_timeout_when_the_server_does_not_spin(ns, client_node):
    with Node("lazy", namespace=ns) as lazy:   # never spins: requests queue, nobody answers
        lazy.create_service("slow", AddRequest, AddResponse, add)
        client = client_node.create_client("slow", AddRequest, AddResponse)
        assert client.wait_for_service(5.0)
        t0 = time.monotonic()
        with pytest.raises(ServiceTimeout, match="no reply within 0.5 s"):
            client.call(AddRequest(1, 1), timeout=0.5)
        assert 0.4 < time.monotonic() - t0 < 4.0


def test_no_server_is_unavailable_quickly(client_node):
    client = client_node.create_client("nobody_serves_this", AddRequest, AddResponse)
    assert client.discovers_servers      # a unicast session: service_is_ready follows declarations
    assert not client.wait_for_service(0.2)
    t0 = time.monotonic()
    with pytest.raises(ServiceUnavailable, match="no server"):
        client.call(AddRequest(1, 1), timeout=10.0)
    assert time.monotonic() - t0 < 3.0    # far below the 10 s timeout
    assert issubclass(ServiceUnavailable, ServiceCallError)


def test_wrong_request_type_names_both_types(server, client_node):
    client = client_node.create_client("add", OtherRequest, AddResponse)
    assert client.wait_for_service(5.0)
    with pytest.raises(ServiceError) as err:
        client.call(OtherRequest("hi"), timeout=3.0)
    assert err.value.kind == "type"
    assert "test_services/AddRequest" in str(err.value)
    assert "test_services/OtherRequest" in str(err.value)
    with pytest.raises(TypeError):
        client.call(AddRequest(1, 2))   # not what this client sends


def test_call_from_a_callback_of_a_single_threaded_executor(server, ns):
    results: list[int] = []
    with Node("caller", namespace=ns) as node:
        client = node.create_client("add", AddRequest, AddResponse)
        assert client.wait_for_service(5.0)

        def tick() -> None:
            if not results:
                results.append(client.call(AddRequest(20, 22), timeout=3.0).total)

        node.create_timer(0.05, tick)
        assert node.spin_until(lambda: bool(results), timeout=10.0)
    assert results == [42]


def test_service_cli_list_and_call(ns):
    proc = python_proc("tests/procs/svc_param_node.py", "--ns", ns)
    try:
        assert wait_ready(proc)
        out = python_proc(*CLI_ARGS, "service", "list", f"/{ns}", "-t")
        text, _ = out.communicate(timeout=30)
        assert out.returncode == 0, text
        assert f"/{ns}/echo [std_msgs/String -> std_msgs/String]" in text
        assert f"/{ns}/pnode/get_parameters" in text
        call = python_proc(*CLI_ARGS, "service", "call", f"/{ns}/echo", "{data: hello}")
        text, _ = call.communicate(timeout=30)
        assert call.returncode == 0, text
        assert "data: HELLO" in text
        bad = python_proc(*CLI_ARGS, "service", "call", f"/{ns}/echo", "{dat: x}")
        text, _ = bad.communicate(timeout=30)
        assert bad.returncode == 1
        assert "has no field(s) ['dat']" in text
    finally:
        proc.terminate()
        proc.wait(timeout=10)
