"""Batch processing of a mocap library: ``extract | STEP | ... | bake`` per file.

For every BVH and C3D file under an input folder (recursively, any case of
the extension) this runs the same pipeline as the shell form::

    staggered extract IN/rel -o - | staggered STEP1 - -o - | ... | staggered bake - -o OUT/rel

but in one process per worker: each stage is the real click command, parsed
by click from the step's own words and invoked in-process with its standard
input and output bound to memory.  A step therefore has exactly the options,
checks and messages of its command, and the two forms (this module and
``make batch``) give the same files.

Steps are written as in ``--steps 'cull --keep 30%|succession --joint
LeftShoulder --offset 0.02 --power 2'``: split on ``|``, each part split
with shell quoting rules (:mod:`shlex`), without a FILE or ``-o`` (the batch
supplies them).  Only commands that turn a document into a document can be
steps (:data:`STEP_COMMANDS`).

Up to date: an output is rebuilt when it is missing or older than its input
(make's rule; changing the steps does not make outputs stale: use ``force``).
A file that fails leaves no output: the bake writes atomically, and an
output left from an earlier run is removed, since it no longer matches its
input.

Nothing heavy is imported at module level: the stages import their own
libraries when they run.  The commands are the caller's: it passes their
table (:data:`Commands`), so that this module knows no command line.
"""

from __future__ import annotations

import contextlib
import io
import os
import shlex
import sys
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass

from .errors import DataError, StaggeredError, UsageError

#: Command name -> ``"module:attribute"`` of its click command (imported on
#: first use; strings, so that the table goes to the worker processes).
Commands = Mapping[str, str]

#: Commands that read a document and write a document: the possible steps.
STEP_COMMANDS = ("cull", "edit-pose", "succession", "randomize", "layer", "detail")

#: File name endings (compared without case) that the batch picks up.
EXTENSIONS = (".bvh", ".c3d")

DONE, SKIPPED, FAILED, TODO = "done", "skipped", "failed", "todo"

_STDIO_NAMES = (None, "-", "<stdin>", "<stdout>")


@dataclass(frozen=True)
class Step:
    """One document -> document stage: a command name and its words."""

    name: str
    args: tuple[str, ...]
    text: str  # as the user wrote it, for messages

    def argv(self) -> list[str]:
        """The words to parse: the step's own, then stdin in and stdout out."""
        return [*self.args, "-", "-o", "-"]


@dataclass(frozen=True)
class Job:
    """One input file and where its output goes (``rel`` is relative to both folders)."""

    rel: str
    src: str
    dst: str


@dataclass(frozen=True)
class Result:
    """What happened to one file: ``status`` is done, skipped, failed (or todo in a dry run)."""

    rel: str
    status: str
    seconds: float | None = None
    reason: str = ""
    messages: tuple[str, ...] = ()  # warnings the stages wrote on stderr


def _one_line(text: str) -> str:
    return " ".join(line.strip() for line in str(text).splitlines() if line.strip())


def _command(name: str, commands: Commands):
    """The click command registered as ``name`` (imported on first use)."""
    import importlib

    module_name, attr = commands[name].split(":")
    return getattr(importlib.import_module(module_name), attr)


class _Pipe(io.BytesIO):
    """A pipe between two of a file's commands: bytes, or the whole
    Document one command wrote to standard output, which the next reads
    from standard input as it is (:func:`~staggered_cli.cli.common.read_document`
    and ``write_document`` hand it over): a document made in this process
    need not be serialized, checked and parsed again between steps (cull +
    succession over the 10 dev BVH files: 325 ms of 3.9 s)."""

    document = None


@contextlib.contextmanager
def _stdio(data) -> Iterator[tuple[_Pipe, io.StringIO]]:
    """Bind stdin to ``data`` (bytes, or a Document handed over) and stdout /
    stderr to memory, as a pipe would.

    Yields the pipe that receives standard output and the StringIO that
    receives standard error (where the commands log their warnings).
    """
    saved = sys.stdin, sys.stdout, sys.stderr
    out, err = _Pipe(), io.StringIO()
    if isinstance(data, bytes | bytearray):
        pipe = _Pipe(data)
    else:
        pipe = _Pipe()
        pipe.document = data
    stdin = io.TextIOWrapper(pipe)
    stdout = io.TextIOWrapper(out, write_through=True)
    sys.stdin, sys.stdout, sys.stderr = stdin, stdout, err
    try:
        yield out, err
    finally:
        sys.stdin, sys.stdout, sys.stderr = saved
        stdout.flush()
        stdout.detach()  # keep `out` open: the wrapper would close it when collected
        stdin.detach()


