"""C3D markers retimed as a kinematic chain (ops/marker_chain): succession and
randomize keep every chain segment within its length range in the source
(±5 %), planted chain markers stay planted, and the marker tree is kept in
the document.  Before: wrist-to-finger of the CMU breakdance went from
94-135 mm to 18-403 mm (199 % beyond), the BTS heel-to-toe from 162-177 to
56-354 mm."""

from __future__ import annotations

import numpy as np
import pytest

from staggered_cli.errors import DataError
from staggered_cli.io.schema import to_parts
from staggered_cli.ops import marker_chain, timing
from staggered_cli.ops.bake import bake

from .conftest import dev_bake, dev_document, dev_motion

EB015 = "c3dorg_sample01_Eb015pi_walk.c3d"


CMU_C3D = "cmu_85_12_breakdance_long.c3d"


BTS = "ezc3d_BTS_walk_gaps.c3d"


# (file, chain, bound on how far a segment may leave its source range)
CHAINS = [
    (EB015, ["PV1", "RTH1", "RSK1", "RFT1"], 0.005),  # before: 2.3 %
    (EB015, ["PV2", "LTH1", "LSK1", "LFT1"], 0.005),  # before: 0.7 %
    (CMU_C3D, ["Male:RSHO", "Male:RELB", "Male:RWRA", "Male:RFIN"], 0.005),  # before: 199 %
    (CMU_C3D, ["Male:LSHO", "Male:LELB", "Male:LWRA", "Male:LFIN"], 0.005),  # before: 180 %
    (CMU_C3D, ["Male:RFWT", "Male:RKNE", "Male:RANK", "Male:RTOE"], 0.005),  # before: 93 %
    (BTS, ["r asis", "r knee 1", "r heel", "r met"], 0.005),  # before: 71 %
    # 'l asis' (the chain's anchor) has gaps of its own that nothing fills
    # better than a straight line: 4.4 % (before: 100 %)
    (BTS, ["l asis", "l knee 1", "l heel", "l met"], 0.05),
]


CHAIN_IDS = [f"{f[:6]}-{c[1]}" for f, c, _ in CHAINS]


def c3d_doc(name: str):
    """(clip, extracted document, its unedited bake), made once per session."""
    return dev_motion(name), dev_document(name), dev_bake(name).points


def beyond_range(source: np.ndarray, result: np.ndarray, idx: list[int]) -> tuple[float, list]:
    """Largest fraction by which a chain segment's length in ``result`` leaves
    its range in ``source`` (frames where both markers are seen), and the
    ranges (mm) per segment."""
    worst, rows = 0.0, []
    for a, b in zip(idx[:-1], idx[1:], strict=True):
        ranges = []
        for pts in (source, result):
            d = np.linalg.norm(pts[:, a] - pts[:, b], axis=1)
            d = d[np.isfinite(d)]
            ranges.append((float(d.min()), float(d.max())))
        (s0, s1), (r0, r1) = ranges
        worst = max(worst, (s0 - r0) / s0, (r1 - s1) / s1)
        rows.append((round(s0), round(s1), round(r0), round(r1)))
    return worst, rows


@pytest.mark.parametrize("name, chain, bound", CHAINS, ids=CHAIN_IDS)
def test_c3d_succession_keeps_each_chain_segment_in_its_source_range(name, chain, bound):
    m, doc, plain = c3d_doc(name)
    edited = timing.succession(doc, 0.03, 1.0, chain=chain, clamp=True)
    out = bake(edited).points  # the contact layer on: planted markers keep the chain too
    idx = [m.labels.index(c) for c in chain]
    worst, rows = beyond_range(m.points, out, idx)
    assert worst <= bound, rows
    # and the succession did retime the limb: its end moved by a tenth of the figure
    moved = np.nanmax(np.linalg.norm(out[:, idx[-1]] - m.points[:, idx[-1]], axis=-1))
    assert moved > 0.1 * m.figure_height(), moved
    # the markers outside the chain are not touched
    others = [i for i in range(len(m.labels)) if i not in idx]
    np.testing.assert_allclose(out[:, others], plain[:, others], atol=1e-6 * m.figure_height())


