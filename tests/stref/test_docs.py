"""The pages say what the code does, where that can be checked without running anything:
every link between the project's pages resolves, the error-id bands and the ids in use the
pages state are mbfb.h's, every section a comment or page cites as `FILE, "Section"` exists in
that file, and no "issue N" is left in the code, the tests, the benchmarks or the pages (the
history is in git)."""
import os
import re
import subprocess

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SKIP_DIRS = {".git", ".venv", "build", "node_modules", "__pycache__"}


def tracked(*exts):
    """The project's files with these extensions (git's list; a walk without git)."""
    try:
        out = subprocess.run(["git", "-C", ROOT, "ls-files"], capture_output=True, text=True,
                             check=True).stdout.split("\n")
        files = [f for f in out if f]
    except (OSError, subprocess.CalledProcessError):
        files = []
        for d, dirs, names in os.walk(ROOT):
            dirs[:] = [x for x in dirs if x not in SKIP_DIRS and not x.startswith("build")]
            files += [os.path.relpath(os.path.join(d, n), ROOT) for n in names]
    return sorted(f for f in files if f.endswith(exts) and os.path.exists(os.path.join(ROOT, f)))


def read(rel):
    with open(os.path.join(ROOT, rel), encoding="utf-8", errors="replace") as fh:
        return fh.read()


def test_links_between_pages_resolve():
    bad = []
    pages = tracked(".md")
    assert len(pages) > 10
    for page in pages:
        text = re.sub(r"```.*?```", "", read(page), flags=re.S)   # code blocks are not links
        for target in re.findall(r"\]\(([^)\s]+)\)", text):
            if re.match(r"[a-z]+:", target) or target.startswith("#"):
                continue
            path = target.split("#", 1)[0]
            if not os.path.exists(os.path.normpath(os.path.join(ROOT, os.path.dirname(page), path))):
                bad.append(f"{page}: ({target})")
    assert not bad, "links to no file:\n" + "\n".join(bad)


def error_ids():
    """mbfb.h: the bands its error table states, and the MBFB_E_* codes defined."""
    h = read("c_shims/include/mbfb.h")
    comm = tuple(map(int, re.search(r"\*\s*(\d+)\.\.(\d+)\s+communication", h).groups()))
    inputs = tuple(map(int, re.search(r"\*\s*(\d+)\.\.(\d+)\s+function-block input", h).groups()))
    codes = {n: int(v) for n, v in re.findall(r"#define\s+MBFB_E_(\w+)\s+(\d+)", h)}
    return comm, inputs, codes


def test_error_codes_lie_in_their_bands():
    comm, inputs, codes = error_ids()
    assert comm == (1, 63) and inputs == (200, 255)
    for name, v in codes.items():
        if name != "EXCEPTION_BASE":
            assert comm[0] <= v <= comm[1] or inputs[0] <= v <= inputs[1], f"MBFB_E_{name} {v}"


def test_pages_state_the_bands_and_ids_in_use():
    comm, inputs, codes = error_ids()
    in_use = max(v for v in codes.values() if comm[0] <= v <= comm[1])
    seen = 0
    for page in tracked(".md") + ["c_shims/include/mbfb.h"]:
        text = read(page)
        for a, b in re.findall(r"\b(\d+)\.\.(\d+)\s+communication", text):
            assert (int(a), int(b)) == comm, f"{page}: {a}..{b} communication, mbfb.h {comm}"
            seen += 1
        for a, b in re.findall(r"\b(\d+)\.\.(\d+)\s+(?:block|function-block) input", text):
            assert (int(a), int(b)) == inputs, f"{page}: {a}..{b} block input, mbfb.h {inputs}"
        for a, b in re.findall(r"\((\d+)\.\.(\d+) in use\)", text):
            assert (int(a), int(b)) == (comm[0], in_use), f"{page}: ({a}..{b} in use), mbfb.h 1..{in_use}"
    assert seen >= 3


def sections(rel):
    """The section names of a file: a Markdown page's headings, or the '---- Name' comments of ST."""
    text = read(rel)
    if rel.endswith(".md"):
        return [h.strip() for h in re.findall(r"^#+\s+(.*)$", text, re.M)]
    return [s.strip() for s in re.findall(r"----\s+([^-:.(]+)", text)]


def test_cited_sections_exist():
    bad, n = [], 0
    for rel in tracked(".st", ".c", ".h", ".md", ".py"):
        if rel.startswith("tests/stref/"):
            continue
        for m in re.finditer(r"\b([\w/]+\.(?:st|md)),?\s+\"([^\"]+)\"", read(rel)):
            target, name = m.group(1), " ".join(m.group(2).split())
            cands = [target, os.path.join(os.path.dirname(rel), target), os.path.join("st_src", target)]
            found = next((c for c in cands if os.path.isfile(os.path.join(ROOT, c))), None)
            if found is None or found.endswith("REFERENCE.md"):
                continue
            n += 1
            if not any(s.startswith(name) or name in s for s in sections(found)):
                bad.append(f'{rel}: {target}, "{name}"')
    assert n >= 10
    assert not bad, "sections cited that do not exist:\n" + "\n".join(sorted(set(bad)))


def test_no_issue_numbers_left():
    bad = []
    for rel in tracked(".st", ".c", ".h", ".cpp", ".hpp", ".py", ".md", ".txt", ".sh", ".cmake"):
        if rel.startswith("tests/stref/"):
            continue
        for i, line in enumerate(read(rel).split("\n"), 1):
            if re.search(r"\bissue\s+#?\d+", line, re.I):
                bad.append(f"{rel}:{i}: {line.strip()[:80]}")
    assert not bad, '"issue N" (the history is in git):\n' + "\n".join(bad)
