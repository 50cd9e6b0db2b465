"""``python -m profrobot.cli``: the ``profrobot`` command."""

import sys

from .main import main

if __name__ == "__main__":
    sys.exit(main())
