"""Contact constraints as a document operation: check a span to add, and
detect contacts again on the source motion, in the document's time.

The command (``staggered constraints``) parses and lists; what a new or
re-detected constraint is, is decided here.  Pure functions of the document.
"""

from __future__ import annotations

from ..contacts.constraint import Constraint
from ..contacts.detect import (
    DEFAULT_MIN_CONTACT,
    DEFAULT_TOLERANCE,
    contact_joints,
    detect_contacts,
    rest_rule,
    warn_never_rested,
)
from ..contacts.ik import two_bone_chain
from ..errors import UsageError, arg, warn
from ..model.document import Document
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
    document's extract parameters, then the detector's defaults.

    Says what happened when it is not plain (one warning line): a detection
    that finds nothing (which constraints on those joints it removed and how
    many on other joints it kept), or, for joints named in ``joints``, those
    of them that never come to rest.
    """
    named = joints is not None
    params = doc.parameters
    if joints is None and params.get("contact_joints"):
        joints = [str(j) for j in params["contact_joints"]]
    if min_contact is None:
        min_contact = float(params.get("min_contact", DEFAULT_MIN_CONTACT))
    if tolerance is None:
        tolerance = float(params.get("contact_tolerance", DEFAULT_TOLERANCE))
    order = contact_joints(doc.source, joints)
    names = set(order)
    found = detect_contacts(doc.source, sorted(names), min_duration=min_contact, tolerance=tolerance)
    kept = tuple(c for c in doc.constraints if c.joint not in names)
    if not found and order:
        gone = len(doc.constraints) - len(kept)
        warn(
            f"{arg('detect')} found no contact on %s: %s; %s, %s "
            f"(see {arg('contact_tolerance')}, {arg('min_contact')})",
            ", ".join(order),
            rest_rule(min_contact, tolerance),
            f"removed the {_count(gone, 'constraint')} they had" if gone else "there were none on them",
            f"kept the {len(kept)} on other joints" if kept else "no constraint is left",
        )
    elif named:
        warn_never_rested(order, found, min_duration=min_contact, tolerance=tolerance)
    return kept + tuple(retimed(doc, f) for f in found)


def _count(n: int, word: str) -> str:
    return f"{n} {word}{'' if n == 1 else 's'}"


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


def edit_constraints(
    doc: Document,
    *,
    add: list[tuple[str, float, float]] = (),  # type: ignore[assignment]
    remove: list[int] = (),  # type: ignore[assignment]
    detect: bool = False,
    contact_joints: list[str] | None = None,
    min_contact: float | None = None,
    contact_tolerance: float | None = None,
) -> Document:
    """The document with its constraints re-detected (``detect``), then
    ``remove`` (indices as listed) dropped, then ``add`` (joint, start, end)
    planted by the user; sorted by start time."""
    from dataclasses import replace

    from ..errors import arg
    from .extract import MAX_MIN_CONTACT

    if min_contact is not None and not 0 <= min_contact <= MAX_MIN_CONTACT:
        raise UsageError(f"{arg('min_contact')} must be from 0 to {MAX_MIN_CONTACT:g} s, got {min_contact:g}")
    cons = tuple(doc.constraints)
    if detect:
        cons = redetect(doc, contact_joints, min_contact, contact_tolerance)
    if remove:
        n = len(cons)
        bad = [k for k in remove if not -n <= k < n]
        if bad:
            has = f"the document has {n}: 0 to {n - 1}"
            raise UsageError(f"no constraint {bad[0]} ({has})" if n else "the document has no constraints")
        drop = {k % n for k in remove}
        if len(drop) < len(remove):
            twice = next(k for i, k in enumerate(remove) if k % n in {j % n for j in remove[:i]})
            raise UsageError(f"{arg('remove')} {twice}: constraint {twice % n} is named more than once")
        cons = tuple(c for i, c in enumerate(cons) if i not in drop)
    for joint, start, end in add:
        joint, start, end = checked_span(doc, joint, start, end)
        cons = cons + (Constraint(joint, start, end, pin=True),)  # the user says it is planted
    return replace(doc, constraints=tuple(sorted(cons, key=lambda c: (c.start, c.end, c.joint))))
