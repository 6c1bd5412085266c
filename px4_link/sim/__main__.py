"""``python -m px4_link.sim``: see px4_link.sim.cli for the options."""
import sys

from .cli import main

sys.exit(main())
