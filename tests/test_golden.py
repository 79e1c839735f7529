"""CLI output compared with the golden files under tests/golden/.

A mismatch means the output changed: if on purpose, run `make golden` and
review the diff; tests never rewrite golden files.
"""

from __future__ import annotations

import json

import pytest

from tests.make_golden import GOLDEN, cases, render

CASES = cases()


@pytest.mark.parametrize("golden", sorted(CASES))
def test_matches_golden(golden):
    path, args = CASES[golden]
    if not path.exists():
        pytest.skip(f"{path} is not there (../shared/mocap must sit beside the checkout)")
    expected = GOLDEN / golden
    assert expected.exists(), f"no golden file {expected}: run `make golden`"
    got = render(path, args)
    assert got == expected.read_text(encoding="utf-8"), f"{golden} changed: run `make golden` if on purpose"


@pytest.mark.parametrize("golden", sorted(CASES))
def test_golden_info_has_the_required_keys(golden):
    expected = GOLDEN / golden
    if not expected.exists():
        pytest.skip(f"no golden file {expected}")
    if expected.suffix != ".json":
        pytest.skip("not an info --json golden file")
    data = json.loads(expected.read_text(encoding="utf-8"))
    assert {"frames", "frame_time", "rate", "duration", "kind", "file"} <= set(data)


def test_no_stale_golden_files():
    stale = sorted(p.name for p in GOLDEN.iterdir() if p.name not in CASES)
    assert not stale, f"golden files without a case (remove them or add the case): {stale}"
