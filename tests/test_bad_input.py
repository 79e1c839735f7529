"""Bad input never crashes the tool, and nothing is lost (SPEC sections 7 and 8).

Real motion capture from ../shared/mocap and real documents (made here by
``staggered extract``) are mutated by the functions of ``tests/fuzz/mutate.py``,
under hypothesis with a fixed seed, and run in-process through click's
CliRunner.  Every case must end with exit 0 (only where the mutation may
still be a valid file) or with one line ``staggered: FILE: reason`` on stderr
and exit 1 (2 for usage), no traceback, no output left behind, in under 5 s.
A few subprocess runs show that the real executable behaves the same.
"""

from __future__ import annotations

import collections
import io
import json
import os
import random
import shutil
import struct
import subprocess
import sys
import tempfile
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

from staggered_cli.cli.main import COMMANDS, cli
from staggered_cli.io.container import MANIFEST_MEMBER, parse_document
from staggered_cli.io.schema import from_parts

from .conftest import SAMPLES, mocap
from .fuzz import mutate as mu

#: Longest a single bad case may take, seconds.
MAX_SECONDS = 5.0
#: Cases per format (BVH, C3D, document) in CI; set STAGGERED_FUZZ_EXAMPLES
#: for a longer run by hand (the cases stay the same for the same number).
#: 200 still draws every kind of mutation of every format (the tests check
#: it) in about 40 % of the time of the 520 that ran before.
EXAMPLES = int(os.environ.get("STAGGERED_FUZZ_EXAMPLES", "200"))
#: Peak memory allowed on a crafted input, bytes (whole process, in a subprocess).
MAX_PEAK = 200 << 20

BVH_BASES = ("bandai2_run_normal_001.bvh", "games105_idle.bvh", "cmu_02_01_walk.bvh", "march.bvh")
C3D_BASES = ("c3dorg_sample01_Eb015pi_walk.c3d", "march.c3d")


def base_path(name: str) -> Path:
    return SAMPLES / name if name.startswith("march.") else mocap(name)


def fuzz_settings(**kw):
    return settings(
        max_examples=EXAMPLES,
        derandomize=True,
        database=None,
        deadline=None,  # each case is timed below, against MAX_SECONDS
        phases=(Phase.explicit, Phase.generate, Phase.shrink),
        suppress_health_check=list(HealthCheck),
        **kw,
    )


def invoke(args, stdin: bytes | None = None):
    start = time.perf_counter()
    result = CliRunner().invoke(cli, [str(a) for a in args], input=stdin)
    return result, time.perf_counter() - start


def assert_clean(result, elapsed: float) -> None:
    """No traceback, no internal error, a known exit code, in time."""
    text = result.stderr + result.stdout_bytes.decode("utf-8", "replace")
    assert "Traceback" not in text, text[-2000:]
    assert "internal error" not in result.stderr, (result.stderr, result.exception)
    assert result.exit_code in (0, 1, 2), (result.exit_code, result.stderr, result.exception)
    assert elapsed < MAX_SECONDS, f"took {elapsed:.1f} s"


def assert_refused(result, shown: str, workdir: Path, keep: set[str], *, to_stdout: bool, code=(1, 2)) -> None:
    """One line naming the file, the right code, nothing written."""
    assert result.exit_code in code, (result.exit_code, result.stderr)
    lines = result.stderr.splitlines()
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith("staggered: "), lines[0]
    assert shown in lines[0], (shown, lines[0])
    assert len(lines[0]) < 400, lines[0]
    left = sorted(set(os.listdir(workdir)) - keep)
    assert not left, f"left behind: {left}"
    if to_stdout:
        assert result.stdout_bytes == b"", result.stdout_bytes[:200]


def no_nan_json(text: str):
    def refuse(token):
        raise AssertionError(f"{token} in JSON output")

    return json.loads(text, parse_constant=refuse)


def assert_valid_output(command: str, result, out: Path | None) -> None:
    """What an accepted case wrote is readable and sane."""
    from staggered_cli.cli.options import detect_kind, load_input

    if command.startswith("info") or command == "constraints":
        assert result.stdout.strip()
        if "json" in command:
            no_nan_json(result.stdout)
        return
    data = out.read_bytes() if out is not None else result.stdout_bytes
    if detect_kind(data) == "document":
        from_parts(*parse_document(data, "output"))
    else:
        with tempfile.TemporaryDirectory() as d:
            p = Path(d) / "baked"
            p.write_bytes(data)
            motion = load_input(str(p))
            values = motion.channels if hasattr(motion, "channels") else motion.points
            assert not np.isinf(values).any()


@pytest.fixture(scope="module")
def worker():
    """One forked process that runs fuzz cases for the tests of this module
    (its assertion errors come back as they were raised): a crash of the tool
    on a case fails that test instead of killing pytest."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    pool = ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("fork"))
    yield pool
    pool.shutdown(cancel_futures=True)


def in_worker(pool, kind: str, fn, *args):
    """``fn(*args)`` (picklable) in ``pool``'s process."""
    from concurrent.futures import TimeoutError as FutureTimeout
    from concurrent.futures.process import BrokenProcessPool

    try:
        return pool.submit(fn, *args).result(timeout=60)
    except BrokenProcessPool:
        pytest.fail(f"{kind}: the process running the case died (a crash of the tool)")
    except FutureTimeout:
        for process in list(getattr(pool, "_processes", {}).values()):
            process.kill()
        pytest.fail(f"{kind}: the case ran for more than 60 s")


class Tally:
    """Counts of the cases tried, by mutation and outcome, printed at the end."""

    def __init__(self, label: str):
        self.label = label
        self.kinds: collections.Counter = collections.Counter()
        self.outcomes: collections.Counter = collections.Counter()

    def add(self, kind: str, strict: bool, code: int) -> None:
        self.kinds[kind.split(":")[0]] += 1
        self.outcomes["accepted" if code == 0 else f"refused ({'must' if strict else 'may'})"] += 1

    @property
    def total(self) -> int:
        return sum(self.kinds.values())

    def report(self) -> str:
        kinds = ", ".join(f"{k} {n}" for k, n in sorted(self.kinds.items()))
        outcomes = ", ".join(f"{k} {n}" for k, n in sorted(self.outcomes.items()))
        return f"{self.label}: {self.total} cases ({outcomes}); {kinds}"


# --------------------------------------------------------------------------- mutated BVH and C3D

MOTION_COMMANDS = ("info", "info --json", "extract -o FILE", "extract - -o FILE", "extract -o -")


def run_motion_case(case: mu.Case, command: str, workdir: Path, suffix: str):
    """Run one mutated BVH/C3D through ``command``; return the result."""
    inp = workdir / f"bad{suffix}"
    inp.write_bytes(case.data)
    out = workdir / "out.stag"
    stdin = None
    shown = str(inp)
    if command == "info":
        args = ["info", inp]
    elif command == "info --json":
        args = ["info", "--json", inp]
    elif command == "extract -o FILE":
        args = ["extract", inp, "-o", out]
    elif command == "extract - -o FILE":
        args, stdin, shown = ["extract", "-", "-o", out], case.data, "<stdin>"
    else:
        args = ["extract", inp, "-o", "-"]
    result, elapsed = invoke(args, stdin)
    assert_clean(result, elapsed)
    writes_file = "-o FILE" in command
    if result.exit_code == 0:
        assert not case.strict, f"{case.kind}: a bad file was accepted"
        assert_valid_output(command, result, out if writes_file else None)
    else:
        assert_refused(
            result,
            shown,
            workdir,
            {inp.name},
            to_stdout=not command.startswith("info"),
            code=(1,) if case.strict else (1, 2),
        )
    return result


