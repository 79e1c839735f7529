"""``staggered preview FILE -o out.png|out.gif``: stick figures at the poses, or animated."""

from __future__ import annotations

import logging
import re

import click

from ..errors import UsageError
from .common import check_output, check_picture_output
from .options import emit, force_option, input_argument, load_input, output_option
from .plot import title_name

_AT = re.compile(r"^(poses|frames)(?:[:=](\d+))?$")


def join_at(args: list[str]) -> list[str]:
    """``--at frames N`` (two words) -> ``--at frames:N``; the rest unchanged."""
    out, i = [], 0
    while i < len(args):
        a = args[i]
        if a == "--":
            return out + args[i:]
        if a == "--at" and args[i + 1 : i + 2] == ["frames"] and args[i + 2 : i + 3] and args[i + 2].isdigit():
            out += ["--at", f"frames:{args[i + 2]}"]
            i += 3
        elif a == "--at=frames" and args[i + 1 : i + 2] and args[i + 1].isdigit():
            out += ["--at", f"frames:{args[i + 1]}"]
            i += 2
        else:
            out.append(a)
            i += 1
    return out


class PreviewCommand(click.Command):
    """Accepts ``--at frames N`` as two words, which click's options (a fixed
    number of values each) cannot: see :func:`join_at`."""

    def parse_args(self, ctx: click.Context, args: list[str]) -> list[str]:
        return super().parse_args(ctx, join_at(list(args)))


def parse_at(value: str | None) -> tuple[str | None, int | None]:
    """``poses``, ``frames`` or ``frames N`` (also ``frames:N``) -> (what, N)."""
    if value is None:
        return None, None
    m = _AT.match(value.strip())
    if not m:
        raise click.BadParameter(f"expected 'poses', 'frames' or 'frames N', got {value!r}", param_hint="--at")
    n = int(m.group(2)) if m.group(2) else None
    if m.group(1) == "poses" and n is not None:
        raise click.BadParameter("'poses' takes no count", param_hint="--at")
    if n is not None and n < 1:
        raise click.BadParameter(f"N must be at least 1, got {n}", param_hint="--at")
    return m.group(1), n


def _subject(path: str):
    """A document (as :class:`~staggered_cli.model.document.Document`) or a clip."""
    return load_input(path)


@click.command("preview", cls=PreviewCommand)
@input_argument
@click.option(
    "--compare",
    metavar="FILE",
    type=click.Path(allow_dash=True, path_type=str),
    help="A second BVH, C3D or document drawn over FILE in another colour.",
)
@click.option(
    "--at",
    "at",
    metavar="poses|frames N",
    help="Show the pose times (default for a PNG) or N evenly spaced frames "
    "(a GIF defaults to every frame in real time).",
)
@click.option(
    "--format",
    "fmt",
    type=click.Choice(["png", "gif"]),
    default=None,
    help="Picture format. Default: gif when the output name ends in .gif, else png.",
)
@click.option("--dpi", default=None, type=click.IntRange(20, 600), help="Resolution [PNG: 100, GIF: 80].")
@output_option
@force_option
def preview(input_path, compare, at, fmt, dpi, output, force):
    """Stick figures of FILE (BVH, C3D or document) in side and front views.

    A PNG shows panels at the pose times (at most 12, evenly chosen, 3.5
    inches tall, up to 18 inches a row); a GIF animates the clip. A document
    is shown as it bakes. C3D markers are joined by lines along the body.
    """
    from .. import pictures

    check_picture_output(output, "a picture")
    check_output(output, force)
    what, count = parse_at(at)
    gif = fmt == "gif" or (fmt is None and output.lower().endswith(".gif"))
    if input_path == "-" and compare == "-":
        raise UsageError("FILE and --compare cannot both be standard input")
    subject = _subject(input_path)
    other = _subject(compare) if compare is not None else None
    if other is not None:
        differs = pictures.skeleton_difference(subject, other)
        if differs:
            logging.getLogger("staggered_cli").warning(
                "--compare %s is another figure than %s (%s): the drawings do not match joint for joint",
                title_name(compare),
                title_name(input_path),
                differs,
            )
    names = {"name": title_name(input_path), "compare_name": title_name(compare) if compare else None}
    if gif:
        data = pictures.preview_gif(subject, compare=other, at=what or "frames", count=count, dpi=dpi or 80, **names)
    else:
        from ..api import preview as op

        fig = op(subject, compare=other, at=what or "poses", count=count, **names)
        data = pictures.png_bytes(fig, dpi or pictures.DPI, pictures.PREVIEW_COLORS)
    emit(output, data, force)
