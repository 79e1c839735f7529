"""The document byte layer (SPEC section 7): exact round trips, deterministic
bytes, and refusal of malformed or hostile files without unpickling,
inflating or allocating what they declare."""

from __future__ import annotations

import io
import json
import os
import pickle
import random
import struct
import time
import tracemalloc
import warnings
import zipfile
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from staggered_cli.cli.main import cli
from staggered_cli.errors import DataError
from staggered_cli.io import container
from staggered_cli.io.container import (
    FORMAT_NAME,
    FORMAT_VERSION,
    MANIFEST_MEMBER,
    document_bytes,
    is_document,
    parse_document,
)

from .conftest import SAMPLES, one_line_error

NAME = "walk.stag"


def _npy_bytes(arr: np.ndarray) -> bytes:
    """The ``.npy`` member the writer stores for ``arr``."""
    return b"".join(bytes(p) for p in container._npy_parts(arr))


def sample():
    rng = np.random.default_rng(7)
    manifest = {
        "frame_time": 0.0083333,
        "source": {"name": "walk.bvh", "sha256": "ab" * 32},
        "names": ["Hips", "LeftUpLeg", "Épaule"],
        "poses": [{"t": 0.1, "priority": 1e-300}, {"t": 1 / 3, "priority": None}],
        "flag": True,
        "count": 3,
    }
    arrays = {
        "pose_t": np.array([0.0, -0.0, 0.1, 1 / 3, 5e-324, 1e308, -np.inf, np.inf, np.nan]),
        "track0/knot_v": rng.normal(size=(6, 4, 3)),
        "track1.knot_q": rng.normal(size=(5, 3, 4)),
        "knot_ptr": np.array([0, 3, 7, 12], dtype=np.int64),
        "big_ints": np.array([np.iinfo(np.int64).min, -1, np.iinfo(np.int64).max]),
        "editing": np.array([[True, False], [False, True]]),
        "c3d_bytes": np.frombuffer(b"\x00\x50\xff" * 5, dtype=np.uint8),
        "empty": np.zeros((0, 3)),
        "scalar": np.array(2.5),
        "fortran": np.asfortranarray(rng.normal(size=(3, 5))),
        "big_endian": np.arange(4, dtype=">f8"),
    }
    return manifest, arrays


def assert_same(arrays, back):
    assert sorted(back) == sorted(arrays)
    for key, arr in arrays.items():
        got = back[key]
        assert got.shape == arr.shape, key
        assert got.dtype == arr.dtype.newbyteorder("="), key
        assert np.array_equal(got, arr, equal_nan=arr.dtype.kind == "f"), key
        if arr.dtype.kind == "f":
            real = ~np.isnan(arr)  # a NaN's sign carries nothing (JSON spells every NaN alike)
            assert np.array_equal(np.signbit(got)[real], np.signbit(arr)[real]), key  # -0.0 kept
        assert got.flags.writeable and got.flags.c_contiguous, key


@pytest.mark.parametrize("fmt", ["npz", "json"])
def test_round_trip_is_exact(fmt):
    manifest, arrays = sample()
    data = document_bytes(manifest, arrays, fmt)
    back_manifest, back = parse_document(data, NAME)
    assert back_manifest == manifest
    assert_same(arrays, back)
    # and again: bytes -> document -> bytes is the identity
    assert document_bytes(back_manifest, back, fmt) == data


@pytest.mark.parametrize("fmt", ["npz", "json"])
def test_bytes_are_deterministic(fmt):
    manifest, arrays = sample()
    first = document_bytes(manifest, arrays, fmt)
    shuffled_arrays = dict(reversed(list(arrays.items())))
    shuffled_manifest = dict(reversed(list(manifest.items())))
    assert document_bytes(shuffled_manifest, shuffled_arrays, fmt) == first
    time.sleep(1.1)  # zip timestamps are fixed, not the clock
    assert document_bytes(manifest, arrays, fmt) == first


def test_npz_is_a_plain_numpy_archive():
    manifest, arrays = sample()
    data = document_bytes(manifest, arrays, "npz")
    with np.load(io.BytesIO(data), allow_pickle=False) as npz:
        assert np.array_equal(npz["track0/knot_v"], arrays["track0/knot_v"])
    with zipfile.ZipFile(io.BytesIO(data)) as zf:
        names = zf.namelist()
        assert names == sorted(names)
        envelope = json.loads(zf.read(MANIFEST_MEMBER))
    assert envelope["format"] == FORMAT_NAME and envelope["version"] == FORMAT_VERSION
    assert envelope["arrays"]["knot_ptr"] == {"dtype": "int64", "shape": [4]}


