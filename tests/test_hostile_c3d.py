"""Hostile C3D files (issue 18, the C3D half): ezc3d never takes the process down.

Every file here is a real one from ../shared/mocap (or the bundled sample)
with one parameter or one byte changed, rebuilt by ``tests/fuzz/mutate.py``
(``c3d_set_parameter`` rewrites the parameter section record by record, so
only the parameter itself is hostile).  The classes:

* empty arrays in the parameters ezc3d reads as one number (a segfault),
  other type codes, and the checks of every parameter ezc3d reads;
* a crash, a hang (a name-length byte of 0x80 makes ezc3d spin, deaf to
  Ctrl-C) or a runaway allocation inside ezc3d: one line, exit 1, no copy of
  the input left in the temp folder, no child process left behind;
* documents whose embedded source C3D is such a file;
* C3D files written with exit 0 that nothing could read back;
* "internal error" cases that must be one-line errors;
* marker labels shared by several markers.

Cases that would crash ezc3d run in a forked child (``in_child``), so that a
regression fails the test instead of killing pytest.
"""

from __future__ import annotations

import hashlib
import os
import signal
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from staggered_cli.cli.main import cli
from staggered_cli.errors import DataError
from staggered_cli.io import c3d as io_c3d
from staggered_cli.io.container import document_bytes, parse_document
from staggered_cli.io.isolate import ChildFailed, run_isolated

from .conftest import SAMPLES, mocap, one_line_error
from .fuzz import mutate as mu

EB015PI = "c3dorg_sample01_Eb015pi_walk.c3d"
CMU = "cmu_85_12_breakdance_long.c3d"
BTS = "ezc3d_BTS_walk_gaps.c3d"
#: Seconds a refused hostile file may take, whole command.
FAST = 5.0
#: The one line for a crash, hang or runaway allocation of ezc3d.
READER_FAILED = "the C3D reader failed on this file (malformed parameters?)"
WRITER_FAILED = "the C3D writer failed on the motion's source C3D (malformed parameters?)"
REPO = Path(__file__).resolve().parents[1]


@pytest.fixture
def scratch(monkeypatch):
    """A private temporary folder, also the process's temp folder for the
    test: it must be empty at the end (nothing left in the temp folder)."""
    with tempfile.TemporaryDirectory(prefix="hostile-") as d:
        work = Path(d) / "work"
        tmp = Path(d) / "tmp"
        work.mkdir()
        tmp.mkdir()
        monkeypatch.setattr(tempfile, "tempdir", str(tmp))
        yield work
        left = sorted(os.listdir(tmp))
        assert not left, f"left in the temp folder: {left}"


def run(*args, stdin: bytes | None = None):
    start = time.perf_counter()
    result = CliRunner().invoke(cli, [str(a) for a in args], input=stdin)
    return result, time.perf_counter() - start


def refused(result, elapsed: float, code: int, *needles: str) -> None:
    one_line_error(result, code, *needles)
    assert "internal error" not in result.stderr, result.stderr
    assert elapsed < FAST, f"took {elapsed:.1f} s"


def in_child(fn, seconds: float = 60.0):
    """``fn()`` in a forked child: a crash fails the test, not pytest."""
    try:
        return run_isolated(fn, memory=4 << 30, seconds=seconds)
    except ChildFailed as exc:
        pytest.fail(f"the test's child process {exc.why}")


def empty(raw: bytes, key: str) -> bytes:
    """``raw`` with parameter ``key`` holding no value (dimensions (0,))."""
    return mu.c3d_set_parameter(raw, key, dims=(0,), values=b"")


