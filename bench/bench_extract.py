"""Extraction speed, memory and scaling (issue 4 goals).

* ``cmu_01_01_forward_jumps.bvh`` (23 s at 120 Hz) in-process: goal < 1.5 s;
* ``bandai1_dance-short_normal_001.bvh`` (63 s at 30 Hz): goal < 3 s;
* peak memory of those extractions (tracemalloc, on a separate run): goal < 500 MB;
* linear scaling: cmu_01_01 without its T-pose frame repeated 1, 2, 4, 8
  times: goal 8x the frames in at most 9x the time.

Each time is the median of ``--repeats`` runs and is split into the stages
of :func:`staggered_cli.ops.extract.extract`: local evidence (trails,
curvature, smoothing), contacts, the spline and displacement fit
(``variables.from_motion``, another module's work) and the rest (pose
selection, refinements).

    python bench/bench_extract.py [--repeats 3] [--no-scaling]
"""

from __future__ import annotations

import argparse
import sys
import time
import tracemalloc
from collections import defaultdict
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from staggered_cli.io.bvh import read_bvh  # noqa: E402
from staggered_cli.ops import extract as X  # noqa: E402
from tests.conftest import MOCAP  # noqa: E402

GOALS = {"cmu_01_01_forward_jumps.bvh": 1.5, "bandai1_dance-short_normal_001.bvh": 3.0}
MEMORY_GOAL_MB = 500.0
SCALING_GOAL = 9.0

_stage_time: dict[str, float] = defaultdict(float)


def _timed(name: str, fn):
    def wrapper(*args, **kwargs):
        t = time.perf_counter()
        try:
            return fn(*args, **kwargs)
        finally:
            _stage_time[name] += time.perf_counter() - t

    return wrapper


# time the stages without touching the library: wrap what extract calls
X.trails.local_evidence = _timed("evidence", X.trails.local_evidence)
X.contact_detection.detect_contacts = _timed("contacts", X.contact_detection.detect_contacts)
X.from_motion = _timed("fit", X.from_motion)


def run(motion, repeats: int) -> tuple[float, dict[str, float], int]:
    """Median wall time, the stage times of that run, and the pose count."""
    runs = []
    for _ in range(repeats):
        _stage_time.clear()
        t = time.perf_counter()
        doc = X.extract(motion)
        total = time.perf_counter() - t
        stages = dict(_stage_time)
        stages["rest"] = total - sum(stages.values())
        runs.append((total, stages, doc.n_poses))
    runs.sort(key=lambda r: r[0])
    return runs[len(runs) // 2]


def peak_memory_mb(motion) -> float:
    tracemalloc.start()
    try:
        X.extract(motion)
        return tracemalloc.get_traced_memory()[1] / 2**20
    finally:
        tracemalloc.stop()


def _stages(stages: dict[str, float]) -> str:
    return "  ".join(f"{k} {stages.get(k, 0.0):6.3f}" for k in ("evidence", "contacts", "fit", "rest"))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3, help="runs per measurement (median)")
    parser.add_argument("--no-scaling", action="store_true", help="skip the 1x-8x scaling runs")
    args = parser.parse_args(argv)
    if not MOCAP.is_dir():
        print(f"skipped: {MOCAP} is missing")
        return 0
    failed = []
    X.extract(read_bvh(MOCAP / "bandai2_run_normal_001.bvh"))  # warm up imports (scipy.signal)

    print("extract, in-process (seconds; stages: evidence, contacts, spline fit, rest)")
    clips = {}
    for name, goal in GOALS.items():
        motion = read_bvh(MOCAP / name)
        clips[name] = motion
        total, stages, poses = run(motion, args.repeats)
        dur = motion.n_frames * motion.frame_time
        ok = total < goal
        failed += [] if ok else [f"{name} {total:.2f}s >= {goal}s"]
        print(
            f"  {name:<36} {motion.n_frames:6d} frames {dur:6.1f}s  {poses:4d} poses  "
            f"total {total:6.3f} (goal < {goal})  {'ok' if ok else 'SLOW'}"
        )
        print(f"  {'':<36} {_stages(stages)}")

    print("peak memory (tracemalloc)")
    for name, motion in clips.items():
        mb = peak_memory_mb(motion)
        ok = mb < MEMORY_GOAL_MB
        failed += [] if ok else [f"{name} {mb:.0f} MB"]
        print(f"  {name:<36} {mb:8.1f} MB (goal < {MEMORY_GOAL_MB:.0f})  {'ok' if ok else 'TOO MUCH'}")

    if not args.no_scaling:
        base = clips["cmu_01_01_forward_jumps.bvh"]
        body = base.channels[1:]  # without the T-pose frame
        print("scaling: cmu_01_01 (no T-pose) repeated")
        t1 = None
        for n in (1, 2, 4, 8):
            motion = replace(base, channels=np.concatenate([body] * n))
            total, stages, poses = run(motion, 1 if n > 2 else args.repeats)
            t1 = t1 or total
            print(
                f"  x{n}  {motion.n_frames:6d} frames  {poses:5d} poses  total {total:7.3f}  "
                f"ratio {total / t1:5.2f}  {_stages(stages)}"
            )
        ok = total / t1 <= SCALING_GOAL
        failed += [] if ok else [f"8x took {total / t1:.2f}x"]
        print(f"  8x time ratio {total / t1:.2f} (goal <= {SCALING_GOAL})  {'ok' if ok else 'SUPERLINEAR'}")

    if failed:
        print("goals missed: " + "; ".join(failed))
    return 0


if __name__ == "__main__":
    sys.exit(main())
