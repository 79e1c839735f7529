"""``staggered detail``: scale the displacement maps (the capture's detail)."""

from __future__ import annotations

import click

from .common import check_output, finite, name_list, read_document, time_range, write_document
from .options import force_option, format_option, input_argument, output_option


@click.command("detail")
@input_argument
@click.option(
    "--gain", required=True, metavar="G", help="0 = the splines alone, 1 = unchanged, 0.5 softens, 1.5 accentuates."
)
@click.option("--joints", metavar="A,B", help="Only these joints or markers (default: all).")
@click.option("--subtree", is_flag=True, help="With --joints: include their descendants.")
@click.option("--time", "time", metavar="A:B", help="Only between A and B seconds (eased in and out over 0.1 s).")
@output_option
@force_option
@format_option
def detail(input_path, gain, joints, subtree, time, output, force, fmt):
    """Scale the displacement maps of document FILE by G.

    The splines through the poses stay; what the capture adds on top of them
    (jitter, overlap, small secondary motion) is scaled.  Later culls and
    retimes keep the result.
    """
    from ..api import detail as op
    from ..ops.layers import check_gain

    check_output(output, force)
    g = finite(gain, "--gain")
    check_gain(g)  # before the document is read (a batch checks its steps so)
    if subtree and not joints:
        raise click.UsageError("--subtree needs --joints: it adds the descendants of the joints named there")
    span = time_range(time, "--time")
    doc = read_document(input_path)
    write_document(op(doc, gain=g, joints=name_list(joints), subtree=subtree, time=span), output, fmt, force)
