"""The byte layer of the staggered-pose document (SPEC section 7).

A document is a JSON-able *manifest* plus named numeric *arrays*.  This
module turns ``(manifest, arrays)`` into bytes and back; what the manifest
and arrays mean is :mod:`staggered_cli.representation`'s business.

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
import math
import re
import struct
import zipfile
import zlib
from typing import Any

import numpy as np

from ..errors import DataError

FORMAT_NAME = "staggered-poses"
FORMAT_VERSION = 1

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


def _npy_bytes(arr: np.ndarray) -> bytes:
    """``.npy`` version 1.0 bytes of a little-endian C-contiguous array.

    The header is written here rather than by NumPy so that the bytes do not
    depend on the NumPy version.
    """
    header = f"{{'descr': {arr.dtype.str!r}, 'fortran_order': False, 'shape': {tuple(arr.shape)!r}, }}"
    # magic (6) + version (2) + length (2) + header + padding + '\n' is a multiple of 64
    pad = -(10 + len(header) + 1) % 64
    header_bytes = (header + " " * pad + "\n").encode("latin1")
    return _NPY_MAGIC + b"\x01\x00" + len(header_bytes).to_bytes(2, "little") + header_bytes + arr.tobytes()


def _zip_member(zf: zipfile.ZipFile, name: str, data: bytes) -> None:
    info = zipfile.ZipInfo(name, date_time=_ZIP_DATE)
    info.compress_type = zipfile.ZIP_STORED
    info.create_system = 3  # unix, so that the mode bits below mean the same everywhere
    info.external_attr = 0o100644 << 16
    zf.writestr(info, data)


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
    items = _canonical(arrays)
    if fmt == "npz":
        index = {name: {"dtype": dname, "shape": list(arr.shape)} for name, dname, arr in items}
        envelope = {"arrays": index, "format": FORMAT_NAME, "manifest": manifest, "version": FORMAT_VERSION}
        members = {MANIFEST_MEMBER: (_dump_manifest(envelope, 1) + "\n").encode("utf-8")}
        for name, _, arr in items:
            members[name + ".npy"] = _npy_bytes(arr)
        buf = io.BytesIO()
        with zipfile.ZipFile(buf, "w", allowZip64=True) as zf:
            for member in sorted(members):
                _zip_member(zf, member, members[member])
        return buf.getvalue()
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
        return text.encode("utf-8")
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


def _parse_npz(data: bytes, name: str) -> tuple[dict, dict[str, np.ndarray]]:
    try:
        return _read_npz(data, name)
    except DataError:
        raise
    except _ZIP_ERRORS as err:
        reason = " ".join(str(err).split())[:80] or type(err).__name__
        raise _fail(name, f"truncated or corrupt NPZ document ({reason})") from None


def _read_npz(data: bytes, name: str) -> tuple[dict, dict[str, np.ndarray]]:
    with zipfile.ZipFile(io.BytesIO(data)) as zf:
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
            if info.compress_size > len(data) or (
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
            arrays[aname] = _read_npy_member(zf, seen[aname + ".npy"], aname, dtype, shape, nbytes, name)
    return env["manifest"], arrays


def _read_npy_member(
    zf: zipfile.ZipFile,
    info: zipfile.ZipInfo,
    aname: str,
    dtype: np.dtype,
    shape: tuple[int, ...],
    nbytes: int,
    name: str,
) -> np.ndarray:
    where = f"array {aname!r}"
    with zf.open(info) as fp:
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
        raw = bytearray(nbytes)
        view = memoryview(raw)
        got = 0
        while got < nbytes:
            n = fp.readinto(view[got:])
            if not n:
                raise _fail(name, f"{where}: truncated data")
            got += n
        fp.read(1)  # reach the end of the member, where zipfile checks its CRC
    arr = np.frombuffer(raw, dtype=ndtype)
    arr = arr.reshape(shape[::-1]).T if fortran else arr.reshape(shape)
    return np.array(arr, dtype=dtype, order="C")


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


def parse_document(data: bytes, name: str) -> tuple[dict, dict[str, np.ndarray]]:
    """``(manifest, arrays)`` from the bytes of a document (npz or json,
    detected by content).

    ``name`` is used in error messages.  Raises :class:`DataError` with a
    one-line reason for anything that is not a valid document of a version
    this code reads.  Arrays come back writable, C-contiguous and in native
    byte order.
    """
    if data[:4] in _ZIP_MAGICS:
        return _parse_npz(data, name)
    if is_document(data):
        return _parse_json(data, name)
    if not data:
        raise _fail(name, "empty file")
    raise _fail(name, f"not a {FORMAT_NAME} document (neither an NPZ zip nor a JSON object)")
