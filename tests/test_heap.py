"""The C heap keeps freed array memory for reuse (glibc), so that a command
does not fault in every array it makes afresh."""

from __future__ import annotations

import platform
import subprocess
import sys

import pytest

from staggered_cli.cli import heap

GLIBC = sys.platform.startswith("linux") and platform.libc_ver()[0] == "glibc"

# page faults of making and freeing an 8 MB array 40 times (after a first)
_LOOP = """
import resource, sys
import numpy as np
if sys.argv[1] == "tuned":
    from staggered_cli.cli.heap import reuse_freed_memory
    assert reuse_freed_memory()
a = np.ones(1 << 20)
del a
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(40):
    a = np.ones(1 << 20)
    del a
print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


def _faults(mode: str) -> int:
    out = subprocess.run([sys.executable, "-c", _LOOP, mode], capture_output=True, text=True, check=True)
    return int(out.stdout.split()[-1])


@pytest.mark.skipif(not GLIBC, reason="glibc's mallopt only")
def test_freed_arrays_are_reused_instead_of_faulted_in_again():
    default, tuned = _faults("default"), _faults("tuned")
    # by default glibc returns freed memory above its trim threshold and the
    # next array faults it in again (about 500 pages here); reused, none is
    assert tuned < 50, tuned
    assert default > 200, default


def test_reuse_says_whether_it_took():
    assert heap.reuse_freed_memory() is GLIBC or not sys.platform.startswith("linux")
    assert heap.MMAP_THRESHOLD <= heap.TRIM_THRESHOLD
