"""Every MB_LINE of docs/wiring.md compiles: the ```iecst blocks of the page, as they are, in a
program with the library (st_src/*.st), through matiec's iec2c with OpenPLC's flags."""
import glob
import os
import re
import subprocess
import tempfile

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
DOC = os.path.join(ROOT, "docs", "wiring.md")
IEC2C, IEC_LIB = os.environ.get("MBFB_IEC2C", ""), os.environ.get("MBFB_IEC_LIB", "")


def snippets():
    with open(DOC, encoding="utf-8") as fh:
        return re.findall(r"```iecst\n(.*?)```", fh.read(), re.S)


def line_fields():
    """The fields of MB_LINE (st_src/MB_Types.st)."""
    with open(os.path.join(ROOT, "st_src", "MB_Types.st"), encoding="utf-8") as fh:
        body = re.search(r"MB_LINE\s*:\s*STRUCT(.*?)END_STRUCT", fh.read(), re.S).group(1)
    return set(re.findall(r"^\s*(\w+)\s*:", re.sub(r"\(\*.*?\*\)", "", body, flags=re.S), re.M))


def test_recipes_name_only_mb_line_fields():
    """(iec2c takes an unknown field in an initialiser without a word: checked here.)"""
    fields = line_fields()
    assert {"Baud", "Parity", "Framing"} <= fields
    for snippet in snippets():
        for init in re.findall(r":\s*MB_LINE\s*:=\s*\((.*?)\)\s*;", snippet, re.S):
            used = re.findall(r"(\w+)\s*:=", init)
            assert set(used) <= fields, f"not MB_LINE fields: {set(used) - fields}"
            assert used == sorted(used, key=str.lower), f"not in alphabetical order: {used}"


def test_the_page_has_recipes():
    assert len(snippets()) >= 2
    assert all("MB_LINE" in s for s in snippets())


@pytest.mark.parametrize("index", range(len(snippets())))
def test_recipe_compiles(index, tmp_path):
    if not os.path.isfile(IEC2C):
        pytest.skip("matiec's iec2c not found (MBFB_IEC2C)")
    library = "".join(open(p, encoding="utf-8").read() for p in sorted(glob.glob(
        os.path.join(ROOT, "st_src", "*.st"))))
    names = re.findall(r"^\s*(\w+)\s*:\s*MB_LINE\b", snippets()[index], re.M)
    assert names
    body = "".join(f"  probe := {n};\n" for n in names)   # each one used, as an MB_LINE
    program = ("PROGRAM main\n" + snippets()[index] + "VAR\n  probe : MB_LINE;\nEND_VAR\n" +
               body + "END_PROGRAM\n"
               "CONFIGURATION Config0\n RESOURCE Res0 ON PLC\n"
               "  TASK t(INTERVAL := T#20ms, PRIORITY := 0);\n"
               "  PROGRAM p WITH t : main;\n END_RESOURCE\nEND_CONFIGURATION\n")
    src = tmp_path / "program.st"
    src.write_text(library + program)
    r = subprocess.run([IEC2C, "-f", "-l", "-p", "-r", "-R", "-a", "-I", IEC_LIB, "program.st"],
                       cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stdout + r.stderr