def motion_case_code(case: mu.Case, command: str, suffix: str) -> int:
    with tempfile.TemporaryDirectory() as d:
        return run_motion_case(case, command, Path(d), suffix).exit_code


def _motion_fuzz(bases, mutations, suffix, label, pool=None):
    tally = Tally(label)
    paths = [base_path(name) for name in bases]

    @fuzz_settings()
    @given(
        base=st.sampled_from(paths),
        mutation=st.sampled_from(mutations),
        seed=st.integers(0, 2**32 - 1),
        command=st.sampled_from(MOTION_COMMANDS),
    )
    def check(base, mutation, seed, command):
        loader = mu.bvh_base if suffix == ".bvh" else mu.c3d_base
        case = mutation(loader(base), random.Random(seed))
        if pool is not None:  # a segfault in ezc3d fails the case, not pytest
            code = in_worker(pool, case.kind, motion_case_code, case, command, suffix)
        else:
            code = motion_case_code(case, command, suffix)
        tally.add(case.kind, case.strict, code)

    check()
    print(tally.report())
    return tally


@pytest.mark.timeout(150)
def test_mutated_bvh_files_are_refused_cleanly():
    tally = _motion_fuzz(BVH_BASES, mu.BVH_MUTATIONS, ".bvh", "BVH")
    assert tally.total >= min(500, EXAMPLES)
    assert set(tally.kinds) >= {
        "truncate",
        "delete",
        "duplicate",
        "braces",
        "value",
        "channels",
        "frames",
        "frame-time",
        "garbage",
        "encoding",
        "unknown-channel",
        "duplicate-joint",
    }


@pytest.mark.timeout(150)
def test_mutated_c3d_files_are_refused_cleanly(worker):
    tally = _motion_fuzz(C3D_BASES, mu.C3D_MUTATIONS, ".c3d", "C3D", worker)
    assert tally.total >= min(500, EXAMPLES)
    assert set(tally.kinds) >= {
        "truncate",
        "frames",
        "sizes",
        "key-byte",
        "processor",
        "flip",
        "record",
        "missing-marker",
        "values",
        "garbage",
        "param-type",
        "param-count",
        "param-value",
        "name-length",
    }


# --------------------------------------------------------------------------- mutated documents


@pytest.fixture(scope="module")
def documents(tmp_path_factory):
    """Real documents: ``staggered extract`` on small real and sample clips."""
    d = tmp_path_factory.mktemp("docs")
    out = {}
    for name in ("march.bvh", "march.c3d", "bandai2_run_normal_001.bvh"):
        target = d / f"{name}.stag"
        result, _ = invoke(["extract", base_path(name), "-o", target])
        assert result.exit_code == 0, result.stderr
        out[name] = target
    return out


DOC_COMMANDS = ("info", "info --json", "bake", "bake -", "cull", "randomize", "succession", "edit-pose")
if "constraints" in COMMANDS:
    DOC_COMMANDS += ("constraints", "constraints --remove")


def doc_command(command: str, doc_kind: str, manifest: dict, inp: Path, out: Path):
    """(args, stdin?, output path or None) of ``command`` on document ``inp``."""
    if command == "info":
        return ["info", inp], False, None
    if command == "info --json":
        return ["info", "--json", inp], False, None
    if command == "constraints":
        return ["constraints", inp], False, None
    if command == "constraints --remove":
        return ["constraints", inp, "--remove", "0", "-o", out], False, out
    if command == "bake":
        return ["bake", inp, "-o", out], False, out
    if command == "bake -":
        return ["bake", "-", "-o", "-"], True, None
    if command == "cull":
        return ["cull", inp, "--keep", "50%", "-o", out], False, out
    if command == "randomize":
        return ["randomize", inp, "--tau", "0.01", "--seed", "7", "--clamp", "-o", out], False, out
    if command == "succession":
        if doc_kind == "bvh":
            names = manifest["bvh"]["names"]
            return (
                ["succession", inp, "--joint", names[min(1, len(names) - 1)], "--offset", "0.01", "--clamp", "-o", out],
                False,
                out,
            )
        chain = ",".join(manifest["c3d"]["labels"][:3])
        return ["succession", inp, "--chain", chain, "--offset", "0.01", "--clamp", "-o", out], False, out
    return ["edit-pose", inp, "--pose", "1", "--shift", "0.001", "-o", out], False, out


@pytest.mark.timeout(150)
def test_mutated_documents_are_refused_cleanly(documents, worker):
    tally = Tally("document")
    bases = {name: mu.doc_base(path.read_bytes()) for name, path in documents.items()}

    @fuzz_settings()
    @given(
        base=st.sampled_from(sorted(bases)),
        mutation=st.sampled_from(mu.DOC_MUTATIONS),
        seed=st.integers(0, 2**32 - 1),
        fmt=st.sampled_from(["npz", "json"]),
        command=st.sampled_from(DOC_COMMANDS),
    )
    def check(base, mutation, seed, fmt, command):
        b = bases[base]
        case = mutation(b, random.Random(seed), fmt)
        if base.endswith(".c3d"):  # its source C3D goes to ezc3d: a crash must fail the case, not pytest
            code = in_worker(worker, case.kind, run_document_case, case, b.manifest, base, command)
        else:
            code = run_document_case(case, b.manifest, base, command)
        tally.add(case.kind, case.strict, code)

    check()
    print(tally.report())
    assert tally.total >= min(500, EXAMPLES)
    assert set(tally.kinds) >= {
        "missing-array",
        "shape",
        "knots",
        "version",
        "format",
        "values",
        "dtype",
        "manifest",
        "refs",
        "truncate",
        "flip",
        "garbage",
        "source-c3d",
    }


def run_document_case(case: mu.Case, manifest: dict, base: str, command: str) -> int:
    """Run one mutated document through ``command``; check the outcome; the exit code."""
    with tempfile.TemporaryDirectory() as d:
        workdir = Path(d)
        inp = workdir / "bad.stag"
        inp.write_bytes(case.data)
        out = workdir / "out"
        args, use_stdin, written = doc_command(command, base.rsplit(".", 1)[1], manifest, inp, out)
        result, elapsed = invoke(args, case.data if use_stdin else None)
        assert_clean(result, elapsed)
        if result.exit_code == 0:
            assert not case.strict, f"{case.kind}: a bad document was accepted"
            assert_valid_output(command, result, written)
        else:
            # an edit may be refused as usage (a knot would cross): exit 2
            assert_refused(
                result,
                "<stdin>" if use_stdin else str(inp),
                workdir,
                {inp.name},
                to_stdout=not command.startswith("info") and command != "constraints",
                code=(1,) if case.strict else (1, 2),
            )
        return result.exit_code


