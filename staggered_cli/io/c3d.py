"""C3D marker files: read to :class:`MarkerMotion`, write back with everything else kept.

ezc3d does the parsing and the writing; this module adds what a command-line
tool needs around it:

* a cheap pre-check of the header and of the few parameters that size the
  data block, *before* ezc3d sees the file.  ezc3d 1.7.2 reads frames until
  end of file without complaint, so a truncated file loads with missing or
  garbage last frames, and a file claiming 10^9 frames is taken at its word
  (header, loop bound); both are refused here with one line naming the file.
* the conversion at the edge: ezc3d's ``(4, markers, frames)`` becomes
  ``(frames, markers, 3)`` float64 in file units, NaN where the marker is
  missing (ezc3d's convention: a negative residual means missing).
* writing over the source file: every parameter, analog channel and header
  event of the source is kept, only the points (and what depends on the
  frame count) change.  Writes are atomic.

Layout facts used here (C3D User Guide): the file is a sequence of 512-byte
blocks; block 1 is the header (16-bit words), the parameter section starts at
the block named by the header's first byte, the data at the block named by
header word 9.  A 3D frame holds ``4 * POINT:USED`` values followed by
``ANALOG:USED * samples_per_frame`` analog values; a value is a 4-byte float
when ``POINT:SCALE < 0``, a 2-byte integer otherwise.
"""

from __future__ import annotations

import logging
import math
import os
import re
import struct
import tempfile
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ..errors import DataError
from ..motion import MAX_RATE, MIN_RATE, MarkerMotion
from .isolate import ChildFailed, fd_path, run_isolated

log = logging.getLogger(__name__)

__all__ = ["read_c3d", "write_c3d", "c3d_bytes", "check_c3d", "rate_ok", "MIN_RATE", "MAX_RATE"]

_BLOCK = 512
_KEY_BYTE = 0x50  # second byte of every C3D file
_PROCESSORS = {84: "intel", 85: "dec", 86: "mips"}
_INTEL = 84
#: More frames than any capture system records (10^8 frames = 9 days at 120 Hz).
MAX_FRAMES = 10**8
#: Largest magnitude of a coordinate, file units (the BVH reader's limit):
#: a sample beyond it is read as missing.
MAX_MAGNITUDE = 1e12
#: Most frames ezc3d 1.7.2 can write so that they read back (16-bit counts).
MAX_WRITE_FRAMES = 65535
# Marker frame rates (POINT:RATE, Hz) read and written are the clips' limits
# (motion.MIN_RATE to MAX_RATE): anything outside is not a capture (and
# 1e-308 Hz is 0 once stored as a 4-byte float).
#: C3D stores the dimensions of a parameter in bytes: at most 255 labels per
#: LABELS parameter, the rest continue in LABELS2, LABELS3, ...
_LABELS_PER_PARAMETER = 255
# Header event block (0-based byte offsets): words 150..234 hold the
# four-character-label key, the event count, 18 float times, 18 display
# bytes and 18 four-character labels.  ezc3d's writer drops them.
_EVENTS_START = 298
_EVENT_TIMES = slice(304, 376)
_EVENTS_STOP = 468


# --------------------------------------------------------------------------
# reading


def read_c3d(
    path: str | os.PathLike[str],
    data: bytes | None = None,
    name: str | None = None,
) -> MarkerMotion:
    """Read the markers of a C3D file.

    Parameters
    ----------
    path : str or path-like
        The file to read; only used to open it when ``data`` is None.
    data : bytes, optional
        The file content, already read (from stdin, say).
    name : str, optional
        How to name the file in error messages (``'<stdin>'``); defaults to
        ``path``.

    Returns
    -------
    MarkerMotion
        ``points`` is ``(T, M, 3)`` float64 in file units (``POINT:UNITS``),
        NaN where a marker is missing; ``labels`` are the ``M`` first entries
        of ``POINT:LABELS`` continued by ``LABELS2``...; ``rate`` is
        ``POINT:RATE`` in Hz; ``source`` holds the file bytes.

    Raises
    ------
    DataError
        Not a C3D file, a truncated or inconsistent one, or one that ezc3d
        refuses; the message names the file.
    """
    source_name = name if name is not None else os.fspath(path)
    if data is None:
        try:
            raw = Path(path).read_bytes()
        except OSError as exc:
            raise DataError(f"cannot read file: {exc.strerror or exc}", source_name) from None
    else:
        raw = bytes(data)

    layout = _check_layout(raw, source_name)
    motion = _isolated(
        lambda: _compact(_markers(raw, layout, source_name)), "reader failed on this file", source_name, len(raw)
    )
    return replace(motion, points=np.asarray(motion.points, dtype=np.float64), source=raw)


def _compact(motion: MarkerMotion) -> MarkerMotion:
    """``motion`` with float32 points when that loses nothing (a float C3D
    holds 4-byte floats): half the bytes to send back from the child."""
    small = motion.points.astype(np.float32)
    if np.array_equal(small, motion.points, equal_nan=True):
        return replace(motion, points=small)
    return motion


def _markers(raw: bytes, layout: _Layout, source_name: str) -> MarkerMotion:
    """The markers of ``raw`` as ezc3d reads them (``source`` left empty);
    runs in the child of :func:`_isolated`."""
    c3d = _load_ezc3d(raw, source_name)

    parameters = c3d["parameters"]
    ez_points = c3d["data"]["points"]  # (4, M, T), row 3 is 1
    residuals = c3d["data"]["meta_points"]["residuals"]  # (1, M, T)
    n_markers, n_frames = ez_points.shape[1], ez_points.shape[2]
    if n_frames < layout.n_frames or n_markers != layout.n_points:
        # _check_layout saw every declared frame in the file: a different
        # count means ezc3d derived another layout than the one checked
        raise DataError(
            f"ezc3d read {n_frames} frames of {n_markers} markers, the file declares "
            f"{layout.n_frames} frames of {layout.n_points} markers",
            source_name,
        )
    # more frames than declared: ezc3d read on into the block padding (it does
    # when a POINT:FRAMES over 32767 is stored as a negative INT)
    n_frames = layout.n_frames

    points = np.ascontiguousarray(ez_points[:3, :, :n_frames].transpose(2, 1, 0), dtype=np.float64)
    # ezc3d already sets NaN where the residual is negative; a coordinate that
    # is not finite (or beyond any capture volume, where the math overflows)
    # in a sample marked valid can only mean missing as well
    with np.errstate(invalid="ignore"):
        wild = ~(np.abs(points) <= MAX_MAGNITUDE).all(axis=-1)
    missing = (residuals[0, :, :n_frames].T < 0) | wild
    points[missing] = np.nan

    labels = [_text(label) for label in _point_labels(parameters)]
    if len(labels) < n_markers:
        # name the unlabelled points the way ezc3d does
        labels = labels + [f"unlabeled_point_{i}" for i in range(len(labels), n_markers)]
    rate = _first_float(parameters["POINT"].get("RATE")) or float(c3d["header"]["points"]["frame_rate"])
    if not np.isfinite(rate) or rate <= 0:
        raise DataError(f"no usable frame rate (POINT:RATE is {rate:g})", source_name)
    units = parameters["POINT"].get("UNITS", {}).get("value") or [""]

    return MarkerMotion(
        labels=tuple(labels[:n_markers]),
        points=points,
        rate=float(rate),
        units=_text(str(units[0])).strip(),
    )


