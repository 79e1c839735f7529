"""Raw bytes in and out: the only place that opens paths, stdin and stdout.

Everything above this module works on ``bytes`` plus a display name, so that
``-`` (stdin / stdout) and real paths behave the same, and so that every
error names the file it is about.
"""

from __future__ import annotations

import errno
import os
import stat
import sys

from ..errors import DataError, StaggeredError, UsageError, arg

STDIO = "-"
STDIN_NAME = "<stdin>"
STDOUT_NAME = "<stdout>"

#: Largest input read, in bytes (2 GiB): bigger files are refused before reading.
MAX_INPUT_BYTES = 2 << 30

_CHUNK = 1 << 20


def display_name(path: str) -> str:
    """How ``path`` is named in messages (``-`` becomes ``<stdin>``)."""
    return STDIN_NAME if path == STDIO else str(path)


def _too_big(size: int, limit: int) -> str:
    return f"input is {size:,} bytes, more than the limit of {limit:,} bytes"


def _read_stream(stream, limit: int, name: str, probe=None, probe_bytes: int = 0) -> bytes:
    """Read ``stream`` to its end, refusing more than ``limit`` bytes; call
    ``probe(head)`` once the first ``probe_bytes`` bytes are in."""
    chunks: list[bytes] = []
    total = 0
    while True:
        chunk = stream.read(min(_CHUNK, limit + 1 - total))
        if not chunk:
            break
        chunks.append(chunk)
        total += len(chunk)
        if total > limit:
            raise DataError(f"input is more than the limit of {limit:,} bytes", source=name)
        if probe is not None and total >= probe_bytes:
            chunks = [b"".join(chunks)]
            try:
                probe(chunks[0])
            except StaggeredError as err:
                raise err.with_source(name) from None
            probe = None
    return b"".join(chunks)


def _os_reason(err: OSError) -> str:
    if isinstance(err, FileNotFoundError):
        return "no such file"
    if isinstance(err, IsADirectoryError):
        return "is a directory, not a file"
    if isinstance(err, PermissionError):
        return "permission denied"
    if isinstance(err, NotADirectoryError):
        return "a component of the path is not a directory"
    return err.strerror or type(err).__name__


_ZIP_MAGIC = b"PK\x03\x04"


def open_zip(path: str, limit: int = MAX_INPUT_BYTES):
    """An open binary file of ``path`` when it is a regular file of at most
    ``limit`` bytes that begins like a zip (an NPZ document), to be read in
    place rather than copied into memory whole; else None (then read it with
    :func:`read_bytes`, which names what is wrong)."""
    if path == STDIO:
        return None
    try:
        f = open(path, "rb")
    except OSError:
        return None
    try:
        st = os.fstat(f.fileno())
        if stat.S_ISREG(st.st_mode) and st.st_size <= limit and f.read(4) == _ZIP_MAGIC:
            f.seek(0)
            return f
    except OSError:
        pass
    f.close()
    return None


def read_bytes(path: str, limit: int = MAX_INPUT_BYTES, probe=None, probe_bytes: int = 0) -> tuple[bytes, str]:
    """The whole content of ``path`` and the name to show for it.

    Parameters
    ----------
    path : str
        A file path, or ``-`` for standard input (named ``<stdin>``).
    limit : int
        Largest size accepted, in bytes.  A regular file larger than this is
        refused before anything is read; a stream is refused as soon as it
        passes it.
    probe : callable, optional
        ``probe(head)`` is called once with the first ``probe_bytes`` bytes
        of an input longer than that, before the rest is read: it may raise
        a ``StaggeredError`` to refuse the input without reading it all (a
        BVH header longer than any real one, say).

    Raises
    ------
    DataError
        Missing, unreadable, a directory, or too large; the error names the path.
    UsageError
        ``-`` while standard input is a terminal (nothing was piped in).
    """
    name = display_name(path)
    if path == STDIO:
        stdin = sys.stdin
        if stdin is None:
            raise UsageError("no standard input to read from", source=name)
        if stdin.isatty():
            raise UsageError("standard input is a terminal: pipe data in or give a FILE", source=name)
        return _read_stream(getattr(stdin, "buffer", stdin), limit, name, probe, probe_bytes), name
    try:
        st = os.stat(path)
        if stat.S_ISDIR(st.st_mode):
            raise IsADirectoryError(errno.EISDIR, "is a directory", path)
        if stat.S_ISREG(st.st_mode) and st.st_size > limit:
            raise DataError(_too_big(st.st_size, limit), source=name)
        with open(path, "rb") as f:
            if stat.S_ISREG(st.st_mode):
                if probe is not None and st.st_size >= probe_bytes:
                    try:  # the head alone first: a file to refuse is not read to its end
                        probe(os.pread(f.fileno(), probe_bytes, 0))
                    except StaggeredError as err:
                        raise err.with_source(name) from None
                # then one read into one buffer of the file's size: no chunks to join
                data = f.read()
                if len(data) > limit:  # it grew since the stat
                    raise DataError(_too_big(len(data), limit), source=name)
                return data, name
            # not only regular files: FIFOs and process substitution too
            return _read_stream(f, limit, name, probe, probe_bytes), name
    except OSError as err:
        raise DataError(f"cannot read: {_os_reason(err)}", source=name) from err


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _is_stream(path: str) -> bool:
    """An existing FIFO or device (``/dev/null``, ``/dev/stdout``, a process
    substitution): written in place, since it cannot be replaced by a rename
    and overwriting it clobbers nothing."""
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return False
    return stat.S_ISFIFO(mode) or stat.S_ISCHR(mode) or stat.S_ISSOCK(mode)


