"""The ground-side process: setpoint/mission streaming, telemetry and images, live statistics."""
