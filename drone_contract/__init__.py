"""The GCS <-> drone contract: what a GCS and a drone's companion agree on, imported by both apps.

- ``messages``: VehicleState, Command, CommandResult, DroneSetpoint, FailsafeEvent.
- ``streams``: the streams between them (``STREAM_SPECS``), their QoS per profile (``PROFILES``).
- ``commands``: the command set (``CommandName``, ``COMMAND_SPECS``).
- ``limits``: the limits the companion enforces and the GCS plans within.
- ``tunnel``: the MAVLink tunnel's packet and streams.

The apps (``companion``, ``gcs``) import this package and never each other
(tests/test_architecture.py). A new stream is one row of ``STREAM_SPECS``.
"""
