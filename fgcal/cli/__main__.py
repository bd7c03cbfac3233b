"""``python -m fgcal.cli``."""
import sys

from fgcal.cli import main

sys.exit(main())