def retyped(raw: bytes, key: str, ptype: int) -> bytes:
    """``raw`` with parameter ``key`` given type code ``ptype``, same bytes where they fit."""
    _, dims, values = mu.c3d_parameter(raw, key)
    count = int(np.prod(dims)) if dims else 1
    size = count * mu.TYPE_BYTES[ptype]
    values = (values * (1 + size // max(len(values), 1)))[:size]
    if ptype == -1 and not dims:
        dims = (size,)
    return mu.c3d_set_parameter(raw, key, ptype=ptype, dims=dims, values=values)


def with_value(raw: bytes, key: str, value: float) -> bytes:
    ptype, _, values = mu.c3d_parameter(raw, key)
    return mu.c3d_set_parameter(raw, key, values=mu.encode_values(ptype, [value]) + values[mu.TYPE_BYTES[ptype] :])


def hanging() -> tuple[bytes, bytes]:
    """(the CMU capture, the same with the name-length byte of its
    SUBJECTS:NAMES record set to 0x80).  Read with a 128-byte name, the
    record runs on into the next ones and ezc3d 1.7.2 takes a byte of them
    for 72 dimensions, one of them 0: it loops over the others forever,
    without allocating, deaf to Ctrl-C."""
    path = mocap(CMU)
    raw = path.read_bytes()
    data = bytearray(raw)
    data[mu.c3d_base(path).parameters["SUBJECTS:NAMES"][0]] = 0x80
    return raw, bytes(data)


# --------------------------------------------------------------------------- empty arrays: a segfault in ezc3d

#: (file, parameter): each held one value; ezc3d indexes [0] of the empty array.
EMPTY = [
    (EB015PI, "POINT:USED"),
    (EB015PI, "POINT:FRAMES"),
    (EB015PI, "POINT:SCALE"),
    (EB015PI, "POINT:RATE"),
    (EB015PI, "ANALOG:GEN_SCALE"),
    (EB015PI, "ANALOG:USED"),
    (EB015PI, "ANALOG:RATE"),
    (CMU, "POINT:USED"),
    (CMU, "POINT:SCALE"),
    (BTS, "POINT:RATE"),
    (BTS, "ANALOG:GEN_SCALE"),
    (BTS, "POINT:FRAMES"),
]


@pytest.mark.parametrize(("name", "key"), EMPTY)
def test_an_empty_parameter_ezc3d_reads_is_refused_before_ezc3d(scratch, name, key):
    bad = scratch / "empty.c3d"
    bad.write_bytes(empty(mocap(name).read_bytes(), key))

    def check():
        out = []
        for args in (["info", bad], ["extract", bad, "-o", scratch / "x.stag"]):
            result, elapsed = run(*args)
            out.append((result.exit_code, result.stderr, elapsed))
        return out

    for code, stderr, elapsed in in_child(check):
        assert code == 1, stderr
        assert stderr == f"staggered: {bad}: corrupt C3D: parameter {key} holds no value (at least 1 expected)\n"
        assert elapsed < FAST
    assert sorted(os.listdir(scratch)) == ["empty.c3d"]


@pytest.mark.parametrize(("name", "key"), EMPTY[:5] + EMPTY[-3:])
def test_a_segfault_in_ezc3d_is_one_line(scratch, monkeypatch, name, key):
    """With the pre-check switched off, ezc3d gets the file and crashes in
    the child: the command still ends with one line, exit 1."""
    monkeypatch.setattr(io_c3d, "_check_read_as", lambda *a: None)
    bad = scratch / "empty.c3d"
    bad.write_bytes(empty(mocap(name).read_bytes(), key))

    def check():
        result, elapsed = run("extract", bad, "-o", scratch / "x.stag")
        return result.exit_code, result.stderr, elapsed

    code, stderr, elapsed = in_child(check)
    assert (code, stderr) == (1, f"staggered: {bad}: {READER_FAILED}\n")
    assert elapsed < FAST
    assert sorted(os.listdir(scratch)) == ["empty.c3d"]


# --------------------------------------------------------------------------- types of the parameters ezc3d reads

#: (file, parameter, new type code, what the message says it should be)
RETYPED = [
    (SAMPLES / "march.c3d", "POINT:UNITS", 1, "char"),  # internal error (numpy truth value) before
    (SAMPLES / "march.c3d", "POINT:LABELS", 1, "char"),  # internal error (unhashable ndarray) before
    (SAMPLES / "march.c3d", "POINT:LABELS", 2, "char"),
    (SAMPLES / "march.c3d", "POINT:DESCRIPTIONS", 4, "char"),  # a C++ overload message of 300 characters
    (EB015PI, "POINT:UNITS", 2, "char"),
    (EB015PI, "ANALOG:SCALE", 2, "float"),
    (EB015PI, "ANALOG:OFFSET", 4, "int or byte"),
    (EB015PI, "ANALOG:LABELS", 1, "char"),
    (CMU, "TRIAL:ACTUAL_END_FIELD", -1, "int or byte"),  # internal error in bake before
    (CMU, "TRIAL:ACTUAL_START_FIELD", 4, "int or byte"),
    (BTS, "POINT:RATE", 2, "float"),
    (BTS, "POINT:USED", 4, "int or byte"),
]
_TYPE = {-1: "char", 1: "byte", 2: "int", 4: "float"}


@pytest.mark.parametrize(("name", "key", "ptype", "expected"), RETYPED)
def test_a_parameter_of_another_type_is_one_line(scratch, name, key, ptype, expected):
    path = name if isinstance(name, Path) else mocap(name)
    bad = scratch / "typed.c3d"
    bad.write_bytes(retyped(path.read_bytes(), key, ptype))
    doc = scratch / "x.stag"

    def check():
        return [(r.exit_code, r.stderr, t) for r, t in (run("info", bad), run("extract", bad, "-o", doc))]

    for code, stderr, elapsed in in_child(check):
        assert code == 1, stderr
        assert stderr == (
            f"staggered: {bad}: unsupported C3D: parameter {key} is of type {_TYPE[ptype]}, readers expect {expected}\n"
        )
        assert elapsed < FAST
    assert not doc.exists()


def test_every_parameter_ezc3d_reads_is_checked_on_every_file():
    """The matrix over the real files: every parameter ezc3d reads that the
    file holds, emptied and given each other type code, and every record's
    name-length byte set to 0x80.  Each is refused in one line (an empty
    array of a parameter read as an array, and int <-> byte, may be
    accepted), never a crash, a hang or a traceback."""
    tally = {"empty": 0, "type": 0, "name-length": 0, "accepted": 0}
    cases = []
    for path in [mocap(EB015PI), mocap(CMU), mocap(BTS), SAMPLES / "march.c3d"]:
        raw = path.read_bytes()
        base = mu.c3d_base(path)
        for key in mu._read_keys(base):
            ptype, _, _ = mu.c3d_parameter(raw, key)
            cases.append(("empty", key, empty(raw, key), key in mu.SCALAR_PARAMETERS))
            for t in (-1, 1, 2, 4):
                if t != ptype:
                    cases.append(("type", key, retyped(raw, key, t), {t, ptype} != {1, 2}))
        for key, (rec, _, _, _) in sorted(base.parameters.items()):
            data = bytearray(raw)
            data[rec] = 0x80
            cases.append(("name-length", key, bytes(data), False))

    def check_all():
        with tempfile.TemporaryDirectory() as d:
            bad = Path(d) / "bad.c3d"
            out = []
            for kind, key, data, strict in cases:
                bad.write_bytes(data)
                result, elapsed = run("info", bad)
                out.append((kind, key, strict, result.exit_code, result.stderr, elapsed))
            return out

    for kind, key, strict, code, stderr, elapsed in in_child(check_all, seconds=600):
        tally[kind] += 1
        assert "Traceback" not in stderr and "internal error" not in stderr, (kind, key, stderr)
        assert elapsed < FAST, (kind, key, elapsed)
        if code == 0:
            assert not strict, f"{kind} {key}: accepted"
            tally["accepted"] += 1
        else:
            assert code == 1, (kind, key, stderr)
            assert len(stderr.splitlines()) == 1 and "bad.c3d: " in stderr, (kind, key, stderr)
    print(f"parameter matrix: {tally}")
    assert tally["empty"] >= 40 and tally["type"] >= 120 and tally["name-length"] >= 120


# --------------------------------------------------------------------------- crashes, hangs, memory: the child


def test_a_hang_in_ezc3d_is_killed_at_the_deadline(scratch, monkeypatch):
    """The name-length byte 0x80 is refused by the pre-check; past it (switched
    off here), ezc3d spins forever and the child is killed at its deadline."""
    raw, data = hanging()
    bad = scratch / "hang.c3d"
    bad.write_bytes(data)
    result, elapsed = run("info", bad)
    refused(result, elapsed, 1, str(bad), "has 72 dimensions (C3D allows 1 to 7, 0 for a number)")

    real = io_c3d._check_layout
    monkeypatch.setattr(io_c3d, "_check_layout", lambda data, source: real(raw, source))
    monkeypatch.setattr(io_c3d, "CHILD_SECONDS", 1.0)
    monkeypatch.setattr(io_c3d, "CHILD_SECONDS_PER_MB", 0.0)
    result, elapsed = run("extract", bad, "-o", scratch / "x.stag")
    refused(result, elapsed, 1, f"staggered: {bad}: {READER_FAILED}")
    assert 1.0 <= elapsed < 3.0
    assert sorted(os.listdir(scratch)) == ["hang.c3d"]


_HANGING_RUN = """
import sys
from pathlib import Path
import staggered_cli.io.c3d as io_c3d
from staggered_cli.cli.main import cli
real = io_c3d._check_layout
good = Path({good!r}).read_bytes()
io_c3d._check_layout = lambda data, source: real(good, source)  # let the hostile file through
sys.argv = ["staggered", "extract", {bad!r}, "-o", {out!r}]
cli()  # {marker}
"""


def _processes_with(marker: str) -> list[int]:
    found = []
    for pid in os.listdir("/proc"):
        if pid.isdigit():
            try:
                cmdline = Path(f"/proc/{pid}/cmdline").read_bytes()
            except OSError:
                continue
            if marker.encode() in cmdline:
                found.append(int(pid))
    return found


def _hanging_process(scratch: Path, tmp: Path) -> tuple[subprocess.Popen, str, Path]:
    bad = scratch / "hang.c3d"
    bad.write_bytes(hanging()[1])
    marker = f"hostile-{os.getpid()}-{time.monotonic_ns()}"
    out = scratch / "x.stag"
    code = _HANGING_RUN.format(good=str(mocap(CMU)), bad=str(bad), out=str(out), marker=marker)
    env = dict(os.environ, TMPDIR=str(tmp))
    proc = subprocess.Popen(
        [sys.executable, "-c", textwrap.dedent(code)], env=env, stderr=subprocess.PIPE, cwd=REPO, text=True
    )
    # wait until the child (a fork: the same command line) is spinning in ezc3d
    deadline = time.monotonic() + 20
    while len(_processes_with(marker)) < 2 and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.05)
    assert len(_processes_with(marker)) == 2, "the read did not start"
    time.sleep(0.5)  # in ezc3d by now (the file is read in about 0.3 s)
    return proc, marker, out


@pytest.mark.skipif(not Path("/proc/self/cmdline").exists(), reason="finds processes through /proc")
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM, signal.SIGKILL])
def test_a_signal_during_a_hanging_read_ends_it_and_leaves_nothing(sig):
    """Ctrl-C (and SIGTERM, SIGKILL) of a command whose ezc3d read hangs ends
    both processes at once, and no copy of the input is left in the temp
    folder (ezc3d used to read a 0600 copy there)."""
    with tempfile.TemporaryDirectory(prefix="hostile-") as d:
        scratch, tmp = Path(d) / "work", Path(d) / "tmp"
        scratch.mkdir()
        tmp.mkdir()
        proc, marker, out = _hanging_process(scratch, tmp)
        assert os.listdir(tmp) == []  # not even while reading
        start = time.monotonic()
        proc.send_signal(sig)
        try:
            _, stderr = proc.communicate(timeout=5)
        finally:
            proc.kill()
        assert time.monotonic() - start < 3
        assert proc.returncode != 0
        if sig == signal.SIGINT:
            assert stderr.strip().endswith("staggered: interrupted"), stderr
        deadline = time.monotonic() + 3
        while _processes_with(marker) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert _processes_with(marker) == [], "the ezc3d child outlived its parent"
        assert os.listdir(tmp) == []
        assert not out.exists()


