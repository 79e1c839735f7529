"""C3D reading and writing on the real captures of ../shared/mocap (MANIFEST.md)."""

from __future__ import annotations

import struct
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from staggered_cli.errors import DataError
from staggered_cli.io.c3d import _decode_float, c3d_bytes, read_c3d, write_c3d
from staggered_cli.motion import MarkerMotion

ezc3d = pytest.importorskip("ezc3d")

MOCAP = Path(__file__).resolve().parents[1].parent / "shared" / "mocap"
EB015PI = "c3dorg_sample01_Eb015pi_walk.c3d"
CMU = "cmu_85_12_breakdance_long.c3d"
BTS = "ezc3d_BTS_walk_gaps.c3d"
FILES = (EB015PI, CMU, BTS)

pytestmark = pytest.mark.skipif(not MOCAP.is_dir(), reason="../shared/mocap is missing")

# Numbers from MANIFEST.md: markers, frames, rate (Hz), NaN fraction
MANIFEST = {
    EB015PI: (26, 450, 50.0, 0.019),
    CMU: (41, 4499, 120.0, 0.0),
    BTS: (22, 675, 100.0, 0.516),
}
FAST = 5.0  # seconds: a refused file must be refused quickly


@pytest.fixture(scope="module")
def motions() -> dict[str, MarkerMotion]:
    return {name: read_c3d(MOCAP / name) for name in FILES}


def _ezc3d(raw: bytes, tmp_path: Path, stem: str = "probe"):
    """ezc3d's own view of C3D bytes, as an independent reference."""
    path = tmp_path / f"{stem}.c3d"
    path.write_bytes(raw)
    return ezc3d.c3d(str(path))


def _parameter_values(c3d) -> dict[tuple[str, str], object]:
    out = {}
    for group in c3d["parameters"]:
        for name, parameter in c3d["parameters"][group].items():
            if name != "__METADATA__":
                out[(group, name)] = parameter["value"]
    return out


def _record(raw: bytes, group: str, name: str) -> int:
    """Byte offset of the type byte of parameter GROUP:NAME (Intel files)."""
    pos = (raw[0] - 1) * 512 + 4
    groups, found = {}, {}
    while True:
        length, ident = abs(struct.unpack_from("b", raw, pos)[0]), struct.unpack_from("b", raw, pos + 1)[0]
        if length == 0:
            break
        label = raw[pos + 2 : pos + 2 + length].decode("latin-1")
        step = struct.unpack_from("<h", raw, pos + 2 + length)[0]
        if ident < 0:
            groups[-ident] = label
        else:
            found[(ident, label)] = pos + 4 + length
        if step <= 0:
            break
        pos += 2 + length + step
    gid = next(k for k, v in groups.items() if v == group)
    return found[(gid, name)]


def _with_value(raw: bytes, group: str, name: str, ptype: int, payload: bytes) -> bytes:
    """``raw`` with the values of GROUP:NAME replaced by ``payload`` of C3D type ``ptype``.

    Keeps the file well formed: the record's offset to the next record grows
    with the values, and as many bytes of the zero padding that ends the
    parameter section are dropped, so that the data keeps its block.
    """
    at = _record(raw, group, name)
    ndims = raw[at + 1]
    count = int(np.prod(list(raw[at + 2 : at + 2 + ndims]), dtype=int))
    start = at + 2 + ndims
    old_size = count * abs(struct.unpack_from("b", raw, at)[0])
    delta = len(payload) - old_size
    out = bytearray(raw[:at] + struct.pack("b", ptype) + raw[at + 1 : start] + payload + raw[start + old_size :])
    step = struct.unpack_from("<h", out, at - 2)[0]
    struct.pack_into("<h", out, at - 2, step + delta)
    data_start = (struct.unpack_from("<H", raw, 16)[0] - 1) * 512 + delta
    assert out[data_start - delta : data_start] == bytes(delta)  # padding
    del out[data_start - delta : data_start]
    return bytes(out)


# --------------------------------------------------------------------------
# reading


@pytest.mark.parametrize("name", FILES)
def test_read_matches_manifest(motions, name):
    motion = motions[name]
    n_markers, n_frames, rate, nan_fraction = MANIFEST[name]
    assert motion.points.shape == (n_frames, n_markers, 3)
    assert motion.points.dtype == np.float64
    assert len(motion.labels) == n_markers
    assert motion.rate == rate
    assert motion.units == "mm"
    gaps = np.isnan(motion.points)
    # a marker is missing as a whole: all three coordinates or none
    assert np.array_equal(gaps.any(axis=-1), gaps.all(axis=-1))
    assert gaps[..., 0].mean() == pytest.approx(nan_fraction, abs=0.001)
    assert np.isfinite(motion.points[~gaps]).all()
    assert motion.source == (MOCAP / name).read_bytes()