def test_document_validation_names_the_problem(documents):
    """The messages of the main document problems say what is wrong."""
    b = mu.doc_base(documents["march.bvh"].read_bytes())
    cases = [
        (mu.doc_missing_array, "missing array"),
        (mu.doc_crossing_knots, "cross"),
        (mu.doc_version, "version"),
        (mu.doc_truncate, "truncated or corrupt NPZ"),
    ]
    with tempfile.TemporaryDirectory() as d:
        for mutation, needle in cases:
            for seed in range(4):
                case = mutation(b, random.Random(seed), "npz")
                inp = Path(d) / "bad.stag"
                inp.write_bytes(case.data)
                result, elapsed = invoke(["info", inp])
                assert_clean(result, elapsed)
                assert result.exit_code == 1 and needle in result.stderr, (case.kind, result.stderr)


# --------------------------------------------------------------------------- regressions the suite found


def _bvh_text() -> str:
    return (SAMPLES / "march.bvh").read_text()


def test_underscore_numbers_are_not_bvh_numbers(tmp_path):
    # numpy's loadtxt and float() read '1_000' as 1000; no BVH reader does
    text = _bvh_text()
    head, body = text.split("Frame Time:", 1)
    first = body.split("\n", 2)
    values = first[1].split()
    values[3] = "1_000"
    bad = tmp_path / "u.bvh"
    bad.write_text(head + "Frame Time:" + first[0] + "\n" + " ".join(values) + "\n" + first[2])
    result, _ = invoke(["info", bad])
    assert result.exit_code == 1 and "'1_000' is not a number" in result.stderr, result.stderr


def test_a_brace_in_a_joint_name_is_refused(tmp_path):
    bad = tmp_path / "b.bvh"
    bad.write_text(_bvh_text().replace("JOINT Spine", "JOINT } Spine", 1))
    result, _ = invoke(["info", bad])
    assert result.exit_code == 1 and "unexpected '}' in a joint name" in result.stderr, result.stderr


@pytest.mark.parametrize(
    ("old", "new"),
    [
        ("0.0542", "1e300"),
        ("0.0542", "-1.5e13"),
        ("OFFSET 0 12 0", "OFFSET 0 1e999 0"),
        ("OFFSET 0 12 0", "OFFSET 0 1e20 0"),
    ],
)
def test_numbers_too_large_for_motion_capture_are_refused(tmp_path, old, new):
    # 1e300 passed the finite check, then overflowed in the signals (RuntimeWarnings
    # on stderr, NaN in the document); '1e999' in an OFFSET was read as inf
    text = _bvh_text()
    assert old in text
    bad = tmp_path / "big.bvh"
    bad.write_text(text.replace(old, new, 1))
    for args in (["info", bad], ["extract", bad, "-o", tmp_path / "out"]):
        result, elapsed = invoke(args)
        assert_clean(result, elapsed)
        assert result.exit_code == 1 and "too large" in result.stderr, result.stderr
    assert not (tmp_path / "out").exists()


def test_c3d_coordinates_beyond_any_capture_volume_read_as_missing(tmp_path):
    base = mu.c3d_base(SAMPLES / "march.c3d")
    data = bytearray(base.data)
    at = base.data_at + (5 * base.stride + 4 * 2) * base.value_bytes  # frame 5, marker 2, x
    data[at : at + 4] = struct.pack("<f", 3e38)
    src = tmp_path / "wild.c3d"
    src.write_bytes(bytes(data))
    from staggered_cli.io.c3d import read_c3d

    assert np.isnan(read_c3d(src).points[5, 2]).all()
    for args in (
        ["extract", src, "-o", tmp_path / "doc.stag"],
        ["bake", tmp_path / "doc.stag", "-o", tmp_path / "o.c3d"],
    ):
        result, elapsed = invoke(args)
        assert_clean(result, elapsed)
        assert result.exit_code == 0, result.stderr
    assert np.isnan(read_c3d(tmp_path / "o.c3d").points[5, 2]).all()


def test_utf16_is_named_as_such(tmp_path):
    for enc in ("utf-16", "utf-16-le", "utf-32"):
        bad = tmp_path / f"{enc}.bvh"
        bad.write_bytes(_bvh_text().encode(enc))
        result, _ = invoke(["info", bad])
        assert result.exit_code == 1 and "save it as UTF-8" in result.stderr, result.stderr


def test_info_names_a_bad_document_by_the_path_given(documents, tmp_path):
    b = mu.doc_base(documents["march.bvh"].read_bytes())
    sub = tmp_path / "sub"
    sub.mkdir()
    bad = sub / "bad.stag"
    bad.write_bytes(mu.doc_crossing_knots(b, random.Random(1), "npz").data)
    result, _ = invoke(["info", bad])
    assert result.exit_code == 1 and f"staggered: {bad}: " in result.stderr, result.stderr


def _reencode(documents, name, change):
    from staggered_cli.io.container import document_bytes

    manifest, arrays = parse_document(documents[name].read_bytes(), "doc")
    change(manifest, arrays)
    return document_bytes(manifest, arrays, "npz")


