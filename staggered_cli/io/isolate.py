"""Run a call into a C library that parses untrusted bytes in a forked child.

ezc3d (C++) trusts the files it reads: a corrupt parameter can make it
segfault, allocate without bound or loop forever, and neither Python nor
Ctrl-C can stop it there.  :func:`run_isolated` forks, runs the call in the
child under an address-space limit (``RLIMIT_AS``), a CPU-time limit
(``RLIMIT_CPU``) and a wall-clock deadline, and sends the result back
pickled through a pipe.  A child that dies, overruns its limits or its
deadline is killed and reported as :class:`ChildFailed`; an exception raised
by the call is re-raised in the parent as it was.

The child inherits everything already imported (fork), so it starts in a
few milliseconds; it never returns into the caller's stack (``os._exit``),
its standard streams are ``/dev/null`` (a C library's prints must not reach
the command's data on stdout), and it dies with its parent (Linux
``PR_SET_PDEATHSIG``; elsewhere the CPU limit ends it).  Where there is no
``fork`` (Windows) the call runs in-process, unguarded.
"""

from __future__ import annotations

import faulthandler
import functools
import math
import os
import pickle
import selectors
import signal
import struct
import time
from collections.abc import Callable
from typing import TypeVar

__all__ = ["ChildFailed", "run_isolated", "fd_path"]

T = TypeVar("T")

_PR_SET_PDEATHSIG = 1
_CHUNK = 1 << 20
#: Linux fcntl F_SETPIPE_SZ: a 1 MB pipe moves a result in fewer round trips.
_F_SETPIPE_SZ = 1031


class ChildFailed(Exception):
    """The isolated call did not return: ``why`` says how it ended."""

    def __init__(self, why: str):
        super().__init__(why)
        self.why = why


def run_isolated(fn: Callable[[], T], *, memory: int, seconds: float) -> T:
    """``fn()`` computed in a forked child, within limits.

    Parameters
    ----------
    fn : callable
        No arguments; its result must pickle.  Whatever it needs is
        inherited by the child (closures, imported modules).
    memory : int
        Bytes the child may allocate beyond the parent's address space at
        the time of the call.
    seconds : float
        Wall-clock deadline (and, rounded up, CPU-time limit) of the child.

    Raises
    ------
    ChildFailed
        The child was killed by a signal (a crash), exceeded ``seconds``,
        ran out of memory, or exited without a result.
    Exception
        What ``fn`` raised, re-raised in the parent.
    """
    if not hasattr(os, "fork"):
        return fn()
    limit = _address_space()
    if limit is not None:
        limit += int(memory)
    parent = os.getpid()
    r, w = os.pipe()
    _widen(w)
    _libc()  # loaded once in the parent, inherited by every child
    pid = os.fork()
    if pid == 0:  # pragma: no cover - the child reports through the pipe
        _child(fn, r, w, parent, limit, seconds)
    os.close(w)
    reaped = False
    try:
        frames = _collect(r, time.monotonic() + seconds)
        if frames is None:
            raise ChildFailed(f"no result after {seconds:g} s (killed)")
        _, status = os.waitpid(pid, 0)
        reaped = True
    finally:
        os.close(r)
        if not reaped:
            _kill(pid)
    if os.WIFSIGNALED(status):
        sig = os.WTERMSIG(status)
        raise ChildFailed(f"killed by {_signal_name(sig)}")
    if not frames:
        raise ChildFailed(f"exited with status {os.WEXITSTATUS(status)} and no result")
    try:
        kind, value = pickle.loads(frames[0], buffers=frames[1:])
    except Exception:  # cannot happen unless the child was killed while writing
        raise ChildFailed("sent an incomplete result") from None
    if kind == "raise":
        if isinstance(value, MemoryError):
            raise ChildFailed("ran out of memory")
        raise value
    return value


def fd_path(fd: int) -> str:
    """A path that opens the file behind descriptor ``fd`` (Linux, BSD, macOS)."""
    proc = f"/proc/self/fd/{fd}"
    return proc if os.path.exists(proc) else f"/dev/fd/{fd}"


