"""The staggered-pose document: poses, tracks, constraints and the source.

A :class:`Document` is the in-memory value every subcommand reads and writes.
It keeps the source motion it came from (BVH skeleton and channel values,
or the C3D clip) so that baking writes the source's layout and, for BVH, can
pick Euler triples on the source's branch (SPEC section 2).

Control variables are ordered translations first, then rotations; this
global order is the second axis of refinement arrays ``(K, V)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from ..contacts.constraint import Constraint
from ..errors import DataError, UsageError, arg
from ..motion import (
    BvhMotion,
    MarkerMotion,
    position_columns,
    rotation_columns,
)
from .kinds import ROTATION, TRANSLATION
from .knots import Track, pose_arrays

#: Most layers a document may stack.
MAX_LAYERS = 64


@dataclass(frozen=True)
class Document:
    """A staggered-pose document.

    Attributes
    ----------
    pose_t : (K,) strictly increasing pose times, seconds; the first and last
        frame always carry a pose.
    priority : (K,) pose priorities ``P(t_k)(t_{k+1} - t_{k-1})``
        (infinite for the first and last pose, which culling always keeps).
    tracks : translation track, then rotation track (C3D: translation only).
    layer_pose_t : the pose times of each layer above the base, bottom up
        (each runs from the first frame to the last); the base layer's are
        ``pose_t``.
    pose_part : (K,) what each base-layer pose owns: None for a whole-body
        pose (knots in every variable), or a body part (``'@left-arm'``,
        see :data:`staggered_cli.names.PARTS`) for a *partial pose*, which
        has knots only in that part's variables (:meth:`part_mask`); the
        other variables pass through it.  Empty (the default): every pose is
        whole-body.  The first and last pose are always whole-body.
    layer_pose_part : the same for each layer above the base (parallel to
        ``layer_pose_t``; empty: all whole-body).
    constraints : contact constraints, by joint or marker name.
    signals : arrays kept for pictures (``'P'`` (T,), ``'p'`` (T, V)).
    parameters : what produced the document (extract options), JSON-able.
    source : the source clip, a BvhMotion or a MarkerMotion.
    source_name, source_sha256 : where it came from.
    """

    pose_t: np.ndarray
    priority: np.ndarray
    tracks: tuple[Track, ...]
    source: BvhMotion | MarkerMotion
    source_name: str = ""
    source_sha256: str = ""
    constraints: tuple[Constraint, ...] = ()
    layer_pose_t: tuple[np.ndarray, ...] = ()
    signals: dict = field(default_factory=dict)
    parameters: dict = field(default_factory=dict)
    pose_part: tuple[str | None, ...] = ()
    layer_pose_part: tuple[tuple[str | None, ...], ...] = ()

    def __post_init__(self) -> None:
        # empty means all whole-body; otherwise one entry per pose (a
        # ``replace`` that changes the poses must give the parts too: see
        # :func:`with_poses`)
        K = len(self.pose_t)
        part = tuple(self.pose_part) or (None,) * K
        if len(part) != K:
            raise ValueError(f"pose_part has {len(part)} entries for {K} poses")
        object.__setattr__(self, "pose_part", part)
        layers = tuple(self.layer_pose_part) or tuple((None,) * len(t) for t in self.layer_pose_t)
        if len(layers) != len(self.layer_pose_t) or any(
            len(p) != len(t) for p, t in zip(layers, self.layer_pose_t, strict=True)
        ):
            raise ValueError("layer_pose_part does not match layer_pose_t")
        object.__setattr__(self, "layer_pose_part", tuple(tuple(p) for p in layers))

    # -- facts --
    @property
    def kind(self) -> str:
        return "bvh" if isinstance(self.source, BvhMotion) else "c3d"

    @property
    def frame_time(self) -> float:
        return float(self.source.frame_time)

    @property
    def n_frames(self) -> int:
        return int(self.source.n_frames)

    @property
    def n_poses(self) -> int:
        return len(self.pose_t)

    @property
    def n_layers(self) -> int:
        """Layers of the stack, the base included."""
        return 1 + len(self.layer_pose_t)

    def poses_of(self, layer: int) -> np.ndarray:
        """The pose times of ``layer`` (0: the base layer's ``pose_t``)."""
        if not 0 <= layer < self.n_layers:
            raise UsageError(
                f"{arg('layer')} must be from 0 to {self.n_layers - 1} (the document has {self.n_layers}), got {layer}"
            )
        return self.pose_t if layer == 0 else self.layer_pose_t[layer - 1]

    def parts_of(self, layer: int) -> tuple[str | None, ...]:
        """What each pose of ``layer`` owns (0: ``pose_part``; see :attr:`pose_part`)."""
        self.poses_of(layer)  # the range check
        return self.pose_part if layer == 0 else self.layer_pose_part[layer - 1]

    @property
    def has_partial_poses(self) -> bool:
        """Whether some pose of some layer is a partial pose."""
        return any(p is not None for p in self.pose_part) or any(
            p is not None for parts in self.layer_pose_part for p in parts
        )

    def part_mask(self, part: str | None) -> np.ndarray:
        """(V,) bool mask of the control variables (all tracks, in
        :attr:`variable_names` order) that body part ``part`` owns; all of
        them for None.  See :func:`part_variables`."""
        V = sum(tr.n_vars for tr in self.tracks)
        if part is None:
            return np.ones(V, dtype=bool)
        return part_variables(self, part)

    def owns(self, layer: int = 0) -> np.ndarray:
        """(K, V) bool: which variables each pose of ``layer`` has knots in
        (a row of True for a whole-body pose, its part's for a partial one)."""
        parts = self.parts_of(layer)
        V = sum(tr.n_vars for tr in self.tracks)
        out = np.ones((len(parts), V), dtype=bool)
        masks: dict[str, np.ndarray] = {}
        for k, p in enumerate(parts):
            if p is not None:
                if p not in masks:
                    masks[p] = self.part_mask(p)
                out[k] = masks[p]
        return out

    def track_owns(self, layer: int = 0) -> list[np.ndarray]:
        """:meth:`owns` split per track: a (K, V_track) mask each."""
        owns = self.owns(layer)
        out, col = [], 0
        for tr in self.tracks:
            out.append(owns[:, col : col + tr.n_vars])
            col += tr.n_vars
        return out

    def pose_label(self, k: int, layer: int = 0) -> str:
        """``'pose 5'``, or ``'pose 5 (@left-arm)'`` for a partial pose."""
        part = self.parts_of(layer)[k]
        return f"pose {k}" if part is None else f"pose {k} ({part})"

    @property
    def frame_times(self) -> np.ndarray:
        return np.arange(self.n_frames) * self.frame_time

    @property
    def duration(self) -> float:
        return (self.n_frames - 1) * self.frame_time

    @property
    def target_names(self) -> tuple[str, ...]:
        """Names of what the variables drive: the skeleton's joints, or the markers."""
        src = self.source
        return tuple(src.skeleton.names) if isinstance(src, BvhMotion) else tuple(src.labels)

    def seconds(self, t: float, *, sign: bool = False) -> str:
        """``t`` seconds as messages print it: to the frame's precision (see :func:`seconds`)."""
        return seconds(t, self.frame_time, sign=sign)

    def target_index(self, name: str) -> int:
        """Index in :attr:`target_names` of the joint or marker the user calls
        ``name``: the exact name, the name without its subject prefix
        (``LSHO`` for ``Male:LSHO``), or a body part (``@left-arm``, BVH only);
        ``UsageError`` suggesting the closest names otherwise
        (:func:`staggered_cli.names.resolve`)."""
        from ..names import resolve

        src = self.source
        if isinstance(src, BvhMotion):
            return src.skeleton.index(name)
        return resolve(name, src.labels, None, what="marker")

    def target_name(self, name: str) -> str:
        """The document's own name for ``name`` (see :meth:`target_index`)."""
        return self.target_names[self.target_index(name)]

    @property
    def variable_names(self) -> tuple[str, ...]:
        return tuple(n for tr in self.tracks for n in tr.names)

    def variable(self, name: str) -> tuple[int, int]:
        """(track index, variable index in that track) of a variable name."""
        for ti, tr in enumerate(self.tracks):
            if name in tr.names:
                return ti, tr.names.index(name)
        raise UsageError(f"unknown variable {name!r}")

    def refinements(self) -> np.ndarray:
        """(K, V) refinements in seconds over all variables (0 where a
        partial pose has no knot)."""
        cols = []
        for tr in self.tracks:
            ext_t, _, _ = pose_arrays(tr, self.n_poses)
            cols.append(np.nan_to_num(ext_t - self.pose_t[:, None], nan=0.0))
        return np.concatenate(cols, axis=1) if cols else np.zeros((self.n_poses, 0))

    def with_tracks(self, tracks: tuple[Track, ...], **changes) -> Document:
        return replace(self, tracks=tuple(tracks), **changes)


def canonical_part(part: str) -> str:
    """``'@left-arm'`` for ``'@Left-Arm'`` or ``'left-arm'``; UsageError
    (naming ``part``) for anything that is not one of the body parts."""
    from ..names import PARTS

    name = str(part).strip().lower().lstrip("@")
    if name not in PARTS:
        raise UsageError(f"{arg('part')} must be one of {', '.join('@' + p for p in PARTS)}, got {part!r}")
    return "@" + name


def part_variables(doc: Document, part: str) -> np.ndarray:
    """(V,) bool mask of the control variables body part ``part`` owns (see :func:`part_of_targets`)."""
    targets = np.concatenate([tr.targets for tr in doc.tracks]) if doc.tracks else np.zeros(0, dtype=int)
    return part_of_targets(doc.source, targets, part)


def part_of_targets(source: BvhMotion | MarkerMotion, targets: np.ndarray, part: str) -> np.ndarray:
    """(V,) bool mask of the variables driving joints ``targets`` (V,) of
    ``source`` that body part ``part`` owns.

    The part's joints are the subtree of its root joint
    (:func:`staggered_cli.names.body_part`: ``@left-arm`` from the left
    clavicle or shoulder down to the fingers) without the subtrees of the
    other parts' roots that lie inside it (``@spine`` stops below the neck
    and the clavicles); a part owns its joints' rotations and, where they
    have position channels, translations.  The root joint belongs to no part:
    its translation and rotation (the figure's place and heading) change
    only at whole-body poses.  BVH only (a C3D's markers have no body
    parts): UsageError otherwise, and where the skeleton has no such part
    or the part has no variables.
    """
    from ..names import PARTS, body_part

    part = canonical_part(part)
    src = source
    if not isinstance(src, BvhMotion):
        raise UsageError(f"partial poses ({part}) need a BVH document: a C3D's markers have no body parts")
    sk = src.skeleton
    root = body_part(part[1:], sk.names, sk.parents)
    joints = np.zeros(sk.n_joints, dtype=bool)
    joints[sk.subtree(root)] = True
    for other in PARTS:
        if "@" + other == part:
            continue
        try:
            j = body_part(other, sk.names, sk.parents)
        except UsageError:
            continue
        if j != root and joints[j]:
            joints[sk.subtree(j)] = False
    joints[sk.parents < 0] = False
    mask = joints[np.asarray(targets, dtype=int)]
    if not mask.any():
        raise UsageError(f"body part {part} has no variables in this skeleton")
    return mask


def with_poses(
    doc: Document,
    pose_t: np.ndarray,
    priority: np.ndarray,
    pose_part: tuple[str | None, ...] | None = None,
    **changes,
) -> Document:
    """``doc`` with new base-layer poses: their times, priorities and parts
    (None: all whole-body), and any other ``changes``; every place that
    changes the poses goes through here, so the three stay of one length."""
    part = (None,) * len(pose_t) if pose_part is None else tuple(pose_part)
    return replace(doc, pose_t=pose_t, priority=priority, pose_part=part, **changes)


def time_decimals(frame_time: float) -> int:
    """Decimals that tell every frame from the next: 3 at 120 Hz, 2 at 30 or 100 Hz."""
    if not math.isfinite(frame_time) or frame_time <= 0:
        return 4
    return max(1, min(9, math.ceil(-math.log10(frame_time) - 1e-9)))


def seconds(t: float, frame_time: float, *, sign: bool = False) -> str:
    """``'0.933 s'``: a time (or a duration) to the precision of the frames,
    never a raw float such as ``0.9332980000000001``."""
    return f"{float(t):{'+' if sign else ''}.{time_decimals(frame_time)}f} s"


def check_time_range(doc: Document, time_range: tuple[float, float]) -> tuple[float, float]:
    """``--time A:B`` checked against the clip: A <= B, and overlapping it."""
    a, b = time_range
    if np.isnan(a) or np.isnan(b) or a > b:
        raise UsageError(f"{arg('time')} must be A:B with A <= B, got {a}:{b}")
    if b < 0 or a > doc.duration + 1e-9:
        raise UsageError(f"{arg('time')} {a:g}:{b:g} lies outside the clip (0 to {doc.seconds(doc.duration)})")
    return float(a), float(b)


def check_pose_index(doc: Document, k: int, layer: int = 0) -> int:
    """``k`` as a pose index of ``layer`` (negative counts from the end)."""
    n = len(doc.poses_of(layer))
    if not -n <= k < n:
        where = "the document has" if layer == 0 else f"layer {layer} has"
        raise UsageError(f"pose {k} is out of range ({where} poses 0 to {n - 1})")
    return k % n


#: Poses keep at least this many frames apart: two poses within one frame
#: would squeeze the motion between them into less than a frame (a pop in
#: the bake), and a time as messages print it (to the frame) names one pose.
MIN_POSE_GAP_FRAMES = 0.5


def check_pose_move(doc: Document, k: int, new_time: float, layer: int = 0) -> None:
    """Refuse moving pose ``k`` of ``layer`` to ``new_time`` unless it is an
    inner pose and the time lies between its neighbours', at least
    :data:`MIN_POSE_GAP_FRAMES` frames from each."""
    times = doc.poses_of(layer)
    of = "" if layer == 0 else f" of layer {layer}"
    if k in (0, len(times) - 1):
        raise UsageError(f"the first and last pose{of} pin the clip's ends and cannot be retimed")
    gap = MIN_POSE_GAP_FRAMES * doc.frame_time
    if not np.isfinite(new_time) or not times[k - 1] + gap <= new_time <= times[k + 1] - gap:
        raise UsageError(
            f"pose {k}{of} can move only between its neighbours "
            f"({doc.seconds(times[k - 1])} and {doc.seconds(times[k + 1])}) and at least half a frame from each, "
            f"got {doc.seconds(new_time)}"
        )


def pose_near(doc: Document, time: float) -> int | None:
    """The pose (of the base layer) within :data:`MIN_POSE_GAP_FRAMES` frames
    of ``time`` seconds, the nearest, or None."""
    if doc.n_poses == 0:
        return None
    k = int(np.argmin(np.abs(doc.pose_t - time)))
    return k if abs(doc.pose_t[k] - time) < MIN_POSE_GAP_FRAMES * doc.frame_time else None


def require_bvh(doc: Document, what: str) -> BvhMotion:
    if not isinstance(doc.source, BvhMotion):
        raise UsageError(f"{what} needs a BVH document (this one comes from a C3D)")
    return doc.source


def not_a_document(name: str) -> DataError:
    return DataError("is not a staggered-pose document", name)


def variable_layout(motion: BvhMotion | MarkerMotion) -> list[tuple[str, tuple[str, ...], np.ndarray]]:
    """The control variables of a clip as (kind, names, targets), one entry
    per track, in the order of :func:`dense_variables` (without its values)."""
    if isinstance(motion, BvhMotion):
        sk = motion.skeleton
        pos_j = [j for j, _ in position_columns(sk)]
        rot_j = [j for j, _, _ in rotation_columns(sk)]
        return [
            (TRANSLATION, tuple(f"{sk.names[j]}.position" for j in pos_j), np.array(pos_j, dtype=int)),
            (ROTATION, tuple(sk.names[j] for j in rot_j), np.array(rot_j, dtype=int)),
        ]
    return [(TRANSLATION, tuple(motion.labels), np.arange(len(motion.labels)))]


def source_frame(doc: Document, k: int) -> int | float:
    """The source frame index of pose ``k`` (frame f is at f · frame_time):
    a whole number when the pose is on a frame, else the fractional frame
    (3 decimals), e.g. after ``cull --add-time`` between frames."""
    f = float(doc.pose_t[k]) / doc.frame_time
    return int(round(f)) if abs(f - round(f)) < 1e-6 else round(f, 3)


def document_summary(doc: Document) -> dict:
    """What ``info --json`` prints for a document (a public interface: keep it stable)."""
    ref = doc.refinements()
    names = doc.variable_names
    poses = []
    for k in range(doc.n_poses):
        r = {names[i]: round(float(ref[k, i]), 9) for i in np.flatnonzero(ref[k] != 0.0)}
        pr = float(doc.priority[k])
        poses.append(
            {
                "index": k,
                "time": round(float(doc.pose_t[k]), 9),
                "frame": source_frame(doc, k),
                "priority": round(pr, 9) if np.isfinite(pr) else None,
                "part": doc.pose_part[k],
                "refinements": r,
            }
        )
    src = doc.source
    out = {
        "kind": "document",
        "source": {"kind": doc.kind, "name": doc.source_name, "sha256": doc.source_sha256},
        "frames": doc.n_frames,
        "frame_time": doc.frame_time,
        "rate": src.rate,
        "duration": round(doc.n_frames * doc.frame_time, 9),  # as for the clip: frames x frame time
        "variables": len(names),
        "poses": poses,
        "layers": [
            {
                "poses": [
                    {"index": k, "time": round(float(t), 9), "part": doc.parts_of(n)[k]}
                    for k, t in enumerate(doc.poses_of(n))
                ]
            }
            for n in range(doc.n_layers)
        ],
        "constraints": [
            {"joint": c.joint, "start": round(c.start, 9), "end": round(c.end, 9)} for c in doc.constraints
        ],
        "figure_height": round(float(src.figure_height()), 6),
        # what extract used, the durations its tempo chose among them (issue 34)
        "parameters": dict(doc.parameters),
    }
    if isinstance(src, BvhMotion):
        out["joints"] = list(src.skeleton.names)
    else:
        out["markers"] = list(src.labels)
    return out


def tree_has_loop(tree: dict) -> bool:
    """Whether ``{child: parent}`` leads from some marker back to itself."""
    for start in tree:
        seen = {start}
        j = tree.get(start)
        while j is not None:
            if j in seen:
                return True
            seen.add(j)
            j = tree.get(j)
    return False