def check_c3d(raw: bytes, source: str) -> None:
    """Raise ``DataError`` (naming ``source``) unless ``raw`` is a C3D whose
    header, parameter section and data block are consistent; cheap, without
    ezc3d (what :func:`read_c3d` checks before handing the file to it)."""
    _check_layout(raw, source)


@dataclass(frozen=True)
class _Layout:
    """What sizes the data block of a C3D file, as ezc3d 1.7.2 will see it."""

    processor: int
    n_points: int  # POINT:USED
    n_analogs: int  # ANALOG:USED
    analog_per_frame: int  # analog samples per 3D frame
    n_frames: int
    value_bytes: int  # 4 (float) or 2 (integer)
    data_offset: int  # byte offset of the first frame


def _check_layout(raw: bytes, source: str) -> _Layout:
    """Validate the header and the sizing parameters without allocating.

    Mirrors the way ezc3d 1.7.2 derives the frame layout (parameters override
    the header: ``POINT:FRAMES`` when non-zero, ``POINT:USED``,
    ``ANALOG:USED``, ``ANALOG:RATE / POINT:RATE``) and checks that the file
    holds every declared frame.
    """
    if len(raw) == 0:
        raise DataError("not a C3D file: the file is empty", source)
    if len(raw) < 2 or raw[1] != _KEY_BYTE:
        raise DataError("not a C3D file (no C3D key byte 0x50 in the header)", source)
    if len(raw) < _BLOCK:
        raise DataError(f"truncated C3D: {len(raw)} bytes, the header alone is {_BLOCK}", source)
    parameter_block = raw[0]
    parameter_offset = (parameter_block - 1) * _BLOCK
    if parameter_block < 2 or parameter_offset + 4 > len(raw):
        raise DataError(
            f"truncated or corrupt C3D: the parameter section (block {parameter_block}) is not in the file",
            source,
        )
    processor = raw[parameter_offset + 3]
    if processor not in _PROCESSORS:
        raise DataError(f"corrupt C3D: unknown processor type {processor} in the parameter section", source)

    word = _word_reader(raw, processor)
    h_points, h_analog_values = word(1), word(2)
    h_first, h_last = word(3), word(4)
    h_scale = _decode_float(raw[12:16], processor)
    h_data_start, h_analog_per_frame = word(8), word(9)
    h_rate = _decode_float(raw[20:24], processor)

    params, n_values, groups, types = _read_sizing_parameters(raw, parameter_offset, processor, source)

    def param(key: str, default: float) -> float:
        value = params.get(key)
        if value is None:
            return default
        if not np.isfinite(value):
            raise DataError(f"corrupt C3D: parameter {key} is {value}", source)
        return value

    n_points = int(param("POINT:USED", h_points))
    n_analogs = int(param("ANALOG:USED", 0))
    if n_points < 0 or n_analogs < 0:
        raise DataError(f"corrupt C3D: POINT:USED={n_points}, ANALOG:USED={n_analogs}", source)

    # frame count: ezc3d takes POINT:FRAMES when it is non-zero, else the
    # header's (1-based, inclusive) frame range
    first = h_first - 1 if h_first else 0
    last = h_last - 1 if (h_last and h_first) else h_last
    n_frames = int(param("POINT:FRAMES", 0))
    if n_frames < 0:
        # an INT parameter over 32767 frames: the C3D guide reads it unsigned
        n_frames += 1 << 16
    if n_frames == 0:
        n_frames = last - first + 1
    if n_frames < 0:
        raise DataError(f"corrupt C3D header: last frame {h_last} before first frame {h_first}", source)
    longer = _long_frame_count(params)
    if n_frames == MAX_WRITE_FRAMES and longer > n_frames:
        # over 65535 frames declared the old way (16-bit counts at their
        # maximum, the true count elsewhere): ezc3d 1.7.2 would silently read
        # the first 65535 only.  Elsewhere a stale TRIAL range is harmless.
        raise DataError(
            f"unsupported C3D: declares {longer} frames in TRIAL:ACTUAL_*_FIELD or POINT:LONG_FRAMES, "
            f"ezc3d reads only {n_frames} of them",
            source,
        )
    if n_frames > MAX_FRAMES:
        raise DataError(f"corrupt C3D: claims {n_frames} frames (more than {MAX_FRAMES})", source)
    if types.get("POINT:FRAMES") == _FLOAT:
        # refused only now, so that an absurd count is named as such first
        raise DataError("unsupported C3D: parameter POINT:FRAMES is of type float, readers expect int or byte", source)

    point_rate = param("POINT:RATE", h_rate)
    if n_points == 0:
        raise DataError(
            "no markers in this C3D (POINT:USED is 0" + (f", {n_analogs} analog channels only)" if n_analogs else ")"),
            source,
        )
    if n_frames == 0:
        raise DataError("no frames in this C3D", source)
    rate = point_rate or h_rate  # ezc3d: a zero POINT:RATE leaves the header's
    if not rate_ok(rate):
        raise DataError(f"frame rate {rate:g} Hz (POINT:RATE) is outside {RATE_LIMITS}", source)
    analog_rate = param("ANALOG:RATE", 0.0)
    analog_per_frame = h_analog_per_frame
    if np.isfinite(point_rate) and np.isfinite(analog_rate) and int(point_rate) != 0:
        from_rates = int(analog_rate / point_rate)
        if from_rates != h_analog_per_frame and not (h_analog_per_frame == 1 and "SHADOW" in groups):
            analog_per_frame = from_rates
    if analog_per_frame < 0:
        raise DataError(f"corrupt C3D: {analog_per_frame} analog samples per frame", source)
    if n_points == 0 and n_analogs == 0:
        n_frames = 0  # ezc3d: no data at all
    if n_frames and n_analogs and analog_per_frame and "SHADOW" not in groups:
        # ezc3d 1.7.2 indexes one scale and one offset per channel without
        # a bounds check: a missing ANALOG:SCALE crashes the interpreter
        for name in ("SCALE", "OFFSET"):
            have = sum(n for key, n in n_values.items() if re.fullmatch(f"ANALOG:{name}[0-9]*", key))
            if have < n_analogs:
                raise DataError(f"corrupt C3D: ANALOG:{name} has {have} values for {n_analogs} analog channels", source)

    scale = param("POINT:SCALE", h_scale) if n_points else h_scale
    value_bytes = 4 if scale < 0 else 2
    data_offset = (h_data_start - 1) * _BLOCK
    if h_data_start < 2 or data_offset > len(raw):
        raise DataError(f"truncated or corrupt C3D: data start block {h_data_start} is not in the file", source)

    stride = 4 * n_points + n_analogs * analog_per_frame  # values per frame, as ezc3d reads
    needed = n_frames * stride * value_bytes
    available = len(raw) - data_offset
    header_stride = 4 * h_points + h_analog_values
    if header_stride != stride:
        # Header and parameters disagree on the frame size.  ezc3d follows the
        # parameters; accept only when the data block fits them and not the
        # header (otherwise ezc3d reads garbage with a wrong stride).
        header_needed = n_frames * header_stride * value_bytes
        if not (needed <= available < needed + _BLOCK) or header_needed <= available < header_needed + _BLOCK:
            raise DataError(
                f"inconsistent C3D: the header says {h_points} points and {h_analog_values} analog "
                f"values per frame, the parameters {n_points} points, {n_analogs} analog channels x "
                f"{analog_per_frame} samples; refusing to guess the frame layout",
                source,
            )
    if needed > available:
        frame_bytes = stride * value_bytes
        whole = available // frame_bytes if frame_bytes else 0
        raise DataError(
            f"truncated C3D: {n_frames} frames of {frame_bytes} bytes declared, "
            f"the file holds {whole} ({available} of {needed} data bytes)",
            source,
        )
    return _Layout(processor, n_points, n_analogs, analog_per_frame, n_frames, value_bytes, data_offset)