def test_read_quirks(motions):
    eb, cmu, bts = motions[EB015PI], motions[CMU], motions[BTS]
    # Eb015pi: 48 POINT:LABELS but POINT:USED = 26, 10 markers with gaps
    assert eb.labels[:3] == ("RFT1", "RFT2", "RFT3") and eb.labels[-1] == "pv4"
    assert np.isnan(eb.points[..., 0]).any(axis=0).sum() == 10
    # CMU: subject-prefixed labels, no gaps
    assert all(label.startswith("Male:") for label in cmu.labels)
    assert "Male:LFWT" in cmu.labels
    # BTS: every marker has gaps, labels with spaces, Y up, walk along X at ~1.7 m/s
    assert np.isnan(bts.points[..., 0]).any(axis=0).all()
    assert "r should" in bts.labels
    sacrum = bts.points[:, bts.labels.index("sacrum")]
    assert 700 < np.nanmedian(sacrum[:, 1]) < 1300  # pelvis height in mm, on Y
    speed = np.nanmedian(np.diff(sacrum[:, 0])) * bts.rate
    assert 1000 < abs(speed) < 2500


def test_read_matches_ezc3d(motions, tmp_path):
    """The conversion at the edge: (4, M, T) -> (T, M, 3), gaps as NaN."""
    raw = (MOCAP / BTS).read_bytes()
    ref = _ezc3d(raw, tmp_path)
    expected = ref["data"]["points"][:3].transpose(2, 1, 0)
    np.testing.assert_array_equal(motions[BTS].points, expected)
    residual_gap = ref["data"]["meta_points"]["residuals"][0].T < 0
    assert np.array_equal(np.isnan(motions[BTS].points[..., 0]), residual_gap)


def test_read_from_bytes_uses_the_given_name(motions):
    raw = (MOCAP / EB015PI).read_bytes()
    motion = read_c3d("-", data=raw, name="<stdin>")
    np.testing.assert_array_equal(motion.points, motions[EB015PI].points)
    assert motion.labels == motions[EB015PI].labels
    with pytest.raises(DataError, match="<stdin>"):
        read_c3d("-", data=raw[:2000], name="<stdin>")


# --------------------------------------------------------------------------
# round trip


@pytest.mark.parametrize("name", FILES)
def test_round_trip_keeps_points_analogs_and_parameters(motions, name, tmp_path):
    motion = motions[name]
    out = tmp_path / "out.c3d"
    write_c3d(out, motion)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.c3d"]  # no temp file left

    again = read_c3d(out)
    assert again.labels == motion.labels
    assert again.rate == motion.rate and again.units == motion.units
    assert np.array_equal(np.isnan(again.points), np.isnan(motion.points))
    np.testing.assert_allclose(again.points, motion.points, atol=1e-3, equal_nan=True)

    src, dst = _ezc3d(motion.source, tmp_path, "src"), ezc3d.c3d(str(out))
    # analog channels: same samples to float32 precision
    a_src, a_dst = src["data"]["analogs"], dst["data"]["analogs"]
    assert a_src.shape == a_dst.shape
    if a_src.size:
        np.testing.assert_allclose(a_dst, a_src, rtol=1e-6, atol=1e-6 * np.abs(a_src).max())
    # residuals and camera masks of the valid samples carry over
    m_src, m_dst = src["data"]["meta_points"], dst["data"]["meta_points"]
    np.testing.assert_allclose(m_dst["residuals"], m_src["residuals"], atol=1e-6)
    valid = m_src["residuals"][0] >= 0
    assert np.array_equal(m_dst["camera_masks"][:, valid], m_src["camera_masks"][:, valid])
    # header events and first frame
    assert dst["header"]["events"]["events_time"] == src["header"]["events"]["events_time"]
    assert dst["header"]["events"]["events_label"] == src["header"]["events"]["events_label"]
    assert dst["header"]["points"]["first_frame"] == src["header"]["points"]["first_frame"]

    # every group and parameter of the source is kept with its value, except
    # what a rewrite must change: the data start, the float format (SCALE
    # sign, analog OFFSET zero) and the lists cut to the points and
    # channels in use
    before, after = _parameter_values(src), _parameter_values(dst)
    assert set(src["parameters"]) <= set(dst["parameters"])
    n_analogs = a_src.shape[1]
    rewritten = {("POINT", "DATA_START"), ("ANALOG", "OFFSET")}
    assert not np.any(after[("ANALOG", "OFFSET")])  # analogs are written as scaled floats
    for key, value in before.items():
        assert key in after, key
        if key in rewritten:
            continue
        if key == ("POINT", "SCALE"):
            assert after[key][0] == -abs(value[0])
        elif key in {("POINT", "LABELS"), ("POINT", "DESCRIPTIONS")}:
            assert list(after[key]) == (list(value) + [""] * len(motion.labels))[: len(motion.labels)]
        elif key[0] == "ANALOG" and key[1] in {"LABELS", "DESCRIPTIONS", "UNITS", "SCALE"}:
            np.testing.assert_array_equal(np.asarray(after[key]), np.asarray(value)[:n_analogs])
        else:
            np.testing.assert_array_equal(np.asarray(after[key]), np.asarray(value), err_msg=str(key))


