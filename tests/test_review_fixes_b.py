"""Regression tests for a second round of review findings.

1. ``bake --fps`` of a C3D kept the analog samples per frame, so the analog
   block was cut (or its last sample held) and relabelled in time.
2. A damaged NPZ document raised zipfile's NotImplementedError or
   ValueError as an internal error.
3. Crafted manifests: huge or fractional integers (OverflowError, silent
   truncation), non-finite or wrongly shaped ``signal.*`` arrays.
4. ``make batch`` with whitespace or make-special characters in IN, OUT or
   the names under IN.
"""

from __future__ import annotations

import json
import os
import random
import shutil
import struct
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from staggered_cli.cli.main import cli

from .conftest import SAMPLES, mocap, one_line_error

ROOT = Path(__file__).resolve().parents[1]


def _run(*args):
    return CliRunner().invoke(cli, [str(a) for a in args], catch_exceptions=False)


def _extract(src: Path, out: Path) -> Path:
    result = _run("extract", src, "-o", out)
    assert result.exit_code == 0, result.stderr
    return out


# --------------------------------------------------------------------------- 1. C3D analogs at a new rate


def _analogs(path: Path) -> tuple[np.ndarray, float, float, int]:
    import ezc3d

    c = ezc3d.c3d(str(path))
    p = c["parameters"]
    analogs = np.asarray(c["data"]["analogs"], dtype=float)[0]  # (A, S)
    return (
        analogs,
        float(p["POINT"]["RATE"]["value"][0]),
        float(p["ANALOG"]["RATE"]["value"][0]),
        c["data"]["points"].shape[2],
    )


@pytest.mark.parametrize(
    "fps, analog_rate",
    [
        (25, 200.0),  # 200 Hz is a whole multiple of 25: kept (8 samples a frame)
        (30, 210.0),  # 200 / 30 = 6.67: the nearest whole multiple, 7 x 30
        (120, 240.0),  # faster than a frame per 4 analog samples: 2 x 120
        (50, 200.0),  # the source's own rate: unchanged
    ],
)
def test_c3d_bake_at_a_new_rate_keeps_the_analog_timing(tmp_path, fps, analog_rate):
    src = mocap("c3dorg_sample01_Eb015pi_walk.c3d")  # points 50 Hz, 16 analogs at 200 Hz
    doc = _extract(src, tmp_path / "tr.stag")
    out = tmp_path / f"tr{fps}.c3d"
    result = _run("bake", doc, "--fps", fps, "-o", out)
    assert result.exit_code == 0, result.stderr
    a0, pr0, ar0, n0 = _analogs(src)
    a1, pr1, ar1, n1 = _analogs(out)
    assert (pr0, ar0) == (50.0, 200.0) and a0.shape[0] == a1.shape[0] == 16
    assert pr1 == fps and ar1 == analog_rate
    per_frame = a1.shape[1] / n1
    assert per_frame == round(analog_rate / fps), (a1.shape, n1)
    # the analog block spans the clip, whose duration is the source's (to a frame)
    assert a1.shape[1] / ar1 == pytest.approx(n1 / pr1)
    assert a0.shape[1] / ar0 == pytest.approx(n0 / pr0)
    assert 0 <= (n0 - 1) / pr0 - (n1 - 1) / pr1 < 1.0 / fps
    # each sample has the source's signal at its own time (linear interpolation)
    t0 = np.arange(a0.shape[1]) / ar0
    t1 = np.arange(a1.shape[1]) / ar1
    scale = np.ptp(a0, axis=1) + 1.0
    for ch in range(a0.shape[0]):
        want = np.interp(t1, t0, a0[ch])
        err = np.abs(a1[ch] - want).max()
        assert err <= 1e-5 * scale[ch], (ch, err, scale[ch])
    # and on the smoothest channel the new samples follow the signal itself,
    # not just the interpolation: within a few percent of its range
    rough = np.abs(np.diff(a0, 2, axis=1)).mean(axis=1) / scale
    smooth = int(np.argmin(rough))
    nearest = np.clip(np.rint(t1 * ar0).astype(int), 0, a0.shape[1] - 1)
    assert np.abs(a1[smooth] - a0[smooth][nearest]).max() <= 0.05 * scale[smooth]