def rate_ok(rate: float) -> bool:
    """Whether ``rate`` Hz is a marker rate C3D files are read and written at
    (``MIN_RATE`` to ``MAX_RATE``; False for NaN)."""
    return bool(MIN_RATE <= rate <= MAX_RATE)


RATE_LIMITS = f"{MIN_RATE:g} to {MAX_RATE:g} Hz"


def _long_frame_count(params: dict[str, float]) -> int:
    """Frame count from POINT:LONG_FRAMES or the TRIAL fields (0 if absent)."""
    count = 0
    long_frames = params.get("POINT:LONG_FRAMES")
    if long_frames is not None and np.isfinite(long_frames):
        count = int(long_frames)
    start, end = params.get("TRIAL:ACTUAL_START_FIELD"), params.get("TRIAL:ACTUAL_END_FIELD")
    if start is not None and end is not None:
        count = max(count, int(end) - int(start) + 1)
    return count


def _word_reader(raw: bytes, processor: int):
    """Reader of unsigned 16-bit header word ``i`` (0-based) for ``processor``."""
    fmt = ">H" if processor == 86 else "<H"
    return lambda i: struct.unpack_from(fmt, raw, 2 * i)[0]


def _decode_float(four: bytes, processor: int) -> float:
    """A 4-byte C3D float in the byte order of ``processor`` (84 Intel, 85 DEC, 86 MIPS)."""
    if processor == 86:
        return struct.unpack(">f", four)[0]
    if processor == 85:
        # DEC F-floating: 16-bit words swapped, exponent biased by 2 more than
        # IEEE, so the value is the swapped IEEE value divided by 4
        b = bytes((four[2], four[3], four[0], four[1]))
        return struct.unpack("<f", b)[0] / 4.0
    return struct.unpack("<f", four)[0]


_SIZING_PARAMETERS = {
    ("POINT", "USED"),
    ("POINT", "FRAMES"),
    ("POINT", "SCALE"),
    ("POINT", "RATE"),
    ("ANALOG", "USED"),
    ("ANALOG", "RATE"),
    ("POINT", "LONG_FRAMES"),
    ("TRIAL", "ACTUAL_START_FIELD"),
    ("TRIAL", "ACTUAL_END_FIELD"),
}
#: Parameters made of two unsigned 16-bit words, low word first.
_TWO_WORD_PARAMETERS = {("TRIAL", "ACTUAL_START_FIELD"), ("TRIAL", "ACTUAL_END_FIELD")}


