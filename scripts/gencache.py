#!/usr/bin/env python3
"""gencache.py: a code generator's output kept by the content of what it reads, as ccache keeps
a compiler's.

    gencache.py NAME [--key TEXT]... [--in FILE]... [--in-dir DIR]... --out FILE... -- COMMAND...

The build runs two generators that are slow and deterministic: matiec's iec2c (1.5 to 14 s of
CPU for one program: it reads the whole library each time) and STruC++ (about 5 s: it loads
its standard libraries each time), once per test program and again after every change. The
key is NAME, each --key (a tool's version, say), the bytes of each --in file and of every file
under each --in-dir, and the command with each path cut to its last part (the paths of a build
tree differ between clones; what is read through them is keyed by content). On a hit the
--out files are written from the cache and the command does not run; on a miss it runs and, if
it succeeds and wrote every --out file, they are kept. The cache: MBFB_TOOL_CACHE/gen-NAME
(MBFB_TOOL_CACHE defaults to ~/.cache/mbfb; empty, or MBFB_GENCACHE=0, for none), the least
recently used entries past 400 removed.

A generator is fit for this only when its output holds no path, time or other input than the
keyed ones (tests: gencache_deterministic).
"""
import hashlib
import os
import shutil
import subprocess
import sys
import tempfile

KEEP = 400   # entries per generator: up to about 1 MB each


def parse(argv):
    if "--" not in argv:
        raise SystemExit("usage: gencache.py NAME [--key T]... [--in F]... [--in-dir D]... "
                         "--out F... -- COMMAND...")
    i = argv.index("--")
    opts, cmd = argv[:i], argv[i + 1:]
    name, opts = opts[0], opts[1:]
    spec = {"--key": [], "--in": [], "--in-dir": [], "--out": []}
    for flag, value in zip(opts[::2], opts[1::2]):
        if flag not in spec:
            raise SystemExit(f"gencache.py: unknown option {flag}")
        spec[flag].append(value)
    if not cmd or not spec["--out"]:
        raise SystemExit("gencache.py: no command or no --out")
    return name, spec, cmd


def tool_cache():
    """The tool cache: MBFB_TOOL_CACHE, default ~/.cache/mbfb (as v4/build-strucpp.sh and
    scripts/venv.sh read it); '' when set empty (no cache)."""
    return os.environ.get("MBFB_TOOL_CACHE", os.path.join(
        os.environ.get("XDG_CACHE_HOME", os.path.expanduser("~/.cache")), "mbfb"))


def cache_root(name):
    if os.environ.get("MBFB_GENCACHE", "1") == "0":
        return None
    base = tool_cache()
    return os.path.join(base, f"gen-{name}") if base else None


def digest(name, spec, cmd):
    h = hashlib.sha256()

    def part(b):
        h.update(len(b).to_bytes(8, "little") + b)

    for s in [name, *spec["--key"], *(os.path.basename(a.rstrip("/")) if "/" in a else a for a in cmd)]:
        part(s.encode())
    for f in spec["--in"]:
        with open(f, "rb") as fh:
            part(fh.read())
    for d in spec["--in-dir"]:
        for root, dirs, files in os.walk(d):
            dirs.sort()
            for f in sorted(files):
                p = os.path.join(root, f)
                part(os.path.relpath(p, d).encode())
                with open(p, "rb") as fh:
                    part(fh.read())
    return h.hexdigest()


def prune(root):
    entries = sorted((os.stat(os.path.join(root, e)).st_mtime, e) for e in os.listdir(root)
                     if not e.startswith("tmp"))
    for _, e in entries[:max(0, len(entries) - KEEP)]:
        shutil.rmtree(os.path.join(root, e), ignore_errors=True)


def main(argv):
    name, spec, cmd = parse(argv)
    outs = spec["--out"]
    root = cache_root(name)
    entry = os.path.join(root, digest(name, spec, cmd)) if root else None
    stored = [os.path.join(entry, f"{i}") for i in range(len(outs))] if entry else []
    if entry and all(os.path.isfile(s) for s in stored):
        for s, o in zip(stored, outs):
            shutil.copyfile(s, o)
        os.utime(entry)
        return 0
    rc = subprocess.call(cmd)
    if rc or not entry or not all(os.path.isfile(o) for o in outs):
        return rc
    try:   # written beside and renamed: a build running at the same time sees all or nothing
        os.makedirs(root, exist_ok=True)
        tmp = tempfile.mkdtemp(prefix="tmp", dir=root)
        for i, o in enumerate(outs):
            shutil.copyfile(o, os.path.join(tmp, f"{i}"))
        try:
            os.rename(tmp, entry)
        except OSError:   # another build stored it meanwhile
            shutil.rmtree(tmp, ignore_errors=True)
        prune(root)
    except OSError as e:
        print(f"gencache.py: {name}: not kept ({e})", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
