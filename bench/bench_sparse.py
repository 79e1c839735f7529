"""How good the extracted poses are as a sparse layer (issue 13).

For every dev BVH file: the candidate count, poses per second and the
smallest gap between poses; the spline-only error (``bake --layers
splines``: world joint positions against the source, mean and max over all
joints and frames, % of figure height) of the extracted poses against the
same number of evenly spaced unrefined poses, at the candidate count and
after ``cull --keep 50%``, ``25%`` and ``10%``; and the extracted pose
times with and without their refinements.  The last line gives the
geometric mean of each ratio (goal: extracted / even <= 1.0, no file above
1.25; unrefined / refined >= 1.0), the same ratio after a cull to 25 % by
the paper's priority, and the contact changes with a pose within 0.075 s.

    python bench/bench_sparse.py [FILE ...]
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from staggered_cli.io.bvh import read_bvh  # noqa: E402
from staggered_cli.model.sampling import local_pose  # noqa: E402
from staggered_cli.model.variables import from_motion  # noqa: E402
from staggered_cli.ops import cull  # noqa: E402
from staggered_cli.ops.extract import extract  # noqa: E402
from staggered_cli.skeleton import forward_kinematics  # noqa: E402
from tests.conftest import MOCAP  # noqa: E402

KEEPS = ("50%", "25%", "10%")


def spline_error(doc, source_positions: np.ndarray, height: float) -> tuple[float, float]:
    """Mean and max world joint position error of the spline layer alone, % of height."""
    rot, tr = local_pose(doc, doc.frame_times, "splines")
    pos = forward_kinematics(doc.source.skeleton, rot, tr)[1]
    err = np.linalg.norm(pos - source_positions, axis=-1) / height * 100.0
    return float(err.mean()), float(err.max())


def even_doc(motion, n: int):
    """``n`` unrefined poses at evenly spaced frames (first and last included)."""
    f = np.unique(np.round(np.linspace(0, motion.n_frames - 1, max(n, 2))).astype(int))
    return from_motion(motion, f * float(motion.frame_time))


def measure(path: Path) -> dict:
    m = read_bvh(path)
    src = m.world()[1]
    h = m.figure_height()
    t0 = time.perf_counter()
    doc = extract(m, source_name=path.name)
    seconds = time.perf_counter() - t0
    row = {
        "file": path.name,
        "K": doc.n_poses,
        "per_s": doc.n_poses / doc.duration,
        "min_gap": float(np.diff(doc.pose_t).min()),
        "extract_s": seconds,
    }
    culled = [(k, cull.keep_poses(doc, cull.choose(doc, keep=k))) for k in KEEPS]
    for label, d in [("all", doc)] + culled:
        e = spline_error(d, src, h)
        v = spline_error(even_doc(m, d.n_poses), src, h)
        row[label] = (d.n_poses, e, v)
    paper = cull.keep_poses(doc, cull.choose(doc, keep="25%", by="paper"))
    row["paper25"] = spline_error(paper, src, h)[0] / spline_error(even_doc(m, paper.n_poses), src, h)[0]
    changes = [t for c in doc.constraints for t in (c.start, c.end) if 0 < t < doc.duration - 1e-9]
    near = [np.min(np.abs(doc.pose_t - t)) <= 0.075 + 1e-9 for t in changes]
    row["covered"] = (int(np.sum(near)), len(near))
    plain = from_motion(m, doc.pose_t)
    row["unrefined"] = spline_error(plain, src, h)
    return row


def main(argv: list[str]) -> None:
    paths = [Path(a) for a in argv] or sorted(MOCAP.glob("*.bvh"))
    ratios: dict[str, list[float]] = {k: [] for k in ("all",) + KEEPS + ("unrefined", "paper25")}
    cover = [0, 0]
    print(
        f"{'file':38s} {'K':>4s} {'/s':>5s} {'gap s':>6s} {'ext s':>6s} | "
        + " | ".join(f"{k:>4s}: n  mean% (even%)  max% (even%)" for k in ("all",) + KEEPS)
        + " | unrefined mean% max% | contacts covered"
    )
    for p in paths:
        r = measure(p)
        cells = []
        for k in ("all",) + KEEPS:
            n, (em, ex), (vm, vx) = r[k]
            ratios[k].append(em / vm)
            cells.append(f"{n:4d} {em:5.2f} ({vm:5.2f}) {ex:5.1f} ({vx:5.1f})")
        um, ux = r["unrefined"]
        ratios["unrefined"].append(um / r["all"][1][0])
        ratios["paper25"].append(r["paper25"])
        print(
            f"{r['file']:38s} {r['K']:4d} {r['per_s']:5.2f} {r['min_gap']:6.3f} {r['extract_s']:6.2f} | "
            + " | ".join(cells)
            + f" | {um:5.2f} {ux:5.1f} | contacts {r['covered'][0]}/{r['covered'][1]}"
        )
        cover[0] += r["covered"][0]
        cover[1] += r["covered"][1]
    gm = {k: float(np.exp(np.mean(np.log(v)))) for k, v in ratios.items()}
    worst = {k: float(np.max(v)) for k, v in ratios.items()}
    print(
        "extracted / even, geometric mean (worst): "
        + ", ".join(f"{k} {gm[k]:.3f} ({worst[k]:.2f})" for k in ("all",) + KEEPS)
    )
    print(f"cull --keep 25% --by paper / even, geometric mean: {gm['paper25']:.3f} (worst {worst['paper25']:.2f})")
    share = 100.0 * cover[0] / max(cover[1], 1)
    print(f"contact changes with a pose within 0.075 s: {cover[0]}/{cover[1]} ({share:.0f} %)")
    low = min(ratios["unrefined"])
    print(f"unrefined / refined at the same pose times, geometric mean: {gm['unrefined']:.3f} (min {low:.2f})")


if __name__ == "__main__":
    main(sys.argv[1:])
