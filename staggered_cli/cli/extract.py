"""``staggered extract``: dense motion capture (BVH, C3D) -> staggered-pose document."""

from __future__ import annotations

import click

from .common import check_document_output, check_output, write_document
from .options import force_option, format_option, input_argument, output_option


def _names(value: str | None) -> list[str] | None:
    if value is None:
        return None
    names = [n.strip() for n in value.split(",") if n.strip()]
    if not names:
        raise click.BadParameter("expected comma-separated joint names or marker labels", param_hint="--contact-joints")
    return names


def _read_motion(path: str):
    """The clip in ``path``; a document is refused."""
    from ..errors import UsageError
    from ..io.files import display_name
    from ..io.formats import read
    from ..model.document import Document
    from ..ops.extract import MAX_EXTRACT_VALUES

    # a BVH too large to extract is refused from its header, before its values are parsed
    motion = read(path, max_bvh_values=MAX_EXTRACT_VALUES)
    if isinstance(motion, Document):
        raise UsageError("is already a staggered-poses document: extract reads BVH or C3D", source=display_name(path))
    return motion


@click.command("extract")
@input_argument
@output_option
@click.option(
    "--contact-joints",
    metavar="A,B,...",
    help=(
        "Joints (BVH) or marker labels (C3D) to find contacts on. "
        "Default: feet and toes, or the lowest markers of the body."
    ),
)
@click.option(
    "--smoothing",
    type=float,
    default=None,
    metavar="SECONDS",
    help="Laplacian smoothing of the curvature signals (standard deviation, seconds).  [default: 0.025]",
)
@click.option(
    "--filter-width",
    type=float,
    default=None,
    metavar="SECONDS",
    help=(
        "Tent filter width (full base) of the pose probability.  "
        "[default: 0.15, times the stride over 1 s for faster motion]"
    ),
)
@click.option(
    "--refine-window", type=float, default=0.25, show_default=True, metavar="SECONDS", help="Largest timing refinement."
)
@click.option(
    "--min-contact",
    type=float,
    default=0.1,
    show_default=True,
    metavar="SECONDS",
    help="Shortest contact (the paper's 0.25 s misses running stance).",
)
@click.option(
    "--contact-tolerance",
    type=float,
    default=0.03,
    show_default=True,
    metavar="F",
    help="How still a planted joint stays, as a fraction of the figure height.",
)
@click.option(
    "--significance",
    type=float,
    default=0.5,
    show_default=True,
    metavar="X",
    help="Motion a pose needs, in figure heights per second summed over the body (0: keep all).",
)
@click.option(
    "--min-spacing",
    type=float,
    default=None,
    metavar="SECONDS",
    help=(
        "Fewest seconds between two poses (one pose per cluster of coordinated events).  "
        "[default: 0.1, times the stride over 1 s for faster motion]"
    ),
)
@click.option(
    "--partial",
    is_flag=True,
    help="Also find each body part's own poses where its features fall between the whole-body poses (BVH only).",
)
@force_option
@format_option
def extract(
    input_path,
    output,
    contact_joints,
    smoothing,
    filter_width,
    refine_window,
    min_contact,
    contact_tolerance,
    significance,
    min_spacing,
    partial,
    force,
    fmt,
):
    """Find staggered poses, timing refinements and contacts in FILE (BVH or C3D).

    Writes a staggered-pose document (NPZ, or JSON with --format json or an
    output name ending in .json).
    """
    from ..api import extract as run_extract

    check_output(output, force)
    check_document_output(output)  # before the work, not after it
    motion = _read_motion(input_path)
    doc = run_extract(
        motion,
        contact_joints=_names(contact_joints),
        smoothing=smoothing,
        filter_width=filter_width,
        refine_window=refine_window,
        min_contact=min_contact,
        contact_tolerance=contact_tolerance,
        significance=significance,
        min_spacing=min_spacing,
        partial=partial,
    )
    write_document(doc, output, fmt, force)
