"""``python -m polarbssrdf`` runs the command line."""

import sys

from polarbssrdf.cli import main

sys.exit(main())
