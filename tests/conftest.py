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