def test_round_trip_of_ezc3d_written_file_is_stable(motions):
    """Writing what we wrote changes nothing in the points."""
    once = read_c3d("once", data=c3d_bytes(motions[EB015PI]))
    twice = read_c3d("twice", data=c3d_bytes(once))
    np.testing.assert_array_equal(twice.points, once.points)


def test_write_edited_points_and_gaps(motions, tmp_path):
    motion = motions[BTS]
    points = motion.points.copy()
    points[:, 0] += np.array([10.0, -5.0, 2.5])  # move one marker
    points[100:120, 1] = np.nan  # a new gap
    filled = np.isnan(points[:, 2, 0])
    points[filled, 2] = [1.0, 2.0, 3.0]  # fill a marker's gaps
    edited = replace(motion, points=points)
    snapshot = points.copy()

    out = tmp_path / "edited.c3d"
    write_c3d(out, edited)
    np.testing.assert_array_equal(edited.points, snapshot)  # the input is not touched
    again = read_c3d(out)
    assert np.array_equal(np.isnan(again.points), np.isnan(points))
    np.testing.assert_allclose(again.points, points, atol=1e-3, equal_nan=True)
    # residuals: valid samples >= 0 (filled gaps included), gaps exactly -1
    residuals = ezc3d.c3d(str(out))["data"]["meta_points"]["residuals"][0].T
    assert (residuals[~np.isnan(points[..., 0])] >= 0).all()
    assert (residuals[np.isnan(points[..., 0])] == -1).all()


@pytest.mark.parametrize("n_frames", [400, 775])
def test_write_a_different_frame_count(motions, tmp_path, n_frames):
    motion = motions[BTS]
    T = motion.n_frames
    if n_frames < T:
        points = motion.points[:n_frames]
    else:
        points = np.concatenate([motion.points, np.repeat(motion.points[-1:], n_frames - T, axis=0)])
    out = tmp_path / "resized.c3d"
    write_c3d(out, replace(motion, points=points))

    again = read_c3d(out)
    assert again.points.shape == (n_frames, 22, 3)
    np.testing.assert_allclose(again.points, points, atol=1e-3, equal_nan=True)

    src, dst = _ezc3d(motion.source, tmp_path, "src"), ezc3d.c3d(str(out))
    a_src, a_dst = src["data"]["analogs"], dst["data"]["analogs"]
    assert a_dst.shape == (1, 44, 10 * n_frames)  # 1000 Hz over 100 Hz kept
    keep = min(n_frames, T) * 10
    np.testing.assert_allclose(a_dst[..., :keep], a_src[..., :keep], rtol=1e-6, atol=1e-9)
    if n_frames > T:  # the last sample is held
        np.testing.assert_array_equal(
            a_dst[..., keep:], np.repeat(a_dst[..., keep - 1 : keep], 10 * n_frames - keep, -1)
        )
    assert dst["parameters"]["POINT"]["FRAMES"]["value"][0] == n_frames
    assert dst["parameters"]["ANALOG"]["RATE"]["value"][0] == 1000.0
    assert dst["header"]["points"]["first_frame"] == src["header"]["points"]["first_frame"]


