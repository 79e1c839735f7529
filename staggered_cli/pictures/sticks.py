"""A clip (or a document as it bakes) as a stick figure: its points and
bones, the views it is seen from and the way it faces.

Up axis (preview, C3D row order): :func:`staggered_cli.contacts.up_direction`,
the world axis along which the figure's per-frame extent is largest (median
over frames: a standing, walking or dancing figure is taller than it is wide
or deep), pointing to the side where the figure lies (capture volumes put the
floor at zero).  Y for the BVH files and BTS C3D, Z for the other C3D files.
The preview strip turns each panel's camera with the figure's heading at
its time (:func:`headings`): the side view looks across the heading, the
front view along it (from the front).  The heading is the left-to-right
direction of the rigid left/right pairs at the figure's middle height (the
hips of a skeleton, the pelvis markers of a marker set) crossed with up;
without such pairs, the direction of travel; for a figure that stays in
place, the clip's own camera.  The clip's own camera (the animated
preview's) looks across the direction of travel from the first frame to
the last (or, for a figure that stays in place, across its narrowest
horizontal spread, which is its depth).
"""

from __future__ import annotations

import re
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from .. import quat
from .common import _up

if TYPE_CHECKING:
    from ..model.document import Document
    from ..motion import BvhMotion, MarkerMotion

_LEFT = re.compile(r"^(left|l(?=[A-Z_]))|(_l|\.l|left)$|^lhand$", re.IGNORECASE)


def _figure_points(
    motion: BvhMotion | MarkerMotion, tree: tuple[np.ndarray, np.ndarray] | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, tuple[str, ...]]:
    """World points ``(T, N, 3)`` (file units, NaN in gaps), bones ``(B, 2)``
    into them, and for each bone whether it is on the figure's left.  BVH:
    the joints of the body proper and their End Sites (a static placeholder
    root would draw a bone from the origin); C3D: the markers, joined by
    :func:`marker_bones` (along ``tree``, a document's marker tree and the
    points it was measured on, where given)."""
    from ..motion import BvhMotion
    from ..skeleton import body_joints, end_site_positions

    if not isinstance(motion, BvhMotion):
        parents, measured = tree if tree is not None else (None, motion.points)
        bones, left = marker_bones(motion.labels, measured, parents)
        return motion.points, bones, left, tuple(motion.labels)
    sk = motion.skeleton
    wr, wp = motion.world()
    ends = end_site_positions(sk, wr, wp)
    body = body_joints(sk)
    ends_kept = np.flatnonzero(np.isin(sk.end_parents, body))
    pts = np.concatenate([wp[:, body], ends[:, ends_kept]], axis=1)
    where = {int(j): n for n, j in enumerate(body)}
    bones, left = [], []
    for j in body:
        p = int(sk.parents[j])
        if p in where:
            bones.append((where[p], where[int(j)]))
            left.append(bool(_LEFT.search(sk.names[j])))
    for n, e in enumerate(ends_kept):
        p = int(sk.end_parents[e])
        bones.append((where[p], len(body) + n))
        left.append(bool(_LEFT.search(sk.names[p])))
    names = tuple(sk.names[j] for j in body) + tuple(f"{sk.names[sk.end_parents[e]]}.end" for e in ends_kept)
    return pts, np.array(bones, dtype=int).reshape(-1, 2), np.array(left, dtype=bool), names


