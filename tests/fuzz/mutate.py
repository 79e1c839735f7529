"""Mutations of real BVH, C3D and staggered-pose documents.

Every mutation is a pure function ``(base, rng) -> Case``: ``base`` is the
parsed view of a real file (cached, computed once), ``rng`` a
``random.Random`` seeded by hypothesis, so that a failing case is
reproduced by its seed.  A :class:`Case` says whether the mutation *must* be
refused (``strict``: a truncated file, a NaN, a wrong count...) or may also
be a valid file (``strict=False``: a flipped byte in a float may give another
valid number, a duplicated ``JOINT`` keyword gives a joint named "JOINT Hips").
Either way the tool must answer with exit 0 or a one-line error, never a
traceback.
"""

from __future__ import annotations

import copy
import io
import random
import re
import struct
import zipfile
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import numpy as np

from staggered_cli.io.schema import DOCUMENT_VERSION


@dataclass(frozen=True)
class Case:
    kind: str  # the mutation's name, for the per-kind counts
    data: bytes
    strict: bool  # the tool must refuse it (exit 1 or 2)


# ---------------------------------------------------------------------------- BVH

_TOKEN = re.compile(rb"[{}]|[^\s{}]+")
_CHANNEL_NAMES = (b"Xposition", b"Yposition", b"Zposition", b"Xrotation", b"Yrotation", b"Zrotation")


@dataclass(frozen=True)
class BvhBase:
    data: bytes
    motion_at: int  # byte offset of the MOTION line
    header_tokens: tuple[tuple[int, int, str], ...]  # (start, end, role)
    frames_line: tuple[int, int]  # span of the 'Frames:' line (without its newline)
    ftime_line: tuple[int, int]
    body_at: int  # first byte of the frame data
    value_spans: np.ndarray  # (N, 2) spans of the MOTION values
    line_starts: np.ndarray  # byte offsets of the frame lines
    n_frames: int
    n_channels: int


@cache
def bvh_base(path: Path) -> BvhBase:
    data = Path(path).read_bytes()
    m = re.search(rb"(?m)^[ \t]*MOTION[ \t]*\r?$", data)
    assert m is not None, path
    motion_at = m.start()
    tokens = []
    prev = b""
    before_prev = b""
    for t in _TOKEN.finditer(data, 0, motion_at):
        tok = t.group()
        if tok in (b"{", b"}"):
            role = "brace"
        elif prev in (b"ROOT", b"JOINT"):
            role = "name"
        elif tok in (b"HIERARCHY", b"ROOT", b"JOINT", b"End", b"Site", b"OFFSET", b"CHANNELS"):
            role = tok.decode().lower()
        elif prev == b"CHANNELS":
            role = "count"
        elif tok in _CHANNEL_NAMES:
            role = "channel"
        else:
            role = "number"
        tokens.append((t.start(), t.end(), role))
        before_prev, prev = prev, tok
    del before_prev
    lines = list(re.finditer(rb"[^\r\n]*(\r\n|\n|\r)?", data[motion_at:]))
    spans = [(motion_at + ln.start(), motion_at + ln.end()) for ln in lines[:3]]
    frames_line = (spans[1][0], spans[1][0] + len(lines[1].group().rstrip(b"\r\n")))
    ftime_line = (spans[2][0], spans[2][0] + len(lines[2].group().rstrip(b"\r\n")))
    body_at = spans[2][1]
    value_spans = np.array([(v.start(), v.end()) for v in re.finditer(rb"\S+", data[body_at:])]) + body_at
    line_starts = np.array(
        [body_at + ln.start() for ln in re.finditer(rb"[^\r\n]+", data[body_at:]) if ln.group().strip()]
    )
    n_frames = int(re.search(rb"\d+", data[frames_line[0] : frames_line[1]]).group())
    n_channels = len(value_spans) // n_frames
    assert n_channels * n_frames == len(value_spans) and len(line_starts) == n_frames, path
    return BvhBase(
        data, motion_at, tuple(tokens), frames_line, ftime_line, body_at, value_spans, line_starts, n_frames, n_channels
    )


def _splice(data: bytes, start: int, end: int, new: bytes) -> bytes:
    return data[:start] + new + data[end:]


def bvh_truncate(b: BvhBase, rng: random.Random) -> Case:
    # any cut that loses a non-blank byte (a cut within the trailing newline
    # leaves the same file)
    stop = len(b.data.rstrip())
    where = rng.choice(["header", "motion", "last line", "anywhere"])
    if where == "header":
        p = rng.randrange(0, b.body_at)
    elif where == "motion":
        p = rng.randrange(b.body_at, stop)
    elif where == "last line":
        p = rng.randrange(int(b.line_starts[-1]), stop)
    else:
        p = rng.randrange(0, stop)
    return Case(f"truncate:{where}", b.data[:p], True)


# roles whose deletion / duplication can never leave a valid file
_STRICT_DELETE = {
    "brace",
    "name",
    "hierarchy",
    "root",
    "joint",
    "end",
    "site",
    "offset",
    "channels",
    "count",
    "channel",
    "number",
}
_STRICT_DUPLICATE = {"brace", "hierarchy", "end", "site", "offset", "channels", "count", "channel", "number"}


def bvh_delete_token(b: BvhBase, rng: random.Random) -> Case:
    start, end, role = rng.choice(b.header_tokens)
    return Case(f"delete:{role}", _splice(b.data, start, end, b""), role in _STRICT_DELETE)


def bvh_duplicate_token(b: BvhBase, rng: random.Random) -> Case:
    start, end, role = rng.choice(b.header_tokens)
    tok = b.data[start:end]
    return Case(f"duplicate:{role}", _splice(b.data, end, end, b" " + tok), role in _STRICT_DUPLICATE)


def bvh_unbalanced_brace(b: BvhBase, rng: random.Random) -> Case:
    braces = [t for t in b.header_tokens if t[2] == "brace"]
    action = rng.choice(["drop", "extra-open", "extra-close"])
    if action == "drop":
        start, end, _ = rng.choice(braces)
        return Case("braces:drop", _splice(b.data, start, end, b""), True)
    start, _, _ = rng.choice(b.header_tokens[1:])
    brace = b"{" if action == "extra-open" else b"}"
    # a '}' inserted in the middle of a joint's name line would be part of the name
    strict = True
    return Case(f"braces:{action}", _splice(b.data, start, start, brace + b" "), strict)


