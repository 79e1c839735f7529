"""Timing edits (succession, randomize, retime): what they move and what they
leave, and the contacts that move with them."""

from __future__ import annotations

import numpy as np

from staggered_cli.io.schema import from_parts, to_parts
from staggered_cli.ops import timing
from staggered_cli.ops.bake import bake

from .conftest import staggered_warnings


def test_clamp_stops_short_and_moves_only_the_chosen_poses(cmu_walk):
    _, doc = cmu_walk
    out = timing.succession(doc, -0.02, 1.5, joint="LeftShoulder", clamp=True)
    assert out.n_poses == doc.n_poses
    mask = timing.select_poses(doc, [3])
    one = timing.randomize(doc, 0.2, 0, poses=mask, clamp=True)
    changed = np.any(one.refinements() != doc.refinements(), axis=1)
    assert not changed[np.arange(doc.n_poses) != 3].any()


def test_contacts_move_with_a_retimed_pose(cmu_walk):
    _, doc = cmu_walk
    c = doc.constraints[len(doc.constraints) // 2]
    k = int(np.argmin(np.abs(doc.pose_t - c.start)))
    k = min(max(k, 1), doc.n_poses - 2)
    dt = 0.3 * (doc.pose_t[k + 1] - doc.pose_t[k])
    moved = timing.retime_pose(doc, k, doc.pose_t[k] + dt)
    old = {(x.joint, x.start) for x in doc.constraints}
    shifted = [x for x in moved.constraints if (x.joint, x.start) not in old]
    assert shifted and all(x.source_span != (x.start, x.end) for x in shifted)
    manifest, arrays = to_parts(moved)
    assert from_parts(manifest, arrays).constraints == moved.constraints
    # the unedited parts keep their constraints and the bake stays finite
    assert np.all(np.isfinite(bake(moved).channels))


def test_variables_that_never_move_are_not_retimed(bandai_run):
    """Bandai has constant position channels on every joint: retiming them
    changed nothing visible and could only get the edit refused."""
    _, doc = bandai_run
    out = timing.succession(doc, 0.02, 1.0, joint="Shoulder_L")
    names = doc.variable_names
    changed = np.any(out.refinements() != doc.refinements(), axis=0)
    assert not any(changed[i] for i, n in enumerate(names) if n.endswith(".position"))
    assert changed[names.index("LowerArm_L")]


def test_retiming_a_document_without_inner_poses_says_it_changes_nothing(tmp_path):
    """The idle clip extracts to its first and last pose only: succession
    and randomize say, in one line, that there is nothing to retime (they
    used to exit 0 in silence with the motion unchanged)."""
    from click.testing import CliRunner

    from staggered_cli.cli.main import cli

    from .conftest import dev_document, document_file

    doc = dev_document("games105_idle.bvh")
    assert doc.n_poses == 2
    path = document_file(doc, tmp_path / "idle.stag")
    for argv in (
        ["succession", str(path), "--joint", "@left-arm", "--offset", "0.03"],
        ["randomize", str(path), "--tau", "0.02", "--seed", "3"],
    ):
        r = CliRunner().invoke(cli, [*argv, "-o", str(tmp_path / "out.stag"), "--force"])
        assert r.exit_code == 0, r.stderr
        lines = r.stderr.splitlines()
        assert len(lines) == 1 and "only its first and last pose" in lines[0] and "nothing to retime" in lines[0], lines


def test_a_pose_moves_no_closer_than_half_a_frame_to_a_neighbour(bandai_run):
    """A pose moved within half a frame of a neighbour would squeeze the
    motion between them into less than a frame: refused in one line, as a
    move past the neighbour is."""
    import pytest

    from staggered_cli.errors import UsageError

    _, doc = bandai_run
    ft = doc.frame_time
    for t in (doc.pose_t[5] - 0.4 * ft, doc.pose_t[3] + 1e-6, doc.pose_t[5]):
        with pytest.raises(
            UsageError, match=r"pose 4 can move only between its neighbours \(.*\) and at least half a frame from each"
        ):
            timing.retime_pose(doc, 4, t)
    moved = timing.retime_pose(doc, 4, doc.pose_t[4] + ft)
    assert moved.pose_t[4] == doc.pose_t[4] + ft


def test_a_succession_that_moves_nothing_says_so(bandai_run):
    """A leaf joint (nothing below it), a chain of one or ``--offset 0``
    keep every knot where it is: one warning line says so instead of silence."""
    _, doc = bandai_run
    for kwargs, needle in (
        ({"joint": "Hand_L", "offset": 0.03}, "joint Hand_L: no joint below it has a variable"),
        ({"chain": ["Hand_L"], "offset": 0.03}, "chain Hand_L: the first of a chain keeps its timing"),
        ({"joint": "Shoulder_L", "offset": 0.0}, "offset 0: nothing to retime"),
    ):
        with staggered_warnings() as seen:
            out = timing.succession(doc, kwargs.pop("offset"), 1.5, **kwargs)
        assert [s for s in seen if s.startswith(needle)], (needle, seen)
        assert any("nothing to retime" in s for s in seen)
        assert np.array_equal(out.refinements(), doc.refinements())
    with staggered_warnings() as seen:
        timing.succession(doc, 0.01, 1.0, joint="Shoulder_L", clamp=True)
    assert not [s for s in seen if "nothing to retime" in s]


def test_a_knot_crossing_names_its_time_to_the_frame():
    """The time a crossing names has the frame's decimals (3 at 120 Hz), as
    every other time in a message, when the frame time is known."""
    import pytest

    from staggered_cli.errors import KnotOrderError
    from staggered_cli.model.knots import check_knot_order

    ptr, t = np.array([0, 3]), np.array([0.0, 0.90166, 0.90166])
    with pytest.raises(KnotOrderError, match=r"knots of 'Toe' would cross at 0\.902 s$"):
        check_knot_order(ptr, t, ("Toe",), 1 / 120)
    with pytest.raises(KnotOrderError, match=r"would cross at 0\.9017 s$"):
        check_knot_order(ptr, t, ("Toe",))
