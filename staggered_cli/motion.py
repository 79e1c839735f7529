"""Dense motion as read from files: BVH skeleton motion and C3D marker motion.

These are plain values converted at the file edge (``io``): no file layout
leaks past them.  Control variables (SPEC section 2) are derived here:

* BVH: one translation variable per joint with position channels
  (named ``JOINT.position``), one rotation variable per joint with rotation
  channels (named ``JOINT``);
* C3D: one translation variable per marker (named by its label).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from functools import cached_property

import numpy as np

from . import quat
from .skeleton import (
    POSITION_CHANNELS,
    ROTATION_CHANNELS,
    Skeleton,
    end_site_positions,
    figure_extents,
    forward_kinematics,
    height_of_extents,
)


@dataclass(frozen=True)
class BvhMotion:
    """A BVH clip.

    Attributes
    ----------
    skeleton : Skeleton
    channels : (T, C) float64, the MOTION values exactly as in the file
        (degrees for rotations, file units for positions).
    frame_time : float, seconds per frame as written.
    frame_time_text : str, the frame time token as written (kept on output).
    number_format : str, printf format that reproduces the file's numbers.
    name : str, the base name of the file it was read from (may be empty):
        :func:`staggered_cli.extract` records it in the document.
    source : bytes, the file it was read from (may be empty): writing keeps
        its layout and the text of every number that did not change
        (:func:`staggered_cli.io.bvh.bvh_bytes`).
    source_values : (T0, C) float64 or None, the numbers of ``source``'s
        MOTION block as the reader read them (the ``channels`` it was read
        with): the writer compares with them instead of parsing the text
        again.  None: the writer parses it.

    ``frame_time_text``, ``number_format``, ``source`` and ``source_values``
    are the file's layout: only the reader sets them and only the writer
    reads them; operations carry them along with :meth:`with_channels`.
    """

    skeleton: Skeleton
    channels: np.ndarray
    frame_time: float
    frame_time_text: str = ""
    number_format: str = "%.6f"
    source: bytes = field(default=b"", repr=False, compare=False)
    source_values: np.ndarray | None = field(default=None, repr=False, compare=False)
    name: str = field(default="", repr=False, compare=False)

    @property
    def n_frames(self) -> int:
        return int(self.channels.shape[0])

    def with_channels(
        self,
        channels: np.ndarray,
        frame_time: float | None = None,
        *,
        same_text: bool = True,
        decimals: int | None = None,
    ) -> BvhMotion:
        """New channel values in this clip's file layout.  At another
        ``frame_time`` its token is written anew (7 decimals, trailing zeros
        dropped); without ``same_text`` the source text is not kept (the
        frames are not the source's frames, e.g. one frame per pose); with
        ``decimals`` numbers get at least that many (a clip sampled densely
        from keys written by hand, which may be whole numbers)."""
        changes: dict = {"channels": channels}
        if frame_time is not None and frame_time != self.frame_time:
            changes.update(frame_time=float(frame_time), frame_time_text=f"{frame_time:.7f}".rstrip("0"))
        if not same_text:
            changes.update(source=b"", source_values=None)
        fmt = self.number_format
        if decimals is not None and fmt[-1:] in ("f", "g"):
            changes["number_format"] = f"%.{max(int(fmt[2:-1]), decimals)}{fmt[-1]}"
        return replace(self, **changes)

    @property
    def rate(self) -> float:
        """Nominal frame rate in Hz (the written frame time rounded sensibly)."""
        return nominal_rate(self.frame_time)

    def channel_slices(self) -> list[tuple[int, int]]:
        """(start, stop) column range of each joint's channels."""
        out, c = [], 0
        for ch in self.skeleton.channels:
            out.append((c, c + len(ch)))
            c += len(ch)
        return out

    # Derived arrays are computed once per clip (extract and bake each need
    # them several times) and handed out read-only, since they are shared.
    # Only what is needed throughout is kept: the local rotations and the
    # world positions.  Local translations are mostly the constant offsets
    # (cheap to make again), world rotations are made in blocks of frames.
    @cached_property
    def _local_rotations(self) -> np.ndarray:
        return _frozen(local_rotations_from_channels(self.skeleton, self.channels))

    @cached_property
    def _world_positions(self) -> tuple[np.ndarray, float]:
        """World positions (T, J, 3) and the figure height, by forward
        kinematics over blocks of frames (each frame is its own: the same
        numbers as all at once), so that world rotations and local
        translations never exist for the whole clip."""
        sk, T = self.skeleton, self.n_frames
        rot = self._local_rotations
        wp = np.empty((T, sk.n_joints, 3))
        extents = np.empty(T)
        step = max(1, _FK_BLOCK // max(sk.n_joints, 1))
        for lo in range(0, T, step):
            hi = min(lo + step, T)
            # the block's translations only: the clip's would be as large as wp
            tr = local_translations_from_channels(sk, self.channels[lo:hi])
            wr_b, wp_b = forward_kinematics(sk, rot[lo:hi], tr)
            wp[lo:hi] = wp_b
            extents[lo:hi] = figure_extents(sk, wp_b, end_site_positions(sk, wr_b, wp_b))
        return _frozen(wp), height_of_extents(sk, extents)

    def local_rotations(self) -> np.ndarray:
        """(T, J, 4) local rotations, w first, each joint's track unrolled (read-only)."""
        return self._local_rotations

    def local_rotation_columns(self, joints: np.ndarray) -> Sequence[np.ndarray]:
        """The local rotations (T, 4) of each of ``joints``, as
        :meth:`local_rotations` has them (the same numbers): from its cache
        where it is made, else each joint's made when it is asked for (and
        not kept), so that a long clip's rotations never all exist at once."""
        cached = self.__dict__.get("_local_rotations")
        if cached is not None:
            return [cached[:, int(j)] for j in joints]
        return _RotationColumns(self.skeleton, self.channels, tuple(int(j) for j in joints))

    def release_local(self) -> None:
        """Forget the cached local rotations (:meth:`local_rotations` computes
        them again if asked): 32 bytes per joint and frame, that bake frees
        once it has compared them with the baked pose."""
        self.__dict__.pop("_local_rotations", None)

    def local_translations(self, joints: np.ndarray | None = None) -> np.ndarray:
        """(T, J, 3) local translations: position channels where present, else
        offsets (read-only; made anew at each call).  ``joints``: only these
        (T, len(joints), 3): a clip's translation variables are a joint or
        two, and all joints' are 24 bytes per joint and frame."""
        return _frozen(local_translations_from_channels(self.skeleton, self.channels, joints))

    def world(self) -> tuple[np.ndarray, np.ndarray]:
        """World rotations (T, J, 4) and positions (T, J, 3) (read-only; the
        rotations are computed anew: :meth:`world_positions` is cached)."""
        wr, _ = forward_kinematics(self.skeleton, self._local_rotations, self.local_translations())
        return _frozen(wr), self.world_positions()

    def world_positions(self) -> np.ndarray:
        """World positions (T, J, 3) (read-only, computed once)."""
        return self._world_positions[0]

    def release_world(self) -> None:
        """Forget the cached world positions (:meth:`world_positions`
        computes them again if asked): 24 bytes per joint and frame, that
        extract frees before its fit.  The figure height stays."""
        if "_world_positions" in self.__dict__:
            self.__dict__["_figure_height"] = self._world_positions[1]
            del self.__dict__["_world_positions"]

    def figure_height(self) -> float:
        cached = self.__dict__.get("_figure_height")
        return cached if cached is not None else self._world_positions[1]


#: Joint transforms computed at once by the world positions' forward kinematics.
_FK_BLOCK = 1 << 16


def _frozen(a: np.ndarray) -> np.ndarray:
    a.flags.writeable = False
    return a


@dataclass(frozen=True)
class MarkerMotion:
    """A C3D marker clip.

    Attributes
    ----------
    labels : tuple of str, (M,)
    points : (T, M, 3) float64, file units, NaN where the marker is missing.
    rate : float, Hz.
    units : str, e.g. ``'mm'`` (may be empty).
    source : bytes, the original file, so that writing keeps analogs and
        every parameter the user had.
    name : str, the base name of the file it was read from (may be empty).
    """

    labels: tuple[str, ...]
    points: np.ndarray
    rate: float
    units: str = ""
    source: bytes = field(default=b"", repr=False)
    name: str = field(default="", repr=False, compare=False)

    @property
    def n_frames(self) -> int:
        return int(self.points.shape[0])

    def with_points(self, points: np.ndarray, rate: float | None = None) -> MarkerMotion:
        """New points (and rate) with this clip's labels, units and source file."""
        return replace(self, points=points, rate=self.rate if rate is None else float(rate))

    @property
    def frame_time(self) -> float:
        return 1.0 / self.rate

    def index(self, label: str) -> int:
        """Index of the marker ``label`` (exact, or without its subject prefix).

        ``UsageError`` when no marker has it (suggesting close ones), or when
        several do: a C3D may repeat a label, and an edit of "the first one"
        would silently leave the others alone.
        """
        from .names import resolve

        return resolve(label, self.labels, None, what="marker")

    def figure_height(self) -> float:
        seen = np.all(np.isfinite(self.points), axis=2)  # (T, M)
        frames = np.flatnonzero(seen.sum(axis=1) >= 2)
        if len(frames) == 0:
            return 1.0
        pts = np.where(seen[frames, :, None], self.points[frames], np.nan)
        with np.errstate(invalid="ignore"):
            ext = np.fmax.reduce(pts, axis=1) - np.fmin.reduce(pts, axis=1)
        size = float(np.median(np.max(ext, axis=1))) if len(ext) else 0.0
        return size if size > 0 else 1.0


#: Frame rates a clip may have, Hz (frame times 1e-4 to 1 s).  No capture
#: lies outside; a frame time of 1e-30 or 1e308 is a corrupt file, and the
#: cost of the signals (smoothing, filters) is bounded by the data only
#: within these.
MIN_RATE = 1.0
MAX_RATE = 10_000.0
MIN_FRAME_TIME = 1.0 / MAX_RATE
MAX_FRAME_TIME = 1.0 / MIN_RATE


def frame_time_problem(frame_time: float) -> str | None:
    """None when ``frame_time`` (seconds) is within the limits, else the reason
    (a phrase to follow the value)."""
    if MIN_FRAME_TIME * (1 - 1e-9) <= frame_time <= MAX_FRAME_TIME * (1 + 1e-9):
        return None
    return (
        f"is out of range: frame times go from {MIN_FRAME_TIME:g} to {MAX_FRAME_TIME:g} s "
        f"({MIN_RATE:g} Hz to {MAX_RATE:g} Hz)"
    )


def rate_problem(rate: float) -> str | None:
    """None when ``rate`` (Hz) is within the limits, else the reason."""
    if MIN_RATE * (1 - 1e-9) <= rate <= MAX_RATE * (1 + 1e-9):
        return None
    return f"is out of range: frame rates go from {MIN_RATE:g} Hz to {MAX_RATE:g} Hz"


def nominal_rate(frame_time: float) -> float:
    """Frame rate in Hz, snapped to a whole number when the written frame time
    is a rounded reciprocal of one (``.0083333`` -> 120, ``0.016667`` -> 60)."""
    if frame_time <= 0:
        return 0.0
    rate = 1.0 / frame_time
    whole = round(rate)
    return float(whole) if whole > 0 and abs(rate - whole) / whole < 2e-4 else rate


def rotation_columns(skeleton: Skeleton) -> list[tuple[int, list[int], str]]:
    """For each joint with rotation channels: (joint, its 3 columns, Euler order)."""
    out, c = [], 0
    for j, ch in enumerate(skeleton.channels):
        cols = [c + n for n, name in enumerate(ch) if name in ROTATION_CHANNELS]
        if cols:
            out.append((j, cols, skeleton.rotation_order(j)))
        c += len(ch)
    return out


def position_columns(skeleton: Skeleton) -> list[tuple[int, list[int]]]:
    """For each joint with position channels: (joint, columns ordered x, y, z).

    A joint with only some of the three position channels keeps its offset
    in the others; its missing columns are given as -1.
    """
    out, c = [], 0
    for j, ch in enumerate(skeleton.channels):
        cols = [c + ch.index(name) if name in ch else -1 for name in POSITION_CHANNELS]
        if any(x >= 0 for x in cols):
            out.append((j, cols))
        c += len(ch)
    return out


#: Joints of one Euler order: (order, joints, their columns joint by joint).
EulerGroup = tuple[str, list[int], list[int]]


def euler_groups(skeleton: Skeleton, joints=None) -> tuple[list[EulerGroup], list[tuple[int, list[int], str]]]:
    """The joints with three rotation channels grouped by Euler order:
    (order, joints, their columns joint by joint), in order of first
    appearance; and the joints with one or two rotation channels, as
    :func:`rotation_columns` gives them.  ``joints``: only these."""
    wanted = None if joints is None else {int(j) for j in joints}
    groups: dict[str, tuple[list[int], list[int]]] = {}
    partial = []
    for j, cols, order in rotation_columns(skeleton):
        if wanted is not None and j not in wanted:
            continue
        if len(order) == 3:
            js, cs = groups.setdefault(order, ([], []))
            js.append(j)
            cs.extend(cols)
        else:
            partial.append((j, cols, order))
    return [(order, js, cs) for order, (js, cs) in groups.items()], partial


def _group_step(n_joints: int) -> int:
    """Frames converted at once for a group of ``n_joints`` joints: about
    :data:`_EULER_BLOCK` angles of each axis (the temporaries stay in cache;
    one joint at a time, a short clip pays numpy's call overhead per joint)."""
    return max(1, _EULER_BLOCK // max(n_joints, 1))


#: Joint-frames converted at once between Euler angles and quaternions: every
#: value is its own, so the same bits as one joint at a time.
_EULER_BLOCK = 8192


class _RotationColumns(Sequence):
    """Each joint's unrolled local rotations (T, 4), made when asked for."""

    def __init__(self, skeleton: Skeleton, channels: np.ndarray, joints: tuple[int, ...]):
        self._skeleton, self._channels, self._joints = skeleton, channels, joints

    def __len__(self) -> int:
        return len(self._joints)

    def __getitem__(self, i):
        if isinstance(i, slice):
            return [self[k] for k in range(*i.indices(len(self)))]
        j = self._joints[i]
        rot = local_rotations_from_channels(self._skeleton, self._channels, joints=[j], compact=True)
        return _frozen(rot[:, 0])


def local_rotations_from_channels(
    skeleton: Skeleton,
    channels: np.ndarray,
    unroll: bool = True,
    joints: np.ndarray | None = None,
    compact: bool = False,
) -> np.ndarray:
    """Local rotations (T, J, 4) of channel values (T, C), w first; each
    joint's track unrolled (without ``unroll``, each frame's own sign: for
    sign-blind uses, which may then take any block of frames).  ``joints``:
    only these (the others are the identity; with ``compact``, only these
    are returned, (T, len(joints), 4) in their order).

    The joints of one Euler order are converted together, a block of frames
    at a time (:func:`_group_step`) while their channels are in cache (a
    joint's column of a long clip's channels, read alone, cost 50x the time
    for 32x the frames), and unrolled in place along the frames, all joints
    at once, a block of frames at a time (each joint's signs are its own:
    those of unrolling its track alone)."""
    T = channels.shape[0]
    if compact and joints is not None:
        at = {int(j): n for n, j in enumerate(joints)}  # a joint's place in the result
        J = len(at)
    else:
        at = None
        J = skeleton.n_joints
    rot = quat.identity((T, J))
    groups, partial = euler_groups(skeleton, joints)
    for order, js, cs in groups:
        step = _group_step(len(js))
        where = js if at is None else [at[j] for j in js]
        for lo in range(0, T, step):
            block = channels[lo : lo + step, cs]
            rot[lo : lo + step, where] = quat.from_euler(block.reshape(len(block), len(js), 3), order)
    step = max(1, _ROTATION_BLOCK // max(4 * J, 1))
    for lo in range(0, T, step):
        block = rot[lo : lo + step]
        for j, cols, order in partial:  # one or two rotation channels: compose what is there
            q = quat.identity((len(block),))
            for col, axis in zip(cols, order, strict=True):
                q = quat.mul(q, quat.from_axis_angle(axis, np.radians(channels[lo : lo + step, col])))
            block[:, j if at is None else at[j]] = q
    if unroll:
        quat.unroll_in_place(rot)
    return rot


#: Rotation components made at once by :func:`local_rotations_from_channels` (2 MB).
_ROTATION_BLOCK = 1 << 18


def local_translations_from_channels(
    skeleton: Skeleton, channels: np.ndarray, joints: np.ndarray | None = None
) -> np.ndarray:
    """Local translations (T, J, 3) of channel values (T, C): the position
    channels where a joint has them, else its offset.  ``joints``: only
    these, in this order (T, len(joints), 3)."""
    T = channels.shape[0]
    js = np.arange(skeleton.n_joints) if joints is None else np.asarray(joints, dtype=int)
    tr = np.broadcast_to(skeleton.offsets[js], (T, len(js), 3)).copy()
    where = {int(j): n for n, j in enumerate(js)}
    for j, cols in position_columns(skeleton):
        if j not in where:
            continue
        for axis, col in enumerate(cols):
            if col >= 0:
                tr[:, where[j], axis] = channels[:, col]
    return tr


def channels_from_local(
    skeleton: Skeleton,
    rotations: np.ndarray,
    translations: np.ndarray,
    reference: np.ndarray,
) -> np.ndarray:
    """BVH channel values (T, C) of local rotations and translations.

    Each joint is written in its own Euler order; among equivalent angle
    triples the one closest to ``reference`` (T, C) is chosen (SPEC section 2).
    """
    out = np.array(reference, dtype=float, copy=True)
    groups, partial = euler_groups(skeleton)
    T = len(out)
    for order, js, cs in groups:  # a joint's angles are its own: the same bits as one joint at a time
        step = _group_step(len(js))
        for lo in range(0, T, step):
            ref = reference[lo : lo + step, cs]
            ang = quat.to_euler(rotations[lo : lo + step, js], order, ref.reshape(len(ref), len(js), 3))
            out[lo : lo + step, cs] = ang.reshape(len(ref), -1)
        _follow_where_far(out, rotations, reference, order, js, cs)
    for j, cols, order in partial:
        if len(order) == 2:
            out[:, cols] = _two_axis_angles(rotations[:, j], order, reference[:, cols])
        else:
            # one channel: the angle about that axis (exact for rotations
            # about it; any other part is dropped), wrapped by whole turns
            # to the reference
            q = rotations[:, j]
            ax = 1 + "XYZ".index(order)
            ang = np.degrees(2.0 * np.arctan2(q[:, ax], q[:, 0]))
            out[:, cols[0]] = ang + 360.0 * np.round((reference[:, cols[0]] - ang) / 360.0)
    for j, cols in position_columns(skeleton):
        for axis, col in enumerate(cols):
            if col >= 0:
                out[:, col] = translations[:, j, axis]
    return out


#: Degrees: an angle triple this far from the reference in one of its
#: angles was chosen by a reference that no longer says which triple.
_FAR_FROM_REFERENCE = 90.0


def _follow_where_far(out, rotations, reference, order: str, js, cs) -> None:
    """Where an edit took a joint's rotation far from the source's angles
    (an angle more than :data:`_FAR_FROM_REFERENCE` from the reference),
    choose its triple nearest the previous frame's instead (in place).

    The reference picks among equivalent triples, whole turn by whole turn
    per angle, which is the source's own choice where the motion is still
    the source's.  Far from it the pick is arbitrary: a retimed motion
    meeting the source's switch to the twin triple (cmu3dsmax's RThumb) got
    one angle 360 degrees off for two frames.  Frames near the reference
    (every unedited one) keep its choice.
    """
    T = len(out)
    if T < 2:
        return
    A = out[:, cs].reshape(T, len(js), 3)
    with np.errstate(invalid="ignore"):
        far = np.any(np.abs(A - reference[:, cs].reshape(T, len(js), 3)) > _FAR_FROM_REFERENCE, axis=2)
    far[0] = False
    frames = np.flatnonzero(far.any(axis=1))
    if not len(frames):
        return
    js = np.asarray(js)
    for f in frames:  # in order: each frame follows the one before, as chosen
        jj = np.flatnonzero(far[f])
        A[f, jj] = quat.to_euler(rotations[f, js[jj]], order, A[f - 1, jj])
    out[:, cs] = A.reshape(T, -1)


def _two_axis_angles(q: np.ndarray, order: str, reference: np.ndarray) -> np.ndarray:
    """Angles (T, 2) in degrees of ``R = R_A(a) R_B(b)`` for a two-channel
    joint of Euler order ``order = A+B``, each nearest ``reference`` by whole turns.

    A rotation stored in two channels is ``R_A(a) R_B(b) R_C(0)`` (C the
    remaining axis): of the Euler triples of order A+B+C it is the one whose
    third angle is 0, which is unique up to whole turns of ``a`` and ``b``,
    also where ``b`` is beyond +-90 (the principal triple would then carry a
    c of 180 that cannot be written) and at ``b = +-90`` (where a three-angle
    decomposition only knows ``a +- c``).  It is solved for directly: ``a``
    maximizes ``|<q, q_A(a) q_B(b)>|`` over ``b`` (the principal direction of
    a 2x2 form, exact for rotations about A and B and the nearest such
    rotation otherwise, e.g. after an edit), then ``b`` is the angle about B
    of ``q_A(a)^-1 q``.
    """
    A, B = ("XYZ".index(c) for c in order)
    s = 1.0 if (B - A) % 3 == 1 else -1.0  # e_A x e_B = s e_C
    C = 3 - A - B
    w, qa, qb, qc = q[:, 0], q[:, 1 + A], q[:, 1 + B], s * q[:, 1 + C]
    # q = (ca cb, sa cb e_A + ca sb e_B + sa sb s e_C) for half angles of a, b:
    # (w, qa) = cb (ca, sa) and (qb, qc) = sb (ca, sa)
    a = np.arctan2(2.0 * (w * qa + qb * qc), w * w + qb * qb - qa * qa - qc * qc)
    rest = quat.mul(quat.conj(quat.from_axis_angle(order[0], a)), q)
    b = 2.0 * np.arctan2(rest[:, 1 + B], rest[:, 0])
    ang = np.degrees(np.stack([a, b], axis=1))
    return ang + 360.0 * np.round((reference - ang) / 360.0)
