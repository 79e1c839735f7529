"""Hostile input (issue 18, the part outside the C3D reader): no crash, hang
or runaway memory from a file or an option, and never a file that cannot be
read back.

Every case is a real file of ../shared/mocap with one value changed: a frame
time, a channel count, a document value, a byte of an embedded source; or a
real clip made long or deep (its motion lines repeated, a chain of 1,000
joints driven by a real clip's rotations).
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from staggered_cli.cli.main import cli
from staggered_cli.io import files
from staggered_cli.io.bvh import read_bvh
from staggered_cli.ops.extract import MAX_EXTRACT_VALUES
from staggered_cli.ops.extract import extract as run_extract
from staggered_cli.signals import smoothing, trails

from .conftest import mocap, one_line_error

STAGGERED = Path(sys.executable).parent / "staggered"
RUN = "bandai2_run_normal_001.bvh"  # 68 frames at 30 Hz, 22 joints
WALK = "cmu_02_01_walk.bvh"  # 343 frames at 120 Hz
JUMPS = "cmu_01_01_forward_jumps.bvh"  # 2752 frames at 120 Hz, T-pose frame 0 (a break)


def run(args, input=None):
    return CliRunner().invoke(cli, args, input=input)


def with_frame_time(tmp_path: Path, text: str, name: str = RUN) -> Path:
    data = re.sub(rb"(?m)^Frame Time:.*$", b"Frame Time: " + text.encode(), mocap(name).read_bytes())
    path = tmp_path / f"ft_{len(list(tmp_path.iterdir()))}.bvh"
    path.write_bytes(data)
    return path


def first_frames(tmp_path: Path, name: str, n: int) -> Path:
    """The first ``n`` frames of a real clip."""
    data = mocap(name).read_bytes()
    head, body = data.split(b"MOTION", 1)
    lines = body.lstrip().splitlines()
    path = tmp_path / f"first{n}_{name}"
    path.write_bytes(head + b"MOTION\nFrames: %d\n" % n + lines[1] + b"\n" + b"\n".join(lines[2 : 2 + n]) + b"\n")
    return path


@pytest.fixture(scope="module")
def run_doc(tmp_path_factory):
    out = tmp_path_factory.mktemp("docs") / "run.json"
    r = run(["extract", str(mocap(RUN)), "-o", str(out)])
    assert r.exit_code == 0, r.stderr
    return out


@pytest.fixture(scope="module")
def c3d_doc(tmp_path_factory):
    out = tmp_path_factory.mktemp("docs") / "walk_c3d.json"
    r = run(["extract", str(mocap("c3dorg_sample01_Eb015pi_walk.c3d")), "-o", str(out)])
    assert r.exit_code == 0, r.stderr
    return out


def altered(doc: Path, tmp_path: Path, change) -> Path:
    d = json.loads(doc.read_text())
    change(d)
    path = tmp_path / f"altered_{len(list(tmp_path.iterdir()))}.json"
    path.write_text(json.dumps(d))
    return path


# --- frame rates: 1 Hz to 10 kHz ------------------------------------------------


@pytest.mark.parametrize("text", ["0.00001", "1e-30", "1e-320", "1e308", "2"])
def test_frame_times_out_of_range_are_refused(tmp_path, text):
    path = with_frame_time(tmp_path, text)
    one_line_error(run(["info", str(path)]), 1, path.name, f"frame time {text} is out of range", "1 Hz to 10000 Hz")
    one_line_error(run(["extract", str(path), "-o", str(tmp_path / "x.npz")]), 1, path.name, "out of range")
    assert not (tmp_path / "x.npz").exists()


@pytest.mark.parametrize("text, rate", [("0.0001", 10000.0), ("1", 1.0), ("1.0e-2", 100.0)])
def test_frame_times_at_the_limits_are_read(tmp_path, text, rate):
    r = run(["info", "--json", str(with_frame_time(tmp_path, text))])
    assert r.exit_code == 0, r.stderr
    assert json.loads(r.stdout)["rate"] == rate


def test_a_frame_time_with_an_underscore_is_not_a_number(tmp_path):
    # float() reads '0.01_6667' as 0.016667; the values' grammar does not
    path = with_frame_time(tmp_path, "0.01_6667")
    one_line_error(run(["info", str(path)]), 1, path.name, "frame time '0.01_6667' is not a number")


@pytest.mark.parametrize("text", ["1e308", "1e-320", "1e-30", "0.00001"])
def test_info_json_is_always_strict_json(tmp_path, text):
    r = run(["info", "--json", str(with_frame_time(tmp_path, text))])

    def refuse(name):
        raise ValueError(f"{name} is not JSON")

    if r.exit_code == 0:
        json.loads(r.stdout, parse_constant=refuse)
    else:
        one_line_error(r, 1, "out of range")


def test_documents_with_a_frame_time_out_of_range_are_refused(run_doc, tmp_path):
    def tiny(d):
        d["manifest"]["frame_time"] = 1e-5
        d["manifest"]["bvh"]["frame_time"] = 1e-5
        d["manifest"]["bvh"]["frame_time_text"] = "0.00001"

    path = altered(run_doc, tmp_path, tiny)
    one_line_error(run(["info", str(path)]), 1, path.name, "frame_time 1e-05 is out of range")


@pytest.mark.parametrize("rate", [0, 1e30, 0.5])
def test_c3d_documents_with_a_rate_out_of_range_are_refused(c3d_doc, tmp_path, rate):
    def change(d):
        d["manifest"]["c3d"]["rate"] = rate
        if rate:
            d["manifest"]["frame_time"] = 1.0 / rate

    path = altered(c3d_doc, tmp_path, change)
    one_line_error(run(["bake", str(path), "-o", str(tmp_path / "x.c3d")]), 1, path.name, "is out of range")
    assert not (tmp_path / "x.c3d").exists()


@pytest.mark.parametrize("fps", ["5e-324", "1e-308", "1e308", "0.5", "20000"])
def test_bake_fps_out_of_range_is_a_usage_error(run_doc, c3d_doc, tmp_path, fps):
    for doc, out in ((run_doc, tmp_path / "x.bvh"), (c3d_doc, tmp_path / "x.c3d")):
        one_line_error(run(["bake", "--fps", fps, str(doc), "-o", str(out)]), 2, "--fps", "1 Hz to 10000 Hz")
        assert not out.exists()


def test_bake_fps_at_the_limits_reads_back(run_doc, tmp_path):
    out = tmp_path / "x.bvh"
    r = run(["bake", "--fps", "1", str(run_doc), "-o", str(out)])
    assert r.exit_code == 0, r.stderr
    back = read_bvh(str(out))
    assert back.frame_time == 1.0 and back.n_frames == 3  # 2.23 s at 1 Hz


# --- runaway cost: options bounded, smoothing independent of sigma * rate -----------


@pytest.mark.timeout(60)
def test_huge_smoothing_on_a_short_clip_is_refused_at_once(tmp_path):
    clip = first_frames(tmp_path, RUN, 45)
    start = time.perf_counter()
    r = run(["extract", str(clip), "-o", str(tmp_path / "x.npz"), "--smoothing", "100"])
    one_line_error(r, 2, "--smoothing must be at most 10 s, got 100")
    assert time.perf_counter() - start < 10


@pytest.mark.parametrize("option", ["--smoothing", "--filter-width", "--refine-window", "--min-contact"])
def test_duration_options_have_an_upper_bound(tmp_path, option):
    r = run(["extract", str(mocap(RUN)), "-o", str(tmp_path / "x.npz"), option, "1e30"])
    one_line_error(r, 2, f"{option} must be at most")
    assert not (tmp_path / "x.npz").exists()


def test_constraints_min_contact_has_an_upper_bound(run_doc, tmp_path):
    r = run(["constraints", str(run_doc), "--detect", "--min-contact", "1e30", "-o", str(tmp_path / "x.json")])
    one_line_error(r, 2, "--min-contact", "at most 60 s")


def test_randomize_tau_minus_zero_is_tau_zero(run_doc, tmp_path):
    outs = []
    for tau in ("-0", "0"):
        out = tmp_path / f"r{tau}.json"
        r = run(["randomize", str(run_doc), "--tau", tau, "--seed", "3", "-o", str(out)])
        assert r.exit_code == 0, r.stderr
        outs.append(json.loads(out.read_text())["arrays"])
    assert outs[0] == outs[1]


@pytest.mark.timeout(120)
def test_smoothing_time_does_not_grow_with_sigma_times_rate():
    # 10 s at 120 Hz: 2.9 million iterations of the explicit scheme (about
    # 140 s here); in the cosine basis, as fast as 0.025 s
    motion = read_bvh(str(mocap(WALK)))
    start = time.perf_counter()
    ev = trails.local_evidence(motion, 10.0)
    assert time.perf_counter() - start < 10
    # a Gaussian of 10 s over a 2.9 s clip: every signal is almost flat at its mean
    kappa = trails.local_evidence(motion, 0.0).p
    np.testing.assert_allclose(ev.p, np.broadcast_to(kappa.mean(axis=0), ev.p.shape), atol=2e-3)


def old_laplacian_smooth(x, duration, rate, breaks=None):
    """The smoothing as it was before issue 18: every iteration explicitly."""
    x = np.array(x, dtype=float, copy=True)
    T = x.shape[0]
    if T < 2:
        return x
    full, last = smoothing.smoothing_iterations(duration, rate)
    cond = np.ones(T - 1) if breaks is None else (~np.asarray(breaks, dtype=bool)).astype(float)
    cond = cond.reshape((T - 1,) + (1,) * (x.ndim - 1))
    for lam in [0.25] * full + ([last] if last > 0 else []):
        flux = cond * np.diff(x, axis=0)
        x[:-1] += lam * flux
        x[1:] -= lam * flux
    return x


@pytest.mark.parametrize("name", [JUMPS, RUN, "games105_idle.bvh"])
@pytest.mark.parametrize("cap", [smoothing.MAX_EXPLICIT_ITERATIONS, 0])
def test_signals_match_the_old_smoothing(monkeypatch, name, cap):
    """p and P at the default settings, with the old smoothing and the new
    (cap 0: the cosine-basis path even where iterations would be run)."""
    motion = read_bvh(str(mocap(name)))
    with monkeypatch.context() as m:
        m.setattr(smoothing, "laplacian_smooth", old_laplacian_smooth)
        old = run_extract(motion, source_name=name).signals
    monkeypatch.setattr(smoothing, "MAX_EXPLICIT_ITERATIONS", cap)
    new = run_extract(motion, source_name=name).signals
    for key in ("p", "P"):
        assert new[key].shape == old[key].shape
        np.testing.assert_allclose(new[key], old[key], rtol=0, atol=1e-6)
    if cap:  # at 30 to 120 Hz the default smoothing runs its iterations: the very same numbers
        np.testing.assert_array_equal(new["p"], old["p"])


@pytest.mark.parametrize("sigma", [0.05, 0.5])
def test_the_cosine_basis_keeps_the_breaks(sigma):
    # JUMPS' T-pose frame 0 is a break: nothing crosses it, in either path
    motion = read_bvh(str(mocap(JUMPS)))
    ev = trails.local_evidence(motion, 0.0)
    assert ev.breaks[0] and ev.breaks.sum() == 1
    kappa = ev.p.copy()
    kappa[0] = 1.0  # the T-pose frame alone
    new = smoothing.laplacian_smooth(kappa, sigma, motion.rate, ev.breaks)
    old = old_laplacian_smooth(kappa, sigma, motion.rate, ev.breaks)
    np.testing.assert_array_equal(new[0], 1.0)
    np.testing.assert_allclose(new[1:], old[1:], rtol=0, atol=1e-9)
    np.testing.assert_allclose(new[1:].sum(axis=0), kappa[1:].sum(axis=0), rtol=1e-9)  # mass stays on its side


# --- never write what the reader refuses ----------------------------------------


def test_a_document_value_the_bvh_cannot_hold_is_not_baked(run_doc, tmp_path):
    def huge(d):
        d["arrays"]["track0.layer0.samp_d"]["values"][5] = 1e50  # documents allow up to 1e100

    path = altered(run_doc, tmp_path, huge)
    out = tmp_path / "x.bvh"
    one_line_error(run(["bake", str(path), "-o", str(out)]), 1, path.name, "beyond ±1e+12", "reader's limit")
    assert not out.exists()


# --- "internal error" cases: one line, exit 1 ------------------------------------


def test_a_channel_count_in_non_ascii_digits(tmp_path):
    path = tmp_path / "sup.bvh"
    path.write_bytes(mocap(RUN).read_bytes().replace(b"CHANNELS 6", "CHANNELS ³".encode(), 1))
    one_line_error(run(["info", str(path)]), 1, "sup.bvh", "line 5: bad channel count '³'")


def chain_bvh(tmp_path: Path, joints: int = 1000) -> Path:
    """A chain of ``joints`` joints: the root moves as RUN's Hips, every
    other joint turns by 1/50 of RUN's Spine rotation."""
    src = read_bvh(str(mocap(RUN)))
    sk = src.skeleton
    cols = np.cumsum([0] + [len(c) for c in sk.channels])
    hips, spine = sk.names.index("Hips"), sk.names.index("Spine")
    root = src.channels[:, cols[hips] : cols[hips] + 6]
    turn = src.channels[:, cols[spine] + 3 : cols[spine] + 6] / 50.0
    lines = ["HIERARCHY", "ROOT J0", "{", "OFFSET 0 0 0", "CHANNELS 6 " + " ".join(sk.channels[hips])]
    for j in range(1, joints):
        lines += [f"JOINT J{j}", "{", "OFFSET 0 1.5 0", "CHANNELS 3 " + " ".join(sk.channels[spine][3:])]
    lines += ["End Site", "{", "OFFSET 0 1.5 0", "}"] + ["}"] * joints
    values = np.hstack([root] + [turn] * (joints - 1))
    lines += ["MOTION", f"Frames: {len(values)}", f"Frame Time: {src.frame_time_text}"]
    lines += [" ".join(f"{v:.6f}" for v in row) for row in values]
    path = tmp_path / "chain.bvh"
    path.write_text("\n".join(lines) + "\n")
    return path


