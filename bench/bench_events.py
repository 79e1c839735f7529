"""Where the poses and knots fall against the motion's events (issue 34).

For every dev BVH file, events found by code written apart from the project
(tests/events.py: the root's height extremes, each hand's swing extremes
along the heading, flight phases) are set against the extracted document
(``extract``) and the same after ``cull --keep 25%``:

* ``root knot``: share of root height extremes with an extreme knot of the
  root's translation variable (``t_k + r[k,i]``) within 0.05 s;
* ``swing knot``: share of hand swing extremes with an extreme knot of a
  rotation variable of that arm (collar/shoulder to hand) within 0.05 s;
* ``pose near``: share of each kind of event with a pose within 0.1 s
  (root extremes, swing extremes, take-offs and landings of flight phases);
* ``offset``: mean signed offset, nearest pose time minus event time, per
  kind (negative: the pose comes early; an event midway between two poses
  counts as 0), per file and pooled over files;
* ``flight``: share of flight phases (both feet off the ground >= 0.1 s)
  with a pose inside (first to last airborne frame);
* ``sparse``: the spline layer alone (``bake --layers splines``, no IK),
  mean world joint position error against the source, divided by the same
  for evenly spaced unrefined poses at the same count (the document culled
  to its first and last pose, unrefined on every dev file, and
  ``cull --add-time`` at the evenly spaced frames: the splines are fitted
  to the motion at those times exactly as for the extracted poses);
  geometric mean and worst file;
* ``density``: poses per second; ``contacts``: share of contact changes
  (constraint starts and ends inside the clip) with a pose within 0.075 s.

Only the public API is used (``import staggered_cli as st``).

    python bench/bench_events.py [FILE ...] [--json out.json] [--no-sparse]

About 2 minutes on one core; the even-spacing baseline of the 63 s dance
(229 poses added one at a time) takes most of it (``--no-sparse`` skips it).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import staggered_cli as st  # noqa: E402
from tests.conftest import MOCAP  # noqa: E402
from tests.events import clip_events  # noqa: E402

KNOT_WINDOW = 0.05
POSE_WINDOW = 0.1
CONTACT_WINDOW = 0.075
KINDS = ("root", "swing", "takeoff", "landing")
LEVELS = ("all", "25%")


def var_columns(doc) -> dict[tuple[str, int], int]:
    """(kind, target joint) -> column of ``doc.refinements()`` (tracks in order)."""
    out, col = {}, 0
    for tr in doc.tracks:
        for j in tr.targets:
            out[(tr.kind, int(j))] = col
            col += 1
    return out


def extreme_times(doc, cols: list[int]) -> np.ndarray:
    """Sorted extreme knot times ``t_k + r[k,i]`` of the variables ``cols``."""
    if not cols:
        return np.zeros(0)
    ref = doc.refinements()[:, cols]
    t = doc.pose_t[:, None] + ref
    return np.sort(t[np.isfinite(t)])


def nearest_offset(times: np.ndarray, events: np.ndarray, signed: bool = False) -> np.ndarray:
    """(N,) nearest ``times`` minus each event time (NaN when there are no times).

    An event midway between two times (on a regular grid of poses, a few
    percent of them) is as far from both: its distance is the same either
    way, but taking the earlier one (``argmin``'s first) would count every
    tie as early.  With ``signed``, a tie counts as the mean of its two
    offsets (zero), so that the mean signed offset measures a bias, not the
    tie rule (issue 34: on the dev files the tie rule alone made the swings
    4 ms and the take-offs 6 ms early)."""
    if len(events) == 0:
        return np.zeros(0)
    if len(times) == 0:
        return np.full(len(events), np.nan)
    i = np.clip(np.searchsorted(times, events), 1, len(times) - 1) if len(times) > 1 else np.zeros(len(events), int)
    cand = np.stack([times[np.maximum(i - 1, 0)], times[i]], axis=1) - events[:, None]
    out = cand[np.arange(len(events)), np.argmin(np.abs(cand), axis=1)]
    if signed:
        tie = np.abs(np.abs(cand[:, 0]) - np.abs(cand[:, 1])) <= 1e-9
        out = np.where(tie, cand.mean(axis=1), out)
    return out


def share(mask) -> float | None:
    mask = np.asarray(mask, bool)
    return float(mask.mean()) if mask.size else None


def spline_error(doc, source: np.ndarray, height: float) -> float:
    """Mean world joint position error of the spline layer alone, % of figure height."""
    pos = st.bake(doc, layers="splines", ik=False).world_positions()
    return float(np.linalg.norm(pos - source, axis=-1).mean() / height * 100.0)


def even(doc):
    """``doc.n_poses`` unrefined poses at evenly spaced frames (first and last included)."""
    ref = doc.refinements()
    if np.any(ref[[0, -1]] != 0):
        raise ValueError("the first or last pose is refined: the even baseline would inherit it")
    frames = np.unique(np.round(np.linspace(0, doc.n_frames - 1, doc.n_poses)).astype(int))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return st.cull(doc, select=[0, doc.n_poses - 1], add_time=list(frames[1:-1] * doc.frame_time))


def measure_doc(doc, ev, motion, sparse: bool) -> dict:
    cols = var_columns(doc)
    row: dict = {"poses": doc.n_poses, "density": doc.n_poses / doc.duration}
    root_col = cols.get(("translation", ev.place))
    at = {
        "root": ev.root_extremes,
        "swing": np.sort(np.concatenate([*ev.swings.values(), np.zeros(0)])),
        "takeoff": ev.flights[:, 0],
        "landing": ev.flights[:, 1],
    }
    off = {k: nearest_offset(doc.pose_t, e) for k, e in at.items()}
    signed = {k: nearest_offset(doc.pose_t, e, signed=True) for k, e in at.items()}
    knots = extreme_times(doc, [] if root_col is None else [root_col])
    refined = 0 if root_col is None else int(np.count_nonzero(doc.refinements()[:, root_col]))
    row["root_refined"] = [refined, doc.n_poses]
    row["root_knot"] = share(np.abs(nearest_offset(knots, ev.root_extremes)) <= KNOT_WINDOW + 1e-9)
    swing_hits = []
    for hand, times in ev.swings.items():
        arm_cols = [cols[("rotation", int(j))] for j in ev.arms[hand] if ("rotation", int(j)) in cols]
        swing_hits.extend(np.abs(nearest_offset(extreme_times(doc, arm_cols), times)) <= KNOT_WINDOW + 1e-9)
    row["swing_knot"] = share(swing_hits)
    row["pose_near"] = {k: share(np.abs(v) <= POSE_WINDOW + 1e-9) for k, v in off.items()}
    row["offset"] = {k: (float(np.mean(v)) if len(v) else None) for k, v in signed.items()}
    row["offsets"] = {k: [float(x) for x in v] for k, v in signed.items()}
    inside = [np.any((doc.pose_t >= a - 1e-9) & (doc.pose_t <= b + 1e-9)) for a, b in ev.flights]
    row["flight"] = share(inside)
    changes = [t for c in doc.constraints for t in (c.start, c.end) if 0 < t < doc.duration - 1e-9]
    near = np.abs(nearest_offset(doc.pose_t, np.sort(np.array(changes, float)))) <= CONTACT_WINDOW + 1e-9
    row["contacts"] = share(near)
    row["contact_hits"] = [int(near.sum()), len(near)]
    if sparse:
        src, h = motion.world_positions(), motion.figure_height()
        row["sparse"] = spline_error(doc, src, h) / spline_error(even(doc), src, h)
    return row


def measure(path: Path, sparse: bool) -> dict:
    t0 = time.perf_counter()
    motion = st.read(path)
    ev = clip_events(motion, path.name)
    doc = st.extract(motion)
    out = {
        "file": path.name,
        "duration": doc.duration,
        "events": {
            "root": len(ev.root_extremes),
            "swing": int(sum(len(v) for v in ev.swings.values())),
            "flight": len(ev.flights),
        },
        "root_extremes": [float(t) for t in ev.root_extremes],
        "swings": {k: [float(t) for t in v] for k, v in ev.swings.items()},
        "flights": ev.flights.tolist(),
    }
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", st.StaggeredWarning)  # idle: "keeping 2 poses"
        culled = st.cull(doc, keep="25%")
    for label, d in (("all", doc), ("25%", culled)):
        out[label] = measure_doc(d, ev, motion, sparse)
    out["seconds"] = time.perf_counter() - t0
    return out


def _fmt(x, pct: bool = False, signed: bool = False) -> str:
    if x is None or (isinstance(x, float) and not np.isfinite(x)):
        return "-"
    if pct:
        return f"{100 * x:.0f}%"
    return f"{1000 * x:+.0f}ms" if signed else f"{x:.3f}"


def _pooled(rows, label, key, sub=None) -> float | None:
    """A share pooled over every event of every file (not a mean of shares)."""
    hit = tot = 0
    for r in rows:
        cnt = r["events"]
        v = r[label][key] if sub is None else r[label][key][sub]
        n = {
            "root_knot": cnt["root"],
            "swing_knot": cnt["swing"],
            "flight": cnt["flight"],
            "contacts": r[label]["contact_hits"][1],
        }.get(key)
        if key == "pose_near":
            n = len(r[label]["offsets"][sub])
        if v is not None and n:
            hit, tot = hit + v * n, tot + n
    return hit / tot if tot else None


def summarize(rows: list[dict], sparse: bool) -> dict:
    out: dict = {}
    for label in LEVELS:
        s: dict = {
            "root_knot": _pooled(rows, label, "root_knot"),
            "swing_knot": _pooled(rows, label, "swing_knot"),
            "flight": _pooled(rows, label, "flight"),
            "contacts": _pooled(rows, label, "contacts"),
            "pose_near": {k: _pooled(rows, label, "pose_near", k) for k in KINDS},
        }
        s["offset_mean"], s["offset_median"] = {}, {}
        for k in KINDS:
            v = np.concatenate([np.array(r[label]["offsets"][k], float) for r in rows])
            v = v[np.isfinite(v)]
            s["offset_mean"][k] = float(v.mean()) if len(v) else None
            s["offset_median"][k] = float(np.median(v)) if len(v) else None
        if sparse:
            r = {row["file"]: row[label]["sparse"] for row in rows}
            worst = max(r, key=r.get)
            s["sparse_geomean"] = float(np.exp(np.mean(np.log(list(r.values())))))
            s["sparse_worst"] = [worst, r[worst]]
        out[label] = s
    return out


def print_tables(rows: list[dict], summary: dict, sparse: bool) -> None:
    w = max(len(r["file"]) for r in rows)
    ev_cols = [
        ("events root/swing/flight", lambda r, _: "{root}/{swing}/{flight}".format(**r["events"])),
    ]
    tables = [
        ("Events found (root height extremes / hand swing extremes / flight phases)", ev_cols, False),
        (
            "Poses and density",
            [("poses", lambda r, lv: str(r[lv]["poses"])), ("per s", lambda r, lv: f"{r[lv]['density']:.2f}")],
            True,
        ),
        (
            "Root height extremes with a root extreme knot within 0.05 s (refined: poses with r != 0 on the root)",
            [
                ("root knot", lambda r, lv: _fmt(r[lv]["root_knot"], pct=True)),
                ("refined", lambda r, lv: "{}/{}".format(*r[lv]["root_refined"])),
            ],
            True,
        ),
        (
            "Hand swing extremes with an extreme knot of that arm within 0.05 s",
            [("swing knot", lambda r, lv: _fmt(r[lv]["swing_knot"], pct=True))],
            True,
        ),
        (
            "Events with a pose within 0.1 s",
            [(k, lambda r, lv, k=k: _fmt(r[lv]["pose_near"][k], pct=True)) for k in KINDS],
            True,
        ),
        (
            "Mean signed offset, nearest pose - event (negative: early)",
            [(k, lambda r, lv, k=k: _fmt(r[lv]["offset"][k], signed=True)) for k in KINDS],
            True,
        ),
        ("Flight phases with a pose inside", [("flight", lambda r, lv: _fmt(r[lv]["flight"], pct=True))], True),
        (
            "Contact changes with a pose within 0.075 s",
            [
                ("contacts", lambda r, lv: _fmt(r[lv]["contacts"], pct=True)),
                ("n", lambda r, lv: "{}/{}".format(*r[lv]["contact_hits"])),
            ],
            True,
        ),
    ]
    if sparse:
        tables.append(
            (
                "Sparse layer: spline error of the poses / of evenly spaced poses at the same count",
                [("ratio", lambda r, lv: f"{r[lv]['sparse']:.3f}")],
                True,
            )
        )
    for title, cols, per_level in tables:
        print(f"\n## {title}")
        levels = LEVELS if per_level else ("all",)
        head = [f"{name} [{lv}]" if per_level else name for lv in levels for name, _ in cols]
        widths = [max(len(h), 7) for h in head]
        print(f"{'file':<{w}}  " + "  ".join(f"{h:>{x}}" for h, x in zip(head, widths, strict=True)))
        for r in rows:
            cells = [f(r, lv) for lv in levels for _, f in cols]
            print(f"{r['file']:<{w}}  " + "  ".join(f"{c:>{x}}" for c, x in zip(cells, widths, strict=True)))
    print("\n## Summary (shares pooled over all events of all files)")
    for lv in LEVELS:
        s = summary[lv]
        print(
            f"[{lv}] root knot {_fmt(s['root_knot'], pct=True)}, swing knot {_fmt(s['swing_knot'], pct=True)}, "
            f"flights with a pose {_fmt(s['flight'], pct=True)}, contacts {_fmt(s['contacts'], pct=True)}"
        )
        print(f"[{lv}] pose within 0.1 s: " + ", ".join(f"{k} {_fmt(s['pose_near'][k], pct=True)}" for k in KINDS))
        print(
            f"[{lv}] offset mean: "
            + ", ".join(f"{k} {_fmt(s['offset_mean'][k], signed=True)}" for k in KINDS)
            + "; median: "
            + ", ".join(f"{k} {_fmt(s['offset_median'][k], signed=True)}" for k in KINDS)
        )
        if sparse:
            print(
                f"[{lv}] sparse ratio: geometric mean {s['sparse_geomean']:.3f}, "
                f"worst {s['sparse_worst'][1]:.3f} ({s['sparse_worst'][0]})"
            )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("files", nargs="*", help="BVH files (default: every dev BVH file)")
    ap.add_argument("--json", help="write every number to this JSON file")
    ap.add_argument("--no-sparse", action="store_true", help="skip the sparse-layer ratio (the slow part)")
    args = ap.parse_args(argv)
    paths = [Path(p) for p in args.files] or sorted(MOCAP.glob("*.bvh"))
    if not paths:
        print(f"no BVH files (looked in {MOCAP})", file=sys.stderr)
        return 1
    sparse = not args.no_sparse
    t0 = time.perf_counter()
    rows = []
    for p in paths:
        rows.append(measure(p, sparse))
        print(f"{p.name}: {rows[-1]['seconds']:.1f} s", file=sys.stderr)
    summary = summarize(rows, sparse)
    print_tables(rows, summary, sparse)
    print(f"\n{len(rows)} files in {time.perf_counter() - t0:.0f} s")
    if args.json:
        Path(args.json).write_text(json.dumps({"files": rows, "summary": summary}, indent=1, sort_keys=True))
    return 0


if __name__ == "__main__":
    sys.exit(main())
