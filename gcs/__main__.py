"""``python -m gcs``: the same as ``zenoh-robot gcs``."""
import sys

if __name__ == "__main__":
    # Ctrl-C, or a launch stopping its processes, can come while the imports below still run (a second
    # or more on a loaded machine): an interrupted start-up ends quietly, exit 130, as a run does.
    try:
        from zenoh_robot.tools.cli.main import run_single

        from .cli import register
    except KeyboardInterrupt:
        sys.exit(130)
    sys.exit(run_single(register, "gcs", "python -m gcs"))
