"""``staggered export-poses``: a document's poses as a BVH, frame k = pose k (for a DCC)."""

from __future__ import annotations

import click

from .common import check_motion_output, check_output, note, read_document, write_motion
from .options import force_option, input_argument, on_option, output_option


@click.command("export-poses")
@input_argument
@on_option("Write")
@output_option
@force_option
def export_poses(input_path, on, output, force):
    """Write the poses of document FILE as a BVH with one frame per pose.

    Same hierarchy, channels, Euler orders, number format and frame time as
    the source; edit it in a DCC and bring it back with
    `edit-pose FILE --from-bvh poses.bvh --all`.
    """
    from ..api import export_poses as op
    from ..io.files import display_name
    from ..ops.pose_file import frame_note

    check_motion_output("bvh", output, "export-poses")
    check_output(output, force)
    doc = read_document(input_path)
    write_motion(op(doc, on=on), output, force)
    note(frame_note(doc, display_name(output)))