def test_c3d_bake_at_half_rate_keeps_the_second_half_of_the_analogs(tmp_path):
    """The reported case: at 25 fps the file held the source's first 900
    samples stretched over the clip; the last second must be the source's."""
    src = mocap("c3dorg_sample01_Eb015pi_walk.c3d")
    doc = _extract(src, tmp_path / "tr.stag")
    out = tmp_path / "tr25.c3d"
    assert _run("bake", doc, "--fps", "25", "-o", out).exit_code == 0
    a0, _, ar0, _ = _analogs(src)
    a1, _, ar1, _ = _analogs(out)
    assert ar1 == ar0 and a1.shape == a0.shape
    np.testing.assert_allclose(a1[:, -200:], a0[:, -200:], rtol=1e-6, atol=1e-3)


# --------------------------------------------------------------------------- 2. damaged NPZ documents


def _info_is_clean(path: Path) -> str:
    """``info`` on a possibly damaged document: exit 0, or one line naming
    the file with exit 1; never an internal error.  The stderr line."""
    result = CliRunner().invoke(cli, ["info", str(path)])
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(result.exception)
    assert "internal error" not in result.stderr and "Traceback" not in result.stderr, result.stderr
    if result.exit_code == 0:
        return ""
    one_line_error(result, 1, str(path))
    return result.stderr


@pytest.fixture(scope="module")
def march_npz(tmp_path_factory) -> bytes:
    path = tmp_path_factory.mktemp("doc") / "march.stag"
    return _extract(SAMPLES / "march.bvh", path).read_bytes()


def _zip_structure(data: bytes) -> list[range]:
    """Byte ranges of the zip's local headers, central directory and end record."""
    import io

    with zipfile.ZipFile(io.BytesIO(data)) as zf:
        infos = zf.infolist()
        cd_start = zf.start_dir
    ranges = [range(i.header_offset, i.header_offset + 30 + len(i.filename)) for i in infos]
    ranges.append(range(cd_start, len(data)))
    return ranges


def test_byte_flips_in_an_npz_document_never_crash(march_npz, tmp_path):
    data = march_npz
    structure = _zip_structure(data)
    rng = random.Random(20240611)
    path = tmp_path / "flipped.stag"
    refused = 0
    for _ in range(300):
        b = bytearray(data)
        for _ in range(rng.randint(1, 4)):
            where = rng.random()
            if where < 0.4:
                pos = rng.choice(structure[-1])  # the central directory and end record
            elif where < 0.8:
                pos = rng.choice(rng.choice(structure[:-1]))  # a local header
            else:
                pos = rng.randrange(len(b))
            b[pos] ^= 1 << rng.randrange(8) if rng.random() < 0.5 else rng.randrange(1, 256)
        path.write_bytes(bytes(b))
        refused += bool(_info_is_clean(path))
    assert refused > 200


def _central_entries(data: bytes) -> list[int]:
    start = _zip_structure(data)[-1].start
    return [i for i in range(start, len(data) - 4) if data[i : i + 4] == b"PK\x01\x02"]


@pytest.mark.parametrize("damage", ["version", "negative_seek", "flag_bit"])
def test_zip_structures_zipfile_does_not_handle_are_refused(march_npz, tmp_path, damage):
    b = bytearray(march_npz)
    entries = _central_entries(march_npz)
    if damage == "version":  # NotImplementedError: zip file version 10.6
        struct.pack_into("<H", b, entries[0] + 6, 106)
    elif damage == "negative_seek":  # ValueError: negative seek value
        eocd = march_npz.rindex(b"PK\x05\x06")
        (offset_cd,) = struct.unpack_from("<I", b, eocd + 16)
        struct.pack_into("<I", b, eocd + 16, offset_cd + 1000)
    else:  # NotImplementedError: strong encryption (flag bit 6)
        (flags,) = struct.unpack_from("<H", b, entries[-1] + 8)
        struct.pack_into("<H", b, entries[-1] + 8, flags | 0x40)
    path = tmp_path / "damaged.stag"
    path.write_bytes(bytes(b))
    assert "corrupt NPZ document" in _info_is_clean(path)


# --------------------------------------------------------------------------- 3. crafted manifests


@pytest.fixture(scope="module")
def march_json(tmp_path_factory) -> dict:
    path = tmp_path_factory.mktemp("doc") / "march.json"
    return json.loads(_extract(SAMPLES / "march.bvh", path).read_text())


def _set(keys):
    def change(doc, value):
        target = doc
        for k in keys[:-1]:
            target = target[k]
        target[keys[-1]] = value

    return change


