"""The lab: programs that run the drone system's processes to show and measure it.

``demo`` (simulator + companion + GCS flying a square), ``experiment`` (the thesis's lossy-link
sweep between network namespaces), ``swarm`` (one GCS, N drones) and the stall and handshake runs.
They start ``python -m companion``, ``-m gcs`` and ``-m px4_link.sim``, so they belong to the
drone wing, not to the library's tools; they plug into ``zenoh-robot`` through the
``zenoh_robot.cli`` entry-point group as the apps do (``drone_lab.cli:register``).
"""
