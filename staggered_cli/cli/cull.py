"""``staggered cull``: keep the highest-priority poses; the motion does not change."""

from __future__ import annotations

import click

from .common import check_output, finite, int_list, read_document, time_range, write_document
from .options import force_option, format_option, input_argument, output_option


@click.command("cull")
@input_argument
@click.option(
    "--keep",
    metavar="N|P%",
    help="Keep exactly N poses (P%: round(P x the pose count)), the first and last included, ranked --by.",
)
@click.option("--interval", metavar="A:B", help="Keep the poses between A and B seconds.")
@click.option("--select", metavar="K,K,...", help="Keep these pose indices (as `info` lists them).")
@click.option(
    "--add-time", "add_times", metavar="T", multiple=True, help="Add an unrefined pose at T seconds (repeatable)."
)
@click.option(
    "--part",
    metavar="@PART",
    help="With --add-time: add partial poses that own only this body part (@left-arm, @right-arm, @left-leg, "
    "@right-leg, @spine, @head; BVH).",
)
@click.option(
    "--by",
    type=click.Choice(["error", "paper"]),
    default="error",
    show_default=True,
    help="How --keep ranks poses: the N whose spline layer fits the motion best (error), or the paper's priority.",
)
@click.option(
    "--ignore-contacts",
    is_flag=True,
    help="Rank every pose alike (by default poses on contact changes go last, within the count).",
)
@output_option
@force_option
@format_option
def cull(input_path, keep, interval, select, add_times, part, by, ignore_contacts, output, force, fmt):
    """Keep a subset of the poses of document FILE (first and last always).

    --interval and --select keep exactly those poses; --keep then keeps
    exactly N of them.  --add-time adds poses (with --part, partial poses
    that own one body part).  The displacement maps are refitted so that the
    baked motion is unchanged.
    """
    from ..api import check_keep
    from ..api import cull as op
    from ..model.document import canonical_part

    check_output(output, force)
    times = [finite(t, "--add-time") for t in add_times]
    choosing = keep is not None or interval is not None or select is not None
    if not choosing and not times:
        raise click.UsageError("say what to keep: --keep, --interval, --select, or --add-time")
    # what the options say alone is checked before the document is read (a
    # batch checks its steps so, once, before any file)
    if keep is not None:
        check_keep(keep)
    if part is not None:
        if not times:
            raise click.UsageError("--part says what the poses of --add-time own: give --add-time")
        canonical_part(part)
    span, chosen = time_range(interval, "--interval"), int_list(select, "--select")
    doc = read_document(input_path)
    doc = op(
        doc, keep=keep, interval=span, select=chosen, add_time=times, part=part, by=by, ignore_contacts=ignore_contacts
    )
    write_document(doc, output, fmt, force)