def test_json_is_standard_json_with_sorted_keys():
    manifest, arrays = sample()
    text = document_bytes(manifest, arrays, "json").decode("utf-8")
    # standard JSON: no bare NaN / Infinity tokens
    parsed = json.loads(text, parse_constant=lambda c: pytest.fail(f"non-standard constant {c}"))
    assert list(parsed) == sorted(parsed)
    assert list(parsed["arrays"]) == sorted(parsed["arrays"])
    assert parsed["arrays"]["pose_t"]["values"][-3:] == ["-Infinity", "Infinity", "NaN"]
    assert parsed["arrays"]["pose_t"]["values"][1] == 0.0 and "-0.0" in text
    # one row of the last axis per line
    assert "\n    0, 3, 7, 12\n" not in text
    assert any(line.strip().count(",") == 3 for line in text.splitlines())


@settings(max_examples=60, deadline=None)
@given(
    arr=hnp.arrays(
        dtype=st.sampled_from([np.float64, np.int64, np.bool_, np.uint8]),
        shape=hnp.array_shapes(min_dims=0, max_dims=4, min_side=0, max_side=5),
    ),
    fmt=st.sampled_from(["npz", "json"]),
)
def test_round_trip_property(arr, fmt):
    manifest, back = parse_document(document_bytes({"k": 1}, {"a": arr}, fmt), NAME)
    assert manifest == {"k": 1}
    assert_same({"a": arr}, back)


def test_writer_refuses_what_a_document_cannot_hold():
    with pytest.raises(ValueError, match="float32"):
        document_bytes({}, {"a": np.zeros(2, dtype=np.float32)}, "npz")
    with pytest.raises(ValueError, match="object"):
        document_bytes({}, {"a": np.array([{}], dtype=object)}, "npz")
    with pytest.raises(ValueError, match="non-finite"):
        document_bytes({"x": float("nan")}, {}, "json")
    with pytest.raises(ValueError, match="bad array name"):
        document_bytes({}, {"../evil": np.zeros(1)}, "npz")
    with pytest.raises(ValueError, match="unknown document format"):
        document_bytes({}, {}, "yaml")
    # NumPy scalars in the manifest are written as plain numbers
    manifest, _ = parse_document(document_bytes({"n": np.int64(3), "x": np.float64(0.5)}, {}, "json"), NAME)
    assert manifest == {"n": 3, "x": 0.5}


def test_is_document():
    assert is_document(document_bytes({}, {}, "npz"))
    assert is_document(document_bytes({}, {}, "json"))
    assert is_document(b"\xef\xbb\xbf \n{")
    assert not is_document(b"HIERARCHY\nROOT Hips")
    assert not is_document(b"")
    assert not is_document(b"\x02\x50" + bytes(100))


# ----------------------------------------------------------------- malformed files


def refused(data, *needles, name=NAME):
    with pytest.raises(DataError) as info:
        parse_document(data, name)
    message = str(info.value)
    assert message.startswith(f"{name}: "), message
    assert "\n" not in message
    for needle in needles:
        assert needle in message, message
    return message


def rezip(members: dict[str, bytes]) -> bytes:
    buf = io.BytesIO()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # zipfile warns on the duplicate names some tests write
        with zipfile.ZipFile(buf, "w") as zf:
            for member, data in members.items():
                zf.writestr(member.split("\0")[0], data)
    return buf.getvalue()


def members_of(data: bytes) -> dict[str, bytes]:
    with zipfile.ZipFile(io.BytesIO(data)) as zf:
        return {n: zf.read(n) for n in zf.namelist()}


def envelope_of(data: bytes) -> dict:
    return json.loads(members_of(data)[MANIFEST_MEMBER])


@pytest.mark.parametrize("keep", [0.2, 0.5, 0.9, 0.999])
def test_truncated_npz(keep):
    data = document_bytes(*sample(), "npz")
    refused(data[: int(len(data) * keep)], "truncated or corrupt NPZ document")