@pytest.mark.parametrize(
    ("name", "change", "needle"),
    [
        # an empty track list: bake indexed the first track (IndexError)
        ("march.c3d", lambda m, a: m.update(tracks=[]), "tracks for the source's 1"),
        # a target out of range: randomize accepted it, succession crashed
        ("march.bvh", lambda m, a: m["tracks"][1]["targets"].__setitem__(0, 10_000), "does not hold the source's"),
        # a repeated variable name: accepted and baked
        (
            "march.bvh",
            lambda m, a: m["tracks"][1]["names"].__setitem__(1, m["tracks"][1]["names"][0]),
            "does not hold the source's",
        ),
        # constraints out of the clip, backwards, or on a joint that does not exist
        (
            "march.bvh",
            lambda m, a: m["constraints"].append({"joint": "Hips", "start": 1.0, "end": 0.0}),
            "not within the clip",
        ),
        (
            "march.bvh",
            lambda m, a: m["constraints"].append({"joint": "Nope", "start": 0.0, "end": 0.1}),
            "unknown joint or marker 'Nope'",
        ),
        # versions 0 and -1 were read as version 1
        ("march.bvh", lambda m, a: m.update(version=0), "bad document version 0"),
        ("march.bvh", lambda m, a: m.update(version=True), "version is missing"),
        # a frame time text that is not a number went into the baked BVH header
        ("march.bvh", lambda m, a: m["bvh"].update(frame_time_text="-3"), "frame_time_text '-3'"),
        ("march.bvh", lambda m, a: m["bvh"].update(frame_time_text="0.03\nJUNK"), "frame_time_text"),
        # joint names and channels are written back into a BVH header
        ("march.bvh", lambda m, a: m["bvh"]["names"].__setitem__(2, "Ch\nest"), "joint name"),
        (
            "march.bvh",
            lambda m, a: m["bvh"]["channels"].__setitem__(0, ["Xposition", "Wrong"] + [""] * 4),
            "unknown or repeated channel",
        ),
        # an extreme knot turned into an editing knot: refinements became NaN (NaN in info --json)
        ("march.bvh", lambda m, a: a["track1.layer0.knot_editing"].__setitem__(3, True), "one extreme knot per pose"),
        # infinite source points made bake fail in the C3D writer
        ("march.c3d", lambda m, a: a["source.points"].__setitem__((0, 0, 0), np.inf), "infinite"),
        # values whose squares overflow: RuntimeWarnings and inf in the baked file
        ("march.bvh", lambda m, a: a["track0.layer0.knot_v"].__setitem__((3, 0), 1e300), "beyond"),
        ("march.bvh", lambda m, a: a["track1.layer0.tan_a"].__setitem__((3, 0), -1e200), "beyond"),
        ("march.bvh", lambda m, a: a["source.channels"].__setitem__((3, 0), 1e300), "source.channels"),
        ("march.bvh", lambda m, a: m["bvh"]["offsets"][2].__setitem__(1, 1e300), "bvh offsets"),
        (
            "march.bvh",
            lambda m, a: a["track0.layer0.knot_t"].__setitem__(a["track0.layer0.knot_ptr"][1] - 1, 99.0),
            "outside the clip",
        ),
        # a source C3D that is not one: bake failed naming "source C3D of the motion"
        ("march.c3d", lambda m, a: a.__setitem__("source.c3d", np.zeros(600, np.uint8)), "source.c3d"),
        # end sites without offsets (IndexError in the figure size)
        ("march.bvh", lambda m, a: m["bvh"].update(end_parents=[]), "end sites"),
        # parameters that `constraints --detect` reuses (TypeError there)
        ("march.bvh", lambda m, a: m["parameters"].update(contact_joints=5), "contact_joints"),
        ("march.bvh", lambda m, a: m["parameters"].update(min_contact="x"), "min_contact"),
        # poses that do not span the clip
        ("march.bvh", lambda m, a: a["pose_t"].__setitem__(-1, a["pose_t"][-1] - 0.01), "pose times must run"),
    ],
)
def test_inconsistent_documents_are_refused_on_reading(documents, tmp_path, name, change, needle):
    bad = tmp_path / "bad.stag"
    bad.write_bytes(_reencode(documents, name, change))
    for args in (["info", "--json", bad], ["bake", bad, "-o", tmp_path / "out"]):
        result, elapsed = invoke(args)
        assert_clean(result, elapsed)
        assert_refused(result, str(bad), tmp_path, {"bad.stag"}, to_stdout=False, code=(1,))
        assert needle in result.stderr, result.stderr


@pytest.mark.skipif("constraints" not in COMMANDS, reason="constraints is not registered")
def test_removing_from_a_document_without_constraints_names_it(documents, tmp_path):
    bare = tmp_path / "bare.stag"
    bare.write_bytes(_reencode(documents, "march.bvh", lambda m, a: m.update(constraints=[])))
    result, elapsed = invoke(["constraints", bare, "--remove", "0", "-o", tmp_path / "out"])
    assert_clean(result, elapsed)
    assert result.exit_code == 2 and f"staggered: {bare}: the document has no constraints" in result.stderr


# --------------------------------------------------------------------------- other commands on bad input


def _bad_inputs(documents, tmp_path: Path) -> list[Path]:
    b = mu.doc_base(documents["march.bvh"].read_bytes())
    rng = random.Random(5)
    files = {
        "truncated.stag": mu.doc_truncate(b, rng, "npz").data,
        "crossing.stag": mu.doc_crossing_knots(b, rng, "json").data,
        "missing.stag": mu.doc_missing_array(b, rng, "npz").data,
        "truncated.bvh": (SAMPLES / "march.bvh").read_bytes()[:5000],
        "truncated.c3d": (SAMPLES / "march.c3d").read_bytes()[:3000],
    }
    out = []
    for name, data in files.items():
        path = tmp_path / name
        path.write_bytes(data)
        out.append(path)
    return out


@pytest.mark.parametrize("command", [c for c in ("plot", "preview", "view") if c in COMMANDS])
def test_picture_commands_refuse_bad_input(documents, tmp_path, command):
    inputs = _bad_inputs(documents, tmp_path)
    keep = {p.name for p in inputs}
    out = "out.html" if command == "view" else "out.png"
    for inp in inputs:
        if command == "plot" and inp.suffix != ".stag":
            continue
        result, elapsed = invoke([command, inp, "-o", tmp_path / out])
        assert_clean(result, elapsed)
        assert_refused(result, str(inp), tmp_path, keep, to_stdout=False, code=(1,))


@pytest.mark.skipif("batch" not in COMMANDS, reason="batch is not registered")
def test_batch_keeps_going_and_leaves_nothing_for_bad_files(tmp_path):
    src = tmp_path / "in"
    src.mkdir()
    shutil.copy(SAMPLES / "march.bvh", src / "good.bvh")
    (src / "cut.bvh").write_bytes((SAMPLES / "march.bvh").read_bytes()[:6000])
    (src / "cut.c3d").write_bytes((SAMPLES / "march.c3d").read_bytes()[:3000])
    (src / "utf16.bvh").write_bytes(_bvh_text().encode("utf-16"))
    dst = tmp_path / "out"
    result, _ = invoke(["batch", src, dst, "-j", "1", "--steps", "cull --keep 50%"])
    assert result.exit_code == 1, (result.stderr, result.stdout)
    assert "Traceback" not in result.stderr + result.stdout and "internal error" not in result.stderr
    written = sorted(str(p.relative_to(dst)) for p in dst.rglob("*") if p.is_file())
    assert written == ["good.bvh"], written
    for name in ("cut.bvh", "cut.c3d", "utf16.bvh"):
        assert name in result.stderr + result.stdout


# --------------------------------------------------------------------------- option values out of range


@pytest.fixture(scope="module")
def doc_file(documents):
    return documents["march.bvh"]


