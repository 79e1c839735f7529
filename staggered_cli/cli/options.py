"""The options every command shares, and the two helpers that move data in
and out of a command: :func:`load_input` and :func:`emit`.

Decorated commands receive these parameters:

==================  ===========================  ==============================
decorator           parameter                    value
==================  ===========================  ==============================
``input_argument``  ``input_path: str``          a path, or ``-`` for stdin
``output_option``   ``output: str``              a path, or ``-`` (the default)
                                                 for stdout
``force_option``    ``force: bool``              overwrite an existing output
``format_option``   ``fmt: str | None``          ``npz``, ``json`` or None
                                                 (then :func:`document_format`
                                                 picks by the output's name)
==================  ===========================  ==============================

Nothing heavy is imported here at module level, so that ``staggered --help``
starts fast.
"""

from __future__ import annotations

import sys
from typing import TYPE_CHECKING, Any

import click

from ..errors import DataError, StaggeredError, UsageError
from ..io import files

if TYPE_CHECKING:
    import numpy as np

    from ..motion import BvhMotion, MarkerMotion

    Document = tuple[dict[str, Any], dict[str, np.ndarray]]

STDIO = files.STDIO

_BOM = b"\xef\xbb\xbf"

#: Where the command's input is remembered, so that the one error path can
#: name it in any error that does not name a file itself.
INPUT_KEY = "staggered.input"


def _remember_input(ctx: click.Context, param: click.Parameter, value: str) -> str:
    ctx.meta[INPUT_KEY] = value
    return value


input_argument = click.argument(
    "input_path",
    metavar="FILE",
    type=click.Path(allow_dash=True, path_type=str),
    callback=_remember_input,
)

output_option = click.option(
    "-o",
    "--output",
    "output",
    metavar="FILE",
    type=click.Path(allow_dash=True, path_type=str),
    default=STDIO,
    show_default=True,
    help="Output file, or '-' for standard output.",
)

force_option = click.option(
    "--force",
    is_flag=True,
    default=False,
    help="Overwrite the output file if it exists.",
)

format_option = click.option(
    "--format",
    "fmt",
    type=click.Choice(["npz", "json"]),
    default=None,
    help="Document format. Default: json when the output name ends in .json, else npz.",
)


def on_option(verb: str):
    """``--on true|extreme``: the true pose at t_k, or the non-staggered pose
    (edit-pose, export-poses)."""
    return click.option(
        "--on",
        "on",
        type=click.Choice(["true", "extreme"]),
        default="true",
        show_default=True,
        help=f"{verb} the true pose at t_k, or the non-staggered pose (the extreme values).",
    )


def document_format(fmt: str | None, output: str) -> str:
    """The document format to write: ``fmt`` if given, else ``json`` for an
    output ending in ``.json`` and ``npz`` for anything else (stdout included)."""
    if fmt is not None:
        return fmt
    return "json" if output != STDIO and output.lower().endswith(".json") else "npz"


def detect_kind(data: bytes) -> str:
    """``'document'``, ``'c3d'`` or ``'bvh'`` from the content of a file.

    Extensions are not looked at (SPEC section 1).  Raises ``ValueError`` for
    anything else; :func:`load_input` turns that into a ``DataError``.
    """
    from ..io.container import is_document

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
        from ..io.bvh import check_header

        check_header(head)


def read_input(path: str) -> tuple[bytes, str]:
    """The bytes of ``path`` (``-``: stdin) and its display name; an input
    that is not a BVH, C3D or document, or a BVH whose header is too long,
    is refused after its first 16 MiB without reading the rest."""
    from ..io.bvh import MAX_HEADER_BYTES

    return files.read_bytes(path, probe=_refuse_early, probe_bytes=MAX_HEADER_BYTES + 64)


def load_input(path: str) -> BvhMotion | MarkerMotion | Document:
    """Read ``path`` (``-`` for stdin) and parse it by content.

    Returns a :class:`~staggered_cli.motion.BvhMotion`, a
    :class:`~staggered_cli.motion.MarkerMotion`, or a document as
    ``(manifest, arrays)``.  Errors are ``DataError`` naming the file.
    """
    zipped = files.open_zip(path)
    if zipped is not None:  # an NPZ document, read from the file: no copy of it in memory
        from ..io.container import parse_document

        name = files.display_name(path)
        with zipped:
            try:
                return parse_document(zipped, name)
            except StaggeredError as err:
                err.with_source(name)
                raise
    data, name = read_input(path)
    try:
        kind = detect_kind(data)
    except ValueError as err:
        raise DataError(str(err), source=name) from None
    try:
        if kind == "document":
            from ..io.container import parse_document

            return parse_document(data, name)
        if kind == "c3d":
            from ..io.c3d import read_c3d

            return read_c3d(path, data=data, name=name)
        from ..io.bvh import read_bvh

        return read_bvh(path, data=data, name=name)
    except StaggeredError as err:
        err.with_source(name)
        raise


def load_document(path: str) -> Document:
    """Like :func:`load_input` but insists on a document: a BVH or C3D given
    where a document is needed is a ``UsageError`` that says what to run."""
    obj = load_input(path)
    if isinstance(obj, tuple):
        return obj
    raise UsageError(
        "is motion capture, not a staggered-poses document: run `staggered extract` on it first",
        source=files.display_name(path),
    )


def check_output(output: str, force: bool) -> None:
    """Refuse an output that exists (without ``force``) before doing any work."""
    files.check_output(output, force)


def _is_binary(data: bytes) -> bool:
    return b"\0" in data[:8192]


def emit(path: str, data, force: bool) -> None:
    """Write ``data`` (bytes, or a list of bytes-like pieces) to ``path``
    atomically, or to stdout for ``-``.

    An existing file is refused without ``force`` (``UsageError`` naming it).
    Binary data (an NPZ document, a C3D) is refused when stdout is a terminal.
    """
    if path == STDIO:
        out = sys.stdout
        # of pieces, the first tells what it is (a zip header, or all the JSON)
        head = bytes(memoryview(data[0] if isinstance(data, list | tuple) and data else data)[:8192])
        if _is_binary(head) and out is not None and out.isatty():
            from ..io.container import is_document

            if is_document(head):
                hint = "refusing to write a binary (NPZ) document to the terminal: use -o FILE or --format json"
            else:
                hint = "refusing to write binary data to the terminal: use -o FILE or redirect standard output"
            raise UsageError(hint, source=files.STDOUT_NAME)
    files.write_atomic(path, data, force)
