"""The whole pipeline on every file of ../shared/mocap, against a numpy floor (issue 9).

Four tables:

1. Per file, each in a fresh subprocess (so that peak memory is that
   file's): frames, joints or markers, then seconds for read, extract, cull
   (to the top 30 % of poses), bake and write, the peak resident memory of
   the process (``ru_maxrss``; "base" is the same after imports and a
   warm-up on the bundled sample), and the floor of the same file measured
   in the same process: for BVH ``np.loadtxt`` of the MOTION lines and
   ``np.savetxt`` of that array (``%.6f``), for C3D ezc3d's own read and write
   (n/a where ezc3d cannot write the file back).
2. Extract time against clip length: cmu_02_01 (a walk) repeated 1, 2, 4
   and 8 times (goal: 8x the frames in at most 9x the time).
3. Whole processes, start-up included (median of ``--repeats``):
   ``staggered extract cmu_01_01 -o x`` then ``staggered bake x -o y.bvh``,
   against one ``python`` process doing loadtxt + savetxt (``%.6f``) of the
   same file (goal: within 6x); numpy's default ``%.18e`` shown for reference.
4. ``staggered batch --jobs 2`` (extract and bake) over the 10 BVH files,
   wall time, against Blender 5.0.1's 11.8 s to import and export them
   unchanged; and ``make -j2 batch`` over the same files (a thin rule over
   ``staggered batch``: the make overhead alone) for comparison.

    python bench/bench_all.py [--repeats 3] [--no-make]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tests.conftest import MOCAP  # noqa: E402

BIN = Path(sys.executable).parent
STAGGERED = str(BIN / "staggered") if (BIN / "staggered").exists() else None
WHOLE_FILE = "cmu_01_01_forward_jumps.bvh"
SCALING_FILE = "cmu_02_01_walk.bvh"
WHOLE_GOAL = 6.0
SCALING_GOAL = 9.0
BLENDER_SECONDS = 11.8

# One process: numpy's text reader and writer on the MOTION block of a BVH.
FLOOR_SCRIPT = """
import io, sys
import numpy as np
text = open(sys.argv[1]).read()
head, sep, rest = text.partition("Frame Time:")
motion = rest.split("\\n", 1)[1]
a = np.loadtxt(io.StringIO(motion), ndmin=2)
np.savetxt(sys.argv[2], a, fmt=sys.argv[3] if len(sys.argv) > 3 else "%.18e")
"""


# --- one file, in a child process ------------------------------------------------------------


def _rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # Linux: kB


def _pipeline(path: Path, tmp: str) -> dict:
    """Each stage once, timed; returns seconds per stage and sizes."""
    from staggered_cli.io import files
    from staggered_cli.io.bvh import bvh_bytes, read_bvh
    from staggered_cli.io.c3d import c3d_bytes, read_c3d
    from staggered_cli.motion import BvhMotion
    from staggered_cli.ops.bake import bake
    from staggered_cli.ops.cull import choose, keep_poses
    from staggered_cli.ops.extract import extract

    out: dict = {}
    t = time.perf_counter()
    data, name = files.read_bytes(str(path))
    is_bvh = path.suffix.lower() == ".bvh"
    motion = (read_bvh if is_bvh else read_c3d)(str(path), data=data, name=name)
    out["read"] = time.perf_counter() - t
    t = time.perf_counter()
    doc = extract(motion, source_name=path.name, source_bytes=data)
    out["extract"] = time.perf_counter() - t
    t = time.perf_counter()
    culled = keep_poses(doc, choose(doc, keep="30%"))
    out["cull"] = time.perf_counter() - t
    t = time.perf_counter()
    baked = bake(culled)
    out["bake"] = time.perf_counter() - t
    t = time.perf_counter()
    blob = bvh_bytes(baked) if isinstance(baked, BvhMotion) else c3d_bytes(baked)
    files.write_atomic(os.path.join(tmp, "out" + path.suffix), blob, force=True)
    out["write"] = time.perf_counter() - t
    out["frames"] = motion.n_frames
    out["vars"] = len(motion.skeleton.names) if isinstance(motion, BvhMotion) else len(motion.labels)
    out["poses"] = [doc.n_poses, culled.n_poses]
    return out


def _floor(path: Path, tmp: str) -> dict:
    """numpy's (BVH) or ezc3d's (C3D) read and write of the same file."""
    if path.suffix.lower() == ".bvh":
        import io

        import numpy as np

        t = time.perf_counter()
        text = path.read_text()
        motion = text.partition("Frame Time:")[2].split("\n", 1)[1]
        a = np.loadtxt(io.StringIO(motion), ndmin=2)
        read = time.perf_counter() - t
        t = time.perf_counter()
        np.savetxt(os.path.join(tmp, "floor.txt"), a, fmt="%.6f")
        return {"floor": "numpy", "floor_read": read, "floor_write": time.perf_counter() - t}
    import ezc3d

    t = time.perf_counter()
    c = ezc3d.c3d(str(path))
    read = time.perf_counter() - t
    t = time.perf_counter()
    try:
        c.write(os.path.join(tmp, "floor.c3d"))
    except Exception as err:  # ezc3d cannot write every file it reads (c3dorg: LABELS2 markers)
        return {"floor": f"ezc3d (write n/a: {type(err).__name__})", "floor_read": read, "floor_write": None}
    return {"floor": "ezc3d", "floor_read": read, "floor_write": time.perf_counter() - t}


def one_file(path: Path) -> dict:
    """Run in a child: warm up on the bundled sample, then measure ``path``."""
    with tempfile.TemporaryDirectory() as tmp:
        sample = ROOT / "data" / "samples" / ("march" + path.suffix.lower())
        if sample.exists():
            _pipeline(sample, tmp)  # imports and first-call costs out of the way
        base = _rss_mb()
        result = _pipeline(path, tmp)
        result["peak_mb"] = _rss_mb()
        result["base_mb"] = base
        result.update(_floor(path, tmp))
    return result


# --- the tables -------------------------------------------------------------------------------


def per_file_table() -> None:
    names = sorted(p for p in MOCAP.iterdir() if p.suffix.lower() in (".bvh", ".c3d"))
    print("per file, one process each (seconds; memory: peak RSS of the process, MB)")
    head = (
        f"  {'file':<36} {'frames':>6} {'j/m':>4} {'read':>6} {'extract':>7} {'cull':>6} {'bake':>6} "
        f"{'write':>6} {'total':>6}  {'peak':>5} {'base':>5}  {'floor: read':>11} {'write':>6} {'total':>6}"
    )
    print(head)
    for path in names:
        proc = subprocess.run(
            [sys.executable, __file__, "--one", str(path)], capture_output=True, text=True, check=False
        )
        if proc.returncode != 0:
            print(f"  {path.name:<36} failed: {proc.stderr.strip().splitlines()[-1:]}")
            continue
        r = json.loads(proc.stdout.strip().splitlines()[-1])
        total = sum(r[k] for k in ("read", "extract", "cull", "bake", "write"))
        tag = "" if r["floor"] == "numpy" else f" ({r['floor']})"
        fw, floor = (
            ("   n/a", "   n/a")
            if r["floor_write"] is None
            else (f"{r['floor_write']:6.3f}", f"{r['floor_read'] + r['floor_write']:6.3f}")
        )
        print(
            f"  {path.name:<36} {r['frames']:6d} {r['vars']:4d} {r['read']:6.3f} {r['extract']:7.3f} "
            f"{r['cull']:6.3f} {r['bake']:6.3f} {r['write']:6.3f} {total:6.2f}  {r['peak_mb']:5.0f} "
            f"{r['base_mb']:5.0f}  {r['floor_read']:11.3f} {fw} {floor}{tag}"
        )


def scaling_table(repeats: int) -> None:
    from dataclasses import replace

    import numpy as np

    from staggered_cli.io.bvh import read_bvh
    from staggered_cli.ops.extract import extract

    base = read_bvh(str(MOCAP / SCALING_FILE))
    extract(base)  # warm up
    print(f"extract time against clip length: {SCALING_FILE} repeated")
    t1 = None
    ratio = 0.0
    for n in (1, 2, 4, 8):
        motion = replace(base, channels=np.concatenate([base.channels] * n))
        times = []
        for _ in range(repeats if n <= 2 else 1):
            t = time.perf_counter()
            extract(motion)
            times.append(time.perf_counter() - t)
        total = statistics.median(times)
        t1 = t1 or total
        ratio = total / t1
        print(f"  x{n}  {motion.n_frames:6d} frames  extract {total:6.3f} s  ratio {ratio:5.2f}")
    print(f"  8x time ratio {ratio:.2f} (goal <= {SCALING_GOAL})  {'ok' if ratio <= SCALING_GOAL else 'SUPERLINEAR'}")


def _wall(cmd: list[str], repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def whole_process_table(repeats: int) -> None:
    src = str(MOCAP / WHOLE_FILE)
    print(f"whole processes, start-up included: {WHOLE_FILE} (median of {repeats})")
    with tempfile.TemporaryDirectory() as tmp:
        doc, out, floor_out = (os.path.join(tmp, n) for n in ("x.stag", "y.bvh", "floor.txt"))
        py = _wall([sys.executable, "-c", "pass"], repeats)
        np_start = _wall([sys.executable, "-c", "import numpy"], repeats)
        helps = _wall([STAGGERED, "--help"], repeats)
        ext = _wall([STAGGERED, "extract", src, "-o", doc, "--force"], repeats)
        bak = _wall([STAGGERED, "bake", doc, "-o", out, "--force"], repeats)
        floor = _wall([sys.executable, "-c", FLOOR_SCRIPT, src, floor_out, "%.6f"], repeats)
        floor_e = _wall([sys.executable, "-c", FLOOR_SCRIPT, src, floor_out], repeats)
    ratio = (ext + bak) / floor
    print(f"  python -c pass                       {py:6.3f} s")
    print(f"  python -c 'import numpy'             {np_start:6.3f} s")
    print(f"  staggered --help                     {helps:6.3f} s")
    print(f"  staggered extract FILE -o x          {ext:6.3f} s")
    print(f"  staggered bake x -o y.bvh            {bak:6.3f} s")
    print(f"  extract + bake                       {ext + bak:6.3f} s")
    print(f"  floor: python loadtxt + savetxt      {floor:6.3f} s  (fmt %.6f; numpy's default %.18e: {floor_e:.3f} s)")
    print(f"  ratio {ratio:.2f} (goal <= {WHOLE_GOAL})  {'ok' if ratio <= WHOLE_GOAL else 'SLOW'}")


def batch_table(with_make: bool) -> None:
    bvh = sorted(p for p in MOCAP.iterdir() if p.suffix.lower() == ".bvh")
    print(
        f"batch over the {len(bvh)} BVH files, 2 jobs, extract and bake (Blender 5.0.1 import + export: "
        f"{BLENDER_SECONDS} s)"
    )
    with tempfile.TemporaryDirectory() as tmp:
        src = os.path.join(tmp, "in")
        os.mkdir(src)
        for p in bvh:
            os.symlink(p, os.path.join(src, p.name))
        t = time.perf_counter()
        proc = subprocess.run(
            [STAGGERED, "-q", "batch", src, os.path.join(tmp, "out"), "--jobs", "2"],
            capture_output=True,
            text=True,
            check=False,
        )
        wall = time.perf_counter() - t
        for line in proc.stdout.splitlines():
            print("    " + line)
        ok = proc.returncode == 0 and wall < BLENDER_SECONDS
        print(
            f"  staggered batch --jobs 2   {wall:6.2f} s  (exit {proc.returncode}; goal < {BLENDER_SECONDS} s)  "
            f"{'ok' if ok else 'SLOW'}"
        )
        make = shutil.which("make")
        if with_make and make:
            t = time.perf_counter()
            proc = subprocess.run(
                [
                    make,
                    "-s",
                    "-C",
                    str(ROOT),
                    "-j2",
                    "batch",
                    f"IN={src}",
                    f"OUT={os.path.join(tmp, 'out_make')}",
                    f"STAGGERED={STAGGERED}",
                    "-o",
                    ".venv/.staggered-installed",
                ],
                capture_output=True,
                text=True,
                check=False,
            )
            wall = time.perf_counter() - t
            print(f"  make -j2 batch             {wall:6.2f} s  (exit {proc.returncode}; staggered batch through make)")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3, help="runs per whole-process measurement (median)")
    parser.add_argument("--no-make", action="store_true", help="skip the make -j2 batch timing")
    parser.add_argument("--one", metavar="FILE", help=argparse.SUPPRESS)  # internal: measure one file
    args = parser.parse_args(argv)
    if args.one:
        print(json.dumps(one_file(Path(args.one))))
        return 0
    if not MOCAP.is_dir():
        print(f"skipped: {MOCAP} is missing")
        return 0
    if STAGGERED is None:
        print(f"skipped: no staggered script beside {sys.executable}")
        return 0
    per_file_table()
    scaling_table(args.repeats)
    whole_process_table(args.repeats)
    batch_table(not args.no_make)
    return 0


if __name__ == "__main__":
    sys.exit(main())