def test_fewer_frames_updates_trial_fields(motions, tmp_path):
    motion = motions[CMU]
    out = tmp_path / "short.c3d"
    write_c3d(out, replace(motion, points=motion.points[:1000]))
    dst = ezc3d.c3d(str(out))
    assert list(dst["parameters"]["TRIAL"]["ACTUAL_END_FIELD"]["value"]) == [1000, 0]
    assert read_c3d(out).n_frames == 1000


def test_write_without_source_builds_a_fresh_c3d(tmp_path):
    rng = np.random.default_rng(7)
    n_frames, n_markers = 30, 300  # more than 255 labels: LABELS2 is needed
    points = rng.uniform(-1.0, 1.0, (n_frames, n_markers, 3))
    points[rng.random((n_frames, n_markers)) < 0.1] = np.nan
    labels = tuple(f"marker {i:03d}" for i in range(n_markers))
    motion = MarkerMotion(labels=labels, points=points, rate=60.0, units="m")

    out = tmp_path / "fresh.c3d"
    write_c3d(out, motion)
    again = read_c3d(out)
    assert again.labels == labels
    assert again.rate == 60.0 and again.units == "m"
    assert np.array_equal(np.isnan(again.points), np.isnan(points))
    np.testing.assert_allclose(again.points, points, atol=1e-6, equal_nan=True)
    assert again.source == out.read_bytes() == c3d_bytes(motion)


def test_write_changes_rate(motions, tmp_path):
    motion = motions[EB015PI]
    out = tmp_path / "rate.c3d"
    write_c3d(out, replace(motion, rate=100.0))
    dst = ezc3d.c3d(str(out))
    assert read_c3d(out).rate == 100.0
    assert dst["header"]["points"]["frame_rate"] == 100.0
    # the analogs keep their real rate (200 Hz, now 2 samples a 100 Hz frame)
    assert dst["parameters"]["ANALOG"]["RATE"]["value"][0] == 200.0
    assert dst["data"]["analogs"].shape[2] == 2 * motion.n_frames


# --------------------------------------------------------------------------
# bad input


def _assert_refused(path: Path, match: str | None = None) -> DataError:
    start = time.perf_counter()
    with pytest.raises(DataError) as info:
        read_c3d(path)
    assert time.perf_counter() - start < FAST
    message = str(info.value)
    assert path.name in message and "\n" not in message
    if match:
        assert match in message
    return info.value


def test_not_a_c3d(tmp_path):
    bvh = tmp_path / "walk.c3d"
    bvh.write_text("HIERARCHY\nROOT Hips\n{\n")
    _assert_refused(bvh, "not a C3D")
    empty = tmp_path / "empty.c3d"
    empty.write_bytes(b"")
    _assert_refused(empty, "empty")
    with pytest.raises(DataError, match="missing.c3d"):
        read_c3d(tmp_path / "missing.c3d")


