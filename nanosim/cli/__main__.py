"""``python -m nanosim.cli``: the command line (:func:`nanosim.cli.main`)."""
import sys

from nanosim.cli import main

if __name__ == "__main__":       # importable (the API reference imports every module) without running
    sys.exit(main())
