"""Modbus device simulator: SetPro MV-D94/VD, MT-S9, FDC Series 100 on one line (see ../README.md)."""