BAD_OPTIONS = [
    ["randomize", "{doc}", "--tau", "-0.1", "--seed", "1"],
    ["randomize", "{doc}", "--tau", "nan", "--seed", "1"],
    ["randomize", "{doc}", "--tau", "inf", "--seed", "1"],
    ["randomize", "{doc}", "--tau", "abc", "--seed", "1"],
    ["randomize", "{doc}", "--tau", "0.01", "--seed", "-1"],
    ["randomize", "{doc}", "--tau", "0.01", "--seed", "1", "--time", "100:200"],
    ["randomize", "{doc}", "--tau", "0.01", "--seed", "1", "--time", "-5:-1"],
    ["randomize", "{doc}", "--tau", "0.01", "--seed", "1", "--time", "2:1"],
    ["randomize", "{doc}", "--tau", "0.01", "--seed", "1", "--time", "nan:1"],
    ["randomize", "{doc}", "--tau", "0.01", "--seed", "1", "--poses", "999"],
    ["randomize", "{doc}", "--tau", "0.01", "--seed", "1", "--joints", "NoSuchJoint"],
    ["cull", "{doc}", "--keep", "0%"],
    ["cull", "{doc}", "--keep", "0"],
    ["cull", "{doc}", "--keep", "-3"],
    ["cull", "{doc}", "--keep", "101%"],
    ["cull", "{doc}", "--keep", "nan%"],
    ["cull", "{doc}", "--keep", "abc"],
    ["cull", "{doc}", "--interval", "3:1"],
    ["cull", "{doc}", "--interval", "nan:1"],
    ["cull", "{doc}", "--select", "999"],
    ["cull", "{doc}", "--add-time", "-1"],
    ["cull", "{doc}", "--add-time", "1e9"],
    ["cull", "{doc}", "--add-time", "nan"],
    ["cull", "{doc}"],
    ["succession", "{doc}", "--joint", "LeftArm", "--offset", "0.01", "--power", "-1"],
    ["succession", "{doc}", "--joint", "LeftArm", "--offset", "0.01", "--power", "0"],
    ["succession", "{doc}", "--joint", "LeftArm", "--offset", "0.01", "--power", "nan"],
    ["succession", "{doc}", "--joint", "LeftArm", "--offset", "0.01", "--power", "inf"],
    ["succession", "{doc}", "--joint", "LeftArm", "--offset", "nan"],
    ["succession", "{doc}", "--joint", "LeftArm", "--offset", "-inf"],
    ["succession", "{doc}", "--joint", "NoSuchJoint", "--offset", "0.01"],
    ["succession", "{doc}", "--joint", "LeftArm", "--offset", "0.01", "--time", "50:60"],
    ["succession", "{doc}", "--joint", "LeftArm", "--offset", "0.01", "--poses", "-999"],
    ["edit-pose", "{doc}", "--pose", "999", "--shift", "0.01"],
    ["edit-pose", "{doc}", "--pose", "1", "--shift", "nan"],
    ["edit-pose", "{doc}", "--pose", "1", "--time", "1e9"],
    ["edit-pose", "{doc}", "--pose", "1", "--time", "-1"],
    ["edit-pose", "{doc}", "--pose", "0", "--shift", "0.01"],
    ["edit-pose", "{doc}", "--pose", "1", "--rotate", "LeftArm=nan,0,0"],
    ["edit-pose", "{doc}", "--pose", "1", "--rotate", "NoSuchJoint=1,0,0"],
    ["edit-pose", "{doc}", "--pose", "1", "--exaggerate", "nan"],
    ["edit-pose", "{doc}", "--pose", "1", "--translate", "Hips=1,inf,0"],
    ["bake", "{doc}", "--fps", "0"],
    ["bake", "{doc}", "--fps", "-30"],
    ["bake", "{doc}", "--fps", "nan"],
    ["bake", "{doc}", "--fps", "inf"],
    ["bake", "{doc}", "--fps", "abc"],
    ["bake", "{doc}", "--ik-blend", "-1"],
    ["bake", "{doc}", "--ik-blend", "nan"],
    ["extract", "{bvh}", "--smoothing", "-1"],
    ["extract", "{bvh}", "--smoothing", "nan"],
    ["extract", "{bvh}", "--filter-width", "-1"],
    ["extract", "{bvh}", "--filter-width", "nan"],
    ["extract", "{bvh}", "--refine-window", "-1"],
    ["extract", "{bvh}", "--refine-window", "inf"],
    ["extract", "{bvh}", "--min-contact", "-1"],
    ["extract", "{bvh}", "--min-contact", "nan"],
    ["extract", "{bvh}", "--contact-tolerance", "-1"],
    ["extract", "{bvh}", "--contact-tolerance", "nan"],
    ["extract", "{bvh}", "--significance", "-1"],
    ["extract", "{bvh}", "--significance", "nan"],
    ["extract", "{bvh}", "--contact-joints", "NoSuchJoint"],
    ["extract", "{bvh}", "--contact-joints", ","],
    ["extract", "{doc}"],
    ["info", "{bvh}", "--bogus"],
    ["bake", "{bvh}"],
]
if "constraints" in COMMANDS:
    BAD_OPTIONS += [
        ["constraints", "{doc}", "--add", "LeftFoot@2:1"],
        ["constraints", "{doc}", "--add", "NoSuchJoint@0:1"],
        ["constraints", "{doc}", "--add", "LeftFoot@0:1e9"],
        ["constraints", "{doc}", "--add", "LeftFoot@-5:1"],
        ["constraints", "{doc}", "--add", "LeftFoot@nan:1"],
        ["constraints", "{doc}", "--remove", "999"],
        ["constraints", "{doc}", "--detect", "--min-contact", "-1"],
        ["constraints", "{doc}", "--detect", "--contact-tolerance", "nan"],
    ]
if "preview" in COMMANDS:
    BAD_OPTIONS += [["preview", "{doc}", "--at", "frames 0"], ["preview", "{doc}", "--dpi", "0"]]
if "plot" in COMMANDS:
    BAD_OPTIONS += [
        ["plot", "{doc}", "--time", "100:200"],
        ["plot", "{doc}", "--dpi", "0"],
        ["plot", "{doc}", "--joints", "NoSuchJoint"],
    ]


@pytest.mark.parametrize("args", BAD_OPTIONS, ids=[" ".join(a[:1] + a[2:]) for a in BAD_OPTIONS])
def test_option_values_out_of_range_are_usage_errors(doc_file, tmp_path, args):
    out = tmp_path / "out"
    argv = [str(a).format(doc=doc_file, bvh=SAMPLES / "march.bvh") for a in args] + ["-o", str(out)]
    result, elapsed = invoke(argv)
    assert_clean(result, elapsed)
    assert result.exit_code == 2, (result.exit_code, result.stderr)
    lines = result.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("staggered: "), result.stderr
    assert not out.exists() and not list(tmp_path.iterdir())
    assert result.stdout_bytes == b""


# --------------------------------------------------------------------------- --force and atomic writes

WRITERS = [
    ["extract", "{bvh}"],
    ["cull", "{doc}", "--keep", "50%"],
    ["succession", "{doc}", "--joint", "LeftArm", "--offset", "0.01", "--clamp"],
    ["randomize", "{doc}", "--tau", "0.01", "--seed", "2", "--clamp"],
    ["edit-pose", "{doc}", "--pose", "1", "--shift", "0.001"],
    ["bake", "{doc}"],
]
if "constraints" in COMMANDS:
    WRITERS.append(["constraints", "{doc}", "--add", "LeftFoot@0.2:0.4"])


def _argv(args, doc, out, *extra):
    return [str(a).format(doc=doc, bvh=SAMPLES / "march.bvh") for a in args] + ["-o", str(out), *extra]


@pytest.mark.parametrize("args", WRITERS, ids=[a[0] for a in WRITERS])
def test_existing_output_needs_force(doc_file, tmp_path, args):
    out = tmp_path / "out.file"
    out.write_bytes(b"precious")
    result, _ = invoke(_argv(args, doc_file, out))
    assert result.exit_code == 2 and "--force" in result.stderr and str(out) in result.stderr, result.stderr
    assert out.read_bytes() == b"precious"
    assert sorted(os.listdir(tmp_path)) == ["out.file"]
    result, _ = invoke(_argv(args, doc_file, out, "--force"))
    assert result.exit_code == 0, result.stderr
    assert out.read_bytes() != b"precious"
    assert_valid_output("write", result, out)
    assert sorted(os.listdir(tmp_path)) == ["out.file"]


