"""``staggered bake``: compose splines, displacement maps and the contact layer into BVH or C3D."""

from __future__ import annotations

import click

from .common import check_motion_output, check_output, finite, read_document, write_motion
from .options import force_option, input_argument, output_option


@click.command("bake")
@input_argument
@output_option
@click.option("--fps", metavar="F", help="Frame rate of the output (default: the source's).")
@click.option(
    "--layers",
    type=click.Choice(["all", "splines"]),
    default="all",
    show_default=True,
    help="'splines' bakes the splines alone: the smooth motion the poses capture.",
)
@click.option("--no-ik", is_flag=True, help="Bake without the contact (IK) layer.")
@click.option(
    "--ik-blend",
    default="0.1",
    show_default=True,
    metavar="S",
    help="Seconds over which the contact layer fades in and out.",
)
@click.option(
    "--move-plants",
    is_flag=True,
    help="The edits moved the figure as a whole: planted feet move with them, horizontally "
    "(by default they stay on their captured path).",
)
@force_option
def bake(input_path, output, fps, layers, no_ik, ik_blend, move_plants, force):
    """Write the motion of document FILE as BVH (BVH source) or C3D (C3D source)."""
    from ..api import bake as op

    check_output(output, force)
    rate = finite(fps, "--fps") if fps is not None else None
    if rate is not None and rate <= 0:
        raise click.BadParameter(f"must be positive, got {fps}", param_hint="--fps")
    if rate is not None:  # the readers' limits, BVH and C3D: never write what they refuse
        from ..motion import rate_problem

        if rate_problem(rate) is not None:
            raise click.BadParameter(f"{fps} {rate_problem(rate)}", param_hint="--fps")
    blend = finite(ik_blend, "--ik-blend")
    if blend < 0:
        raise click.BadParameter(f"must not be negative, got {ik_blend}", param_hint="--ik-blend")
    doc = read_document(input_path)
    check_motion_output(doc.kind, output)
    write_motion(op(doc, fps=rate, layers=layers, ik=not no_ik, ik_blend=blend, move_plants=move_plants), output, force)
