import os
import sys

import pytest

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "tools", "openplc"))
import oplc  # noqa: E402


@pytest.fixture(scope="session")
def dist():
    """The library tree the build generated (plc_lib/CMakeLists.txt)."""
    d = os.environ.get("MBFB_DIST", "")
    assert os.path.isfile(os.path.join(d, "MANIFEST")), f"no generated library at {d!r}"
    return d


@pytest.fixture
def scratch():
    with oplc.Scratch() as s:
        yield s
