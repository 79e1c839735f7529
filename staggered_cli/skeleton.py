"""Skeletons: names, parents, offsets and channel layout; forward kinematics.

A skeleton is parallel per-joint arrays in parent-before-child order (the
order joints appear in the BVH HIERARCHY).  Forward kinematics loops over
joints, never over frames.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from . import quat

ROTATION_CHANNELS = ("Xrotation", "Yrotation", "Zrotation")
POSITION_CHANNELS = ("Xposition", "Yposition", "Zposition")


@dataclass(frozen=True)
class Skeleton:
    """A joint hierarchy.

    Attributes
    ----------
    names : tuple of str, (J,)
    parents : (J,) int array, -1 for the root.  Parents come before children.
    offsets : (J, 3) float array, file units, relative to the parent.
    channels : tuple of tuple of str
        Per joint, the BVH channel names in file order (may be empty).
    end_sites : (E,) int array and (E, 3) offsets
        ``end_parents[e]`` is the joint an End Site hangs from.
    """

    names: tuple[str, ...]
    parents: np.ndarray
    offsets: np.ndarray
    channels: tuple[tuple[str, ...], ...]
    end_parents: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    end_offsets: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))

    @property
    def n_joints(self) -> int:
        return len(self.names)

    def index(self, name: str) -> int:
        """Index of joint ``name``: exact, without a namespace prefix, or a body
        part such as ``@left-arm`` (:func:`staggered_cli.names.resolve`);
        ``UsageError`` suggesting close names if unknown."""
        from .names import resolve

        if name in self.names:
            return self.names.index(name)
        return resolve(name, self.names, self.parents, what="joint")

    def rotation_order(self, j: int) -> str:
        """Euler order of joint ``j`` as axis letters, e.g. ``'ZXY'`` ('' if none)."""
        return "".join(c[0] for c in self.channels[j] if c in ROTATION_CHANNELS)

    def has_position(self, j: int) -> bool:
        return any(c in POSITION_CHANNELS for c in self.channels[j])

    def has_rotation(self, j: int) -> bool:
        return len(self.rotation_order(j)) > 0

    def children(self, j: int) -> np.ndarray:
        return np.flatnonzero(self.parents == j)

    def depth_below(self, j: int) -> np.ndarray:
        """Depth of every joint below ``j`` (0 at ``j``), -1 outside its subtree."""
        depth = np.full(self.n_joints, -1, dtype=int)
        depth[j] = 0
        for c in range(j + 1, self.n_joints):
            p = self.parents[c]
            if p >= 0 and depth[p] >= 0:
                depth[c] = depth[p] + 1
        return depth

    def subtree(self, j: int) -> np.ndarray:
        """Indices of ``j`` and all its descendants."""
        return np.flatnonzero(self.depth_below(j) >= 0)

    def tips(self, j: int) -> np.ndarray:
        """Local offsets (n, 3) from joint ``j`` to its children and end sites."""
        kids = [self.offsets[c] for c in self.children(j)]
        kids += [o for p, o in zip(self.end_parents, self.end_offsets, strict=True) if p == j]
        return np.array(kids, dtype=float).reshape(-1, 3)


def forward_kinematics(
    skeleton: Skeleton, rotations: np.ndarray, translations: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """World rotations and positions of every joint.

    Parameters
    ----------
    rotations : (T, J, 4) local rotations, w first.
    translations : (T, J, 3) local translations (the offset, or the position
        channels where a joint has them), file units.

    Returns
    -------
    world_rot : (T, J, 4); world_pos : (T, J, 3), file units.

    The chain runs on component-major copies (4, J, T) and (3, J, T), one
    contiguous row of frames per component and joint, with the operations of
    ``quat.mul`` and ``quat.mul_vec`` in their order (the same bits): a
    joint's column of frame-major arrays is read with a stride of the whole
    frame, which took twice the time on a long clip.
    """
    T, J = rotations.shape[:2]
    rot = np.ascontiguousarray(np.transpose(rotations, (2, 1, 0)), dtype=float)
    tr = np.ascontiguousarray(np.transpose(translations, (2, 1, 0)), dtype=float)
    world_rot = np.empty((4, J, T))
    world_pos = np.empty((3, J, T))
    for j in range(J):
        p = skeleton.parents[j]
        if p < 0:
            world_rot[:, j] = rot[:, j]
            world_pos[:, j] = tr[:, j]
            continue
        quat.mul_rows(world_rot[:, p], rot[:, j], world_rot[:, j])
        pos = world_pos[:, j]
        _mul_vec_rows(world_rot[:, p], tr[:, j], pos)
        pos += world_pos[:, p]
    return (
        np.ascontiguousarray(np.transpose(world_rot, (2, 1, 0))),
        np.ascontiguousarray(np.transpose(world_pos, (2, 1, 0))),
    )


def _mul_vec_rows(q: np.ndarray, v: np.ndarray, out: np.ndarray) -> None:
    """``quat.mul_vec(q, v)`` of (4, n) and (3, n) rows into ``out`` (3, n):
    ``v + w t + u x t`` with ``t = 2 u x v``, as it adds them."""
    w, x, y, z = q
    v0, v1, v2 = v
    t0 = 2.0 * (y * v2 - z * v1)
    t1 = 2.0 * (z * v0 - x * v2)
    t2 = 2.0 * (x * v1 - y * v0)
    np.multiply(w, t0, out=out[0])
    out[0] += v0
    out[0] += y * t2 - z * t1
    np.multiply(w, t1, out=out[1])
    out[1] += v1
    out[1] += z * t0 - x * t2
    np.multiply(w, t2, out=out[2])
    out[2] += v2
    out[2] += x * t1 - y * t0


def end_site_positions(skeleton: Skeleton, world_rot: np.ndarray, world_pos: np.ndarray) -> np.ndarray:
    """World positions ``(T, E, 3)`` of the End Sites."""
    p = skeleton.end_parents
    return world_pos[:, p] + quat.mul_vec(world_rot[:, p], skeleton.end_offsets[None])


def body_joints(skeleton: Skeleton) -> np.ndarray:
    """Joints of the body proper: the subtree of the first joint below the
    root that branches.  Skips a static placeholder root (Bandai's
    ``joint_Root`` at the origin while ``Hips`` carries the translation)."""
    j = int(np.flatnonzero(skeleton.parents < 0)[0])
    while len(skeleton.children(j)) == 1:
        j = int(skeleton.children(j)[0])
    return skeleton.subtree(j) if len(skeleton.children(j)) else np.arange(skeleton.n_joints)


def figure_height(skeleton: Skeleton, world_pos: np.ndarray, end_pos: np.ndarray | None = None) -> float:
    """Size of the figure in file units.

    The median over frames of the largest side of the body's bounding box
    (joints of :func:`body_joints` and their End Sites): independent of the up
    axis and of units, and not fooled by a crouch or a T-pose frame.
    """
    return height_of_extents(skeleton, figure_extents(skeleton, world_pos, end_pos))


def figure_extents(skeleton: Skeleton, world_pos: np.ndarray, end_pos: np.ndarray | None = None) -> np.ndarray:
    """The largest side (T,) of the body's bounding box in each frame (see
    :func:`figure_height`, which is their median): a frame's own, so that
    a long clip can be measured a block of frames at a time."""
    body = body_joints(skeleton)
    pts = world_pos[:, body]
    if end_pos is not None and end_pos.shape[1]:
        pts = np.concatenate([pts, end_pos[:, np.isin(skeleton.end_parents, body)]], axis=1)
    ext = np.max(pts, axis=1) - np.min(pts, axis=1)  # (T, 3)
    return np.max(ext, axis=1)


def height_of_extents(skeleton: Skeleton, extents: np.ndarray) -> float:
    """The figure height of the per-frame :func:`figure_extents`."""
    size = float(np.median(extents))
    if not np.isfinite(size) or size <= 0:
        size = float(np.sum(np.linalg.norm(skeleton.offsets, axis=1))) or 1.0
    return size
