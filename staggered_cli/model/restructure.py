"""Retiming and refitting a track's knots while keeping its motion (paper 4.2, SPEC 5).

Knots moved in time carry their segments' detail along in normalized time;
a layer refitted to new knots keeps the segments that did not change as they
are and measures the others' displacement maps from the motion as it was.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from . import fit
from .evaluate import evaluate_at, fitted_spline
from .knots import Knots, Track, check_knot_order, locate_inside

# --- structure ----------------------------------------------------------------


def sample_times(track: Track, i: int, layer: int = 0) -> np.ndarray:
    """Current times (seconds) of variable ``i``'s displacement samples in ``layer``."""
    lay = track.layers[layer]
    kt = lay.knots.t[lay.knots.of(i)]
    s = lay.samp_s[lay.samples(i)]
    if len(kt) < 2:
        return np.full(len(s), kt[0] if len(kt) else 0.0)
    seg = np.clip(np.floor(s).astype(int), 0, len(kt) - 2)
    return kt[seg] + (s - seg) * (kt[seg + 1] - kt[seg])


def with_knot_times(track: Track, knot_t: np.ndarray, layer: int = 0, frame_time: float | None = None) -> Track:
    """The same track with a layer's knots moved in time (same structure):
    the motion between them is warped, its detail carried along in
    normalized time.  ``frame_time``: the clip's, for the precision of the
    time a KnotOrderError names."""
    lay = track.layers[layer]
    check_knot_order(lay.knots.ptr, knot_t, track.names, frame_time)
    return track.with_layer(layer, replace(lay, knots=lay.knots.with_times(knot_t)))


