"""``staggered edit-pose``: change a pose's geometry or time, keeping the detail."""

from __future__ import annotations

import click

from ..errors import StaggeredError, UsageError
from .common import check_output, finite, name_list, read_document, triples, write_document
from .options import force_option, format_option, input_argument, on_option, output_option


@click.command("edit-pose")
@input_argument
@click.option("--pose", "pose", type=int, help="Pose index, as `info --json` reports it.")
@click.option(
    "--layer",
    type=int,
    default=0,
    show_default=True,
    metavar="L",
    help="Edit pose K of layer L (0: the base layer's staggered poses; see `staggered layer`).",
)
@on_option("Edit")
@click.option(
    "--rotate",
    multiple=True,
    metavar="JOINT=rx,ry,rz",
    help="Rotate by degrees about the joint's local axes (XYZ order).",
)
@click.option(
    "--translate",
    multiple=True,
    metavar="JOINT=x,y,z",
    help="Translate a joint with position channels (or a marker), file units.",
)
@click.option(
    "--exaggerate",
    metavar="W",
    help=(
        "Scale the pose's difference from a reference pose by W (1 = unchanged). BVH: joint rotations only; the "
        "figure keeps its place and heading (the root's translation and its turn about the up axis), its tilt is "
        "scaled. C3D: the marker shape about the body's centre, each limb segment within the lengths the capture "
        "gives it, planted markers held."
    ),
)
@click.option(
    "--relative-to",
    default="average",
    show_default=True,
    metavar="prev|next|average|K",
    help="Reference pose for --exaggerate.",
)
@click.option(
    "--ease",
    metavar="X",
    help="Scale the inner spline controls on both sides of the pose: 1 = unchanged, 0 = linear, above 1 = hold longer.",
)
@click.option("--joints", metavar="A,B", help="Restrict --exaggerate, --from-bvh and --ease to these joints.")
@click.option("--subtree", is_flag=True, help="With --joints: include their descendants.")
@click.option(
    "--from-bvh", "from_bvh", metavar="FILE", help="Set the pose from a frame of a BVH with the same skeleton."
)
@click.option("--frame", type=int, default=None, help="Frame of --from-bvh (0-based).")
@click.option(
    "--root",
    is_flag=True,
    help=(
        "With --from-bvh: take the root's place and heading from the file too; with --exaggerate: scale them too "
        "(default: keep the document's)."
    ),
)
@click.option(
    "--all",
    "all_poses",
    is_flag=True,
    help="With --from-bvh: frame k of the file sets pose k, for every pose (a file from export-poses).",
)
@click.option("--time", "new_time", metavar="T", help="Move the pose to T seconds.")
@click.option("--shift", metavar="DT", help="Move the pose by DT seconds.")
@output_option
@force_option
@format_option
def edit_pose(
    input_path,
    pose,
    layer,
    on,
    rotate,
    translate,
    exaggerate,
    relative_to,
    ease,
    joints,
    subtree,
    from_bvh,
    frame,
    root,
    all_poses,
    new_time,
    shift,
    output,
    force,
    fmt,
):
    """Edit pose K of document FILE; the motion changes only between its neighbours."""
    from ..ops import edit_pose as ops

    check_output(output, force)
    rot = triples(rotate, "--rotate")
    tra = triples(translate, "--translate")
    w = finite(exaggerate, "--exaggerate") if exaggerate is not None else None
    x = finite(ease, "--ease") if ease is not None else None
    # the values and options alone are checked before the document is read (a batch checks its steps so)
    ops.check_values(w, x)
    try:
        ops.check_request(
            pose=pose,
            all_poses=all_poses,
            rotate=bool(rot),
            translate=bool(tra),
            exaggerate=w,
            ease=x,
            from_bvh=from_bvh,
            frame=frame,
            root=root,
            layer=layer,
            time=new_time,
            shift=shift,
            joints=bool(joints),
            subtree=subtree,
        )
    except UsageError as err:  # options that do not go together: a usage error of the command
        raise click.UsageError(err.cli_message()) from None
    if all_poses:
        return _apply_all(input_path, from_bvh, on, joints, subtree, output, force, fmt)
    from ..api import edit_pose as op

    doc = read_document(input_path)
    pose_file = None
    if from_bvh is not None:  # read here, so that its errors name it as the command line gave it
        from ..motion import BvhMotion
        from .options import load_input

        pose_file = load_input(from_bvh)
        if not isinstance(pose_file, BvhMotion):
            from ..io.files import display_name

            raise UsageError("--from-bvh needs a BVH document and a BVH file", source=display_name(from_bvh))
    try:
        doc = op(
            doc,
            pose,
            layer=layer,
            on=on,
            rotate=rot,
            translate=tra,
            exaggerate=w,
            relative_to=relative_to,
            ease=x,
            joints=name_list(joints),
            subtree=subtree,
            from_bvh=pose_file,
            frame=frame,
            root=root,
            time=finite(new_time, "--time") if new_time is not None else None,
            shift=finite(shift, "--shift") if shift is not None else None,
        )
    except StaggeredError as err:
        if from_bvh is not None and err.source == getattr(pose_file, "name", None):
            from ..io.files import display_name

            err.source = display_name(from_bvh)
        raise
    write_document(doc, output, fmt, force)


def _apply_all(input_path, from_bvh, on, joints, subtree, output, force, fmt):
    """``--from-bvh FILE --all``: frame k of FILE sets pose k where it changed."""
    from ..io.files import display_name
    from ..motion import BvhMotion
    from ..ops.pose_file import apply_pose_file
    from .common import note
    from .options import load_input

    doc = read_document(input_path)
    other = load_input(from_bvh)
    name = display_name(from_bvh)
    if not isinstance(other, BvhMotion):
        raise click.UsageError(f"--from-bvh {name} is not a BVH file")
    doc, n_poses, n_joints = apply_pose_file(doc, other, on=on, joints=name_list(joints), subtree=subtree, name=name)
    write_document(doc, output, fmt, force)
    note(
        f"{name}: {n_poses} of {doc.n_poses} poses changed ({n_joints} joint{'' if n_joints == 1 else 's'}); "
        "the others are untouched"
    )
