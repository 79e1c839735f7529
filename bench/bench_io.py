"""BVH read/write of cmu_01_01 beside the numpy loadtxt/savetxt floor, and
the in-process bake time (issues 2 and 3).  Prints a small table."""

from __future__ import annotations

import io
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from staggered_cli.io.bvh import bvh_bytes, read_bvh  # noqa: E402
from staggered_cli.ops.bake import bake  # noqa: E402
from staggered_cli.ops.extract import extract  # noqa: E402

MOCAP = ROOT.parent / "shared" / "mocap"


def best(fn, repeat: int = 5) -> float:
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return min(times)


def main() -> None:
    path = MOCAP / "cmu_01_01_forward_jumps.bvh"
    if not path.exists():
        print(f"skipped: {path} is missing")
        return
    data = path.read_bytes()
    text = data.decode()
    body = text[text.index("Frame Time") :].split("\n", 1)[1]
    motion = read_bvh(path)
    floor_read = best(lambda: np.loadtxt(io.StringIO(body)))
    floor_write = best(lambda: np.savetxt(io.StringIO(), motion.channels, fmt="%.4f"))
    ours_read = best(lambda: read_bvh(path))
    ours_write = best(lambda: bvh_bytes(motion))
    doc = extract(motion)
    bake_time = best(lambda: bake(doc), repeat=3)
    print(f"{'cmu_01_01 (2752 frames, 96 channels)':40s} {'ours':>8s} {'numpy floor':>12s} {'ratio':>6s}")
    print(f"{'BVH read':40s} {ours_read:8.3f} {floor_read:12.3f} {ours_read / floor_read:6.2f}")
    print(f"{'BVH write':40s} {ours_write:8.3f} {floor_write:12.3f} {ours_write / floor_write:6.2f}")
    print(f"{'bake in-process (goal < 0.3 s)':40s} {bake_time:8.3f}")


if __name__ == "__main__":
    main()