def restructure(
    track: Track, knots: Knots, *, frame_t: np.ndarray | None = None, dense: np.ndarray | None = None
) -> Track:
    """Refit the base layer of ``track`` to new knots, keeping the motion it has now.

    Only segments that changed are refitted: a new segment whose two knots
    (times and values) are two consecutive knots of the old base layer keeps
    its tangents and displacement samples as they are, so what a user set
    there (``--ease``, ``detail``) stays exactly.  The other segments are
    fitted again and their displacement maps measured from the base layer's
    motion as it was (SPEC invariant 2), sampled at the source frame times
    ``frame_t`` (increasing; where the motion is baked, so it stays exact
    there even after a retiming moved the old samples between frames) plus
    the old knot times inside them; without ``frame_t``, at the current
    sample times.  ``dense`` (T, V, D), when given with ``frame_t``, is that
    motion at ``frame_t`` (``evaluate(track, frame_t, depth=1)``, which a
    caller may already have): it is read instead of evaluated again, and only
    the knot times between frames are evaluated.  Only the variables with a
    refitted segment are sampled at all.  The layers above the base are kept
    as they are.
    """
    check_knot_order(
        knots.ptr, knots.t, track.names, None if frame_t is None or len(frame_t) < 2 else frame_t[1] - frame_t[0]
    )
    old = track.base
    V = track.n_vars
    kept_old = _unchanged_segments(old.knots, knots)  # (S_new,) old segment index or -1
    new_first = knots.seg_first
    seg_var = knots.seg_var
    refit = np.flatnonzero(kept_old < 0)
    is_refit = kept_old < 0
    ft = None if frame_t is None else np.asarray(frame_t, dtype=float)
    if dense is not None and (ft is None or dense.shape[:2] != (len(ft), V)):
        raise ValueError(f"dense must be (T, V, D) values at frame_t, got {np.shape(dense)}")
    D = track.dim
    # the changed segments are numbered 0..len(refit)-1 and fitted over groups
    # of whole variables of about fit.FIT_GROUP samples (every segment's fit is
    # its own, so grouping does not change a bit): the temporaries stay
    # bounded however long the clip
    local = np.full(len(new_first), -1)
    local[refit] = np.arange(len(refit))
    a_new = np.zeros((len(refit), 3))
    b_new = np.zeros((len(refit), 3))
    # (not np.unique, which imports numpy.ma: 15 ms at a command's first call)
    todo = np.flatnonzero(np.bincount(seg_var[refit], minlength=V))
    n_old = np.diff(old.knots.ptr)
    if ft is None:
        size = np.diff(old.samp_ptr)[todo] + n_old[todo]
    else:
        size = len(ft) + n_old[todo]
    # the new samples are written in their final order (by variable, then
    # knot coordinate) into arrays allocated once, range of variables by
    # range: each fit group's variables with their carried samples, and the
    # variables in between (nothing refitted) in groups of fit.FIT_GROUP old
    # samples.  The bound (old samples + the refitted variables' candidate
    # times) is allocated but the pages past the end are never touched.
    old_to_new = np.full(int(old.knots.seg_ptr[-1]), -1)
    kept = np.flatnonzero(kept_old >= 0)
    old_to_new[kept_old[kept]] = kept
    bound = int(old.samp_ptr[-1]) + int(np.sum(size))
    out_s = np.empty(bound)
    out_d = np.empty((bound, D))
    # the fit's spline at the samples, where the old layer has it: carried
    # with the kept segments' samples, computed at the refitted ones
    old_fit = fitted_spline(old)
    out_f = np.empty((bound, D)) if old_fit is not None and bound * D * 8 <= fit.FITTED_BYTES else None
    counts = np.zeros(V, dtype=int)
    w = 0

    def emit(i0: int, i1: int, g_var, g_seg, g_s, g_d, g_f) -> None:
        # the old samples of variables i0..i1-1 whose segment is kept, and
        # the fresh ones, in order of (new) segment: each segment's samples
        # are already in order, and all carried or all fresh, so ordering by
        # segment (stably) is enough
        nonlocal w
        o0, o1 = int(old.samp_ptr[i0]), int(old.samp_ptr[i1])
        ss = old.samp_s[o0:o1]
        owner = np.repeat(np.arange(i0, i1), np.diff(old.samp_ptr[i0 : i1 + 1]))
        old_local = np.floor(ss).astype(int)
        old_local = np.minimum(old_local, np.maximum(n_old[owner] - 2, 0))
        new_of_sample = old_to_new[old_local + old.knots.seg_ptr[owner]] if len(ss) else np.zeros(0, dtype=int)
        carry = new_of_sample >= 0
        carried_seg = new_of_sample[carry]
        carried_s = ss[carry] - old_local[carry] + (carried_seg - knots.seg_ptr[seg_var[carried_seg]])
        del old_local, new_of_sample
        o = np.argsort(np.concatenate([carried_seg, g_seg]), kind="stable")
        n = len(o)
        out_s[w : w + n] = np.concatenate([carried_s, g_s])[o]
        out_d[w : w + n] = np.concatenate([old.samp_d[o0:o1][carry], g_d])[o]
        if out_f is not None:
            out_f[w : w + n] = np.concatenate([old_fit[o0:o1][carry], g_f])[o]
        counts[i0:i1] = np.bincount(np.concatenate([owner[carry], g_var]) - i0, minlength=i1 - i0)
        w += n

    none_i, none_f, none_d = np.zeros(0, dtype=int), np.zeros(0), np.zeros((0, D))
    old_counts = np.diff(old.samp_ptr)

    def emit_carried(i0: int, i1: int) -> None:
        for c0, c1 in fit.variable_groups(old_counts[i0:i1], fit.FIT_GROUP):
            emit(i0 + c0, i0 + c1, none_i, none_i, none_f, none_d, none_d)

    done = 0  # variables emitted so far
    groups = fit.variable_groups(size, fit.FIT_GROUP)
    for j0, j1 in groups:
        # samples of the group's segments to refit: (time, frame index or -1)
        samples_t, samples_frame, samples_var, samples_seg, samples_u = [], [], [], [], []
        for i in todo[j0:j1]:
            kt = knots.t[knots.of(i)]
            old_kt = old.knots.t[old.knots.of(i)]
            if ft is None:
                st = np.unique(np.concatenate([sample_times(track, i), old_kt]))
                frame = np.full(len(st), -1)
            else:
                st, frame = _with_knot_times(ft, old_kt)
            seg, u, inside = locate_inside(kt, st)
            gseg = seg + knots.seg_ptr[i]
            take = inside & is_refit[gseg]
            samples_t.append(st[take])
            samples_frame.append(frame[take])
            samples_var.append(np.full(int(take.sum()), i))
            samples_seg.append(gseg[take])
            samples_u.append(u[take])
            del st, frame, seg, u, inside, gseg, take
        g_t = np.concatenate(samples_t)
        g_frame = np.concatenate(samples_frame)
        g_var = np.concatenate(samples_var)
        g_seg = np.concatenate(samples_seg)
        g_u = np.concatenate(samples_u)
        del samples_t, samples_frame, samples_var, samples_seg, samples_u
        if dense is None:
            values = evaluate_at(track, g_var, g_t, depth=1) if len(g_t) else np.zeros((0, D))
        else:
            # the same numbers: evaluate and evaluate_at compute each value alike
            # rows of the (T * V, D) view (a knot time between frames takes row 0, then its own value)
            on_frame = g_frame >= 0
            rows = np.where(on_frame, g_frame * V + g_var, 0)
            values = np.take(dense.reshape(-1, D), rows, axis=0)
            del rows
            off = np.flatnonzero(~on_frame)
            if len(off):
                values[off] = evaluate_at(track, g_var[off], g_t[off], depth=1)
        del g_t, g_frame
        r0 = int(np.searchsorted(refit, knots.seg_ptr[todo[j0]]))
        r1 = int(np.searchsorted(refit, knots.seg_ptr[todo[j1 - 1] + 1]))
        fs = new_first[refit[r0:r1]]
        gf = None if out_f is None else np.empty((len(g_u), D))
        ga, gb, gd = fit.fit_segments(
            track.kind, knots.v[fs], knots.v[fs + 1], local[g_seg] - r0, g_u, values, r1 - r0, gf
        )
        del values
        a_new[r0:r1], b_new[r0:r1] = ga, gb
        i0, i1 = int(todo[j0]), int(todo[j1 - 1]) + 1
        emit_carried(done, i0)
        emit(i0, i1, g_var, g_seg, (g_seg - knots.seg_ptr[g_var]) + g_u, gd, gf)
        done = i1
        del g_var, g_seg, g_u, ga, gb, gd, gf
    emit_carried(done, V)
    tan_a = np.zeros((len(new_first), 3))
    tan_b = np.zeros((len(new_first), 3))
    tan_a[kept], tan_b[kept] = old.tan_a[kept_old[kept]], old.tan_b[kept_old[kept]]
    tan_a[refit], tan_b[refit] = a_new, b_new
    samp_ptr = np.concatenate([[0], np.cumsum(counts)]).astype(int)
    layer = fit.fitted_layer(knots, tan_a, tan_b, samp_ptr, out_s[:w], out_d[:w], None if out_f is None else out_f[:w])
    return track.with_base(layer)


