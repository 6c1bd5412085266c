"""``python -m px4_zenoh.sim``: see px4_zenoh.sim.cli for the options."""
import sys

if __name__ == "__main__":
    # Ctrl-C, or a launch stopping its processes, can come while the imports below still run (a second
    # or more on a loaded machine): an interrupted start-up ends quietly, exit 130, as a run does.
    try:
        from .cli import main

        code = main()
    except KeyboardInterrupt:
        code = 130
    sys.exit(code)
