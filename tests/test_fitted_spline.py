"""A layer fitted in this process keeps the spline at its samples
(``Layer.fitted``), and its evaluation there takes those values instead of
computing them again: the same numbers, and never a spline it no longer has.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from staggered_cli import quat
from staggered_cli.io.bvh import bvh_bytes
from staggered_cli.io.schema import from_parts, to_parts
from staggered_cli.model.evaluate import fitted_spline, layer_at
from staggered_cli.model.kinds import ROTATION
from staggered_cli.ops import layers, timing
from staggered_cli.ops.bake import bake
from staggered_cli.ops.cull import choose, keep_poses

from .conftest import BVH_FILES, C3D_FILES, dev_document


def _all_queries(doc, track):
    t = doc.frame_times
    var = np.tile(np.arange(track.n_vars), len(t))
    return var, np.repeat(t, track.n_vars)


def _uncached(doc):
    """``doc`` with no layer holding its fit's spline (as read from a file)."""
    return from_parts(*to_parts(doc))


@pytest.mark.parametrize("name", BVH_FILES + C3D_FILES)
def test_the_fitted_spline_is_the_spline_and_the_bake_is_the_bake_read_back(name):
    doc = dev_document(name)
    for track in doc.tracks:
        layer = track.base
        assert fitted_spline(layer) is not None, (name, track.kind)
        var, t = _all_queries(doc, track)
        with_fit = layer_at(track.kind, layer, var, t)
        without = layer_at(track.kind, replace(layer, fitted=None), var, t)
        assert np.array_equal(with_fit, without), (name, track.kind)
    baked, read_back = bake(doc), bake(_uncached(doc))
    if name.endswith(".bvh"):
        assert bvh_bytes(baked) == bvh_bytes(read_back), name
    else:
        assert np.array_equal(baked.points, read_back.points, equal_nan=True), name


def test_a_layer_with_other_knots_tangents_or_samples_evaluates_its_own_spline():
    doc = dev_document("cmu_02_01_walk.bvh")
    track = next(tr for tr in doc.tracks if tr.kind == ROTATION)
    layer = track.base
    kn = layer.knots
    var, t = _all_queries(doc, track)
    bent = quat.normalize(kn.v + 0.05)
    for other in (
        replace(layer, knots=kn.with_values(bent)),
        replace(layer, tan_a=layer.tan_a * 0.5),
        replace(layer, tan_b=layer.tan_b * 0.5),
        replace(layer, samp_s=layer.samp_s.copy()),
    ):
        assert other.fitted is layer.fitted and fitted_spline(other) is None
        got = layer_at(track.kind, other, var, t)
        assert np.array_equal(got, layer_at(track.kind, replace(other, fitted=None), var, t))
        assert not np.array_equal(got, layer_at(track.kind, layer, var, t)) or other.samp_s is not layer.samp_s
    # other displacements over the same spline: the fit's spline still holds
    scaled = replace(layer, samp_d=layer.samp_d.copy())
    assert fitted_spline(scaled) is layer.fitted.values


def _edits(doc):
    """Edits of every kind a batch step makes, each on ``doc``."""
    keep = choose(doc, keep=str(max(3, doc.n_poses // 3)))
    culled = keep_poses(doc, keep)
    yield "cull (refits around the removed poses)", culled
    yield "cull, then succession", timing.succession(culled, 0.03, 1.5, joint="@left-arm", clamp=True)
    yield "detail (displacements only)", layers.detail(doc, 0.5)
    yield "succession (moves knots)", timing.succession(doc, 0.05, 1.0, joint="@left-arm", clamp=True)
    yield "retime (moves knots)", timing.retime_pose(doc, 1, float(doc.pose_t[1] + 0.02))
    yield "ease (changes tangents)", layers.ease(doc, 1, 0.5)


@pytest.mark.parametrize("name", ["cmu_05_06_modern_dance.bvh", "bandai1_walk_normal_001.bvh"])
def test_edited_documents_bake_as_when_read_back(name):
    """Whatever an edit keeps or replaces of a fitted layer, the bake in the
    process that fitted it is the bake of the edited document read back."""
    for what, edited in _edits(dev_document(name)):
        assert bvh_bytes(bake(edited)) == bvh_bytes(bake(_uncached(edited))), (name, what)