def test_the_child_reports_crashes_memory_and_exceptions():
    with pytest.raises(ChildFailed, match="killed by SIGSEGV"):
        run_isolated(lambda: os.kill(os.getpid(), signal.SIGSEGV), memory=1 << 30, seconds=10)
    with pytest.raises(ChildFailed, match="killed by SIGABRT"):
        run_isolated(os.abort, memory=1 << 30, seconds=10)
    # 2 GB more than allowed: refused inside the child, the parent is untouched
    with pytest.raises(ChildFailed, match="ran out of memory"):
        run_isolated(lambda: np.ones(1 << 28).sum(), memory=512 << 20, seconds=10)
    with pytest.raises(ChildFailed, match="no result after 0.5 s"):
        run_isolated(lambda: time.sleep(30), memory=1 << 30, seconds=0.5)
    # an error of the call comes back as it was raised, its file included
    with pytest.raises(DataError) as info:
        run_isolated(lambda: (_ for _ in ()).throw(DataError("bad parameter", "walk.c3d")), memory=1 << 30, seconds=10)
    assert str(info.value) == "walk.c3d: bad parameter"
    assert run_isolated(lambda: np.arange(5) * 2, memory=1 << 30, seconds=10).tolist() == [0, 2, 4, 6, 8]


def test_a_runaway_allocation_in_ezc3d_is_one_line(scratch, monkeypatch):
    """The bundled sample with the name-length byte of POINT:FRAMES set to
    0x80: past the pre-check (switched off here) ezc3d allocates without
    bound; under the child's memory limit that ends in a second, one line."""
    raw = (SAMPLES / "march.c3d").read_bytes()
    data = bytearray(raw)
    data[mu.c3d_base(SAMPLES / "march.c3d").parameters["POINT:FRAMES"][0]] = 0x80
    bad = scratch / "runaway.c3d"
    bad.write_bytes(bytes(data))
    result, elapsed = run("info", bad)
    refused(result, elapsed, 1, str(bad), "corrupt C3D: parameter record")

    real = io_c3d._check_layout
    monkeypatch.setattr(io_c3d, "_check_layout", lambda data, source: real(raw, source))
    monkeypatch.setattr(io_c3d, "CHILD_SECONDS", 30.0)  # so that the memory limit is what ends it
    result, elapsed = run("info", bad)
    refused(result, elapsed, 1, f"staggered: {bad}: {READER_FAILED}")


