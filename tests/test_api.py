"""The public API (``import staggered_cli as st``): its examples run, the
Python pipeline writes the shell pipeline's bytes on every dev file, and bad
input raises a StaggeredError that names the Python argument."""

from __future__ import annotations

import doctest
import importlib
import inspect
import io
import warnings
from pathlib import Path

import pytest
from click.testing import CliRunner

import staggered_cli as st
from staggered_cli.cli.main import cli

from .conftest import BVH_FILES, C3D_FILES, mocap, staggered_warnings

ROOT = Path(__file__).resolve().parents[1]

#: Modules whose docstring examples run here (the public API and its errors).
DOCTEST_MODULES = ("staggered_cli", "staggered_cli.api", "staggered_cli.errors")


@pytest.mark.parametrize("name", DOCTEST_MODULES)
def test_examples_in_docstrings_run(name, monkeypatch):
    monkeypatch.chdir(ROOT)  # examples name data/samples/... and write under out/doctest/
    (ROOT / "out" / "doctest").mkdir(parents=True, exist_ok=True)
    module = importlib.import_module(name)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", st.StaggeredWarning)  # a sample's small warnings are not the point
        result = doctest.testmod(module, optionflags=doctest.ELLIPSIS, raise_on_error=False)
    assert result.failed == 0, f"{result.failed} of {result.attempted} examples failed in {name}"


def test_every_public_function_has_a_summary_and_an_example():
    assert sorted(st.__all__) == sorted(set(st.__all__))
    for name in st.__all__:
        value = getattr(st, name)
        doc = inspect.getdoc(value) or ""
        assert doc.splitlines() and doc.splitlines()[0].strip(), name
        if inspect.isfunction(value):
            assert "Examples\n--------" in doc and ">>> " in doc, f"{name} has no example"


def _shell(*argv: str, data: bytes | None = None) -> bytes:
    result = CliRunner().invoke(cli, list(argv), input=data)
    assert result.exit_code == 0, (argv, result.stderr)
    return result.stdout_bytes


def _succession_kwargs(clip) -> dict:
    """Down the left arm for a skeleton; down three markers for a C3D."""
    if hasattr(clip, "skeleton"):
        return {"joint": "@left-arm"}
    return {"chain": list(clip.labels[:3])}


@pytest.mark.parametrize("name", BVH_FILES + C3D_FILES)
def test_the_python_pipeline_writes_the_shell_pipeline_s_bytes(name, tmp_path):
    path = str(mocap(name))
    clip = st.read(path)
    kwargs = _succession_kwargs(clip)
    option = ["--joint", kwargs["joint"]] if "joint" in kwargs else ["--chain", ",".join(kwargs["chain"])]
    ext = Path(name).suffix
    doc_bytes = _shell("extract", path, "-o", "-")
    culled = _shell("cull", "-", "--keep", "30%", "-o", "-", data=doc_bytes)
    loose = _shell("succession", "-", *option, "--offset", "0.03", "--power", "1.5", "--clamp", "-o", "-", data=culled)
    _shell("bake", "-", "-o", str(tmp_path / f"shell{ext}"), data=loose)

    with staggered_warnings():
        doc = st.extract(clip)
        buffer = io.BytesIO()
        st.write(doc, buffer)
        assert buffer.getvalue() == doc_bytes  # the document itself, source name and checksum included
        doc = st.cull(doc, keep="30%")
        doc = st.succession(doc, offset=0.03, power=1.5, clamp=True, **kwargs)
        st.write(st.bake(doc), tmp_path / f"python{ext}")
    assert (tmp_path / f"python{ext}").read_bytes() == (tmp_path / f"shell{ext}").read_bytes()


@pytest.fixture(scope="module")
def walk():
    return st.extract(st.read(str(mocap("cmu_02_01_walk.bvh"))))


def _c3d_without_markers(tmp: Path) -> Path:
    from .test_hostile_c3d import _no_points

    out = tmp / "zero.c3d"
    _no_points(ROOT / "data" / "samples" / "march.c3d", out)
    return out


