"""``python -m hwbridge`` runs the command line."""

import sys

from hwbridge.cli import main

sys.exit(main())