_PARAMETER_TYPES = {-1: 1, 1: 1, 2: 2, 4: 4}  # C3D type code -> bytes per value
#: The C3D User Guide: a parameter has at most 7 dimensions.
_MAX_DIMENSIONS = 7
#: Most entries of an empty array (a zero dimension) ezc3d is given.
_MAX_EMPTY_ENTRIES = 1 << 16
_CHAR, _BYTE, _INT, _FLOAT = -1, 1, 2, 4
_TYPE_NAMES = {_CHAR: "char", _BYTE: "byte", _INT: "int", _FLOAT: "float"}
_INTEGER = (_INT, _BYTE)
#: The parameters ezc3d 1.7.2 (and this module) read: the C3D types read
#: (ezc3d's valuesAsInt() takes int and byte, valuesAsDouble() float,
#: valuesAsString() char; another type throws, or is misread by the code
#: here) and the number of values indexed without a bounds check
#: (``valuesAsInt()[0]`` of an empty array is a segfault).
_READ_AS: dict[tuple[str, str], tuple[tuple[int, ...], int]] = {
    ("POINT", "USED"): (_INTEGER, 1),
    ("POINT", "FRAMES"): ((_INT, _BYTE, _FLOAT), 1),  # float: the c3d.org way past 65535 (ezc3d refuses it)
    ("POINT", "SCALE"): ((_FLOAT,), 1),
    ("POINT", "RATE"): ((_FLOAT,), 1),
    ("POINT", "DATA_START"): (_INTEGER, 1),
    ("POINT", "LONG_FRAMES"): ((_FLOAT, _INT, _BYTE), 1),
    ("ANALOG", "USED"): (_INTEGER, 1),
    ("ANALOG", "RATE"): ((_FLOAT,), 1),
    ("ANALOG", "GEN_SCALE"): ((_FLOAT,), 1),
    ("ANALOG", "BITS"): (_INTEGER, 0),
    ("ANALOG", "FORMAT"): ((_CHAR,), 0),
    ("TRIAL", "ACTUAL_START_FIELD"): (_INTEGER, 2),
    ("TRIAL", "ACTUAL_END_FIELD"): (_INTEGER, 2),
    ("ROTATION", "USED"): (_INTEGER, 1),
    ("ROTATION", "DATA_START"): (_INTEGER, 1),
    ("ROTATION", "RATIO"): (_INTEGER, 1),
    ("ROTATION", "RATE"): ((_FLOAT,), 1),
    ("MANUFACTURER", "COMPANY"): ((_CHAR,), 0),
}
#: Parameters continued by NAME2, NAME3, ... (ezc3d reads them all, in order).
_READ_AS_NUMBERED: dict[tuple[str, str], tuple[int, ...]] = {
    ("POINT", "LABELS"): (_CHAR,),
    ("POINT", "DESCRIPTIONS"): (_CHAR,),
    ("POINT", "UNITS"): (_CHAR,),
    ("POINT", "SCALE"): (_FLOAT,),
    ("ANALOG", "LABELS"): (_CHAR,),
    ("ANALOG", "DESCRIPTIONS"): (_CHAR,),
    ("ANALOG", "UNITS"): (_CHAR,),
    ("ANALOG", "SCALE"): (_FLOAT,),
    ("ANALOG", "OFFSET"): _INTEGER,
}
_NUMBERED = re.compile(r"(.*?)([2-9]|[1-9][0-9]+)")


def _check_read_as(group: str, name: str, ptype: int, count: int, source: str) -> None:
    """Refuse a parameter that ezc3d reads as another type, or with fewer values than it indexes."""
    key = (group, name)
    rule = _READ_AS.get(key)
    if rule is None:
        m = _NUMBERED.fullmatch(name)
        base = (group, m.group(1)) if m else None
        types = _READ_AS_NUMBERED.get(key) or (_READ_AS_NUMBERED.get(base) if base else None)
        if types is None:
            return
        rule = (types, 0)
    types, least = rule
    shown = f"{group}:{name}"
    if ptype not in types:
        expected = " or ".join(_TYPE_NAMES[t] for t in types)
        raise DataError(
            f"unsupported C3D: parameter {shown} is of type {_TYPE_NAMES.get(ptype, ptype)}, readers expect {expected}",
            source,
        )
    if count < least:
        held = "no value" if count == 0 else f"{count} value"
        raise DataError(f"corrupt C3D: parameter {shown} holds {held} (at least {least} expected)", source)


def _read_sizing_parameters(
    raw: bytes, offset: int, processor: int, source: str
) -> tuple[dict[str, float], dict[str, int], set[str], dict[str, int]]:
    """Walk the parameter section, check its structure, and pick what sizes the data.

    The walk follows the C3D User Guide ("The parameter section"): each
    record is a group or a parameter with a name, an offset to the next
    record, and (for a parameter) a type, dimensions, values and a
    description that must fit before the next record.  ezc3d 1.7.2 does not
    check that and can crash the interpreter on a corrupt section, so a
    record that overruns its neighbour, an unknown type or a parameter of a
    group that does not exist is refused here.

    Returns
    -------
    values : dict
        ``{'GROUP:NAME': first value}`` for ``_SIZING_PARAMETERS``.
    counts : dict
        ``{'GROUP:NAME': number of values}`` for every parameter.
    groups : set of str
        The group names.
    types : dict
        ``{'GROUP:NAME': C3D type code}`` for every parameter.

    Raises
    ------
    DataError
        A malformed record; the message gives its byte offset.
    """
    int16, uint16 = (">h", ">H") if processor == 86 else ("<h", "<H")
    end = len(raw)
    group_names: dict[int, str] = {}
    records: list[tuple[int, str, int, int, bytes]] = []  # group id, name, type, count, first 4 value bytes
    pos = offset + 4
    for _ in range(100_000):  # bounded: a corrupt offset must not loop forever
        if pos + 2 > end:
            break
        name_len = abs(struct.unpack_from("b", raw, pos)[0])
        ident = struct.unpack_from("b", raw, pos + 1)[0]
        if name_len == 0 or ident == 0:
            break  # the end mark
        next_at = pos + 2 + name_len
        if next_at + 2 > end:
            raise DataError(f"truncated C3D: parameter record at byte {pos} runs past the end of file", source)
        name = raw[pos + 2 : next_at].decode("latin-1")  # exact, as ezc3d compares names
        # ezc3d reads the offset unsigned, a zero marks the last record
        step = struct.unpack_from(uint16, raw, next_at)[0]
        record_end = next_at + step if step > 0 else end
        body = next_at + 2

        def bad(why: str, at: int = pos, label: str = name) -> DataError:
            # a corrupt name length makes the "name" run on through the section
            return DataError(f"corrupt C3D: parameter record {label[:40]!r} at byte {at} {why}", source)

        if record_end > end:
            raise bad("points past the end of file")
        # ezc3d reads description lengths and dimension counts as signed bytes
        # and crashes (or allocates 4 GB) on a "negative" one: refuse >= 128
        if ident < 0:
            if body + 1 > record_end or raw[body] >= 128 or body + 1 + raw[body] > record_end:
                raise bad("has a description longer than the record")
            group_names[-ident] = name
        else:
            if body + 2 > record_end:
                raise bad("is shorter than its header")
            ptype, ndims = struct.unpack_from("b", raw, body)[0], raw[body + 1]
            if ptype not in _PARAMETER_TYPES:
                raise bad(f"has unknown type {ptype}")
            if ndims > _MAX_DIMENSIONS or (ptype == -1 and ndims == 0):
                raise bad(f"has {ndims} dimensions (C3D allows 1 to {_MAX_DIMENSIONS}, 0 for a number)")
            first_value = body + 2 + ndims
            dims = raw[body + 2 : first_value]
            count = math.prod(dims)  # Python ints: no overflow
            if count == 0 and math.prod(d for d in dims if d) > _MAX_EMPTY_ENTRIES:
                # ezc3d loops over the dimensions in turn: an empty array of
                # 255 x 255 x ... x 0 entries still costs it forever
                raise bad(f"is an empty array of {'x'.join(map(str, dims))} entries")
            values_end = first_value + count * _PARAMETER_TYPES[ptype]
            if (
                first_value > record_end
                or values_end + 1 > record_end
                or raw[values_end] >= 128
                or values_end + 1 + raw[values_end] > record_end
            ):
                raise bad("holds more than the record (values or description overrun the next one)")
            records.append((ident, name, ptype, count, raw[first_value : min(first_value + 4, values_end)]))
        if step <= 0:
            break
        pos = next_at + step

    values: dict[str, float] = {}
    counts: dict[str, int] = {}
    types: dict[str, int] = {}
    for gid, name, ptype, count, first in records:
        if gid not in group_names:
            raise DataError(
                f"corrupt C3D: parameter {name[:40]!r} belongs to group {gid}, which does not exist", source
            )
        key = (group_names[gid], name)
        counts[f"{key[0]}:{key[1]}"] = count
        types[f"{key[0]}:{key[1]}"] = ptype
        _check_read_as(key[0], key[1], ptype, count, source)
        if key not in _SIZING_PARAMETERS or count == 0:
            continue
        if key in _TWO_WORD_PARAMETERS:
            if ptype != 2 or count < 2:
                continue
            low, high = struct.unpack(">HH" if processor == 86 else "<HH", first)
            number: float = low | high << 16
        elif ptype == 4:
            number = _decode_float(first, processor)
        elif ptype == 2:
            number = struct.unpack(int16, first[:2])[0]
        elif ptype == 1:
            number = first[0]
        else:
            continue
        values[f"{key[0]}:{key[1]}"] = number
    return values, counts, set(group_names.values()), types