def test_a_1000_joint_chain_extracts_and_bakes(tmp_path):
    path = chain_bvh(tmp_path)
    doc, out = tmp_path / "chain.npz", tmp_path / "chain_out.bvh"
    assert run(["extract", str(path), "-o", str(doc)]).exit_code == 0
    r = run(["bake", str(doc), "-o", str(out)])
    assert r.exit_code == 0, r.stderr
    a, b = read_bvh(str(path)), read_bvh(str(out))
    assert b.skeleton.n_joints == 1000 and list(b.skeleton.parents[:3]) == [-1, 0, 1]
    np.testing.assert_allclose(b.channels, a.channels, rtol=0, atol=1e-4)


def test_a_json_integer_of_5000_digits(run_doc, tmp_path):
    text = run_doc.read_text()
    path = tmp_path / "digits.json"
    path.write_text(re.sub(r'"frames": \d+', '"frames": ' + "9" * 5000, text, count=1))
    one_line_error(run(["info", str(path)]), 1, "digits.json", "a number has too many digits")


@pytest.mark.parametrize("args", [["info", "{f}"], ["extract", "{f}", "--format", "json"], ["--help"]])
def test_closed_standard_output(args):
    words = " ".join(f"'{a}'" for a in args).format(f=mocap(RUN))
    r = subprocess.run(["bash", "-c", f"'{STAGGERED}' {words} >&-"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 1
    assert r.stderr.splitlines() == ["staggered: <stdout>: standard output is closed: nothing can be written to it"]


# --- signals and pipes -------------------------------------------------------------


def _catches_sigterm(pid: int) -> bool:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("SigCgt:"):
            return bool(int(line.split()[1], 16) >> (signal.SIGTERM - 1) & 1)
    return False


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_sigterm_is_handled_like_ctrl_c(tmp_path):
    # eight copies of JUMPS' motion: 22,016 frames, about 4 s of extraction
    # (three copies took 8 s once; at 1.5 s the signal could come as the
    # process was ending, after its handler was gone)
    data = mocap(JUMPS).read_bytes()
    head, body = data.split(b"MOTION", 1)
    lines = body.lstrip().splitlines()
    frames = lines[3:] * 8
    path = tmp_path / "long.bvh"
    path.write_bytes(head + b"MOTION\nFrames: %d\n" % len(frames) + lines[1] + b"\n" + b"\n".join(frames) + b"\n")
    out = tmp_path / "out.npz"
    proc = subprocess.Popen(
        [str(STAGGERED), "extract", str(path), "-o", str(out)], stdout=subprocess.PIPE, stderr=subprocess.PIPE
    )
    deadline = time.monotonic() + 60
    while not _catches_sigterm(proc.pid) and time.monotonic() < deadline:  # started, handler in place
        time.sleep(0.05)
    time.sleep(1.0)  # now reading or extracting
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 143, err
    assert err.decode().splitlines() == ["staggered: terminated"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["long.bvh"]


def test_a_killed_writers_temporary_file_is_removed_by_the_next_run(run_doc, tmp_path):
    out = tmp_path / "out.bvh"
    dead = subprocess.Popen(["true"])
    dead.wait()
    writer = subprocess.Popen(["sleep", "60"])  # a writer still running
    try:
        stale = tmp_path / f".out.bvh.staggered-{dead.pid}.tmp"  # as SIGKILL mid-write leaves it
        live = tmp_path / f".out.bvh.staggered-{writer.pid}.tmp"
        stale.write_bytes(b"HIERARCHY\npartial")
        live.write_bytes(b"HIERARCHY\nbeing written")
        r = run(["bake", str(run_doc), "-o", str(out)])
        assert r.exit_code == 0, r.stderr
        assert sorted(p.name for p in tmp_path.iterdir()) == [live.name, "out.bvh"]
        assert read_bvh(str(out)).n_frames == 68
    finally:
        writer.kill()
        writer.wait()
    assert files.remove_stale_temporaries(str(out)) == [live.name]  # its writer is gone now


def test_help_into_a_closed_pipe_exits_141_silently():
    read_end, write_end = os.pipe()
    os.close(read_end)
    try:
        r = subprocess.run([str(STAGGERED), "--help"], stdout=write_end, stderr=subprocess.PIPE, timeout=60)
    finally:
        os.close(write_end)
    assert (r.returncode, r.stderr) == (141, b"")


def test_bake_into_head_exits_141(tmp_path):
    doc = tmp_path / "jumps.npz"
    assert run(["extract", str(mocap(JUMPS)), "-o", str(doc)]).exit_code == 0
    r = subprocess.run(
        ["bash", "-c", f"'{STAGGERED}' bake '{doc}' | head -1; echo ${{PIPESTATUS[0]}}"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.stdout.splitlines() == ["HIERARCHY", "141"]  # 2 MB into a reader that left after one line
    assert r.stderr == ""


# --- the document's source is the one its sha256 names ---------------------------


def test_an_embedded_c3d_that_does_not_match_its_sha256(c3d_doc, tmp_path):
    def flip(d):
        values = d["arrays"]["source.c3d"]["values"]
        values[len(values) // 2] ^= 0x01  # one bit of the data section

    path = altered(c3d_doc, tmp_path, flip)
    one_line_error(run(["bake", str(path), "-o", str(tmp_path / "x.c3d")]), 1, path.name, "does not match")
    one_line_error(run(["info", str(path)]), 1, path.name, "source.c3d does not match the source's sha256")


def test_a_sha256_that_is_not_a_digest(run_doc, tmp_path):
    def bad(d):
        d["manifest"]["source"]["sha256"] = "not a digest"

    path = altered(run_doc, tmp_path, bad)
    one_line_error(run(["info", str(path)]), 1, path.name, "source sha256 is not a SHA-256 digest")


# --- memory bounded by the input ----------------------------------------------------


def repeated_motion(path: Path, frames: int) -> Path:
    """JUMPS' motion lines (without its T-pose) repeated to ``frames`` frames."""
    data = mocap(JUMPS).read_bytes()
    head, body = data.split(b"MOTION", 1)
    lines = body.lstrip().splitlines()
    motion = b"\n".join(lines[3:]) + b"\n"
    n = len(lines) - 3
    with open(path, "wb") as f:
        f.write(head + b"MOTION\nFrames: %d\n" % frames + lines[1] + b"\n")
        for _ in range(frames // n):
            f.write(motion)
        f.write(b"\n".join(lines[3 : 3 + frames % n]) + b"\n")
    return path


def peak_rss(code: str, *args: str) -> tuple[subprocess.CompletedProcess, float]:
    """Run ``code`` in a child Python; its result and its peak resident memory in MB.

    The peak is the child's own ``VmHWM``: ``ru_maxrss`` would keep, across
    the exec, the high-water mark of the process it was forked from (pytest's).
    """
    code = (
        "import sys\n"
        f"try:\n    {code}\n"
        "finally:\n"
        "    hwm = [ln for ln in open('/proc/self/status') if ln.startswith('VmHWM:')][0]\n"
        "    print(hwm.split()[1], file=sys.stderr)\n"
    )
    r = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, timeout=300)
    *lines, rss = r.stderr.splitlines()
    return subprocess.CompletedProcess(r.args, r.returncode, r.stdout, "\n".join(lines)), int(rss) / 1024


CLI = "from staggered_cli.cli.main import cli; cli(sys.argv[1:], prog_name='staggered')"
READ = "from staggered_cli.io.bvh import read_bvh; print(read_bvh(sys.argv[1]).n_frames)"


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
@pytest.mark.timeout(300)
def test_a_clip_beyond_the_extract_limit_is_refused_up_front(tmp_path):
    frames = MAX_EXTRACT_VALUES // 96 + 1  # 96 channels: 62 MB of BVH
    path = repeated_motion(tmp_path / "long.bvh", frames)
    try:
        start = time.perf_counter()
        r, rss = peak_rss(CLI, "extract", str(path), "-o", str(tmp_path / "x.npz"))
        seconds = time.perf_counter() - start
        assert r.returncode == 1, r.stderr
        assert r.stderr.splitlines() == [
            f"staggered: {path}: has {frames:,} frames of 96 channels ({frames * 96:,} values): more than the "
            f"limit of {MAX_EXTRACT_VALUES:,} values (frames x channels): cut it into parts"
        ]
        size_mb = path.stat().st_size / 2**20
        assert seconds < 30 and rss < size_mb + 250, (seconds, rss)  # the bytes, not their values (111 MB here)
        # reading it all takes the bytes, the values and a chunk, not copies
        # of the whole text (before: 10 times the file's size)
        r, rss = peak_rss(READ, str(path))
        assert r.returncode == 0 and int(r.stdout) == frames, r.stderr
        values_mb = frames * 96 * 8 / 2**20
        assert rss < size_mb + 2 * values_mb + 150, (rss, size_mb, values_mb)
    finally:
        path.unlink()
    assert not (tmp_path / "x.npz").exists()
