"""BVH reading and writing.

The header is parsed here by hand and the MOTION block with numpy in float64
(bvhio is 20x slower, keeps float32 and reformats numbers; it serves as an
independent oracle in the tests).  Writing keeps the hierarchy, joint order,
channel order, End Sites and the frame time as written.  A motion read from a
file keeps that file's text: its header (offsets as written, indentation,
line endings) and, in the MOTION block, the source's own token and spacing for
every number that did not change, so an unchanged round trip gives back the
file byte for byte.  Other numbers are printed in the format the source used.
"""

from __future__ import annotations

import io
import os
import re
import warnings

import numpy as np

from ..errors import DataError
from ..motion import BvhMotion, frame_time_problem
from ..skeleton import POSITION_CHANNELS, ROTATION_CHANNELS, Skeleton

MAX_JOINTS = 10_000
MAX_HEADER_BYTES = 16 * 1024 * 1024
#: Largest magnitude of a number (offset or channel value).  No capture comes
#: near it (10^12 mm, or degrees); beyond it squares and products overflow.
MAX_MAGNITUDE = 1e12
_KNOWN_CHANNELS = set(POSITION_CHANNELS) | set(ROTATION_CHANNELS)
_NUMBER = re.compile(r"^[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?$")


def read_bvh(
    path: str | os.PathLike, data: bytes | None = None, name: str | None = None, max_values: int | None = None
) -> BvhMotion:
    """Read a BVH file (or its bytes) into a :class:`BvhMotion`.

    Parameters
    ----------
    path : the file to read (ignored for reading when ``data`` is given).
    data : the file's bytes, e.g. from stdin.
    name : the name used in error messages (default: ``path``).
    max_values : refuse, before reading them, more than this many channel
        values (frames x channels); None: no limit beyond the file size's.

    Raises
    ------
    DataError naming the file and, where it applies, the line or frame.
    """
    name = name or os.fspath(path)
    if data is None:
        try:
            with open(path, "rb") as fh:
                data = fh.read()
        except OSError as exc:
            raise DataError(f"cannot read: {exc.strerror or exc}", name) from None
    try:
        return parse_bvh(data, max_values)
    except DataError as exc:
        raise exc.with_source(name) from None


def parse_bvh(data: bytes, max_values: int | None = None) -> BvhMotion:
    """Parse BVH bytes.  See :func:`read_bvh`."""
    source = data
    if data.startswith((b"\xff\xfe", b"\xfe\xff")):
        raise DataError("is UTF-16 encoded; BVH files are plain ASCII text (save it as UTF-8)")
    if data.startswith(b"\xef\xbb\xbf"):
        data = data[3:]
    if b"\x00" in data[:4096]:
        raise DataError("is not a BVH file (binary data)")
    motion_at = _find_motion(data)
    if motion_at < 0:
        head = data[:2048].lstrip()
        if not head.upper().startswith(b"HIERARCHY"):
            raise DataError("is not a BVH file (no HIERARCHY keyword)" if data.strip() else "is empty")
        if len(data) > MAX_HEADER_BYTES:
            raise DataError(f"has no MOTION section in its first {MAX_HEADER_BYTES // 2**20} MiB")
        raise DataError("has no MOTION section (truncated?)")
    if motion_at > MAX_HEADER_BYTES:
        raise DataError(f"HIERARCHY is over {MAX_HEADER_BYTES // 2**20} MiB: not a plausible BVH header")
    try:
        header = data[:motion_at].decode("utf-8")
    except UnicodeDecodeError as exc:
        raise DataError(f"HIERARCHY is not text (byte {exc.start})") from None
    skeleton = _parse_hierarchy(header)
    header_lines = header.count("\n") + header.count("\r") - header.count("\r\n")
    channels, frame_time, frame_time_text, fmt = _parse_motion(
        data, motion_at, sum(len(c) for c in skeleton.channels), header_lines, max_values
    )
    return BvhMotion(skeleton, channels, frame_time, frame_time_text, fmt, source=source, source_values=channels)


def check_header(head: bytes) -> None:
    """Refuse, from the first ``MAX_HEADER_BYTES + 64`` bytes of a BVH, one
    whose HIERARCHY does not end within ``MAX_HEADER_BYTES`` (so that a huge
    file is refused without being read to its end)."""
    head = head.removeprefix(b"\xef\xbb\xbf")
    if len(head) > MAX_HEADER_BYTES and not 0 <= _find_motion(head) <= MAX_HEADER_BYTES:
        raise DataError(f"has no MOTION section in its first {MAX_HEADER_BYTES // 2**20} MiB")


_MOTION = re.compile(rb"(^|[\r\n])[ \t]*MOTION[ \t]*(\r\n|\r|\n|$)")


def _find_motion(data: bytes) -> int:
    # endpos: as if the data ended there ('$' matches), without a copy of the head
    m = _MOTION.search(data, 0, MAX_HEADER_BYTES + 64)
    return -1 if m is None else m.start() + len(m.group(1))


_HEADER_TOKEN = re.compile(r"\r\n|\r|\n|[{}]|[^\s{}]+")


