"""A contact constraint: a joint or marker planted over a span of time
(paper Appendix B), moved with the motion by timing edits."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..model.timewarp import warp_span


@dataclass(frozen=True)
class Constraint:
    """A contact: ``joint`` (joint name or marker label) is planted from
    ``start`` to ``end`` seconds (inclusive).

    ``source_start`` and ``source_end`` are the same span in the source's
    time (None: the same as ``start`` and ``end``).  Timing edits move a
    constraint with the motion; the contact layer then follows the
    captured path of its source span, stretched onto the new one.

    ``pin``: the user planted it (``constraints --add``): bake holds the
    point at one place (its mean position over the constraint) whether or
    not an edit disturbed it, rather than following the capture.
    """

    joint: str
    start: float
    end: float
    source_start: float | None = None
    source_end: float | None = None
    pin: bool = False

    @property
    def source_span(self) -> tuple[float, float]:
        s = self.start if self.source_start is None else self.source_start
        e = self.end if self.source_end is None else self.source_end
        return float(s), float(e)

    def warped(self, old_t: np.ndarray, new_t: np.ndarray) -> Constraint:
        """The constraint moved by the piecewise-linear time map ``old_t -> new_t``."""
        s0, s1 = self.source_span
        start, end = warp_span(self.start, self.end, old_t, new_t)
        if (start, end) == (self.start, self.end):
            return self
        return Constraint(self.joint, start, end, s0, s1, self.pin)

