"""Any file the tool reads or writes, by content: BVH, C3D or a document.

:func:`read` tells a file's kind from its bytes (never from its name) and
hands it to its reader; :func:`write` picks the writer by the value's kind
and checks the output's name against it.  Paths, ``-`` (standard input or
output), bytes and binary file objects all work, so the command line, the
batch and a Python caller share one path in and one path out.
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING, Any, BinaryIO

from ..errors import DataError, StaggeredError, UsageError, arg
from . import files

if TYPE_CHECKING:
    from ..model.document import Document
    from ..motion import BvhMotion, MarkerMotion

STDIO = files.STDIO
_BOM = b"\xef\xbb\xbf"

#: Output name endings that say what a file holds (compared without case).
KIND_OF_EXTENSION = {
    ".bvh": "bvh",
    ".c3d": "c3d",
    ".stag": "document",
    ".npz": "document",
    ".json": "document",
    ".glb": "gltf",
    ".gltf": "gltf",
}
#: Formats a motion may be written in besides its own: glTF, binary or JSON.
GLTF_FORMATS = ("glb", "gltf")


def detect_kind(data: bytes) -> str:
    """``'document'``, ``'c3d'`` or ``'bvh'`` from the content of a file.

    Extensions are not looked at (SPEC section 1).  Raises ``ValueError`` for
    anything else; :func:`read` turns that into a ``DataError``.
    """
    from .container import is_document

    if is_document(data):
        return "document"
    if len(data) >= 2 and data[1] == 0x50:  # C3D header: parameter-section key 0x50 at byte 1
        return "c3d"
    text = data[3:64] if data.startswith(_BOM) else data[:64]
    if text.lstrip(b" \t\r\n").upper().startswith(b"HIERARCHY"):
        return "bvh"
    if not data:
        raise ValueError("empty file")
    if data.startswith((b"\xff\xfe", b"\xfe\xff", b"\x00\x00\xfe\xff")) or b"\x00" in data[:2]:
        for enc in ("utf-32", "utf-16", "utf-16-le", "utf-16-be"):
            try:
                head = data[:256].decode(enc, errors="ignore").lstrip("\ufeff \t\r\n")
            except UnicodeError:
                continue
            if head.upper().startswith(("HIERARCHY", "{")):
                raise ValueError(f"is {enc.upper()[:6]} text: save it as UTF-8 (BVH and JSON are read as UTF-8)")
    raise ValueError("not a BVH, C3D or staggered-poses document (unrecognized content)")


def _refuse_early(head: bytes) -> None:
    """Probe of :func:`read_input` on the first bytes of a large input."""
    try:
        kind = detect_kind(head)
    except ValueError as err:
        raise DataError(str(err)) from None
    if kind == "bvh":
        from .bvh import check_header

        check_header(head)


def read_input(path: str) -> tuple[bytes, str]:
    """The bytes of ``path`` (``-``: stdin) and its display name; an input
    that is not a BVH, C3D or document, or a BVH whose header is too long,
    is refused after its first 16 MiB without reading the rest."""
    from .bvh import MAX_HEADER_BYTES

    return files.read_bytes(path, probe=_refuse_early, probe_bytes=MAX_HEADER_BYTES + 64)


def parse(data: bytes, name: str, *, max_bvh_values: int | None = None, path: str = "") -> Any:
    """The motion (BvhMotion, MarkerMotion) or document in ``data``, read by
    its content; ``name`` names it in errors and is kept as the motion's
    ``name`` (its base name)."""
    try:
        kind = detect_kind(data)
    except ValueError as err:
        raise DataError(str(err), source=name) from None
    try:
        if kind == "document":
            from .container import parse_document
            from .schema import from_parts

            return from_parts(*parse_document(data, name))
        if kind == "c3d":
            from .c3d import read_c3d

            motion = read_c3d(path or name, data=data, name=name)
        else:
            from .bvh import read_bvh

            motion = read_bvh(path or name, data=data, name=name, max_values=max_bvh_values)
    except StaggeredError as err:
        raise err.with_source(name) from None
    from dataclasses import replace

    return replace(motion, name=_base_name(name))


def _base_name(name: str) -> str:
    return name if name.startswith("<") else os.path.basename(name)


def read(source: str | os.PathLike | bytes | bytearray | memoryview | BinaryIO, *, max_bvh_values: int | None = None):
    """Read a BVH, a C3D or a staggered-pose document, by its content.

    ``source`` is a path (``-``: standard input), the file's bytes, or a
    binary file object.  A document in an NPZ file is read in place, not
    copied into memory whole.
    """
    if isinstance(source, bytes | bytearray | memoryview):
        return parse(bytes(source), "<bytes>", max_bvh_values=max_bvh_values)
    if hasattr(source, "read"):
        name = str(getattr(source, "name", "") or "<file>")
        data = source.read()
        if not isinstance(data, bytes | bytearray):
            raise UsageError(f"{arg('source')} must be opened in binary mode ('rb'), not text", source=name)
        return parse(bytes(data), name, max_bvh_values=max_bvh_values)
    if not isinstance(source, str | os.PathLike):
        raise UsageError(
            f"{arg('source')} must be a path, bytes or a binary file object, got {type(source).__name__}"
        )
    path = os.fspath(source)
    zipped = files.open_zip(path)
    if zipped is not None:  # an NPZ document, read from the file: no copy of it in memory
        from .container import parse_document
        from .schema import from_parts

        name = files.display_name(path)
        with zipped:
            try:
                return from_parts(*parse_document(zipped, name))
            except StaggeredError as err:
                raise err.with_source(name) from None
    data, name = read_input(path)
    return parse(data, name, max_bvh_values=max_bvh_values, path=path)


def kind_in_name(output: str) -> str | None:
    """What the output name's extension says it holds (None: ``-`` or no known extension)."""
    return None if output == STDIO else KIND_OF_EXTENSION.get(os.path.splitext(output)[1].lower())


