"""`zenoh-robot interface list|show`: the library's, the drone's (entry points) and .msg files' types."""
from __future__ import annotations

from cli_helpers import ROOT, cli


def test_list_has_standard_drone_and_service_types():
    out = cli("interface", "list")
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    msgs, srvs = lines.index("Messages:"), lines.index("Services:")
    messages, services = lines[msgs + 1:srvs], lines[srvs + 1:]
    for name in ("std_msgs/String", "zenoh_robot/Setpoint", "sensor_msgs/Image",
                 "zenoh_robot/VehicleState", "zenoh_robot/Command"):        # the last two: entry point
        assert f"    {name}" in messages, out.stdout
    assert "    zenoh_robot/GetParameters" in services
    assert not [m for m in messages if m.endswith(("_Request", "_Response"))], messages
    only = cli("interface", "list", "--only-srvs")
    assert "Messages:" not in only.stdout and "    zenoh_robot/SetParameters" in only.stdout


def test_show_expands_nested_types_with_defaults():
    out = cli("interface", "show", "Setpoint")
    assert out.returncode == 0, out.stderr
    assert out.stdout.splitlines() == [
        "std_msgs/Header header", "\tint64 stamp 0", "\tstring frame_id ''", "\tint64 seq 0",
        "float64 x 0.0", "float64 y 0.0", "float64 z 0.0", "float64 yaw 0.0", "bool is_velocity false"]
    flat = cli("interface", "show", "zenoh_robot/Setpoint", "--no-expand")
    assert "\t" not in flat.stdout and flat.stdout.startswith("std_msgs/Header header\nfloat64 x 0.0\n")


def test_show_a_drone_message_and_a_service():
    out = cli("interface", "show", "VehicleState")
    assert out.returncode == 0, out.stderr
    assert "bool landed true" in out.stdout.splitlines() and "float32[3] position [0.0, 0.0, 0.0]" in out.stdout
    out = cli("interface", "show", "GetParameters")
    assert out.returncode == 0, out.stderr
    request, response = out.stdout.split("---\n")
    assert request == "string[] names\n"
    assert response.startswith("zenoh_robot/ParameterValue[] values\n\tuint8 type 0\n\tbool bool_value false\n")


def test_show_a_msg_file_keeps_its_constants_and_long_arrays_short(tmp_path):
    out = cli("interface", "show", str(ROOT / "configs/msg/HumanoidState.msg"))
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    assert lines[0] == "uint8 NUM_JOINTS=28"
    assert "float64[28] joint_positions" in lines            # 28 zeros would say nothing
    assert "float64[3] center_of_mass [0.0, 0.0, 0.0]" in lines
    msg = tmp_path / "Pose2.msg"
    msg.write_text("std_msgs/Header header\nfloat32 heading 1.5  # rad\nstring[] tags\n")
    out = cli("interface", "show", str(msg))
    assert out.stdout.splitlines() == ["std_msgs/Header header", "\tint64 stamp 0", "\tstring frame_id ''",
                                       "\tint64 seq 0", "float32 heading 1.5", "string[] tags"], out.stdout


def test_unknown_interface_is_one_line_with_a_suggestion():
    out = cli("interface", "show", "Setpoin")
    assert out.returncode == 1
    assert out.stderr.splitlines() == ["zenoh-robot interface: unknown interface 'Setpoin' (did you mean Setpoint "
                                       "or DroneSetpoint or String?) (see `zenoh-robot interface list`)"]
