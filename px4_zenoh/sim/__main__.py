"""``python -m px4_zenoh.sim``: see px4_zenoh.sim.cli for the options."""
import sys

from .cli import main

sys.exit(main())
