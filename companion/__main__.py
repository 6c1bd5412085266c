"""``python -m companion``: the same as ``zenoh-robot companion``."""
import sys

from zenoh_robot.tools.cli.main import run_single

from .cli import register

if __name__ == "__main__":
    sys.exit(run_single(register, "companion", "python -m companion"))
