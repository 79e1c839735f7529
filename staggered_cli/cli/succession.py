"""``staggered succession``: nonlinear succession of timing down a limb."""

from __future__ import annotations

import click

from .common import (
    check_output,
    finite,
    int_list,
    name_list,
    read_document,
    time_range,
    timing_options,
    write_document,
)
from .options import force_option, format_option, input_argument, output_option


@click.command("succession")
@input_argument
@click.option("--joint", metavar="J", help="Joint the succession starts from (depth 0; its subtree follows).")
@click.option(
    "--chain", metavar="M1,M2,...", help="Explicit order instead of --joint (C3D markers): depths 0, 1, 2, ..."
)
@click.option(
    "--offset", "offset", required=True, metavar="S", help="Seconds per unit of depth (negative: the limb leads)."
)
@click.option(
    "--power",
    "power",
    default="1",
    show_default=True,
    metavar="L",
    help="Nonlinearity: r += S * depth**L (1 = linear).",
)
@timing_options
@output_option
@force_option
@format_option
def succession(input_path, joint, chain, offset, power, poses, time, clamp, output, force, fmt):
    """Stagger the timing of FILE's poses down a limb: r[k,i] += S * d(i)**L."""
    from ..api import succession as op

    check_output(output, force)
    s = finite(offset, "--offset")
    p = finite(power, "--power")
    if p <= 0:
        raise click.BadParameter(f"must be positive, got {power}", param_hint="--power")
    if (joint is None) == (chain is None):
        raise click.UsageError("give exactly one of --joint and --chain")
    doc = read_document(input_path)
    doc = op(doc, offset=s, power=p, joint=joint, chain=name_list(chain), poses=int_list(poses, "--poses"),
             time=time_range(time, "--time"), clamp=clamp)
    write_document(doc, output, fmt, force)