def _tokens(header: str):
    """(token, line number) pairs; braces are tokens even when glued to words.

    Lazy, so that a header of millions of tokens (or 10^5 joints) is refused
    at the first error or limit without holding them all in memory.
    """
    lineno = 1
    for m in _HEADER_TOKEN.finditer(header):
        tok = m.group()
        if tok in ("\r\n", "\r", "\n"):
            lineno += 1
        else:
            yield tok, lineno


def _parse_hierarchy(header: str) -> Skeleton:
    stream = _tokens(header)
    nxt = next(stream, None)  # one token of look-ahead

    def take(expect: str | None = None) -> tuple[str, int]:
        nonlocal nxt
        if nxt is None:
            raise DataError(f"HIERARCHY ends early{f' (expected {expect})' if expect else ''}")
        tok, ln = nxt
        nxt = next(stream, None)
        if expect is not None and tok.upper() != expect.upper():
            raise DataError(f"line {ln}: expected {expect}, found {tok[:40]!r}")
        return tok, ln

    def number(ln_hint: int) -> float:
        tok, ln = take()
        if not _NUMBER.match(tok):
            raise DataError(f"line {ln}: expected a number, found {tok[:40]!r}")
        if not abs(float(tok)) <= MAX_MAGNITUDE:  # also '1e999', which reads as inf
            raise DataError(f"line {ln}: {tok[:40]!r} is too large (the limit is {MAX_MAGNITUDE:g})")
        return float(tok)

    take("HIERARCHY")
    names: list[str] = []
    parents: list[int] = []
    offsets: list[list[float]] = []
    channels: list[tuple[str, ...]] = []
    end_parents: list[int] = []
    end_offsets: list[list[float]] = []

    def joint_name(ln: int) -> str:
        # the name is the rest of the line (names may contain spaces), minus a glued brace
        parts = []
        while nxt is not None and nxt[1] == ln and nxt[0] != "{":
            if nxt[0] == "}":
                # a '}' in a name would be written back as an unbalanced brace
                raise DataError(f"line {ln}: unexpected '}}' in a joint name")
            parts.append(take()[0])
        if not parts:
            raise DataError(f"line {ln}: joint without a name")
        return " ".join(parts)

    declared: set[int] = set()  # joints whose CHANNELS line has been read

    def open_joint(parent: int, ln: int) -> int:
        """Read a joint's name, '{' and OFFSET; return its index."""
        name = joint_name(ln)
        if name in seen:
            raise DataError(f"line {ln}: duplicate joint name {name!r}")
        if len(names) >= MAX_JOINTS:
            raise DataError(f"more than {MAX_JOINTS} joints: not a plausible skeleton")
        seen.add(name)
        names.append(name)
        parents.append(parent)
        channels.append(())
        take("{")
        _, ln = take("OFFSET")
        offsets.append([number(ln) for _ in range(3)])
        return len(names) - 1

    seen: set[str] = set()
    # an explicit stack of the open joints: a chain of MAX_JOINTS joints
    # nests that deep, more than Python's recursion allows
    while nxt is not None:
        tok, ln = take()
        if tok.upper() != "ROOT":
            raise DataError(f"line {ln}: expected ROOT, found {tok[:40]!r}")
        stack = [open_joint(-1, ln)]
        while stack:
            j = stack[-1]
            tok, ln = take()
            key = tok.upper()
            if key == "CHANNELS":
                if j in declared:
                    raise DataError(f"line {ln}: second CHANNELS line for joint {names[j]!r}")
                declared.add(j)
                ntok, _ = take()
                # isascii: str.isdigit() also accepts '³' and other digits int() refuses
                if not (ntok.isascii() and ntok.isdigit()) or int(ntok) > 6:
                    raise DataError(f"line {ln}: bad channel count {ntok[:20]!r}")
                ch = tuple(take()[0] for _ in range(int(ntok)))
                for c in ch:
                    if c not in _KNOWN_CHANNELS:
                        raise DataError(f"line {ln}: unknown channel {c[:40]!r} for joint {names[j]!r}")
                if len(set(ch)) != len(ch):
                    raise DataError(f"line {ln}: repeated channel for joint {names[j]!r}")
                channels[j] = ch
            elif key == "JOINT":
                stack.append(open_joint(j, ln))
            elif key == "END":
                take("Site")
                take("{")
                _, ln2 = take("OFFSET")
                end_parents.append(j)
                end_offsets.append([number(ln2) for _ in range(3)])
                take("}")
            elif key == "}":
                stack.pop()
            else:
                raise DataError(f"line {ln}: unexpected {tok[:40]!r} in joint {names[j]!r}")
    if not names:
        raise DataError("HIERARCHY has no ROOT joint")
    return Skeleton(
        names=tuple(names),
        parents=np.array(parents, dtype=int),
        offsets=np.array(offsets, dtype=float).reshape(-1, 3),
        channels=tuple(channels),
        end_parents=np.array(end_parents, dtype=int),
        end_offsets=np.array(end_offsets, dtype=float).reshape(-1, 3),
    )


_FRAMES = re.compile(rb"^\s*Frames\s*:\s*(\S+)\s*$", re.IGNORECASE)
_FTIME = re.compile(rb"^\s*Frame\s+Time\s*:\s*(\S+)\s*$", re.IGNORECASE)


