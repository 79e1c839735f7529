"""Contact constraints as a document operation: check a span to add, and
detect contacts again on the source motion, in the document's time.

The command (``staggered constraints``) parses and lists; what a new or
re-detected constraint is, is decided here.  Pure functions of the document.
"""

from __future__ import annotations

from ..contacts import DEFAULT_MIN_CONTACT, DEFAULT_TOLERANCE, contact_joints, detect_contacts
from ..errors import UsageError
from ..ik import two_bone_chain
from ..model.document import Constraint, Document
from ..model.timewarp import from_pairs
from ..motion import BvhMotion


def checked_span(doc: Document, joint: str, start: float, end: float) -> tuple[str, float, float]:
    """A constraint to add must name a joint (with a chain to solve) or marker,
    and lie within the clip: (the document's own name for it, start, end)."""
    joint = doc.target_name(joint)  # exact, without subject prefix, or @part; else UsageError
    if isinstance(doc.source, BvhMotion):
        two_bone_chain(doc.source.skeleton, joint)  # no chain to solve: UsageError
    half = 0.5 * doc.frame_time  # times as the listing prints them (4 decimals) must be accepted
    if start < -half or end > doc.duration + half:
        raise UsageError(
            f"constraint {joint}@{start:g}:{end:g} must lie within the clip (0 to {doc.seconds(doc.duration)})"
        )
    return joint, max(start, 0.0), min(end, doc.duration)


def redetect(
    doc: Document, joints: list[str] | None = None, min_contact: float | None = None, tolerance: float | None = None
) -> tuple[Constraint, ...]:
    """The document's constraints with those on the detected joints replaced by
    a fresh detection on the source motion; unset options come from the
    document's extract parameters, then the detector's defaults."""
    params = doc.parameters
    if joints is None and params.get("contact_joints"):
        joints = [str(j) for j in params["contact_joints"]]
    if min_contact is None:
        min_contact = float(params.get("min_contact", DEFAULT_MIN_CONTACT))
    if tolerance is None:
        tolerance = float(params.get("contact_tolerance", DEFAULT_TOLERANCE))
    names = set(contact_joints(doc.source, joints))
    found = detect_contacts(doc.source, sorted(names), min_duration=min_contact, tolerance=tolerance)
    return tuple(c for c in doc.constraints if c.joint not in names) + tuple(retimed(doc, f) for f in found)


def retimed(doc: Document, found: Constraint) -> Constraint:
    """A constraint detected on the source, moved into the document's time.

    Detection runs on the captured motion, in source time.  Where timing
    edits moved the joint's earlier constraints, their source and current
    spans give the joint's time map; the new constraint follows it (its
    source span stays the detected one).
    """
    pairs = [(0.0, 0.0), (doc.duration, doc.duration)]
    for c in doc.constraints:
        if c.joint == found.joint:
            (s0, s1), (t0, t1) = c.source_span, (c.start, c.end)
            pairs += [(s0, t0), (s1, t1)]
    return found.warped(*from_pairs(pairs))
