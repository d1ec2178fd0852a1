import os
import sys

import pytest

sys.path.insert(0, os.path.dirname(__file__))
import oplc  # noqa: E402


@pytest.fixture
def dist():
    d = os.environ.get("MBFB_DIST", "")
    assert os.path.isfile(os.path.join(d, "MANIFEST")), f"no generated library at {d!r}"
    return d


@pytest.fixture
def scratch():
    with oplc.Scratch() as s:
        yield s
