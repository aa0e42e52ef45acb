"""``python -m raytrax ...``: the ``raytrax`` command (:func:`raytrax.cli.main`)."""

import sys

from raytrax.cli import main

if __name__ == "__main__":
    sys.exit(main())
