"""The ``zenoh-robot`` command line."""