def _collect(r: int, deadline: float) -> list[bytearray] | None:
    """The frames the child sends on ``r`` (see :func:`_send`): ``[]`` when it
    sent nothing or not all, None at the deadline.  Each frame is read
    straight into its own buffer: a result's arrays are not copied again."""
    with selectors.DefaultSelector() as sel:
        sel.register(r, selectors.EVENT_READ)

        def read(n: int) -> bytearray | None:
            buf = bytearray(n)
            view = memoryview(buf)
            got = 0
            while got < n:
                left = deadline - time.monotonic()
                if left <= 0:
                    raise TimeoutError
                if not sel.select(left):
                    continue
                k = os.readv(r, [view[got : got + _CHUNK]])
                if k == 0:
                    return None
                got += k
            return buf

        try:
            head = read(16)
            if head is None:
                return []
            size, count = struct.unpack("<QQ", head)
            frames = [read(size)]
            for _ in range(count):
                length = read(8)
                frames.append(read(struct.unpack("<Q", length)[0]) if length is not None else None)
        except TimeoutError:
            return None
    return [] if any(f is None for f in frames) else frames  # type: ignore[misc]


def _send(w: int, out) -> None:  # pragma: no cover - runs in the child
    """Write ``out`` pickled to ``w``: a frame with the pickle, then one per
    out-of-band buffer (numpy arrays, bytearrays), each length-prefixed."""
    buffers: list[pickle.PickleBuffer] = []
    head = pickle.dumps(out, protocol=5, buffer_callback=buffers.append)
    views = [b.raw() for b in buffers]
    _write(w, struct.pack("<QQ", len(head), len(views)) + head)
    for view in views:
        _write(w, struct.pack("<Q", view.nbytes))
        _write(w, view)


def _write(w: int, data) -> None:  # pragma: no cover - runs in the child
    view = memoryview(data).cast("B")
    while view:
        view = view[os.write(w, view) :]


def _child(fn, r: int, w: int, parent: int, limit: int | None, seconds: float) -> None:  # pragma: no cover
    """Run ``fn`` and write ``pickle(('ok', result))`` or ``('raise', exc)`` to ``w``; never returns."""
    try:
        os.close(r)
        for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGPIPE):
            signal.signal(sig, signal.SIG_DFL)
        faulthandler.disable()  # its dump of a crash would go to the parent's stderr
        _die_with_parent(parent)
        null = os.open(os.devnull, os.O_RDWR)
        for fd in (0, 1, 2):
            os.dup2(null, fd)
        os.close(null)
        import resource

        cpu = math.ceil(seconds) + 1
        resource.setrlimit(resource.RLIMIT_CPU, (cpu, cpu + 1))
        if limit is not None:
            try:
                resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
            except (ValueError, OSError):
                pass  # a hard limit below ours already holds
        try:
            out = ("ok", fn())
        except BaseException as exc:  # everything goes back to the parent
            out = ("raise", exc)
        try:
            _send(w, out)
        except (pickle.PicklingError, TypeError, AttributeError) as exc:  # an unpicklable result or exception
            _send(w, ("raise", RuntimeError(f"{type(exc).__name__}: {exc}")))
    finally:
        os._exit(0)


def _die_with_parent(parent: int) -> None:  # pragma: no cover - runs in the child
    """Have the kernel kill this child when its parent dies (Linux)."""
    libc = _libc()
    if libc is None:
        return
    try:
        libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL)
    except AttributeError:  # no prctl
        return
    if os.getppid() != parent:  # the parent died before prctl
        os._exit(1)


@functools.cache
def _libc():
    """The C library (for ``prctl``) on Linux, else None."""
    if not os.path.exists("/proc/self/status"):
        return None
    try:
        import ctypes

        return ctypes.CDLL(None, use_errno=True)
    except OSError:
        return None


def _widen(fd: int) -> None:
    try:
        import fcntl

        fcntl.fcntl(fd, _F_SETPIPE_SZ, _CHUNK)
    except (ImportError, OSError):
        pass  # not Linux, or over /proc/sys/fs/pipe-max-size: the default size works


def _address_space() -> int | None:
    """Bytes of address space of this process now (Linux), else None."""
    try:
        with open("/proc/self/statm", "rb") as fh:
            pages = int(fh.read().split()[0])
    except (OSError, ValueError, IndexError):
        return None
    return pages * os.sysconf("SC_PAGE_SIZE")


def _kill(pid: int) -> None:
    """Kill and reap our child ``pid``."""
    try:
        os.kill(pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    try:
        os.waitpid(pid, 0)
    except ChildProcessError:
        pass


def _signal_name(sig: int) -> str:
    try:
        return signal.Signals(sig).name
    except ValueError:
        return f"signal {sig}"
