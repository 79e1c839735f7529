"""``staggered view FILE [--compare FILE ...] -o view.html``: a page that plays the motion."""

from __future__ import annotations

import click

from ..errors import UsageError
from .options import check_output, emit, force_option, input_argument, load_input, output_option
from .plot import title_name


@click.command("view")
@input_argument
@click.option(
    "--compare",
    "compare",
    metavar="FILE",
    multiple=True,
    type=click.Path(allow_dash=True, path_type=str),
    help="Another BVH, C3D or document drawn over FILE in another colour (repeatable).",
)
@output_option
@force_option
def view(input_path, compare, output, force):
    """Write one HTML page that plays FILE (BVH, C3D or document) in the browser.

    The page works offline from file:// (no network, no server): 3D
    playback with orbit, pan and zoom; play, pause, step, speed and loop; a
    timeline with the pose times and, for a document, its staggered timing
    (as `plot --kind timing`). A document is shown as it bakes. URL
    fragments #t=SECONDS and #pose=K open it paused there.
    """
    from ..api import view as op
    from ..io.page import check_page_name

    check_page_name(output)
    check_output(output, force)
    paths = (input_path, *compare)
    if paths.count("-") > 1:
        raise UsageError("only one of FILE and --compare can be standard input")
    subject = load_input(input_path)
    others = [load_input(p) for p in compare]
    page = op(
        subject,
        compare=others,
        name=title_name(input_path),
        compare_names=[title_name(p) for p in compare],
    )
    emit(output, page.encode("utf-8"), force)

