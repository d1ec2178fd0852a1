"""tools/sim/README.md "Start it by hand" works as written: every simulator command is run (its
/tmp paths moved into a temporary folder), its ready line is compared with the `# ->` comment
under it (pty numbers and TCP ports vary), and the mbpoll and socat lines after it are run
against it, with mbpoll's `# [0]: 1000` comments checked."""
import os
import re
import shlex
import shutil
import signal
import subprocess
import sys
import tempfile

import pytest

import simctl

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
README = os.path.join(ROOT, "tools", "sim", "README.md")
REQUIRE = os.environ.get("MBFB_REQUIRE_TOOLCHAIN") == "1"


def blocks():
    """[(command, expected ready line or None, [(follow-up command, comment)])] of the section."""
    with open(README, encoding="utf-8") as fh:
        text = fh.read()
    section = text.split("## Start it by hand", 1)[1]
    code = section.split("```sh\n", 1)[1].split("```", 1)[0]
    lines, cur = [], ""
    for raw in code.splitlines():
        cur += raw.rstrip("\\").rstrip() + " " if raw.endswith("\\") else raw
        if not raw.endswith("\\"):
            lines.append(cur.strip())
            cur = ""
    out = []
    for line in lines:
        if line.startswith(".venv/bin/python tools/sim/mbsim.py"):
            out.append([line, None, []])
        elif line.startswith("# ->") and out and out[-1][1] is None:
            out[-1][1] = line[4:].split("(")[0].strip()
        elif line and not line.startswith("#") and out:
            cmd, _, comment = line.partition("#")
            out[-1][2].append((cmd.strip(), comment.strip()))
    return out


CASES = blocks()


def test_the_section_has_the_commands():
    assert len(CASES) >= 5 and all(expected for _, expected, _ in CASES)


def pattern(expected: str, tmp: str) -> str:
    exp = re.escape(expected.replace("/tmp/", tmp + "/"))
    exp = re.sub(r"/dev/pts/\d+", r"/dev/pts/\\d+", exp)
    return re.sub(r"127\\\.0\\\.0\\\.1:\d+", r"127\\.0\\.0\\.1:\\d+", exp)


@pytest.mark.parametrize("cmd,expected,follow", CASES, ids=[c[1] for c in CASES])
def test_readme_command(cmd, expected, follow):
    with tempfile.TemporaryDirectory(prefix="mbsim-readme-") as tmp:
        args = shlex.split(cmd.replace("/tmp/", tmp + "/"))
        args[0] = simctl.VENV_PYTHON if os.path.exists(simctl.VENV_PYTHON) else sys.executable
        proc = subprocess.Popen(args, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                text=True)
        try:
            ready = proc.stdout.readline().strip()
            assert re.fullmatch(pattern(expected, tmp), ready), (ready, proc.stderr.read()
                                                                  if proc.poll() is not None
                                                                  else "")
            port = ready.rpartition(":")[2] if ready.startswith("TCP") else None
            for fcmd, comment in follow:
                tool = fcmd.split()[0] if not fcmd.startswith("echo") else "socat"
                if shutil.which(tool) is None:
                    if REQUIRE:
                        pytest.fail(f"{tool} is not installed (.ci/apt-packages.txt)")
                    continue
                fcmd = fcmd.replace("/tmp/", tmp + "/")
                if port:
                    fcmd = fcmd.replace("-p 40321", f"-p {port}")
                res = subprocess.run(fcmd, shell=True, cwd=ROOT, capture_output=True, text=True,
                                     timeout=30, check=False)
                assert res.returncode == 0, (fcmd, res.stdout, res.stderr)
                want = re.match(r"\[(\d+)\]: (-?\d+)", comment)
                if want:
                    assert re.search(rf"^\[{want.group(1)}\]:\s+{want.group(2)}$", res.stdout,
                                     re.M), (fcmd, res.stdout)
                if fcmd.startswith("echo"):
                    assert '"ok": true' in res.stdout, res.stdout
        finally:
            proc.send_signal(signal.SIGTERM)
            assert proc.wait(10) == 0
            proc.stdout.close()
            proc.stderr.close()
        assert not any(os.path.lexists(os.path.join(tmp, f)) for f in os.listdir(tmp)
                       if f.endswith((".port", ".sock")) or f == "rs485"), os.listdir(tmp)
