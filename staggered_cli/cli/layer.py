"""``staggered layer``: add, remove and list layers of offsets over the motion."""

from __future__ import annotations

import click

from .common import check_output, finite, read_document, write_document
from .options import force_option, format_option, input_argument, output_option


@click.command("layer")
@input_argument
@click.option("--add", "add", is_flag=True, help="Add a layer of identity offsets on top (the motion is unchanged).")
@click.option(
    "--keep", metavar="N|P%", help="With --add: the layer's poses are N of the current poses, as cull ranks them."
)
@click.option("--times", metavar="T,T,...", help="With --add: the layer's poses are at these times (seconds).")
@click.option("--remove", "remove", type=int, metavar="L", help="Remove layer L (1 and up; the base layer 0 stays).")
@click.option("--list", "list_", is_flag=True, help="List the layers: their poses and how far their offsets reach.")
@output_option
@force_option
@format_option
def layer(input_path, add, keep, times, remove, list_, output, force, fmt):
    """Stack layers of offsets on document FILE, the way animation layers work.

    A layer added with --add holds identity offsets at its own poses (the
    first and last frame always among them), so the motion does not change.
    `edit-pose --layer L --pose K` then edits it: the change spreads smoothly
    between the layer's neighbouring poses, over the detail of the layers
    below.  --remove gives back the motion without that layer, exactly.
    """
    from ..ops import layers as ops

    chosen = [name for name, on in (("--add", add), ("--remove", remove is not None), ("--list", list_)) if on]
    if len(chosen) != 1:
        raise click.UsageError("give one of --add, --remove or --list")
    if (keep is not None or times is not None) and not add:
        raise click.UsageError("--keep and --times go with --add")
    if add and (keep is None) == (times is None):
        raise click.UsageError("--add needs the layer's poses: --keep N or --times T,T,...")
    if not list_:
        check_output(output, force)
    if keep is not None:  # before the document is read (a batch checks its steps so)
        from ..ops.cull import keep_count

        keep_count(keep, 1)
    doc = read_document(input_path)
    if list_:
        click.echo(_table(doc, ops.layer_rows(doc)))
        return
    from .. import api

    if remove is not None:
        doc = api.remove_layer(doc, remove)
    elif keep is not None:
        doc = api.add_layer(doc, keep=keep)
    else:
        values = [v.strip() for v in times.split(",") if v.strip()]
        if not values:
            raise click.BadParameter("give at least one time", param_hint="--times")
        doc = api.add_layer(doc, times=[finite(v, "--times") for v in values])
    write_document(doc, output, fmt, force)


def _table(doc, rows: list[dict]) -> str:
    lines = [f"{'layer':>5}  {'poses':>5}  {'rotation':>9}  {'translation':>11}  times (s)"]
    for row in rows:
        times = ", ".join(doc.seconds(t) for t in row["poses"])
        if len(times) > 60:
            times = times[:57] + "..."
        if row["layer"] == 0:
            lines.append(f"{0:>5}  {len(row['poses']):>5}  {'(base)':>9}  {'':>11}  {times}")
        else:
            lines.append(
                f"{row['layer']:>5}  {len(row['poses']):>5}  {row['largest_rotation']:>8.3g}°  "
                f"{row['largest_translation']:>11.4g}  {times}"
            )
    return "\n".join(lines)