def _load_ezc3d(raw: bytes, source: str):
    """ezc3d's c3d object of ``raw``.

    ezc3d only reads paths: it is given one to an anonymous file (a memfd,
    else a temporary file unlinked as soon as it is created), so that no copy
    of the input is ever left in the temporary folder, whatever kills us.
    """
    import ezc3d

    with _anonymous_file(raw) as fd:
        try:
            return ezc3d.c3d(fd_path(fd))
        except Exception as exc:  # ezc3d raises OSError/RuntimeError/ValueError from C++
            _raise_out_of_memory(exc)
            message = " ".join(str(exc).split()) or type(exc).__name__
            raise DataError(f"ezc3d cannot read this C3D: {message}", source) from None


def _raise_out_of_memory(exc: Exception) -> None:
    """Re-raise ezc3d's ``std::bad_alloc`` (a RuntimeError) as the MemoryError it is:
    the child's memory limit was hit, which :func:`_isolated` reports as such."""
    if isinstance(exc, MemoryError) or "bad_alloc" in str(exc):
        raise MemoryError(str(exc)) from None


class _anonymous_file:
    """A descriptor of a file without a name holding ``data`` (context manager)."""

    def __init__(self, data: bytes = b""):
        self.data = data
        self.fd = -1

    def __enter__(self) -> int:
        if hasattr(os, "memfd_create"):
            self.fd = os.memfd_create("staggered-c3d")
        else:
            fh = tempfile.TemporaryFile(prefix="staggered-")  # unlinked at once on POSIX
            self.fd = os.dup(fh.fileno())
            fh.close()
        view = memoryview(self.data)
        while view:
            view = view[os.write(self.fd, view) :]
        os.lseek(self.fd, 0, os.SEEK_SET)
        return self.fd

    def __exit__(self, *exc) -> None:
        os.close(self.fd)


#: Wall-clock seconds an ezc3d read or write may take: a fixed allowance plus
#: a time per MB of data (ezc3d reads about 15 MB/s here, so this is a wide margin).
CHILD_SECONDS = 3.0
CHILD_SECONDS_PER_MB = 0.5
#: Memory an ezc3d read or write may allocate: a fixed allowance plus a
#: multiple of the data size (ezc3d's objects take about 13x the file).
CHILD_MEMORY = 256 << 20
CHILD_MEMORY_PER_BYTE = 48


def _isolated(fn, what: str, source: str | None, n_bytes: int):
    """``fn()`` (a call into ezc3d on ``n_bytes`` of data) in a child
    process, see :mod:`.isolate`.

    A crash, hang or runaway allocation of ezc3d becomes one ``DataError``
    naming ``source`` (None: the command's input): "the C3D ``what``
    failed ...".
    """
    import ezc3d  # noqa: F401 - imported here so that the child inherits it (~0.1 s)

    memory = CHILD_MEMORY + CHILD_MEMORY_PER_BYTE * n_bytes
    seconds = CHILD_SECONDS + CHILD_SECONDS_PER_MB * n_bytes / 1e6
    try:
        return run_isolated(fn, memory=memory, seconds=seconds)
    except ChildFailed as exc:
        log.debug("ezc3d in a child process: %s", exc.why)
        raise DataError(f"the C3D {what} (malformed parameters?)", source) from None


def _point_labels(parameters) -> list[str]:
    """POINT:LABELS continued by LABELS2, LABELS3, ... (ezc3d's order)."""
    group = parameters["POINT"]
    labels = list(group.get("LABELS", {}).get("value", []))
    k = 2
    while f"LABELS{k}" in group:
        labels.extend(group[f"LABELS{k}"]["value"])
        k += 1
    return [str(label) for label in labels]


def _text(value: str) -> str:
    """A C3D string as clean text.

    C3D strings are bytes; ezc3d decodes them as UTF-8 and keeps the bytes
    that are not (latin-1 accents of European software: ``é`` is 0xE9) as
    lone surrogates, which can be neither printed nor written back.  Read
    those bytes as latin-1.
    """
    return _SURROGATE.sub(lambda m: chr(ord(m.group()) - 0xDC00), value)


_SURROGATE = re.compile("[\udc80-\udcff]")


def _first_float(parameter: dict | None) -> float:
    if not parameter:
        return 0.0
    value = np.asarray(parameter.get("value", []), dtype=float).ravel()
    return float(value[0]) if value.size else 0.0


# --------------------------------------------------------------------------
# writing