def test_the_guarded_reader_and_writer_give_what_ezc3d_gives(scratch):
    """Through the child, a round trip is what it was in-process: points within
    1e-3, the same gaps, the analogs kept."""
    import ezc3d

    for name in (EB015PI, CMU, BTS):
        path = mocap(name)
        motion = io_c3d.read_c3d(path)
        layout = io_c3d._check_layout(path.read_bytes(), name)
        direct = io_c3d._markers(path.read_bytes(), layout, name)
        np.testing.assert_array_equal(motion.points, direct.points)
        assert motion.labels == direct.labels and motion.rate == direct.rate and motion.source == path.read_bytes()
        out = scratch / "round.c3d"
        out.write_bytes(io_c3d.c3d_bytes(motion))
        back = io_c3d.read_c3d(out)
        np.testing.assert_array_equal(np.isnan(back.points), np.isnan(motion.points))
        np.testing.assert_allclose(back.points, motion.points, atol=1e-3, equal_nan=True)
        src, new = ezc3d.c3d(str(path))["data"]["analogs"], ezc3d.c3d(str(out))["data"]["analogs"]
        assert new.shape == src.shape
        if src.size:  # Eb015pi and BTS: 16 and 44 channels
            np.testing.assert_allclose(new, src, atol=1e-4 * np.abs(src).max())
        out.unlink()