_NON_NUMERIC = [
    b"abc",
    b"1.2.3",
    b"0x10",
    b"--1",
    b"1,5",
    b"e5",
    b"1e",
    b".",
    b"-",
    b"+",
    b"1_000",
    b"1d3",
    b"NULL",
    b"#",
    b"12a",
    b"\xc3\xa9",
    b"\x00",
    b"\xff\xfe",
    b"1\x002",
]
_NON_FINITE = [b"nan", b"NaN", b"-nan", b"inf", b"-inf", b"Infinity", b"+inf", b"1e999", b"-1e400", b"INF"]
_HUGE = [b"1e300", b"-1e200", b"1e13", b"9e307", b"-1.7976931348623157e308"]


def bvh_bad_value(b: BvhBase, rng: random.Random) -> Case:
    i = rng.randrange(len(b.value_spans))
    start, end = (int(x) for x in b.value_spans[i])
    pool = rng.choice(["non-numeric", "non-finite", "huge", "huge-offset"])
    if pool == "huge-offset":  # in the HIERARCHY
        start, end, _ = rng.choice([t for t in b.header_tokens if t[2] == "number"])
        return Case("value:huge-offset", _splice(b.data, start, end, rng.choice(_HUGE + [b"1e999"])), True)
    new = rng.choice({"non-numeric": _NON_NUMERIC, "non-finite": _NON_FINITE, "huge": _HUGE}[pool])
    return Case(f"value:{pool}", _splice(b.data, start, end, new), True)


def bvh_channel_count(b: BvhBase, rng: random.Random) -> Case:
    action = rng.choice(["drop-value", "extra-value", "drop-channel", "extra-channel", "count-only"])
    data = b.data
    if action == "drop-value":
        start, end = (int(x) for x in b.value_spans[rng.randrange(len(b.value_spans))])
        return Case("channels:drop-value", _splice(data, start, end, b""), True)
    if action == "extra-value":
        _, end = (int(x) for x in b.value_spans[rng.randrange(len(b.value_spans))])
        return Case("channels:extra-value", _splice(data, end, end, b" 1.0"), True)
    # the CHANNELS lines of the header
    lines = list(re.finditer(rb"CHANNELS[ \t]+(\d+)([^\r\n]*)", data[: b.motion_at]))
    m = rng.choice(lines)
    n = int(m.group(1))
    names = m.group(2).split()
    if action == "drop-channel" and n > 1:
        k = rng.randrange(n)
        new = b"CHANNELS %d %s" % (n - 1, b" ".join(names[:k] + names[k + 1 :]))
    elif action == "extra-channel" and n < 6:
        missing = [c for c in _CHANNEL_NAMES if c not in names]
        new = b"CHANNELS %d %s" % (n + 1, b" ".join(names + [rng.choice(missing)]))
    else:
        action = "count-only"
        new = b"CHANNELS %d %s" % (rng.choice([x for x in range(0, 7) if x != n]), b" ".join(names))
    return Case(f"channels:{action}", _splice(data, m.start(), m.end(), new), True)


def bvh_frames_claim(b: BvhBase, rng: random.Random) -> Case:
    T = b.n_frames
    choices = [
        b"0",
        b"1",
        b"100000000",
        b"-5",
        b"abc",
        b"1e3",
        b"%d" % (T + 1),
        b"%d" % (T - 1),
        b"99999999999999999999",
        b"",
        b"3.5",
    ]
    new = rng.choice([c for c in choices if c != b"%d" % T])
    s, e = b.frames_line
    return Case(f"frames:{new.decode(errors='replace')[:9]}", _splice(b.data, s, e, b"Frames: " + new), True)


def bvh_frame_time(b: BvhBase, rng: random.Random) -> Case:
    new = rng.choice([b"0", b"-0.0333", b"nan", b"inf", b"abc", b"", b"0x1p-5", b"1e-400"])
    s, e = b.ftime_line
    return Case("frame-time", _splice(b.data, s, e, b"Frame Time: " + new), True)


def bvh_garbage(b: BvhBase, rng: random.Random) -> Case:
    where = rng.choice(["whole", "motion", "header"])
    n = rng.randrange(1, 300)
    junk = bytes(rng.randrange(256) for _ in range(n))
    if where == "whole":
        # anything but a file that happens to start like a document or a C3D
        return Case("garbage:whole", b"\x00" + junk, True)
    if where == "motion":
        junk = junk + b"\xff"  # at least one byte that is not ASCII text
        p = rng.randrange(b.body_at, len(b.data))
        return Case("garbage:motion", _splice(b.data, p, min(p + n, len(b.data)), junk), True)
    p = rng.randrange(len(b"HIERARCHY"), b.motion_at)
    # binary bytes in the header may still decode as UTF-8 in a joint name
    return Case("garbage:header", _splice(b.data, p, min(p + n, b.motion_at), junk), False)


def bvh_encoding(b: BvhBase, rng: random.Random) -> Case:
    enc = rng.choice(["utf-16", "utf-16-le-bom", "utf-16-be-bom", "utf-32", "utf-16-no-bom", "utf-8-bom", "crlf", "cr"])
    text = b.data.decode("ascii")
    if enc == "utf-16":
        return Case("encoding:utf-16", text.encode("utf-16"), True)
    if enc == "utf-16-le-bom":
        return Case("encoding:utf-16-le-bom", b"\xff\xfe" + text.encode("utf-16-le"), True)
    if enc == "utf-16-be-bom":
        return Case("encoding:utf-16-be-bom", b"\xfe\xff" + text.encode("utf-16-be"), True)
    if enc == "utf-32":
        return Case("encoding:utf-32", text.encode("utf-32"), True)
    if enc == "utf-16-no-bom":
        return Case("encoding:utf-16-no-bom", text.encode("utf-16-le"), True)
    # valid variants: a UTF-8 BOM and other line endings are read as usual
    if enc == "utf-8-bom":
        return Case("encoding:utf-8-bom", b"\xef\xbb\xbf" + b.data, False)
    unix = b.data.replace(b"\r\n", b"\n")
    return Case(f"encoding:{enc}", unix.replace(b"\n", b"\r\n" if enc == "crlf" else b"\r"), False)


_BAD_CHANNELS = [b"Wrotation", b"xrotation", b"XRotation", b"Xrot", b"Xposition2", b"rotation", b"Ztranslation"]


