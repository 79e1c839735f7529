"""The byte layer of the staggered-pose document (SPEC section 7).

A document is a JSON-able *manifest* plus named numeric *arrays*.  This
module turns ``(manifest, arrays)`` into bytes and back, and a
:class:`~staggered_cli.document.Document` into ``(manifest, arrays)`` and
back (:func:`to_parts`, :func:`from_parts`: the schema and its validation).

Two containers, both read by every command:

* **npz** -- a zip whose members are ``manifest.json`` and one ``NAME.npy``
  per array (NumPy's ``.npy`` format, readable by ``np.load``).  The member
  ``manifest.json`` is the *envelope*::

      {"arrays": {NAME: {"dtype": "float64", "shape": [T, J, 4]}, ...},
       "format": "staggered-poses", "manifest": {...}, "version": 1}

  Members are stored uncompressed in sorted order with fixed timestamps, so
  the same content always gives the same bytes.
* **json** -- one JSON text with the same envelope, where each array entry
  also has ``"values"``: the elements in C order as one flat list (one row of
  the last axis per line).  Floats are written with Python's shortest
  round-trip repr, so JSON -> arrays is exact; non-finite values are the
  strings ``"NaN"``, ``"Infinity"`` and ``"-Infinity"``; ``-0.0`` is kept.

Reading never unpickles and checks every declared size (zip members,
``.npy`` headers, shapes) against limits *before* reading or inflating
anything, so a crafted file is refused with a one-line :class:`DataError`.
"""

from __future__ import annotations

import ast
import hashlib
import io
import json
import logging
import math
import mmap
import os
import re
import struct
import zipfile
import zlib
from typing import Any

import numpy as np

from ..errors import DataError
from ..model.document import MAX_LAYERS, Constraint, Document, variable_layout
from ..model.kinds import ROTATION, TRANSLATION
from ..model.knots import Knots, Layer, Track
from ..motion import BvhMotion, MarkerMotion, frame_time_problem, rate_problem
from ..skeleton import POSITION_CHANNELS, ROTATION_CHANNELS

FORMAT_NAME = "staggered-poses"
#: The container's version (the envelope and its array encoding).
FORMAT_VERSION = 1
#: The schema's version (what the manifest and arrays mean): 2 has layers.
DOCUMENT_VERSION = 2

log = logging.getLogger(__name__)

MANIFEST_MEMBER = "manifest.json"

#: dtypes an array may have, by name (the only ones written or read).
ALLOWED_DTYPES = {
    "float64": np.dtype(np.float64),
    "int64": np.dtype(np.int64),
    "bool": np.dtype(np.bool_),
    "uint8": np.dtype(np.uint8),
}

#: Largest single array, in bytes.
MAX_ARRAY_BYTES = 2 << 30
#: Largest sum of all arrays (and of all zip members), in bytes.
MAX_TOTAL_BYTES = 4 << 30
#: Largest manifest.json member, in bytes.
MAX_MANIFEST_BYTES = 64 << 20
#: Most arrays (zip members) in one document.
MAX_ARRAYS = 10_000
#: Deflated members may inflate to at most this many times their compressed
#: size in total, plus :data:`INFLATE_ALLOWANCE` bytes (arrays of floats
#: deflate less than 2:1, a zip bomb over 1000:1), so that what reading
#: allocates follows the size of the file.
MAX_INFLATE_RATIO = 20
INFLATE_ALLOWANCE = 16 << 20
#: Most dimensions of one array.
MAX_NDIM = 32

_NPY_MAGIC = b"\x93NUMPY"
_MAX_NPY_HEADER = 1 << 16
_ZIP_MAGICS = (b"PK\x03\x04", b"PK\x05\x06")
_ZIP_DATE = (1980, 1, 1, 0, 0, 0)
_NAME_RE = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.\-]*(/[A-Za-z0-9_][A-Za-z0-9_.\-]*)*")
_NONFINITE_TEXT = {"NaN": math.nan, "Infinity": math.inf, "-Infinity": -math.inf}
_DESCR_RE = re.compile(r"[<>|=]?[fiub][1-8]")


# --------------------------------------------------------------------------- writing


def _dtype_name(name: str, arr: np.ndarray) -> str:
    for dname, dtype in ALLOWED_DTYPES.items():
        if arr.dtype == dtype or (arr.dtype.kind == dtype.kind and arr.dtype.itemsize == dtype.itemsize):
            return dname
    raise ValueError(
        f"array {name!r} has dtype {arr.dtype}; documents hold only {', '.join(ALLOWED_DTYPES)} (convert it first)"
    )


def _check_name(name: Any) -> str:
    if not isinstance(name, str) or not _NAME_RE.fullmatch(name) or ".." in name.split("/") or len(name) > 200:
        raise ValueError(f"bad array name {name!r}: use letters, digits, '_', '.', '-' and '/' between parts")
    return name


def _json_default(obj: Any) -> Any:
    if isinstance(obj, np.bool_):
        return bool(obj)
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, np.floating):
        return float(obj)
    raise TypeError(f"manifest value of type {type(obj).__name__} is not JSON (put arrays in `arrays`)")


def _dump_manifest(manifest: dict, indent: int | None) -> str:
    if not isinstance(manifest, dict):
        raise TypeError(f"manifest must be a dict, not {type(manifest).__name__}")
    try:
        return json.dumps(
            manifest, sort_keys=True, indent=indent, allow_nan=False, ensure_ascii=False, default=_json_default
        )
    except ValueError as err:  # NaN or inf: not JSON
        raise ValueError(f"manifest holds a non-finite float ({err}); store it in an array instead") from None


def _canonical(arrays: dict[str, np.ndarray]) -> list[tuple[str, str, np.ndarray]]:
    """(name, dtype name, little-endian C-contiguous array), sorted by name."""
    if not isinstance(arrays, dict):
        raise TypeError(f"arrays must be a dict, not {type(arrays).__name__}")
    out = []
    for name in sorted(arrays):
        _check_name(name)
        arr = np.asarray(arrays[name])
        dname = _dtype_name(name, arr)
        if arr.ndim > MAX_NDIM:
            raise ValueError(f"array {name!r} has {arr.ndim} dimensions (at most {MAX_NDIM})")
        arr = np.asarray(arr, dtype=ALLOWED_DTYPES[dname].newbyteorder("<"), order="C")
        out.append((name, dname, arr))
    return out


def _npy_parts(arr: np.ndarray) -> list:
    """``.npy`` version 1.0 bytes of a little-endian C-contiguous array, as
    its header and a view of its data (not copied).

    The header is written here rather than by NumPy so that the bytes do not
    depend on the NumPy version.
    """
    header = f"{{'descr': {arr.dtype.str!r}, 'fortran_order': False, 'shape': {tuple(arr.shape)!r}, }}"
    # magic (6) + version (2) + length (2) + header + padding + '\n' is a multiple of 64
    pad = -(10 + len(header) + 1) % 64
    header_bytes = (header + " " * pad + "\n").encode("latin1")
    head = _NPY_MAGIC + b"\x01\x00" + len(header_bytes).to_bytes(2, "little") + header_bytes
    if arr.size == 0:
        return [head]
    return [head, memoryview(arr.reshape(-1)).cast("B")]


def _zip_member(zf: zipfile.ZipFile, name: str, parts: list) -> None:
    """Store the member ``name`` whose bytes are the concatenation of ``parts``
    (bytes-like), written through without joining them: the same bytes as
    ``writestr`` of the joined data (which sets the size first, then writes)."""
    info = zipfile.ZipInfo(name, date_time=_ZIP_DATE)
    info.compress_type = zipfile.ZIP_STORED
    info.create_system = 3  # unix, so that the mode bits below mean the same everywhere
    info.external_attr = 0o100644 << 16
    info.file_size = sum(memoryview(p).nbytes for p in parts)
    with zf.open(info, mode="w") as dest:
        for part in parts:
            dest.write(part)


