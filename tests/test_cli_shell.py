"""The command-line shell: global options, the one error path, shared options
and `info`, on real motion capture from ../shared/mocap."""

from __future__ import annotations

import json
import logging
import os
import subprocess
import sys
from pathlib import Path

import click
import numpy as np
import pytest
from click.testing import CliRunner

from staggered_cli import __version__
from staggered_cli.cli import options
from staggered_cli.cli.main import COMMANDS, EXIT_BROKEN_PIPE, EXIT_INTERRUPTED, StaggeredGroup, cli
from staggered_cli.errors import DataError, StaggeredError, UsageError
from staggered_cli.io import files
from staggered_cli.io import summary as info_ops
from staggered_cli.io.container import document_bytes, parse_document

ROOT = Path(__file__).resolve().parents[1]
MOCAP = Path(__file__).resolve().parents[1].parent / "shared" / "mocap"


def mocap(name: str) -> Path:
    path = MOCAP / name
    if not path.exists():
        pytest.skip(f"{path} is not there (../shared/mocap must sit beside the checkout)")
    return path


def run(args, input=None, group=None):
    return CliRunner().invoke(group or cli, args, input=input)


def assert_one_line_error(result, code, *needles):
    assert result.exit_code == code, (result.exit_code, result.stderr, result.exception)
    lines = result.stderr.splitlines()
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith("staggered: "), lines[0]
    for needle in needles:
        assert needle in lines[0]
    assert "Traceback" not in result.output + result.stderr
    assert result.stdout == ""


# ----------------------------------------------------------------- global options


def test_version():
    result = run(["--version"])
    assert result.exit_code == 0
    assert result.stdout.strip() == f"staggered {__version__}"


def test_help_lists_every_command():
    result = run(["--help"])
    assert result.exit_code == 0
    listed = result.stdout.split("Commands:")[1]
    for name in COMMANDS:
        assert f"  {name} " in listed
    for option in ("--version", "--verbose", "--quiet", "--debug"):
        assert option in result.stdout