def marker_bones(
    labels: Sequence[str], points: np.ndarray, parents: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Lines to draw between the markers of a set (B, 2), and whether each
    is on the figure's left (B,).

    ``parents`` (M,) is the marker tree to draw (a document's
    :func:`~staggered_cli.ops.marker_chain.document_tree`); without it the
    tree of the most rigid pairs
    (:func:`~staggered_cli.ops.marker_chain.rigid_tree`, the tree a
    randomize or retime of all markers moves them by).  Its lines that no
    body segment could be are left out: longer than :data:`LONGEST_LINE`
    of the figure height, or across the body (a marker on the left to one
    on the right, other than a mirrored pair such as the two hip markers).
    The parts this leaves, and markers the tree does not hold, are then
    joined by the most rigid pairs that are neither (each link the one
    whose distance varies least, as the rigid tree's), so that each body
    segment's markers are joined, the segments where they meet, and the
    limbs to the pelvis on their own side.
    """
    from ..motion import MarkerMotion
    from ..ops.marker_chain import rigid_tree

    M = len(labels)
    if parents is None:
        parents = rigid_tree(points)
    spread, length = _pair_stats(points)
    size = MarkerMotion(tuple(labels), points, 1.0).figure_height()
    sides = np.array(_sides(labels))
    sided = sides != ""
    cross = sided[:, None] & sided[None, :] & (sides[:, None] != sides[None, :])
    for a, b in side_pairs(labels):
        cross[a, b] = cross[b, a] = False
    with np.errstate(invalid="ignore"):
        allowed = (length <= LONGEST_LINE * size) & ~cross & np.isfinite(spread)
    group = np.arange(M)

    def root(i: int) -> int:
        while group[i] != i:
            group[i] = group[group[i]]
            i = int(group[i])
        return i

    def join(a: int, b: int) -> bool:
        ra, rb = root(a), root(b)
        if ra == rb:
            return False
        group[rb] = ra
        return True

    bones: list[tuple[int, int]] = []
    for c in np.flatnonzero(parents >= 0):
        p = int(parents[c])
        if allowed[p, c] and join(p, int(c)):
            bones.append((p, int(c)))
    a, b = np.triu_indices(M, 1)
    ok = allowed[a, b]
    a, b = a[ok], b[ok]
    for k in np.argsort(spread[a, b], kind="stable"):
        if len(bones) == M - 1:
            break
        if join(int(a[k]), int(b[k])):
            bones.append((int(a[k]), int(b[k])))
    out = _rooted(bones, parents, M)
    left = np.array([sides[i] == "left" and sides[j] == "left" for i, j in out], dtype=bool)
    return out, left


def _rooted(bones: list[tuple[int, int]], parents: np.ndarray, M: int) -> np.ndarray:
    """``bones`` (a forest) as (parent, child) pairs, each part hanging from
    the root of ``parents`` it holds (the most rigid marker), else from its
    first marker: a marker in a gap is bridged to its parent's parent."""
    near: list[list[int]] = [[] for _ in range(M)]
    for a, b in bones:
        near[a].append(b)
        near[b].append(a)
    starts = [int(r) for r in np.flatnonzero(parents < 0)] + list(range(M))
    done = np.zeros(M, dtype=bool)
    out: list[tuple[int, int]] = []
    for r in starts:
        if done[r]:
            continue
        done[r] = True
        todo = [r]
        while todo:
            i = todo.pop()
            for j in near[i]:
                if not done[j]:
                    done[j] = True
                    out.append((i, j))
                    todo.append(j)
    return np.array(out, dtype=int).reshape(-1, 2)


def _pair_stats(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Spread (standard deviation over frames) and median of the distance of
    every pair of markers (M, M), gaps ignored: infinite spread and NaN
    length for a pair seen together in fewer than two frames.  Over at most
    400 frames evenly spread, and at most 4 million distances at once."""
    T, M, _ = points.shape
    frames = min(T, 400, max(10, 4_000_000 // max(M * M, 1)))
    pts = points[np.unique(np.linspace(0, T - 1, frames).astype(int))]
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # pairs never seen together
        sq = np.sum(pts * pts, axis=-1)
        d2 = sq[:, :, None] + sq[:, None, :] - 2.0 * np.einsum("tmk,tnk->tmn", pts, pts)
        d = np.sqrt(np.maximum(d2, 0.0))  # (F, M, M), NaN where a marker is missing
        n = np.isfinite(d).sum(axis=0)
        spread = np.where(n >= 2, np.nanstd(d, axis=0), np.inf)
        length = np.where(n >= 2, np.nanmedian(d, axis=0), np.nan)
    np.fill_diagonal(spread, np.inf)
    return spread, length


#: Lines between markers longer than this share of the figure height (median
#: over the clip) are not drawn: longer than any segment of the body (thigh
#: and shank are about 0.25), they join markers the rigid tree links only
#: because it must join them all (c7 to a knee on the BTS walk, 0.73; one
#: thigh to the other on the c3d.org walk, 0.52).
LONGEST_LINE = 0.45


def _sides(names: Sequence[str]) -> list[str]:
    """``'left'``, ``'right'`` or ``''`` for each name, as :func:`side_pairs` reads them."""
    out = [""] * len(names)
    for a, b in side_pairs(names):
        out[a], out[b] = "left", "right"
    return out


@dataclass(frozen=True)
class _Stick:
    """A clip ready to draw: world points (T, N, 3) in file units and bones."""

    name: str
    points: np.ndarray
    bones: np.ndarray
    left: np.ndarray
    frame_time: float
    pose_t: np.ndarray | None
    names: tuple[str, ...] = ()
    markers: bool = False  # a C3D marker set (drawn as dots, lines between them)

    def at(self, times: np.ndarray) -> np.ndarray:
        """Frame indices nearest ``times`` (seconds)."""
        f = np.rint(np.asarray(times) / self.frame_time).astype(int)
        return np.clip(f, 0, len(self.points) - 1)


def _stick(subject: Document | BvhMotion | MarkerMotion, name: str) -> _Stick:
    from ..model.document import Document
    from ..motion import BvhMotion
    from ..ops.bake import bake

    pose_t = tree = None
    if isinstance(subject, Document):
        pose_t = subject.pose_t
        if subject.kind != "bvh":  # the tree its timing edits keep, over the clip it was made from
            from ..ops.marker_chain import document_tree

            tree = (document_tree(subject), subject.source.points)
        subject = bake(subject)
    pts, bones, left, names = _figure_points(subject, tree)
    markers = not isinstance(subject, BvhMotion)
    return _Stick(name, pts, bones, left, float(subject.frame_time), pose_t, names, markers)


@dataclass(frozen=True)
class _View:
    """Projection of world points on the side and front views."""

    up: np.ndarray
    forward: np.ndarray
    lateral: np.ndarray
    size: float
    floor: float
    top: float

    def project(self, pts: np.ndarray, view: str) -> tuple[np.ndarray, np.ndarray]:
        across = self.forward if view == "side" else self.lateral
        return pts @ across, pts @ self.up


def view_axes(points: np.ndarray) -> _View:
    """Up, forward and lateral directions of a figure's points (T, N, 3)."""
    seen = np.all(np.isfinite(points), axis=2)
    good = seen.sum(axis=1) >= max(2, int(0.5 * seen.sum(axis=1).max()))
    pts = points[good] if good.any() else points[:1]
    ok = np.all(np.isfinite(pts), axis=2)
    with np.errstate(invalid="ignore"):
        ext = np.fmax.reduce(pts, axis=1) - np.fmin.reduce(pts, axis=1)
    ext_ok = np.all(np.isfinite(ext), axis=1)
    size = float(np.median(np.max(ext[ext_ok], axis=1))) if ext_ok.any() else 1.0
    size = size if size > 0 else 1.0
    up = _up(pts, size)
    count = np.maximum(ok.sum(axis=1), 1)
    center = np.where(ok[..., None], pts, 0.0).sum(axis=1) / count[:, None]  # (T', 3)
    flat = center - np.outer(center @ up, up)
    travel = flat[-1] - flat[0]
    if np.linalg.norm(travel) > 0.5 * size:
        forward = travel / np.linalg.norm(travel)
    else:  # standing in place: the narrowest horizontal spread of the body is its depth
        rel = np.where(ok[..., None], pts - center[:, None], np.nan).reshape(-1, 3)
        rel = rel[np.all(np.isfinite(rel), axis=1)]
        rel = rel - np.outer(rel @ up, up)
        if len(rel) >= 3:
            _, vecs = np.linalg.eigh(rel.T @ rel)
            forward = vecs[:, 1]  # middle eigenvalue: the smallest is the up axis (zero spread)
        else:
            forward = np.roll(np.abs(up), 1)
    forward = forward - (forward @ up) * up
    forward /= np.linalg.norm(forward)
    lateral = np.cross(up, forward)
    h = pts @ up
    h = h[np.isfinite(h)]
    floor, top = (float(h.min()), float(h.max())) if h.size else (0.0, size)  # no marker ever seen
    return _View(up, forward, lateral, size, floor, top)


#: Pairs of left and right points whose distance varies by less than this
#: share (standard deviation over median) are rigid across the body (hips,
#: pelvis markers): their left-to-right direction is the figure's.
RIGID_PAIR = 0.05
#: The heading at a time is measured over this many seconds around it
#: (against marker noise; a spinning dancer turns a quarter in 0.25 s:
#: on the dev dances and walks, the side panels show the hips at a median
#: 2-13 % of their width in the front panels with it, 15-25 % with 1 s);
#: the direction of travel (without sides) over the longer window, two
#: steps of a slow walk, so that the pelvis' sway from step to step cancels.
HEADING_WINDOW = 0.25
TRAVEL_WINDOW = 2.0


def side_pairs(names: Sequence[str]) -> list[tuple[int, int]]:
    """(left, right) index pairs of points whose names mirror each other:
    ``LeftUpLeg``/``RightUpLeg``, ``UpperLeg_L``/``UpperLeg_R``, ``l asis``/
    ``r asis``, ``Male:LFWT``/``Male:RFWT`` (a leading L or R before capitals,
    when the mirrored label exists)."""
    from ..names import base_name, side, tokens

    bases = [base_name(n) for n in names]
    have = set(bases)
    keys: dict[tuple[str, tuple[str, ...]], int] = {}
    for j, (n, b) in enumerate(zip(names, bases, strict=True)):
        where = side(n)
        if where:
            key = tuple(t for t in tokens(n) if t not in ("l", "r", "left", "right"))
        elif len(b) > 1 and b[0] in "LR" and b[1:].isupper() and ("RL"[b[0] == "R"] + b[1:]) in have:
            where, key = ("left" if b[0] == "L" else "right"), (b[1:],)
        else:
            continue
        keys.setdefault((where, key), j)
    return [(j, keys[("right", k)]) for (w, k), j in keys.items() if w == "left" and ("right", k) in keys]


def headings(stick: _Stick, frames: np.ndarray, view: _View) -> np.ndarray:
    """The figure's forward direction (F, 3), unit and level, at each of
    ``frames``: across the rigid left-right pairs nearest the figure's
    centre in height (the hips, the pelvis markers; :data:`RIGID_PAIR`), their
    left-to-right direction crossed with up, averaged over
    :data:`HEADING_WINDOW` around the frame; without such pairs (or where
    none is seen), the direction of travel over :data:`TRAVEL_WINDOW`; for a figure that stays
    in place, the clip's own view (:func:`view_axes`)."""
    frames = np.asarray(frames, dtype=int)
    pts, up, size = stick.points, view.up, view.size
    T = len(pts)
    half = max(1, round(0.5 * HEADING_WINDOW / stick.frame_time))
    lo, hi = np.clip(frames - half, 0, T - 1), np.clip(frames + half, 0, T - 1)
    lateral = np.full((len(frames), 3), np.nan)
    pairs = side_pairs(stick.names)
    if pairs:
        L, R = np.array([a for a, _ in pairs]), np.array([b for _, b in pairs])
        diff = pts[:, L] - pts[:, R]  # (T, P, 3)
        with np.errstate(invalid="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # pairs never seen
            dist = quat.norm(diff)
            med = np.nanmedian(dist, axis=0)
            rigid = (med > 0.03 * size) & (np.nanstd(dist, axis=0) < RIGID_PAIR * med)
            height = np.nanmedian((pts[:, L] + pts[:, R]) @ up, axis=0) / 2
        if rigid.any():
            # the pairs nearest the figure's centre in height: the hips or pelvis
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                centre = np.nanmedian(pts @ up)
            off = np.where(rigid, np.abs(height - centre), np.inf)
            low = rigid & (off <= off.min() + 0.15 * size)
            flat = diff[:, low] - (diff[:, low] @ up)[..., None] * up  # (T, P', 3)
            summed = np.where(np.isfinite(flat), flat, 0.0).sum(axis=1)  # (T, 3)
            seen = np.isfinite(flat).all(axis=2).any(axis=1)
            csum = np.concatenate([np.zeros((1, 3)), np.cumsum(summed, axis=0)])
            cseen = np.concatenate([[0], np.cumsum(seen)])
            got = cseen[hi + 1] - cseen[lo] > 0
            lateral[got] = (csum[hi + 1] - csum[lo])[got]
    fwd = np.cross(lateral, up)
    # where no side is seen: the direction of travel over the window
    need = ~(quat.norm(fwd) > 1e-9 * size)
    if need.any():
        ok = np.isfinite(pts).all(axis=2)
        count = np.maximum(ok.sum(axis=1), 1)
        centre = np.where(ok[..., None], pts, 0.0).sum(axis=1) / count[:, None]
        centre[~ok.any(axis=1)] = np.nan
        wide = max(1, round(0.5 * TRAVEL_WINDOW / stick.frame_time))
        for k in np.flatnonzero(need):  # (a few panels)
            c = centre[max(frames[k] - wide, 0) : frames[k] + wide + 1]
            c = c[np.isfinite(c).all(axis=1)]
            if len(c) >= 2:
                move = c[-1] - c[0]
                move = move - (move @ up) * up
                if np.linalg.norm(move) > 0.05 * size:
                    fwd[k] = move
    bad = ~(quat.norm(fwd) > 1e-9 * size)
    fwd[bad] = view.forward
    fwd = fwd - np.outer(fwd @ up, up)
    return fwd / quat.norm(fwd)[:, None]


def turned(view: _View, forward: np.ndarray) -> _View:
    """``view`` looking across (side) and along (front) ``forward``."""
    from dataclasses import replace

    return replace(view, forward=forward, lateral=np.cross(view.up, forward))


def skeleton_difference(a, b) -> str | None:
    """How the figure of ``b`` differs from that of ``a`` (documents or
    clips), in a few words, or None when they have the same joints (or
    markers) and sizes within 10 %: ``preview --compare`` warns, since
    the two drawings then do not line up joint for joint."""
    from ..model.document import Document
    from ..motion import BvhMotion

    clips = [x.source if isinstance(x, Document) else x for x in (a, b)]
    names = [tuple(c.skeleton.names) if isinstance(c, BvhMotion) else tuple(c.labels) for c in clips]
    kinds = ["skeleton" if isinstance(c, BvhMotion) else "marker set" for c in clips]
    if kinds[0] != kinds[1]:
        return f"a {kinds[1]}, not a {kinds[0]}"
    what = "joint" if kinds[0] == "skeleton" else "marker"
    if names[0] != names[1]:
        missing = [n for n in names[0] if n not in names[1]]
        extra = [n for n in names[1] if n not in names[0]]
        if missing or extra:
            first = f"no {what} {missing[0]}" if missing else f"an extra {what} {extra[0]}"
            return f"{len(names[1])} {what}s against {len(names[0])}, {first}"
        return f"the same {what}s in another order"
    h = [float(c.figure_height()) for c in clips]
    if abs(h[1] - h[0]) > 0.1 * max(h[0], 1e-12):
        return f"another size: {h[1]:.4g} file units tall against {h[0]:.4g}"
    return None
