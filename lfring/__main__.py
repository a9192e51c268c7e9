"""``python -m lfring``: the same command-line app as the ``lfring`` script."""

import sys

from lfring.cli.main import main

if __name__ == "__main__":
    sys.exit(main())