def bvh_unknown_channel(b: BvhBase, rng: random.Random) -> Case:
    start, end, _ = rng.choice([t for t in b.header_tokens if t[2] == "channel"])
    return Case("unknown-channel", _splice(b.data, start, end, rng.choice(_BAD_CHANNELS)), True)


def bvh_duplicate_joint(b: BvhBase, rng: random.Random) -> Case:
    names = [t for t in b.header_tokens if t[2] == "name"]
    (s1, e1, _), (s2, e2, _) = rng.sample(names, 2)
    new = b.data[s1:e1]
    return Case("duplicate-joint", _splice(b.data, s2, e2, new), True)


BVH_MUTATIONS = (
    bvh_truncate,
    bvh_delete_token,
    bvh_duplicate_token,
    bvh_unbalanced_brace,
    bvh_bad_value,
    bvh_channel_count,
    bvh_frames_claim,
    bvh_frame_time,
    bvh_garbage,
    bvh_encoding,
    bvh_unknown_channel,
    bvh_duplicate_joint,
)


# ---------------------------------------------------------------------------- C3D


@dataclass(frozen=True)
class C3dBase:
    data: bytes
    processor: int
    parameters: dict  # 'GROUP:NAME' -> (offset of the first value, type, count)
    parameter_at: int
    data_at: int
    data_end: int  # end of the declared frames
    n_points: int
    n_frames: int
    stride: int  # values per frame
    value_bytes: int


def _c3d_parameters(raw: bytes, offset: int) -> dict[str, tuple[int, int, int, int]]:
    """'GROUP:NAME' -> (record start, offset of the first value, type, count), Intel files only."""
    groups: dict[int, str] = {}
    found = []
    pos = offset + 4
    while pos + 2 <= len(raw):
        n = abs(struct.unpack_from("b", raw, pos)[0])
        ident = struct.unpack_from("b", raw, pos + 1)[0]
        if n == 0 or ident == 0:
            break
        name = raw[pos + 2 : pos + 2 + n].decode("latin-1")
        step = struct.unpack_from("<H", raw, pos + 2 + n)[0]
        body = pos + 4 + n
        if ident < 0:
            groups[-ident] = name
        else:
            ptype, ndims = struct.unpack_from("b", raw, body)[0], raw[body + 1]
            count = int(np.prod(list(raw[body + 2 : body + 2 + ndims]))) if ndims else 1
            found.append((ident, name, pos, body + 2 + ndims, ptype, count))
        if step == 0:
            break
        pos = pos + 2 + n + step
    return {f"{groups.get(g, '?')}:{name}": (rec, at, ptype, count) for g, name, rec, at, ptype, count in found}


@cache
def c3d_base(path: Path) -> C3dBase:
    return c3d_base_of(Path(path).read_bytes(), str(path))


@cache
def c3d_base_of(raw: bytes, name: str = "c3d") -> C3dBase:
    """The parsed view of the C3D bytes ``raw``."""
    from staggered_cli.io.c3d import _check_layout

    layout = _check_layout(raw, name)
    assert layout.processor == 84, "the mutations assume Intel C3D files"
    stride = 4 * layout.n_points + layout.n_analogs * layout.analog_per_frame
    end = layout.data_offset + layout.n_frames * stride * layout.value_bytes
    param_at = (raw[0] - 1) * 512
    return C3dBase(
        raw,
        layout.processor,
        _c3d_parameters(raw, param_at),
        param_at,
        layout.data_offset,
        end,
        layout.n_points,
        layout.n_frames,
        stride,
        layout.value_bytes,
    )


def _set_word(data: bytes, word: int, value: int) -> bytes:
    return _splice(data, 2 * word, 2 * word + 2, struct.pack("<H", value & 0xFFFF))


def _set_parameter(b: C3dBase, data: bytes, key: str, value: float) -> bytes:
    _, at, ptype, _ = b.parameters[key]
    if ptype == 4:
        return _splice(data, at, at + 4, struct.pack("<f", value))
    if ptype == 2:
        return _splice(data, at, at + 2, struct.pack("<h", int(value)))
    return _splice(data, at, at + 1, bytes([int(value) & 0xFF]))


def c3d_truncate(b: C3dBase, rng: random.Random) -> Case:
    where = rng.choice(["header", "parameters", "data", "anywhere"])
    lo, hi = {
        "header": (0, 512),
        "parameters": (512, b.data_at),
        "data": (b.data_at, b.data_end),
        "anywhere": (0, b.data_end),
    }[where]
    return Case(f"truncate:{where}", b.data[: rng.randrange(lo, hi)], True)


def c3d_frames_claim(b: C3dBase, rng: random.Random) -> Case:
    claim = rng.choice([b.n_frames + 1, 2 * b.n_frames, 32767, 65535, 10**8 + 1, 10**9])
    # one more frame may still fit in the padding of the last 512-byte block
    strict = claim * b.stride * b.value_bytes > len(b.data) - b.data_at
    data = b.data
    if "POINT:FRAMES" in b.parameters and b.parameters["POINT:FRAMES"][1] == 2 and claim < 65536:
        value = claim - 65536 if claim > 32767 else claim
        return Case("frames:POINT:FRAMES", _set_parameter(b, data, "POINT:FRAMES", value), strict)
    # a huge count the old way: POINT:FRAMES 0 (header range) and LONG_FRAMES / TRIAL fields
    first = struct.unpack_from("<H", data, 6)[0] or 1
    data = _set_word(data, 4, min(first + claim - 1, 65535))
    if "POINT:FRAMES" in b.parameters:
        data = _set_parameter(b, data, "POINT:FRAMES", 0)
    return Case("frames:header", data, strict)