def _invoke(name: str, argv: Sequence[str], data, messages: list[str], commands: Commands):
    """Run command ``name`` on ``argv`` with ``data`` as its standard input
    (bytes, or a Document handed over by the previous command).

    Returns what it wrote on standard output (the Document it handed over,
    if it did); what it wrote on standard error is appended to
    ``messages``.  Its exceptions propagate unchanged.
    """
    command = _command(name, commands)
    with _stdio(data) as (out, err):
        try:
            with command.make_context(name, list(argv)) as ctx:
                command.invoke(ctx)
        finally:
            messages.extend(line for line in err.getvalue().splitlines() if line.strip())
    return out.document if out.document is not None else out.getvalue()


def parse_steps(text: str | None, commands: Commands) -> list[Step]:
    """Parse and check ``'cmd opts|cmd opts|...'`` before any file is read.

    Every step is parsed by its own click command and run up to the point
    where it reads its input (here empty), so that a bad option or value
    fails now, once, instead of on every file.

    Raises
    ------
    UsageError
        One line naming the step: an unknown or unsuitable command, a FILE or
        ``-o`` in the step, or an option the command refuses.
    """
    import click

    steps: list[Step] = []
    if text is None or not text.strip():
        return steps
    for i, part in enumerate(text.split("|"), start=1):
        part = part.strip()
        where = f"--steps: step {i} ({part!r})" if part else f"--steps: step {i}"
        try:
            words = shlex.split(part)
        except ValueError as err:
            raise UsageError(f"{where}: {err}") from None
        if not words:
            raise UsageError(f"{where}: empty step (two '|' in a row, or a '|' at an end)")
        name, args = words[0], tuple(words[1:])
        if name not in STEP_COMMANDS:
            if name in ("extract", "bake"):
                what = f"{name!r} is not a step: extract and bake are implied"
            elif name in commands:
                what = f"{name!r} does not turn a document into a document"
            else:
                what = f"unknown command {name!r}"
            raise UsageError(f"{where}: {what} (steps: {', '.join(STEP_COMMANDS)})")
        if name == "layer" and "--list" in args:
            raise UsageError(f"{where}: 'layer --list' does not turn a document into a document")
        if any(a.startswith(("-o", "--output")) for a in args):
            raise UsageError(f"{where}: a step takes no -o: the batch passes each step's output to the next")
        command = _command(name, commands)
        try:
            # a FILE here would be read instead of the previous stage's output
            probe = command.make_context(name, list(args), resilient_parsing=True)
            given = probe.params.get("input_path")
        except click.exceptions.ClickException:
            given = None  # the full parse below reports it
        if given is not None:
            raise UsageError(f"{where}: a step takes no FILE: the batch feeds it the previous stage's output")
        step = Step(name, args, part)
        try:
            _invoke(name, step.argv(), b"", [], commands)
        except DataError:
            pass  # the options passed; the (empty) input did not: as expected
        except click.exceptions.Exit:
            raise UsageError(f"{where}: not a step (for help: staggered {name} --help)") from None
        except click.exceptions.ClickException as err:
            raise UsageError(f"{where}: {_one_line(err.format_message())}") from None
        except StaggeredError as err:
            raise UsageError(f"{where}: {_one_line(err.message)}") from None
        steps.append(step)
    return steps


def find_inputs(in_dir: str) -> list[str]:
    """Paths, relative to ``in_dir`` and sorted, of the BVH and C3D files under it.

    Regular files and links to files, at any depth; links to folders are not
    followed (as ``find -xtype f``).
    """
    found: list[str] = []
    for root, dirs, names in os.walk(in_dir):
        dirs.sort()
        for name in names:
            path = os.path.join(root, name)
            if name.lower().endswith(EXTENSIONS) and os.path.isfile(path):
                found.append(os.path.relpath(path, in_dir))
    return sorted(found)


def _stale(src: str, dst: str) -> bool:
    """make's rule: rebuild when the output is missing or older than the input."""
    try:
        return os.stat(dst).st_mtime_ns < os.stat(src).st_mtime_ns
    except FileNotFoundError:
        return True


def _inside(path: str, folder: str) -> bool:
    path, folder = os.path.realpath(path), os.path.realpath(folder)
    return path == folder or path.startswith(folder.rstrip(os.sep) + os.sep)


def parse_shard(text: str) -> tuple[int, int]:
    """``"I/N"`` -> ``(I, N)``: the I-th of N parts, numbered from 1 (``1/8`` to
    ``8/8``), as ``sbatch --array=1-8`` numbers its tasks.  Raises ``UsageError``."""
    index, slash, count = (part.strip() for part in text.partition("/"))
    if not (slash and _digits(index) and _digits(count)):
        raise UsageError(f"--shard {text[:40]!r}: expected I/N, e.g. 3/8 for the 3rd of 8 parts")
    index, count = int(index), int(count)
    if count < 1:
        raise UsageError(f"--shard {text[:40]!r}: N (the number of parts) must be at least 1")
    if not 1 <= index <= count:
        raise UsageError(f"--shard {text[:40]!r}: I must be between 1 and {count} (parts are numbered from 1)")
    return index, count


