"""Make the bundled samples: a small procedural BVH and a C3D of its joints.

``march.bvh``: a 15-joint figure marching in place for 4 s at 30 Hz, in
centimetres, Y up, ZXY Euler channels.  Thigh and shin have equal lengths and
the knee bends twice the hip, so a lifted foot rises straight up and comes
down where it left: every step is a real foot plant.  Arms swing against the
legs with the elbows and hands following a little later, and seeded noise
adds capture-like detail.

``march.c3d``: markers at the same figure's joints and end sites (mm, 60 Hz,
Z up) with a short gap in one marker, like a real capture.

Run ``python data/samples/make_samples.py`` (``make samples``); the files are
deterministic.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[1]))

from staggered_cli import quat  # noqa: E402
from staggered_cli.io.bvh import bvh_bytes  # noqa: E402
from staggered_cli.motion import BvhMotion, MarkerMotion, channels_from_local  # noqa: E402
from staggered_cli.skeleton import Skeleton, end_site_positions, forward_kinematics  # noqa: E402

# name, parent, offset (cm)
JOINTS = [
    ("Hips", -1, (0.0, 90.0, 0.0)),
    ("Spine", 0, (0.0, 12.0, 0.0)),
    ("Chest", 1, (0.0, 18.0, 0.0)),
    ("Neck", 2, (0.0, 20.0, 0.0)),
    ("Head", 3, (0.0, 8.0, 0.0)),
    ("LeftArm", 2, (18.0, 16.0, 0.0)),
    ("LeftForeArm", 5, (0.0, -28.0, 0.0)),
    ("LeftHand", 6, (0.0, -25.0, 0.0)),
    ("RightArm", 2, (-18.0, 16.0, 0.0)),
    ("RightForeArm", 8, (0.0, -28.0, 0.0)),
    ("RightHand", 9, (0.0, -25.0, 0.0)),
    ("LeftUpLeg", 0, (9.0, -4.0, 0.0)),
    ("LeftLeg", 11, (0.0, -42.0, 0.0)),
    ("LeftFoot", 12, (0.0, -42.0, 0.0)),
    ("RightUpLeg", 0, (-9.0, -4.0, 0.0)),
    ("RightLeg", 14, (0.0, -42.0, 0.0)),
    ("RightFoot", 15, (0.0, -42.0, 0.0)),
]
END_SITES = [
    (4, (0.0, 12.0, 0.0)),
    (7, (0.0, -8.0, 0.0)),
    (10, (0.0, -8.0, 0.0)),
    (13, (0.0, -2.0, 14.0)),
    (16, (0.0, -2.0, 14.0)),
]


def skeleton() -> Skeleton:
    rot = ("Zrotation", "Xrotation", "Yrotation")
    return Skeleton(
        names=tuple(n for n, _, _ in JOINTS),
        parents=np.array([p for _, p, _ in JOINTS]),
        offsets=np.array([o for _, _, o in JOINTS], dtype=float),
        channels=tuple((("Xposition", "Yposition", "Zposition") + rot) if p < 0 else rot for _, p, _ in JOINTS),
        end_parents=np.array([p for p, _ in END_SITES]),
        end_offsets=np.array([o for _, o in END_SITES], dtype=float),
    )


def march(rate: float = 30.0, seconds: float = 4.0, seed: int = 0) -> tuple[Skeleton, np.ndarray, np.ndarray]:
    """Local rotations (T, J, 4) and translations (T, J, 3) of the march."""
    sk = skeleton()
    rng = np.random.default_rng(seed)
    t = np.arange(int(round(seconds * rate)) + 1) / rate
    T, J = len(t), sk.n_joints
    step = 2 * np.pi * t / 1.2  # one stride (two steps) every 1.2 s
    lift_l = np.radians(40.0) * np.maximum(0.0, np.sin(step)) ** 1.5
    lift_r = np.radians(40.0) * np.maximum(0.0, np.sin(step + np.pi)) ** 1.5
    euler = np.zeros((T, J, 3))  # degrees about X, Y, Z
    euler[:, sk.names.index("LeftUpLeg"), 0] = -np.degrees(lift_l)
    euler[:, sk.names.index("LeftLeg"), 0] = 2 * np.degrees(lift_l)
    euler[:, sk.names.index("LeftFoot"), 0] = -np.degrees(lift_l)
    euler[:, sk.names.index("RightUpLeg"), 0] = -np.degrees(lift_r)
    euler[:, sk.names.index("RightLeg"), 0] = 2 * np.degrees(lift_r)
    euler[:, sk.names.index("RightFoot"), 0] = -np.degrees(lift_r)
    # arms swing against the legs; elbows and hands follow later (succession)
    for side, phase in (("Left", np.pi), ("Right", 0.0)):
        euler[:, sk.names.index(f"{side}Arm"), 0] = 25.0 * np.sin(step + phase)
        euler[:, sk.names.index(f"{side}ForeArm"), 0] = -20.0 - 15.0 * np.sin(step + phase - 0.5)
        euler[:, sk.names.index(f"{side}Hand"), 0] = 10.0 * np.sin(step + phase - 1.0)
    euler[:, sk.names.index("Chest"), 1] = 6.0 * np.sin(step)
    euler[:, sk.names.index("Head"), 1] = 20.0 * np.sin(2 * np.pi * t / 4.0)
    euler += rng.normal(0.0, 0.15, euler.shape) * (np.arange(J) > 0)[None, :, None]
    rot = quat.from_euler(euler[..., [2, 0, 1]], "ZXY")
    tr = np.broadcast_to(sk.offsets, (T, J, 3)).copy()
    tr[:, 0, 1] = 90.0 + 0.3 * np.sin(2 * step)
    return sk, rot, tr


def sample_bvh() -> bytes:
    sk, rot, tr = march()
    ref = np.zeros((rot.shape[0], sum(len(c) for c in sk.channels)))
    channels = np.round(channels_from_local(sk, rot, tr, ref), 4)
    return bvh_bytes(BvhMotion(sk, channels, 1 / 30, "0.0333333", "%.4f"))


def sample_c3d_motion() -> MarkerMotion:
    sk, rot, tr = march(rate=60.0)
    wr, wp = forward_kinematics(sk, rot, tr)
    pts = np.concatenate([wp, end_site_positions(sk, wr, wp)], axis=1) * 10.0  # cm -> mm
    pts = pts[..., [0, 2, 1]] * np.array([1.0, -1.0, 1.0])  # Y up -> Z up, right-handed
    pts[40:52, 3] = np.nan  # a short gap in the neck marker
    labels = tuple(sk.names) + tuple(f"{sk.names[p]}_end" for p, _ in END_SITES)
    return MarkerMotion(labels, pts, 60.0, "mm")


def main() -> None:
    from staggered_cli.io.c3d import c3d_bytes

    (HERE / "march.bvh").write_bytes(sample_bvh())
    (HERE / "march.c3d").write_bytes(c3d_bytes(sample_c3d_motion()))
    print(f"wrote {HERE / 'march.bvh'} and {HERE / 'march.c3d'}")


if __name__ == "__main__":
    main()
