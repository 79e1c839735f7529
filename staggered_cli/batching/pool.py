"""Worker processes for a batch: one file at a time each, and a file whose
worker dies (a segmentation fault in native code, the out-of-memory killer)
fails alone.

The pool runs any picklable ``work(job) -> Result`` (:func:`.run.run_file`
with its plan bound, in a batch); the workers are started with ``spawn``
(no fork of a process that may run threads) and end with the process that
started them, however it ends.
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Callable, Sequence

from .plan import Job
from .results import FAILED, Result

#: What a worker runs on each job.
Work = Callable[[Job], Result]

#: Seconds a worker is given to end (and remove its temporary file) after
#: SIGTERM before it is killed.
_GRACE = 3.0


def _die_with_parent(parent_pid: int) -> None:
    """End this worker when the batch process ends, however it ends.

    On Linux the kernel sends SIGTERM on the parent's death
    (``prctl(PR_SET_PDEATHSIG)``); elsewhere, and for a parent that died
    before the call, a thread watches the parent's pid and sends it.  SIGTERM
    unwinds the worker (see ``_worker_main``), so that the output it was
    writing when a SIGKILL took the batch leaves no temporary file behind.
    An idle worker also ends when its pipe closes.
    """
    import signal
    import threading

    if sys.platform.startswith("linux"):
        try:
            import ctypes

            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(1, int(signal.SIGTERM), 0, 0, 0)  # 1 = PR_SET_PDEATHSIG
        except (OSError, AttributeError):
            pass  # no prctl: the watcher thread below still ends us
    if os.getppid() != parent_pid:
        os._exit(1)

    def watch() -> None:
        while os.getppid() == parent_pid:
            time.sleep(0.5)
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(_GRACE)
        os._exit(1)

    threading.Thread(target=watch, name="parent-watch", daemon=True).start()


def _worker_main(conn, parent_pid: int, work: Work) -> None:
    """A worker process: run ``work`` on the jobs sent on ``conn`` one by one, send back each Result."""
    import signal
    import threading

    _die_with_parent(parent_pid)
    # Ctrl-C reaches the whole process group: the parent handles it and ends
    # the workers.  SIGTERM (from the parent) unwinds, so that a write's
    # temporary file is removed.
    signal.signal(signal.SIGINT, signal.SIG_IGN)

    def unwind(signum, frame):
        # a worker that cannot unwind in time (stuck in native code) is ended
        threading.Timer(_GRACE, os._exit, (1,)).start()
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, unwind)
    from ..cli.heap import reuse_freed_memory

    reuse_freed_memory()
    try:
        while True:
            try:
                job = conn.recv()
            except (EOFError, OSError):
                return  # the parent is gone
            if job is None:
                return
            conn.send(work(job))
    except KeyboardInterrupt:
        return


def _death(exitcode: int | None) -> str:
    """Why a worker ended, in a few words."""
    import signal

    if exitcode is not None and exitcode < 0:
        try:
            name = signal.Signals(-exitcode).name
        except ValueError:
            name = f"signal {-exitcode}"
        native = ": a crash in native code"
        hint = {"SIGKILL": ": out of memory?", "SIGSEGV": native, "SIGBUS": native, "SIGABRT": native}
        return f"worker process died ({name}{hint.get(name, '')})"
    return f"worker process died (exit code {exitcode})"


class _Worker:
    """One worker process, the pipe to it and the job it is running."""

    def __init__(self, ctx, work: Work):
        self.conn, child = ctx.Pipe()
        self.proc = ctx.Process(target=_worker_main, args=(child, os.getpid(), work), daemon=True)
        self.proc.start()
        child.close()
        self.job: Job | None = None
        self.start = 0.0

    def run(self, job: Job) -> None:
        self.job, self.start = job, time.perf_counter()
        try:
            self.conn.send(job)
        except OSError:
            pass  # it died already: its sentinel reports it

    def stop(self) -> None:
        """Ask an idle worker to end."""
        try:
            self.conn.send(None)
        except OSError:
            pass  # already gone
        self.conn.close()
        self.proc.join(_GRACE)
        if self.proc.is_alive():
            self.proc.kill()
            self.proc.join()


def _end_all(pool: Sequence[_Worker]) -> None:
    """SIGTERM every worker, give it time to clean up, then SIGKILL."""
    for w in pool:
        if w.proc.is_alive():
            w.proc.terminate()
    deadline = time.monotonic() + _GRACE
    for w in pool:
        w.proc.join(max(0.0, deadline - time.monotonic()))
        if w.proc.is_alive():
            w.proc.kill()
            w.proc.join()
        w.conn.close()


def _size(path: str) -> int:
    try:
        return os.path.getsize(path)
    except OSError:
        return 0


def _cleanup(job: Job) -> None:
    """Remove what a dead worker may have left of ``job``'s output."""
    from ..io.files import remove_stale_temporaries
    from .run import remove_output

    remove_output(job.dst)
    remove_stale_temporaries(job.dst)


def run_batch(
    jobs: Sequence[Job],
    work: Work,
    workers: int,
    on_result: Callable[[Result], None] | None = None,
) -> list[Result]:
    """Run ``work`` on every job in ``workers`` processes (at least one, even
    for one job: a crash in native code then fails one file, not the batch).

    The largest files are started first, so that the last worker to finish
    is not the one that drew the longest clip at the end.  A worker that
    dies fails the file it was running with a one-line reason, and a new
    worker takes its place.  ``on_result`` is called in this process as
    each file finishes.
    """
    import multiprocessing
    from collections import deque
    from multiprocessing.connection import wait

    order = deque(sorted(jobs, key=lambda j: -_size(j.src)))
    results: list[Result] = []
    if not order:
        return results

    def done(result: Result) -> None:
        results.append(result)
        if on_result is not None:
            on_result(result)

    # spawn: no fork of a process that may run threads (the progress bar's monitor)
    ctx = multiprocessing.get_context("spawn")
    pool: list[_Worker] = []
    try:
        for _ in range(max(1, min(workers, len(order)))):
            w = _Worker(ctx, work)
            pool.append(w)
            w.run(order.popleft())
        while any(w.job is not None for w in pool):
            busy = [w for w in pool if w.job is not None]
            wait([w.conn for w in busy] + [w.proc.sentinel for w in busy])
            for i, w in enumerate(pool):
                if w.job is None:
                    continue
                result = None
                if w.conn.poll():
                    try:
                        result = w.conn.recv()
                    except (EOFError, OSError):
                        result = None  # died while sending: reported below
                elif w.proc.is_alive():
                    continue
                if result is not None:
                    done(result)
                    w.job = None
                else:
                    job = w.job
                    w.proc.join()
                    w.conn.close()
                    _cleanup(job)
                    why = _death(w.proc.exitcode)
                    done(Result(job.rel, FAILED, time.perf_counter() - w.start, why, cli_reason=why))
                    w = pool[i] = _Worker(ctx, work) if order else w
                    w.job = None
                if order and w.job is None and w.proc.is_alive():
                    w.run(order.popleft())
    except BaseException:
        _end_all(pool)
        raise
    for w in pool:
        if w.proc.is_alive():
            w.stop()
    return results