def _signal(name, value=None, shape=None):
    def change(doc, _):
        entry = doc["arrays"][f"signal.{name}"]
        if value is not None:
            entry["values"][3] = value
        if shape is not None:
            entry["shape"] = shape
            entry["values"] = [0.5] * int(np.prod(shape))

    return change


BIG = 10**30


@pytest.mark.parametrize(
    "change, value, needle",
    [
        (_set(["manifest", "bvh", "parents", 1]), 1e308, "bvh parents[1]"),
        (_set(["manifest", "bvh", "parents", 1]), BIG, "bvh parents[1]"),
        (_set(["manifest", "bvh", "parents", 2]), 0.5, "bvh parents[2]"),  # was truncated to 0
        (_set(["manifest", "bvh", "parents", 2]), 1.0, "bvh parents[2]"),
        (_set(["manifest", "bvh", "parents", 1]), True, "bvh parents[1]"),
        (_set(["manifest", "bvh", "end_parents", 0]), 1e308, "bvh end_parents[0]"),
        (_set(["manifest", "bvh", "end_parents", 0]), BIG, "bvh end_parents[0]"),
        (_set(["manifest", "bvh", "end_parents", 0]), 2.5, "bvh end_parents[0]"),
        (_set(["manifest", "tracks", 1, "targets", 0]), 1e308, "track 1 targets[0]"),
        (_set(["manifest", "tracks", 1, "targets", 0]), BIG, "track 1 targets[0]"),
        (_set(["manifest", "tracks", 1, "targets", 1]), 1.5, "track 1 targets[1]"),
        (_set(["manifest", "tracks", 0, "targets", 0]), -(BIG), "track 0 targets[0]"),
        (_set(["manifest", "frames"]), 121.5, "frames"),
        (_set(["manifest", "frames"]), BIG, "frames"),
        (_set(["manifest", "constraints"]), [{"joint": "Hips", "start": 10**400, "end": 0}], "OverflowError"),
        (_signal("P", value="Infinity"), None, "signal.P"),
        (_signal("P", value="NaN"), None, "signal.P"),
        (_signal("p", value="-Infinity"), None, "signal.p"),
        (_signal("P", shape=[120]), None, "signal.P"),
        (_signal("p", shape=[18, 121]), None, "signal.p"),
        (_signal("weights", shape=[17]), None, "signal.weights"),
        (_signal("contact", shape=[121, 1]), None, "signal.contact"),
    ],
)
def test_crafted_manifests_are_refused_in_one_line(march_json, tmp_path, change, value, needle):
    doc = json.loads(json.dumps(march_json))
    change(doc, value)
    path = tmp_path / "crafted.json"
    path.write_text(json.dumps(doc))
    for args in (["info", path], ["bake", path, "-o", tmp_path / "out.bvh"]):
        result = CliRunner().invoke(cli, [str(a) for a in args])
        one_line_error(result, 1, str(path), needle)
        assert "internal error" not in result.stderr
    assert not (tmp_path / "out.bvh").exists()


def test_an_infinite_signal_is_refused_before_plotting(march_json, tmp_path):
    doc = json.loads(json.dumps(march_json))
    doc["arrays"]["signal.P"]["values"][10] = "Infinity"
    path = tmp_path / "inf.json"
    path.write_text(json.dumps(doc))
    out = tmp_path / "signals.png"
    result = CliRunner().invoke(cli, ["plot", str(path), "--kind", "signals", "-o", str(out)])
    one_line_error(result, 1, str(path), "signal.P", "not finite")
    assert not out.exists()


def test_the_untouched_json_document_still_reads(march_json, tmp_path):
    path = tmp_path / "same.json"
    path.write_text(json.dumps(march_json))
    assert _run("info", path).exit_code == 0


# --------------------------------------------------------------------------- 4. make batch and awkward names

MAKE = shutil.which("make")
STAGGERED = Path(sys.executable).parent / "staggered"
needs_make = pytest.mark.skipif(
    MAKE is None or not STAGGERED.exists(), reason="GNU make or the staggered executable is not there"
)
UNSUPPORTED = "file name not supported by make batch; use staggered batch"