# --------------------------------------------------------------------------- documents embedding such a C3D


@pytest.fixture(scope="module")
def eb_document():
    with tempfile.TemporaryDirectory() as d:
        doc = Path(d) / "eb.stag"
        result, _ = run("extract", mocap(EB015PI), "-o", doc)
        assert result.exit_code == 0, result.stderr
        yield doc.read_bytes()


def _document_with(doc: bytes, change) -> bytes:
    manifest, arrays = parse_document(doc, "doc")
    change(manifest, arrays)
    return document_bytes(manifest, arrays, "npz")


@pytest.mark.parametrize("key", ["POINT:SCALE", "ANALOG:GEN_SCALE", "POINT:USED"])
def test_a_document_embedding_an_empty_parameter_c3d_does_not_crash_bake(scratch, monkeypatch, eb_document, key):
    source = empty(mocap(EB015PI).read_bytes(), key)
    bad = scratch / "bad.stag"

    def embed(manifest, arrays):  # a consistent crafted document: its sha256 names the file it embeds
        arrays["source.c3d"] = np.frombuffer(source, np.uint8)
        manifest["source"]["sha256"] = hashlib.sha256(source).hexdigest()

    bad.write_bytes(_document_with(eb_document, embed))
    out = scratch / "out.c3d"

    def bake():
        result, elapsed = run("bake", bad, "-o", out)
        return result.exit_code, result.stderr, elapsed

    code, stderr, elapsed = in_child(bake)
    assert (
        code == 1
        and stderr
        == f"staggered: {bad}: source.c3d: corrupt C3D: parameter {key} holds no value (at least 1 expected)\n"
    )
    # past the checks (switched off), ezc3d crashes in the writer's child
    monkeypatch.setattr(io_c3d, "_check_read_as", lambda *a: None)
    code, stderr, elapsed = in_child(bake)
    assert (code, stderr) == (1, f"staggered: {bad}: {WRITER_FAILED}\n")
    assert elapsed < FAST and not out.exists()