@pytest.mark.parametrize("name", [EB015PI, BTS])
def test_truncated_files_are_refused(tmp_path, name):
    raw = (MOCAP / name).read_bytes()
    # the data of both files ends less than 400 bytes before the end of file
    for cut in (1, 300, 512, 700, 3000, len(raw) // 2, len(raw) - 600, len(raw) - 400):
        path = tmp_path / f"cut_{cut}_{name}"
        path.write_bytes(raw[:cut])
        _assert_refused(path)


def test_cutting_block_padding_only_is_fine(motions):
    # Eb015pi's last 352 bytes pad its last 512-byte block
    raw = (MOCAP / EB015PI).read_bytes()
    motion = read_c3d("padded", data=raw[:-352])
    np.testing.assert_array_equal(motion.points, motions[EB015PI].points)
    with pytest.raises(DataError, match="truncated"):
        read_c3d("cut", data=raw[:-353])


def test_absurd_frame_count_fails_fast(tmp_path):
    raw = (MOCAP / BTS).read_bytes()
    # POINT:FRAMES becomes a float claiming 10^9 frames (the c3d.org way to
    # store more than 65535; ezc3d 1.7.2 wants an INT and refuses it later)
    billion = _with_value(raw, "POINT", "FRAMES", 4, struct.pack("<f", 1e9))
    path = tmp_path / "billion.c3d"
    path.write_bytes(billion)
    _assert_refused(path, "1000000000 frames")

    # the header's own range, when POINT:FRAMES is 0: 65535 frames in 1.4 MB
    raw = bytearray((MOCAP / BTS).read_bytes())
    at = _record(bytes(raw), "POINT", "FRAMES")
    raw[at + 2 + raw[at + 1] : at + 4 + raw[at + 1]] = struct.pack("<h", 0)
    raw[6:10] = struct.pack("<HH", 1, 65535)
    path = tmp_path / "header.c3d"
    path.write_bytes(bytes(raw))
    _assert_refused(path, "truncated")


def test_header_and_analog_used_disagree(tmp_path):
    """MANIFEST 'Rejected': header has analog values per frame, ANALOG:USED = 0."""
    raw = bytearray((MOCAP / EB015PI).read_bytes())
    at = _record(bytes(raw), "ANALOG", "USED")
    raw[at + 2 + raw[at + 1] : at + 4 + raw[at + 1]] = struct.pack("<h", 0)
    path = tmp_path / "standing.c3d"
    path.write_bytes(bytes(raw))
    _assert_refused(path, "inconsistent")


def test_failed_write_leaves_no_file(motions, tmp_path):
    out = tmp_path / "out.c3d"
    broken = replace(motions[EB015PI], source=b"not a c3d at all")
    with pytest.raises(DataError):
        write_c3d(out, broken)
    mismatched = replace(motions[EB015PI], labels=motions[EB015PI].labels[:-1])
    with pytest.raises(ValueError, match="labels"):
        write_c3d(out, mismatched)
    infinite = motions[EB015PI].points.copy()
    infinite[0, 0, 0] = np.inf
    with pytest.raises(ValueError, match="infinite"):
        write_c3d(out, replace(motions[EB015PI], points=infinite))
    assert list(tmp_path.iterdir()) == []


def test_failed_write_keeps_the_previous_file(motions, tmp_path):
    out = tmp_path / "out.c3d"
    out.write_bytes(b"previous")
    with pytest.raises(DataError):
        write_c3d(out, replace(motions[EB015PI], source=b"\x02\x50" + bytes(510)))
    assert out.read_bytes() == b"previous"
    assert [p.name for p in tmp_path.iterdir()] == ["out.c3d"]


def test_dec_float_decoding():
    # DEC F-floating 1.0 is IEEE 4.0 with its 16-bit words swapped
    ieee4 = struct.pack("<f", 4.0)
    assert _decode_float(ieee4[2:] + ieee4[:2], 85) == 1.0
    assert _decode_float(struct.pack(">f", -2.5), 86) == -2.5
    assert _decode_float(struct.pack("<f", 120.0), 84) == 120.0


def test_more_than_65535_frames_declared_in_trial_is_refused(tmp_path):
    """ezc3d 1.7.2 would read only 65535 frames of such a file, silently."""
    raw = bytearray((MOCAP / CMU).read_bytes())
    at = _record(bytes(raw), "POINT", "FRAMES")
    raw[at + 2 + raw[at + 1] : at + 4 + raw[at + 1]] = struct.pack("<H", 65535)
    at = _record(bytes(raw), "TRIAL", "ACTUAL_END_FIELD")
    raw[at + 2 + raw[at + 1] : at + 6 + raw[at + 1]] = struct.pack("<HH", 70000 & 0xFFFF, 70000 >> 16)
    path = tmp_path / "long.c3d"
    path.write_bytes(bytes(raw))
    _assert_refused(path, "70000 frames")


def test_more_than_65535_frames_cannot_be_written(tmp_path):
    motion = MarkerMotion(labels=("a",), points=np.zeros((65536, 1, 3)), rate=120.0, units="mm")
    out = tmp_path / "long.c3d"
    with pytest.raises(DataError, match="65535"):
        write_c3d(out, motion)
    assert not out.exists()


def test_latin1_text_reads_and_writes(motions, tmp_path):
    """European software writes latin-1 (é = 0xE9): not UTF-8, ezc3d keeps surrogates."""
    raw = bytearray((MOCAP / EB015PI).read_bytes())
    at = raw.find(b"RFT2")
    raw[at + 3] = 0xE9  # the label RFT2 becomes RFTé, same length
    at = raw.find(b"elizabeth baumgartner")
    raw[at + 2] = 0xE9
    motion = read_c3d("latin1", data=bytes(raw))
    assert motion.labels[:3] == ("RFT1", "RFTé", "RFT3")

    out = tmp_path / "latin1.c3d"
    write_c3d(out, motion)
    again = read_c3d(out)
    assert again.labels == motion.labels
    np.testing.assert_allclose(again.points, motion.points, atol=1e-3, equal_nan=True)
    assert ezc3d.c3d(str(out))["parameters"]["SUBJECT"]["NAME"]["value"] == ["elézabeth baumgartner"]
