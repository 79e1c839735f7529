"""The document container: a manifest and named arrays as bytes (SPEC section 7).

A document is a JSON-able *manifest* plus named numeric *arrays*.  This
module turns ``(manifest, arrays)`` into bytes and back; what they mean (the
:class:`~staggered_cli.model.document.Document` they hold) is
:mod:`staggered_cli.io.schema`'s.

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

FORMAT_NAME = "staggered-poses"
#: The container's version (the envelope and its array encoding).
FORMAT_VERSION = 1

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
