"""Partial poses in a document (issue 37): which were found, for which part.

The finding is :mod:`staggered_cli.signals.partial`; this module reads what
:func:`staggered_cli.ops.extract.extract` recorded.
"""

from __future__ import annotations

import numpy as np

from ..model.document import Document
from ..motion import BvhMotion
from ..signals import partial as partial_signals

#: The document parameter the partial poses extract found are recorded in:
#: body part -> their times, seconds.
PARAMETER = "partial_poses"


def part_roots(motion: BvhMotion) -> dict[str, int]:
    """Body part -> its root joint, for the parts the skeleton has."""
    return partial_signals.part_roots(motion)


def partial_times(doc: Document) -> dict[str, np.ndarray]:
    """Body part (``left-arm``, ...) -> the times (seconds, sorted) of its partial poses."""
    found = doc.parameters.get(PARAMETER) or {}
    return {str(p): np.sort(np.asarray(t, dtype=float)) for p, t in found.items()}