class _Pieces:
    """A seekable sink that keeps what is written as a list of pieces
    without copying them (a zip member's data is a view of its array).

    ``zipfile`` writes forward, and overwrites only a member's local header
    once its CRC is known, with a header of the same length: that is the one
    rewrite supported."""

    def __init__(self) -> None:
        self.pieces: list = []
        self._starts: dict[int, int] = {}  # offset -> index of the piece starting there
        self._end = 0
        self._pos = 0

    def tell(self) -> int:
        return self._pos

    def seek(self, pos: int, whence: int = 0) -> int:
        self._pos = {0: pos, 1: self._pos + pos, 2: self._end + pos}[whence]
        return self._pos

    def write(self, data) -> int:
        n = memoryview(data).nbytes
        if self._pos == self._end:
            self._starts[self._pos] = len(self.pieces)
            self.pieces.append(data if n > _COPY_BELOW else bytes(data))
            self._end += n
        else:
            i = self._starts.get(self._pos)
            if i is None or memoryview(self.pieces[i]).nbytes != n:
                raise ValueError("only a whole piece can be rewritten")
            self.pieces[i] = bytes(data)
        self._pos += n
        return n

    def flush(self) -> None:
        pass


#: Pieces smaller than this are copied (headers): larger ones are kept as given.
_COPY_BELOW = 1 << 16


def _format_value(dname: str) -> Any:
    if dname == "float64":

        def fmt(v: float) -> str:
            if v != v:
                return '"NaN"'
            if v in (math.inf, -math.inf):
                return '"Infinity"' if v > 0 else '"-Infinity"'
            return repr(v)

        return fmt
    if dname == "bool":
        return lambda v: "true" if v else "false"
    return str


def _json_values(dname: str, arr: np.ndarray) -> str:
    """The flat value list of ``arr``, one row of its last axis per line."""
    flat = arr.ravel().tolist()
    if not flat:
        return "[]"
    fmt = _format_value(dname)
    tokens = [fmt(v) for v in flat]
    width = arr.shape[-1] if arr.ndim >= 2 and arr.shape[-1] > 0 else 1
    lines = [", ".join(tokens[i : i + width]) for i in range(0, len(tokens), width)]
    return "[\n    " + ",\n    ".join(lines) + "\n   ]"


def document_bytes(manifest: dict, arrays: dict[str, np.ndarray], fmt: str) -> bytes:
    """The bytes of a document.

    Parameters
    ----------
    manifest : dict
        JSON-able content (str keys; lists, not tuples, come back; NumPy
        scalars are written as plain numbers; NaN/inf are refused).
    arrays : dict of str -> ndarray
        Numeric arrays of dtype float64, int64, bool or uint8, any shape.
        Names use letters, digits, ``_ . -`` and ``/`` between parts.
    fmt : {'npz', 'json'}

    The same input always gives the same bytes.  Raises ``ValueError`` or
    ``TypeError`` for content a document cannot hold (a bug in the caller).
    """
    return b"".join(document_pieces(manifest, arrays, fmt))


def document_pieces(manifest: dict, arrays: dict[str, np.ndarray], fmt: str) -> list:
    """The bytes of :func:`document_bytes` as a list of bytes-like pieces to
    write one after the other: an NPZ's large pieces are views of the arrays,
    so that writing a long clip's document takes no second copy of it."""
    items = _canonical(arrays)
    if fmt == "npz":
        index = {name: {"dtype": dname, "shape": list(arr.shape)} for name, dname, arr in items}
        envelope = {"arrays": index, "format": FORMAT_NAME, "manifest": manifest, "version": FORMAT_VERSION}
        members = {MANIFEST_MEMBER: [(_dump_manifest(envelope, 1) + "\n").encode("utf-8")]}
        for name, _, arr in items:
            members[name + ".npy"] = _npy_parts(arr)
        sink = _Pieces()
        with zipfile.ZipFile(sink, "w", allowZip64=True) as zf:  # type: ignore[arg-type]
            for member in sorted(members):
                _zip_member(zf, member, members[member])
        return sink.pieces
    if fmt == "json":
        entries = []
        for name, dname, arr in items:
            entries.append(
                f"  {json.dumps(name)}: {{\n"
                f'   "dtype": "{dname}",\n'
                f'   "shape": {json.dumps(list(arr.shape))},\n'
                f'   "values": {_json_values(dname, arr)}\n'
                "  }"
            )
        arrays_text = "{\n" + ",\n".join(entries) + "\n }" if entries else "{}"
        manifest_text = _dump_manifest(manifest, 1).replace("\n", "\n ")
        text = (
            "{\n"
            f' "arrays": {arrays_text},\n'
            f' "format": {json.dumps(FORMAT_NAME)},\n'
            f' "manifest": {manifest_text},\n'
            f' "version": {FORMAT_VERSION}\n'
            "}\n"
        )
        return [text.encode("utf-8")]
    raise ValueError(f"unknown document format {fmt!r} (npz or json)")


# --------------------------------------------------------------------------- reading


def is_document(data: bytes) -> bool:
    """Whether ``data`` looks like a document container (a zip, or a JSON
    object), judged by content only; :func:`parse_document` validates it."""
    if data[:4] in _ZIP_MAGICS:
        return True
    head = data[:64]
    if head.startswith(b"\xef\xbb\xbf"):
        head = head[3:]
    return head.lstrip(b" \t\r\n").startswith(b"{")


def _fail(name: str, reason: str) -> DataError:
    return DataError(reason, source=name)


def _check_envelope(env: Any, name: str, container: str) -> dict:
    if not isinstance(env, dict):
        raise _fail(name, f"not a {FORMAT_NAME} document ({container} does not hold a JSON object)")
    fmt = env.get("format")
    if fmt != FORMAT_NAME:
        got = "no format name" if fmt is None else f"format {fmt!r}"
        raise _fail(name, f"not a {FORMAT_NAME} document ({got})")
    version = env.get("version")
    if type(version) is not int or version < 1:
        raise _fail(name, f"bad document version {version!r} (expected a whole number >= 1)")
    if version > FORMAT_VERSION:
        from .. import __version__

        raise _fail(
            name,
            f"document format version {version} is newer than this staggered {__version__} reads "
            f"(version {FORMAT_VERSION}): upgrade staggered",
        )
    if not isinstance(env.get("manifest"), dict):
        raise _fail(name, "document has no manifest object")
    if not isinstance(env.get("arrays"), dict):
        raise _fail(name, "document has no arrays object")
    if len(env["arrays"]) > MAX_ARRAYS:
        raise _fail(name, f"document declares {len(env['arrays'])} arrays (at most {MAX_ARRAYS})")
    return env


def _check_shape(shape: Any, where: str, name: str) -> tuple[int, ...]:
    if not isinstance(shape, list | tuple) or len(shape) > MAX_NDIM:
        raise _fail(name, f"{where}: bad shape {shape!r}")
    for n in shape:
        # floats (including inf/nan from JSON), bools and negatives are all refused
        if type(n) is not int or n < 0:
            raise _fail(name, f"{where}: bad shape {list(shape)!r} (dimensions must be whole numbers >= 0)")
    return tuple(shape)


def _nbytes(shape: tuple[int, ...], itemsize: int) -> int:
    return math.prod(shape) * itemsize  # Python ints: no overflow