def test_a_document_with_a_c3d_rate_of_zero_is_one_line(scratch, eb_document):
    for rate in (0.0, -50.0, 1e30):
        bad = scratch / "rate.stag"
        bad.write_bytes(_document_with(eb_document, lambda m, a, r=rate: m["c3d"].update(rate=r)))
        for args in (["info", bad], ["bake", bad, "-o", scratch / "out.c3d"]):
            result, elapsed = run(*args)
            refused(result, elapsed, 1, str(bad), f"c3d rate {rate:g} Hz is out of range", "1 Hz to 10000 Hz")


# --------------------------------------------------------------------------- never write what cannot be read back


def test_bake_of_a_c3d_with_two_data_start_values_reads_back(scratch):
    raw = (SAMPLES / "march.c3d").read_bytes()
    _, _, values = mu.c3d_parameter(raw, "POINT:DATA_START")
    src = scratch / "ds.c3d"
    src.write_bytes(mu.c3d_set_parameter(raw, "POINT:DATA_START", dims=(2,), values=values + values))
    doc, out = scratch / "ds.stag", scratch / "out.c3d"
    assert run("extract", src, "-o", doc)[0].exit_code == 0
    result, _ = run("bake", doc, "-o", out)
    assert result.exit_code == 0, result.stderr
    # it used to write a file whose DATA_START record overran the next one
    back, before = io_c3d.read_c3d(out), io_c3d.read_c3d(src)
    np.testing.assert_allclose(back.points, before.points, atol=1e-3, equal_nan=True)
    assert mu.c3d_parameter(out.read_bytes(), "POINT:DATA_START")[:2] == (2, ())


@pytest.mark.parametrize("fps", ["1e-308", "5e-324", "1e308", "0.5", "20000"])
def test_bake_fps_outside_the_c3d_rates_is_a_usage_error(scratch, eb_document, fps):
    doc = scratch / "eb.stag"
    doc.write_bytes(eb_document)
    out = scratch / "out.c3d"
    result, elapsed = run("bake", doc, "--fps", fps, "-o", out)
    refused(result, elapsed, 2, "--fps", f"{fps} is out of range: frame rates go from 1 Hz to 10000 Hz")
    assert not out.exists()


def test_bake_fps_at_the_lowest_c3d_rate_and_above_reads_back(scratch, eb_document):
    doc = scratch / "eb.stag"
    doc.write_bytes(eb_document)
    for fps in ("1", "1000"):
        out = scratch / f"out{fps}.c3d"
        result, _ = run("bake", doc, "--fps", fps, "--no-ik", "-o", out)
        assert result.exit_code == 0, result.stderr
        back = io_c3d.read_c3d(out)
        # 450 frames at 50 Hz: 8.98 s
        assert back.rate == float(fps) and back.n_frames == int(8.98 * float(fps) + 1e-9) + 1
        out.unlink()


def test_the_c3d_writer_refuses_a_rate_its_reader_would_refuse():
    motion = io_c3d.read_c3d(SAMPLES / "march.c3d")
    from dataclasses import replace

    for rate in (1e-308, 0.5, 1e5):
        with pytest.raises(DataError, match="cannot write a C3D at"):
            io_c3d.c3d_bytes(replace(motion, rate=rate))


# --------------------------------------------------------------------------- internal errors that are one line now


def _no_points(path: Path, out: Path) -> None:
    """``path`` written by ezc3d without its markers (analogs kept)."""
    import ezc3d

    c = ezc3d.c3d(str(path))
    c["data"]["points"] = np.zeros((4, 0, c["data"]["points"].shape[2]))
    c["data"]["meta_points"] = {}
    c["parameters"]["POINT"]["LABELS"]["value"] = []
    c["parameters"]["POINT"]["DESCRIPTIONS"]["value"] = []
    io_c3d._cut_to_used(c["parameters"]["ANALOG"], c["data"]["analogs"].shape[1])
    c.write(str(out))