def c3d_sizes(b: C3dBase, rng: random.Random) -> Case:
    """POINT:USED / ANALOG:USED / header counts that disagree with the data."""
    action = rng.choice(["point-used", "header-points", "analog-used", "data-start", "parameter-block"])
    data = b.data
    if action == "point-used":
        value = rng.choice([b.n_points + 1, b.n_points + 100, 32767, 0, -1])
        return Case("sizes:point-used", _set_parameter(b, data, "POINT:USED", value), value > b.n_points or value < 0)
    if action == "header-points":
        return Case("sizes:header-points", _set_word(data, 1, rng.choice([0, b.n_points + 3, 65535])), False)
    if action == "analog-used" and "ANALOG:USED" in b.parameters:
        return Case("sizes:analog-used", _set_parameter(b, data, "ANALOG:USED", rng.choice([1, 64, 32767, -3])), False)
    if action == "data-start":
        block = rng.choice([0, 1, 2, len(data) // 512 + 1, 65535])
        return Case("sizes:data-start", _set_word(data, 8, block), block in (0, 1) or block > len(data) // 512)
    block = rng.choice([0, 1, 255, b.data_at // 512 + 1])
    return Case("sizes:parameter-block", bytes([block]) + data[1:], block in (0, 1, 255))


def c3d_key_processor(b: C3dBase, rng: random.Random) -> Case:
    if rng.random() < 0.5:
        return Case(
            "key-byte", data=b.data[:1] + bytes([rng.choice([0x00, 0x51, 0xFF, 0x4F])]) + b.data[2:], strict=True
        )
    at = b.parameter_at + 3
    return Case("processor", _splice(b.data, at, at + 1, bytes([rng.choice([0, 83, 87, 255])])), True)


def c3d_flip(b: C3dBase, rng: random.Random) -> Case:
    """Random bytes changed in one region: may be valid, must not crash."""
    where = rng.choice(["header", "parameters", "data"])
    lo, hi = {"header": (2, 512), "parameters": (b.parameter_at, b.data_at), "data": (b.data_at, b.data_end)}[where]
    data = bytearray(b.data)
    for _ in range(rng.randrange(1, 9)):
        data[rng.randrange(lo, hi)] = rng.randrange(256)
    return Case(f"flip:{where}", bytes(data), False)


def c3d_parameter_record(b: C3dBase, rng: random.Random) -> Case:
    """A corrupt parameter record: name length, offset to the next, type, dimensions."""
    key = rng.choice(sorted(b.parameters))
    rec, at, _, _ = b.parameters[key]
    data = bytearray(b.data)
    n = abs(struct.unpack_from("b", data, rec)[0])
    body = rec + 4 + n
    ndims = data[body + 1]
    field = rng.choice(["name-length", "offset", "type", "ndims", "dim", "description"])
    if field == "name-length":
        data[rec] = rng.choice([0x7F, 0x80, 0xFF, n + 1])
    elif field == "offset":
        data[rec + 2 + n : rec + 4 + n] = struct.pack("<H", rng.choice([1, 2, 3, 0xFFFF, 0x8000]))
    elif field == "type":
        data[body] = rng.choice([0, 3, 5, 0x80, 0xFF])
    elif field == "ndims":
        data[body + 1] = rng.choice([7, 100, 128, 200, 255])
    elif field == "dim" and ndims:
        data[body + 2 + rng.randrange(ndims)] = rng.choice([0, 255])
    else:
        field = "description"
        desc_at = at + {-1: 1, 1: 1, 2: 2, 4: 4}.get(struct.unpack_from("b", data, body)[0], 1) * b.parameters[key][3]
        if desc_at < len(data):
            data[desc_at] = rng.choice([0x7F, 0x80, 0xFF])
    return Case(f"record:{field}", bytes(data), False)


def c3d_missing_marker(b: C3dBase, rng: random.Random) -> Case:
    """One marker missing (residual -1, coordinates 0) in every frame: a valid file."""
    return Case("missing-marker", c3d_without_marker(b, rng.randrange(b.n_points)), False)


def c3d_without_marker(b: C3dBase, m: int) -> bytes:
    """``b`` with marker ``m`` missing (residual -1, coordinates 0) in every frame."""
    data = bytearray(b.data)
    vb = b.value_bytes
    sample = struct.pack("<4f", 0.0, 0.0, 0.0, -1.0) if vb == 4 else struct.pack("<4h", 0, 0, 0, -1)
    for f in range(b.n_frames):
        at = b.data_at + (f * b.stride + 4 * m) * vb
        data[at : at + 4 * vb] = sample
    return bytes(data)


def c3d_bad_values(b: C3dBase, rng: random.Random) -> Case:
    """NaN / inf coordinates in valid samples: read as missing."""
    data = bytearray(b.data)
    for _ in range(rng.randrange(1, 20)):
        f, m, c = rng.randrange(b.n_frames), rng.randrange(b.n_points), rng.randrange(4)
        at = b.data_at + (f * b.stride + 4 * m + c) * b.value_bytes
        if b.value_bytes == 4:
            data[at : at + 4] = struct.pack("<f", rng.choice([float("nan"), float("inf"), -float("inf"), 3e38, 1e13]))
        else:  # integer C3D: extreme values
            data[at : at + 2] = struct.pack("<h", rng.choice([32767, -32768, -1]))
    return Case("values:non-finite", bytes(data), False)


def c3d_garbage(b: C3dBase, rng: random.Random) -> Case:
    n = rng.randrange(2, 4000)
    junk = bytearray(rng.randrange(256) for _ in range(n))
    junk[1] = 0x50  # looks like a C3D by its key byte
    junk[0] = rng.choice([0, 1, 2, 200])
    return Case("garbage:whole", bytes(junk), True)


def c3d_appended(b: C3dBase, rng: random.Random) -> Case:
    junk = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 2000)))
    return Case("garbage:appended", b.data + junk, False)


# ----------------------------------------------- C3D parameter-level edits
#
# A parameter section rebuilt record by record (Intel files): a parameter's
# type code, dimensions and values replaced, then every "offset to the next
# record" recomputed and the section grown by whole blocks when it must be
# (the data block moves; the header's data-start word and POINT:DATA_START
# follow).  Each edit is what another program could have written, so the
# file stays structurally sound: only the parameter itself is hostile.

#: C3D type code -> bytes per value
TYPE_BYTES = {-1: 1, 1: 1, 2: 2, 4: 4}


@dataclass
class Record:
    name_len: int  # the signed byte as stored (negative: locked)
    ident: int  # negative: a group; positive: a parameter of group ``ident``
    name: bytes
    body: bytes  # everything after the offset word, up to the next record

    def split(self) -> tuple[int, tuple[int, ...], bytes, bytes]:
        """A parameter's (type, dims, values, description part)."""
        ptype = struct.unpack_from("b", self.body, 0)[0]
        ndims = self.body[1]
        dims = tuple(self.body[2 : 2 + ndims])
        count = int(np.prod(dims)) if dims else 1
        start = 2 + ndims
        stop = start + count * TYPE_BYTES[ptype]
        return ptype, dims, self.body[start:stop], self.body[stop:]


def c3d_records(raw: bytes) -> tuple[int, list[Record]]:
    """(byte offset of the parameter section, its records in file order)."""
    offset = (raw[0] - 1) * 512
    pos = offset + 4
    records = []
    while pos + 2 <= len(raw):
        n = struct.unpack_from("b", raw, pos)[0]
        ident = struct.unpack_from("b", raw, pos + 1)[0]
        if n == 0 or ident == 0:
            break
        name = raw[pos + 2 : pos + 2 + abs(n)]
        step = struct.unpack_from("<H", raw, pos + 2 + abs(n))[0]
        body_at = pos + 4 + abs(n)
        end = pos + 2 + abs(n) + step if step else len(raw)
        if step == 0:  # the last record: its body ends with its description
            desc_len_at = _body_end(raw, body_at, ident)
            end = desc_len_at
        records.append(Record(n, ident, name, raw[body_at:end]))
        if step == 0:
            break
        pos = pos + 2 + abs(n) + step
    return offset, records


def _body_end(raw: bytes, at: int, ident: int) -> int:
    if ident < 0:
        return at + 1 + raw[at]
    ptype, ndims = struct.unpack_from("b", raw, at)[0], raw[at + 1]
    dims = raw[at + 2 : at + 2 + ndims]
    count = int(np.prod(list(dims))) if ndims else 1
    stop = at + 2 + ndims + count * TYPE_BYTES[ptype]
    return stop + 1 + raw[stop]


def c3d_rebuild(raw: bytes, records: list[Record]) -> bytes:
    """``raw`` with its parameter section made of ``records``."""
    offset = (raw[0] - 1) * 512
    section = bytearray(raw[offset : offset + 4])
    for r in records:
        section += struct.pack("bb", r.name_len, r.ident) + r.name + struct.pack("<H", 2 + len(r.body)) + r.body
    section += b"\x00\x00"  # end mark: a record without a name
    data_block = struct.unpack_from("<H", raw, 16)[0]
    have = data_block - raw[0]
    need = -(-len(section) // 512)
    grow = max(0, need - have)
    section += bytes((have + grow) * 512 - len(section))
    section[2] = have + grow
    out = bytearray(raw[:offset]) + section + raw[(data_block - 1) * 512 :]
    if grow:
        out[16:18] = struct.pack("<H", data_block + grow)
        out = bytearray(_shift_data_start(bytes(out), grow))
    return bytes(out)


def _shift_data_start(raw: bytes, grow: int) -> bytes:
    offset, records = c3d_records(raw)
    groups = {-r.ident: r.name.decode("latin-1") for r in records if r.ident < 0}
    pos = offset + 4
    out = bytearray(raw)
    for r in records:
        head = 4 + abs(r.name_len)
        if r.ident > 0 and groups.get(r.ident) in ("POINT", "ROTATION") and r.name == b"DATA_START":
            ptype, dims, values, _ = r.split()
            if ptype == 2 and values:
                at = pos + head + 2 + len(dims)
                out[at : at + 2] = struct.pack("<h", struct.unpack_from("<h", values)[0] + grow)
        pos += head + len(r.body)
    return bytes(out)


def c3d_set_parameter(
    raw: bytes,
    key: str,
    *,
    ptype: int | None = None,
    dims: tuple[int, ...] | None = None,
    values: bytes | None = None,
) -> bytes:
    """``raw`` with parameter ``key`` ('GROUP:NAME') given a new type code,
    dimensions and value bytes (each kept when None)."""
    offset, records = c3d_records(raw)
    group, name = key.split(":")
    gid = next(-r.ident for r in records if r.ident < 0 and r.name.decode("latin-1") == group)
    for r in records:
        if r.ident == gid and r.name.decode("latin-1") == name:
            old_type, old_dims, old_values, rest = r.split()
            ptype = old_type if ptype is None else ptype
            dims = old_dims if dims is None else dims
            values = old_values if values is None else values
            r.body = struct.pack("bB", ptype, len(dims)) + bytes(dims) + values + rest
            return c3d_rebuild(raw, records)
    raise KeyError(key)


def c3d_parameter(raw: bytes, key: str) -> tuple[int, tuple[int, ...], bytes]:
    """(type, dims, value bytes) of parameter ``key`` of ``raw``."""
    _, records = c3d_records(raw)
    group, name = key.split(":")
    gid = next(-r.ident for r in records if r.ident < 0 and r.name.decode("latin-1") == group)
    for r in records:
        if r.ident == gid and r.name.decode("latin-1") == name:
            return r.split()[:3]
    raise KeyError(key)


def encode_values(ptype: int, numbers) -> bytes:
    """Values of C3D type ``ptype`` as bytes (char: ``numbers`` are bytes)."""
    if ptype == -1:
        return bytes(numbers)
    fmt = {1: "B", 2: "h", 4: "f"}[ptype]
    return struct.pack(f"<{len(numbers)}{fmt}", *numbers)


#: Parameters ezc3d reads (as C3D types), the ones each base file holds
#: decide which are mutated.
READ_PARAMETERS = (
    "POINT:USED",
    "POINT:FRAMES",
    "POINT:SCALE",
    "POINT:RATE",
    "POINT:DATA_START",
    "POINT:LABELS",
    "POINT:DESCRIPTIONS",
    "POINT:UNITS",
    "ANALOG:USED",
    "ANALOG:RATE",
    "ANALOG:GEN_SCALE",
    "ANALOG:SCALE",
    "ANALOG:OFFSET",
    "ANALOG:LABELS",
    "ANALOG:UNITS",
    "TRIAL:ACTUAL_START_FIELD",
    "TRIAL:ACTUAL_END_FIELD",
    "ROTATION:USED",
    "ROTATION:DATA_START",
    "ROTATION:RATE",
    "ROTATION:RATIO",
)
#: Parameters read as one number: an empty array of them is fatal to ezc3d.
SCALAR_PARAMETERS = {
    "POINT:USED",
    "POINT:FRAMES",
    "POINT:SCALE",
    "POINT:RATE",
    "POINT:DATA_START",
    "ANALOG:USED",
    "ANALOG:RATE",
    "ANALOG:GEN_SCALE",
    "ROTATION:USED",
    "ROTATION:DATA_START",
    "ROTATION:RATE",
    "ROTATION:RATIO",
}


def _read_keys(b: C3dBase) -> list[str]:
    return [k for k in READ_PARAMETERS if k in b.parameters]


def c3d_parameter_type(b: C3dBase, rng: random.Random) -> Case:
    """A parameter ezc3d reads given another type code, its bytes reinterpreted.

    Always refused: ezc3d would read the values as another type (or not at all).
    """
    key = rng.choice(_read_keys(b))
    ptype, dims, values = c3d_parameter(b.data, key)
    new = rng.choice([t for t in (-1, 1, 2, 4) if t != ptype and not (ptype in (1, 2) and t in (1, 2))])
    count = int(np.prod(dims)) if dims else 1
    size = count * TYPE_BYTES[new]
    values = (values * (1 + size // max(len(values), 1)))[:size] if values else bytes(size)
    if new == -1 and not dims:
        dims = (len(values),)
    return Case(f"param-type:{key}", c3d_set_parameter(b.data, key, ptype=new, dims=dims, values=values), True)


def c3d_parameter_count(b: C3dBase, rng: random.Random) -> Case:
    """A parameter ezc3d reads with no value (an empty array), with one more
    value, or as a matrix of the same values.

    No value is refused where ezc3d reads one number; more values may be harmless.
    """
    key = rng.choice(_read_keys(b))
    ptype, dims, values = c3d_parameter(b.data, key)
    action = rng.choice(["empty", "empty", "more", "matrix"])
    if action == "empty":
        new_dims = (dims[:-1] + (0,)) if len(dims) > 1 else (0,)
        data = c3d_set_parameter(b.data, key, dims=new_dims, values=b"")
        return Case(f"param-count:empty:{key}", data, key in SCALAR_PARAMETERS)
    if action == "more" and (not dims or dims[-1] < 255):
        # one more entry along the last dimension, a copy of the last one
        new_dims = dims[:-1] + ((dims[-1] if dims else 1) + 1,)
        entry = (int(np.prod(dims[:-1])) if len(dims) > 1 else 1) * TYPE_BYTES[ptype]
        extra = values[-entry:] if values else bytes(entry)
        data = c3d_set_parameter(b.data, key, dims=new_dims, values=values + extra)
        return Case(f"param-count:more:{key}", data, False)
    # a scalar as a 1x1 matrix, a vector as an (n, 1) matrix: the same values
    new_dims = (dims or (1,)) + (1,)
    return Case(f"param-count:matrix:{key}", c3d_set_parameter(b.data, key, dims=new_dims, values=values), False)


def c3d_parameter_value(b: C3dBase, rng: random.Random) -> Case:
    """Numbers no capture holds in the parameters that size and time the data."""
    nan, inf = float("nan"), float("inf")
    choices = {  # key: (values, refused for sure)
        "POINT:RATE": ([0.0, -50.0, 1e30, nan, inf, 1e-30, 1e6], True),
        "POINT:SCALE": ([0.0, nan, inf], False),
        "POINT:USED": ([-1, -32768], True),
        "POINT:FRAMES": ([-1, 32767], False),
        "ANALOG:RATE": ([-1000.0, nan, 1e30], False),
        "ANALOG:GEN_SCALE": ([nan, inf, 0.0], False),
        "POINT:DATA_START": ([0, -1, 32767], False),
    }
    key = rng.choice([k for k in choices if k in b.parameters])
    pool, strict = choices[key]
    ptype, _, values = c3d_parameter(b.data, key)
    value = rng.choice(pool)
    if key == "POINT:RATE" and value == 0.0:
        strict = False  # ezc3d then takes the header's rate, which is valid
    if ptype != 4:
        value = int(value)
    new = encode_values(ptype, [value]) + values[TYPE_BYTES[ptype] :]
    return Case(f"param-value:{key}", c3d_set_parameter(b.data, key, values=new), strict)


def c3d_name_length(b: C3dBase, rng: random.Random) -> Case:
    """A record's name-length byte set to 0x80 (-128) or another wild value."""
    key = rng.choice(sorted(b.parameters))
    rec = b.parameters[key][0]
    data = bytearray(b.data)
    data[rec] = rng.choice([0x80, 0x81, 0xC0, 0x7F, 0x40])
    return Case("name-length", bytes(data), False)


C3D_MUTATIONS = (
    c3d_truncate,
    c3d_frames_claim,
    c3d_sizes,
    c3d_key_processor,
    c3d_flip,
    c3d_parameter_record,
    c3d_missing_marker,
    c3d_bad_values,
    c3d_garbage,
    c3d_appended,
    c3d_parameter_type,
    c3d_parameter_count,
    c3d_parameter_value,
    c3d_name_length,
)


# ---------------------------------------------------------------------- documents


@dataclass(frozen=True)
class DocBase:
    manifest: dict
    arrays: dict  # name -> ndarray (read-only by convention: mutations copy)
    npz: bytes
    json: bytes


def doc_base(npz: bytes) -> DocBase:
    from staggered_cli.io.container import document_bytes, parse_document

    manifest, arrays = parse_document(npz, "base")
    return DocBase(manifest, arrays, npz, document_bytes(manifest, arrays, "json"))


def _encode(manifest: dict, arrays: dict, fmt: str) -> bytes:
    from staggered_cli.io.container import document_bytes

    return document_bytes(manifest, arrays, fmt)


def _parts(b: DocBase) -> tuple[dict, dict]:
    return copy.deepcopy(b.manifest), {k: v.copy() for k, v in b.arrays.items()}


def _required_arrays(b: DocBase) -> list[str]:
    # signals are for pictures and source.bvh only keeps the file's text (both optional)
    names = [k for k in b.arrays if not k.startswith("signal.") and k != "source.bvh"]
    return sorted(names)


def doc_missing_array(b: DocBase, rng: random.Random, fmt: str) -> Case:
    manifest, arrays = _parts(b)
    del arrays[rng.choice(_required_arrays(b))]
    return Case("missing-array", _encode(manifest, arrays, fmt), True)


def doc_wrong_shape(b: DocBase, rng: random.Random, fmt: str) -> Case:
    manifest, arrays = _parts(b)
    key = rng.choice(_required_arrays(b))
    a = arrays[key]
    action = rng.choice(["drop-row", "extra-row", "add-axis", "flatten", "empty", "drop-column"])
    if action == "drop-row" and len(a):
        a = a[:-1]
    elif action == "extra-row" and len(a):
        a = np.concatenate([a, a[-1:]])
    elif action == "add-axis":
        a = a[..., None]
    elif action == "flatten" and a.ndim > 1:
        a = a.ravel()
    elif action == "drop-column" and a.ndim > 1 and a.shape[-1] > 1:
        a = a[..., :-1]
    else:
        action = "empty"
        a = a[:0]
    arrays[key] = a
    # source.c3d is the raw C3D: a shorter one is still a byte string
    strict = key != "source.c3d"
    return Case(f"shape:{action}", _encode(manifest, arrays, fmt), strict)


def _track_names(b: DocBase) -> list[int]:
    return [int(k[5:].split(".")[0]) for k in b.arrays if k.startswith("track") and k.endswith(".knot_t")]


def doc_crossing_knots(b: DocBase, rng: random.Random, fmt: str) -> Case:
    manifest, arrays = _parts(b)
    n = rng.choice(_track_names(b))
    ptr, kt = arrays[f"track{n}.layer0.knot_ptr"], arrays[f"track{n}.layer0.knot_t"].copy()
    var = rng.randrange(len(ptr) - 1)
    lo, hi = int(ptr[var]), int(ptr[var + 1])
    j = rng.randrange(lo, hi - 1)
    action = rng.choice(["swap", "equal", "past"])
    if action == "swap":
        kt[j], kt[j + 1] = kt[j + 1], kt[j]
    elif action == "equal":
        kt[j + 1] = kt[j]
    else:
        kt[j] = kt[j + 1] + rng.uniform(1e-6, 1.0)
    arrays[f"track{n}.layer0.knot_t"] = kt
    return Case(f"knots:{action}", _encode(manifest, arrays, fmt), True)


def doc_version(b: DocBase, rng: random.Random, fmt: str) -> Case:
    manifest, arrays = _parts(b)
    where = rng.choice(["manifest", "envelope"])
    value = rng.choice([0, DOCUMENT_VERSION + 1, 99, -1, "1", 1.0, None, True, [1]])
    if where == "manifest":
        manifest["version"] = value
        data = _encode(manifest, arrays, fmt)
    else:
        data = _set_envelope(_encode(manifest, arrays, fmt), "version", value)
    return Case(f"version:{where}", data, True)


def doc_format_name(b: DocBase, rng: random.Random, fmt: str) -> Case:
    manifest, arrays = _parts(b)
    value = rng.choice(["staggered-pose", "", None, 1, "STAGGERED-POSES"])
    if rng.random() < 0.5:
        manifest["format"] = value
        return Case("format:manifest", _encode(manifest, arrays, fmt), True)
    return Case("format:envelope", _set_envelope(_encode(manifest, arrays, fmt), "format", value), True)


def _set_envelope(data: bytes, key: str, value) -> bytes:
    """Change a key of the envelope (the outer JSON object) of document bytes."""
    import json

    if data[:2] == b"PK":
        zin = zipfile.ZipFile(io.BytesIO(data))
        out = io.BytesIO()
        with zipfile.ZipFile(out, "w") as zout:
            for info in zin.infolist():
                member = zin.read(info)
                if info.filename == "manifest.json":
                    env = json.loads(member)
                    env[key] = value
                    member = json.dumps(env).encode()
                zout.writestr(info, member)
        return out.getvalue()
    env = json.loads(data)
    env[key] = value
    return json.dumps(env).encode()


def doc_bad_values(b: DocBase, rng: random.Random, fmt: str) -> Case:
    """Non-finite or out-of-range values where they cannot be."""
    manifest, arrays = _parts(b)
    n = rng.choice(_track_names(b))
    key = rng.choice(
        [
            "pose_t",
            "priority",
            f"track{n}.layer0.knot_t",
            f"track{n}.layer0.knot_v",
            f"track{n}.layer0.tan_a",
            f"track{n}.layer0.samp_s",
            f"track{n}.layer0.samp_d",
            f"track{n}.layer0.knot_pose",
            f"track{n}.layer0.knot_ptr",
            f"track{n}.layer0.samp_ptr",
        ]
    )
    a = arrays[key].copy()
    if not a.size:
        return doc_missing_array(b, rng, fmt)
    flat = a.reshape(-1)
    i = rng.randrange(flat.size)
    if a.dtype.kind == "f":
        choices = [np.nan, np.inf, -np.inf, 1e300, -1e200]
        if key.endswith(("knot_v", "samp_d")) and _kinds(manifest, n) == "rotation":
            choices.append(flat[i] + 0.5)  # no longer a unit quaternion
        if key.endswith("samp_s"):
            choices += [-1.0, 1e9]
        flat[i] = rng.choice(choices)
        strict = key != "priority" or bool(np.isnan(flat[i]))
    else:
        flat[i] = rng.choice([-1, 10**6, -(2**40)])
        strict = True
    arrays[key] = a
    return Case(f"values:{key.split('.')[-1]}", _encode(manifest, arrays, fmt), strict)


def _kinds(manifest: dict, n: int) -> str:
    try:
        return str(manifest["tracks"][n]["kind"])
    except (KeyError, IndexError, TypeError):
        return ""


def doc_dtype(b: DocBase, rng: random.Random, fmt: str) -> Case:
    manifest, arrays = _parts(b)
    key = rng.choice(_required_arrays(b))
    a = arrays[key]
    target = rng.choice([np.float64, np.int64, np.bool_, np.uint8])
    if a.dtype == np.dtype(target):
        target = np.int64 if a.dtype.kind == "f" else np.float64
    with np.errstate(invalid="ignore"):
        arrays[key] = a.astype(target)
    # another integer kind that holds the same values is the same document
    strict = not (a.dtype.kind in "iu" and np.dtype(target).kind in "iu" and np.array_equal(arrays[key], a))
    return Case("dtype", _encode(manifest, arrays, fmt), strict)


def doc_manifest(b: DocBase, rng: random.Random, fmt: str) -> Case:
    """Missing or malformed manifest entries."""
    manifest, arrays = _parts(b)
    kind = manifest["source"]["kind"]
    paths = [
        ("frames",),
        ("frame_time",),
        ("source",),
        ("source", "kind"),
        ("tracks",),
        ("tracks", 0),
        ("tracks", 0, "names"),
        ("tracks", 0, "targets"),
        ("tracks", 0, "kind"),
        ("constraints",),
        ("parameters",),
        ("parameters", "contact_joints"),
        ("parameters", "min_contact"),
        ("parameters", "contact_tolerance"),
    ]
    if kind == "bvh":
        paths += [
            ("bvh",),
            ("bvh", "names"),
            ("bvh", "parents"),
            ("bvh", "offsets"),
            ("bvh", "channels"),
            ("bvh", "end_parents"),
            ("bvh", "frame_time"),
            ("bvh", "number_format"),
            ("bvh", "frame_time_text"),
            ("bvh", "channels", 0),
        ]
    else:
        paths += [("c3d",), ("c3d", "labels"), ("c3d", "rate")]
    path = rng.choice(paths)
    action = rng.choice(["delete", "null", "string", "negative", "huge", "nan-text", "list", "dict"])
    parent = manifest
    for p in path[:-1]:
        parent = parent[p]
    last = path[-1]
    optional = path == ("constraints",)
    if action == "delete":
        if isinstance(parent, list):
            parent.pop(last)
        else:
            del parent[last]
    else:
        parent[last] = {
            "null": None,
            "string": "x",
            "negative": -3,
            "huge": 10**12,
            "nan-text": "NaN",
            "list": [],
            "dict": {},
        }[action]
        if path == ("constraints",) and action == "list":
            optional = True
    strict = not optional
    if path == ("tracks", 0, "names") or path == ("c3d", "labels") or path == ("bvh", "names"):
        strict = True
    if path == ("parameters",):
        strict = False  # free-form: a document without them is read with none
    elif path[0] == "parameters":
        # absent is fine, and so are an empty joint list and a large tolerance
        strict = action not in ("delete", "list" if last == "contact_joints" else "huge")
    return Case(f"manifest:{'.'.join(map(str, path))}:{action}", _encode(manifest, arrays, fmt), strict)


def doc_references(b: DocBase, rng: random.Random, fmt: str) -> Case:
    """Names and indices that point nowhere: targets, parents, constraints."""
    manifest, arrays = _parts(b)
    action = rng.choice(
        ["target", "constraint-joint", "constraint-time", "parent", "names-dup", "track-kind", "tracks-swap", "frames"]
    )
    strict = True
    if action == "target":
        tr = manifest["tracks"][rng.randrange(len(manifest["tracks"]))]
        tr["targets"][rng.randrange(len(tr["targets"]))] = rng.choice([-1, 10_000, -(10**6)])
    elif action == "constraint-joint":
        manifest.setdefault("constraints", []).append({"joint": "NoSuchJoint", "start": 0.0, "end": 0.1})
    elif action == "constraint-time":
        manifest.setdefault("constraints", []).append(
            {"joint": _first_name(manifest), "start": rng.choice([1.0, -5.0, 1e9]), "end": rng.choice([0.0, -1e9])}
        )
    elif action == "parent" and "bvh" in manifest:
        parents = manifest["bvh"]["parents"]
        parents[rng.randrange(1, len(parents))] = rng.choice([len(parents), 10**6, -2])
    elif action == "names-dup":
        tr = manifest["tracks"][rng.randrange(len(manifest["tracks"]))]
        if len(tr["names"]) > 1:
            tr["names"][1] = tr["names"][0]
        else:
            tr["names"].append(tr["names"][0])
    elif action == "track-kind":
        tr = manifest["tracks"][rng.randrange(len(manifest["tracks"]))]
        tr["kind"] = "rotation" if tr["kind"] == "translation" else "translation"
    elif action == "tracks-swap" and len(manifest["tracks"]) > 1:
        manifest["tracks"].reverse()
    else:
        action = "frames"
        manifest["frames"] = manifest["frames"] + rng.choice([1, -1, 1000])
    return Case(f"refs:{action}", _encode(manifest, arrays, fmt), strict)


def _first_name(manifest: dict) -> str:
    if "bvh" in manifest:
        return manifest["bvh"]["names"][0]
    return manifest["c3d"]["labels"][0]


def doc_truncate(b: DocBase, rng: random.Random, fmt: str) -> Case:
    data = b.npz if fmt == "npz" else b.json
    stop = len(data) if fmt == "npz" else len(data.rstrip())
    return Case(f"truncate:{fmt}", data[: rng.randrange(0, stop)], True)


def doc_flip(b: DocBase, rng: random.Random, fmt: str) -> Case:
    data = bytearray(b.npz if fmt == "npz" else b.json)
    for _ in range(rng.randrange(1, 6)):
        data[rng.randrange(len(data))] = rng.randrange(256)
    return Case(f"flip:{fmt}", bytes(data), False)


def doc_garbage(b: DocBase, rng: random.Random, fmt: str) -> Case:
    junk = bytes(rng.randrange(256) for _ in range(rng.randrange(0, 500)))
    head = rng.choice([b"PK\x03\x04", b"PK\x05\x06", b"{", b"\xef\xbb\xbf{", b" \n{"])
    return Case("garbage", head + junk, True)


def doc_source_c3d(b: DocBase, rng: random.Random, fmt: str) -> Case:
    """The embedded source C3D of a C3D document given a parameter-level
    mutation (type, count, value, name length): what bake rewrites."""
    manifest, arrays = _parts(b)
    if manifest["source"]["kind"] != "c3d" or not arrays["source.c3d"].size:
        return doc_flip(b, rng, fmt)
    base = c3d_base_of(arrays["source.c3d"].tobytes(), "source.c3d")
    mutation = rng.choice([c3d_parameter_type, c3d_parameter_count, c3d_parameter_value, c3d_name_length])
    case = mutation(base, rng)
    arrays["source.c3d"] = np.frombuffer(case.data, np.uint8)
    return Case(f"source-c3d:{case.kind}", _encode(manifest, arrays, fmt), case.strict)


DOC_MUTATIONS = (
    doc_missing_array,
    doc_wrong_shape,
    doc_crossing_knots,
    doc_version,
    doc_format_name,
    doc_bad_values,
    doc_dtype,
    doc_manifest,
    doc_references,
    doc_truncate,
    doc_flip,
    doc_garbage,
    doc_source_c3d,
)