def test_start_up_and_help_do_not_import_heavy_modules():
    code = (
        "import sys\n"
        "from staggered_cli.cli.main import cli\n"
        "try:\n    cli(['--help'], prog_name='staggered')\nexcept SystemExit:\n    pass\n"
        "heavy = sorted(m for m in ('numpy', 'scipy', 'matplotlib', 'ezc3d') if m in sys.modules)\n"
        "print('HEAVY', heavy, file=sys.stderr)\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert "HEAVY []" in proc.stderr


def test_python_dash_m_and_completion_script():
    proc = subprocess.run(
        [sys.executable, "-m", "staggered_cli", "--version"], capture_output=True, text=True, timeout=60
    )
    assert proc.returncode == 0 and proc.stdout.strip() == f"staggered {__version__}"
    env = {**os.environ, "_STAGGERED_COMPLETE": "bash_source"}
    proc = subprocess.run([sys.executable, "-m", "staggered_cli"], capture_output=True, text=True, timeout=60, env=env)
    assert proc.returncode == 0
    assert "_STAGGERED_COMPLETE" in proc.stdout and "complete " in proc.stdout


def test_completion_lists_commands():
    env = {"_STAGGERED_COMPLETE": "bash_complete", "COMP_WORDS": "staggered in", "COMP_CWORD": "1"}
    result = CliRunner().invoke(cli, [], env=env, prog_name="staggered")
    assert "plain,info" in result.stdout


def test_real_process_error_is_one_line_without_traceback(tmp_path):
    missing = tmp_path / "nope.bvh"
    proc = subprocess.run(
        [sys.executable, "-m", "staggered_cli", "info", str(missing)], capture_output=True, text=True, timeout=60
    )
    assert proc.returncode == 1
    assert proc.stdout == ""
    assert proc.stderr.splitlines() == [f"staggered: {missing}: cannot read: no such file"]


# ----------------------------------------------------------------- info


def test_info_bvh_table_and_json():
    path = mocap("cmu3dsmax_131_02_start_walk_stop.bvh")
    result = run(["info", "--json", str(path)])
    assert result.exit_code == 0, result.stderr
    assert result.stderr == ""
    data = json.loads(result.stdout)
    assert list(data) == sorted(data)  # sort_keys
    assert data["kind"] == "bvh"
    assert data["file"] == path.name
    assert data["frames"] == 1247
    assert data["frame_time"] == pytest.approx(0.0083333, abs=0)
    assert data["frame_time_text"] == ".0083333"
    assert data["rate"] == 120.0
    assert data["duration"] == pytest.approx(1247 * 0.0083333, abs=1e-6)
    assert data["joints"] == 31 and len(data["joint_names"]) == 31 and data["joint_names"][0] == "Hips"
    assert data["channels"] == 96
    # the 3dsMax conversion mixes two Euler orders in one file
    assert data["euler_orders"] == {"ZXY": 12, "ZYX": 19}
    # CMU units: a person is a few tens of units tall
    assert 15 < data["figure_height"] < 40

    table = run(["info", str(path)])
    assert table.exit_code == 0
    rows = dict(line.split(None, 1) for line in table.stdout.splitlines())
    assert rows["frames"] == "1247"
    assert rows["frame_time"] == ".0083333 s"
    assert rows["euler_orders"] == "ZXY 12, ZYX 19"
    # aligned: every value starts in the same column
    starts = {len(line) - len(line.split(None, 1)[1]) for line in table.stdout.splitlines()}
    assert len(starts) == 1


def test_info_c3d():
    path = mocap("c3dorg_sample01_Eb015pi_walk.c3d")
    result = run(["info", "--json", str(path)])
    assert result.exit_code == 0, result.stderr
    data = json.loads(result.stdout)
    assert data["kind"] == "c3d"
    assert data["frames"] == 450
    assert data["rate"] == 50.0
    assert data["frame_time"] == 0.02
    assert data["duration"] == 9.0
    assert data["markers"] == 26 and data["marker_labels"][:3] == ["RFT1", "RFT2", "RFT3"]
    assert data["units"] == "mm"
    # MANIFEST: 10 of 26 markers have gaps, 1.9 % of samples missing
    assert data["markers_with_gaps"] == 10
    assert data["gap_fraction"] == pytest.approx(0.019, abs=0.001)
    assert 500 < data["figure_size"] < 2500  # mm


def test_info_reads_stdin_and_detects_by_content(tmp_path):
    path = mocap("bandai2_run_normal_001.bvh")
    from_file = json.loads(run(["info", "--json", str(path)]).stdout)
    result = run(["info", "--json", "-"], input=path.read_bytes())
    assert result.exit_code == 0, result.stderr
    from_stdin = json.loads(result.stdout)
    assert from_stdin.pop("file") == "<stdin>"
    from_file.pop("file")
    assert from_stdin == from_file
    # the extension means nothing: a BVH named .c3d with a BOM and blank lines is a BVH
    odd = tmp_path / "walk.c3d"
    odd.write_bytes(b"\xef\xbb\xbf\r\n  " + path.read_bytes())
    result = run(["info", "--json", str(odd)])
    assert result.exit_code == 0, result.stderr
    assert json.loads(result.stdout)["frames"] == 68


# ----------------------------------------------------------------- the error path


@pytest.mark.parametrize(
    ("content", "needle"),
    [
        (b"", "empty file"),
        (b"hello, world\n", "not a BVH, C3D or staggered-poses document"),
        (b"PK\x03\x04 truncated", "truncated or corrupt NPZ document"),
        (b'{"format": "staggered-poses", "version": 1, "arrays": {}', "malformed"),
    ],
)
def test_bad_input_is_one_line_exit_1(tmp_path, content, needle):
    bad = tmp_path / "bad.file"
    bad.write_bytes(content)
    assert_one_line_error(run(["info", str(bad)]), 1, str(bad), needle)


def test_truncated_bvh_is_one_line_exit_1(tmp_path):
    data = mocap("bandai2_run_normal_001.bvh").read_bytes()
    cut = tmp_path / "cut.bvh"
    cut.write_bytes(data[: len(data) * 2 // 3])
    assert_one_line_error(run(["info", str(cut)]), 1, str(cut))


def test_missing_file_and_directory(tmp_path):
    assert_one_line_error(run(["info", str(tmp_path / "nope.bvh")]), 1, "nope.bvh", "no such file")
    assert_one_line_error(run(["info", str(tmp_path)]), 1, str(tmp_path), "directory")


def test_click_usage_errors_exit_2():
    result = run(["info"])
    assert result.exit_code == 2
    assert "Missing argument" in result.stderr and "Traceback" not in result.stderr
    assert run(["--no-such-option"]).exit_code == 2
    assert run(["no-such-command"]).exit_code == 2


def test_debug_lets_the_exception_through(tmp_path):
    result = CliRunner().invoke(cli, ["--debug", "info", str(tmp_path / "nope.bvh")])
    assert result.exit_code == 1
    assert isinstance(result.exception, DataError)


def test_internal_error_is_one_line(monkeypatch, tmp_path):
    path = mocap("bandai2_run_normal_001.bvh")

    def boom(*args, **kwargs):
        raise ZeroDivisionError("oops\nsecond line")

    monkeypatch.setattr(info_ops, "summarize", boom)
    result = run(["info", str(path)])
    assert_one_line_error(result, 1, "internal error: ZeroDivisionError: oops second line", "--debug")
    result = CliRunner().invoke(cli, ["--debug", "info", str(path)])
    assert isinstance(result.exception, ZeroDivisionError)


def _raising_group() -> StaggeredGroup:
    group = StaggeredGroup(name="staggered")

    def add(name, exc):
        def callback():
            click.echo("partial")
            raise exc

        group.add_command(click.Command(name, callback=callback))

    add("data", DataError("bad frame 3", source="x.bvh"))
    add("usage", UsageError("unknown joint 'Foo'"))
    add("plain", StaggeredError("multi\nline"))
    add("interrupt", KeyboardInterrupt())
    add("pipe", BrokenPipeError(32, "Broken pipe"))
    add("bug", RuntimeError("boom"))
    return group


@pytest.mark.parametrize(
    ("command", "code", "message"),
    [
        ("data", 1, "staggered: x.bvh: bad frame 3"),
        ("usage", 2, "staggered: unknown joint 'Foo'"),
        ("plain", 1, "staggered: multi line"),
        ("bug", 1, "staggered: internal error: RuntimeError: boom (run with --debug for the traceback)"),
    ],
)
def test_error_path_exit_codes(command, code, message):
    result = run([command], group=_raising_group())
    assert result.exit_code == code
    assert result.stderr.splitlines() == [message]


def test_interrupt_and_broken_pipe():
    result = run(["interrupt"], group=_raising_group())
    assert result.exit_code == EXIT_INTERRUPTED == 130
    assert "Traceback" not in result.stderr
    result = run(["pipe"], group=_raising_group())
    assert result.exit_code == EXIT_BROKEN_PIPE
    assert result.stderr == ""


def test_verbose_and_quiet_set_logging_on_stderr():
    group = StaggeredGroup(name="staggered", params=cli.params, callback=cli.callback)

    def talk():
        log = logging.getLogger("staggered_cli.test")
        log.debug("a debug line")
        log.info("an info line")
        log.warning("a warning line")
        click.echo("data")

    group.add_command(click.Command("talk", callback=talk))
    default = run(["talk"], group=group)
    assert default.stdout == "data\n"
    assert default.stderr == "staggered: WARNING: a warning line\n"
    verbose = run(["-v", "talk"], group=group)
    assert "an info line" in verbose.stderr and "a debug line" not in verbose.stderr
    assert "a debug line" in run(["-vv", "talk"], group=group).stderr
    quiet = run(["-q", "talk"], group=group)
    assert quiet.stderr == "" and quiet.stdout == "data\n"


# ----------------------------------------------------------------- shared options: output


def _copy_group() -> StaggeredGroup:
    """A command built only from the shared options: document in, document out."""

    @click.command("copy")
    @options.input_argument
    @options.output_option
    @options.force_option
    @options.format_option
    def copy(input_path, output, force, fmt):
        options.check_output(output, force)
        manifest, arrays = parse_document(*options.read_input(input_path))  # the container alone, no schema
        options.emit(output, document_bytes(manifest, arrays, options.document_format(fmt, output)), force)

    group = StaggeredGroup(name="staggered")
    group.add_command(copy)
    return group


MANIFEST = {"frame_time": 0.0083333, "names": ["Hips", "LeftUpLeg"]}
ARRAYS = {"pose_t": np.array([0.0, 0.5, -0.0]), "v": np.array([[1.0, np.nan], [np.inf, 2.0]])}


@pytest.fixture()
def doc_file(tmp_path):
    path = tmp_path / "in.stag"
    path.write_bytes(document_bytes(MANIFEST, ARRAYS, "npz"))
    return path


def test_output_refused_without_force(tmp_path, doc_file):
    out = tmp_path / "out.stag"
    out.write_bytes(b"precious")
    result = run(["copy", str(doc_file), "-o", str(out)], group=_copy_group())
    assert_one_line_error(result, 2, str(out), "--force")
    assert out.read_bytes() == b"precious"
    result = run(["copy", str(doc_file), "-o", str(out), "--force"], group=_copy_group())
    assert result.exit_code == 0, result.stderr
    assert out.read_bytes() == doc_file.read_bytes()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.stag", "out.stag"]  # no temporary left


def test_output_format_from_extension_and_option(tmp_path, doc_file):
    as_json = tmp_path / "out.json"
    assert run(["copy", str(doc_file), "-o", str(as_json)], group=_copy_group()).exit_code == 0
    assert as_json.read_bytes() == document_bytes(MANIFEST, ARRAYS, "json")
    forced = tmp_path / "out.data"
    assert run(["copy", str(doc_file), "-o", str(forced), "--format", "json"], group=_copy_group()).exit_code == 0
    assert forced.read_bytes().startswith(b"{")
    assert run(["copy", str(doc_file), "--format", "yaml"], group=_copy_group()).exit_code == 2


def test_output_to_stdout_and_pipeline(doc_file):
    result = run(["copy", str(doc_file), "-o", "-"], group=_copy_group())
    assert result.exit_code == 0
    assert result.stdout_bytes == doc_file.read_bytes()
    # stdin to stdout, as in a pipeline, json this time
    piped = run(["copy", "-", "--format", "json"], input=result.stdout_bytes, group=_copy_group())
    assert piped.exit_code == 0
    manifest, arrays = parse_document(piped.stdout_bytes, "<stdout>")
    assert manifest == MANIFEST
    assert np.array_equal(arrays["v"], ARRAYS["v"], equal_nan=True)


def test_motion_where_a_document_is_needed_is_a_usage_error():
    path = mocap("bandai2_run_normal_001.bvh")
    result = run(["cull", str(path), "--keep", "3", "-o", "-"])
    assert_one_line_error(result, 2, path.name, "staggered extract")


def test_output_into_missing_directory_or_onto_a_directory(tmp_path, doc_file):
    result = run(["copy", str(doc_file), "-o", str(tmp_path / "no" / "out.stag")], group=_copy_group())
    assert_one_line_error(result, 2, "does not exist")
    result = run(["copy", str(doc_file), "-o", str(tmp_path), "--force"], group=_copy_group())
    assert_one_line_error(result, 2, "directory")
    # a file where a folder of the path should be is named as such, not as missing
    (tmp_path / "walk.stag").write_bytes(b"x")
    for sub in ("walk.stag/out.stag", "walk.stag/a/out.stag"):
        result = run(["copy", str(doc_file), "-o", str(tmp_path / sub)], group=_copy_group())
        assert_one_line_error(result, 2, f"{tmp_path / 'walk.stag'}' is a file, not a directory")


class _FakeTerminal:
    def __init__(self):
        self.written = b""
        self.buffer = self

    def isatty(self):
        return True

    def write(self, data):
        self.written += data

    def flush(self):
        pass


def test_binary_document_refused_on_a_terminal(monkeypatch):
    fake = _FakeTerminal()
    monkeypatch.setattr(sys, "stdout", fake)
    with pytest.raises(UsageError, match=r"-o FILE or --format json"):
        options.emit("-", document_bytes(MANIFEST, ARRAYS, "npz"), force=False)
    assert fake.written == b""
    text = document_bytes(MANIFEST, ARRAYS, "json")
    options.emit("-", text, force=False)
    assert fake.written == text


# ----------------------------------------------------------------- files


def test_write_atomic_leaves_nothing_on_failure(tmp_path, monkeypatch):
    out = tmp_path / "out.bin"

    def failing_fsync(fd):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "fsync", failing_fsync)
    with pytest.raises(StaggeredError, match="No space left") as info:
        files.write_atomic(str(out), b"x" * 1000, force=False)
    assert info.value.exit_code == 1
    assert list(tmp_path.iterdir()) == []
    out.write_bytes(b"old")
    with pytest.raises(StaggeredError):
        files.write_atomic(str(out), b"new", force=True)
    assert out.read_bytes() == b"old"
    assert [p.name for p in tmp_path.iterdir()] == ["out.bin"]


def test_write_atomic_mode_follows_umask(tmp_path):
    out = tmp_path / "out.bin"
    files.write_atomic(str(out), b"data", force=False)
    mask = os.umask(0)
    os.umask(mask)
    assert out.stat().st_mode & 0o777 == 0o666 & ~mask


def test_read_bytes_limits(tmp_path):
    big = tmp_path / "big.bvh"
    big.write_bytes(b"x" * 1000)
    with pytest.raises(DataError, match="more than the limit") as info:
        files.read_bytes(str(big), limit=999)
    assert str(big) in str(info.value)
    assert files.read_bytes(str(big), limit=1000) == (b"x" * 1000, str(big))


def test_read_bytes_from_a_fifo(tmp_path):
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    writer = subprocess.Popen(["sh", "-c", f"printf 'HIERARCHY' > '{fifo}'"])
    try:
        assert files.read_bytes(str(fifo)) == (b"HIERARCHY", str(fifo))
    finally:
        writer.wait(timeout=10)


def test_detect_kind():
    assert options.detect_kind(document_bytes({}, {}, "npz")) == "document"
    assert options.detect_kind(b'  {"format": "staggered-poses"}') == "document"
    assert options.detect_kind(b"\x02\x50" + bytes(510)) == "c3d"
    assert options.detect_kind(b"\xef\xbb\xbf\n\tHIERARCHY\nROOT Hips") == "bvh"
    with pytest.raises(ValueError, match="empty"):
        options.detect_kind(b"")
    with pytest.raises(ValueError, match="not a BVH"):
        options.detect_kind(b"MOTION\nFrames: 1")


def test_info_on_a_document_npz_and_json(tmp_path):
    from staggered_cli.io.schema import to_parts
    from staggered_cli.model.variables import from_motion

    sample = ROOT / "data" / "samples" / "march.bvh"
    if not sample.exists():
        pytest.skip(f"{sample} is not there")
    motion = options.load_input(str(sample))
    end = (motion.n_frames - 1) * motion.frame_time
    doc = from_motion(motion, np.array([0.0, 1.0, end]), source_name=sample.name)
    manifest, arrays = to_parts(doc)
    for fmt in ("npz", "json"):
        path = tmp_path / f"march.{fmt}"
        path.write_bytes(document_bytes(manifest, arrays, fmt))
        result = run(["info", "--json", "-"], input=path.read_bytes())
        assert result.exit_code == 0, result.stderr
        data = json.loads(result.stdout)
        assert data["kind"] == "document" and data["file"] == "<stdin>"
        assert data["frames"] == motion.n_frames
        assert data["frame_time"] == motion.frame_time
        assert len(data["poses"]) == 3
        table = run(["info", str(path)])
        assert table.exit_code == 0, table.stderr
        assert "poses" in table.stdout and "index 2" in table.stdout


def test_write_to_a_device_or_fifo_in_place(tmp_path):
    files.write_atomic(os.devnull, b"discarded", force=False)
    assert os.path.exists(os.devnull) and not os.path.isfile(os.devnull)
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    reader = subprocess.Popen(["cat", str(fifo)], stdout=subprocess.PIPE)
    files.write_atomic(str(fifo), b"through the fifo", force=False)
    assert reader.communicate(timeout=10)[0] == b"through the fifo"
