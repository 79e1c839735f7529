"""glTF 2.0 out: a baked motion as a skinned skeleton (BVH) or animated
marker nodes (C3D), in metres and Y up.

The container is :mod:`pygltflib`'s; the skeleton, the skin and the
sampling are written here.  This is the one place where quaternions are
(x, y, z, w): glTF's order.

* **BVH**: one node per joint with its offset as translation and the
  identity as rest rotation, an end site as a leaf node, a skin over all of
  them (inverse bind matrices of the rest pose) and a small skinned mesh,
  one thin triangle per bone, so that importers (Blender, three.js) build
  an armature and show the figure.  One animation: the joints' rotations
  and the translations of the joints with position channels, at every
  frame, LINEAR.  BVH is taken as Y up (the format's convention).
* **C3D**: one node per marker under one root node, translation at every
  frame (LINEAR); a marker in a gap keeps its last place and is hidden by
  a scale of 0 (a STEP channel, only for markers with gaps).  The figure's
  up axis (Z in most C3D files) is turned to glTF's Y.

Units: ``unit_scale`` is metres per file unit; :func:`unit_scale_for` gives
the default (a C3D's POINT:UNITS, else the unit that makes the figure's
height that of a person) and says what it assumed.
"""

from __future__ import annotations

import base64
import math

import numpy as np

from ..errors import DataError, UsageError, arg
from ..motion import BvhMotion, MarkerMotion

#: Units a file may be in, metres per unit, in the order they are tried.
UNITS = (
    ("m", 1.0),
    ("cm", 0.01),
    ("mm", 0.001),
    ("CMU units (1/0.45 inch)", 0.0254 / 0.45),
    ("inches", 0.0254),
    ("dm", 0.1),
)
#: Heights, metres, that a captured person has: the inferred unit puts the figure in them.
HUMAN_HEIGHT = (1.0, 2.2)
#: Figure heights, metres, an explicit unit scale may give: outside, it is a mistake.
SANE_HEIGHT = (0.01, 1000.0)
#: Words of C3D's POINT:UNITS, metres per unit.
C3D_UNITS = {"mm": 0.001, "cm": 0.01, "m": 1.0, "in": 0.0254, "inch": 0.0254, "dm": 0.1}
KEYS = ("dense", "poses")
_FLOAT, _USHORT = 5126, 5123
_ARRAY_BUFFER = 34962
_FLOAT32_MAX = float(np.finfo(np.float32).max)


def unit_scale_for(motion: BvhMotion | MarkerMotion) -> tuple[float, str]:
    """The default metres per file unit of ``motion`` and a line saying why.

    A C3D whose POINT:UNITS names a unit has it.  Otherwise the first of
    :data:`UNITS` that makes the figure 1.0 to 2.2 m tall; if none does, the
    one nearest 1.7 m, and the line says so.
    """
    height = float(motion.figure_height())
    if isinstance(motion, MarkerMotion):
        unit = motion.units.strip().lower()
        if unit in C3D_UNITS:
            scale = C3D_UNITS[unit]
            return scale, f"glTF in metres: POINT:UNITS says {unit!r} (figure {height * scale:.2f} m tall)"
    for name, scale in UNITS:
        if HUMAN_HEIGHT[0] <= height * scale <= HUMAN_HEIGHT[1]:
            return scale, (
                f"glTF in metres: assumed the file is in {name} (figure {height * scale:.2f} m tall); "
                f"{arg('unit_scale')} S sets metres per unit"
            )
    name, scale = min(UNITS, key=lambda u: abs(math.log(max(height * u[1], 1e-300) / 1.7)))
    return scale, (
        f"glTF in metres: no unit makes the figure 1.0-2.2 m tall; assumed {name} "
        f"({height * scale:.3g} m); {arg('unit_scale')} S sets metres per unit"
    )


def check_unit_scale(motion: BvhMotion | MarkerMotion, scale) -> float:
    """``scale`` as a float, refused (``UsageError``) unless finite, positive
    and giving the figure a height between 1 cm and 1 km."""
    try:
        s = float(scale)
    except (TypeError, ValueError):
        raise UsageError(f"{arg('unit_scale')} must be a number, got {scale!r}") from None
    if not math.isfinite(s) or s <= 0:
        raise UsageError(f"{arg('unit_scale')} must be a positive number of metres per unit, got {scale!r}")
    metres = float(motion.figure_height()) * s
    if not SANE_HEIGHT[0] <= metres <= SANE_HEIGHT[1]:
        raise UsageError(
            f"{arg('unit_scale')} {scale!r} makes the figure {metres:.3g} m tall "
            f"(allowed {SANE_HEIGHT[0]:g} to {SANE_HEIGHT[1]:g} m)"
        )
    return s


