"""Partial poses (issue #37): poses that own one body part's variables.

Real files: the CMU walk (cmu_02_01, 120 Hz, 31 joints) with left-arm poses
inserted by hand between its whole-body poses; the bundled march; a
version 2 document written before partial poses existed
(tests/fixtures/march_v2.stag, ``staggered extract data/samples/march.bvh``
at the commit before this change) with the SHA-256 of its bakes then.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import staggered_cli as st
from staggered_cli.cli.main import cli
from staggered_cli.errors import UsageError
from staggered_cli.io.schema import DOCUMENT_VERSION, from_parts, to_parts
from staggered_cli.ops import cull, timing
from staggered_cli.ops.bake import bake

from .conftest import dev_document, document_file, staggered_warnings

FIXTURES = Path(__file__).resolve().parent / "fixtures"
WALK = "cmu_02_01_walk.bvh"
#: bakes of tests/fixtures/march_v2.stag by the code before partial poses:
#: as it is, and after ``edit-pose --pose 3 --rotate LeftArm=10,0,5``
V2_BAKE = "7efad085b8375b3161c942825ce22dabb1874b0fd40e3981d706dc1ffcf6f0f8"
V2_EDITED_BAKE = "f20c2a30f0eae48a50b8d2d4fedbb394259fed029e9591b94b89807ca203958e"


def run(args, input=None):
    return CliRunner().invoke(cli, [str(a) for a in args], input=input)


def midpoints(doc, n: int, start: int = 2) -> list[float]:
    """Times halfway between whole-body poses start, start+2, ... (n of them)."""
    t = doc.pose_t
    return [float(0.5 * (t[k] + t[k + 1])) for k in range(start, start + 2 * n, 2)]


@pytest.fixture(scope="module")
def walk():
    return dev_document(WALK)


@pytest.fixture(scope="module")
def arm_walk(walk):
    """The walk with four @left-arm poses between its whole-body poses."""
    return cull.add_poses(walk, midpoints(walk, 4), "@left-arm")


def channel_columns(doc, mask: np.ndarray) -> np.ndarray:
    """(C,) bool: the BVH channels of the joints whose variables ``mask`` (V,) selects."""
    sk = doc.source.skeleton
    targets = np.concatenate([tr.targets for tr in doc.tracks])
    joints = np.zeros(sk.n_joints, dtype=bool)
    joints[targets[mask]] = True
    return np.repeat(joints, [len(c) for c in sk.channels])


def variable_arrays(doc, i: int) -> tuple:
    """Knot times, values, poses and displacement samples of global variable ``i``."""
    for tr in doc.tracks:
        if i < tr.n_vars:
            k, s = tr.knots.of(i), tr.samples(i)
            return tr.knot_t[k], tr.knot_v[k], tr.samp_s[s], tr.samp_d[s], tr.tan_a[tr.seg_ptr[i] : tr.seg_ptr[i + 1]]
        i -= tr.n_vars
    raise IndexError(i)


def same_variables(a, b, mask: np.ndarray) -> bool:
    return all(
        all(np.array_equal(x, y) for x, y in zip(variable_arrays(a, i), variable_arrays(b, i), strict=True))
        for i in np.flatnonzero(mask)
    )


# --- the representation ----------------------------------------------------------


def test_parts_own_their_limbs_and_the_root_belongs_to_none(walk):
    names = walk.variable_names
    arm = [n for n, m in zip(names, walk.part_mask("@left-arm"), strict=True) if m]
    assert arm[:4] == ["LeftShoulder", "LeftArm", "LeftForeArm", "LeftHand"]
    assert all(n.startswith(("Left", "LThumb")) for n in arm)
    spine = [n for n, m in zip(names, walk.part_mask("@spine"), strict=True) if m]
    assert "Spine" in spine and "Neck" not in spine and "LeftShoulder" not in spine and "Hips" not in spine
    masks = [walk.part_mask(p) for p in ("@left-arm", "@right-arm", "@left-leg", "@right-leg", "@spine", "@head")]
    assert np.all(np.sum(masks, axis=0) <= 1)  # the parts do not overlap
    root = [i for i, n in enumerate(names) if n in ("Hips", "Hips.position")]
    assert len(root) == 2 and not np.any(np.array(masks)[:, root])
    assert walk.part_mask(None).all()


def test_a_partial_pose_is_inserted_losslessly_and_only_in_its_part(walk, arm_walk):
    mask = walk.part_mask("@left-arm")
    assert arm_walk.n_poses == walk.n_poses + 4
    assert [p for p in arm_walk.pose_part if p] == ["@left-arm"] * 4
    owns = arm_walk.owns()
    new = [k for k, p in enumerate(arm_walk.pose_part) if p]
    assert np.array_equal(owns[new], np.tile(mask, (4, 1)))
    for tr, own in zip(arm_walk.tracks, arm_walk.track_owns(), strict=True):
        has = np.zeros_like(own)
        has[tr.knot_pose, tr.knots.var] = True
        assert np.array_equal(has, own)  # knots exactly where the poses own variables
    # the other variables' knots, tangents and displacement maps are the same, bit for bit
    assert same_variables(walk, arm_walk, ~mask)
    # the motion is unchanged
    np.testing.assert_allclose(bake(arm_walk, ik=False).channels, bake(walk, ik=False).channels, atol=1e-9)
    # whole-body priorities do not change; the partial poses get their own
    whole = [k for k, p in enumerate(arm_walk.pose_part) if p is None]
    np.testing.assert_array_equal(arm_walk.priority[whole], walk.priority)
    assert np.all(np.isfinite(arm_walk.priority[new])) and np.all(arm_walk.priority[new] > 0)


def test_partial_poses_are_refused_where_they_cannot_be(walk):
    with pytest.raises(UsageError, match="already a pose"):
        cull.add_poses(walk, [float(walk.pose_t[3])], "@left-arm")
    with pytest.raises(UsageError, match="part must be one of"):
        cull.add_poses(walk, [0.5], "@tail")
    with pytest.raises(UsageError, match="half a frame apart"):
        cull.add_poses(walk, [0.5, 0.5 + 0.2 * walk.frame_time], "@left-arm")
    march_c3d = st.extract(st.read("data/samples/march.c3d"))
    with pytest.raises(UsageError, match="need a BVH document"):
        st.cull(march_c3d, add_time=1.0, part="@left-arm")
    with pytest.raises(UsageError, match="add_time"):
        st.cull(walk, keep=5, part="@left-arm")


def test_refinements_of_a_partial_pose_move_only_its_part(arm_walk):
    k = arm_walk.pose_part.index("@left-arm")
    mask = arm_walk.part_mask("@left-arm")
    delta = np.zeros((arm_walk.n_poses, len(mask)))
    delta[k] = 0.02  # asked of every variable: only the part's have knots to move
    with staggered_warnings():
        moved = timing.change_refinements(arm_walk, delta)
    r = moved.refinements()
    moving = ~np.concatenate([timing.static_variables(tr) for tr in arm_walk.tracks])  # a still finger has no timing
    np.testing.assert_allclose(r[k, mask & moving], 0.02, atol=1e-12)
    assert (mask & moving).sum() >= 5 and np.all(r[k, mask & ~moving] == 0.0)
    assert np.all(r[k, ~mask] == 0.0)
    assert same_variables(arm_walk, moved, ~mask)
    a, b = bake(arm_walk, ik=False).channels, bake(moved, ik=False).channels
    cols = channel_columns(arm_walk, mask)
    assert np.array_equal(a[:, ~cols], b[:, ~cols])
    changed = np.flatnonzero(np.any(np.abs(a - b) > 1e-9, axis=1))
    t = arm_walk.pose_t
    # only between the pose's neighbours in its part (the whole-body poses around it)
    ft = arm_walk.frame_time
    assert len(changed) and t[k - 1] <= changed[0] * ft and changed[-1] * ft <= t[k + 1]


# --- the format ---------------------------------------------------------------------


def test_version_3_round_trip_keeps_the_parts(arm_walk, tmp_path):
    manifest, arrays = to_parts(arm_walk)
    assert manifest["version"] == DOCUMENT_VERSION == 3
    assert manifest["pose_parts"] == list(arm_walk.pose_part) and manifest["layer_pose_parts"] == []
    back = from_parts(json.loads(json.dumps(manifest)), arrays)
    assert back.pose_part == arm_walk.pose_part
    assert same_variables(arm_walk, back, np.ones(len(arm_walk.variable_names), dtype=bool))
    path = document_file(arm_walk, tmp_path / "arm.stag")
    r = run(["info", path, "--json"])
    assert r.exit_code == 0, r.stderr
    poses = json.loads(r.stdout)["poses"]
    assert [p["part"] for p in poses] == list(arm_walk.pose_part)
    text = run(["info", path]).stdout
    assert text.count("part @left-arm") == 4 and "part -" not in text


def test_a_manifest_with_bad_parts_is_refused(arm_walk):
    manifest, arrays = to_parts(arm_walk)
    bad = dict(manifest, pose_parts=manifest["pose_parts"][:-1])
    with pytest.raises(st.DataError, match="pose_parts must be a list"):
        from_parts(bad, arrays)
    bad = dict(manifest, pose_parts=["@tail" if p else p for p in manifest["pose_parts"]])
    with pytest.raises(st.DataError, match="neither null nor a body part"):
        from_parts(bad, arrays)
    # knots that do not match what the poses own
    bad = dict(manifest, pose_parts=["@right-arm" if p else p for p in manifest["pose_parts"]])
    with pytest.raises(st.DataError, match="one extreme knot per pose that owns it"):
        from_parts(bad, arrays)


def test_a_version_2_document_reads_edits_and_bakes_as_before(tmp_path):
    old = FIXTURES / "march_v2.stag"
    doc = st.read(old)
    assert doc.pose_part == (None,) * doc.n_poses
    out = tmp_path / "b.bvh"
    assert run(["bake", old, "-o", out]).exit_code == 0
    assert hashlib.sha256(out.read_bytes()).hexdigest() == V2_BAKE
    edited = tmp_path / "e.stag"
    r = run(["edit-pose", old, "--pose", "3", "--rotate", "LeftArm=10,0,5", "-o", edited])
    assert r.exit_code == 0, r.stderr
    assert run(["bake", edited, "-o", out, "--force"]).exit_code == 0
    assert hashlib.sha256(out.read_bytes()).hexdigest() == V2_EDITED_BAKE
