"""BVH reading and writing on every real file of ../shared/mocap."""

from __future__ import annotations

import re

import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import given, settings
from hypothesis import strategies as st

from staggered_cli import quat
from staggered_cli.cli.main import cli
from staggered_cli.errors import DataError
from staggered_cli.io import bvh
from staggered_cli.io.bvh import bvh_bytes, parse_bvh, read_bvh
from staggered_cli.motion import channels_from_local

from .conftest import BVH_FILES, cli_document, mocap, one_line_error

pytestmark = pytest.mark.skipif(not BVH_FILES, reason="../shared/mocap is missing")


def run(args, input=None):
    return CliRunner().invoke(cli, args, input=input)


@pytest.fixture(scope="module", params=BVH_FILES)
def motion(request):
    return request.param, read_bvh(mocap(request.param))


def test_round_trip_is_exact(motion):
    name, m = motion
    back = parse_bvh(bvh_bytes(m))
    assert back.skeleton.names == m.skeleton.names
    assert back.skeleton.channels == m.skeleton.channels
    np.testing.assert_array_equal(back.skeleton.offsets, m.skeleton.offsets)
    np.testing.assert_array_equal(back.skeleton.end_offsets, m.skeleton.end_offsets)
    np.testing.assert_array_equal(back.channels, m.channels)  # the source's numbers, to the bit
    assert back.frame_time_text == m.frame_time_text