def _with_knot_times(frame_t: np.ndarray, knot_t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The increasing times ``frame_t`` (T,) and ``knot_t`` (n,) together, in
    order and each once (``np.unique`` of both), and the frame index (-1 for
    a knot time between frames) of each."""
    pos = np.searchsorted(frame_t, knot_t)
    at = np.minimum(pos, len(frame_t) - 1)
    new = (pos >= len(frame_t)) | (frame_t[at] != knot_t) if len(frame_t) else np.ones(len(knot_t), dtype=bool)
    st = np.insert(frame_t, pos[new], knot_t[new])
    frame = np.insert(np.arange(len(frame_t)), pos[new], -1)
    return st, frame


def _unchanged_segments(old: Knots, new: Knots) -> np.ndarray:
    """For each segment of ``new``, the index of the segment of ``old`` that
    has the same two knots (variable, times and values exactly), else -1."""
    new_first = new.seg_first
    out = np.full(len(new_first), -1)
    old_first = old.seg_first
    if len(new_first) == 0 or len(old_first) == 0:
        return out
    for i in range(new.n_vars):
        ns = slice(int(new.seg_ptr[i]), int(new.seg_ptr[i + 1]))
        os_ = slice(int(old.seg_ptr[i]), int(old.seg_ptr[i + 1]))
        if ns.stop == ns.start or os_.stop == os_.start:
            continue
        o0 = old.t[old_first[os_]]
        n0 = new.t[new_first[ns]]
        j = np.clip(np.searchsorted(o0, n0), 0, len(o0) - 1)
        cand = old_first[os_][j]
        nf = new_first[ns]
        same = (
            (old.t[cand] == new.t[nf])
            & (old.t[cand + 1] == new.t[nf + 1])
            & np.all(old.v[cand] == new.v[nf], axis=1)
            & np.all(old.v[cand + 1] == new.v[nf + 1], axis=1)
        )
        out[np.arange(ns.start, ns.stop)[same]] = (os_.start + j)[same]
    return out
