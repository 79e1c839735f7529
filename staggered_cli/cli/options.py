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
from typing import TYPE_CHECKING

import click

from ..errors import UsageError
from ..io import files

if TYPE_CHECKING:
    from ..model.document import Document
    from ..motion import BvhMotion, MarkerMotion

STDIO = files.STDIO

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
    from ..io.formats import document_format as choose

    return choose(fmt, output)


def detect_kind(data: bytes) -> str:
    """``'document'``, ``'c3d'`` or ``'bvh'`` from a file's content (see
    :func:`staggered_cli.io.formats.detect_kind`)."""
    from ..io.formats import detect_kind as detect

    return detect(data)


def read_input(path: str) -> tuple[bytes, str]:
    """The bytes of ``path`` (``-``: stdin) and its display name (see
    :func:`staggered_cli.io.formats.read_input`)."""
    from ..io.formats import read_input as read

    return read(path)


def load_input(path: str) -> BvhMotion | MarkerMotion | Document:
    """Read ``path`` (``-`` for stdin) and parse it by content: a
    BvhMotion, a MarkerMotion or a Document.  Errors name the file."""
    from ..io.formats import read

    return read(path)


def load_document(path: str) -> Document:
    """Like :func:`load_input` but insists on a document: a BVH or C3D given
    where a document is needed is a ``UsageError`` that says what to run."""
    from ..model.document import Document

    obj = load_input(path)
    if isinstance(obj, Document):
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