def test_written_numbers_equal_the_source_text(motion):
    name, m = motion
    src = mocap(name).read_bytes().replace(b"\r\n", b"\n").replace(b"\r", b"\n")
    out = bvh_bytes(m)
    src_rows = src[src.index(b"MOTION") :].split(b"\n")[3:]
    out_rows = out[out.index(b"MOTION") :].split(b"\n")[3:]
    src_rows = [r.split() for r in src_rows if r.strip()]
    out_rows = [r.split() for r in out_rows if r.strip()]
    assert len(src_rows) == len(out_rows) == m.n_frames
    # equal to the precision the source is written in: as numbers, exactly
    for a, b in zip(src_rows[:: max(1, len(src_rows) // 50)], out_rows[:: max(1, len(src_rows) // 50)], strict=True):
        assert [float(x) for x in a] == [float(x) for x in b]


def test_euler_round_trip_through_quaternions(motion):
    """channels -> quaternions -> channels with the source as reference gives the source."""
    name, m = motion
    rot = m.local_rotations()
    tr = m.local_translations()
    back = channels_from_local(m.skeleton, rot, tr, m.channels)
    assert np.abs(back - m.channels).max() < 1e-6
    wr, wp = m.world()
    from staggered_cli.motion import local_rotations_from_channels
    from staggered_cli.skeleton import forward_kinematics

    wr2, wp2 = forward_kinematics(m.skeleton, local_rotations_from_channels(m.skeleton, back), tr)
    assert np.abs(wp2 - wp).max() < 1e-6 * m.figure_height()


def test_quaternions_agree_with_bvhio(motion):
    bvhio = pytest.importorskip("bvhio")
    name, m = motion
    root = bvhio.readAsBvh(str(mocap(name))).Root
    ours = m.local_rotations()
    frames = np.linspace(0, m.n_frames - 1, min(m.n_frames, 25)).astype(int)
    worst = 0.0
    stack = [root]
    while stack:
        joint = stack.pop()
        stack.extend(joint.Children)
        j = m.skeleton.index(joint.Name)
        if not m.skeleton.has_rotation(j):
            continue
        theirs = np.array(
            [[k.Rotation.w, k.Rotation.x, k.Rotation.y, k.Rotation.z] for k in (joint.Keyframes[f] for f in frames)]
        )
        worst = max(worst, float(np.degrees(quat.angle_between(quat.normalize(theirs), ours[frames, j])).max()))
    assert worst < 1e-4


def test_mixed_euler_orders_are_kept():
    m = read_bvh(mocap("cmu3dsmax_131_02_start_walk_stop.bvh"))
    orders = {m.skeleton.rotation_order(j) for j in range(m.skeleton.n_joints) if m.skeleton.has_rotation(j)}
    assert orders == {"ZYX", "ZXY"}


def test_known_facts_of_the_files():
    m = read_bvh(mocap("cmu_01_01_forward_jumps.bvh"))
    assert (m.n_frames, m.skeleton.n_joints, m.rate, m.frame_time_text) == (2752, 31, 120.0, ".0083333")
    b = read_bvh(mocap("bandai1_walk_normal_001.bvh"))
    assert b.skeleton.names[0] == "joint_Root" and all(len(c) == 6 for c in b.skeleton.channels)
    assert b.rate == 30.0 and b.n_frames == 195
    g = read_bvh(mocap("games105_idle.bvh"))
    assert g.rate == 60.0 and g.skeleton.rotation_order(0) == "XYZ"
    assert 1.3 < g.figure_height() < 2.0  # metres
    assert 20 < m.figure_height() < 35  # CMU units of 5.64 cm


def test_gimbal_lock_has_no_flips():
    """cmu_115_06 bends over through Hips Y = 88 deg: writing an edited motion
    (no reference at the same time) follows the previous frame without jumps."""
    m = read_bvh(mocap("cmu_115_06_pick_up_box.bvh"))
    rot = m.local_rotations()
    # a reference far from the source: the principal triples, then unwrap by the previous frame
    ref = np.zeros_like(m.channels)
    back = channels_from_local(m.skeleton, rot, m.local_translations(), ref)
    # whatever the branch, re-reading gives the same rotations
    from staggered_cli.motion import local_rotations_from_channels

    again = local_rotations_from_channels(m.skeleton, back)
    assert np.degrees(quat.angle_between(again, rot)).max() < 1e-6
    with_source = channels_from_local(m.skeleton, rot, m.local_translations(), m.channels)
    assert np.abs(np.diff(with_source, axis=0)).max() == pytest.approx(
        np.abs(np.diff(m.channels, axis=0)).max(), abs=1e-6
    )


HEAD = b"HIERARCHY\nROOT Hips\n{\n OFFSET 0 0 0\n CHANNELS 3 Xposition Yposition Zposition\n}\nMOTION\nFrames: "


@pytest.mark.parametrize(
    "text, message",
    [
        (b"", "is empty"),
        (b"hello world\n", "not a BVH"),
        (b"\xff\xfeH\x00I\x00", "UTF-16"),
        (b"HIERARCHY\nROOT Hips\n{\n OFFSET 0 0 0\n CHANNELS 3 Xposition Yposition Zposition\n}\n", "no MOTION"),
        (
            HEAD + b"2\nFrame Time: 0.1\n1 2 3\n",
            "declares 2 frames but has 1",
        ),
        (
            HEAD + b"2\nFrame Time: 0.1\n1 2 3\n1 2\n",
            "frame 1 has 2 values",
        ),
        (
            b"HIERARCHY\nROOT Hips\n{\n OFFSET 0 0 0\n CHANNELS 3 Xposition Yposition Wposition\n}\nMOTION\nFrames: 1\nFrame Time: 0.1\n1 2 3\n",  # noqa: E501
            "unknown channel",
        ),
        (
            HEAD + b"1\nFrame Time: 0.1\n1 nan 3\n",
            "not a finite number",
        ),
        (
            HEAD + b"1\nFrame Time: 0.1\n1 x 3\n",
            "'x' is not a number",
        ),
        (
            b"HIERARCHY\nROOT Hips\n{\n OFFSET 0 0 0\n CHANNELS 3 Xposition Yposition Zposition\nMOTION\nFrames: 1\nFrame Time: 0.1\n1 2 3\n",  # noqa: E501
            "ends early",
        ),
        (
            HEAD + b"100000000\nFrame Time: 0.1\n1 2 3\n",
            "declares 100000000 frames but has 1",
        ),
        (HEAD + b"-5\nFrame Time: 0.1\n1 2 3\n", "line 8: frame count -5 is negative"),
        (HEAD + b"0\nFrame Time: 0.1\n", "has no motion frames (Frames: 0)"),
    ],
)
def test_malformed_input_names_the_file(text, message, tmp_path):
    path = tmp_path / "bad.bvh"
    path.write_bytes(text)
    with pytest.raises(DataError) as err:
        read_bvh(path)
    assert message in str(err.value)
    assert str(path) in str(err.value)
    assert "\n" not in str(err.value)


def test_truncated_real_file_fails_cleanly(tmp_path):
    data = mocap("cmu_02_01_walk.bvh").read_bytes()
    for cut in (10, 500, len(data) // 3, len(data) - 7):
        path = tmp_path / f"cut{cut}.bvh"
        path.write_bytes(data[:cut])
        with pytest.raises(DataError):
            read_bvh(path)


def test_crlf_tabs_and_bom_parse_the_same():
    text = mocap("games105_idle.bvh").read_bytes()
    a = parse_bvh(text)
    b = parse_bvh(b"\xef\xbb\xbf" + text.replace(b"\r\n", b"\n").replace(b"  ", b"\t"))
    np.testing.assert_array_equal(a.channels, b.channels)
    assert a.skeleton.names == b.skeleton.names


@pytest.mark.parametrize("name", BVH_FILES)
def test_unedited_round_trip_is_byte_identical_on_every_dev_bvh(name):
    src = mocap(name).read_bytes()
    r = run(["bake", "-", "-o", "-"], input=cli_document(name, ["cull", "--keep", "30%"]))
    assert r.exit_code == 0, r.stderr
    assert r.stdout_bytes == src  # header numbers, CRLF, tabs, column spacing and every token as written


def _motion_tokens(data: bytes) -> tuple[list[bytes], list[bytes]]:
    at = data.index(b"MOTION")
    rest = data[at:].split(None, 6)  # MOTION Frames: N Frame Time: t
    return data[:at].split(), rest[6].split()


def test_an_edit_rewrites_only_the_numbers_it_changes():
    name = "cmu3dsmax_131_02_start_walk_stop.bvh"  # mixed CRLF/LF, numbers like -46.182 among %.4f ones
    src = mocap(name).read_bytes()
    m = parse_bvh(src)
    sk = m.skeleton
    doc = cli_document(
        name, ["cull", "--keep", "30%"], ["succession", "--joint", "@left-arm", "--offset", "0.03", "--clamp"]
    )
    out = run(["bake", "-", "-o", "-"], input=doc).stdout_bytes
    assert out[: src.index(b"MOTION")] == src[: src.index(b"MOTION")]
    assert out.count(b"\r\n") == src.count(b"\r\n") and out.count(b"\n") == src.count(b"\n")
    head_a, a = _motion_tokens(src)
    head_b, b = _motion_tokens(out)
    C = m.channels.shape[1]
    changed = (np.array(a) != np.array(b)).reshape(-1, C)
    arm = np.zeros(C, dtype=bool)
    for j in sk.subtree(sk.index("@left-arm")):
        s, e = m.channel_slices()[j]
        arm[s:e] = True
    assert changed[:, arm].sum() > 1000 and not changed[:, ~arm].any()


def test_a_resampled_bake_keeps_the_header_as_written():
    src = mocap("games105_idle.bvh").read_bytes()  # CRLF, offsets like 0.100000
    out = run(["bake", "-", "--fps", "30", "-o", "-"], input=cli_document("games105_idle.bvh")).stdout_bytes
    at = src.index(b"MOTION")
    assert out[:at] == src[:at]
    lines = out[at:].split(b"\r\n")
    assert lines[1:3] == [b"Frames: 100", b"Frame Time:   0.0333333"]
    assert b"\n" not in out.replace(b"\r\n", b"")
    assert parse_bvh(out).channels.shape == (100, 63)


def test_a_document_whose_source_text_is_not_the_source_is_refused():
    from staggered_cli.io.container import document_bytes, parse_document

    manifest, arrays = parse_document(cli_document("bandai2_run_normal_001.bvh"), "doc")
    text = arrays["source.bvh"].copy()
    text[text.tobytes().index(b"Hips")] = ord("X")  # a header that no longer matches
    arrays["source.bvh"] = text
    r = run(["bake", "-", "-o", "-"], input=document_bytes(manifest, arrays, "npz"))
    one_line_error(r, 1, "<stdin>", "source.bvh is not the source file")
    del arrays["source.bvh"]  # a document without the text still bakes, in the source's number format
    r = run(["bake", "-", "-o", "-"], input=document_bytes(manifest, arrays, "npz"))
    assert r.exit_code == 0, r.stderr
    np.testing.assert_allclose(
        parse_bvh(r.stdout_bytes).channels,
        parse_bvh(mocap("bandai2_run_normal_001.bvh").read_bytes()).channels,
        atol=1e-6,
    )


@settings(max_examples=200, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.sampled_from(["0", "-1.5", "12.345678", "1e-05", "+3.", ".25"]),
            st.sampled_from([" ", "\t", "  ", "\r\n", "\n", " \t\n", "\x0b", "\x0c"]),
            st.booleans(),
        ),
        min_size=1,
        max_size=40,
    ),
    st.booleans(),
    st.booleans(),
)
def test_spliced_tokens_equal_the_tokens_replaced_one_by_one(items, lead, trail):
    """The writer's splice (one gather over the bytes) is the source with
    the chosen tokens replaced and every other byte kept, as replacing the
    tokens of a white-space split does."""
    text = (" \n" if lead else "") + "".join(tok + sep for tok, sep, _ in items)
    if not trail:
        text = text.rstrip(" \t\r\n\x0b\x0c")
    data = b"#" + text.encode("ascii") + b"#"  # the piece is data[1:-1]
    a, b = 1, len(data) - 1
    starts, ends = bvh._token_spans(data, a, b)
    pieces = re.split(rb"(\s+)", data[a:b])
    first = 2 if pieces and pieces[0] == b"" else 0
    tokens = pieces[first::2]
    tokens = tokens[:-1] if tokens and tokens[-1] == b"" else tokens
    assert [data[a + s : a + e] for s, e in zip(starts, ends, strict=True)] == tokens
    which = np.flatnonzero([chosen for _, _, chosen in items][: len(tokens)])
    if not len(which):
        return
    new = [f"N{j}x" * (j % 3 + 1) for j in range(len(which))]
    for i, tok in zip(which.tolist(), new, strict=True):
        pieces[first + 2 * i] = tok.encode()
    got = bvh._spliced(data, a, b, starts[which], ends[which], " ".join(new).encode())
    assert got == b"".join(pieces)


def test_number_format_counts_the_same_without_exponents():
    """The sample's decimals and digits counted on tokens without an
    exponent (every file seen) and with the general rule (which a token
    '0e0', of no decimals or digits, switches on): the same format."""
    from staggered_cli.io.bvh import _number_format

    rng = np.random.default_rng(2)
    tokens = ["1.5", "-0.000", "+3", "0", "-0", "00.1200", "12.", "-.5", "+.0", "0.0001230", "123.456789", "-98.76"]
    for _ in range(300):
        sample = list(rng.choice(tokens, size=int(rng.integers(1, 8))))
        values = np.array([float(t) for t in sample])
        assert _number_format(sample, values) == _number_format([*sample, "0e0"], values), sample


def test_scale_to_digits_is_the_power_of_ten_of_each_value():
    """The table of powers gives each value's ``10 ** (digits - 1 -
    floor(log10 |x|))`` to the bit, over magnitudes from 1e-290 to 1e9."""
    from staggered_cli.io.bvh import _scale_to_digits

    rng = np.random.default_rng(4)
    x = rng.choice([-1.0, 1.0], 5000) * 10.0 ** rng.uniform(-290, 9, 5000)
    for digits in (1, 6, 17):
        want = 10.0 ** (digits - 1 - np.floor(np.log10(np.abs(x))))
        assert np.array_equal(_scale_to_digits(x, digits), want)
    assert _scale_to_digits(np.zeros(0), 6).size == 0
