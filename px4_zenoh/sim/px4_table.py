"""What PX4 main of 2026-03 (02e73e3b, ``px4_sitl_zenoh``) declares on Zenoh, as the simulator copies it.

- ``DECLARED``: PX4's default ``pub.csv`` / ``sub.csv`` topics that its zenoh module declared (46
  entities; ``/fmu/in/aux_global_position`` is configured but fails to declare in that build). Type
  names follow the message type, not the topic.
- ``PAYLOAD_LEN``: what PX4 sends per sample of each type: 4-byte header + CDR body + leftover
  bytes, i.e. 4 + sizeof(the uORB C struct) + 24. Sizes of the types the simulator publishes.
- ``RATES_HZ``: how often PX4 SITL (SIH, 250 Hz loop) publishes each topic on the ground; the
  simulator publishes on PX4's 4 ms grid, so 248 Hz reads as 250 and 124 Hz as 125.
- ``LEAN_RATES_HZ``: ``rates="lean"``, the fast topics slowed down for loaded machines (documented
  in docs/px4-zenoh-sim.md); PX4's rates stay the default.
"""
from __future__ import annotations

from px4_zenoh.topics import IN, OUT, Px4Topic

_OUT = ("airspeed_validated AirspeedValidated", "arming_check_request ArmingCheckRequest",
        "battery_status BatteryStatus", "collision_constraints CollisionConstraints",
        "estimator_status_flags EstimatorStatusFlags", "failsafe_flags FailsafeFlags",
        "manual_control_setpoint ManualControlSetpoint", "mode_completed ModeCompleted",
        "position_setpoint_triplet PositionSetpointTriplet",
        "register_ext_component_reply RegisterExtComponentReply", "sensor_combined SensorCombined",
        "timesync_status TimesyncStatus", "vehicle_attitude VehicleAttitude",
        "vehicle_command_ack VehicleCommandAck", "vehicle_control_mode VehicleControlMode",
        "vehicle_global_position VehicleGlobalPosition", "vehicle_gps_position SensorGps",
        "vehicle_land_detected VehicleLandDetected", "vehicle_local_position VehicleLocalPosition",
        "vehicle_odometry VehicleOdometry", "vehicle_status VehicleStatus")
_IN = ("actuator_motors ActuatorMotors", "actuator_servos ActuatorServos", "arming_check_reply ArmingCheckReply",
       "config_control_setpoints VehicleControlMode", "config_overrides_request ConfigOverrides",
       "distance_sensor DistanceSensor", "goto_setpoint GotoSetpoint",
       "manual_control_input ManualControlSetpoint", "mode_completed ModeCompleted",
       "obstacle_distance ObstacleDistance", "offboard_control_mode OffboardControlMode",
       "onboard_computer_status OnboardComputerStatus",
       "register_ext_component_request RegisterExtComponentRequest", "sensor_optical_flow SensorOpticalFlow",
       "telemetry_status TelemetryStatus", "trajectory_setpoint TrajectorySetpoint",
       "unregister_ext_component UnregisterExtComponent", "vehicle_attitude_setpoint VehicleAttitudeSetpoint",
       "vehicle_command VehicleCommand", "vehicle_command_mode_executor VehicleCommand",
       "vehicle_mocap_odometry VehicleOdometry", "vehicle_rates_setpoint VehicleRatesSetpoint",
       "vehicle_thrust_setpoint VehicleThrustSetpoint", "vehicle_torque_setpoint VehicleTorqueSetpoint",
       "vehicle_visual_odometry VehicleOdometry")


def _topics(direction: str, rows: tuple[str, ...]) -> tuple[Px4Topic, ...]:
    return tuple(Px4Topic(f"/fmu/{direction}/{name}", short) for name, short in (r.split() for r in rows))


DECLARED: tuple[Px4Topic, ...] = _topics(OUT, _OUT) + _topics(IN, _IN)

PAYLOAD_LEN: dict[str, int] = {
    "VehicleStatus": 108, "VehicleCommandAck": 52, "FailsafeFlags": 124, "VehicleLandDetected": 52,
    "VehicleLocalPosition": 220, "VehicleGlobalPosition": 100, "VehicleAttitude": 84, "SensorCombined": 76,
    "BatteryStatus": 196, "SensorGps": 180, "VehicleControlMode": 52,
    # external modes: sizeof(register_ext_component_reply_s) 48, arming_check_request_s 16, mode_completed_s 16
    "RegisterExtComponentReply": 76, "ArmingCheckRequest": 44, "ModeCompleted": 44,
}

RATES_HZ: dict[str, float] = {
    "/fmu/out/sensor_combined": 250.0, "/fmu/out/vehicle_attitude": 250.0,
    "/fmu/out/vehicle_local_position": 125.0, "/fmu/out/vehicle_global_position": 125.0,
    "/fmu/out/battery_status": 100.0, "/fmu/out/vehicle_gps_position": 8.0,
    "/fmu/out/vehicle_status": 2.0, "/fmu/out/failsafe_flags": 2.0, "/fmu/out/vehicle_control_mode": 2.0,
    "/fmu/out/vehicle_land_detected": 1.0,
}
LEAN_RATES_HZ: dict[str, float] = {
    **RATES_HZ, "/fmu/out/sensor_combined": 50.0, "/fmu/out/vehicle_attitude": 50.0,
    "/fmu/out/vehicle_local_position": 50.0, "/fmu/out/vehicle_global_position": 25.0,
    "/fmu/out/battery_status": 10.0,
}
RATE_SETS = {"px4": RATES_HZ, "lean": LEAN_RATES_HZ}
# Published on every change too, besides their period (PX4 publishes these uORB topics on change).
ON_CHANGE = ("/fmu/out/vehicle_status", "/fmu/out/vehicle_land_detected", "/fmu/out/vehicle_control_mode",
             "/fmu/out/failsafe_flags")