#: The slow path (ragged lines, errors) splits the MOTION block this many
#: bytes at a time (cut at line ends), so that it needs the file's bytes, the
#: values and one chunk, not copies of the whole text.
_CHUNK_BYTES = 1 << 23
_NON_ASCII = re.compile(rb"[\x80-\xff]")
_NON_SPACE = re.compile(rb"\S")


def _split_lines(data: bytes, start: int, count: int) -> tuple[list[bytes], int]:
    """The first ``count`` lines from ``start`` (fewer if the data ends) and
    where the rest begins, without copying the rest."""
    lines: list[bytes] = []
    pos = start
    for _ in range(count):
        nl = data.find(b"\n", pos)
        if nl < 0:
            lines.append(data[pos:])
            return lines, len(data)
        lines.append(data[pos:nl])
        pos = nl + 1
    return lines, pos


def _chunks(data: bytes, start: int, size: int = _CHUNK_BYTES):
    """``data[start:]`` in pieces of about ``size`` bytes ending at a line end."""
    for pos, end in _chunk_ranges(data, start, size):
        yield data[pos:end]


def _chunk_ranges(data: bytes, start: int, size: int = _CHUNK_BYTES):
    """The ``(start, end)`` offsets of :func:`_chunks`' pieces."""
    pos, end_all = start, len(data)
    while pos < end_all:
        end = data.find(b"\n", min(pos + size, end_all))
        end = end_all if end < 0 else end + 1
        yield pos, end
        pos = end


def _parse_motion(
    data: bytes, start: int, n_channels: int, first_line: int, max_values: int | None = None
) -> tuple[np.ndarray, float, str, str]:
    # data[start:] begins at the MOTION line
    lines, body_at = _split_lines(data, start, 3)
    if len(lines) < 3:
        # tolerate old-Mac CR-only files
        data, start = data[start:].replace(b"\r\n", b"\n").replace(b"\r", b"\n"), 0
        lines, body_at = _split_lines(data, start, 3)
    if len(lines) < 3:
        raise DataError("MOTION section ends before 'Frames:' and 'Frame Time:' (truncated?)")
    m_frames = _FRAMES.match(lines[1])
    if not m_frames:
        raise DataError(f"line {first_line + 2}: expected 'Frames: N' after MOTION")
    m_time = _FTIME.match(lines[2])
    if not m_time:
        raise DataError(f"line {first_line + 3}: expected 'Frame Time: seconds'")
    try:
        n_frames = int(m_frames.group(1))
    except ValueError:
        count = m_frames.group(1)[:20].decode(errors="replace")
        raise DataError(f"line {first_line + 2}: frame count {count!r} is not a whole number") from None
    ft_text = m_time.group(1).decode("ascii", errors="replace")
    # the grammar of every other number here (float() alone takes '0.01_6667', 'inf', 'nan')
    if not _NUMBER.match(ft_text):
        raise DataError(f"line {first_line + 3}: frame time {ft_text[:20]!r} is not a number")
    frame_time = float(ft_text)
    if not np.isfinite(frame_time) or frame_time <= 0:
        raise DataError(f"line {first_line + 3}: frame time {ft_text[:20]!r} is not a positive number")
    problem = frame_time_problem(frame_time)
    if problem is not None:
        raise DataError(f"line {first_line + 3}: frame time {ft_text[:20]} {problem}")
    if n_frames < 0:
        raise DataError(f"line {first_line + 2}: frame count {n_frames} is negative")
    if n_frames == 0:
        raise DataError("has no motion frames (Frames: 0)")
    if n_channels == 0:
        raise DataError("no joint has CHANNELS")
    if max_values is not None and n_frames * n_channels > max_values:
        raise DataError(
            f"has {n_frames:,} frames of {n_channels} channels ({n_frames * n_channels:,} values): "
            f"more than the limit of {max_values:,} values (frames x channels): cut it into parts"
        )
    bad = None if _is_ascii(data, body_at) else _NON_ASCII.search(data, body_at)
    if bad is not None:
        raise DataError(f"MOTION data is not text (byte {bad.start() - body_at} of the data)")

    def text() -> str:  # the whole block, for the messages of the error paths only
        return data[body_at:].decode("ascii")

    # every value takes a character and a separator: more declared than that
    # cannot be there (and must not be allocated)
    if _NON_SPACE.search(data, body_at) is None or n_frames * n_channels > (len(data) - body_at + 1) // 2:
        _explain_count(text(), n_frames, n_channels, first_line + 4)
    values = _fast_values(data, body_at, n_frames, n_channels)
    if values is None:  # ragged lines or odd tokens: the slow path says exactly where
        values, wrong = _slow_values(data, body_at, n_frames, n_channels)
        if values is None:
            if wrong == "count":
                _explain_count(text(), n_frames, n_channels, first_line + 4)
            _explain_values(text(), first_line + 4)
            raise DataError("MOTION data does not parse")  # not reached: the two above explain
    lo, hi = float(values.min()), float(values.max())
    if not (np.isfinite(lo) and np.isfinite(hi)):
        bad_at = int(np.flatnonzero(~np.isfinite(values.ravel()))[0])
        raise DataError(f"frame {bad_at // n_channels}: a value is not a finite number ({values.ravel()[bad_at]})")
    if max(-lo, hi) > MAX_MAGNITUDE:
        bad_at = int(np.argmax(np.abs(values.ravel()) > MAX_MAGNITUDE))
        raise DataError(
            f"frame {bad_at // n_channels}: value {values.ravel()[bad_at]:g} is too large "
            f"(the limit is {MAX_MAGNITUDE:g})"
        )
    head = data[body_at : body_at + 200_000].decode("ascii")
    sample = head.split() if len(data) - body_at <= len(head) else head.rsplit(None, 1)[0].split()
    fmt = _number_format(sample, values.ravel())
    tail = data[max(body_at, len(data) - 4096) :]
    if fmt.endswith("f") and not tail.rstrip(b" \t").endswith((b"\n", b"\r")):
        # no final newline and a last number shorter than all the others: cut off
        last, decimals = tail.decode("ascii").rsplit(None, 1)[-1], int(fmt[2:-1])
        if decimals > 0 and "." not in last or "." in last and len(last) - last.index(".") - 1 < decimals:
            raise DataError(f"frame {n_frames - 1}: the last line is cut off after {last[:20]!r} (truncated?)")
    return values, frame_time, ft_text, fmt


