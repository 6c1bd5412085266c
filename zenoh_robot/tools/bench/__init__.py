"""``zenoh-robot bench``: the framework's cost over raw zenoh-python, measured in the same run."""
