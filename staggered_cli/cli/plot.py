"""``staggered plot DOC -o out.png``: pictures of the signals, the timing and the curves."""

from __future__ import annotations

import os

import click

from ..errors import StaggeredError
from .common import check_output, check_picture_output, name_list, read_document, time_range
from .options import emit, force_option, input_argument, output_option


def title_name(path: str) -> str:
    """A file as named in a picture's title: its base name."""
    return "<stdin>" if path == "-" else os.path.basename(path)


@click.command("plot")
@input_argument
@output_option
@click.option(
    "--kind",
    type=click.Choice(["signals", "timing", "curves"]),
    default="signals",
    show_default=True,
    help="signals: evidence p_i(t), P(t), poses and contacts; timing: dope sheet of the knots; "
    "curves: channels of a few joints (source, spline layer, baked).",
)
@click.option("--joints", metavar="A,B", help="Joints, markers or variables to draw (default: those that move).")
@click.option("--time", "time", metavar="A:B", help="Seconds to show; an empty side is the clip's end.")
@click.option("--dpi", default=100, show_default=True, type=click.IntRange(20, 600), help="Resolution of the PNG.")
@force_option
def plot(input_path, output, kind, joints, time, dpi, force):
    """Draw document FILE as a PNG picture (12 x 7 inches).

    Rows are in hierarchy order (C3D markers from the highest down), times
    in seconds, angles in degrees; see the README's Pictures section.
    """
    from .. import pictures
    from ..api import plot as op
    from ..io.files import display_name

    check_picture_output(output, "a PNG picture")
    check_output(output, force)
    window = time_range(time, "--time")
    doc = read_document(input_path)
    try:
        fig = op(doc, kind=kind, name=title_name(input_path), joints=name_list(joints), time=window)
    except StaggeredError as err:
        raise err.with_source(display_name(input_path)) from None
    emit(output, pictures.png_bytes(fig, dpi), force)
