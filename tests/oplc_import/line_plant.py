"""The plant both converter end-to-end tests run (e2e_oplc_import in OpenPLC v3,
strucpp_v4_import in Runtime v4): a relay module (slave 2, line_relays.json) and a meter
(slave 5, line_meter.json) on one RTU line, and the user program that uses their located
addresses (%IX100.0.., %IW100.., %QX100.0.., %QW100..)."""

# the CONFIGURATION the OpenPLC Editor writes for a PROGRAM main
CONFIGURATION = """CONFIGURATION Config0
  RESOURCE Res0 ON PLC
    TASK task0(INTERVAL := T#20ms,PRIORITY := 0);
    PROGRAM instance0 WITH task0 : main;
  END_RESOURCE
END_CONFIGURATION
"""

RELAY_INPUTS = [True, False, True, True, False, False, True, False]
METER_WORDS = [2301, 52, 1196, 0, 65535, 7, 8, 9, 0, 0x4248, 0x3333, 0x3F73]


def user_program(decls="", body=""):
    """The user's PROGRAM main and its CONFIGURATION; decls and body: a test's own lines (its
    own located variables, what it copies where it can read it)."""
    return """PROGRAM main
  VAR
""" + "".join(f"    in{i} AT %IX100.{i} : BOOL;\n" for i in range(8)) \
        + "".join(f"    w{i} AT %IW{100 + i} : WORD;\n" for i in range(12)) \
        + "".join(f"    relay{i} AT %QX100.{i} : BOOL;\n" for i in range(4)) + """    out0 AT %QW100 : WORD;
    out1 AT %QW101 : WORD;
    meter_ok AT %QX0.0 : BOOL;
""" + decls + """  END_VAR
  VAR
    scans : UDINT;
  END_VAR
  scans := scans + 1;
""" + body + """END_PROGRAM

""" + CONFIGURATION