def test_c3d_files_without_markers_are_one_line(scratch):
    analog_only, zero = scratch / "analog_only.c3d", scratch / "zero.c3d"
    _no_points(mocap(EB015PI), analog_only)
    _no_points(SAMPLES / "march.c3d", zero)
    for path, needle in ((analog_only, "(POINT:USED is 0, 16 analog channels only)"), (zero, "(POINT:USED is 0)")):
        for args in (["info", path], ["extract", path, "-o", scratch / "x.stag"]):
            result, elapsed = run(*args)
            refused(result, elapsed, 1, f"{path}: no markers in this C3D {needle}")


@pytest.mark.parametrize("rate", [1e30, 1e6, 0.5, -50.0])
def test_a_point_rate_no_capture_has_is_one_line(scratch, rate):
    bad = scratch / "rate.c3d"
    bad.write_bytes(with_value((SAMPLES / "march.c3d").read_bytes(), "POINT:RATE", rate))
    for args in (["info", bad], ["extract", bad, "-o", scratch / "x.stag"]):
        result, elapsed = run(*args)
        refused(result, elapsed, 1, f"{bad}: frame rate {rate:g} Hz (POINT:RATE) is outside 1 to 10000 Hz")


# --------------------------------------------------------------------------- labels shared by several markers


@pytest.fixture
def shared_labels(scratch):
    """Eb015pi with markers 3 and 7 relabelled RFT3 (marker 2's label): three RFT3."""
    raw = mocap(EB015PI).read_bytes()
    _, dims, values = mu.c3d_parameter(raw, "POINT:LABELS")
    width = dims[0]
    labels = [values[i * width : (i + 1) * width] for i in range(dims[1])]
    labels[3] = labels[7] = labels[2]
    src = scratch / "shared.c3d"
    src.write_bytes(mu.c3d_set_parameter(raw, "POINT:LABELS", values=b"".join(labels)))
    doc = scratch / "shared.stag"
    result, _ = run("extract", src, "-o", doc)
    assert result.exit_code == 0, result.stderr
    assert "no contact detection on marker 'RFT3'" in result.stderr or "RFT3" not in result.stderr
    return src, doc


@pytest.mark.parametrize(
    "args",
    [
        ["edit-pose", "--pose", "1", "--translate", "RFT3=10,0,0"],
        ["edit-pose", "--pose", "1", "--exaggerate", "1.5", "--joints", "RFT3"],
        ["succession", "--chain", "RFT1,RFT3", "--offset", "0.02"],
        ["constraints", "--add", "RFT3@0:0.5"],
        ["constraints", "--detect", "--contact-joints", "RFT3"],
    ],
)
def test_a_label_several_markers_share_is_refused(scratch, shared_labels, args):
    _, doc = shared_labels
    out = scratch / "out.stag"
    result, elapsed = run(args[0], doc, *args[1:], "-o", out)
    refused(result, elapsed, 2, str(doc), "marker label 'RFT3' is ambiguous: 3 markers share it")
    assert not out.exists()


def test_a_unique_label_next_to_shared_ones_edits_its_own_marker(scratch, shared_labels):
    src, doc = shared_labels
    out, baked = scratch / "out.stag", scratch / "out.c3d"
    result, _ = run("edit-pose", doc, "--pose", "1", "--translate", "RFT1=10,0,0", "-o", out)
    assert result.exit_code == 0, result.stderr
    assert run("bake", out, "--no-ik", "-o", baked)[0].exit_code == 0
    before, after = io_c3d.read_c3d(src), io_c3d.read_c3d(baked)
    moved = np.nanmax(np.abs(after.points - before.points), axis=(0, 2))  # per marker
    assert moved[0] > 5.0  # RFT1 moved (about 10 mm at the pose)
    assert np.all(moved[1:] < 1e-3)  # every other marker, the three RFT3 included, did not
    # each repeated marker keeps its own gaps (residuals were copied from the first RFT3)
    np.testing.assert_array_equal(np.isnan(after.points), np.isnan(before.points))