def gltf_pieces(
    motion: BvhMotion | MarkerMotion,
    *,
    binary: bool = True,
    unit_scale: float | None = None,
    keys: str = "dense",
    document=None,
) -> list[bytes]:
    """The bytes of ``motion`` as a glTF 2.0 file: binary (.glb) or JSON
    with the buffer embedded as base64 (.gltf).

    ``unit_scale``: metres per file unit (default :func:`unit_scale_for`).
    ``keys``: ``"dense"``, a key at every frame, LINEAR; ``"poses"``, the
    staggered poses of ``document`` (a BVH document of one layer; ``motion``
    gives its skeleton), each variable keyed at its own knots, CUBICSPLINE
    (:mod:`staggered_cli.model.hermite_keys`).  ``DataError`` if a value is
    not finite or does not fit glTF's 32-bit floats.
    """
    import pygltflib as g

    if keys not in KEYS:
        raise UsageError(f"{arg('keys')} must be one of {', '.join(KEYS)}, got {keys!r}")
    if keys == "poses" and (document is None or not isinstance(motion, BvhMotion)):
        raise UsageError(f"{arg('keys')} poses writes the staggered poses of a BVH document (a C3D's: dense)")
    if isinstance(motion, BvhMotion):
        finite = np.all(np.isfinite(motion.channels))
    else:  # a C3D's gaps are NaN: only an infinity is wrong
        finite = not np.any(np.isinf(getattr(motion, "points", np.zeros(0))))
    if not finite:
        raise DataError("the motion has values that are not finite: nothing to write")
    scale = unit_scale_for(motion)[0] if unit_scale is None else check_unit_scale(motion, unit_scale)
    out = _Builder(g, motion.frame_time, motion.n_frames)
    if isinstance(motion, BvhMotion):
        _skeleton(out, motion, scale, document if keys == "poses" else None)
    elif isinstance(motion, MarkerMotion):
        _markers(out, motion, scale)
    else:
        raise UsageError(f"{arg('value')} must be a BvhMotion or a MarkerMotion, got {type(motion).__name__}")
    return out.finish(binary, getattr(motion, "name", "") or "")


class _Builder:
    """A glTF under construction: one buffer, a view per array."""

    def __init__(self, g, frame_time: float, n_frames: int):
        self.g = g
        self.doc = g.GLTF2(asset=g.Asset(version="2.0", generator="staggered (staggered poses)"))
        self.blob = bytearray()
        self.frame_time, self.n_frames = frame_time, n_frames
        self.samplers: list = []
        self.channels: list = []
        self.time: int | None = None

    def animate(self, node: int, path: str, values: np.ndarray, kind: str, how: str = "LINEAR") -> None:
        """A channel of ``node``'s ``path`` keyed at every frame."""
        g = self.g
        if self.time is None:
            self.time = _times(self, self.n_frames, self.frame_time)
        self.samplers.append(g.AnimationSampler(input=self.time, output=self.accessor(values, kind), interpolation=how))
        target = g.AnimationChannelTarget(node=node, path=path)
        self.channels.append(g.AnimationChannel(sampler=len(self.samplers) - 1, target=target))

    def accessor(self, array: np.ndarray, kind: str, *, component: int = _FLOAT, target=None, bounds=False) -> int:
        """Append ``array`` (rows of ``kind``: SCALAR, VEC3, VEC4, MAT4) and return its accessor."""
        g = self.g
        if component == _FLOAT and not np.all(np.abs(array) <= _FLOAT32_MAX):
            raise DataError("a value does not fit glTF's 32-bit floats (not finite or too large)")
        data = np.ascontiguousarray(array, dtype=np.float32 if component == _FLOAT else np.uint16)
        while len(self.blob) % 4:
            self.blob.append(0)
        view = g.BufferView(buffer=0, byteOffset=len(self.blob), byteLength=data.nbytes)
        if target is not None:
            view.target = target
        self.blob.extend(data.tobytes())
        self.doc.bufferViews.append(view)
        count = len(data)
        acc = g.Accessor(bufferView=len(self.doc.bufferViews) - 1, componentType=component, count=count, type=kind)
        if bounds:
            flat = data.reshape(count, -1)
            acc.min = [float(x) for x in flat.min(axis=0)]
            acc.max = [float(x) for x in flat.max(axis=0)]
        self.doc.accessors.append(acc)
        return len(self.doc.accessors) - 1

    def node(self, name: str, **fields) -> int:
        self.doc.nodes.append(self.g.Node(name=name, **fields))
        return len(self.doc.nodes) - 1

    def finish(self, binary: bool, name: str) -> list[bytes]:
        g, doc = self.g, self.doc
        if self.channels:
            doc.animations.append(g.Animation(name=name or "motion", samplers=self.samplers, channels=self.channels))
        while len(self.blob) % 4:
            self.blob.append(0)
        blob = bytes(self.blob)
        if binary:
            doc.buffers = [g.Buffer(byteLength=len(blob))]
            doc.set_binary_blob(blob)
            return [bytes(b) for b in doc.save_to_bytes()]
        uri = "data:application/octet-stream;base64," + base64.b64encode(blob).decode("ascii")
        doc.buffers = [g.Buffer(byteLength=len(blob), uri=uri)]
        return [doc.to_json(separators=(",", ":")).encode("utf-8")]


