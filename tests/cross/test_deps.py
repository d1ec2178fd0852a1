"""scripts/deps.sh on a machine with foreign architectures enabled: a package is
checked for the machine's own architecture (or `all`), so a multiarch package installed for
several architectures (libmodbus-dev for amd64 and arm64) is not "missing" and nothing runs
apt-get; a package installed only for a foreign architecture is missing; `NAME:ARCH` in the
list enables ARCH only when such a package is missing and ARCH is not enabled yet.

deps.sh runs in a copy of the repository's layout with its own package list, against fakes of
dpkg-query, dpkg, apt-get and sudo on PATH that answer from a table of installed packages
(NAME ARCH, one a line) and log every call."""
import os
import shutil
import subprocess
import textwrap

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

# dpkg-query -W [-f=FORMAT] NAME[:ARCH]...: every known instance of each name, as dpkg does
# (an instance listed with status installed); -s / dpkg -s NAME: ambiguous (exit 2) when more
# than one instance is installed and no architecture is given, as dpkg says
FAKE_DPKG_QUERY = textwrap.dedent(r'''
    #!/usr/bin/env python3
    import os, sys
    db = [l.split() for l in open(os.environ["FAKE_DB"]) if l.strip()]
    with open(os.environ["FAKE_LOG"], "a") as log:
        log.write("dpkg-query " + " ".join(sys.argv[1:]) + "\n")
    args = sys.argv[1:]
    fmt = "${Package}\t${Version}\n"
    names, rc = [], 0
    mode = None
    for a in args:
        if a.startswith("-f=") or a.startswith("--showformat="):
            fmt = a.split("=", 1)[1]
        elif a in ("-W", "--show"):
            mode = "W"
        elif a in ("-s", "--status"):
            mode = "s"
        else:
            names.append(a)
    def inst(spec):
        name, _, arch = spec.partition(":")
        return [r for r in db if r[0] == name and (not arch or r[1] == arch)]
    for spec in names:
        found = inst(spec)
        if mode == "s":
            if len(found) > 1 and ":" not in spec:
                sys.stderr.write(f"dpkg-query: error: ambiguous package name '{spec}'\n")
                sys.exit(2)
            if not found:
                sys.stderr.write(f"dpkg-query: package '{spec}' is not installed\n")
                rc = 1
            continue
        if not found:
            sys.stderr.write(f"dpkg-query: no packages found matching {spec}\n")
            rc = 1
        for name, arch in found:
            out = fmt.replace("${Package}", name).replace("${Architecture}", arch)
            out = out.replace("${db:Status-Status}", "installed")
            out = out.replace("${Status}", "install ok installed").replace("${Version}", "1")
            sys.stdout.write(out.encode().decode("unicode_escape"))
    sys.exit(rc)
''').lstrip()

FAKE_DPKG = textwrap.dedent(r'''
    #!/bin/sh
    echo "dpkg $*" >>"$FAKE_LOG"
    case $1 in
    --print-architecture) echo amd64 ;;
    --print-foreign-architectures) cat "$FAKE_FOREIGN" ;;
    --add-architecture) echo "$2" >>"$FAKE_FOREIGN" ;;
    -s) exec dpkg-query "$@" ;;
    *) exit 2 ;;
    esac
''').lstrip()

FAKE_LOGGER = '#!/bin/sh\necho "$(basename "$0") $*" >>"$FAKE_LOG"\n'
FAKE_SUDO = '#!/bin/sh\nexec "$@"\n'

LIST = """\
# comment
cmake
tzdata
libmodbus-dev
libmodbus-dev:arm64
"""


