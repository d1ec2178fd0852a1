"""The pages say what the code does, where that can be checked without running anything:
every link between the project's pages resolves, the error-id bands and the ids in use the
pages state are mbfb.h's, every section a comment or page cites as `FILE, "Section"` exists in
that file, no "issue N" is left in the code, the tests, the benchmarks or the pages (the
history is in git), and the claims that drifted before: the files with `{{ }}` pragmas as
st_src/README.md lists them, the tests that run alone as README.md names them (from ctest's
properties), the shim calls per scan quoted alike in README.md and st_src/README.md and as
bench/README.md measured them."""
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


def words(text):
    """A page's text on one line: the claims below may wrap anywhere."""
    return " ".join(text.split())


def pragma_files():
    """The st_src files that hold a {{ }} pragma (their text outside comments and strings
    is not parsed: a {{ in an ST comment would count, and none is there)."""
    return sorted(os.path.basename(f) for f in tracked(".st")
                  if f.startswith("st_src/") and "{{" in read(f))


def test_the_pragma_files_are_those_listed():
    """st_src/README.md lists the files with pragmas once; every other page that says where
    pragmas are names none of them (it refers to that list)."""
    have = pragma_files()
    assert len(have) >= 5
    m = re.search(r"Files with pragmas: (.*?); no other file has one", words(read("st_src/README.md")))
    assert m, "st_src/README.md: no 'Files with pragmas: ...; no other file has one' sentence"
    listed = sorted(set(re.findall(r"`(\w+\.st)`", m.group(1))))
    assert listed == have, f"st_src/README.md lists {listed}; st_src has pragmas in {have}"
    stems = {os.path.splitext(f)[0] for f in tracked(".st") if f.startswith("st_src/")}
    bad = []
    for page in tracked(".md"):
        if page == "st_src/README.md" or page.startswith("st_src/REFERENCE"):
            continue
        for sentence in re.split(r"(?<=[.;])\s", words(read(page))):
            if "{{ }}" in sentence and re.search(r"\bonly\b|\blists?\b|\bhold", sentence):
                named = set(re.findall(r"`(\w+?)(?:\.st)?`", sentence)) & stems
                if named:
                    bad.append(f"{page}: names {sorted(named)} where pragmas are: {sentence[:120]}")
    assert not bad, "where pragmas are is said in st_src/README.md only:\n" + "\n".join(bad)


def ctest_tests():
    """The build tree's tests with their properties (ctest --show-only=json-v1), or None
    without a configured build tree."""
    build = os.environ.get("MBFB_BUILD_DIR") or os.path.join(ROOT, "build")
    if not os.path.isfile(os.path.join(build, "CTestTestfile.cmake")):
        return None
    import json
    out = subprocess.run([os.environ.get("MBFB_CTEST", "ctest"), "--test-dir", build,
                          "--show-only=json-v1"], capture_output=True, text=True, check=True).stdout
    tests = {}
    for t in json.loads(out)["tests"]:
        tests[t["name"]] = {p["name"]: p["value"] for p in t.get("properties", [])}
    return tests


def test_the_serial_tests_are_those_the_readme_names():
    """README.md, "Tests": the tests that run alone (RUN_SERIAL), by name or name* pattern;
    each pattern names serial tests only and every serial test is named."""
    import fnmatch
    tests = ctest_tests()
    if tests is None:
        import pytest
        pytest.skip("no configured build tree (MBFB_BUILD_DIR or build/): the tests' "
                    "properties come from ctest")
    m = re.search(r"\(`RUN_SERIAL`: (.*?); `docs_true` checks this list", words(read("README.md")))
    assert m, "README.md: no '(`RUN_SERIAL`: ...; `docs_true` checks this list' sentence"
    patterns = re.findall(r"`([\w.*]+)`", m.group(1))
    serial = {n for n, p in tests.items() if p.get("RUN_SERIAL")}
    assert serial, "no RUN_SERIAL test at all: the README's list says otherwise"
    for pat in patterns:
        hits = fnmatch.filter(tests, pat)
        assert hits, f"README.md names `{pat}` as serial: no such test"
        parallel = sorted(set(hits) - serial)
        assert not parallel, f"README.md says `{pat}` runs alone; these do not: {parallel}"
    unnamed = sorted(n for n in serial if not any(fnmatch.fnmatch(n, p) for p in patterns))
    assert not unnamed, f"RUN_SERIAL tests the README does not name: {unnamed}"


def test_the_tests_run_last_follow_every_other():
    """README.md, "Tests": `shims_late_*` and `soak_smoke` run after every other test
    (tests/last.cmake) and beside each other only: each DEPENDS on every test but those, and
    none runs alone."""
    import fnmatch
    tests = ctest_tests()
    if tests is None:
        import pytest
        pytest.skip("no configured build tree (MBFB_BUILD_DIR or build/): the tests' "
                    "properties come from ctest")
    assert "`shims_late_*`" in read("README.md") and "`soak_smoke` run last" in words(read("README.md"))
    last = fnmatch.filter(tests, "shims_late_*") + fnmatch.filter(tests, "soak_smoke")
    assert len(last) > 1, "no shims_late_* or soak_smoke test"
    others = set(tests) - set(last)
    for n in last:
        deps = set(tests[n].get("DEPENDS") or [])
        assert others <= deps, f"{n} may start before {sorted(others - deps)[:5]}"
        assert not tests[n].get("RUN_SERIAL"), f"{n} runs alone: the others would wait for it"


def test_shim_calls_per_scan_quoted_alike():
    """The shim calls per scan are bench/README.md's table; README.md and st_src/README.md
    quote its most and its steady figure, the same in both."""
    rows = re.findall(r"^\| `(\w+)` \|.*\| (\d+) / (\d+) \|$",
                      section(read("bench/README.md"), "Scan cost of a block"), re.M)
    assert len(rows) >= 3, "bench/README.md, 'Scan cost of a block': no shim-call column"
    steady = {int(s) for _, s, _ in rows}
    most = max(int(p) for _, _, p in rows)
    assert len(steady) == 1, f"steady shim calls differ between blocks: {rows}"
    quoted = {}
    for page in ("README.md", "st_src/README.md"):
        found = re.findall(r"at most (\d+) (?:instructions|of them) \((\d+) in a steady scan\)",
                           words(read(page)))
        assert len(found) == 1, f"{page}: the shim calls per scan quoted {len(found)} times"
        quoted[page] = tuple(map(int, found[0]))
    assert set(quoted.values()) == {(most, steady.pop())}, \
        f"shim calls per scan: bench/README.md at most {most}; quoted {quoted}"


def section(text, title):
    """The text of a Markdown section (## or ###) from its heading to the next one of its level."""
    m = re.search(r"^(#+) " + re.escape(title) + r".*$", text, re.M)
    assert m, f"no section {title!r}"
    end = re.search(r"^#{1,%d} " % len(m.group(1)), text[m.end():], re.M)
    return text[m.end(): m.end() + end.start()] if end else text[m.end():]
