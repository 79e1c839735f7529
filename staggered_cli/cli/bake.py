"""``staggered bake``: compose splines, displacement maps and the contact layer into BVH or C3D."""

from __future__ import annotations

import click

from ..errors import cli_text
from .common import check_motion_output, check_output, finite, note, read_document, write_motion
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
@click.option(
    "--unit-scale",
    metavar="S",
    help="glTF output: metres per file unit (default: the C3D's POINT:UNITS, else the unit "
    "that makes the figure 1.0-2.2 m tall; a line on stderr says which).",
)
@click.option(
    "--keys",
    type=click.Choice(["dense", "poses"]),
    default="dense",
    show_default=True,
    help="glTF output: 'dense' keys every frame (LINEAR), the baked motion exactly; 'poses' keys each "
    "joint at its own knots (the staggered poses, CUBICSPLINE) following the splines: the displacement "
    "maps and the contact layer are not in these keys (BVH documents of one layer).",
)
@force_option
def bake(input_path, output, fps, layers, no_ik, ik_blend, move_plants, unit_scale, keys, force):
    """Write the motion of document FILE as BVH (BVH source) or C3D (C3D source),
    or as glTF 2.0 with -o NAME.glb (binary) or NAME.gltf (JSON): a skinned
    skeleton (BVH) or marker nodes (C3D), in metres, Y up."""
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
    from ..io.formats import gltf_format

    as_gltf = gltf_format(None, output) is not None
    scale = finite(unit_scale, "--unit-scale") if unit_scale is not None else None
    if scale is not None and not as_gltf:
        raise click.BadParameter("applies to glTF output (-o NAME.glb or NAME.gltf)", param_hint="--unit-scale")
    if scale is not None and scale <= 0:
        raise click.BadParameter(f"must be positive (metres per unit), got {unit_scale}", param_hint="--unit-scale")
    if keys != "dense" and not as_gltf:
        raise click.BadParameter("applies to glTF output (-o NAME.glb or NAME.gltf)", param_hint="--keys")
    if keys == "poses":  # the keys are the document's knots: no bake options shape them
        given = [
            o
            for o, on in (
                ("--fps", fps),
                ("--layers", layers != "all"),
                ("--no-ik", no_ik),
                ("--move-plants", move_plants),
            )
            if on
        ]
        if given:
            raise click.BadParameter(
                f"poses keys the knots of the splines: {given[0]} does not apply", param_hint="--keys"
            )
    doc = read_document(input_path)
    check_motion_output(doc.kind, output)
    if keys == "poses":
        from ..io.formats import pieces
        from ..io.gltf import unit_scale_for
        from .options import emit

        if scale is None and doc.kind == "bvh":
            scale, why = unit_scale_for(doc.source)
            note(cli_text(why))
        emit(output, pieces(doc, name=output, keys="poses", unit_scale=scale), force)
        return
    motion = op(doc, fps=rate, layers=layers, ik=not no_ik, ik_blend=blend, move_plants=move_plants)
    if not as_gltf:
        write_motion(motion, output, force)
        return
    if scale is None:
        from ..io.gltf import unit_scale_for

        scale, why = unit_scale_for(motion)
        note(cli_text(why))
    write_motion(motion, output, force, unit_scale=scale, keys=keys)