def _check_index(index: dict, name: str) -> dict[str, tuple[np.dtype, tuple[int, ...], int]]:
    """Validate the declared dtype and shape of every array; limits on sizes."""
    out = {}
    total = 0
    for aname, entry in index.items():
        if not isinstance(aname, str) or not _NAME_RE.fullmatch(aname) or ".." in aname.split("/"):
            raise _fail(name, f"bad array name {aname!r}")
        where = f"array {aname!r}"
        if not isinstance(entry, dict):
            raise _fail(name, f"{where}: entry is not an object")
        dname = entry.get("dtype")
        if not isinstance(dname, str) or dname not in ALLOWED_DTYPES:
            raise _fail(name, f"{where}: dtype {dname!r} not allowed (only {', '.join(ALLOWED_DTYPES)})")
        dtype = ALLOWED_DTYPES[dname]
        shape = _check_shape(entry.get("shape"), where, name)
        nbytes = _nbytes(shape, dtype.itemsize)
        if nbytes > MAX_ARRAY_BYTES:
            raise _fail(
                name, f"{where}: shape {list(shape)} is {nbytes:,} bytes, over the limit of {MAX_ARRAY_BYTES:,}"
            )
        total += nbytes
        if total > MAX_TOTAL_BYTES:
            raise _fail(name, f"arrays total more than the limit of {MAX_TOTAL_BYTES:,} bytes")
        out[aname] = (dtype, shape, nbytes)
    return out


def _load_json_text(raw: bytes, name: str, what: str) -> Any:
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as err:
        raise _fail(name, f"{what} is not UTF-8 text (byte {err.start})") from None
    try:
        return json.loads(text)
    except json.JSONDecodeError as err:
        raise _fail(name, f"malformed {what}: {err.msg} at line {err.lineno} column {err.colno}") from None
    except RecursionError:
        raise _fail(name, f"malformed {what}: nested too deeply") from None
    except ValueError:  # an integer of more than sys.get_int_max_str_digits() digits
        raise _fail(name, f"malformed {what}: a number has too many digits") from None


def _parse_npy_header(head: bytes, aname: str, name: str) -> tuple[np.dtype, bool, tuple[int, ...], int]:
    """dtype, fortran_order, shape and header length of a ``.npy`` member."""
    where = f"array {aname!r}"
    if len(head) < 10 or not head.startswith(_NPY_MAGIC):
        raise _fail(name, f"{where}: not a .npy member")
    major = head[6]
    if major == 1:
        hlen, start = int.from_bytes(head[8:10], "little"), 10
    elif major in (2, 3):
        if len(head) < 12:
            raise _fail(name, f"{where}: truncated .npy header")
        hlen, start = int.from_bytes(head[8:12], "little"), 12
    else:
        raise _fail(name, f"{where}: unknown .npy version {major}")
    if hlen > _MAX_NPY_HEADER or start + hlen > len(head):
        raise _fail(name, f"{where}: .npy header too long or truncated")
    try:
        header = ast.literal_eval(head[start : start + hlen].decode("utf-8" if major == 3 else "latin1"))
    except (ValueError, SyntaxError, UnicodeDecodeError, MemoryError, RecursionError):
        raise _fail(name, f"{where}: unreadable .npy header") from None
    if not isinstance(header, dict) or set(header) != {"descr", "fortran_order", "shape"}:
        raise _fail(name, f"{where}: unreadable .npy header")
    descr, fortran = header["descr"], header["fortran_order"]
    if not isinstance(descr, str) or not _DESCR_RE.fullmatch(descr):
        # object ('|O'), structured, string... dtypes: refused, never unpickled
        raise _fail(name, f"{where}: dtype {descr!r} not allowed (only {', '.join(ALLOWED_DTYPES)})")
    dtype = np.dtype(descr)
    if not any(dtype.kind == d.kind and dtype.itemsize == d.itemsize for d in ALLOWED_DTYPES.values()):
        raise _fail(name, f"{where}: dtype {descr!r} not allowed (only {', '.join(ALLOWED_DTYPES)})")
    if type(fortran) is not bool:
        raise _fail(name, f"{where}: unreadable .npy header")
    shape = _check_shape(header["shape"], where, name)
    return dtype, fortran, shape, start + hlen


#: What zipfile raises on a damaged zip, at opening or reading a member:
#: besides BadZipFile, NotImplementedError ("zip file version 10.6", flag
#: bits), ValueError ("negative seek value"), EOFError, OSError, struct and
#: zlib errors.  (DataError is none of these: our own refusals pass.)
_ZIP_ERRORS = (
    zipfile.BadZipFile,
    zipfile.LargeZipFile,
    NotImplementedError,
    ValueError,
    EOFError,
    OSError,
    OverflowError,
    struct.error,
    zlib.error,
)


def _parse_npz(data, name: str) -> tuple[dict, dict[str, np.ndarray]]:
    try:
        return _read_npz(data, name)
    except DataError:
        raise
    except _ZIP_ERRORS as err:
        reason = " ".join(str(err).split())[:80] or type(err).__name__
        raise _fail(name, f"truncated or corrupt NPZ document ({reason})") from None


def _read_npz(data, name: str) -> tuple[dict, dict[str, np.ndarray]]:
    """``data``: the bytes, or a seekable binary file, of an NPZ document."""
    if isinstance(data, bytes | bytearray | memoryview):
        size, source = len(data), io.BytesIO(data)
    else:
        size, source = data.seek(0, 2), data
        data.seek(0)
    with zipfile.ZipFile(source) as zf:
        infos = zf.infolist()
        if len(infos) > MAX_ARRAYS + 1:
            raise _fail(name, f"document has {len(infos)} members (at most {MAX_ARRAYS + 1})")
        # every declared size is checked before anything is inflated
        seen: dict[str, zipfile.ZipInfo] = {}
        total = 0
        for info in infos:
            if info.filename in seen:
                raise _fail(name, f"duplicate member {info.filename!r}")
            seen[info.filename] = info
            if info.flag_bits & 0x1:
                raise _fail(name, f"member {info.filename!r} is encrypted")
            if info.compress_type not in (zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED):
                raise _fail(name, f"member {info.filename!r} uses an unsupported compression ({info.compress_type})")
            limit = MAX_MANIFEST_BYTES if info.filename == MANIFEST_MEMBER else MAX_ARRAY_BYTES + _MAX_NPY_HEADER
            if info.file_size > limit:
                raise _fail(
                    name, f"member {info.filename!r} declares {info.file_size:,} bytes, over the limit of {limit:,}"
                )
            if info.compress_size > size or (
                info.compress_type == zipfile.ZIP_STORED and info.compress_size != info.file_size
            ):
                raise _fail(name, f"corrupt NPZ document (member {info.filename!r} declares sizes the file lacks)")
            total += info.file_size
            if total > MAX_TOTAL_BYTES:
                raise _fail(name, f"members total more than the limit of {MAX_TOTAL_BYTES:,} bytes")
        compressed = sum(info.compress_size for info in infos)
        if total > MAX_INFLATE_RATIO * compressed + INFLATE_ALLOWANCE:
            raise _fail(
                name,
                f"members inflate to {total:,} bytes from {compressed:,} (over {MAX_INFLATE_RATIO}:1): "
                "refusing a zip bomb",
            )
        if MANIFEST_MEMBER not in seen:
            raise _fail(name, f"not a {FORMAT_NAME} document (no {MANIFEST_MEMBER})")
        env = _check_envelope(_load_json_text(zf.read(MANIFEST_MEMBER), name, MANIFEST_MEMBER), name, MANIFEST_MEMBER)
        declared = _check_index(env["arrays"], name)
        expected = {a + ".npy" for a in declared} | {MANIFEST_MEMBER}
        extra = sorted(set(seen) - expected)
        missing = sorted(expected - set(seen))
        if extra:
            raise _fail(name, f"unexpected member {extra[0]!r}")
        if missing:
            raise _fail(name, f"missing member {missing[0]!r}")
        arrays = {}
        for aname, (dtype, shape, nbytes) in declared.items():
            info = seen[aname + ".npy"]
            # a stored member (what the writer makes) is read from the
            # source straight into its array: zipfile's reader copies it
            # twice through Python-level pieces (cmu_01_01's document: 16.6 -> 9.0 ms)
            member = _StoredMember(source, info, size) if info.compress_type == zipfile.ZIP_STORED else zf.open(info)
            fd = _mappable(source, aname, info, nbytes)
            arrays[aname] = _read_npy_member(member, info, aname, dtype, shape, nbytes, name, fd)
    return env["manifest"], arrays


