"""Which files a batch builds: the inputs under a folder, a shard of them,
and those whose output is not up to date.

Up to date: an output is rebuilt when it is missing or older than its input
(make's rule; changing the steps does not make outputs stale: use ``force``).
"""

from __future__ import annotations

import os
from dataclasses import dataclass

from ..errors import UsageError, arg
from .results import SKIPPED, Result

#: File name endings (compared without case) that the batch picks up.
EXTENSIONS = (".bvh", ".c3d")


@dataclass(frozen=True)
class Job:
    """One input file and where its output goes (``rel`` is relative to both folders)."""

    rel: str
    src: str
    dst: str


def find_inputs(in_dir: str) -> list[str]:
    """Paths, relative to ``in_dir`` and sorted, of the BVH and C3D files under it.

    Regular files and links to files, at any depth; links to folders are not
    followed (as ``find -xtype f``).
    """
    from ..io.files import find_files

    return find_files(in_dir, EXTENSIONS)


def _stale(src: str, dst: str) -> bool:
    """make's rule: rebuild when the output is missing or older than the input."""
    try:
        return os.stat(dst).st_mtime_ns < os.stat(src).st_mtime_ns
    except FileNotFoundError:
        return True


def _inside(path: str, folder: str) -> bool:
    path, folder = os.path.realpath(path), os.path.realpath(folder)
    return path == folder or path.startswith(folder.rstrip(os.sep) + os.sep)


def parse_shard(text: str | tuple[int, int]) -> tuple[int, int]:
    """``"I/N"`` (or ``(I, N)``) -> ``(I, N)``: the I-th of N parts, numbered
    from 1 (``1/8`` to ``8/8``), as ``sbatch --array=1-8`` numbers its tasks.
    Raises ``UsageError``."""
    if isinstance(text, tuple | list):
        text = "/".join(str(x) for x in text)
    text = str(text)
    where = f"{arg('shard')} {text[:40]!r}"
    index, slash, count = (part.strip() for part in text.partition("/"))
    if not (slash and _digits(index) and _digits(count)):
        raise UsageError(f"{where}: expected I/N, e.g. 3/8 for the 3rd of 8 parts")
    index, count = int(index), int(count)
    if count < 1:
        raise UsageError(f"{where}: N (the number of parts) must be at least 1")
    if not 1 <= index <= count:
        raise UsageError(f"{where}: I must be between 1 and {count} (parts are numbered from 1)")
    return index, count


def _digits(text: str) -> bool:
    return 0 < len(text) <= 9 and text.isascii() and text.isdigit()


def shard_of(rel: str, count: int) -> int:
    """The part (1 to ``count``) that the input at ``rel`` (relative to the
    input folder) belongs to: a hash of the path with ``/`` separators, so
    that every machine splits a library the same way, whatever the order its
    file system lists the files in, and adding a file moves no other."""
    import hashlib

    key = rel.replace(os.sep, "/").encode("utf-8", "surrogateescape")
    return int.from_bytes(hashlib.sha256(key).digest()[:8], "big") % count + 1


def plan(
    in_dir: str, out_dir: str, force: bool = False, shard: tuple[int, int] | None = None
) -> tuple[list[Job], list[Result]]:
    """The files to build and the ones already up to date; with ``shard``
    ``(I, N)`` only those of the I-th of N parts (:func:`shard_of`).

    Raises ``UsageError`` when ``in_dir`` is not a folder or ``out_dir`` lies
    inside it (the outputs would become inputs of the next run).
    """
    in_dir, out_dir = os.fspath(in_dir), os.fspath(out_dir)
    if not os.path.isdir(in_dir):
        raise UsageError("is not a folder", source=in_dir)
    if _inside(out_dir, in_dir):
        raise UsageError(f"the output folder {out_dir!r} must not be inside the input folder", source=in_dir)
    if os.path.exists(out_dir) and not os.path.isdir(out_dir):
        raise UsageError("output is not a folder", source=out_dir)
    todo: list[Job] = []
    skipped: list[Result] = []
    for rel in find_inputs(in_dir):
        if shard is not None and shard_of(rel, shard[1]) != shard[0]:
            continue
        job = Job(rel, os.path.join(in_dir, rel), os.path.join(out_dir, rel))
        if force or _stale(job.src, job.dst):
            todo.append(job)
        else:
            skipped.append(Result(rel, SKIPPED))
    return todo, skipped