def _fast_values(data: bytes, start: int, n_frames: int, n_channels: int) -> np.ndarray | None:
    """The MOTION block as (frames, channels) with numpy's C parser, or None
    when it does not parse as ``n_frames`` lines of ``n_channels`` numbers
    (then the slow path reads it, or explains).

    The parser reads the file's own bytes (a ``BytesIO`` over ``data``
    shares its buffer) into an array of the declared size: no copy of the
    text, no growing of the result.  The caller has checked that the block
    is ASCII and holds something other than white space.
    """
    if data.find(b"_", start) >= 0:  # loadtxt, like float(), reads '1_000'
        return None
    stream = io.BytesIO(data)
    stream.seek(start)
    with warnings.catch_warnings():
        # with max_rows, numpy warns that blank lines do not count as rows
        warnings.filterwarnings("ignore", "Input line", UserWarning)
        try:
            # one row more than declared: a longer block shows as a wrong count
            vals = np.loadtxt(stream, dtype=float, ndmin=2, comments=None, max_rows=n_frames + 1)
        except ValueError:
            return None
    return vals if vals.shape == (n_frames, n_channels) else None


def _is_ascii(data: bytes, start: int, block: int = 1 << 24) -> bool:
    """``data[start:]`` is ASCII (tested a block at a time: no copy of the whole)."""
    return all(data[i : i + block].isascii() for i in range(start, len(data), block))


def _slow_values(data: bytes, start: int, n_frames: int, n_channels: int) -> tuple[np.ndarray | None, str]:
    """The values of a MOTION block whose lines are ragged (the count of all
    its numbers is what matters), chunk by chunk.  Returns the values and "",
    or None and what is wrong: "count" (not frames x channels numbers) or
    "value" (a token that is not a number)."""
    total = n_frames * n_channels
    out = np.empty(total)
    k = 0
    bad_value = data.find(b"_", start) >= 0  # Python's float() reads '1_000'; no BVH reader does
    for piece in _chunks(data, start):
        tokens = piece.split()
        if k + len(tokens) > total:
            return None, "count"
        if not bad_value:
            try:
                out[k : k + len(tokens)] = [float(t) for t in tokens]
            except ValueError:
                bad_value = True
        k += len(tokens)
    if k != total:
        return None, "count"
    return (None, "value") if bad_value else (out.reshape(n_frames, n_channels), "")


def _explain_count(text: str, n_frames: int, n_channels: int, first_line: int) -> None:
    rows = [ln for ln in text.splitlines()]
    frame = 0
    for i, ln in enumerate(rows):
        n = len(ln.split())
        if n == 0:
            continue
        if n != n_channels:
            raise DataError(
                f"line {first_line + i}: frame {frame} has {n} values, the HIERARCHY declares {n_channels} channels"
            )
        frame += 1
    if frame < n_frames:
        raise DataError(f"declares {n_frames} frames but has {frame} (truncated?)")
    raise DataError(f"declares {n_frames} frames but has {frame}")


def _explain_values(text: str, first_line: int) -> None:
    for i, ln in enumerate(text.splitlines()):
        for tok in ln.split():
            try:
                if "_" in tok:
                    raise ValueError
                float(tok)
            except ValueError:
                raise DataError(f"line {first_line + i}: {tok[:40]!r} is not a number") from None


