"""``staggered constraints``: list, add, remove and re-detect contact constraints.

The paper pairs its heuristic detector with manual cleanup (section 4.1.2,
Appendix B): every detector makes mistakes.  Without an edit option the
command lists the document's constraints; with one it writes the changed
document.  Edits apply in this order: ``--detect`` (replaces the constraints
on the joints it looks at), ``--remove`` (indices as ``--list`` shows them
for the document as read), ``--add``.  The result is sorted by start time.
"""

from __future__ import annotations

import json
import math

import click

from .common import check_output, finite, name_list, read_document, write_document
from .options import STDIO, force_option, format_option, input_argument, output_option


def parse_span(value: str) -> tuple[str, float, float]:
    """``'JOINT@START:END'`` (seconds) -> (joint, start, end)."""
    joint, sep, times = value.rpartition("@")
    a, colon, b = times.partition(":")
    if not sep or not joint or not colon:
        raise click.BadParameter(f"expected JOINT@START:END (seconds), got {value!r}", param_hint="--add")
    start, end = finite(a, "--add"), finite(b, "--add")
    if start > end:
        raise click.BadParameter(f"START must not exceed END in {value!r}", param_hint="--add")
    return joint, start, end


def _table(constraints) -> str:
    width = max([len("joint")] + [len(c.joint) for c in constraints])
    lines = [f"{'#':>3}  {'joint':<{width}}  {'start':>9}  {'end':>9}  {'duration':>9}"]
    for i, c in enumerate(constraints):
        lines.append(f"{i:>3}  {c.joint:<{width}}  {c.start:>9.4f}  {c.end:>9.4f}  {c.end - c.start:>9.4f}")
    if not constraints:
        lines.append("(no constraints)")
    return "\n".join(lines)


def _json(constraints) -> str:
    rows = [
        {"index": i, "joint": c.joint, "start": round(float(c.start), 9), "end": round(float(c.end), 9)}
        for i, c in enumerate(constraints)
    ]
    return json.dumps({"constraints": rows}, sort_keys=True, indent=2)


@click.command("constraints")
@input_argument
@click.option("--list", "show", is_flag=True, help="List the constraints (the default when nothing is edited).")
@click.option("--json", "as_json", is_flag=True, help="List them as JSON.")
@click.option(
    "--add",
    "adds",
    multiple=True,
    metavar="JOINT@START:END",
    help="Add a constraint: JOINT is planted from START to END seconds (repeatable).",
)
@click.option(
    "--remove", "removes", multiple=True, type=int, metavar="N", help="Remove constraint N as listed (repeatable)."
)
@click.option("--detect", is_flag=True, help="Re-detect contacts on the source motion, replacing those on its joints.")
@click.option(
    "--contact-joints",
    metavar="A,B,...",
    help="Joints or markers --detect looks at. Default: those extract used (feet and toes).",
)
@click.option("--min-contact", type=float, metavar="SECONDS", help="Shortest contact for --detect.")
@click.option(
    "--contact-tolerance", type=float, metavar="F", help="How still a planted joint stays, fraction of figure height."
)
@output_option
@force_option
@format_option
def constraints(
    input_path, show, as_json, adds, removes, detect, contact_joints, min_contact, contact_tolerance, output, force, fmt
):
    """List or edit the contact constraints of document FILE.

    Times are seconds from the first frame.  Without --add, --remove or
    --detect the constraints are listed on standard output; with them the
    changed document is written to -o (standard output by default), and
    --list/--json also print the new list when -o names a file.
    """
    editing = bool(adds or removes or detect)
    if not detect and (contact_joints is not None or min_contact is not None or contact_tolerance is not None):
        raise click.UsageError("--contact-joints, --min-contact and --contact-tolerance go with --detect")
    if detect and removes:
        raise click.UsageError("--remove refers to the listed constraints: run it apart from --detect")
    if editing and (show or as_json) and output == STDIO:
        raise click.UsageError("the document goes to standard output: give -o FILE to also list the constraints")
    if not editing and (output != STDIO or force or fmt is not None):
        raise click.UsageError("nothing to write: give --add, --remove or --detect")
    for value, what in ((min_contact, "--min-contact"), (contact_tolerance, "--contact-tolerance")):
        if value is not None and not math.isfinite(value):
            raise click.BadParameter(f"must be a finite number, got {value}", param_hint=what)
    from ..ops.extract import MAX_MIN_CONTACT

    if min_contact is not None and min_contact > MAX_MIN_CONTACT:
        raise click.BadParameter(
            f"must be at most {MAX_MIN_CONTACT:g} s, got {min_contact:g}", param_hint="--min-contact"
        )
    spans = [parse_span(a) for a in adds]
    if editing:
        check_output(output, force)
    doc = read_document(input_path)

    if not editing:
        click.echo(_json(doc.constraints) if as_json else _table(doc.constraints))
        return

    from ..api import constraints as op

    joints = name_list(contact_joints)
    if detect and contact_joints is not None and not joints:
        raise click.BadParameter("expected comma-separated joint names or marker labels", param_hint="--contact-joints")
    doc = op(
        doc,
        add=spans,
        remove=list(removes),
        detect=detect,
        contact_joints=joints,
        min_contact=min_contact,
        contact_tolerance=contact_tolerance,
    )
    cons = doc.constraints
    write_document(doc, output, fmt, force)
    if show or as_json:
        click.echo(_json(cons) if as_json else _table(cons))
