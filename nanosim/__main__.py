"""``python -m nanosim`` runs the command line."""
import sys

from nanosim.cli import main

if __name__ == "__main__":       # importable (the API reference imports every module) without running
    sys.exit(main())
