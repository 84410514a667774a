"""``python -m nanosim.cli``: the command line (:func:`nanosim.cli.main`)."""
import sys

from nanosim.cli import main

sys.exit(main())