def _times(out: _Builder, n: int, frame_time: float) -> int:
    times = np.arange(n, dtype=np.float64) * frame_time
    if n > 1 and not np.all(np.diff(times.astype(np.float32)) > 0):
        raise DataError("the frame times do not stay increasing in glTF's 32-bit floats (clip too long)")
    return out.accessor(times, "SCALAR", bounds=True)


def _xyzw(q_wxyz: np.ndarray) -> np.ndarray:
    """glTF's (x, y, z, w) of w-first quaternions, unit length."""
    q = q_wxyz / np.linalg.norm(q_wxyz, axis=-1, keepdims=True)
    return np.concatenate([q[..., 1:], q[..., :1]], axis=-1)


def _skeleton(out: _Builder, motion: BvhMotion, scale: float, document=None) -> None:
    g, doc = out.g, out.doc
    sk = motion.skeleton
    J, E = sk.n_joints, len(sk.end_parents)
    offsets = np.concatenate([sk.offsets, sk.end_offsets]) * scale
    parents = np.concatenate([sk.parents, sk.end_parents]).astype(int)
    names = list(sk.names) + [f"{sk.names[p]}_End" for p in sk.end_parents]
    for i in range(J + E):
        out.node(names[i], translation=[float(x) for x in offsets[i]])
    for i in range(J + E):
        if parents[i] >= 0:
            doc.nodes[parents[i]].children.append(i)
    rest = offsets.copy()  # world rest positions: identity rotations, parents first
    for i in range(J + E):
        if parents[i] >= 0:
            rest[i] = rest[parents[i]] + offsets[i]
    inverse_bind = np.tile(np.eye(4), (J + E, 1, 1))
    inverse_bind[:, :3, 3] = -rest
    ibm = out.accessor(inverse_bind.transpose(0, 2, 1).reshape(J + E, 16), "MAT4")  # column-major
    roots = [i for i in range(J + E) if parents[i] < 0]
    doc.skins.append(
        g.Skin(name=motion.name or "skeleton", joints=list(range(J + E)), inverseBindMatrices=ibm, skeleton=roots[0])
    )
    mesh_node = _bone_mesh(out, rest, parents)
    doc.scenes.append(g.Scene(nodes=roots + ([mesh_node] if mesh_node is not None else [])))
    doc.scene = 0

    if document is not None:
        _pose_keys(out, document, scale)
        return
    moved = [j for j in range(J) if sk.has_position(j)]
    if moved:
        translations = motion.local_translations(np.array(moved)) * scale
        for k, j in enumerate(moved):
            out.animate(j, "translation", translations[:, k], "VEC3")
    turned = [j for j in range(J) if sk.has_rotation(j)]
    for j, column in zip(turned, motion.local_rotation_columns(np.array(turned)), strict=True):
        out.animate(j, "rotation", _xyzw(np.asarray(column)), "VEC4")