class _StoredMember:
    """A stored (uncompressed) zip member read from ``source`` with its CRC
    checked at the end, as ``ZipFile.open`` would: its local header is
    checked the same way (signature, name) and reading stops at its size."""

    def __init__(self, source, info: zipfile.ZipInfo, size: int) -> None:
        source.seek(info.header_offset)
        head = source.read(30)
        if len(head) != 30:
            raise zipfile.BadZipFile("Truncated file header")
        if head[:4] != b"PK\x03\x04":
            raise zipfile.BadZipFile("Bad magic number for file header")
        if info.flag_bits & 0x20:
            raise NotImplementedError("compressed patched data (flag bit 5)")
        if info.flag_bits & 0x40:
            raise NotImplementedError("strong encryption (flag bit 6)")
        if info.flag_bits & 0x1:
            raise zipfile.BadZipFile(f"member {info.orig_filename!r} is encrypted")
        flags = int.from_bytes(head[6:8], "little")
        n_name, n_extra = int.from_bytes(head[26:28], "little"), int.from_bytes(head[28:30], "little")
        raw = source.read(n_name)
        if raw.decode("utf-8" if flags & 0x800 else "cp437") != info.orig_filename:
            raise zipfile.BadZipFile(f"File name in directory {info.orig_filename!r} and header {raw!r} differ.")
        self._at = info.header_offset + 30 + n_name + n_extra
        if self._at + info.compress_size > size:
            raise zipfile.BadZipFile(f"Truncated file header of {info.orig_filename!r}")
        self._source, self._info, self._left, self._crc = source, info, info.compress_size, 0

    def __enter__(self) -> _StoredMember:
        return self

    def __exit__(self, *exc) -> None:
        pass

    def _check(self) -> None:
        if self._left == 0 and self._crc != self._info.CRC:
            raise zipfile.BadZipFile(f"Bad CRC-32 for file {self._info.orig_filename!r}")

    def read(self, n: int) -> bytes:
        self._source.seek(self._at)
        data = self._source.read(max(0, min(n, self._left)))
        self._at, self._left = self._at + len(data), self._left - len(data)
        self._crc = zlib.crc32(data, self._crc)
        self._check()
        return data

    def readinto(self, view: memoryview) -> int:
        view = view[: self._left]
        self._source.seek(self._at)
        got = self._source.readinto(view) if len(view) else 0
        self._at, self._left = self._at + got, self._left - got
        self._crc = zlib.crc32(view[:got], self._crc)
        self._check()
        return got

    def map_rest(self, fd: int) -> tuple[mmap.mmap, int] | None:
        """The rest of the member mapped read-only from the file ``fd``, and
        the offset of its first byte in the mapping; its CRC is checked a
        piece at a time, each piece's pages released once read.  None (and
        nothing read) where the file cannot be mapped: then it is read."""
        start = self._at - self._at % mmap.ALLOCATIONGRANULARITY
        try:
            mapped = mmap.mmap(fd, self._at + self._left - start, offset=start, access=mmap.ACCESS_READ)
        except (OSError, ValueError):  # a file system without mappings, a file cut short meanwhile
            return None
        view = memoryview(mapped)
        try:
            for lo in range(self._at - start, len(mapped), _READ_CHUNK):
                hi = min(lo + _READ_CHUNK, len(mapped))
                self._crc = zlib.crc32(view[lo:hi], self._crc)
                _release_pages(mapped, lo, hi)
        finally:
            view.release()
        self._at, self._left, at = self._at + self._left, 0, self._at - start
        self._check()
        return mapped, at


#: Bytes of an array read from a zip member at once (see :func:`_read_npy_member`).
_READ_CHUNK = 1 << 20

#: Arrays of the source (its numbers and its file) that a document file's
#: reader maps instead of reading: steps carry them through untouched, and
#: mapped pages not in use leave memory (peak of `cull --keep 30%` of the 32x
#: clip: 548 -> 487 MB).
_MAPPED = frozenset({"source.channels", "source.points", "source.bvh", "source.c3d"})
#: Smaller arrays are read: a mapping costs a system call or two.
_MAP_MIN_BYTES = 1 << 22


def _mappable(source, aname: str, info: zipfile.ZipInfo, nbytes: int) -> int | None:
    """The descriptor of the file ``source`` when array ``aname`` is to be
    mapped from it (a stored member of a large source array), else None.
    Only where pages can be released (``madvise``) and a mapped file can
    still be replaced (POSIX: a step may write over its own input)."""
    if aname not in _MAPPED or nbytes < _MAP_MIN_BYTES or info.compress_type != zipfile.ZIP_STORED:
        return None
    if os.name != "posix" or not hasattr(mmap.mmap, "madvise"):
        return None
    try:
        return source.fileno()
    except (AttributeError, OSError, io.UnsupportedOperation):
        return None  # bytes in memory


def _release_pages(mapped: mmap.mmap, lo: int = 0, hi: int | None = None) -> None:
    """Let the pages of ``mapped[lo:hi]`` leave this process's memory (a
    read-only file mapping: they are read again from the file if touched)."""
    page = mmap.PAGESIZE
    lo -= lo % page
    hi = len(mapped) if hi is None else hi
    if hi > lo:
        mapped.madvise(mmap.MADV_DONTNEED, lo, hi - lo)


def release_mapped(arr: np.ndarray) -> None:
    """Release the resident pages of ``arr`` when it is a view of a mapped
    document member (see :data:`_MAPPED`); else nothing."""
    base = arr
    while isinstance(base, np.ndarray):
        base = base.base
    if isinstance(base, memoryview):  # what np.frombuffer keeps of the mapping
        base = base.obj
    if isinstance(base, mmap.mmap):
        _release_pages(base)