@pytest.mark.parametrize("args", WRITERS, ids=[a[0] for a in WRITERS])
def test_failed_command_leaves_existing_output_alone(documents, tmp_path, args):
    out = tmp_path / "out.file"
    out.write_bytes(b"precious")
    bad = tmp_path / "bad.stag"
    b = mu.doc_base(documents["march.bvh"].read_bytes())
    bad.write_bytes(mu.doc_truncate(b, random.Random(3), "npz").data)
    if args[0] == "extract":
        bad.write_bytes((SAMPLES / "march.bvh").read_bytes()[:5000])
    argv = [a if a not in ("{doc}", "{bvh}") else str(bad) for a in args] + ["-o", str(out), "--force"]
    result, _ = invoke(argv)
    assert result.exit_code == 1, result.stderr
    assert out.read_bytes() == b"precious"
    assert sorted(os.listdir(tmp_path)) == ["bad.stag", "out.file"]


@pytest.mark.parametrize("error", [OSError(28, "No space left on device"), KeyboardInterrupt()])
@pytest.mark.parametrize("force", [False, True])
def test_a_write_that_fails_leaves_no_partial_file(doc_file, tmp_path, monkeypatch, error, force):
    out = tmp_path / "out.bvh"
    if force:
        out.write_bytes(b"precious")

    def fail(fd):
        raise error

    monkeypatch.setattr(os, "fsync", fail)  # the data is written, not yet renamed into place
    result, _ = invoke(["bake", doc_file, "-o", out] + (["--force"] if force else []))
    monkeypatch.undo()
    assert result.exit_code == (130 if isinstance(error, KeyboardInterrupt) else 1), result.stderr
    assert "Traceback" not in result.stderr
    assert sorted(os.listdir(tmp_path)) == (["out.bvh"] if force else [])
    if force:
        assert out.read_bytes() == b"precious"


def test_output_into_a_missing_directory_or_onto_a_directory(doc_file, tmp_path):
    for out in (tmp_path / "no" / "such" / "dir.bvh", tmp_path):
        result, _ = invoke(["bake", doc_file, "-o", out])
        assert result.exit_code == 2 and len(result.stderr.splitlines()) == 1, result.stderr
    assert list(tmp_path.iterdir()) == []


# --------------------------------------------------------------------------- pipes


def _pipe(steps: list[list[str]], first_input: bytes | None = None) -> bytes:
    data = first_input
    for step in steps:
        result, _ = invoke(step, data)
        assert result.exit_code == 0, (step, result.stderr)
        assert "Traceback" not in result.stderr
        data = result.stdout_bytes
    return data


@pytest.mark.parametrize("fmt", ["npz", "json"])
def test_bvh_pipeline_through_every_command(fmt):
    f = ["--format", fmt]
    baked = _pipe(
        [
            ["extract", "-", "-o", "-", *f],
            ["cull", "-", "--keep", "50%", "-o", "-", *f],
            ["succession", "-", "--joint", "LeftArm", "--offset", "0.02", "--power", "2", "--clamp", "-o", "-", *f],
            ["randomize", "-", "--tau", "0.01", "--seed", "4", "--clamp", "-o", "-", *f],
            ["edit-pose", "-", "--pose", "1", "--rotate", "LeftArm=0,0,10", "-o", "-", *f],
            ["bake", "-", "-o", "-"],
        ],
        (SAMPLES / "march.bvh").read_bytes(),
    )
    from staggered_cli.io.bvh import parse_bvh

    source = parse_bvh((SAMPLES / "march.bvh").read_bytes())
    motion = parse_bvh(baked)
    assert motion.channels.shape == source.channels.shape
    assert np.isfinite(motion.channels).all()
    assert motion.frame_time_text == source.frame_time_text
    info, _ = invoke(["info", "--json", "-"], baked)
    assert info.exit_code == 0 and no_nan_json(info.stdout)["frames"] == source.n_frames


@pytest.mark.parametrize(
    "command",
    [
        c
        for c in (["plot", "-", "-o", "-"], ["preview", "-", "-o", "-"], ["constraints", "-", "--json"])
        if c[0] in COMMANDS
    ],
    ids=lambda c: c[0],
)
def test_document_on_stdin_to_the_other_commands(doc_file, command):
    result, _ = invoke(command, doc_file.read_bytes())
    assert result.exit_code == 0, result.stderr
    if command[0] == "constraints":
        assert isinstance(no_nan_json(result.stdout), list | dict)
    else:
        assert result.stdout_bytes.startswith(b"\x89PNG")


@pytest.mark.skipif("constraints" not in COMMANDS, reason="constraints is not registered")
def test_constraints_in_a_pipe():
    doc = _pipe([["extract", "-", "-o", "-"]], (SAMPLES / "march.bvh").read_bytes())
    baked = _pipe(
        [
            ["constraints", "-", "--add", "LeftFoot@1:1.2", "-o", "-"],
            ["constraints", "-", "--remove", "0", "-o", "-"],
            ["bake", "-", "-o", "-"],
        ],
        doc,
    )
    assert baked.startswith(b"HIERARCHY")


def test_c3d_pipeline_through_every_command():
    labels = None
    doc = _pipe([["extract", "-", "-o", "-"]], (SAMPLES / "march.c3d").read_bytes())
    labels = parse_document(doc, "doc")[0]["c3d"]["labels"]
    baked = _pipe(
        [
            ["cull", "-", "--keep", "40%", "-o", "-"],
            ["succession", "-", "--chain", ",".join(labels[:4]), "--offset", "0.01", "--clamp", "-o", "-"],
            ["randomize", "-", "--tau", "0.01", "--seed", "9", "--clamp", "-o", "-"],
            ["edit-pose", "-", "--pose", "1", "--translate", f"{labels[0]}=0,0,5", "-o", "-"],
            ["bake", "-", "-o", "-"],
        ],
        doc,
    )
    from staggered_cli.io.c3d import read_c3d

    source = read_c3d(SAMPLES / "march.c3d")
    motion = read_c3d("baked", data=baked)
    assert motion.points.shape == source.points.shape
    assert motion.labels == source.labels


def _executable() -> list[str]:
    script = Path(sys.executable).with_name("staggered")
    return [str(script)] if script.exists() else [sys.executable, "-m", "staggered_cli"]


def test_real_executable_pipeline(tmp_path):
    exe = " ".join(_executable())
    out = tmp_path / "out.bvh"
    pipeline = (
        f"set -o pipefail; {exe} extract - -o - < {SAMPLES / 'march.bvh'} | {exe} cull - --keep 50% | "
        f"{exe} succession - --joint LeftArm --offset 0.02 --clamp | {exe} randomize - --tau 0.01 --seed 1 --clamp | "
        f"{exe} edit-pose - --pose 1 --shift 0.005 | {exe} bake - -o {out}"
    )
    proc = subprocess.run(["bash", "-c", pipeline], capture_output=True, timeout=120)
    assert proc.returncode == 0, proc.stderr.decode()
    assert b"Traceback" not in proc.stderr
    result, _ = invoke(["info", out])
    assert result.exit_code == 0
    # a reader that stops early: no message, no traceback (exit 141 where the
    # kernel reports the closed pipe; some sandboxes let a single large write through)
    proc = subprocess.run(
        ["bash", "-c", f"set -o pipefail; {exe} extract {mocap('cmu_02_01_walk.bvh')} -o - --format json | head -c 10"],
        capture_output=True,
        timeout=120,
    )
    assert proc.returncode in (0, 141), proc.stderr.decode()
    assert proc.stderr == b""