def check_motion_name(kind: str, output: str, writer: str | None = None) -> None:
    """Refuse an output name whose extension says another kind than the
    ``kind`` (``'bvh'`` or ``'c3d'``) being written: ``walk.c3d`` of a BVH
    would otherwise hold BVH text (``writer``: the command, when it is not a
    bake of a document of that kind).  Names without a known extension
    (``-``, ``/dev/null``, ``out.txt``) are taken as they are."""
    said = kind_in_name(output)
    if said is not None and said != kind and said != "gltf":  # any motion may be written as glTF
        what = "a document" if said == "document" else said.upper()
        does = f"{writer} writes" if writer else f"a {kind.upper()} document bakes to"
        raise UsageError(f"{does} {kind.upper()}, but the name says {what}", source=output)


def check_document_name(output: str) -> None:
    """Refuse a document output name that says BVH or C3D: a zip would
    otherwise land under a motion file's name."""
    said = kind_in_name(output)
    if said in ("bvh", "c3d", "gltf"):
        raise UsageError(
            f"this writes a staggered-pose document, but the name says {'glTF' if said == 'gltf' else said.upper()} "
            "(`bake` writes the motion; name the document .stag)",
            source=output,
        )


def check_picture_name(output: str, what: str) -> None:
    """Refuse an output name whose extension says a motion file or a
    document: a picture (``what``, e.g. ``'a PNG picture'``) would otherwise
    land under a motion file's name."""
    said = kind_in_name(output)
    if said is not None:
        kind = "a document" if said == "document" else "glTF" if said == "gltf" else said.upper()
        raise UsageError(f"this writes {what}, but the name says {kind}", source=output)


def document_format(fmt: str | None, output: str) -> str:
    """The document format to write: ``fmt`` if given, else ``json`` for an
    output ending in ``.json`` and ``npz`` for anything else (stdout included)."""
    if fmt is not None:
        if fmt not in ("npz", "json"):
            raise UsageError(f"{arg('format')} must be 'npz' or 'json', got {fmt!r}")
        return fmt
    return "json" if output != STDIO and output.lower().endswith(".json") else "npz"


