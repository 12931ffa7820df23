"""``python -m torchfluidwarp``: the command line, as the ``torchfluidwarp`` script
(:func:`torchfluidwarp.apps.cli.main`)."""

import sys

from torchfluidwarp.apps.cli import main

if __name__ == "__main__":
    sys.exit(main())