def run_deps(tmp_path, installed, foreign="", script=None, package_list=LIST):
    """Run deps.sh (or the given script text) against the fakes; return (rc, log lines,
    foreign architectures after)."""
    repo = tmp_path / "repo"
    (repo / "scripts").mkdir(parents=True)
    (repo / ".ci").mkdir()
    deps = repo / "scripts" / "deps.sh"
    if script is None:
        shutil.copy(os.path.join(ROOT, "scripts", "deps.sh"), deps)
    else:
        deps.write_text(script)
    deps.chmod(0o755)
    (repo / ".ci" / "apt-packages.txt").write_text(package_list)
    bin_ = tmp_path / "bin"
    bin_.mkdir()
    for name, text in (("dpkg-query", FAKE_DPKG_QUERY), ("dpkg", FAKE_DPKG),
                       ("apt-get", FAKE_LOGGER), ("sudo", FAKE_SUDO)):
        (bin_ / name).write_text(text)
        (bin_ / name).chmod(0o755)
    db = tmp_path / "db"
    db.write_text("".join(f"{n} {a}\n" for n, a in installed))
    fa = tmp_path / "foreign"
    fa.write_text(foreign)
    log = tmp_path / "log"
    log.write_text("")
    env = dict(os.environ, PATH=f"{bin_}:{os.environ['PATH']}", FAKE_DB=str(db),
               FAKE_LOG=str(log), FAKE_FOREIGN=str(fa))
    r = subprocess.run(["bash", str(deps)], env=env, capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == 0, r.stderr
    return log.read_text().splitlines(), fa.read_text().split()


ALL = [("cmake", "amd64"), ("tzdata", "all"), ("libmodbus-dev", "amd64"),
       ("libmodbus-dev", "arm64"), ("libmodbus-dev", "armhf")]


def apt(log):
    return [ln for ln in log if ln.startswith("apt-get")]


def test_every_package_present_with_foreign_instances_runs_no_apt(tmp_path):
    log, _ = run_deps(tmp_path, ALL, foreign="arm64\narmhf\n")
    assert apt(log) == []
    assert not [ln for ln in log if "--add-architecture" in ln]


def test_old_check_ran_apt_on_the_same_machine(tmp_path):
    """The check deps.sh had before (`dpkg -s NAME`): ambiguous for libmodbus-dev, so it ran
    apt-get on every call: the fakes reproduce the failure the new check fixes."""
    old = textwrap.dedent('''
        set -euo pipefail
        cd "$(dirname "$0")/.."
        pkgs=$(grep -v '^\\s*#' .ci/apt-packages.txt | grep -v : | xargs)
        missing=$(for p in $pkgs; do dpkg -s "$p" >/dev/null 2>&1 || echo "$p"; done | xargs)
        [ -z "$missing" ] && exit 0
        apt-get update -q
        apt-get install -y -q $missing
    ''')
    log, _ = run_deps(tmp_path, ALL, foreign="arm64\narmhf\n", script=old)
    assert "apt-get install -y -q libmodbus-dev" in apt(log)


def test_only_a_foreign_instance_is_missing_for_this_machine(tmp_path):
    installed = [p for p in ALL if p != ("libmodbus-dev", "amd64")]
    log, _ = run_deps(tmp_path, installed, foreign="arm64\narmhf\n")
    assert apt(log) == ["apt-get update -q", "apt-get install -y -q libmodbus-dev"]


def test_missing_foreign_package_enables_its_architecture_once(tmp_path):
    installed = [p for p in ALL if p[1] != "arm64"]
    log, foreign = run_deps(tmp_path, installed, foreign="armhf\n")
    assert [ln for ln in log if "--add-architecture" in ln] == ["dpkg --add-architecture arm64"]
    assert foreign == ["armhf", "arm64"]
    assert apt(log) == ["apt-get update -q", "apt-get install -y -q libmodbus-dev:arm64"]


def test_enabled_architecture_is_not_added_again(tmp_path):
    installed = [p for p in ALL if p[1] != "arm64"]
    log, foreign = run_deps(tmp_path, installed, foreign="arm64\n")
    assert not [ln for ln in log if "--add-architecture" in ln]
    assert foreign == ["arm64"]
    assert apt(log)[-1] == "apt-get install -y -q libmodbus-dev:arm64"


def test_no_foreign_package_listed_enables_nothing(tmp_path):
    log, foreign = run_deps(tmp_path, [("tzdata", "all")],
                            package_list="cmake\ntzdata\ng++-aarch64-linux-gnu\n")
    assert not [ln for ln in log if "--add-architecture" in ln] and foreign == []
    assert apt(log)[-1] == "apt-get install -y -q cmake g++-aarch64-linux-gnu"


@pytest.mark.parametrize("name", ["g++-aarch64-linux-gnu", "libstdc++6"])
def test_names_with_regex_characters(tmp_path, name):
    log, _ = run_deps(tmp_path, [(name, "amd64")], package_list=name + "\n")
    assert apt(log) == []
