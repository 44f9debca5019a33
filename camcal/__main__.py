"""``python -m camcal`` runs the command line."""

import sys

from camcal.cli import main

sys.exit(main())
