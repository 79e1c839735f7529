"""``staggered randomize``: random timing offsets, reproducible by seed."""

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


@click.command("randomize")
@input_argument
@click.option("--tau", required=True, metavar="T", help="Bound of the offsets in seconds: r += uniform(-T, T).")
@click.option("--seed", required=True, type=int, help="Random seed (the same seed gives the same document).")
@click.option("--joints", metavar="A,B", help="Only these joints or markers (default: all).")
@click.option("--subtree", is_flag=True, help="With --joints: include their descendants.")
@timing_options
@output_option
@force_option
@format_option
def randomize(input_path, tau, seed, joints, subtree, poses, time, clamp, output, force, fmt):
    """Add random offsets to the refinements of FILE's poses."""
    from ..api import randomize as op

    check_output(output, force)
    t = finite(tau, "--tau")
    if t < 0:
        raise click.BadParameter(f"must not be negative, got {tau}", param_hint="--tau")
    if subtree and not joints:
        raise click.UsageError("--subtree needs --joints: it adds the descendants of the joints named there")
    if seed < 0:
        raise click.BadParameter(f"must not be negative, got {seed}", param_hint="--seed")
    doc = read_document(input_path)
    doc = op(
        doc,
        tau=t,
        seed=seed,
        joints=name_list(joints),
        subtree=subtree,
        poses=int_list(poses, "--poses"),
        time=time_range(time, "--time"),
        clamp=clamp,
    )
    write_document(doc, output, fmt, force)
