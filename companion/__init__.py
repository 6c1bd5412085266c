"""The drone-side process: setpoints in -> PX4; PX4 telemetry and camera frames out."""