def check_output(path: str, force: bool) -> None:
    """Refuse early, before any work, an output that cannot be written.

    ``UsageError`` when ``path`` exists and ``force`` is false, when it is a
    directory, or when its directory does not exist.  ``-`` always passes.
    """
    if path == STDIO or _is_stream(path):
        return
    if os.path.isdir(path):
        raise UsageError("output is a directory", source=path)
    if os.path.lexists(path) and not force:
        raise UsageError(f"output exists (use {arg('force')} to overwrite it)", source=path)
    parent = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(parent):
        above = parent  # the nearest existing folder above, or the file in the way
        while not os.path.exists(above) and os.path.dirname(above) != above:
            above = os.path.dirname(above)
        if os.path.exists(above) and not os.path.isdir(above):
            shown = os.path.relpath(above) if not os.path.isabs(path) else above
            raise UsageError(f"{shown!r} is a file, not a directory", source=path)
        raise UsageError(f"output directory {os.path.dirname(path) or parent!r} does not exist", source=path)


def _pieces(data) -> list:
    """``data`` (bytes-like, or a list of bytes-like pieces) as a list of pieces."""
    return list(data) if isinstance(data, list | tuple) else [data]


def _write_pieces(f, data) -> None:
    for piece in _pieces(data):
        f.write(piece)


def write_stdout(data) -> None:
    """Write ``data`` (bytes, or a list of bytes-like pieces written one
    after the other) to standard output as bytes and flush.

    A real file descriptor is written with ``os.write`` until every byte is
    out: a reader that goes away mid-way (``| head -1``) then raises
    ``BrokenPipeError`` (exit 141) instead of a short write passing unseen.
    """
    out = sys.stdout
    if out is None:
        raise StaggeredError("standard output is closed: nothing can be written to it", source=STDOUT_NAME)
    buf = getattr(out, "buffer", None)
    if buf is None:  # a text-only replacement of stdout
        out.write(b"".join(_pieces(data)).decode("utf-8", errors="surrogateescape"))
        out.flush()
        return
    out.flush()  # keep order with text already written
    try:
        fd = buf.fileno()
    except (OSError, ValueError, AttributeError):
        fd = None  # in memory (tests, batch stages)
    if fd is None:
        _write_pieces(buf, data)
        buf.flush()
    else:
        buf.flush()
        for piece in _pieces(data):
            view = memoryview(piece).cast("B")
            while view:
                view = view[os.write(fd, view[: 1 << 20]) :]
    out.flush()