def _pose_keys(out: _Builder, document, scale: float) -> None:
    """One CUBICSPLINE channel per variable of the document, keyed at its knots."""
    from ..model.hermite_keys import pose_keys
    from ..model.kinds import ROTATION

    g = out.g
    for keys in pose_keys(document):
        rows = np.stack([keys.tangent_in, keys.values, keys.tangent_out], axis=1)  # (K, 3, D)
        if keys.kind == ROTATION:
            rows, kind, path = np.concatenate([rows[..., 1:], rows[..., :1]], axis=-1), "VEC4", "rotation"
        else:
            rows, kind, path = rows * scale, "VEC3", "translation"
        time = out.accessor(keys.times, "SCALAR", bounds=True)
        output = out.accessor(rows.reshape(-1, rows.shape[-1]), kind)
        out.samplers.append(g.AnimationSampler(input=time, output=output, interpolation="CUBICSPLINE"))
        target = g.AnimationChannelTarget(node=keys.target, path=path)
        out.channels.append(g.AnimationChannel(sampler=len(out.samplers) - 1, target=target))


def _bone_mesh(out: _Builder, rest: np.ndarray, parents: np.ndarray) -> int | None:
    """A node with a skinned mesh of one thin triangle per bone (parent to
    child, bound to the parent), so that the skin is used: importers build
    the armature from it and show the figure."""
    g, doc = out.g, out.doc
    tris, joints = [], []
    for c in range(len(parents)):
        p = parents[c]
        if p < 0:
            continue
        d = rest[c] - rest[p]
        length = float(np.linalg.norm(d))
        if length <= 0:
            continue
        side = np.cross(d, np.eye(3)[int(np.argmin(np.abs(d)))])
        side *= 0.08 * length / np.linalg.norm(side)
        tris.append([rest[p], rest[c], rest[p] + side])
        joints.append(p)
    if not tris:
        return None
    positions = np.asarray(tris).reshape(-1, 3)
    joint_rows = np.zeros((len(positions), 4))
    joint_rows[:, 0] = np.repeat(joints, 3)
    weights = np.zeros((len(positions), 4))
    weights[:, 0] = 1.0
    attrs = g.Attributes(
        POSITION=out.accessor(positions, "VEC3", target=_ARRAY_BUFFER, bounds=True),
        JOINTS_0=out.accessor(joint_rows, "VEC4", component=_USHORT, target=_ARRAY_BUFFER),
        WEIGHTS_0=out.accessor(weights, "VEC4", target=_ARRAY_BUFFER),
    )
    doc.meshes.append(g.Mesh(name="bones", primitives=[g.Primitive(attributes=attrs, mode=4)]))
    return out.node("bones", mesh=len(doc.meshes) - 1, skin=0)


def up_turn(up: np.ndarray) -> np.ndarray:
    """A rotation matrix (3, 3), a permutation of axes with signs, that
    takes the unit axis vector ``up`` to +Y."""
    y = np.asarray(up, dtype=float)
    x = np.eye(3)[int(np.argmin(np.abs(y)))]  # the first axis across it
    z = np.cross(x, y)
    return np.stack([x, y, z])


def _markers(out: _Builder, motion: MarkerMotion, scale: float) -> None:
    from ..contacts.detect import up_direction

    g, doc = out.g, out.doc
    pts = motion.points
    turn = up_turn(up_direction(pts, float(motion.figure_height())))
    M = pts.shape[1]
    root = out.node(motion.name or "markers", children=list(range(1, M + 1)))
    for m in range(M):
        p = pts[:, m] @ turn.T * scale
        seen = np.all(np.isfinite(p), axis=1)
        held = _hold(p, seen)
        node = out.node(motion.labels[m] or f"marker{m}", translation=[float(x) for x in held[0]])  # m + 1
        out.animate(node, "translation", held, "VEC3")
        if not seen.all():
            doc.nodes[node].scale = [float(seen[0])] * 3
            out.animate(node, "scale", np.repeat(seen[:, None].astype(float), 3, axis=1), "VEC3", "STEP")
    doc.scenes.append(g.Scene(nodes=[root]))
    doc.scene = 0


def _hold(p: np.ndarray, seen: np.ndarray) -> np.ndarray:
    """``p`` (T, 3) with each unseen frame at the last seen place (before the
    first sight: the first; never seen: the origin)."""
    if not seen.any():
        return np.zeros_like(p)
    idx = np.where(seen, np.arange(len(p)), -1)
    idx = np.maximum.accumulate(idx)
    idx[idx < 0] = int(np.flatnonzero(seen)[0])
    return p[idx]
