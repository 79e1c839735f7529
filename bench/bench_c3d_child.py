"""What running ezc3d in a child process costs per C3D read and write (issue 18).

For each C3D of ../shared/mocap: the time of ``read_c3d`` and ``c3d_bytes``
(which run ezc3d in a forked child with a memory and a time limit) against
the same work done in-process (the functions the child runs, called
directly), best and median of ``--repeats`` runs.  Goal: at most 30 ms
overhead per read or write.

Two tables.  "cold": each measurement is the first read (or write) of a
fresh process after the CLI's imports, as in one ``staggered`` command.
"warm": repeated in one process, where the in-process side reuses memory it
has already touched and the child cannot (so the overhead shown is larger).

    python bench/bench_c3d_child.py [--repeats 9]
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import time
from pathlib import Path

from staggered_cli.io import c3d as io_c3d

MOCAP = Path(__file__).resolve().parents[1].parent / "shared" / "mocap"


def timed(fn, repeats: int) -> list[float]:
    out = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t)
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=9)
    args = ap.parse_args()
    import ezc3d  # noqa: F401 - both sides start with ezc3d imported

    print("cold: first call in a fresh process (ms)")
    print(f"{'file':36s} {'op':5s} {'in-process ms':>14s} {'child ms':>10s} {'overhead ms (best / median)':>28s}")
    for path in sorted(MOCAP.glob("*.c3d")):
        for op in ("read", "write"):
            a = [_cold(path, op, "direct") for _ in range(args.repeats)]
            b = [_cold(path, op, "child") for _ in range(args.repeats)]
            best = (min(b) - min(a)) * 1e3
            median = (statistics.median(b) - statistics.median(a)) * 1e3
            print(f"{path.name:36s} {op:5s} {min(a) * 1e3:14.1f} {min(b) * 1e3:10.1f} {best:14.1f} / {median:.1f}")
    print("warm: repeated in one process (ms)")
    print(f"{'file':36s} {'op':5s} {'in-process ms':>14s} {'child ms':>10s} {'overhead ms (best / median)':>28s}")
    for path in sorted(MOCAP.glob("*.c3d")):
        for op, (direct, guarded) in _cases(path).items():
            a = timed(direct, args.repeats)
            b = timed(guarded, args.repeats)
            best = (min(b) - min(a)) * 1e3
            median = (statistics.median(b) - statistics.median(a)) * 1e3
            print(f"{path.name:36s} {op:5s} {min(a) * 1e3:14.1f} {min(b) * 1e3:10.1f} {best:14.1f} / {median:.1f}")


_COLD = """
import json, sys, time
from pathlib import Path
import ezc3d
import staggered_cli.cli.main
from staggered_cli.io import c3d as io_c3d
sys.path.insert(0, {here!r})
from bench_c3d_child import _cases
direct, guarded = _cases(Path({path!r}))[{op!r}]
t = time.perf_counter()
(direct if {how!r} == "direct" else guarded)()
print(json.dumps(time.perf_counter() - t))
"""


def _cold(path: Path, op: str, how: str) -> float:
    """Seconds of one read or write, the first of a fresh process."""
    code = _COLD.format(here=str(Path(__file__).parent), path=str(path), op=op, how=how)
    out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True).stdout
    return float(json.loads(out))


def _cases(path: Path) -> dict:
    """op -> (the work in-process, the same through the child)."""
    raw = path.read_bytes()
    motion = io_c3d.read_c3d(path)
    layout = io_c3d._check_layout(raw, path.name)
    labels = list(motion.labels)
    return {
        "read": (
            lambda: io_c3d._markers(raw, layout, path.name),
            lambda: io_c3d.read_c3d(path, data=raw),
        ),
        "write": (
            lambda: io_c3d._ezc3d_bytes(motion, motion.points, labels, path.name),
            lambda: io_c3d.c3d_bytes(motion),
        ),
    }


if __name__ == "__main__":
    main()
