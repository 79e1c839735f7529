"""A batch whose workers die for real, for tests/test_batch_isolation.py.

Run as ``python -c "from tests.batch_faults import main; main()" SPEC batch IN OUT ...``
from the repository root: it wraps the function the batch workers run on
each file (:func:`staggered_cli.batching.run.run_file`, looked up when the
batch starts and sent to the spawned workers by reference to this module)
and then runs the ``staggered`` command line as usual.  The production
code holds no hook: the fault lives here.

``SPEC`` is ``NAME=HOW[;NAME=HOW...]``: the worker that draws the file
named NAME (its path under IN, or its base name) dies before it reads it,
the way a crash in a native library would: HOW is ``exit``
(``os._exit(3)``), ``segv`` (a real segmentation fault), ``kill`` (SIGKILL,
as the out-of-memory killer sends), ``hang`` (sleeps until killed) or
``hang-writing`` (sleeps in the write of its output).
"""

from __future__ import annotations

import functools
import os
import sys
import time


def inject(spec: str, rel: str) -> None:
    for item in filter(None, spec.split(";")):
        name, _, how = item.partition("=")
        if name not in (rel, os.path.basename(rel)):
            continue
        if how == "exit":
            os._exit(3)
        elif how == "segv":
            import ctypes

            ctypes.string_at(0)  # reads address 0: SIGSEGV
        elif how == "kill":
            import signal

            os.kill(os.getpid(), signal.SIGKILL)
        elif how == "hang":
            while True:
                time.sleep(1.0)
        elif how == "hang-writing":  # hangs once an output's temporary file exists

            def hang(fd: int) -> None:
                while True:
                    time.sleep(1.0)

            os.fsync = hang


def run_file_with_fault(spec: str, job, **kwargs):
    """The worker's function: the fault for ``job``, if any, then the real run."""
    from staggered_cli.batching import run

    inject(spec, job.rel)
    return run.run_file(job, **kwargs)


def main() -> None:
    from staggered_cli.batching import run
    from staggered_cli.cli.main import main as cli_main

    spec = sys.argv.pop(1)
    run.run_file = functools.partial(run_file_with_fault, spec)  # in this process: what the batch sends
    sys.argv[0] = "staggered"
    cli_main()
