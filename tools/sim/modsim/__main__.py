"""`python -m modsim ...` (from tools/sim) is the same as `python tools/sim/mbsim.py ...`."""
import sys

from .app import main

sys.exit(main())