def write_atomic(path: str, data, force: bool) -> None:
    """Write ``data`` (bytes, or a list of bytes-like pieces written one after
    the other) to ``path`` so that it is either complete or not there.

    The bytes go to a temporary file in the same directory, are flushed and
    fsync'd, then renamed over ``path``.  Without ``force`` an existing
    ``path`` is refused (``UsageError``), atomically: the final step is a hard
    link that fails if the name was taken meanwhile.  ``-`` writes to
    standard output; an existing FIFO or device is written in place.  On any failure the temporary file is removed and
    ``path`` is left as it was.
    """
    if path == STDIO:
        write_stdout(data)
        return
    if _is_stream(path):
        try:
            with open(path, "wb") as f:
                _write_pieces(f, data)
        except OSError as err:
            raise StaggeredError(f"cannot write: {_os_reason(err)}", source=path) from err
        return
    check_output(path, force)
    directory = os.path.dirname(os.path.abspath(path))
    remove_stale_temporaries(path)
    try:
        fd, tmp = _create_temporary(path)
    except OSError as err:
        raise StaggeredError(f"cannot write: {_os_reason(err)}", source=path) from err
    try:
        with os.fdopen(fd, "wb") as f:
            _write_pieces(f, data)
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, 0o666 & ~_umask())
        if force:
            os.replace(tmp, path)
        else:
            try:
                os.link(tmp, path)
            except FileExistsError:
                raise UsageError(f"output exists (use {arg('force')} to overwrite it)", source=path) from None
            except OSError:  # a filesystem without hard links
                if os.path.lexists(path):
                    raise UsageError(f"output exists (use {arg('force')} to overwrite it)", source=path) from None
                os.replace(tmp, path)
        _fsync_directory(directory)
    except OSError as err:
        raise StaggeredError(f"cannot write: {_os_reason(err)}", source=path) from err
    finally:
        if os.path.lexists(tmp):
            try:
                os.unlink(tmp)
            except OSError:
                pass  # the rename or link succeeded; nothing else to clean up


_TEMP_TAG = ".staggered-"


def _temporary_name(path: str, pid: int) -> str:
    """``DIR/.NAME.staggered-PID.tmp``: one name per output and process, so
    that a later run can tell a leftover of a killed run from a live one."""
    directory, base = os.path.split(os.path.abspath(path))
    return os.path.join(directory, f".{base}{_TEMP_TAG}{pid}.tmp")


def _create_temporary(path: str) -> tuple[int, str]:
    tmp = _temporary_name(path, os.getpid())
    for _ in range(2):
        try:
            return os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600), tmp
        except FileExistsError:
            # left by an earlier, dead process that had our pid (this process
            # writes one output at a time)
            os.unlink(tmp)
    return os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600), tmp


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True  # someone else's process
    except OSError:
        return True  # cannot tell: keep its file
    return True


def remove_stale_temporaries(path: str) -> list[str]:
    """Remove the temporary files of ``path`` left by writers that were killed
    (SIGKILL, power loss) before they could clean up: those whose pid is no
    longer running.  Returns the names removed."""
    directory, base = os.path.split(os.path.abspath(path))
    prefix = f".{base}{_TEMP_TAG}"
    removed = []
    try:
        names = [n for n in os.listdir(directory) if n.startswith(prefix) and n.endswith(".tmp")]
    except OSError:
        return removed
    for n in names:
        pid = n[len(prefix) : -len(".tmp")]
        if not pid.isascii() or not pid.isdigit() or int(pid) == os.getpid() or _alive(int(pid)):
            continue
        try:
            os.unlink(os.path.join(directory, n))
            removed.append(n)
        except OSError:
            pass  # removed meanwhile, or not ours to remove
    return removed


def _fsync_directory(directory: str) -> None:
    """Make the rename durable; not every platform can open a directory."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass  # some filesystems refuse fsync on a directory; the data itself is synced
    finally:
        os.close(fd)


def find_files(folder: str, extensions: tuple[str, ...]) -> list[str]:
    """Paths, relative to ``folder`` and sorted, of the files under it whose
    name ends (in any case) with one of ``extensions``.

    Regular files and links to files, at any depth; links to folders are not
    followed (as ``find -xtype f``).
    """
    found: list[str] = []
    for root, dirs, names in os.walk(folder):
        dirs.sort()
        for name in names:
            path = os.path.join(root, name)
            if name.lower().endswith(extensions) and os.path.isfile(path):
                found.append(os.path.relpath(path, folder))
    return sorted(found)


def same_bytes(path: str, data: bytes) -> bool:
    """Whether the file at ``path`` holds exactly ``data`` (non-empty)."""
    if not data or os.path.getsize(path) != len(data):
        return False
    with open(path, "rb") as fh:
        return fh.read() == data


def remove_quietly(path: str) -> None:
    """Remove ``path`` if it is there and can be removed (an output left from
    an earlier run that no longer matches its input); nothing else."""
    try:
        os.unlink(path)
    except OSError:
        pass  # nothing there (the usual case), or not removable: the failure itself is what gets reported


def make_parent(path: str) -> None:
    """Make the folder ``path`` goes into, with the folders above it."""
    os.makedirs(os.path.dirname(path) or ".", exist_ok=True)
