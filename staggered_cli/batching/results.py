"""What happened to each file of a batch, and the summary table."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

#: built: written and different from its input; unchanged: written, the
#: same bytes as its input (e.g. a succession with nothing to retime);
#: skipped: up to date; failed; todo: what a dry run would build.
BUILT, UNCHANGED, SKIPPED, FAILED, TODO = "built", "unchanged", "skipped", "failed", "todo"
STATUSES = (BUILT, UNCHANGED, SKIPPED, FAILED)


@dataclass(frozen=True)
class Result:
    """What happened to one file.

    ``rel`` is its path relative to the input (and output) folder;
    ``status`` one of :data:`STATUSES` (or todo in a dry run); ``seconds``
    its wall time; ``reason`` why it failed (``stage: message``);
    ``messages`` the warnings its stages gave; ``stages`` one line per stage
    saying what it did (extract: poses, contacts; a step: what it changed;
    bake: frames, layers, contacts).  ``cli_reason`` and ``cli_messages``
    are the same texts naming command-line options instead of keywords.
    """

    rel: str
    status: str
    seconds: float | None = None
    reason: str = ""
    messages: tuple[str, ...] = ()
    stages: tuple[str, ...] = ()
    cli_reason: str = field(default="", repr=False, compare=False)
    cli_messages: tuple[str, ...] = field(default=(), repr=False, compare=False)


def summary_table(results: Sequence[Result], cli: bool = False) -> list[str]:
    """The lines of the summary: one row per file (sorted by path)."""
    rows = [("file", "status", "seconds", "reason")]
    for r in sorted(results, key=lambda r: r.rel):
        reason = (r.cli_reason or r.reason) if cli else r.reason
        rows.append((r.rel, r.status, "-" if r.seconds is None else f"{r.seconds:.2f}", reason))
    w0 = max(len(r[0]) for r in rows)
    w1 = max(len(r[1]) for r in rows)
    w2 = max(len(r[2]) for r in rows)
    return [f"{a:<{w0}}  {b:<{w1}}  {c:>{w2}}  {d}".rstrip() for a, b, c, d in rows]


def counts(results: Sequence[Result]) -> dict[str, int]:
    """Files per status (every status of :data:`STATUSES`, zeros included)."""
    out = dict.fromkeys(STATUSES, 0)
    for r in results:
        out[r.status] = out.get(r.status, 0) + 1
    return out
