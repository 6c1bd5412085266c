"""QoS profiles: rclpy-like repr, presets, YAML round trip with clear errors, Zenoh mapping."""
from __future__ import annotations

from pathlib import Path

import pytest
import zenoh

from zenoh_robot import QoSError, QoSProfile, qos
from zenoh_robot.qos import DurabilityPolicy, HistoryPolicy, Priority, ReliabilityPolicy, load_qos, save_qos
from zenoh_robot.qos_mapping import publisher_options

pytestmark = pytest.mark.fast   # in-process only (conftest: the fast tier)

ROOT = Path(__file__).resolve().parents[2]


def test_repr_reads_like_rclpy() -> None:
    assert repr(qos.SENSOR_DATA) == (
        "QoSProfile(reliability=ReliabilityPolicy.BEST_EFFORT, durability=DurabilityPolicy.VOLATILE, "
        "history=HistoryPolicy.KEEP_LAST, depth=5)")
    assert "deadline=0.5" in repr(QoSProfile(deadline=0.5))


def test_presets() -> None:
    assert (qos.SYSTEM_DEFAULT.reliability, qos.SYSTEM_DEFAULT.depth) == (ReliabilityPolicy.RELIABLE, 10)
    assert qos.CONTROL.depth == 3 and qos.CONTROL.reliability is ReliabilityPolicy.RELIABLE
    assert qos.CONFIGURATION.durability is DurabilityPolicy.TRANSIENT_LOCAL
    assert qos.CONFIGURATION.history is HistoryPolicy.KEEP_ALL
    assert qos.FEEDBACK.depth == 10
    assert qos.SETPOINT.priority is Priority.REAL_TIME and qos.SETPOINT.express
    assert qos.IMAGE.priority is Priority.DATA_LOW


def test_strings_parse_and_bad_values_name_the_key() -> None:
    p = QoSProfile(reliability="best_effort", history="KEEP_ALL", depth=0, deadline="infinite")
    assert p.reliability is ReliabilityPolicy.BEST_EFFORT and p.deadline is None
    with pytest.raises(QoSError, match="reliability: 'sometimes' is not a ReliabilityPolicy"):
        QoSProfile(reliability="sometimes")
    with pytest.raises(QoSError, match="depth"):
        QoSProfile(depth=-1)
    with pytest.raises(QoSError, match="KEEP_LAST needs depth >= 1"):
        QoSProfile(depth=0)
    with pytest.raises(QoSError, match="deadline"):
        QoSProfile(deadline="soon")


def test_yaml_round_trip(tmp_path: Path) -> None:
    profiles = {"a": qos.SENSOR_DATA, "b": QoSProfile(deadline=0.25, lifespan=2.0, priority=Priority.DATA_HIGH,
                                                      express=True, liveliness="manual_by_topic",
                                                      liveliness_lease_duration=1.5)}
    path = tmp_path / "q.yaml"
    save_qos(profiles, path)
    assert load_qos(path) == profiles


def test_yaml_errors_name_file_profile_and_key(tmp_path: Path) -> None:
    path = tmp_path / "bad.yaml"
    path.write_text("setpoint:\n  reliabilty: reliable\n")
    with pytest.raises(QoSError, match=r"bad.yaml: profile 'setpoint': unknown QoS key\(s\) \['reliabilty'\]"):
        load_qos(path)
    path.write_text("setpoint:\n  depth: many\n")
    with pytest.raises(QoSError, match="depth"):
        load_qos(path)
    path.write_text("a: [unclosed\n")
    with pytest.raises(QoSError, match="not valid YAML"):
        load_qos(path)


def test_shipped_profiles_load() -> None:
    for f in (ROOT / "configs" / "qos").glob("*.yaml"):
        assert load_qos(f), f
    robot = load_qos(ROOT / "configs" / "qos" / "robot_profiles.yaml")
    assert robot["setpoint"].deadline == 1.0 and robot["setpoint"].priority is Priority.REAL_TIME


def test_mapping_to_zenoh() -> None:
    be = publisher_options(qos.SETPOINT)
    assert be["reliability"] == zenoh.Reliability.BEST_EFFORT
    assert be["congestion_control"] == zenoh.CongestionControl.DROP
    assert be["priority"] == zenoh.Priority.REAL_TIME and be["express"] is True
    rel = publisher_options(qos.CONFIGURATION)
    assert rel["reliability"] == zenoh.Reliability.RELIABLE
    assert rel["congestion_control"] == zenoh.CongestionControl.BLOCK
