"""``python -m lfstudio`` — same as the ``lfstudio`` console script."""

import sys

from lfstudio.cli import main

if __name__ == "__main__":
    sys.exit(main())