def test_real_executable_prints_one_line_on_bad_input(tmp_path):
    out = tmp_path / "out"
    cases = {
        "cut.bvh": ((SAMPLES / "march.bvh").read_bytes()[:4000], "extract"),
        "cut.c3d": ((SAMPLES / "march.c3d").read_bytes()[:2000], "extract"),
        "junk.stag": (b"PK\x03\x04" + bytes(range(256)), "bake"),
    }
    for name, (data, writer) in cases.items():
        path = tmp_path / name
        path.write_bytes(data)
        for argv in (["info", str(path)], [writer, str(path), "-o", str(out)]):
            proc = subprocess.run(_executable() + argv, capture_output=True, timeout=60)
            err = proc.stderr.decode()
            assert proc.returncode == 1, err
            assert len(err.splitlines()) == 1 and err.startswith(f"staggered: {path}: "), err
            assert "Traceback" not in err and proc.stdout == b""
            assert not out.exists()


# --------------------------------------------------------------------------- untrusted documents (SPEC 7)


class _Exploit:
    """Unpickling this creates a marker file."""

    def __init__(self, marker: str):
        self.marker = marker

    def __reduce__(self):
        return (os.mkdir, (self.marker,))


def _members(data: bytes) -> dict[str, bytes]:
    with zipfile.ZipFile(io.BytesIO(data)) as zf:
        return {info.filename: zf.read(info) for info in zf.infolist()}


def _zip(members: dict[str, bytes], compression=zipfile.ZIP_STORED) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression=compression) as zf:
        for name, data in members.items():
            zf.writestr(name, data)
    return buf.getvalue()


def test_a_pickled_object_is_refused_without_running_it(documents, tmp_path):
    marker = tmp_path / "pwned"
    payload = io.BytesIO()
    np.save(payload, np.array([_Exploit(str(marker))], dtype=object), allow_pickle=True)
    members = _members(documents["march.bvh"].read_bytes())
    crafted = {}
    members["pose_t.npy"] = payload.getvalue()
    crafted["member.stag"] = _zip(members)
    env = json.loads(members[MANIFEST_MEMBER])
    env["arrays"]["pose_t"] = {"dtype": "object", "shape": [1]}
    crafted["declared.stag"] = _zip({**members, MANIFEST_MEMBER: json.dumps(env).encode()})
    plain = io.BytesIO()
    np.savez(plain, pose_t=np.array([_Exploit(str(marker))], dtype=object))
    crafted["plain.npz"] = plain.getvalue()
    for name, data in crafted.items():
        path = tmp_path / name
        path.write_bytes(data)
        for args in (["info", path], ["bake", path, "-o", tmp_path / "out"], ["cull", "-", "--keep", "2"]):
            result, elapsed = invoke(args, data if "-" in args else None)
            assert_clean(result, elapsed)
            assert result.exit_code == 1 and len(result.stderr.splitlines()) == 1, result.stderr
            assert not marker.exists(), f"{name}: the pickle ran"
    assert not (tmp_path / "out").exists()
    # the payload is live: loading it the unsafe way runs it
    with zipfile.ZipFile(io.BytesIO(crafted["member.stag"])) as zf, zf.open("pose_t.npy") as fp:
        np.load(fp, allow_pickle=True)
    assert marker.exists()


# The peak is VmHWM, the high-water mark of this process's own memory: ru_maxrss
# would also count the parent's at the fork (vfork/exec keeps it), i.e. pytest's.
_DRIVER = """
import resource, sys, time
from click.testing import CliRunner
from staggered_cli.cli.main import cli
start = time.perf_counter()
result = CliRunner().invoke(cli, sys.argv[1:], input=sys.stdin.buffer)
elapsed = time.perf_counter() - start
sys.stderr.write(result.stderr)
try:
    with open("/proc/self/status") as f:
        peak = next(int(line.split()[1]) for line in f if line.startswith("VmHWM:")) * 1024
except (OSError, StopIteration):
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
print(result.exit_code, peak, elapsed)
"""


def run_measured(args, stdin_file: Path | None = None) -> tuple[int, str, int, float]:
    """Run the CLI in a fresh interpreter: (exit code, stderr, peak RSS bytes, seconds)."""
    with open(stdin_file or os.devnull, "rb") as stdin:
        proc = subprocess.run(
            [sys.executable, "-c", _DRIVER, *map(str, args)],
            stdin=stdin,
            capture_output=True,
            timeout=120,
            text=True,
        )
    code, peak, elapsed = proc.stdout.split()
    return int(code), proc.stderr, int(peak), float(elapsed)


def _patch_sizes(data: bytes, member: str, size: int) -> bytes:
    """Declare ``size`` bytes for a stored ``member`` in its local header and in the central directory."""
    out = bytearray(data)
    name = member.encode()
    for sig, size_at, name_len_at, name_at in ((b"PK\x03\x04", 22, 26, 30), (b"PK\x01\x02", 24, 28, 46)):
        pos = out.find(sig)
        while pos >= 0:
            (n,) = struct.unpack_from("<H", out, pos + name_len_at)
            if bytes(out[pos + name_at : pos + name_at + n]) == name:
                struct.pack_into("<I", out, pos + size_at, size)
                struct.pack_into("<I", out, pos + size_at - 4, size)  # the compressed size: stored members
            pos = out.find(sig, pos + 4)
    return bytes(out)


def _npy_header(shape: tuple[int, ...]) -> bytes:
    head = b"{'descr': '<f8', 'fortran_order': False, 'shape': %s, }" % repr(tuple(shape)).encode()
    head += b" " * (-(10 + len(head) + 1) % 64) + b"\n"
    return b"\x93NUMPY\x01\x00" + len(head).to_bytes(2, "little") + head