BAD = [
    ("truncated BVH", lambda w: st.read(mocap("cmu_02_01_walk.bvh").read_bytes()[:3000]), st.DataError, "<bytes>"),
    ("missing file", lambda w: st.read("no/such/walk.bvh"), st.DataError, "no such file"),
    ("unknown joint", lambda w: st.edit_pose(w, 2, rotate={"LeftArmm": (0, 0, 10)}), st.UsageError, "LeftArm"),
    ("keep 0", lambda w: st.cull(w, keep="0"), st.UsageError, "keep"),
    ("pose past the end", lambda w: st.edit_pose(w, 999, rotate={"LeftArm": (0, 0, 10)}), st.UsageError, "999"),
    ("offset not a number", lambda w: st.succession(w, joint="LeftArm", offset="fast"), st.UsageError, "offset"),
    ("negative fps", lambda w: st.bake(w, fps=-30), st.UsageError, "fps"),
    ("extract of a document", lambda w: st.extract(w), st.UsageError, "motion"),
    ("gain out of range", lambda w: st.detail(w, gain=1e9), st.UsageError, "gain"),
    ("relative_to unknown", lambda w: st.edit_pose(w, 2, exaggerate=1.5, relative_to="sideways"), st.UsageError,
     "relative_to"),
    ("min_spacing negative", lambda w: st.extract(st.read("data/samples/march.bvh"), min_spacing=-1), st.UsageError,
     "min_spacing"),
    ("a document named .bvh", lambda w: st.write(w, "out/doctest/walk.bvh", force=True), st.UsageError, "BVH"),
    ("a C3D with no markers", lambda w: st.read(_c3d_without_markers(ROOT / "out" / "doctest")), st.DataError,
     "no markers"),
]


@pytest.mark.parametrize("what,call,kind,needle", BAD, ids=[b[0] for b in BAD])
def test_bad_input_raises_a_staggered_error_naming_the_argument(walk, monkeypatch, what, call, kind, needle):
    monkeypatch.chdir(ROOT)
    (ROOT / "out" / "doctest").mkdir(parents=True, exist_ok=True)
    with pytest.raises(kind) as caught:
        call(walk)
    text = str(caught.value)
    assert needle in text, text
    assert "--" not in text, f"the library names options, not arguments: {text}"
    assert "\n" not in text
    # no frame of click in the traceback: the library knows no command line
    assert not any("click" in entry.path.parts for entry in caught.traceback), what


def test_the_cli_names_the_option_where_the_library_names_the_argument(walk, tmp_path):
    with pytest.raises(st.UsageError) as caught:
        st.cull(walk, keep="0")
    assert str(caught.value).startswith("keep must keep at least one pose")
    assert caught.value.cli_message().startswith("--keep must keep at least one pose")
    doc = tmp_path / "walk.stag"
    st.write(walk, doc)
    result = CliRunner().invoke(cli, ["cull", str(doc), "--keep", "0", "-o", "-"])
    assert result.exit_code == 2
    assert result.stderr.strip() == f"staggered: {doc}: --keep must keep at least one pose, got '0'"


def test_warnings_are_staggered_warnings_a_caller_can_turn_into_errors(walk):
    with warnings.catch_warnings():
        warnings.simplefilter("error", st.StaggeredWarning)
        with pytest.raises(st.StaggeredWarning, match=r"^keep 10%: keeping 2 poses"):
            st.cull(walk, keep="10%")


def test_values_are_never_changed(walk):
    import numpy as np

    before = [tr.knot_v.copy() for tr in walk.tracks], walk.pose_t.copy()
    st.edit_pose(walk, 2, rotate={"LeftArm": (0, 0, 20)})
    st.succession(walk, joint="LeftArm", offset=0.02, clamp=True)
    st.cull(walk, keep=5)
    assert all(np.array_equal(a, tr.knot_v) for a, tr in zip(before[0], walk.tracks, strict=True))
    assert np.array_equal(before[1], walk.pose_t)


def test_write_refuses_an_existing_file_unless_forced(walk, tmp_path):
    out = tmp_path / "walk.bvh"
    out.write_bytes(b"precious")
    with pytest.raises(st.UsageError, match="exists"):
        st.write(st.bake(walk), out)
    assert out.read_bytes() == b"precious"
    st.write(st.bake(walk), out, force=True)
    assert out.read_bytes().startswith(b"HIERARCHY")
    with out.open("rb") as f:
        assert st.read(f).n_frames == walk.n_frames
