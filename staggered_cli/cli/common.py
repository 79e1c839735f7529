"""Helpers shared by the commands that read and write staggered-pose documents,
and parsers for the small option languages (``A:B`` ranges, ``J=x,y,z``)."""

from __future__ import annotations

import math

import click

from ..errors import DataError
from .options import check_output, document_format, emit, load_document


def read_document(path: str):
    """The :class:`~staggered_cli.model.document.Document` in ``path`` (``-``: stdin)."""
    return load_document(path)


def write_document(doc, output: str, fmt: str | None, force: bool) -> None:
    """Serialize ``doc`` and write it atomically (or to stdout)."""
    from ..io.formats import pieces

    check_document_output(output)
    emit(output, pieces(doc, document_format(fmt, output), output), force)


def write_motion(motion, output: str, force: bool, **gltf) -> None:
    """Write a BvhMotion as BVH or a MarkerMotion as C3D, or either as glTF
    when ``output`` ends in .glb or .gltf (``gltf``: its keywords)."""
    from ..io.formats import pieces

    emit(output, pieces(motion, name=output, **gltf), force)


def check_motion_output(kind: str, output: str, writer: str | None = None) -> None:
    """See :func:`staggered_cli.io.formats.check_motion_name`."""
    from ..io.formats import check_motion_name

    check_motion_name(kind, output, writer)


def check_picture_output(output: str, what: str) -> None:
    """See :func:`staggered_cli.io.formats.check_picture_name`."""
    from ..io.formats import check_picture_name

    check_picture_name(output, what)


def check_document_output(output: str) -> None:
    """See :func:`staggered_cli.io.formats.check_document_name`."""
    from ..io.formats import check_document_name

    check_document_name(output)


def finite(value: str, what: str) -> float:
    try:
        x = float(value)
    except ValueError:
        raise click.BadParameter(f"{value!r} is not a number", param_hint=what) from None
    if not math.isfinite(x):
        raise click.BadParameter(f"{value!r} is not a finite number", param_hint=what)
    return x


def time_range(value: str | None, what: str) -> tuple[float, float] | None:
    """``'A:B'`` seconds -> (A, B); empty sides mean the clip's ends."""
    if value is None:
        return None
    a, sep, b = value.partition(":")
    if not sep:
        raise click.BadParameter(f"expected A:B seconds, got {value!r}", param_hint=what)
    lo = finite(a, what) if a.strip() else -math.inf
    hi = finite(b, what) if b.strip() else math.inf
    if lo > hi:
        raise click.BadParameter(f"A must not exceed B in {value!r}", param_hint=what)
    return lo, hi


def int_list(value: str | None, what: str) -> list[int] | None:
    if value is None:
        return None
    try:
        out = [int(x) for x in value.split(",") if x.strip()]
    except ValueError:
        raise click.BadParameter(f"expected comma-separated pose indices, got {value!r}", param_hint=what) from None
    if not out:
        raise click.BadParameter("no pose index given", param_hint=what)
    return out


def name_list(value: str | None) -> list[str] | None:
    if value is None:
        return None
    return [x.strip() for x in value.split(",") if x.strip()] or None


def triples(values: tuple[str, ...], what: str) -> dict[str, tuple[float, float, float]]:
    """``('LeftArm=0,0,20', ...)`` -> {'LeftArm': (0, 0, 20)}."""
    out: dict[str, tuple[float, float, float]] = {}
    for item in values:
        name, sep, rest = item.rpartition("=")
        parts = rest.split(",")
        if not sep or not name or len(parts) != 3:
            raise click.BadParameter(f"expected JOINT=x,y,z, got {item!r}", param_hint=what)
        out[name] = tuple(finite(p, what) for p in parts)  # type: ignore[assignment]
    return out


def timing_options(command):
    """``--poses``, ``--time`` and ``--clamp``: which poses a timing edit
    touches and what to do when knots would cross (succession, randomize)."""
    command = click.option("--clamp", is_flag=True, help="Stop knots short of their neighbours instead of refusing.")(
        command
    )
    command = click.option("--time", "time", metavar="A:B", help="Only the poses between A and B seconds.")(command)
    return click.option("--poses", metavar="K,K,...", help="Only these poses (default: all but the first and last).")(
        command
    )


def pose_mask(doc, poses: str | None, time: str | None):
    from ..ops.timing import select_poses

    return select_poses(doc, int_list(poses, "--poses"), time_range(time, "--time"))


def note(message: str) -> None:
    """One informational line on stderr, ``staggered: message`` (silenced by -q)."""
    import logging

    if logging.getLogger("staggered_cli").isEnabledFor(logging.WARNING):
        click.echo(f"staggered: {message}", err=True)


__all__ = ["note", "check_output", "read_document", "write_document", "write_motion", "DataError"]