def _deflate_bomb(n_bytes: int) -> bytes:
    """A document whose one array inflates to ``n_bytes`` of zeros; honest sizes."""
    n = n_bytes // 8
    env = {
        "arrays": {"a": {"dtype": "float64", "shape": [n]}},
        "format": "staggered-poses",
        "manifest": {},
        "version": 1,
    }
    buf = io.BytesIO()
    # level 1: half the time of 9, and 4.5 MB for a gigabyte of zeros is still a bomb
    with zipfile.ZipFile(buf, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=1) as zf:
        zf.writestr(MANIFEST_MEMBER, json.dumps(env))
        with zf.open("a.npy", "w", force_zip64=True) as member:
            member.write(_npy_header((n,)))
            chunk = bytes(1 << 22)
            for _ in range(n_bytes // len(chunk)):
                member.write(chunk)
    return buf.getvalue()


@pytest.mark.timeout(120)
def test_zip_bombs_and_absurd_shapes_are_refused_before_allocating(documents, tmp_path):
    bombs = {}
    # a member that inflates to a gigabyte (declared honestly, under the 2 GiB array limit)
    bombs["deflate.stag"] = (_deflate_bomb(1 << 30), "zip bomb")
    # a member that declares 8 GiB (stored)
    members = _members(documents["march.bvh"].read_bytes())
    bombs["declared.stag"] = (_patch_sizes(_zip(members), "source.channels.npy", 0xFFFFFFF0), "declares")
    # a stored member and a manifest that agree on 1.5 GB the file does not hold
    n = 190_000_000
    env = {
        "arrays": {"a": {"dtype": "float64", "shape": [n]}},
        "format": "staggered-poses",
        "manifest": {},
        "version": 1,
    }
    liar = _zip({MANIFEST_MEMBER: json.dumps(env).encode(), "a.npy": _npy_header((n,)) + bytes(64)})
    bombs["liar.stag"] = (_patch_sizes(liar, "a.npy", len(_npy_header((n,))) + 8 * n), "corrupt NPZ")
    # absurd shapes, in both containers
    env["arrays"]["a"]["shape"] = [10**6, 10**6]
    bombs["shape.stag"] = (
        _zip({MANIFEST_MEMBER: json.dumps(env).encode(), "a.npy": _npy_header((1,)) + bytes(8)}),
        "over the limit",
    )
    bombs["shape.json"] = (
        json.dumps({**env, "arrays": {"a": {**env["arrays"]["a"], "values": [0.0]}}}).encode(),
        "over the limit",
    )
    for name, (data, needle) in bombs.items():
        path = tmp_path / name
        path.write_bytes(data)
        assert len(data) < 8 << 20
        for args in (["info", path], ["bake", path, "-o", tmp_path / "out"]):
            code, err, peak, elapsed = run_measured(args)
            assert code == 1 and len(err.splitlines()) == 1 and needle in err, (name, err)
            assert peak < MAX_PEAK, f"{name}: peak {peak / 2**20:.0f} MiB"
            assert elapsed < MAX_SECONDS
    assert not (tmp_path / "out").exists()


# --------------------------------------------------------------------------- inputs sized to exhaust memory


def _many_joints_bvh(n: int, chain: bool) -> str:
    parts = [
        "HIERARCHY\nROOT Hips\n{\nOFFSET 0 0 0\nCHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation "
        "Yrotation\n"
    ]
    for i in range(n):
        if chain:
            parts.append(f"JOINT J{i}\n{{\nOFFSET 0 1 0\nCHANNELS 3 Zrotation Xrotation Yrotation\n")
        else:
            parts.append(f"JOINT J{i}\n{{\nOFFSET 0 1 0\nCHANNELS 3 Zrotation Xrotation Yrotation\n}}\n")
    parts.append("}\n" * (n + 1 if chain else 1))
    parts.append("MOTION\nFrames: 1\nFrame Time: 0.1\n" + " ".join(["0"] * (6 + 3 * n)) + "\n")
    return "".join(parts)


@pytest.mark.parametrize("chain", [False, True], ids=["siblings", "chain"])
def test_a_bvh_with_100000_joints_fails_fast(tmp_path, chain):
    path = tmp_path / "many.bvh"
    path.write_text(_many_joints_bvh(100_000, chain))
    code, err, peak, elapsed = run_measured(["info", path])
    assert code == 1 and "more than 10000 joints" in err and len(err.splitlines()) == 1, err
    assert peak < MAX_PEAK, f"peak {peak / 2**20:.0f} MiB"
    assert elapsed < MAX_SECONDS


@pytest.mark.timeout(120)
def test_a_huge_header_line_fails_fast(tmp_path):
    # a 256 MiB line where the disk has room for it (more than MAX_PEAK: held whole
    # it would fail the memory bound; 1 GiB before, four times the writing);
    # otherwise 64 MiB show the header limit
    size = 256 << 20 if shutil.disk_usage(tmp_path).free > 4 << 30 else 64 << 20
    path = tmp_path / "long.bvh"
    with open(path, "w") as f:
        f.write("HIERARCHY\nROOT ")
        chunk = "a" * (1 << 22)
        for _ in range(size // len(chunk)):
            f.write(chunk)
        f.write(
            "\n{\nOFFSET 0 0 0\nCHANNELS 3 Zrotation Xrotation Yrotation\n}\nMOTION\nFrames: 1\n"
            "Frame Time: 0.1\n0 0 0\n"
        )
    try:
        for args, stdin in ((["info", path], None), (["extract", "-", "-o", tmp_path / "out"], path)):
            code, err, peak, elapsed = run_measured(args, stdin)
            assert code == 1 and "no MOTION section in its first 16 MiB" in err, err
            assert len(err.splitlines()) == 1
            assert peak < MAX_PEAK, f"peak {peak / 2**20:.0f} MiB"
            assert elapsed < MAX_SECONDS
        assert not (tmp_path / "out").exists()
    finally:
        path.unlink()


def test_a_c3d_claiming_a_billion_frames_fails_fast(tmp_path):
    import ezc3d

    c3d = ezc3d.c3d(str(SAMPLES / "march.c3d"))
    c3d.add_parameter("POINT", "LONG_FRAMES", np.array([1e9]))
    valid = tmp_path / "long_frames.c3d"
    c3d.write(str(valid))
    base = mu.c3d_base(valid)
    data = mu._set_parameter(base, base.data, "POINT:FRAMES", -1)  # 65535 as a signed INT
    data = mu._set_word(data, 4, 65535)
    claims = {"billion.c3d": (data, "declares 1000000000 frames")}
    # and a header claiming 65535 frames for a file that holds 241
    base = mu.c3d_base(SAMPLES / "march.c3d")
    data = mu._set_parameter(base, base.data, "POINT:FRAMES", 0)
    claims["header.c3d"] = (mu._set_word(data, 4, 65535), "65535 frames")
    for name, (data, needle) in claims.items():
        path = tmp_path / name
        path.write_bytes(data)
        for args in (["info", path], ["extract", path, "-o", tmp_path / "out"]):
            code, err, peak, elapsed = run_measured(args)
            assert code == 1 and needle in err and len(err.splitlines()) == 1, err
            assert peak < MAX_PEAK and elapsed < MAX_SECONDS
    assert not (tmp_path / "out").exists()


def test_a_document_is_not_written_under_a_motion_file_name(tmp_path):
    """`extract walk.bvh -o out.bvh` wrote an NPZ document (a zip) under a
    BVH name; like `bake -o x.stag`, the name is refused (extract before
    reading the clip), in one line, and nothing is written."""
    from .conftest import dev_document, document_file, one_line_error

    src = mocap("cmu_02_01_walk.bvh")
    doc = document_file(dev_document("cmu_02_01_walk.bvh"), tmp_path / "walk.stag")
    for argv, out in (
        (["extract", str(src)], tmp_path / "out.bvh"),
        (["cull", str(doc), "--keep", "5"], tmp_path / "out.C3D"),
    ):
        r = CliRunner().invoke(cli, [*argv, "-o", str(out)])
        one_line_error(r, 2, out.name, "this writes a staggered-pose document, but the name says")
        assert not out.exists()