def _make(cwd: Path, *args: str) -> subprocess.CompletedProcess:
    """The repository's Makefile run from ``cwd`` (a temporary folder: any
    stray file lands there, never in the checkout)."""
    env = {k: v for k, v in os.environ.items() if k not in ("MAKEFLAGS", "MFLAGS", "MAKELEVEL")}
    return subprocess.run(
        [MAKE, "-f", str(ROOT / "Makefile"), *args, f"STAGGERED={STAGGERED}", "-o", ".venv/.staggered-installed"],
        cwd=cwd,
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
    )


def _usage_error(m: subprocess.CompletedProcess, needle: str) -> None:
    assert m.returncode == 2, (m.stdout, m.stderr)
    lines = m.stderr.splitlines()
    assert len(lines) == 1 and needle in lines[0], m.stderr
    assert m.stdout == ""


@needs_make
@pytest.mark.parametrize("which", ["IN", "OUT", "both"])
def test_make_batch_refuses_whitespace_in_in_or_out(tmp_path, which):
    work = tmp_path / "work"
    work.mkdir()
    src = tmp_path / ("in sp" if which != "OUT" else "in")
    src.mkdir()
    shutil.copy(SAMPLES / "march.bvh", src / "march.bvh")
    dst = tmp_path / ("out sp" if which != "IN" else "out")
    m = _make(work, "-k", "batch", f"IN={src}", f"OUT={dst}")
    _usage_error(m, "must not contain whitespace")
    assert not dst.exists()
    assert list(work.iterdir()) == []  # no stray sp/*.err where make ran
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted({"work", src.name})


@needs_make
@pytest.mark.parametrize("char", [";", "=", ":", "#", "$", '"', "%", "\\", "|", "*"])
def test_make_batch_refuses_make_special_characters_in_in_or_out(tmp_path, char):
    work = tmp_path / "work"
    work.mkdir()
    src = tmp_path / "in"
    src.mkdir()
    shutil.copy(SAMPLES / "march.bvh", src / "march.bvh")
    m = _make(work, "-k", "batch", f"IN={src}", f"OUT={tmp_path / ('o' + char + 'x')}")
    _usage_error(m, "must not contain any of")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in", "work"]
    assert list(work.iterdir()) == []


@needs_make
def test_make_batch_without_in_is_a_usage_error(tmp_path):
    _usage_error(_make(tmp_path, "batch", f"OUT={tmp_path / 'out'}"), "usage: make")


@needs_make
def test_make_batch_skips_and_reports_names_it_cannot_handle(tmp_path):
    work = tmp_path / "work"
    work.mkdir()
    src = tmp_path / "in"
    good = ["a.bvh", "sub dir/b c.bvh"]
    bad = ["x=y.bvh", "p;q.bvh", "sub dir/r$s.bvh", "t:u.bvh"]
    for rel in good + bad:
        (src / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(SAMPLES / "march.bvh", src / rel)
    dst = tmp_path / "out"
    m = _make(work, "-j2", "-k", "batch", f"IN={src}", f"OUT={dst}")
    assert m.returncode != 0, m.stdout + m.stderr
    assert "recipe commences" not in m.stderr and "No rule" not in m.stderr, m.stderr
    for rel in good:
        assert (dst / rel).read_bytes().startswith(b"HIERARCHY"), rel
    for rel in bad:
        assert not (dst / rel).exists()
        assert f"  FAILED {rel}: {UNSUPPORTED}" in m.stdout.splitlines(), m.stdout
    assert f"make batch: 6 files, {len(bad)} failed" in m.stdout
    assert list(work.iterdir()) == []


@needs_make
def test_make_batch_counts_inputs_left_unbuilt_as_failed(tmp_path):
    """Without -k make stops at the first failure: the files after it have
    no output and are failures too, not silently left out of the count."""
    src = tmp_path / "in"
    src.mkdir()
    (src / "a_broken.bvh").write_bytes((SAMPLES / "march.bvh").read_bytes()[:5000])
    for rel in ("b.bvh", "c.bvh"):
        shutil.copy(SAMPLES / "march.bvh", src / rel)
    dst = tmp_path / "out"
    m = _make(tmp_path, "batch", f"IN={src}", f"OUT={dst}")
    assert m.returncode != 0
    lines = m.stdout.splitlines()
    assert any(line.startswith("  FAILED a_broken.bvh: staggered: ") for line in lines), m.stdout
    assert "  FAILED b.bvh: not built" in lines and "  FAILED c.bvh: not built" in lines, m.stdout
    assert "make batch: 3 files, 3 failed" in m.stdout
    assert not (dst / "b.bvh").exists()