def _read_npy_member(
    member,
    info: zipfile.ZipInfo,
    aname: str,
    dtype: np.dtype,
    shape: tuple[int, ...],
    nbytes: int,
    name: str,
    fd: int | None = None,
) -> np.ndarray:
    where = f"array {aname!r}"
    with member as fp:
        prefix = fp.read(min(info.file_size, 12))
        if len(prefix) < 10 or not prefix.startswith(_NPY_MAGIC):
            raise _fail(name, f"{where}: not a .npy member")
        size_len = 2 if prefix[6] == 1 else 4
        hlen = int.from_bytes(prefix[8 : 8 + size_len], "little")
        if hlen > _MAX_NPY_HEADER:
            raise _fail(name, f"{where}: .npy header too long")
        head = prefix + fp.read(max(0, min(8 + size_len + hlen, info.file_size) - len(prefix)))
        ndtype, fortran, nshape, data_start = _parse_npy_header(head, aname, name)
        if ndtype.kind != dtype.kind or ndtype.itemsize != dtype.itemsize or nshape != shape:
            raise _fail(
                name,
                f"{where}: .npy header says {ndtype} {list(nshape)} but the manifest says {dtype} {list(shape)}",
            )
        if info.file_size != data_start + nbytes:
            raise _fail(
                name,
                f"{where}: member holds {info.file_size - data_start:,} data bytes, "
                f"shape {list(shape)} needs {nbytes:,}",
            )
        if fd is not None and not fortran and ndtype == dtype and isinstance(fp, _StoredMember):
            got = fp.map_rest(fd)  # read-only pages of the file, resident only while used
            if got is not None:
                mapped, at = got
                return np.frombuffer(mapped, dtype=dtype, count=nbytes // dtype.itemsize, offset=at).reshape(shape)
        # straight into the array's own (numpy-allocated, aligned) buffer: no copy
        raw = np.empty(nbytes // ndtype.itemsize if ndtype.itemsize else 0, dtype=ndtype)
        view = memoryview(raw.reshape(-1)).cast("B")
        got = 0
        while got < nbytes:
            # in pieces: zipfile reads a (compressed) member through a bytes
            # object of the size asked for, and those of a long clip's arrays,
            # once freed, stayed in the process's heap (x32 cull: 38 MB)
            n = fp.readinto(view[got : got + _READ_CHUNK])
            if not n:
                raise _fail(name, f"{where}: truncated data")
            got += n
        fp.read(1)  # reach the end of the member, where zipfile checks its CRC
    arr = raw.reshape(shape[::-1]).T if fortran else raw.reshape(shape)
    if fortran or arr.dtype != dtype:
        return np.array(arr, dtype=dtype, order="C")
    return arr


def _array_from_json(aname: str, entry: dict, dtype: np.dtype, shape: tuple[int, ...], name: str) -> np.ndarray:
    where = f"array {aname!r}"
    values = entry.get("values")
    if not isinstance(values, list):
        raise _fail(name, f"{where}: no values list")
    count = math.prod(shape)
    if len(values) != count:
        raise _fail(name, f"{where}: {len(values):,} values for shape {list(shape)} ({count:,} expected)")
    if count == 0:
        return np.zeros(shape, dtype=dtype)
    kinds = set(map(type, values))
    try:
        if dtype.kind == "f":
            if not kinds <= {float, int, str}:
                raise ValueError
            if str in kinds:
                if not {v for v in values if type(v) is str} <= _NONFINITE_TEXT.keys():
                    raise ValueError
                values = [_NONFINITE_TEXT[v] if type(v) is str else v for v in values]
            arr = np.array(values, dtype=np.float64)
        elif dtype.kind == "b":
            if kinds != {bool}:
                raise ValueError
            arr = np.array(values, dtype=np.bool_)
        else:
            if kinds != {int}:
                raise ValueError
            if dtype.kind == "u" and (min(values) < 0 or max(values) > 255):
                raise ValueError
            arr = np.array(values, dtype=dtype)
    except (ValueError, TypeError, OverflowError):
        raise _fail(name, f"{where}: values do not fit dtype {dtype}") from None
    return arr.reshape(shape)


def _parse_json(data: bytes, name: str) -> tuple[dict, dict[str, np.ndarray]]:
    env = _check_envelope(_load_json_text(data, name, "JSON document"), name, "the JSON text")
    declared = _check_index(env["arrays"], name)
    arrays = {
        aname: _array_from_json(aname, env["arrays"][aname], dtype, shape, name)
        for aname, (dtype, shape, _) in declared.items()
    }
    return env["manifest"], arrays


def parse_document(data, name: str) -> tuple[dict, dict[str, np.ndarray]]:
    """``(manifest, arrays)`` from the bytes of a document (npz or json,
    detected by content), or from a seekable binary file of an NPZ one
    (read in place: the arrays are all it allocates).

    ``name`` is used in error messages.  Raises :class:`DataError` with a
    one-line reason for anything that is not a valid document of a version
    this code reads.  Arrays come back writable, C-contiguous and in native
    byte order, except those of the source read from a file (:data:`_MAPPED`):
    read-only views of its pages.
    """
    if not isinstance(data, bytes | bytearray | memoryview):
        return _parse_npz(data, name)
    if data[:4] in _ZIP_MAGICS:
        return _parse_npz(data, name)
    if is_document(data):
        return _parse_json(data, name)
    if not data:
        raise _fail(name, "empty file")
    raise _fail(name, f"not a {FORMAT_NAME} document (neither an NPZ zip nor a JSON object)")


# --------------------------------------------------------------------------- the schema
#
# What the manifest and arrays of a document mean (SPEC section 7): the
# staggered-pose Document in and out of (manifest, arrays), validated on the
# way in.


_TRACK_ARRAYS = (
    "knot_ptr",
    "knot_t",
    "knot_v",
    "knot_pose",
    "knot_editing",
    "tan_a",
    "tan_b",
    "samp_ptr",
    "samp_s",
    "samp_d",
)


def _flag(value, what: str) -> bool:
    if not isinstance(value, bool):
        raise ValueError(f"{what} must be true or false")
    return value


def _constraint_entry(c: Constraint) -> dict:
    entry = {"joint": c.joint, "start": float(c.start), "end": float(c.end)}
    if c.source_span != (float(c.start), float(c.end)):
        entry["source_start"], entry["source_end"] = c.source_span
    if c.pin:
        entry["pin"] = True
    return entry


def _layer_arrays(layer: Layer) -> dict[str, np.ndarray]:
    k = layer.knots
    return {
        "knot_ptr": k.ptr,
        "knot_t": k.t,
        "knot_v": k.v,
        "knot_pose": k.pose,
        "knot_editing": k.editing,
        "tan_a": layer.tan_a,
        "tan_b": layer.tan_b,
        "samp_ptr": layer.samp_ptr,
        "samp_s": layer.samp_s,
        "samp_d": layer.samp_d,
    }


def to_parts(doc: Document) -> tuple[dict, dict[str, np.ndarray]]:
    """The stored form of a document: a JSON-able manifest and numeric arrays.

    Version 2: the base layer's poses are ``pose_t`` and ``priority``, layer
    ``lay >= 1`` has its poses in ``layer{lay}.pose_t``, and track ``n``'s layer
    ``lay`` is stored as ``track{n}.layer{lay}.{knot_ptr,knot_t,...}``.
    """
    arrays: dict[str, np.ndarray] = {"pose_t": doc.pose_t, "priority": doc.priority}
    for lay, pose_t in enumerate(doc.layer_pose_t, start=1):
        arrays[f"layer{lay}.pose_t"] = pose_t
    tracks = []
    for n, tr in enumerate(doc.tracks):
        tracks.append({"kind": tr.kind, "names": list(tr.names), "targets": [int(x) for x in tr.targets]})
        for lay, layer in enumerate(tr.layers):
            for key, val in _layer_arrays(layer).items():
                arrays[f"track{n}.layer{lay}.{key}"] = val
    for key, val in doc.signals.items():
        arrays[f"signal.{key}"] = np.asarray(val)
    manifest: dict = {
        "format": FORMAT_NAME,
        "version": DOCUMENT_VERSION,
        "layers": doc.n_layers,
        "source": {"kind": doc.kind, "name": doc.source_name, "sha256": doc.source_sha256},
        "frame_time": doc.frame_time,
        "frames": doc.n_frames,
        "tracks": tracks,
        "constraints": [_constraint_entry(c) for c in doc.constraints],
        "parameters": doc.parameters,
    }
    src = doc.source
    if isinstance(src, BvhMotion):
        sk = src.skeleton
        manifest["bvh"] = {
            "names": list(sk.names),
            "parents": [int(p) for p in sk.parents],
            "offsets": sk.offsets.tolist(),
            "channels": [list(c) for c in sk.channels],
            "end_parents": [int(p) for p in sk.end_parents],
            "end_offsets": sk.end_offsets.tolist(),
            "frame_time": src.frame_time,
            "frame_time_text": src.frame_time_text,
            "number_format": src.number_format,
        }
        arrays["source.channels"] = src.channels
        if src.source:  # the file's text, so that bake keeps its layout and numbers as written
            arrays["source.bvh"] = np.frombuffer(src.source, dtype=np.uint8)
    else:
        manifest["c3d"] = {"labels": list(src.labels), "rate": src.rate, "units": src.units}
        arrays["source.points"] = src.points
        arrays["source.c3d"] = np.frombuffer(src.source, dtype=np.uint8)
    return manifest, arrays


def from_parts(manifest: dict, arrays: dict[str, np.ndarray]) -> Document:
    """Rebuild and validate a document from its stored form.

    Raises DataError naming the first inconsistency (no source attached:
    the caller adds the file name).  A version 1 document (one layer, its
    arrays named ``track{n}.{key}``) is converted, and said so at ``-v``.
    """
    from ..skeleton import Skeleton

    def need(cond: bool, msg: str) -> None:
        if not cond:
            raise DataError(msg)

    def arr(key: str, ndim: int, dtype_kind: str = "f") -> np.ndarray:
        need(key in arrays, f"missing array {key!r}")
        a = arrays[key]
        need(isinstance(a, np.ndarray) and a.ndim == ndim, f"array {key!r} must have {ndim} dimension(s)")
        need(a.dtype.kind in dtype_kind, f"array {key!r} has dtype {a.dtype}, expected {dtype_kind!r} kind")
        return a

    need(isinstance(manifest, dict), "manifest is not a JSON object")
    need(manifest.get("format") == FORMAT_NAME, f"format is {str(manifest.get('format'))[:40]!r}, not {FORMAT_NAME!r}")
    version = manifest.get("version")
    need(type(version) is int, "version is missing")
    need(version >= 1, f"bad document version {version} (expected a whole number >= 1)")
    need(
        version <= DOCUMENT_VERSION,
        f"document version {version} is newer than this staggered reads ({DOCUMENT_VERSION}); upgrade staggered",
    )
    if version == 1:
        log.info("document format version 1: converted to version 2 (one layer) on reading")
        arrays = _from_version_1(arrays)
        n_layers = 1
    else:
        n_layers = manifest.get("layers")
        need(
            type(n_layers) is int and 1 <= n_layers <= MAX_LAYERS,
            f"layers must be a whole number from 1 to {MAX_LAYERS}, got {str(n_layers)[:20]}",
        )
    try:
        frames = _whole_number(manifest["frames"], "frames", 1, _MAX_INDEX)
        frame_time = float(manifest["frame_time"])
        src_info = manifest["source"]
        kind = src_info["kind"]
        track_info = manifest["tracks"]
        constraints = tuple(
            Constraint(
                str(c["joint"]),
                float(c["start"]),
                float(c["end"]),
                None if c.get("source_start") is None else float(c["source_start"]),
                None if c.get("source_end") is None else float(c["source_end"]),
                _flag(c.get("pin", False), "constraint pin"),
            )
            for c in manifest.get("constraints", [])
        )
        parameters = manifest.get("parameters", {})
    except (KeyError, TypeError, ValueError, OverflowError) as exc:
        raise DataError(f"manifest is incomplete ({type(exc).__name__}: {str(exc)[:60]})") from None
    need(frames >= 1 and np.isfinite(frame_time) and frame_time > 0, "frames and frame_time must be positive")
    problem = frame_time_problem(frame_time)
    need(problem is None, f"frame_time {frame_time:g} {problem}")
    need(kind in ("bvh", "c3d"), f"unknown source kind {str(kind)[:20]!r}")
    sha = src_info.get("sha256", "") if isinstance(src_info, dict) else None
    need(
        isinstance(sha, str) and (sha == "" or re.fullmatch(r"[0-9a-f]{64}", sha) is not None),
        "source sha256 is not a SHA-256 digest (64 lower-case hex digits)",
    )
    try:
        if kind == "bvh":
            b = manifest["bvh"]
            names = tuple(str(n) for n in b["names"])
            J = len(names)
            sk = Skeleton(
                names=names,
                parents=_whole_numbers(b["parents"], "bvh parents", -1, J - 1).reshape(J),
                offsets=np.array(b["offsets"], dtype=float).reshape(J, 3),
                channels=tuple(tuple(str(c) for c in ch) for ch in b["channels"]),
                end_parents=_whole_numbers(b["end_parents"], "bvh end_parents", 0, J - 1).reshape(-1),
                end_offsets=np.array(b["end_offsets"], dtype=float).reshape(-1, 3),
            )
            need(len(sk.channels) == J, "bvh channels do not match the joints")
            # names and channels are written back into a BVH header: they must read back
            need(len(set(names)) == J, "bvh joint names are not unique")
            need(all(_BVH_NAME.fullmatch(n) for n in names), "a bvh joint name is empty or has braces or line breaks")
            need(
                all(set(c) <= _BVH_CHANNELS and len(set(c)) == len(c) for c in sk.channels),
                "bvh channels hold an unknown or repeated channel name",
            )
            need(
                bool(np.all(np.abs(sk.offsets) <= _MAX_MAGNITUDE))
                and bool(np.all(np.abs(sk.end_offsets) <= _MAX_MAGNITUDE)),
                f"bvh offsets are not all finite numbers within ±{_MAX_MAGNITUDE:g}",
            )
            need(
                bool(np.all(sk.parents < np.arange(J))) and bool(np.all(sk.parents >= -1)),
                "bvh parents are not in hierarchy order",
            )
            need(bool(np.all((sk.end_parents >= 0) & (sk.end_parents < J))), "bvh end sites name unknown joints")
            need(len(sk.end_parents) == len(sk.end_offsets), "bvh end sites and their offsets differ in number")
            ch = arr("source.channels", 2)
            need(
                ch.shape == (frames, sum(len(c) for c in sk.channels)),
                f"source.channels has shape {ch.shape}, expected ({frames}, channels)",
            )
            text = b""
            if "source.bvh" in arrays:
                member = arr("source.bvh", 1, "u")
                text = member.tobytes()
                release_mapped(member)
            sha = str(manifest.get("source", {}).get("sha256", ""))
            need(
                not text or not sha or hashlib.sha256(text).hexdigest() == sha,
                "source.bvh is not the source file (its checksum differs from the manifest's)",
            )
            # source.channels are the numbers of source.bvh as read (what
            # extract stores), which the writer compares with
            source: BvhMotion | MarkerMotion = BvhMotion(
                sk,
                ch,
                float(b["frame_time"]),
                str(b["frame_time_text"]),
                str(b["number_format"]),
                source=text,
                source_values=ch if text else None,
            )
            need(abs(source.frame_time - frame_time) < 1e-12, "frame_time disagrees with the bvh header")
            need(_safe_format(source.number_format), "number_format is not a plain numeric format")
            need(
                _rows_all(ch, lambda b: np.abs(b) <= _MAX_MAGNITUDE),
                f"source.channels are not all finite numbers within ±{_MAX_MAGNITUDE:g}",
            )
            release_mapped(ch)  # checked: its pages come back when used (a step may not)
            text = source.frame_time_text
            need(
                text == ""
                or (_FRAME_TIME.fullmatch(text) is not None and abs(float(text) / source.frame_time - 1) < 1e-4),
                f"frame_time_text {text[:20]!r} is not the frame time",
            )
        else:
            c = manifest["c3d"]
            labels = tuple(str(x) for x in c["labels"])
            pts = arr("source.points", 3)
            need(
                pts.shape == (frames, len(labels), 3),
                f"source.points has shape {pts.shape}, expected ({frames}, {len(labels)}, 3)",
            )
            need(
                _rows_all(pts, lambda b: ~(np.abs(b) > _MAX_MAGNITUDE)),
                f"source.points hold values that are infinite or beyond ±{_MAX_MAGNITUDE:g}",
            )
            release_mapped(pts)
            member = arr("source.c3d", 1, "u")
            raw = member.tobytes()
            release_mapped(member)
            if raw:  # baking rewrites it: refuse a broken one now, naming the document
                from .c3d import check_c3d

                try:
                    check_c3d(raw, "source.c3d")
                except DataError as exc:
                    need(False, str(exc))
            rate = float(c["rate"])
            problem = rate_problem(rate) if np.isfinite(rate) else "is not a finite number"
            need(problem is None, f"c3d rate {rate:g} Hz {problem}")
            sha = src_info.get("sha256", "")
            if raw and sha:  # the embedded file is the source the manifest names
                need(
                    hashlib.sha256(raw).hexdigest() == sha,
                    "source.c3d does not match the source's sha256 in the manifest (altered or corrupted)",
                )
            source = MarkerMotion(labels, pts, rate, str(c.get("units", "")), raw)
            need(abs(1.0 / source.rate - frame_time) < 1e-9, "frame_time disagrees with the c3d rate")
    except (KeyError, TypeError, ValueError, OverflowError) as exc:
        raise DataError(f"source description is malformed ({type(exc).__name__}: {str(exc)[:60]})") from None
    pose_t = arr("pose_t", 1)
    priority = arr("priority", 1)
    K = len(pose_t)
    need(K >= 1 and priority.shape == (K,), "pose_t and priority must be non-empty and of equal length")
    need(
        bool(np.all(np.isfinite(pose_t))) and bool(np.all(np.diff(pose_t) > 0)),
        "pose times must be finite and strictly increasing",
    )
    need(not np.any(np.isnan(priority)), "priorities must not be NaN")
    duration = (frames - 1) * frame_time
    need(
        abs(pose_t[0]) < 1e-6 and abs(pose_t[-1] - duration) < 1e-6,
        f"pose times must run from the first frame to the last (0 to {duration:.4f} s)",
    )
    layer_pose_t = tuple(_checked_layer_poses(arrays, lay, duration, need, arr) for lay in range(1, n_layers))
    tracks = []
    need(isinstance(track_info, list), "tracks must be a list")
    layout = variable_layout(source)
    need(len(track_info) == len(layout), f"{len(track_info)} tracks for the source's {len(layout)}")
    for n, info in enumerate(track_info):
        try:
            tkind = info["kind"]
            tnames = tuple(str(x) for x in info["names"])
            targets = _whole_numbers(info["targets"], f"track {n} targets", 0, _MAX_INDEX).reshape(len(tnames))
        except (KeyError, TypeError, ValueError, OverflowError):
            raise DataError(f"track {n} description is malformed") from None
        need(tkind in (TRANSLATION, ROTATION), f"track {n} has unknown kind {str(tkind)[:20]!r}")
        want_kind, want_names, want_targets = layout[n]
        need(
            tkind == want_kind and tnames == want_names and np.array_equal(targets, want_targets),
            f"track {n} does not hold the source's {want_kind} variables (kind, names or targets differ)",
        )
        layers = tuple(
            _checked_layer(n, lay, tkind, tnames, arrays, pose_t if lay == 0 else layer_pose_t[lay - 1], need, arr)
            for lay in range(n_layers)
        )
        tracks.append(Track(tkind, tnames, targets, layers))
    joints = set(source.skeleton.names) if isinstance(source, BvhMotion) else set(source.labels)
    half_frame = 0.5 * frame_time
    for c in constraints:
        need(c.joint in joints, f"constraint on unknown joint or marker {c.joint[:40]!r}")
        need(
            bool(np.isfinite(c.start) and np.isfinite(c.end))
            and -half_frame <= c.start <= c.end <= duration + half_frame,
            f"constraint on {c.joint[:40]!r} from {c.start:g} to {c.end:g} s is not within the clip",
        )
        s0, s1 = c.source_span
        need(
            bool(np.isfinite(s0) and np.isfinite(s1)) and -half_frame <= s0 <= s1 <= duration + half_frame,
            f"constraint on {c.joint[:40]!r}: its source span {s0:g} to {s1:g} s is not within the clip",
        )
    signals = _checked_signals(arrays, frames, sum(len(tr.names) for tr in tracks), need)
    if isinstance(parameters, dict):  # what `constraints --detect` reuses must be usable
        joints_param = parameters.get("contact_joints", [])
        need(
            isinstance(joints_param, list) and all(isinstance(j, str) for j in joints_param),
            "parameters: contact_joints is not a list of names",
        )
        tree = parameters.get("marker_tree", {})
        need(
            isinstance(tree, dict)
            and all(isinstance(k, str) and isinstance(v, str) for k, v in tree.items())
            and set(tree) | set(tree.values()) <= joints,
            "parameters: marker_tree is not a map of marker labels to marker labels",
        )
        from ..ops.marker_chain import tree_has_loop

        need(not tree_has_loop(tree), "parameters: marker_tree has a loop")
        for key in ("min_contact", "contact_tolerance"):
            value = parameters.get(key, 0.0)
            need(
                type(value) in (int, float) and np.isfinite(value) and value >= 0,
                f"parameters: {key} is not a non-negative number",
            )
    return Document(
        pose_t=pose_t,
        priority=priority,
        tracks=tuple(tracks),
        layer_pose_t=layer_pose_t,
        source=source,
        source_name=str(src_info.get("name", "")),
        source_sha256=str(src_info.get("sha256", "")),
        constraints=constraints,
        signals=signals,
        parameters=parameters if isinstance(parameters, dict) else {},
    )


def _rows_all(a: np.ndarray, test) -> bool:
    """Whether the elementwise (or row-wise) ``test`` holds everywhere in
    ``a``, judged a block of rows at a time: no temporaries of a long clip's
    arrays."""
    if a.ndim == 0:
        return bool(test(a))
    rows = max(1, _CHECK_BLOCK // max(int(np.prod(a.shape[1:])), 1))
    return all(bool(np.all(test(a[lo : lo + rows]))) for lo in range(0, len(a), rows))


def _unit_rows(q: np.ndarray) -> np.ndarray:
    return np.abs(np.linalg.norm(q, axis=1) - 1) < 1e-6


#: Values checked at once by :func:`_rows_all`.
_CHECK_BLOCK = 1 << 18


def _safe_format(fmt: str) -> bool:
    return re.fullmatch(r"%\.\d{1,2}[fg]", fmt) is not None


#: Largest frame count or index a manifest may give (far beyond any clip, and
#: small enough for every integer array and float conversion).
_MAX_INDEX = 2**31 - 1


def _whole_number(value, what: str, lo: int, hi: int) -> int:
    """``value`` if it is a JSON whole number (not a float, not a bool) in
    ``[lo, hi]``; else a DataError naming ``what``."""
    if type(value) is not int or not lo <= value <= hi:
        shown = repr(value) if len(repr(value)) <= 24 else repr(value)[:20] + "..."
        raise DataError(f"{what} must be a whole number from {lo} to {hi}, got {shown}")
    return value


def _whole_numbers(values, what: str, lo: int, hi: int) -> np.ndarray:
    """An int array of a JSON list of whole numbers in ``[lo, hi]`` (floats
    such as 2.5 or 1e308 and bools are refused, not truncated)."""
    if not isinstance(values, list):
        raise DataError(f"{what} must be a list of whole numbers")
    for i, v in enumerate(values):
        _whole_number(v, f"{what}[{i}]", lo, hi)
    return np.array(values, dtype=np.int64)


#: Stored signals of known meaning and their shapes: T frames, V variables.
_SIGNAL_SHAPES = {"P": ("T",), "p": ("T", "V"), "weights": ("V",), "contact": ("T",)}


def _checked_signals(arrays: dict, frames: int, n_vars: int, need) -> dict[str, np.ndarray]:
    """The ``signal.*`` arrays: numeric and finite, and the known ones of
    their shape (plots and reprioritizing read them)."""
    signals = {}
    for key, val in arrays.items():
        if not key.startswith("signal."):
            continue
        name = key.split(".", 1)[1]
        need(isinstance(val, np.ndarray) and val.dtype.kind in "fiub", f"array {key!r} is not numeric")
        need(_rows_all(val, np.isfinite), f"array {key!r} holds values that are not finite")
        if name in _SIGNAL_SHAPES:
            dims = {"T": frames, "V": n_vars}
            want = tuple(dims[d] for d in _SIGNAL_SHAPES[name])
            need(val.shape == want, f"array {key!r} has shape {val.shape}, expected {want}")
        signals[name] = val
    return signals


#: Largest magnitude of a source value (the readers' limit) and of a fitted
#: one (knots, tangents, displacements; cubes of it stay finite): beyond them
#: the spline and FK math overflows.
_MAX_MAGNITUDE = 1e12
_MAX_FITTED = 1e100
_BVH_NAME = re.compile(r"[^\s{}]+( [^\s{}]+)*")
_BVH_CHANNELS = set(POSITION_CHANNELS) | set(ROTATION_CHANNELS)
_FRAME_TIME = re.compile(r"[+]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?")


def _from_version_1(arrays: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Version 1 arrays renamed as version 2's: ``track{n}.{key}`` is layer 0."""
    out = {}
    for key, val in arrays.items():
        head, _, rest = key.partition(".")
        if head.startswith("track") and head[5:].isdigit() and rest in _TRACK_ARRAYS:
            key = f"{head}.layer0.{rest}"
        out[key] = val
    return out


def _checked_layer_poses(arrays, lay: int, duration: float, need, arr) -> np.ndarray:
    """The pose times of layer ``lay >= 1``: strictly increasing, from the first
    frame to the last."""
    pose_t = arr(f"layer{lay}.pose_t", 1)
    need(
        len(pose_t) >= 2 and bool(np.all(np.isfinite(pose_t))) and bool(np.all(np.diff(pose_t) > 0)),
        f"layer{lay}.pose_t must hold at least two finite, strictly increasing times",
    )
    need(
        abs(pose_t[0]) < 1e-6 and abs(pose_t[-1] - duration) < 1e-6,
        f"layer{lay}.pose_t must run from the first frame to the last (0 to {duration:.4f} s)",
    )
    return pose_t


def _checked_layer(n, lay, kind, names, arrays, pose_t, need, arr) -> Layer:
    """Layer ``lay`` of track ``n``, checked against its poses ``pose_t``: every
    variable has one extreme knot per pose, in pose order; the base layer's
    editing knots sit at their pose times, and a layer above it has none."""
    from ..model.knots import check_knot_order

    K = len(pose_t)
    V = len(names)
    D = 3 if kind == TRANSLATION else 4
    p = f"track{n}.layer{lay}."
    knot_ptr = arr(p + "knot_ptr", 1, "iu").astype(int)
    knot_t = arr(p + "knot_t", 1)
    knot_v = arr(p + "knot_v", 2)
    knot_pose = arr(p + "knot_pose", 1, "iu").astype(int)
    knot_editing = arr(p + "knot_editing", 1, "b")
    tan_a = arr(p + "tan_a", 2)
    tan_b = arr(p + "tan_b", 2)
    samp_ptr = arr(p + "samp_ptr", 1, "iu").astype(int)
    samp_s = arr(p + "samp_s", 1)
    samp_d = arr(p + "samp_d", 2)
    NK = len(knot_t)
    need(
        knot_ptr.shape == (V + 1,) and knot_ptr[0] == 0 and knot_ptr[-1] == NK, f"{p}knot_ptr does not index the knots"
    )
    need(bool(np.all(np.diff(knot_ptr) >= 1)), f"{p}knot_ptr gives a variable no knot")
    need(
        knot_v.shape == (NK, D) and knot_pose.shape == (NK,) and knot_editing.shape == (NK,),
        f"{p}knot arrays have inconsistent shapes",
    )
    need(tan_a.shape == (NK - V, 3) and tan_b.shape == (NK - V, 3), f"{p}tangents do not match the segments")
    NS = len(samp_s)
    need(
        samp_ptr.shape == (V + 1,) and samp_ptr[0] == 0 and samp_ptr[-1] == NS and bool(np.all(np.diff(samp_ptr) >= 0)),
        f"{p}samp_ptr does not index the samples",
    )
    need(samp_d.shape == (NS, D), f"{p}samp_d has the wrong shape")
    for a, label in (
        (knot_t, "knot times"),
        (knot_v, "knot values"),
        (tan_a, "tangents"),
        (tan_b, "tangents"),
        (samp_s, "samples"),
        (samp_d, "displacements"),
    ):
        need(_rows_all(a, np.isfinite), f"{p}{label} are not all finite")
        need(_rows_all(a, lambda b: np.abs(b) <= _MAX_FITTED), f"{p}{label} are beyond ±{_MAX_FITTED:g}")
    need(
        bool(np.all((knot_t >= pose_t[0] - 1e-6) & (knot_t <= pose_t[-1] + 1e-6))),
        f"{p}knot times lie outside the clip",
    )
    need(bool(np.all((knot_pose >= 0) & (knot_pose < K))), f"{p}knots name poses that do not exist")
    nseg = np.diff(knot_ptr) - 1
    # a variable at a time: no per-sample temporaries of a long clip
    inside, ordered = True, True
    for i in range(V):
        s_i = samp_s[samp_ptr[i] : samp_ptr[i + 1]]
        inside = inside and bool(np.all((s_i >= 0) & (s_i <= nseg[i])))
        ordered = ordered and bool(np.all(np.diff(s_i) >= 0))
    need(inside, f"{p}samples lie outside their variable's segments")
    need(ordered, f"{p}a variable's samples are not in order")
    if kind == ROTATION:
        need(
            _rows_all(knot_v, _unit_rows),
            f"{p}knot rotations are not unit quaternions",
        )
        need(
            _rows_all(samp_d, _unit_rows),
            f"{p}displacement rotations are not unit quaternions",
        )
    try:
        check_knot_order(knot_ptr, knot_t, names)
    except Exception as exc:  # KnotOrderError is a usage error when editing, a data error when read
        raise DataError(f"{p}{exc}") from None
    # every variable has one extreme knot per pose, in pose order, and its
    # editing knots sit at their pose's time (else refinements are undefined)
    var = np.repeat(np.arange(V), np.diff(knot_ptr))
    ext = ~knot_editing.astype(bool)
    need(
        np.array_equal(var[ext], np.repeat(np.arange(V), K))
        and np.array_equal(knot_pose[ext], np.tile(np.arange(K), V)),
        f"{p}knots do not give every variable one extreme knot per pose",
    )
    need(
        bool(np.all(np.abs(knot_t[~ext] - pose_t[knot_pose[~ext]]) < 1e-6)),
        f"{p}editing knots do not sit at their pose times",
    )
    need(lay == 0 or not bool(np.any(knot_editing)), f"{p}a layer above the base has editing knots")
    knots = Knots(knot_ptr, knot_t, knot_v, knot_pose, knot_editing.astype(bool))
    return Layer(knots, tan_a, tan_b, samp_ptr, samp_s, samp_d)
