"""``staggered new``: a document from key poses blocked in a DCC (a sparse BVH)."""

from __future__ import annotations

import os

import click

from .common import check_output, finite, write_document
from .options import force_option, format_option, input_argument, output_option


def _times(value: str | None):
    if value is None:
        return None
    parts = [p for p in value.split(",") if p.strip()]
    if not parts:
        raise click.BadParameter("expected comma-separated seconds", param_hint="--times")
    return [finite(p, "--times") for p in parts]


@click.command("new")
@input_argument
@click.option(
    "--times",
    metavar="T,T,...",
    help="Seconds of each key (frame) of FILE, from 0, increasing. Default: the file's own frame times.",
)
@output_option
@force_option
@format_option
def new(input_path, times, output, force, fmt):
    """A document whose poses are the frames of the BVH FILE (key poses).

    Cubic splines pass through the keys with smooth blocking tangents; the
    displacement maps are empty.  The motion runs at FILE's frame time.
    """
    from ..api import new as op
    from ..errors import UsageError
    from ..model.document import Document
    from ..motion import BvhMotion
    from .options import load_input

    check_output(output, force)
    t = _times(times)
    motion = load_input(input_path)
    name = "<stdin>" if input_path == "-" else os.path.basename(input_path)
    if isinstance(motion, Document):
        raise UsageError("is already a staggered-poses document: new reads key poses from a BVH", source=name)
    if not isinstance(motion, BvhMotion):
        raise UsageError("new reads key poses from a BVH (this is a C3D)", source=name)
    try:
        doc = op(motion, times=t)
    except UsageError as err:
        raise err.with_source(name) from None
    write_document(doc, output, fmt, force)