def _digits(text: str) -> bool:
    return 0 < len(text) <= 9 and text.isascii() and text.isdigit()


def shard_of(rel: str, count: int) -> int:
    """The part (1 to ``count``) that the input at ``rel`` (relative to the
    input folder) belongs to: a hash of the path with ``/`` separators, so
    that every machine splits a library the same way, whatever the order its
    file system lists the files in, and adding a file moves no other."""
    import hashlib

    key = rel.replace(os.sep, "/").encode("utf-8", "surrogateescape")
    return int.from_bytes(hashlib.sha256(key).digest()[:8], "big") % count + 1


def plan(
    in_dir: str, out_dir: str, force: bool = False, shard: tuple[int, int] | None = None
) -> tuple[list[Job], list[Result]]:
    """The files to build and the ones already up to date; with ``shard``
    ``(I, N)`` only those of the I-th of N parts (:func:`shard_of`).

    Raises ``UsageError`` when ``in_dir`` is not a folder or ``out_dir`` lies
    inside it (the outputs would become inputs of the next run).
    """
    if not os.path.isdir(in_dir):
        raise UsageError("is not a folder", source=in_dir)
    if _inside(out_dir, in_dir):
        raise UsageError(f"the output folder {out_dir!r} must not be inside the input folder", source=in_dir)
    if os.path.exists(out_dir) and not os.path.isdir(out_dir):
        raise UsageError("output is not a folder", source=out_dir)
    todo: list[Job] = []
    skipped: list[Result] = []
    for rel in find_inputs(in_dir):
        if shard is not None and shard_of(rel, shard[1]) != shard[0]:
            continue
        job = Job(rel, os.path.join(in_dir, rel), os.path.join(out_dir, rel))
        if force or _stale(job.src, job.dst):
            todo.append(job)
        else:
            skipped.append(Result(rel, SKIPPED))
    return todo, skipped


def _reason(stage: str, err: BaseException, job: Job) -> str:
    """One line: the stage and what went wrong (the file is named by the table)."""
    import click

    if isinstance(err, StaggeredError):
        from .errors import cli_text

        ours = err.source in _STDIO_NAMES or err.source in (job.src, job.dst)
        text = cli_text(err.message) if ours else err.cli_message()
    elif isinstance(err, click.exceptions.ClickException):
        text = err.format_message()
    else:
        text = f"internal error: {type(err).__name__}: {err}"
    return f"{stage}: {_one_line(text)}"


def run_file(job: Job, steps: Sequence[Step], commands: Commands) -> Result:
    """Extract, apply ``steps`` and bake one file; never raises for a bad file."""
    start = time.perf_counter()
    messages: list[str] = []
    stage = "extract"
    try:
        data = _invoke("extract", ["-o", "-", "--", job.src], b"", messages, commands)
        for step in steps:
            stage = step.name
            data = _invoke(step.name, step.argv(), data, messages, commands)
        stage = "bake"
        os.makedirs(os.path.dirname(job.dst) or ".", exist_ok=True)
        _invoke("bake", ["--force", "-o", job.dst, "-"], data, messages, commands)
    except Exception as err:  # one file's failure, whatever it is, is reported and the batch goes on
        _remove_stale(job.dst)
        return Result(job.rel, FAILED, time.perf_counter() - start, _reason(stage, err, job), tuple(messages))
    return Result(job.rel, DONE, time.perf_counter() - start, "", tuple(messages))


def _remove_stale(path: str) -> None:
    try:
        os.unlink(path)
    except OSError:
        pass  # nothing there (the usual case), or not removable: the failure itself is what gets reported


#: Test hook, read by batch workers only: ``NAME=HOW[;NAME=HOW...]`` makes the
#: worker that draws the file named NAME (its path under IN_DIR, or its base
#: name) die before it reads it, the way a crash in a native library would:
#: HOW is ``exit`` (``os._exit(3)``), ``segv`` (a real segmentation fault),
#: ``kill`` (SIGKILL, as the out-of-memory killer sends), ``hang`` (sleeps
#: until killed) or ``hang-writing`` (sleeps in the write of its output).
#: The tests use it to check that a dead worker fails its file only; nothing
#: else sets it.
FAULT_ENV = "STAGGERED_TEST_WORKER_FAULT"

#: Seconds a worker is given to end (and remove its temporary file) after
#: SIGTERM before it is killed.
_GRACE = 3.0


