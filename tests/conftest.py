"""Shared fixtures: the real motion capture in ../shared/mocap (never copied here)."""

from __future__ import annotations

from pathlib import Path

import pytest

MOCAP = Path(__file__).resolve().parents[1].parent / "shared" / "mocap"
SAMPLES = Path(__file__).resolve().parents[1] / "data" / "samples"

BVH_FILES = sorted(p.name for p in MOCAP.glob("*.bvh")) if MOCAP.is_dir() else []
C3D_FILES = sorted(p.name for p in MOCAP.glob("*.c3d")) if MOCAP.is_dir() else []


def mocap(name: str) -> Path:
    path = MOCAP / name
    if not path.exists():
        pytest.skip(f"{path} is not there (../shared/mocap must sit beside the checkout)")
    return path


def one_line_error(result, code: int, *needles: str) -> None:
    """A CLI result that failed with ``code`` and one ``staggered: ...`` line
    on stderr containing every needle, without a traceback."""
    assert result.exit_code == code, (result.exit_code, result.stderr)
    lines = result.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("staggered: "), result.stderr
    for n in needles:
        assert n in lines[0], lines[0]
    assert "Traceback" not in result.stderr