def write_c3d(path: str | os.PathLike[str], motion: MarkerMotion, force: bool = True) -> None:
    """Write ``motion`` to ``path`` atomically: complete or not there at all.

    See :func:`c3d_bytes` for what is written.  The bytes are built first, so
    a failure leaves no file and an existing ``path`` untouched; then
    :func:`~staggered_cli.io.files.write_atomic` writes them (temporary file
    in the same directory, fsync, rename; ``force=False`` refuses an existing
    ``path``; ``'-'`` is standard output there, as for BVH).
    """
    from .files import write_atomic

    write_atomic(os.fspath(path), c3d_bytes(motion), force=force)


def c3d_bytes(motion: MarkerMotion) -> bytes:
    """The C3D file content of ``motion``.

    With ``motion.source`` (the bytes of the file it was read from) the
    source is rewritten with new points: every parameter, analog channel and
    header event is kept.  Markers are matched to the source by label (the
    k-th marker of a repeated label to the k-th of the source), so their
    residuals and camera masks carry over; new markers get residual 0.
    When the frame count or rate differs from the source, frames keep their
    time from the first frame on and so do analog samples: at the source's
    rate they are cut at the new end, or the last sample is held to fill a
    longer clip; at a new rate they are resampled in time, at the source's
    analog rate when it is a whole multiple of the new point rate, else at
    the nearest whole multiple (see :func:`_fit_analogs`); the frame-count
    parameters (``POINT:FRAMES``, ``TRIAL:ACTUAL_END_FIELD``,
    ``POINT:LONG_FRAMES``) follow.

    Without a source a fresh C3D is built with POINT parameters only.

    Gaps (a NaN in any coordinate of a sample) are written the C3D way:
    coordinates 0 and residual -1; valid samples have residual >= 0.
    Points are written as 4-byte floats in file units, so they round to
    float32 precision.

    Raises
    ------
    ValueError
        ``motion`` is not consistent (shape, labels, rate, infinite values).
    DataError
        ``motion.source`` is not a readable C3D, more than 65535 frames, or
        ezc3d refuses to write.
    """
    points = np.asarray(motion.points, dtype=np.float64)
    labels = [str(label) for label in motion.labels]
    _check_motion(points, labels, motion.rate)
    if not rate_ok(float(motion.rate)):
        raise DataError(f"cannot write a C3D at {motion.rate:g} Hz: C3D frame rates are {RATE_LIMITS}")
    n_frames = points.shape[0]
    if n_frames > MAX_WRITE_FRAMES:
        # ezc3d caps the header and POINT:FRAMES at 65535 and writes no other
        # count: any reader, ezc3d included, would silently lose the rest
        raise DataError(f"cannot write {n_frames} frames to C3D: ezc3d writes at most {MAX_WRITE_FRAMES}")

    source_name = "source C3D of the motion"
    if motion.source:
        _check_layout(motion.source, source_name)
    payload = _isolated(
        lambda: _ezc3d_bytes(motion, points, labels, source_name),
        "writer failed on the motion's source C3D" if motion.source else "writer failed",
        None,  # the command's input: the document that holds the source
        len(motion.source) + points.nbytes,
    )
    payload = bytes(payload)
    # what was written must read back: the same checks as the reader
    try:
        check_c3d(payload, "")
    except DataError as exc:
        raise DataError(f"cannot write this C3D: the file ezc3d made would not read back ({exc.message})") from None
    return payload


def _ezc3d_bytes(motion: MarkerMotion, points: np.ndarray, labels: list[str], source_name: str) -> bytearray:
    """The bytes ezc3d writes for ``motion`` (see :func:`c3d_bytes`); runs in
    the child of :func:`_isolated`."""
    n_frames, n_markers = points.shape[:2]
    gap = np.isnan(points).any(axis=-1)  # (T, M)
    ez_points = np.ones((4, n_markers, n_frames))
    ez_points[:3] = np.where(gap[..., None], 0.0, points).transpose(2, 1, 0)
    residuals = np.zeros((1, n_markers, n_frames))
    camera_masks = np.zeros((7, n_markers, n_frames), dtype=bool)

    if motion.source:
        c3d = _load_ezc3d(motion.source, source_name)
        _carry_point_metadata(c3d, labels, n_frames, residuals, camera_masks)
        point_rate = _fit_analogs(c3d, n_frames, motion.rate)
        _fit_frame_count_parameters(c3d["parameters"], n_frames)
        events = _header_events(motion.source)
    else:
        import ezc3d

        c3d = ezc3d.c3d()
        events = None
        point_rate = float(motion.rate)

    residuals[0][gap.T] = -1.0
    _clean_texts(c3d["parameters"])
    _one_data_start(c3d["parameters"])
    point = c3d["parameters"]["POINT"]
    _set_point_labels(point, labels, _descriptions_by_label(point))
    _set_parameter(point, "RATE", 4, np.array([point_rate]))
    if motion.units:
        _set_parameter(point, "UNITS", -1, [motion.units])
    c3d["data"]["points"] = ez_points
    c3d["data"]["meta_points"] = {"residuals": residuals, "camera_masks": camera_masks}

    with _anonymous_file() as fd:
        try:
            # ezc3d appends '.c3d' to a path that does not end with it
            c3d.write(_C3dSuffixed(fd_path(fd)))
        except Exception as exc:  # ezc3d's checks raise ValueError/TypeError/RuntimeError
            _raise_out_of_memory(exc)
            message = " ".join(str(exc).split()) or type(exc).__name__
            raise DataError(f"ezc3d cannot write this C3D: {message}") from None
        size = os.lseek(fd, 0, os.SEEK_END)
        payload = bytearray(os.pread(fd, size, 0))
    if events is not None:
        payload[_EVENTS_START:_EVENTS_STOP] = events
    return payload  # a bytearray leaves the child without a copy (pickle buffers)


class _C3dSuffixed(str):
    """A path that ezc3d's Python writer takes as is.

    ``ezc3d.c3d.write`` appends ``.c3d`` to a path whose last four
    characters are not ``.c3d``, which would turn ``/proc/self/fd/5`` into a
    file that does not exist; this string says it ends with ``.c3d``.
    """

    def __getitem__(self, key):
        if key == slice(-4, None):
            return ".c3d"
        return str.__getitem__(self, key)


def _one_data_start(parameters) -> None:
    """POINT:DATA_START (and ROTATION's) as one integer, which ezc3d fills in.

    ezc3d writes the block number over the first value it finds: with two
    values, or a float, the record it writes no longer matches its size.
    """
    for group in ("POINT", "ROTATION"):
        if group in parameters and "DATA_START" in parameters[group]:
            entry = parameters[group]["DATA_START"]
            entry["type"] = _INT
            entry["value"] = np.array([0])


