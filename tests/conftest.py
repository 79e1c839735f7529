"""Shared fixtures: the real motion capture in ../shared/mocap (never copied
here), and what the tests make of it, made once per test session.

``dev_motion``, ``dev_document``, ``dev_bake`` and ``cli_document`` cache per
process: with ``pytest -n 2`` each worker builds its own once.  The values
are shared by every module, so a test must not change them in place (the
library never does: every operation returns new values).

Without ../shared/mocap the tests that need it skip, except under ``CI=true``,
where the run fails at once: a CI run that skipped the real data would pass
without testing anything that matters.
"""

from __future__ import annotations

import functools
import os
from pathlib import Path

import pytest

MOCAP = Path(__file__).resolve().parents[1].parent / "shared" / "mocap"
SAMPLES = Path(__file__).resolve().parents[1] / "data" / "samples"

BVH_FILES = sorted(p.name for p in MOCAP.glob("*.bvh")) if MOCAP.is_dir() else []
C3D_FILES = sorted(p.name for p in MOCAP.glob("*.c3d")) if MOCAP.is_dir() else []


def in_ci() -> bool:
    """True when the environment says this is a CI run (``CI=true``)."""
    return os.environ.get("CI", "").strip().lower() in ("true", "1", "yes")


def _missing(path: Path) -> str:
    return f"{path} is not there (../shared/mocap must sit beside the checkout)"


def pytest_configure(config):
    if in_ci() and not MOCAP.is_dir():
        raise pytest.UsageError(f"CI=true: {_missing(MOCAP)}; the tests on real motion capture cannot run")


def dev_bvh_files() -> list[str]:
    """:data:`BVH_FILES`, for a test over all of them (it skips, like
    :func:`mocap`, when ../shared/mocap is not there: an empty list would
    make it fail instead)."""
    if not BVH_FILES:
        mocap("")
    return BVH_FILES


def mocap(name: str) -> Path:
    path = MOCAP / name
    if not path.exists():
        if in_ci():
            pytest.fail(f"CI=true: {_missing(path)}", pytrace=False)
        pytest.skip(_missing(path))
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


def short_bvh(name: str, seconds: float) -> bytes:
    """The BVH file ``name`` cut to its first ``seconds`` of frames: its own
    header and frame lines, byte for byte, with the frame count changed."""
    data = mocap(name).read_bytes()
    at = data.index(b"MOTION")
    lines = data[at:].splitlines(keepends=True)
    assert lines[1].split()[0] == b"Frames:" and lines[2].split()[:2] == [b"Frame", b"Time:"], lines[:3]
    n, frame_time = int(lines[1].split()[1]), float(lines[2].split()[2])
    keep = min(n, max(2, int(round(seconds / frame_time))))
    frames = lines[1].replace(str(n).encode(), str(keep).encode(), 1)
    return data[:at] + lines[0] + frames + lines[2] + b"".join(lines[3 : 3 + keep])


# --------------------------------------------------------------------------- shared per session


def read_only(value, _seen=None):
    """``value`` with every numpy array in it (through dataclasses, tuples,
    lists and dicts) made read-only, so that a test or an operation that
    writes into a shared value fails where it writes instead of changing
    what later tests see."""
    import dataclasses

    import numpy as np

    seen = set() if _seen is None else _seen
    if id(value) in seen:
        return value
    seen.add(id(value))
    if isinstance(value, np.ndarray):
        value.flags.writeable = False
    elif dataclasses.is_dataclass(value) and not isinstance(value, type):
        for f in dataclasses.fields(value):
            read_only(getattr(value, f.name), seen)
    elif isinstance(value, (tuple, list)):
        for v in value:
            read_only(v, seen)
    elif isinstance(value, dict):
        for v in value.values():
            read_only(v, seen)
    return value


@functools.cache
def dev_motion(name: str):
    """The clip ``name`` of ../shared/mocap (BvhMotion or MarkerMotion), read once (read-only)."""
    path = mocap(name)
    if name.lower().endswith(".c3d"):
        from staggered_cli.io.c3d import read_c3d

        return read_only(read_c3d(path))
    from staggered_cli.io.bvh import read_bvh

    return read_only(read_bvh(path))


@functools.cache
def dev_document(name: str):
    """``extract`` of the clip ``name`` with the default options, once (read-only)."""
    from staggered_cli.ops.extract import extract

    return read_only(extract(dev_motion(name), source_name=name))


@functools.cache
def dev_bake(name: str):
    """The unedited bake (contact layer on) of :func:`dev_document`, once (read-only)."""
    from staggered_cli.ops.bake import bake

    return read_only(bake(dev_document(name)))


@functools.cache
def cli_extract(name: str) -> bytes:
    """What ``staggered extract NAME -o -`` writes: the bytes of
    :func:`dev_document` with the source's SHA-256, as the command records it
    (test_extract checks that they are the command's, byte for byte)."""
    import hashlib
    from dataclasses import replace

    from staggered_cli.io.container import document_bytes
    from staggered_cli.io.schema import to_parts

    sha = hashlib.sha256(mocap(name).read_bytes()).hexdigest()
    return document_bytes(*to_parts(replace(dev_document(name), source_sha256=sha)), "npz")


def cli_document(name: str, *steps: list[str]) -> bytes:
    """``staggered extract NAME -o - | STEP - -o - | ...`` as NPZ bytes, in
    memory; the extraction is made once per session."""
    from click.testing import CliRunner

    from staggered_cli.cli.main import cli

    data = cli_extract(name)
    for step in steps:
        r = CliRunner().invoke(cli, [*step, "-", "-o", "-"], input=data)
        assert r.exit_code == 0, r.stderr
        data = r.stdout_bytes
    return data


def document_file(doc, path: Path) -> Path:
    """``doc`` written to ``path`` as an NPZ document."""
    from staggered_cli.io.container import document_bytes
    from staggered_cli.io.schema import to_parts

    path.write_bytes(document_bytes(*to_parts(doc), "npz"))
    return path


@pytest.fixture(scope="session")
def cmu_walk():
    """(motion, extracted document) of the CMU walk at 120 Hz (cmu_02_01)."""
    return dev_motion("cmu_02_01_walk.bvh"), dev_document("cmu_02_01_walk.bvh")


@pytest.fixture(scope="session")
def bandai_run():
    """(motion, extracted document) of the Bandai run at 30 Hz (68 frames)."""
    return dev_motion("bandai2_run_normal_001.bvh"), dev_document("bandai2_run_normal_001.bvh")


class StaggeredWarnings(list):
    """The messages (``str``, Python's wording) of the :class:`StaggeredWarning`
    s issued inside ``with staggered_warnings() as seen:``."""


def staggered_warnings():
    """Collect the library's warnings (every one, none turned into an error)."""
    import contextlib
    import warnings

    from staggered_cli.errors import StaggeredWarning

    @contextlib.contextmanager
    def collect():
        seen = StaggeredWarnings()
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", StaggeredWarning)
            yield seen
        seen.extend(str(w.message) for w in caught if issubclass(w.category, StaggeredWarning))
        others = [w for w in caught if not issubclass(w.category, StaggeredWarning)]
        for w in others:  # anything else still fails the test, as -W error would
            raise AssertionError(f"unexpected warning: {w.category.__name__}: {w.message}")

    return collect()