def test_truncated_and_malformed_json():
    data = document_bytes(*sample(), "json")
    refused(data[: len(data) // 2], "malformed JSON document", "line")
    refused(b"{" * 100_000, "malformed JSON document")  # nested too deeply
    refused(b"{\xff}", "not UTF-8")
    refused(b"[1, 2]", "not a staggered-poses document")


def test_corrupt_member_data_fails_its_crc():
    data = bytearray(document_bytes({}, {"a": np.arange(100.0)}, "npz"))
    pos = data.index(np.arange(100.0)[50:51].tobytes())
    data[pos] ^= 0xFF
    refused(bytes(data), "corrupt NPZ document", "CRC")


@pytest.mark.parametrize("fmt", ["npz", "json"])
def test_wrong_format_name_and_versions(fmt):
    def with_envelope(**changes):
        if fmt == "json":
            env = json.loads(document_bytes({"m": 1}, {"a": np.zeros(2)}, "json"))
            env.update(changes)
            return json.dumps(env).encode()
        members = members_of(document_bytes({"m": 1}, {"a": np.zeros(2)}, "npz"))
        env = json.loads(members[MANIFEST_MEMBER])
        env.update(changes)
        members[MANIFEST_MEMBER] = json.dumps(env).encode()
        return rezip(members)

    refused(with_envelope(format="blender-poses"), "not a staggered-poses document", "blender-poses")
    message = refused(with_envelope(version=FORMAT_VERSION + 1), "newer", "upgrade")
    assert f"version {FORMAT_VERSION + 1}" in message
    refused(with_envelope(version="1"), "bad document version")
    refused(with_envelope(version=0), "bad document version")
    refused(with_envelope(version=True), "bad document version")
    refused(with_envelope(manifest=[1]), "no manifest")
    assert parse_document(with_envelope(), NAME)[0] == {"m": 1}


def test_zip_without_manifest_or_with_stray_members():
    refused(rezip({"a.npy": b"x"}), "no manifest.json")
    members = members_of(document_bytes({}, {"a": np.zeros(2)}, "npz"))
    refused(rezip({**members, "evil.py": b"print(1)"}), "unexpected member 'evil.py'")
    del members["a.npy"]
    refused(rezip(members), "missing member 'a.npy'")


def test_duplicate_members():
    members = members_of(document_bytes({}, {"a": np.zeros(2)}, "npz"))
    refused(rezip({**members, "a.npy\0dup": members["a.npy"]}), "duplicate member 'a.npy'")


class _Exploit:
    """Unpickling this would create a marker file."""

    def __init__(self, marker):
        self.marker = marker

    def __reduce__(self):
        return (os.mkdir, (self.marker,))


def test_pickled_object_array_is_refused_without_running_it(tmp_path):
    marker = str(tmp_path / "pwned")
    buf = io.BytesIO()
    np.save(buf, np.array([_Exploit(marker)], dtype=object), allow_pickle=True)
    assert b"pwned" in buf.getvalue()
    members = members_of(document_bytes({}, {"a": np.zeros(1)}, "npz"))
    members["a.npy"] = buf.getvalue()
    refused(rezip(members), "array 'a'", "dtype '|O' not allowed")
    # the same with a manifest that admits the object dtype
    env = json.loads(members[MANIFEST_MEMBER])
    env["arrays"]["a"]["dtype"] = "object"
    members[MANIFEST_MEMBER] = json.dumps(env).encode()
    refused(rezip(members), "dtype 'object' not allowed")
    assert not os.path.exists(marker)
    # the file really is a pickle bomb: the unsafe way would have run it
    pickle.loads(buf.getvalue()[buf.getvalue().index(b"\x80") :])
    assert os.path.exists(marker)


def _patch_declared_size(data: bytes, member: str, size: int) -> bytes:
    """Rewrite the uncompressed size of ``member`` in its local header and
    the central directory (what a zip bomb lies about or boasts of)."""
    out = bytearray(data)
    name = member.encode()
    for sig, size_at, name_len_at, name_at in ((b"PK\x03\x04", 22, 26, 30), (b"PK\x01\x02", 24, 28, 46)):
        pos = out.find(sig)
        while pos >= 0:
            (n,) = struct.unpack_from("<H", out, pos + name_len_at)
            if bytes(out[pos + name_at : pos + name_at + n]) == name:
                struct.pack_into("<I", out, pos + size_at, size)
            pos = out.find(sig, pos + 4)
    return bytes(out)


def _npy_header(n: int) -> bytes:
    """A .npy version 1.0 header for a float64 array of shape (n,)."""
    head = b"{'descr': '<f8', 'fortran_order': False, 'shape': (%d,), }" % n
    head += b" " * (-(10 + len(head) + 1) % 64) + b"\n"
    return b"\x93NUMPY\x01\x00" + len(head).to_bytes(2, "little") + head


def _measure(fn):
    tracemalloc.start()
    start = time.perf_counter()
    try:
        fn()
    finally:
        elapsed = time.perf_counter() - start
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
    return elapsed, peak


def test_member_declaring_gigabytes_is_refused_quickly_with_low_memory():
    data = document_bytes({}, {"a": np.zeros(1000)}, "npz")
    bomb = _patch_declared_size(data, "a.npy", 0xFFFFFFF0)  # about 4 GiB
    elapsed, peak = _measure(lambda: refused(bomb, "member 'a.npy' declares 4,294,967,280 bytes"))
    assert elapsed < 1.0
    assert peak < 2 << 20


def test_deflate_bomb_over_the_limits_is_not_inflated(monkeypatch):
    # a real bomb: 256 MiB of zeros deflate to about 256 KiB; honest sizes
    n = 32 << 20
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        env = {"arrays": {"a": {"dtype": "float64", "shape": [n]}}, "format": FORMAT_NAME, "manifest": {}, "version": 1}
        zf.writestr(MANIFEST_MEMBER, json.dumps(env))
        with zf.open("a.npy", "w", force_zip64=True) as member:
            member.write(_npy_header(n))
            chunk = bytes(1 << 20)
            for _ in range(n * 8 // len(chunk)):
                member.write(chunk)
    bomb = buf.getvalue()
    assert len(bomb) < 1 << 20
    monkeypatch.setattr(container, "MAX_ARRAY_BYTES", 64 << 20)
    elapsed, peak = _measure(lambda: refused(bomb, "over the limit"))
    assert elapsed < 1.0
    assert peak < 2 << 20


def test_member_lying_small_is_cut_at_its_declared_size():
    data = document_bytes({}, {"a": np.zeros(1000)}, "npz")
    members = members_of(data)
    big = members["a.npy"] + bytes(10 << 20)  # inflates to 10 MiB more than declared
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        zf.writestr(MANIFEST_MEMBER, members[MANIFEST_MEMBER])
        zf.writestr("a.npy", big)
    liar = _patch_declared_size(buf.getvalue(), "a.npy", len(members["a.npy"]))
    elapsed, peak = _measure(lambda: refused(liar, "corrupt NPZ document"))
    assert peak < 4 << 20


def test_total_of_members_is_capped(monkeypatch):
    monkeypatch.setattr(container, "MAX_TOTAL_BYTES", 10_000)
    refused(document_bytes({}, {"a": np.zeros(800), "b": np.zeros(800)}, "npz"), "total more than the limit")
    refused(document_bytes({}, {"a": np.zeros(800), "b": np.zeros(800)}, "json"), "total more than the limit")


@pytest.mark.parametrize("shape", [[10**6, 10**6], [10**12], [2**62, 2**62, 2**62]])
def test_absurd_shapes_are_refused_before_allocating(shape):
    env = {"arrays": {"a": {"dtype": "float64", "shape": shape}}, "format": FORMAT_NAME, "manifest": {}, "version": 1}
    members = {MANIFEST_MEMBER: json.dumps(env).encode(), "a.npy": _npy_bytes(np.zeros(1))}
    elapsed, peak = _measure(lambda: refused(rezip(members), "array 'a'", "over the limit"))
    assert elapsed < 1.0 and peak < 2 << 20
    env["arrays"]["a"]["values"] = []
    elapsed, peak = _measure(lambda: refused(json.dumps(env).encode(), "array 'a'", "over the limit"))
    assert elapsed < 1.0 and peak < 2 << 20


def test_npy_header_must_agree_with_the_manifest():
    members = members_of(document_bytes({}, {"a": np.zeros(4)}, "npz"))
    members["a.npy"] = _npy_bytes(np.zeros(5))
    refused(rezip(members), "array 'a'", "header says")
    # a header whose shape matches but whose member is too short for it
    members["a.npy"] = _npy_bytes(np.zeros(4))[:-8]
    refused(rezip(members), "array 'a'", "data bytes")
    members["a.npy"] = b"not npy at all"
    refused(rezip(members), "not a .npy member")
    members["a.npy"] = _npy_bytes(np.zeros(4)).replace(b"'<f8'", b"'<U2'")
    refused(rezip(members), "dtype '<U2' not allowed")


@pytest.mark.parametrize(
    ("entry", "needle"),
    [
        ({"dtype": "float64", "shape": [1e400]}, "bad shape"),  # 1e400 parses as inf
        ({"dtype": "float64", "shape": [2.0]}, "bad shape"),
        ({"dtype": "float64", "shape": [-1]}, "bad shape"),
        ({"dtype": "float64", "shape": [True]}, "bad shape"),
        ({"dtype": "float64", "shape": 3}, "bad shape"),
        ({"dtype": "float64", "shape": [1] * 40}, "bad shape"),
        ({"dtype": "float32", "shape": [1]}, "dtype 'float32' not allowed"),
        ({"dtype": "object", "shape": [1]}, "dtype 'object' not allowed"),
        ({"dtype": "float64", "shape": [2], "values": [1.0]}, "1 values for shape [2]"),
        ({"dtype": "float64", "shape": [2], "values": [1.0, None]}, "do not fit"),
        ({"dtype": "float64", "shape": [2], "values": [1.0, "1.5"]}, "do not fit"),
        ({"dtype": "float64", "shape": [2], "values": [1.0, [2.0]]}, "do not fit"),
        ({"dtype": "float64", "shape": [2], "values": [1.0, True]}, "do not fit"),
        ({"dtype": "int64", "shape": [2], "values": [1, 2.0]}, "do not fit"),
        ({"dtype": "int64", "shape": [1], "values": [2**64]}, "do not fit"),
        ({"dtype": "uint8", "shape": [1], "values": [256]}, "do not fit"),
        ({"dtype": "bool", "shape": [1], "values": [1]}, "do not fit"),
        ({"dtype": "float64", "shape": [1], "values": "1.0"}, "no values list"),
    ],
)
def test_json_array_entries_are_validated(entry, needle):
    text = json.dumps({"arrays": {"a": entry}, "format": FORMAT_NAME, "manifest": {}, "version": 1})
    refused(text.encode(), needle)


def test_json_accepts_integers_in_float_arrays():
    text = json.dumps(
        {
            "arrays": {"a": {"dtype": "float64", "shape": [2], "values": [1, "NaN"]}},
            "format": FORMAT_NAME,
            "manifest": {},
            "version": 1,
        }
    )
    _, arrays = parse_document(text.encode(), NAME)
    assert arrays["a"].dtype == np.float64 and arrays["a"][0] == 1.0 and np.isnan(arrays["a"][1])


def test_unusual_zip_features_are_refused():
    data = document_bytes({}, {"a": np.zeros(2)}, "npz")
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression=zipfile.ZIP_BZIP2) as zf:
        for member, content in members_of(data).items():
            zf.writestr(member, content)
    refused(buf.getvalue(), "unsupported compression")
    refused(b"", "empty file")
    refused(b"HIERARCHY", "not a staggered-poses document")


def _run(*args):
    return CliRunner().invoke(cli, [str(a) for a in args], catch_exceptions=False)


def _extract(src: Path, out: Path) -> Path:
    result = _run("extract", src, "-o", out)
    assert result.exit_code == 0, result.stderr
    return out


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


def test_pieces_join_to_the_document_bytes_and_a_file_reads_like_its_bytes(tmp_path):
    """What the CLI writes (views of the arrays, piece by piece) is
    ``document_bytes``, and an NPZ read from its open file (in place, no
    bytes copy) is the same as from its bytes."""
    manifest, arrays = sample()
    data = document_bytes(manifest, arrays, "npz")
    pieces = container.document_pieces(manifest, arrays, "npz")
    assert b"".join(bytes(p) for p in pieces) == data
    path = tmp_path / NAME
    path.write_bytes(data)
    m_bytes, a_bytes = parse_document(data, NAME)
    with open(path, "rb") as fh:
        m_file, a_file = parse_document(fh, NAME)
    assert m_file == m_bytes
    assert_same(arrays, a_file)
    for key, value in a_file.items():
        assert value.flags.writeable and value.flags.c_contiguous and value.dtype.isnative, key


# --- the source's arrays are mapped from a document file -------------------------------------


def _mapping_rss_kb(path: Path) -> int | None:
    """Resident kB of this process's mappings of ``path`` (None without /proc/self/smaps)."""
    try:
        lines = Path("/proc/self/smaps").read_text().splitlines()
    except OSError:
        return None
    total, inside = 0, False
    for line in lines:
        head = line.split()
        if head and "-" in head[0] and len(head) >= 5 and ":" in head[3]:  # a mapping's header line
            inside = line.rstrip().endswith(str(path))
        elif inside and line.startswith("Rss:"):
            total += int(line.split()[1])
    return total


@pytest.fixture
def mapped_everything(monkeypatch):
    """Map the source's arrays whatever their size (the sample's are small)."""
    monkeypatch.setattr(container, "_MAP_MIN_BYTES", 1)


def test_source_arrays_of_a_file_are_mapped_read_only_and_equal_to_its_bytes(march_npz, tmp_path, mapped_everything):
    path = tmp_path / "m.stag"
    path.write_bytes(march_npz)
    _, from_bytes = parse_document(march_npz, NAME)
    with open(path, "rb") as fh:
        _, from_file = parse_document(fh, NAME)
    assert from_file.keys() == from_bytes.keys()
    for key, value in from_file.items():
        np.testing.assert_array_equal(value, from_bytes[key], err_msg=key)
        assert value.dtype == from_bytes[key].dtype and value.flags.c_contiguous, key
        # the source's arrays are the file's pages (read-only: a step that
        # wrote into the source would be a bug), the others the reader's own
        assert value.flags.writeable == (key not in container._MAPPED), key


def test_a_mapped_member_still_fails_its_crc(march_npz, tmp_path, mapped_everything):
    with zipfile.ZipFile(io.BytesIO(march_npz)) as zf:
        info = zf.getinfo("source.channels.npy")
    assert info.compress_type == zipfile.ZIP_STORED
    b = bytearray(march_npz)
    b[info.header_offset + 30 + len(info.filename) + info.file_size - 3] ^= 0x10  # in the last value
    path = tmp_path / "bad.stag"
    path.write_bytes(bytes(b))
    with open(path, "rb") as fh, pytest.raises(DataError) as err:
        parse_document(fh, NAME)
    assert "corrupt NPZ document" in str(err.value) and "CRC" in str(err.value)
    one_line_error(_run("info", path), 1, "bad.stag", "CRC")


def test_checked_source_pages_leave_memory(march_npz, tmp_path, mapped_everything):
    """After reading, the mapped channels take (almost) no memory: the
    checks touched every page and released it; using them brings them back."""
    from staggered_cli.cli.common import read_document

    path = tmp_path / "rss.stag"
    path.write_bytes(march_npz)
    doc = read_document(str(path))
    after_read = _mapping_rss_kb(path)
    if after_read is None:
        pytest.skip("no /proc/self/smaps")
    channel_kb = doc.source.channels.nbytes // 1024
    assert channel_kb >= 40  # the measure below can tell
    assert after_read <= 16, after_read  # a few pages at the ends of members
    assert float(np.sum(doc.source.channels)) == pytest.approx(float(np.sum(np.array(doc.source.channels))))
    assert _mapping_rss_kb(path) >= channel_kb - 8


def test_a_step_writes_over_its_own_mapped_input(march_npz, tmp_path, mapped_everything):
    """``cull doc -o doc --force`` reads the source's arrays from the file
    it replaces (a new file renamed over it): the result is the same as
    written elsewhere, and reads back."""
    a, b = tmp_path / "a.stag", tmp_path / "b.stag"
    a.write_bytes(march_npz)
    assert _run("cull", "--keep", "50%", a, "-o", b).exit_code == 0
    result = _run("cull", "--keep", "50%", a, "-o", a, "--force")
    assert result.exit_code == 0, result.stderr
    assert a.read_bytes() == b.read_bytes()
    assert _run("bake", a, "-o", tmp_path / "a.bvh").exit_code == 0


def test_a_file_that_cannot_be_mapped_is_read(march_npz, tmp_path, mapped_everything, monkeypatch):
    class Unmappable:  # a file system without mappings
        madvise = None

        def __init__(self, *args, **kwargs):
            raise OSError("no mappings here")

    monkeypatch.setattr(container.mmap, "mmap", Unmappable)
    path = tmp_path / "m.stag"
    path.write_bytes(march_npz)
    _, from_bytes = parse_document(march_npz, NAME)
    with open(path, "rb") as fh:
        _, from_file = parse_document(fh, NAME)
    for key, value in from_file.items():
        np.testing.assert_array_equal(value, from_bytes[key], err_msg=key)
        assert value.flags.writeable, key  # read, not mapped
