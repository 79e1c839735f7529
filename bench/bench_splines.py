"""Rotation spline fits: batched Levenberg-Marquardt against the paper's Nelder-Mead.

Cuts every rotation track of two real clips into segments (knots every
0.25 s, samples = the frames strictly inside each segment), fits all
segments at once with ``staggered_cli.model.rotation_fit.fit_rotation_tangents`` and
compares with the paper's Appendix A fit (per segment Nelder-Mead with a
unit-length penalty, the reference implementation in tests/test_splines.py).
The reference is timed on a random subset of segments and extrapolated.

    python bench/bench_splines.py [--reference-segments 300] [--seed 0]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from staggered_cli.io.bvh import read_bvh  # noqa: E402
from staggered_cli.model import rotation_fit, rotation_spline  # noqa: E402
from tests.conftest import MOCAP  # noqa: E402
from tests.test_splines import fit_errors, reference_fit_segments, track_segments  # noqa: E402

CLIPS = (
    ("cmu_01_01_forward_jumps.bvh", True),  # frame 0 is a T-pose: dropped
    ("bandai1_dance-short_normal_001.bvh", False),
)


def _batched(data: dict, repeats: int = 3) -> tuple[np.ndarray, np.ndarray, float]:
    """Tangents and the median wall time of ``repeats`` runs."""
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        a, b = rotation_fit.fit_rotation_tangents(
            data["q0"], data["q3"], data["seg"], data["u"], data["values"], data["n_segments"]
        )
        times.append(time.perf_counter() - t)
    return a, b, float(np.median(times))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reference-segments", type=int, default=300, help="segments timed with Nelder-Mead per clip")
    parser.add_argument("--seed", type=int, default=0, help="seed of the random subset")
    args = parser.parse_args(argv)
    if not MOCAP.is_dir():
        print(f"skipped: {MOCAP} is missing")
        return 0
    rng = np.random.default_rng(args.seed)

    print("Rotation spline fits, knots every 0.25 s (RMS angle per segment, degrees)")
    header = f"{'clip':<36} {'segments':>8}  {'method':<22} {'mean':>7} {'max':>7} {'time':>9} {'per seg':>9}"
    print(header)
    print("-" * len(header))
    total_lm = total_ref = 0.0
    for name, drop_first in CLIPS:
        data = track_segments(read_bvh(MOCAP / name), drop_first=drop_first)
        count = np.bincount(data["seg"], minlength=data["n_segments"])
        fitted = np.flatnonzero(count >= 2)
        a, b, t_lm = _batched(data)
        err = np.degrees(fit_errors(data, a, b))

        rows = np.sort(rng.choice(fitted, min(args.reference_segments, fitted.size), replace=False))
        t = time.perf_counter()
        ra, rb = reference_fit_segments(data, rows)
        per_ref = (time.perf_counter() - t) / rows.size
        t_ref = per_ref * fitted.size  # extrapolated to every fitted segment
        ref_err = np.degrees(fit_errors(data, ra, rb))[rows]
        total_lm += t_lm
        total_ref += t_ref

        a0, b0 = rotation_spline.default_rotation_tangents(data["q0"], data["q3"])
        err0 = np.degrees(fit_errors(data, a0, b0))

        def row(clip, n, method, e, seconds=None, per=None):
            timing = f"{seconds:8.2f}s {per:7.2f}ms" if seconds is not None else f"{'':>9} {'':>9}"
            print(f"{clip:<36} {n:>8}  {method:<22} {np.mean(e):7.3f} {np.max(e):7.3f} {timing}")

        row(name, fitted.size, "uniform slerp (start)", err0[fitted])
        row("", fitted.size, "batched LM (all)", err[fitted], t_lm, 1e3 * t_lm / fitted.size)
        row("", rows.size, "batched LM (subset)", err[rows])
        row("", rows.size, "Nelder-Mead (subset)", ref_err, t_ref, 1e3 * per_ref)
        not_worse = np.mean(err[rows] <= ref_err + np.degrees(1e-9))
        print(
            f"{'':<36} LM <= Nelder-Mead on {100 * not_worse:.1f} % of the subset; "
            f"speed-up {t_ref / t_lm:.0f}x (Nelder-Mead time extrapolated from {rows.size} segments)"
        )
    print("-" * len(header))
    print(
        f"total: batched LM {total_lm:.2f} s, Nelder-Mead {total_ref:.1f} s (extrapolated), "
        f"speed-up {total_ref / total_lm:.0f}x"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