def gltf_format(fmt: str | None, name: str) -> str | None:
    """``'glb'`` or ``'gltf'`` when a motion is to be written as glTF: ``fmt``
    if given, else the name's extension (``.glb``, ``.gltf``); None: the
    motion's own format."""
    if fmt is not None:
        if fmt not in GLTF_FORMATS:
            raise UsageError(
                f"{arg('format')} of a motion must be 'glb' or 'gltf' (default: its own, BVH or C3D), got {fmt!r}"
            )
        return fmt
    if kind_in_name(name) == "gltf":
        return os.path.splitext(name)[1].lower()[1:]
    return None


def pieces(value, fmt: str | None = None, name: str = STDIO, **gltf) -> list | bytes:
    """The bytes of ``value`` as written: a Document (NPZ or JSON by ``fmt``
    or the name), a BvhMotion as BVH text, a MarkerMotion as C3D, a motion
    as glTF (``fmt`` ``'glb'`` or ``'gltf'``, or a name ending so; ``gltf``:
    the keywords of :func:`staggered_cli.io.gltf.gltf_pieces`)."""
    from ..model.document import Document
    from ..motion import BvhMotion, MarkerMotion

    gltf = {k: v for k, v in gltf.items() if v is not None}  # None: the default
    if isinstance(value, Document):
        from .container import document_pieces
        from .schema import to_parts

        if gltf_format(fmt if fmt in GLTF_FORMATS else None, name) is not None:
            if gltf.get("keys") != "poses":
                raise UsageError(f"a document is written as glTF with {arg('keys')} 'poses' (bake it for its motion)")
            from .gltf import gltf_pieces

            binary = gltf_format(fmt if fmt in GLTF_FORMATS else None, name) == "glb"
            return gltf_pieces(value.source, binary=binary, document=value, **gltf)
        if gltf:
            raise UsageError(f"{arg(next(iter(gltf)))} applies to glTF output (a motion written as .glb or .gltf)")
        manifest, arrays = to_parts(value)
        return document_pieces(manifest, arrays, document_format(fmt, name))
    as_gltf = gltf_format(fmt, name) if isinstance(value, BvhMotion | MarkerMotion) else None
    if as_gltf is not None:
        from .gltf import gltf_pieces

        return gltf_pieces(value, binary=as_gltf == "glb", **gltf)
    if gltf:
        raise UsageError(f"{arg(next(iter(gltf)))} applies to glTF output (a name ending in .glb or .gltf)")
    if isinstance(value, BvhMotion):
        from .bvh import bvh_pieces

        return bvh_pieces(value)
    if isinstance(value, MarkerMotion):
        from .c3d import c3d_bytes

        return c3d_bytes(value)
    raise UsageError(f"{arg('value')} must be a Document, a BvhMotion or a MarkerMotion, got {type(value).__name__}")


def check_name_for(value, output: str) -> None:
    """Refuse an output name that says another kind than ``value``'s."""
    from ..model.document import Document

    if isinstance(value, Document):
        if kind_in_name(output) != "gltf":  # a document's pose keys may be written as glTF
            check_document_name(output)
    else:
        from ..motion import BvhMotion

        check_motion_name("bvh" if isinstance(value, BvhMotion) else "c3d", output, "this")


def write(
    value: Document | BvhMotion | MarkerMotion,
    dest: str | os.PathLike | BinaryIO,
    *,
    format: str | None = None,
    force: bool = False,
    **gltf,
) -> None:
    """Write a document, a BVH motion or a C3D motion to ``dest`` (a path,
    ``-`` for standard output, or a binary file object), atomically for a
    path: the file is complete or not there, and an existing one is refused
    unless ``force``.  A motion named ``.glb``/``.gltf`` (or with ``format``
    ``'glb'``/``'gltf'``) is written as glTF, with the keywords ``gltf`` of
    :func:`staggered_cli.io.gltf.gltf_pieces` (``unit_scale``, ``keys``)."""
    if hasattr(dest, "write"):
        data = pieces(value, format, str(getattr(dest, "name", "") or STDIO), **gltf)
        for piece in data if isinstance(data, list | tuple) else [data]:
            dest.write(piece)
        return
    if not isinstance(dest, str | os.PathLike):
        raise UsageError(f"{arg('dest')} must be a path or a binary file object, got {type(dest).__name__}")
    path = os.fspath(dest)
    check_name_for(value, path)
    files.check_output(path, force)
    files.write_atomic(path, pieces(value, format, path, **gltf), force)
