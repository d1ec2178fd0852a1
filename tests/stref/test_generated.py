"""The write-or-check of the generated files (tools/stref/generated.py) and the four generators
that use it, run as their staleness tests run them: a fresh copy passes, a stale or missing one
is caught (exit 1, "stale" or the reason, and what to run), and writing writes the text."""
import os
import shutil
import subprocess
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path.insert(0, os.path.join(ROOT, "tools", "stref"))
sys.path.insert(0, os.path.join(ROOT, "maps"))
from generated import generate, write_or_check  # noqa: E402

# generator, its committed output, what its stale message tells to run
GENERATORS = [
    (["tools/stref/stref.py"], "st_src/REFERENCE.md", "st_reference"),
    (["tools/stref/errors.py"], "docs/errors.md", "tools/stref/errors.py"),
    (["maps/settings.py"], "st_src/MB_Settings.st", "maps/settings.py --out it"),
]


def test_fresh_passes_stale_and_missing_are_caught(tmp_path, capsys):
    f = tmp_path / "out.txt"
    assert write_or_check("t", "a\nb\n", out=str(f)) == 0
    assert f.read_text() == "a\nb\n"
    assert write_or_check("t", "a\nb\n", check=str(f), hint="make it") == 0
    assert "up to date" in capsys.readouterr().out
    assert write_or_check("t", "a\nc\n", check=str(f), hint="make it") == 1
    cap = capsys.readouterr()
    assert f"t: {f} is stale: run make it" in cap.err
    assert "-b" in cap.out and "+c" in cap.out                      # the difference is shown
    assert f.read_text() == "a\nb\n"                                # a check writes nothing
    assert write_or_check("t", "a\n", check=str(tmp_path / "none"), hint="make it") == 1
    assert "run make it" in capsys.readouterr().err


def test_without_out_it_writes_to_standard_output(capsys):
    assert write_or_check("t", "x\n") == 0
    assert capsys.readouterr().out == "x\n"


def test_bad_input_is_one_line_exit_2_and_nothing_written(tmp_path, capsys):
    def bad():
        raise ValueError("no ids in the header")
    f = tmp_path / "out.txt"
    assert generate("t", bad, ValueError, out=str(f)) == 2
    assert capsys.readouterr().err == "t: no ids in the header\n"
    assert not f.exists()
    assert generate("t", lambda: "x\n", ValueError, out=str(f)) == 0 and f.read_text() == "x\n"


@pytest.mark.parametrize("gen,committed,hint", GENERATORS, ids=lambda v: str(v))
def test_each_generator_catches_its_stale_file(tmp_path, gen, committed, hint):
    copy = tmp_path / os.path.basename(committed)
    shutil.copyfile(os.path.join(ROOT, committed), copy)
    cmd = [sys.executable, os.path.join(ROOT, *gen), "--check", str(copy)]
    r = subprocess.run(cmd, capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr
    copy.write_text(copy.read_text() + "edited by hand\n")
    r = subprocess.run(cmd, capture_output=True, text=True)
    assert r.returncode == 1 and "is stale" in r.stderr and hint in r.stderr, r.stderr
    assert "+edited by hand" not in r.stdout and "-edited by hand" in r.stdout


def test_mkdoc_catches_a_stale_page(tmp_path, monkeypatch, capsys):
    import mkdoc
    shutil.copyfile(os.path.join(ROOT, "maps", "README.md"), tmp_path / "README.md")
    monkeypatch.setattr(mkdoc, "HERE", str(tmp_path))     # the page it checks; maps read as before
    assert mkdoc.main(["--check"]) == 0
    (tmp_path / "README.md").write_text("old page\n")
    assert mkdoc.main(["--check"]) == 1
    assert "is stale: run python3 maps/mkdoc.py" in capsys.readouterr().err
    assert mkdoc.main([]) == 0                                # writing mends it
    assert mkdoc.main(["--check"]) == 0
