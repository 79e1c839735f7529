"""Test clips no one captured: the arms of one capture on the body of another
(issue 37's partial poses).

A *spliced* clip takes the root, spine, head and legs channels of one BVH
capture and the channels of both arms (from the clavicle or shoulder down)
of another capture of the same skeleton, over the same number of frames:
the arms then move to another rhythm than the legs, as when an animator keys
a gesture apart from a walk.  The clips are made here from
``../shared/mocap`` at test time (never written into the repository).

The two captures must share the skeleton's joint names and each joint's
channels (CMU's cgspeed conversions do); the frame rates must agree to
0.1 %; the body's frame time and file layout are kept.
"""

from __future__ import annotations

import numpy as np

from staggered_cli import names as joint_names
from staggered_cli.io.bvh import read_bvh
from staggered_cli.motion import BvhMotion

from .conftest import mocap

#: The spliced clips: (body file, its first frame, arms file, its first frame, frames).
#: cmu_115_06 starts on a T-pose frame: its body is taken from frame 1.
SPLICES = {
    "walk+dance_a": ("cmu_02_01_walk.bvh", 0, "cmu_05_06_modern_dance.bvh", 0, 343),
    "walk+dance_b": ("cmu_02_01_walk.bvh", 0, "cmu_05_06_modern_dance.bvh", 480, 343),
    "lift+dance": ("cmu_115_06_pick_up_box.bvh", 1, "cmu_05_06_modern_dance.bvh", 240, 357),
}


def arm_joints(motion: BvhMotion) -> np.ndarray:
    """Indices of both arms' joints: the subtrees of ``@left-arm`` and ``@right-arm``."""
    sk = motion.skeleton
    out = []
    for part in ("left-arm", "right-arm"):
        out.extend(sk.subtree(joint_names.body_part(part, sk.names, sk.parents)))
    return np.array(sorted(set(int(j) for j in out)), dtype=int)


def splice(
    body: BvhMotion, arms: BvhMotion, body_first: int = 0, arms_first: int = 0, n: int | None = None
) -> BvhMotion:
    """``body``'s channels from ``body_first`` with the arm channels of
    ``arms`` from ``arms_first``, ``n`` frames (default: as many as both have)."""
    a, b = body.skeleton, arms.skeleton
    if tuple(a.names) != tuple(b.names) or tuple(a.channels) != tuple(b.channels):
        raise ValueError("the two captures do not share the skeleton's joints and channels")
    if abs(body.frame_time / arms.frame_time - 1.0) > 1e-3:
        raise ValueError(f"frame times differ: {body.frame_time} and {arms.frame_time}")
    if n is None:
        n = min(body.n_frames - body_first, arms.n_frames - arms_first)
    if body_first + n > body.n_frames or arms_first + n > arms.n_frames:
        raise ValueError("not enough frames")
    channels = np.array(body.channels[body_first : body_first + n], dtype=float)
    spans = body.channel_slices()
    for j in arm_joints(body):
        lo, hi = spans[j]
        channels[:, lo:hi] = arms.channels[arms_first : arms_first + n, lo:hi]
    return body.with_channels(channels, same_text=False)


def spliced(name: str) -> BvhMotion:
    """The spliced clip ``name`` (a key of :data:`SPLICES`), read from ../shared/mocap."""
    body_file, body_first, arms_file, arms_first, n = SPLICES[name]
    return splice(read_bvh(mocap(body_file)), read_bvh(mocap(arms_file)), body_first, arms_first, n)