def _number_format(tokens: list[str], values: np.ndarray) -> str:
    """A printf format that reproduces every one of the file's numbers.

    Fixed decimals when every value has at most that many (checked on all
    values, vectorized), else significant digits, else full precision.
    """
    step = max(1, len(tokens) // 4000)
    sample = tokens[::step]
    exponents = "e" in (text := " ".join(sample)) or "E" in text
    if exponents:
        decimals = max((len(t) - t.index(".") - 1 if "." in t and "e" not in t.lower() else 0) for t in sample)
    else:  # no exponents (most files): the same count in fewer string operations a token
        decimals = max(map(len, [t.partition(".")[2] for t in sample]))
    if decimals <= 12 and _whole_scaled(values, 10.0**decimals):
        return f"%.{decimals}f"
    # the significant digits are counted only where fixed decimals do not do
    # (the CMU files' numbers are fixed: counting them took a third of this)
    if exponents:
        digits = max(len(t.lower().split("e")[0].lstrip("+-").replace(".", "").lstrip("0")) for t in sample)
    else:
        digits = max(map(len, [t.lstrip("+-").replace(".", "").lstrip("0") for t in sample]))
    if digits <= 17 and all(_whole(part * _scale_to_digits(part, max(digits, 1))) for part in _nonzero_blocks(values)):
        return f"%.{max(digits, 1)}g"
    return "%.17g"


def _scale_to_digits(part: np.ndarray, digits: int) -> np.ndarray:
    """``10 ** (digits - 1 - floor(log10 |part|))``: the factor that makes a
    value of ``part`` (none zero) whole when it has ``digits`` significant
    digits.  The powers are taken from a table of the few exponents met (the
    same ``10.0 ** e``, the same bits), not one ``pow`` a value: a third of
    the check's time on a file of ``%g`` numbers."""
    e = (digits - 1) - np.floor(np.log10(np.abs(part)))
    if e.size == 0:
        return e
    lo = e.min()
    table = 10.0 ** np.arange(lo, e.max() + 1.0)
    return table[(e - lo).astype(np.intp)]


def _whole(scaled: np.ndarray) -> bool:
    # a value printed with that many digits is a whole number once scaled, up
    # to the rounding of the scaling itself
    return bool(np.all(np.abs(scaled - np.rint(scaled)) <= 1e-7 * np.maximum(1.0, np.abs(scaled)) + 1e-9))


#: Values per block of the vectorized checks of a whole MOTION block: their
#: temporaries (a few arrays of a block each) stay in cache, and a format
#: that does not fit is refused on the first block (256 kB each).
_BLOCK = 1 << 15


def _nonzero_blocks(values: np.ndarray):
    return (block[block != 0.0] for block in (values[i : i + _BLOCK] for i in range(0, len(values), _BLOCK)))


def _whole_scaled(values: np.ndarray, scale, block: int = _BLOCK) -> bool:
    """``_whole(values * scale)`` a block at a time (``scale`` a number or an
    array like ``values``): no temporaries the size of a long clip."""
    for i in range(0, len(values), block):
        part = scale if np.ndim(scale) == 0 else scale[i : i + block]
        if not _whole(values[i : i + block] * part):
            return False
    return True


def _fmt_number(x: float) -> str:
    s = repr(float(x))
    return s[:-2] if s.endswith(".0") else s


def check_writable(motion: BvhMotion) -> None:
    """Refuse to write a BVH that :func:`read_bvh` would refuse: numbers
    beyond :data:`MAX_MAGNITUDE` (or not finite), a frame time out of range
    or not in the reader's number grammar.  Raises ``DataError``."""
    sk = motion.skeleton
    for what, values in (("joint offset", sk.offsets), ("End Site offset", sk.end_offsets)):
        if values.size and not np.all(np.abs(values) <= MAX_MAGNITUDE):
            raise DataError(f"cannot write the BVH: a {what} is beyond ±{MAX_MAGNITUDE:g} (the BVH reader's limit)")
    ch = motion.channels
    rows = max(1, (1 << 18) // max(ch.shape[1], 1))  # a block at a time: no temporaries of the clip
    if ch.size and not all(np.all(np.abs(ch[lo : lo + rows]) <= MAX_MAGNITUDE) for lo in range(0, len(ch), rows)):
        bad = int(np.flatnonzero(~(np.abs(ch.ravel()) <= MAX_MAGNITUDE))[0])
        frame, col = divmod(bad, ch.shape[1])
        raise DataError(
            f"cannot write the BVH: frame {frame}, channel {col} would be {ch.ravel()[bad]:g}, "
            f"beyond ±{MAX_MAGNITUDE:g} (the BVH reader's limit)"
        )
    text = motion.frame_time_text or _fmt_number(motion.frame_time)
    problem = "is not a number" if not _NUMBER.match(text) else frame_time_problem(float(text))
    if problem is not None:
        raise DataError(f"cannot write the BVH: frame time {text[:20]} {problem}")


def bvh_bytes(motion: BvhMotion) -> bytes:
    """The BVH file of ``motion`` as bytes (see :func:`bvh_pieces`)."""
    return b"".join(bvh_pieces(motion))


def bvh_pieces(motion: BvhMotion) -> list:
    """The BVH file of ``motion`` as bytes-like pieces to write one after the
    other (what is kept of the source's text is a view of it, not a copy).

    With ``motion.source`` (the file it was read from, same skeleton) the
    source's text is kept: the header as written (only the ``Frames:`` and
    ``Frame Time:`` values follow the motion) and, at the same frame count,
    the source's token and spacing for every number equal to the source's
    value at that place; changed numbers are printed with
    ``motion.number_format``.  Without a usable source: tab-indented header,
    LF line endings, every number in ``motion.number_format``.

    Raises ``DataError`` for a motion the reader would refuse
    (:func:`check_writable`): a command never writes what it cannot read back.
    """
    check_writable(motion)
    if motion.source:
        kept = _in_source_layout(motion)
        if kept is not None:
            return kept
    sk = motion.skeleton
    out: list[str] = ["HIERARCHY"]
    ends: dict[int, list[np.ndarray]] = {}
    for p, o in zip(sk.end_parents, sk.end_offsets, strict=True):
        ends.setdefault(int(p), []).append(o)
    children: dict[int, list[int]] = {}
    for j, p in enumerate(sk.parents):
        children.setdefault(int(p), []).append(j)

    # depth first with an explicit stack (a chain of 10^4 joints is as deep
    # as it is long): ("open", j, depth) writes joint j and queues its
    # children, then ("close", j, depth) writes its End Sites and brace
    stack: list[tuple[bool, int, int]] = [(True, r, 0) for r in reversed(children.get(-1, []))]
    while stack:
        opening, j, depth = stack.pop()
        ind = "\t" * depth
        if opening:
            out.append(f"{ind}{'ROOT' if sk.parents[j] < 0 else 'JOINT'} {sk.names[j]}")
            out.append(f"{ind}{{")
            out.append(f"{ind}\tOFFSET {' '.join(_fmt_number(v) for v in sk.offsets[j])}")
            if sk.channels[j]:
                out.append(f"{ind}\tCHANNELS {len(sk.channels[j])} {' '.join(sk.channels[j])}")
            stack.append((False, j, depth))
            stack.extend((True, c, depth + 1) for c in reversed(children.get(j, [])))
            continue
        for o in ends.get(j, []):
            out.extend(
                [
                    f"{ind}\tEnd Site",
                    f"{ind}\t{{",
                    f"{ind}\t\tOFFSET {' '.join(_fmt_number(v) for v in o)}",
                    f"{ind}\t}}",
                ]
            )
        out.append(f"{ind}}}")

    ch = motion.channels
    out += [
        "MOTION",
        f"Frames: {ch.shape[0]}",
        f"Frame Time: {motion.frame_time_text or _fmt_number(motion.frame_time)}",
    ]
    header = "\n".join(out) + "\n"
    if ch.shape[0] == 0:
        return [header.encode("utf-8")]
    row = " ".join([motion.number_format] * ch.shape[1]) + "\n"
    # one % over the whole block: the fastest pure-Python formatting
    flat = ch.ravel().tolist()
    body = (row * ch.shape[0]) % tuple(flat)
    return [(header + body).encode("utf-8")]


_LINE = re.compile(rb"[^\r\n]*(?:\r\n|\r|\n|$)")
_FRAMES_LINE = re.compile(rb"^(\s*Frames\s*:\s*)(\S+)(.*)$", re.IGNORECASE | re.DOTALL)
_FTIME_LINE = re.compile(rb"^(\s*Frame\s+Time\s*:\s*)(\S+)(.*)$", re.IGNORECASE | re.DOTALL)


def _same_skeleton(a: Skeleton, b: Skeleton) -> bool:
    return (
        a.names == b.names
        and a.channels == b.channels
        and np.array_equal(a.parents, b.parents)
        and np.array_equal(a.offsets, b.offsets)
        and np.array_equal(a.end_parents, b.end_parents)
        and np.array_equal(a.end_offsets, b.end_offsets)
    )


def _in_source_layout(motion: BvhMotion) -> list | None:
    """``motion`` written in the text of ``motion.source`` (see :func:`bvh_bytes`),
    or None when the source is not a BVH of the same skeleton."""
    data = motion.source
    bom = b"\xef\xbb\xbf" if data.startswith(b"\xef\xbb\xbf") else b""
    data = data[len(bom) :]
    at = _find_motion(data)
    if at < 0:
        return None
    try:
        if not _same_skeleton(_parse_hierarchy(data[:at].decode("utf-8")), motion.skeleton):
            return None
    except (DataError, UnicodeDecodeError):
        return None
    lines, pos = [], at
    for _ in range(3):  # MOTION, Frames:, Frame Time:
        m = _LINE.match(data, pos)
        if m is None or m.end() == pos:
            return None
        lines.append(m.group())
        pos = m.end()
    frames, ftime = _FRAMES_LINE.match(lines[1]), _FTIME_LINE.match(lines[2])
    if frames is None or ftime is None:
        return None
    ch = motion.channels
    T, C = ch.shape
    text = motion.frame_time_text or _fmt_number(motion.frame_time)
    lines[1] = frames.group(1) + str(T).encode() + frames.group(3)
    lines[2] = ftime.group(1) + text.encode("ascii") + ftime.group(3)
    head = bom + data[:at] + b"".join(lines)
    if T == 0:
        return [head]
    kept = _kept_numbers(data, pos, ch, motion.number_format, motion.source_values)
    if kept is None:  # another frame count (a resampled bake): the source's line ending
        newline = lines[2][len(lines[2].rstrip(b"\r\n")) :] or b"\n"
        row = " ".join([motion.number_format] * C) + newline.decode("ascii")
        return [head + ((row * T) % tuple(ch.ravel().tolist())).encode("ascii")]
    return [head, *kept]


#: The writer rewrites the source's MOTION block this many bytes at a time:
#: its offsets and gathers then take a few tens of MB, not ten times the file.
_WRITE_CHUNK_BYTES = 1 << 20


def _kept_numbers(
    data: bytes, start: int, channels: np.ndarray, fmt: str, source_values: np.ndarray | None = None
) -> list[bytes] | None:
    """The source's MOTION block ``data[start:]``, in pieces to join, with
    every number that is not the value at its place in ``channels`` (T, C)
    printed with ``fmt`` and every other token and all the white space kept;
    None unless the block holds exactly T * C plain numbers.

    ``source_values``: the block's numbers as the reader read them (frame by
    frame, in the order of the text), so that they need not be parsed again.
    """
    if data.find(b"_", start) >= 0 or not _is_ascii(data, start):
        return None
    T, C = channels.shape
    changed_rows = None
    if channels.size and _NON_SPACE.search(data, start) is not None:
        # when no number changed (a round trip) the block is the source's,
        # and no token need be looked at; with one frame a line and no blank
        # line, only the lines that changed are
        if source_values is not None:
            found = _changed_from_values(channels, source_values)
        else:
            found = _changed_rows(data, start, channels)
        if found is not None:
            rows, values = found
            if not rows.any():
                return [memoryview(data)[start:]]  # the source's own block: a view, not a copy
            lines = data.count(b"\n", start) + (not data.endswith(b"\n"))
            if lines == T:
                changed_rows = rows
    if changed_rows is not None:
        # values the reader read need the count of each piece kept whole
        # checked (the parse here checks it: one frame a line)
        kept = _replace_tokens(data, start, channels, fmt, changed_rows, values, count_kept=source_values is not None)
        if kept is not None:
            return kept
    return _replace_tokens(data, start, channels, fmt)


def _changed_from_values(channels: np.ndarray, source_values: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """:func:`_changed_rows` from the numbers the reader read (T, C), without
    parsing: which frames of ``channels`` differ, and those numbers; None
    when they are not T frames of C numbers."""
    if source_values.shape != channels.shape:
        return None
    T = len(channels)
    rows = np.empty(T, dtype=bool)
    step = max(1, _COMPARE_VALUES // max(channels.shape[1], 1))
    for lo in range(0, T, step):  # a block at a time: no temporaries of the clip
        np.any(channels[lo : lo + step] != source_values[lo : lo + step], axis=1, out=rows[lo : lo + step])
    return rows, source_values


#: Values compared at once by :func:`_changed_from_values`.
_COMPARE_VALUES = 1 << 18
#: The bytes that separate numbers (what ``bytes.split()`` and ``rb"\\s"`` split on).
_IS_SPACE = np.zeros(256, dtype=bool)
_IS_SPACE[list(b" \t\n\r\f\v")] = True


def _count_tokens(data: bytes, a: int, b: int) -> int:
    """The number of white-space separated tokens in ``data[a:b]``, counted
    on the bytes (no token objects)."""
    if b <= a:
        return 0
    space = _IS_SPACE[np.frombuffer(data, dtype=np.uint8, count=b - a, offset=a)]
    return int(not space[0]) + int(np.count_nonzero(space[:-1] > space[1:]))


def _changed_rows(data: bytes, start: int, channels: np.ndarray) -> tuple[np.ndarray, _SourceRows | None] | None:
    """Which frames (T,) of ``channels`` (T, C) differ from the numbers of the
    MOTION block ``data[start:]``, and the block's values by frame if any
    does (:class:`_SourceRows`: ``channels`` itself where equal); None when
    the block does not parse as T lines of C numbers.

    The block is parsed like :func:`_fast_values`, a few MB of lines at a
    time, so that a round trip (nothing changed) keeps no parsed copy of
    the clip.
    """
    T, C = channels.shape
    rows = np.zeros(T, dtype=bool)
    n, pos, end = 0, start, len(data)
    changed: list[tuple[int, np.ndarray]] = []
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", "Input line", UserWarning)
        warnings.filterwarnings("ignore", ".*no data", UserWarning)  # a piece of blank lines
        while pos < end:
            cut = data.find(b"\n", min(pos + _PARSE_CHUNK_BYTES, end - 1))
            stop = end if cut < 0 else cut + 1
            try:
                vals = np.loadtxt(io.BytesIO(data[pos:stop]), dtype=float, ndmin=2, comments=None)
            except ValueError:
                return None
            pos = stop
            if vals.size == 0:
                continue
            if vals.shape[1] != C or n + len(vals) > T:
                return None
            differ = np.any(vals != channels[n : n + len(vals)], axis=1)
            if differ.any():
                changed.append((n, vals))
                rows[n : n + len(vals)] = differ
            n += len(vals)
    if n != T:
        return None
    return rows, (_SourceRows(channels, changed) if changed else None)


class _SourceRows:
    """The values of a MOTION block by frame, ``[lo:hi]`` -> (hi - lo, C):
    ``channels`` where they equal the block's numbers, the parsed values of
    the pieces where some differ (only those are kept)."""

    def __init__(self, channels: np.ndarray, pieces: list[tuple[int, np.ndarray]]) -> None:
        self.channels = channels
        self.pieces = pieces

    def __getitem__(self, rows: slice) -> np.ndarray:
        lo, hi, _ = rows.indices(len(self.channels))
        out = np.array(self.channels[lo:hi], dtype=float, copy=True)
        for n0, vals in self.pieces:
            a, b = max(lo, n0), min(hi, n0 + len(vals))
            if a < b:
                out[a - lo : b - lo] = vals[a - n0 : b - n0]
        return out


#: Bytes of the MOTION block :func:`_changed_rows` parses at once.
_PARSE_CHUNK_BYTES = 1 << 22


def _replace_tokens(
    data: bytes,
    start: int,
    channels: np.ndarray,
    fmt: str,
    changed_rows: np.ndarray | None = None,
    source: np.ndarray | _SourceRows | None = None,
    count_kept: bool = False,
) -> list[bytes] | None:
    """:func:`_kept_numbers` a piece of :data:`_WRITE_CHUNK_BYTES` at a time.
    With ``changed_rows`` (T,) and the ``source`` values (T, C) (the block is
    one frame a line), pieces without a changed frame are kept whole and the
    others' numbers are not parsed again.  ``count_kept``: a piece kept whole
    must also hold its lines' C numbers each, in all (else None: the lines
    are not the frames)."""
    flat = channels.ravel()
    C = channels.shape[1]
    out: list = []
    view = memoryview(data)  # pieces kept as they are go out as views of the source, not copies
    k, row, total = 0, 0, len(flat)
    for a, b in _chunk_ranges(data, start, _WRITE_CHUNK_BYTES):
        if changed_rows is not None:
            n_rows = data.count(b"\n", a, b) + (data[b - 1 : b] != b"\n")
            if not changed_rows[row : row + n_rows].any():
                if count_kept and _count_tokens(data, a, b) != n_rows * C:
                    return None
                out.append(view[a:b])
                row, k = row + n_rows, k + n_rows * C
                continue
        starts, ends = _token_spans(data, a, b)
        n = len(starts)
        if k + n > total or (changed_rows is not None and n != n_rows * C):
            return None
        piece = view[a:b]
        if n:
            if source is not None:
                values = source[row : row + n_rows].ravel()
            else:
                try:
                    values = np.array(data[a:b].split(), dtype=float)
                except ValueError:
                    return None
            changed = np.flatnonzero(values != flat[k : k + n])
            if len(changed):
                new = (" ".join([fmt] * len(changed)) % tuple(flat[k + changed].tolist())).encode("ascii")
                piece = _spliced(data, a, b, starts[changed], ends[changed], new)
        out.append(piece)
        k += n
        if changed_rows is not None:
            row += n_rows
    return out if k == total else None


def _token_spans(data: bytes, a: int, b: int) -> tuple[np.ndarray, np.ndarray]:
    """Offsets (from ``a``) of the starts and ends of the white-space
    separated tokens of ``data[a:b]``, found on the bytes (no token objects)."""
    word = ~_IS_SPACE[np.frombuffer(data, dtype=np.uint8, count=b - a, offset=a)]
    edge = np.diff(word.view(np.int8), prepend=np.int8(0), append=np.int8(0))
    return np.flatnonzero(edge == 1), np.flatnonzero(edge == -1)


def _spliced(data: bytes, a: int, b: int, starts: np.ndarray, ends: np.ndarray, new: bytes) -> bytes:
    """``data[a:b]`` with its tokens at ``[starts[j], ends[j])`` (increasing
    offsets from ``a``) replaced by the space-separated tokens of ``new``, in
    order, and every other byte kept: one gather over the piece and ``new``
    (a Python object per token took 4x as long)."""
    buf = np.frombuffer(data, dtype=np.uint8, count=b - a, offset=a)
    nb = np.frombuffer(new, dtype=np.uint8)
    gaps = np.flatnonzero(nb == ord(" "))
    m = len(starts)
    # segments: the bytes kept before each replaced token (and after the
    # last), interleaved with the new tokens; as offsets into buf + new
    src = np.empty(2 * m + 1, dtype=np.int64)
    size = np.empty(2 * m + 1, dtype=np.int64)
    src[0] = 0
    src[2::2] = ends
    size[0:-1:2] = starts - src[0:-1:2]
    size[-1] = len(buf) - src[-1]
    new_start = np.concatenate([[0], gaps + 1])
    src[1::2] = len(buf) + new_start
    size[1::2] = np.concatenate([gaps, [len(nb)]]) - new_start
    at = np.cumsum(size) - size  # where each segment goes in the output
    index = np.repeat(src - at, size) + np.arange(int(at[-1] + size[-1]))
    return np.concatenate([buf, nb])[index].tobytes()


def write_bvh(path: str | os.PathLike, motion: BvhMotion, force: bool = True) -> None:
    """Write ``motion`` to ``path`` atomically (temp file, then rename)."""
    from .files import write_atomic

    write_atomic(os.fspath(path), bvh_pieces(motion), force=force)
