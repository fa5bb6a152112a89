"""``python -m scanqa`` runs the command line."""

import sys

from scanqa.cli import main

sys.exit(main())
