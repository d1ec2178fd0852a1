"""tools/stref/stref.py on ST written here: what the reference says, --check, bad input."""
import os
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
STREF = os.path.join(os.path.dirname(os.path.dirname(HERE)), "tools", "stref", "stref.py")
HEADER = """#define MBFB_E_TIMEOUT       1  /* no reply after all retries */
#define MBFB_E_BAUD         14  /* baud rate the serial driver cannot set exactly
                                   (second line) */
#define MBFB_E_EXCEPTION_BASE 128 /* + Modbus exception code */
#define MBFB_E_RANGE       202 /* set point out of range */
"""
ST = """(* MB_Device - the core. *)
FUNCTION_BLOCK MB_Device
  VAR_INPUT
    Enable : BOOL;               (* monitoring *)
  END_VAR
  VAR CONSTANT
    SHIM_E_BAUD : DINT := 14;
    MB_E_BAD_LINE : WORD := 207; (* line settings invalid *)
  END_VAR
  Enable := Enable;
END_FUNCTION_BLOCK

(* Dev_X - a device. *)
FUNCTION_BLOCK Dev_X
  VAR_INPUT
    Period : TIME := T#1s;       (* refresh period *)
    SetPoint : REAL;
  END_VAR
  VAR_OUTPUT
    Valid : BOOL;                (* data fresh *)
  END_VAR
  VAR CONSTANT
    E_RANGE : WORD := 202;
  END_VAR
  VAR
    dev : MB_Device;
  END_VAR
  dev(Enable := TRUE);
END_FUNCTION_BLOCK
"""


def run(*args, src=ST):
    with tempfile.TemporaryDirectory() as d:
        os.mkdir(os.path.join(d, "st"))
        with open(os.path.join(d, "st", "a.st"), "w") as fh:
            fh.write(src)
        with open(os.path.join(d, "mbfb.h"), "w") as fh:
            fh.write(HEADER)
        out = os.path.join(d, "REF.md")
        args = [a.replace("@OUT", out) for a in args]
        r = subprocess.run([sys.executable, STREF, "--src", os.path.join(d, "st"), "--header",
                            os.path.join(d, "mbfb.h"), *args], capture_output=True, text=True)
        text = open(out).read() if os.path.exists(out) else ""
        return r, text


def test_reference_lists_inputs_outputs_and_every_error_id():
    r, text = run("--out", "@OUT")
    assert r.returncode == 0, r.stderr
    dev = text[text.index("## Dev_X"):text.index("## MB_Device")]
    assert "| `Period` | `TIME` | `T#1s` | refresh period |" in dev
    assert "| `SetPoint` | `REAL` |  |  |" in dev
    assert "| `Valid` | `BOOL` |  | data fresh |" in dev
    assert "| 1 | `MBFB_E_TIMEOUT` | no reply after all retries |" in dev   # reaches the bus
    assert "| 202 | `E_RANGE` | set point out of range |" in dev          # meaning from mbfb.h
    assert "| 207 | `MB_E_BAD_LINE` | line settings invalid |" in dev      # from the core it uses
    assert "| 14 |" not in dev                                            # reported as 207
    assert "| 128+x |" in dev
    assert "[`Dev_X`](#dev_x) | `a.st` | public" in text
    assert "internal" in text[text.index("## MB_Device"):]


def test_check_fails_on_a_stale_file_and_passes_on_a_fresh_one():
    with tempfile.TemporaryDirectory() as d:
        ref = os.path.join(d, "REF.md")
        r, text = run("--out", "@OUT")
        with open(ref, "w") as fh:
            fh.write(text)
        assert run("--check", ref)[0].returncode == 0
        r, _ = run("--check", ref, src=ST.replace("(* refresh period *)", "(* changed *)"))
        assert r.returncode == 1 and "stale" in r.stderr


def test_bad_input_is_one_line_and_exit_2():
    r, _ = run(src=ST.replace("E_RANGE : WORD := 202", "E_RANGE : WORD := 2x"))
    assert r.returncode == 2
    assert r.stderr.count("\n") == 1 and r.stderr.startswith("stref: ")


SHARED = """TYPE
  MB_ERROR_IDS : STRUCT
    NOT_READY : WORD := 205;
    RANGE : WORD := 202;         (* value out of range *)
  END_STRUCT;
END_TYPE

(* Dev_Y - a device using the shared ids. *)
FUNCTION_BLOCK Dev_Y
  VAR_INPUT
    SetPoint : REAL;
  END_VAR
  VAR
    ERR : MB_ERROR_IDS;
    id : WORD;
  END_VAR
  IF SetPoint > 1.0 THEN
    id := ERR.RANGE;
  END_IF;
END_FUNCTION_BLOCK
"""


def test_the_shared_error_ids_a_block_uses_are_its_error_ids():
    r, text = run("--out", "@OUT", src=SHARED)
    assert r.returncode == 0, r.stderr
    dev = text[text.index("## Dev_Y"):text.index("## Functions")]
    assert "| 202 | `MB_ERROR_IDS.RANGE` | set point out of range |" in dev   # meaning from mbfb.h
    assert "| 205 |" not in dev                                             # declared, not used
    r, _ = run(src=SHARED.replace("ERR.RANGE", "ERR.RANGES"))
    assert r.returncode == 2 and "MB_ERROR_IDS has no RANGES" in r.stderr
