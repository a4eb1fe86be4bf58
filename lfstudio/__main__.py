"""``python -m lfstudio`` — same as the ``lfstudio`` console script."""

import sys

from lfstudio.cli import main

if __name__ == "__main__":
    import multiprocessing

    multiprocessing.freeze_support()   # a PyInstaller bundle starts its worker processes through here
    sys.exit(main())