def _clean_texts(parameters) -> None:
    """Make every string of ezc3d's parameter dict writable (see :func:`_text`).

    ezc3d's writer passes strings to C++ as UTF-8 and fails on the lone
    surrogates its reader produced; such bytes are written back as the
    UTF-8 of their latin-1 reading.
    """

    def clean(value):
        if isinstance(value, str):
            return _text(value)
        if isinstance(value, list):
            return [clean(v) for v in value]
        return value

    if any(_text(group) != group for group in parameters):  # names too, keeping their order
        groups = [(_text(group), parameters[group]) for group in parameters]
        for group in list(parameters):
            del parameters[group]
        for group, entries in groups:
            parameters[group] = entries
    for group in parameters:
        entries = parameters[group]
        if any(_text(name) != name for name in entries):
            renamed = {_text(name): entry for name, entry in entries.items()}
            entries.clear()
            entries.update(renamed)
        for name, entry in entries.items():
            if name == "__METADATA__":
                entry["DESCRIPTION"] = clean(entry["DESCRIPTION"])
            else:
                entry["description"] = clean(entry["description"])
                entry["value"] = clean(entry["value"])


def _check_motion(points: np.ndarray, labels: list[str], rate: float) -> None:
    if points.ndim != 3 or points.shape[2] != 3:
        raise ValueError(f"motion.points must have shape (frames, markers, 3), got {points.shape}")
    if points.shape[0] == 0:
        raise ValueError("motion.points has no frames")
    if len(labels) != points.shape[1]:
        raise ValueError(f"motion.labels has {len(labels)} entries for {points.shape[1]} markers")
    if np.isinf(points).any():
        raise ValueError("motion.points holds infinite values")
    if not (np.isfinite(rate) and rate > 0):
        raise ValueError(f"motion.rate must be a positive frame rate in Hz, got {rate!r}")


def _carry_point_metadata(
    c3d,
    labels: list[str],
    n_frames: int,
    residuals: np.ndarray,
    camera_masks: np.ndarray,
) -> None:
    """Copy the source's residuals (1, M, T) and camera masks (7, M, T) by label.

    Frames past the source's end keep residual 0; a source gap that now has
    a value gets residual 0 too (a negative residual would hide it).
    """
    src_residuals = c3d["data"]["meta_points"]["residuals"]  # (1, Ms, Ts)
    src_masks = c3d["data"]["meta_points"]["camera_masks"]  # (7, Ms, Ts)
    src_labels = _point_labels(c3d["parameters"])[: src_residuals.shape[1]]
    # the k-th marker of a label takes the k-th source marker of that label:
    # C3D labels may repeat, and each marker keeps its own residuals
    index: dict[str, list[int]] = {}
    for i, label in enumerate(src_labels):
        index.setdefault(label, []).append(i)
    columns = np.array([index[label].pop(0) if index.get(label) else -1 for label in labels], dtype=int)
    have = np.flatnonzero(columns >= 0)
    overlap = min(n_frames, src_residuals.shape[2])
    if have.size == 0 or overlap == 0:
        return
    residuals[:, have, :overlap] = np.maximum(src_residuals[:, columns[have], :overlap], 0.0)
    if src_masks.shape[0] == camera_masks.shape[0] and src_masks.shape[2] == src_residuals.shape[2]:
        camera_masks[:, have, :overlap] = src_masks[:, columns[have], :overlap]


def _fit_analogs(c3d, n_frames: int, rate: float) -> float:
    """Fit the analog block (1, channels, T * r) to ``n_frames`` frames at ``rate`` Hz.

    Analog samples keep their time: sample ``s`` of the source lies at
    ``s / analog_rate`` seconds from the first frame.  At the source's point
    rate the samples stay as they are (cut at the new end, or the last one
    held to fill a longer clip).  At another point rate there must be a whole
    number of samples per frame: the source's analog rate is kept when it is
    a whole multiple of ``rate``, else the nearest whole multiple (at least
    one sample per frame) becomes ``ANALOG:RATE``, and every channel is
    resampled onto the new sample times by linear interpolation (the last
    sample held past the source's end).

    Returns the point rate to write: ``rate``, or the float32 nearest to it
    whose analog rate divides back to exactly the samples per frame (see
    :func:`_divisible_rate`).
    """
    parameters = c3d["parameters"]
    analogs = np.asarray(c3d["data"]["analogs"], dtype=np.float64)  # (1, A, S)
    src_frames = c3d["data"]["points"].shape[2]
    old_point_rate = _first_float(parameters["POINT"].get("RATE")) or rate
    old_analog_rate = _first_float(parameters["ANALOG"].get("RATE"))
    if analogs.shape[1] and src_frames:
        src_per_frame = analogs.shape[2] // src_frames
    else:
        src_per_frame = int(round(old_analog_rate / old_point_rate)) if old_point_rate > 0 else 0
    same_rate = abs(rate - old_point_rate) <= 1e-6 * rate
    if same_rate or src_per_frame == 0:
        per_frame = src_per_frame
    else:
        # the source's samples per second, as its frames lay them out
        per_frame = max(1, int(round(src_per_frame * old_point_rate / rate)))
    samples = n_frames * per_frame
    if analogs.shape[2] == 0:
        analogs = np.zeros((1, analogs.shape[1], samples))
    elif same_rate:
        if analogs.shape[2] >= samples:
            analogs = analogs[:, :, :samples]
        else:
            analogs = np.pad(analogs, ((0, 0), (0, 0), (0, samples - analogs.shape[2])), mode="edge")
    else:
        analogs = _resample_analogs(analogs, src_per_frame * old_point_rate, per_frame * float(rate), samples)
    c3d["data"]["analogs"] = analogs
    _cut_to_used(parameters["ANALOG"], analogs.shape[1])
    point_rate = _divisible_rate(float(rate), per_frame) if per_frame and not same_rate else float(rate)
    if per_frame and ("RATE" in parameters["ANALOG"] or not same_rate):
        # ezc3d checks ANALOG:RATE == samples per frame x POINT:RATE
        _set_parameter(parameters["ANALOG"], "RATE", 4, np.array([per_frame * point_rate]))
    return point_rate


