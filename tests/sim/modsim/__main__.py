"""`python -m modsim ...` (from tests/sim) is the same as `python tests/sim/mbsim.py ...`."""
import sys

from .app import main

sys.exit(main())
