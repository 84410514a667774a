"""``python -m nanosim`` runs the command line."""
import sys

from nanosim.cli import main

sys.exit(main())