def test_c3d_planted_chain_markers_stay_planted():
    """The contact layer holds a planted chain marker by bending the chain
    (two-bone IK on points), not by tearing the segment: each plant of the
    retimed ankle wanders at most 1 % of the figure height more than in the
    capture (measured: 7 mm at most)."""
    m, doc, _ = c3d_doc(CMU_C3D)
    chain = ["Male:RFWT", "Male:RKNE", "Male:RANK", "Male:RTOE"]
    edited = timing.succession(doc, 0.03, 1.0, chain=chain, clamp=True)
    assert edited.parameters["marker_tree"] == {
        "Male:RKNE": "Male:RFWT",
        "Male:RANK": "Male:RKNE",
        "Male:RTOE": "Male:RANK",
    }
    out = bake(edited).points
    t = np.arange(m.n_frames) / m.rate
    j = m.labels.index("Male:RANK")
    checked = 0
    for c in edited.constraints:
        if c.joint != "Male:RANK" or c.end - c.start < 0.1:
            continue
        s0, s1 = c.source_span
        spread_src = np.ptp(m.points[(t >= s0) & (t <= s1), j], axis=0).max()
        spread_out = np.ptp(out[(t >= c.start) & (t <= c.end), j], axis=0).max()
        assert spread_out <= spread_src + 0.01 * m.figure_height(), (c, spread_src, spread_out)
        checked += 1
    assert checked >= 10


RANDOM = [CHAINS[i] for i in (2, 4, 5, 6)]  # an arm and a leg of CMU, both legs of BTS


@pytest.mark.parametrize("name, chain, bound", RANDOM, ids=[CHAIN_IDS[i] for i in (2, 4, 5, 6)])
def test_c3d_randomize_keeps_chain_segments(name, chain, bound):
    m, doc, plain = c3d_doc(name)
    edited = timing.randomize(doc, 0.03, 7, joints=chain, clamp=True)  # before: up to 196 %
    idx = [m.labels.index(c) for c in chain]
    worst, rows = beyond_range(m.points, bake(edited).points, idx)
    assert worst <= max(bound, 0.01), rows


@pytest.mark.parametrize("name, bound", [(EB015, 0.05), (CMU_C3D, 0.01)])  # measured: 2.9 %, 0.2 %
def test_c3d_randomize_of_every_marker_keeps_the_rigid_tree(name, bound):
    """Without --joints every marker joins one tree of the most rigid pairs,
    whose edges keep their lengths (before: the CMU wrist-to-finger distance
    went from 58-121 mm to 31-153 mm)."""
    m, doc, plain = c3d_doc(name)
    parents = marker_chain.rigid_tree(m.points)
    assert (parents < 0).sum() == 1  # one tree
    out = bake(timing.randomize(doc, 0.03, 7, clamp=True)).points
    for i in np.flatnonzero(parents >= 0):
        worst, rows = beyond_range(m.points, out, [int(parents[i]), int(i)])
        assert worst <= bound, (m.labels[i], m.labels[parents[i]], rows)


def test_the_marker_tree_is_kept_in_the_document_and_checked_when_read():
    from staggered_cli.io.schema import from_parts

    m, doc, _ = c3d_doc(EB015)
    edited = timing.succession(doc, 0.02, 1.0, chain=["PV1", "RTH1", "RSK1"], clamp=True)
    manifest, arrays = to_parts(edited)
    assert from_parts(manifest, arrays).parameters["marker_tree"] == {"RTH1": "PV1", "RSK1": "RTH1"}
    for bad, needle in (({"RTH1": "NOPE"}, "marker labels"), ({"RTH1": "RSK1", "RSK1": "RTH1"}, "loop")):
        manifest["parameters"]["marker_tree"] = bad
        with pytest.raises(DataError, match=needle):
            from_parts(manifest, arrays)


def test_a_chain_names_each_marker_once():
    from staggered_cli.errors import UsageError

    _, doc, _ = c3d_doc(EB015)
    with pytest.raises(UsageError, match="'PV1' appears twice in chain"):
        timing.succession(doc, 0.01, 1.0, chain=["PV1", "RTH1", "PV1"])
