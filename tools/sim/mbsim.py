#!/usr/bin/env python3
"""Modbus device simulator: SetPro MV-D94/VD, MT-S9 and FDC Series 100 on a pty, a serial
device or Modbus/TCP on 127.0.0.1. Usage and options: tools/sim/README.md (or --help).

    .venv/bin/python tools/sim/mbsim.py --pty --device mvd94:1:SV=100.0,DP=1
"""
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from modsim.app import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main())