def _inject_fault(rel: str) -> None:
    spec = os.environ.get(FAULT_ENV, "")
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


def _worker_main(conn, parent_pid: int, level: int, commands: Commands) -> None:
    """A worker process: run the jobs sent on ``conn`` one by one, send back each Result."""
    import signal
    import threading

    _die_with_parent(parent_pid)
    # Ctrl-C reaches the whole process group: the parent handles it and ends
    # the workers.  SIGTERM (from the parent) unwinds, so that a bake's
    # temporary file is removed.
    signal.signal(signal.SIGINT, signal.SIG_IGN)

    def unwind(signum, frame):
        # a worker that cannot unwind in time (stuck in native code) is ended
        threading.Timer(_GRACE, os._exit, (1,)).start()
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, unwind)
    from .cli.heap import reuse_freed_memory
    from .cli.log import configure_logging, log

    reuse_freed_memory()
    configure_logging(0, 0)
    log.setLevel(level)
    try:
        while True:
            try:
                msg = conn.recv()
            except (EOFError, OSError):
                return  # the parent is gone
            if msg is None:
                return
            job, steps = msg
            _inject_fault(job.rel)
            conn.send(run_file(job, steps, commands))
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

    def __init__(self, ctx, level: int, commands: Commands):
        self.conn, child = ctx.Pipe()
        self.proc = ctx.Process(target=_worker_main, args=(child, os.getpid(), level, dict(commands)), daemon=True)
        self.proc.start()
        child.close()
        self.job: Job | None = None
        self.start = 0.0

    def run(self, job: Job, steps: tuple[Step, ...]) -> None:
        self.job, self.start = job, time.perf_counter()
        try:
            self.conn.send((job, steps))
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


def run_batch(
    jobs: Sequence[Job],
    steps: Sequence[Step],
    workers: int,
    commands: Commands,
    on_result: Callable[[Result], None] | None = None,
) -> list[Result]:
    """Process ``jobs`` with ``workers`` processes (at least one, even for
    one job: a crash in native code then fails one file, not the batch).

    The largest files are started first, so that the last worker to finish
    is not the one that drew the longest clip at the end.  A worker that
    dies (a segmentation fault, the out-of-memory killer) fails the file it
    was running with a one-line reason, and a new worker takes its place.
    ``commands`` is the table the steps' names are looked up in;
    ``on_result`` is called in this process as each file finishes.
    """
    import logging
    import multiprocessing
    from collections import deque
    from multiprocessing.connection import wait

    order = deque(sorted(jobs, key=lambda j: -_size(j.src)))
    results: list[Result] = []
    if not order:
        return results
    frozen = tuple(steps)

    def done(result: Result) -> None:
        results.append(result)
        if on_result is not None:
            on_result(result)

    level = logging.getLogger("staggered_cli").getEffectiveLevel()
    # spawn: no fork of a process that may run threads (the progress bar's monitor)
    ctx = multiprocessing.get_context("spawn")
    pool: list[_Worker] = []
    try:
        for _ in range(max(1, min(workers, len(order)))):
            w = _Worker(ctx, level, commands)
            pool.append(w)
            w.run(order.popleft(), frozen)
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
                    _remove_stale(job.dst)
                    from .io.files import remove_stale_temporaries

                    remove_stale_temporaries(job.dst)
                    done(Result(job.rel, FAILED, time.perf_counter() - w.start, _death(w.proc.exitcode)))
                    w = pool[i] = _Worker(ctx, level, commands) if order else w
                    w.job = None
                if order and w.job is None and w.proc.is_alive():
                    w.run(order.popleft(), frozen)
    except BaseException:
        _end_all(pool)
        raise
    for w in pool:
        if w.proc.is_alive():
            w.stop()
    return results


def _size(path: str) -> int:
    try:
        return os.path.getsize(path)
    except OSError:
        return 0


def summary_table(results: Sequence[Result]) -> list[str]:
    """The lines of the summary: one row per file (sorted by path)."""
    rows = [("file", "status", "seconds", "reason")]
    for r in sorted(results, key=lambda r: r.rel):
        rows.append((r.rel, r.status, "-" if r.seconds is None else f"{r.seconds:.2f}", r.reason))
    w0 = max(len(r[0]) for r in rows)
    w1 = max(len(r[1]) for r in rows)
    w2 = max(len(r[2]) for r in rows)
    return [f"{a:<{w0}}  {b:<{w1}}  {c:>{w2}}  {d}".rstrip() for a, b, c, d in rows]


def counts(results: Sequence[Result]) -> dict[str, int]:
    out = {DONE: 0, SKIPPED: 0, FAILED: 0}
    for r in results:
        out[r.status] = out.get(r.status, 0) + 1
    return out
