"""Every bench/*.py script still loads against the library's current layout
(a module it patches or imports by its old name fails here, not in `make
bench`): each is run in a child process with a name other than __main__,
so its module-level code runs and its benchmark does not."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[1] / "bench"


@pytest.mark.parametrize("script", sorted(p.name for p in BENCH.glob("*.py")))
def test_bench_script_loads(script):
    code = f"import runpy; runpy.run_path({str(BENCH / script)!r}, run_name='bench_check')"
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr[-2000:]