def _divisible_rate(rate: float, per_frame: int) -> float:
    """A point rate within a few float32 steps of ``rate`` whose analog rate
    ``per_frame * rate``, stored as float32 like every C3D rate, divides by it
    to at least ``per_frame``.

    Readers (ezc3d, this module) take the analog samples per frame as the
    truncated ratio of the two stored rates: at 29.97 Hz with 7 samples per
    frame, float32(209.79) / float32(29.97) is 6.99999..., read as 6, and the
    whole frame layout is misread.  A rate whose product rounds up (or is
    exact) cannot truncate below ``per_frame``.
    """
    r32 = np.float32(rate)
    candidates = [r32]
    up, down = r32, r32
    for _ in range(8):
        up, down = np.nextafter(up, np.float32(np.inf)), np.nextafter(down, np.float32(0))
        candidates += [up, down]
    for r in candidates:  # nearest first
        if float(np.float32(per_frame * float(r))) >= per_frame * float(r):
            return float(r)
    return float(r32)


def _resample_analogs(analogs: np.ndarray, old_rate: float, new_rate: float, samples: int) -> np.ndarray:
    """``analogs`` (1, A, S) sampled at ``old_rate`` Hz, linearly interpolated
    at ``samples`` times ``j / new_rate`` (both grids start at the first
    frame); times past the last sample take its value."""
    last = analogs.shape[2] - 1
    pos = np.clip(np.arange(samples) * (old_rate / new_rate), 0.0, last)
    i0 = np.floor(pos).astype(np.int64)
    i1 = np.minimum(i0 + 1, last)
    w = pos - i0
    return analogs[:, :, i0] * (1.0 - w) + analogs[:, :, i1] * w


def _cut_to_used(analog: dict, n_channels: int) -> None:
    """Cut the per-channel ANALOG parameters to the channels in use.

    Files often declare more LABELS/SCALE/OFFSET entries than ANALOG:USED
    (Eb015pi: 32 for 16); ezc3d's writer requires exactly one per channel
    and would otherwise drop SCALE, UNITS and DESCRIPTIONS.
    """
    for key in ("LABELS", "DESCRIPTIONS", "UNITS", "SCALE", "OFFSET"):
        if key in analog and len(analog[key]["value"]) > n_channels:
            analog[key]["value"] = analog[key]["value"][:n_channels]


def _fit_frame_count_parameters(parameters, n_frames: int) -> None:
    """Keep the optional frame-count parameters in step with ``n_frames``.

    ezc3d updates POINT:FRAMES itself; readers that prefer TRIAL or
    LONG_FRAMES (Vicon, BTK) would otherwise see the source's count.
    """
    trial = parameters["TRIAL"] if "TRIAL" in parameters else {}
    if "ACTUAL_START_FIELD" in trial and "ACTUAL_END_FIELD" in trial:
        start_words = np.asarray(trial["ACTUAL_START_FIELD"]["value"], dtype=np.int64).ravel()
        end_words = np.asarray(trial["ACTUAL_END_FIELD"]["value"], dtype=np.int64).ravel()
        if start_words.size == 2 and end_words.size == 2:
            # two 16-bit words, low word first, read as unsigned
            start = int(start_words[0] & 0xFFFF) | int(start_words[1] & 0xFFFF) << 16
            end = start + n_frames - 1
            trial["ACTUAL_END_FIELD"]["value"] = np.array([_as_int16(end & 0xFFFF), _as_int16(end >> 16)])
    point = parameters["POINT"]
    if "LONG_FRAMES" in point:
        point["LONG_FRAMES"]["value"] = np.array([float(n_frames)])


def _as_int16(word: int) -> int:
    """An unsigned 16-bit word as the signed value ezc3d stores for INT parameters."""
    return word - (1 << 16) if word >= 1 << 15 else word


def _descriptions_by_label(point: dict) -> dict[str, str]:
    labels = list(point.get("LABELS", {}).get("value", []))
    descriptions = list(point.get("DESCRIPTIONS", {}).get("value", []))
    k = 2
    while f"LABELS{k}" in point:
        labels.extend(point[f"LABELS{k}"]["value"])
        descriptions.extend(point.get(f"DESCRIPTIONS{k}", {}).get("value", []))
        k += 1
    return {label: desc for label, desc in zip(labels, descriptions, strict=False)}


def _set_point_labels(point: dict, labels: list[str], descriptions: dict[str, str]) -> None:
    """POINT:LABELS (and LABELS2... past 255 markers), DESCRIPTIONS to match."""
    chunks = _chunks(labels, _LABELS_PER_PARAMETER)
    point["LABELS"]["value"] = chunks[0] if chunks else []
    for k, chunk in enumerate(chunks[1:], start=2):
        _set_parameter(point, f"LABELS{k}", -1, chunk)
    k = max(len(chunks), 1) + 1
    while f"LABELS{k}" in point:  # stale continuations of a longer source list
        del point[f"LABELS{k}"]
        k += 1
    if len(labels) <= _LABELS_PER_PARAMETER and "DESCRIPTIONS" in point:
        # one entry per marker, or ezc3d's writer drops the parameter
        point["DESCRIPTIONS"]["value"] = [descriptions.get(label, "") for label in labels]


def _set_parameter(group: dict, name: str, ptype: int, value) -> None:
    """Set a parameter's value in ezc3d's dict, creating it when absent.

    ``ptype`` is the C3D type code (-1 char, 1 byte, 2 int, 4 float).
    """
    if name in group:
        group[name]["value"] = value
    else:
        group[name] = {"type": ptype, "description": "", "is_locked": False, "value": value}


def _chunks(items: list[str], size: int) -> list[list[str]]:
    return [items[i : i + size] for i in range(0, len(items), size)]


def _header_events(raw: bytes) -> bytes:
    """The header event block of ``raw`` (bytes 298..468) in Intel byte order.

    ezc3d writes Intel files and drops header events; the block is copied
    over its output.  Times are the only multi-byte values to convert.
    """
    processor = raw[(raw[0] - 1) * _BLOCK + 3]
    block = bytearray(raw[_EVENTS_START:_EVENTS_STOP])
    if processor != _INTEL:
        word = _word_reader(raw, processor)
        block[0:4] = struct.pack("<HH", word(149), word(150))
        times = [_decode_float(raw[i : i + 4], processor) for i in range(_EVENT_TIMES.start, _EVENT_TIMES.stop, 4)]
        start = _EVENT_TIMES.start - _EVENTS_START
        block[start : start + 72] = struct.pack("<18f", *times)
    return bytes(block)
