"""Regenerate the golden files under tests/golden/ (run by `make golden`, on
purpose, never by a test).

Each case is an input file and the CLI arguments whose stdout is kept;
tests/test_golden.py runs the same cases and compares.  After a deliberate
change of output, run `make golden` and review the diff before committing.
"""

from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
GOLDEN = ROOT / "tests" / "golden"
MOCAP = ROOT.parent / "shared" / "mocap"
SAMPLES = ROOT / "data" / "samples"

#: Small real files from ../shared/mocap (read there, never copied here).
REAL_FILES = ("bandai2_run_normal_001.bvh", "c3dorg_sample01_Eb015pi_walk.c3d")


#: Pipelines on the bundled sample: each step's stdout is the next one's stdin.
PIPELINES = {
    "extract_march.bvh.json": [["extract", "--format", "json"], ["info", "--json"]],
    "extract_march.c3d.json": [["extract", "--format", "json"], ["info", "--json"]],
    "pipeline_march.bvh.json": [
        ["extract", "--format", "json"],
        ["cull", "--keep", "50%", "--format", "json"],
        ["succession", "--joint", "LeftArm", "--offset", "0.03", "--power", "1.5", "--clamp", "--format", "json"],
        ["info", "--json"],
    ],
    "constraints_march.bvh.txt": [["extract"], ["constraints"]],
}


def cases() -> dict[str, tuple[Path, list]]:
    """golden file name -> (input path, arguments before the path, or a list
    of such argument lists for a pipeline)."""
    out: dict[str, tuple[Path, list]] = {}
    for golden, steps in PIPELINES.items():
        out[golden] = (SAMPLES / golden.split("_", 1)[1].rsplit(".", 1)[0], steps)
    for path in sorted(SAMPLES.glob("*.bvh")) + sorted(SAMPLES.glob("*.c3d")):
        out[f"info_{path.name}.json"] = (path, ["info", "--json"])
    for name in REAL_FILES:
        out[f"info_{name}.json"] = (MOCAP / name, ["info", "--json"])
    return out


def render(path: Path, args: list) -> str:
    """The stdout of `staggered ARGS PATH` (or of the pipeline), which must succeed."""
    from click.testing import CliRunner

    from staggered_cli.cli.main import cli

    steps = args if args and isinstance(args[0], list) else [args]
    data: bytes | None = None
    for n, step in enumerate(steps):
        argv = [*step, str(path)] if n == 0 else [*step, "-"]
        result = CliRunner().invoke(cli, argv, input=data, catch_exceptions=False)
        if result.exit_code != 0:
            raise RuntimeError(f"staggered {' '.join(argv)} failed ({result.exit_code}): {result.stderr}")
        data = result.stdout_bytes
    return data.decode("utf-8")


def main() -> int:
    GOLDEN.mkdir(parents=True, exist_ok=True)
    for golden, (path, args) in cases().items():
        if not path.exists():
            print(f"skipped {golden}: {path} is not there", file=sys.stderr)
            continue
        (GOLDEN / golden).write_text(render(path, args), encoding="utf-8")
        print(f"wrote tests/golden/{golden}")
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(ROOT))  # the checkout's package, installed or not
    sys.exit(main())
