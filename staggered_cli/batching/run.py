"""One file of a batch through the public API: read, extract, steps, bake, write.

:func:`run_file` never raises for a bad file: it returns a
:class:`~.results.Result` saying what happened, with one line per stage of
what the stage did and the warnings the stages gave.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from typing import Any

from ..errors import StaggeredError, cli_text, python_text
from .plan import Job
from .results import BUILT, FAILED, UNCHANGED, Result
from .steps import Step


@dataclass(frozen=True)
class Plan:
    """What to do with every file: the extract options, the steps for each
    kind of file (checked, :func:`~.steps.check_steps`) and the bake options."""

    steps_bvh: tuple[Step, ...] = ()
    steps_c3d: tuple[Step, ...] = ()
    extract_opts: dict[str, Any] = field(default_factory=dict)
    bake_opts: dict[str, Any] = field(default_factory=dict)


def _plural(n: int, word: str) -> str:
    return f"{n} {word}{'' if n == 1 else 's'}"


def _retimed(before, after) -> int:
    """Variables (joint channels, markers) whose knot times a step changed;
    -1 when the tracks are not comparable (another variable layout)."""
    import numpy as np

    if len(before.tracks) != len(after.tracks):
        return -1
    changed = 0
    for a, b in zip(before.tracks, after.tracks, strict=True):
        ka, kb = a.base.knots, b.base.knots
        if ka.n_vars != kb.n_vars:
            return -1
        if ka.t.shape == kb.t.shape and np.array_equal(ka.ptr, kb.ptr) and np.array_equal(ka.t, kb.t):
            continue
        for i in range(ka.n_vars):  # a loop over variables (tens), not frames
            ta, tb = ka.t[ka.ptr[i] : ka.ptr[i + 1]], kb.t[kb.ptr[i] : kb.ptr[i + 1]]
            changed += int(ta.shape != tb.shape or not np.array_equal(ta, tb))
    return changed


def describe_change(before, after) -> str:
    """What a step changed in a document, in a few words."""
    parts = []
    if after is before:
        return "nothing changed"
    if after.n_poses != before.n_poses:
        parts.append(
            f"{after.n_poses} of {before.n_poses} poses kept"
            if after.n_poses < before.n_poses
            else f"poses {before.n_poses} -> {after.n_poses}"
        )
    if after.n_layers != before.n_layers:
        parts.append(f"layers {before.n_layers} -> {after.n_layers}")
    if len(after.constraints) != len(before.constraints):
        parts.append(f"contacts {len(before.constraints)} -> {len(after.constraints)}")
    if not parts:
        moved = _retimed(before, after)
        if moved > 0:
            parts.append(f"the knots of {_plural(moved, 'variable')} retimed")
    return ", ".join(parts) or "poses, layers, contacts and knot times as they were"


def _reason(stage: str, err: BaseException, job: Job) -> tuple[str, str]:
    """One line, as Python and as the command line name arguments: the stage
    and what went wrong (the table names the file)."""
    if isinstance(err, StaggeredError):
        own = err.source is None or err.source in (job.src, job.dst, "<bytes>")
        raw = err.message if own else f"{err.source}: {err.message}"
        return f"{stage}: {_one_line(python_text(raw))}", f"{stage}: {_one_line(cli_text(raw))}"
    text = f"{stage}: internal error: {type(err).__name__}: {_one_line(str(err))}"
    return text, text


def _one_line(text: str) -> str:
    return " ".join(line.strip() for line in str(text).splitlines() if line.strip())


def remove_output(path: str) -> None:
    """Remove an output left from an earlier run (it no longer matches its input)."""
    from ..io.files import remove_quietly

    remove_quietly(path)


class _Collect(logging.Handler):
    """Keeps the text of each warning logged while a file runs."""

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.lines: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.lines.append(record.getMessage())


def run_file(job: Job, plan: Plan) -> Result:
    """Extract, apply the steps of the file's kind and bake one file; never raises for a bad file.

    The output is written atomically (replacing an older one); a file that
    fails leaves no output.  The status is ``unchanged`` when the output
    holds the same bytes as the input.
    """
    import warnings

    from .. import api
    from ..io.files import make_parent, same_bytes

    start = time.perf_counter()
    stages: list[str] = []
    stage = "extract"
    status = BUILT
    logged = _Collect()
    logger = logging.getLogger("staggered_cli")  # the modules that still log rather than warn
    logger.addHandler(logged)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            t = time.perf_counter()
            clip = api.read(job.src)
            doc = api.extract(clip, **plan.extract_opts)
            stages.append(
                f"extract: {_plural(doc.n_poses, 'pose')}, {_plural(len(doc.constraints), 'contact')}, "
                f"{time.perf_counter() - t:.2f} s"
            )
            for name, kwargs in plan.steps_bvh if doc.kind == "bvh" else plan.steps_c3d:
                stage = name.replace("_", "-")
                t = time.perf_counter()
                before, doc = doc, getattr(api, name)(doc, **kwargs)
                stages.append(f"{stage}: {describe_change(before, doc)}, {time.perf_counter() - t:.2f} s")
                del before
            stage = "bake"
            t = time.perf_counter()
            motion = api.bake(doc, **plan.bake_opts)
            make_parent(job.dst)
            api.write(motion, job.dst, force=True)
            if same_bytes(job.dst, clip.source):
                status = UNCHANGED
            stages.append(
                f"bake: {_plural(motion.n_frames, 'frame')} at {float(motion.rate):g} Hz, "
                f"{_plural(doc.n_layers, 'layer')}, {_plural(len(doc.constraints), 'contact')} held"
                f"{' (the input unchanged)' if status == UNCHANGED else ''}, {time.perf_counter() - t:.2f} s"
            )
        except Exception as err:  # one file's failure, whatever it is, is reported and the batch goes on
            remove_output(job.dst)
            status = FAILED
            reason, cli_reason = _reason(stage, err, job)
        else:
            reason = cli_reason = ""
    logger.removeHandler(logged)
    messages = [w.message.args[0] if w.message.args else str(w.message) for w in caught] + logged.lines
    return Result(
        job.rel,
        status,
        time.perf_counter() - start,
        reason,
        tuple(_one_line(python_text(str(m))) for m in messages),
        tuple(stages),
        cli_reason,
        tuple(_one_line(cli_text(str(m))) for m in messages),
    )
