"""The document schema: a Document in and out of (manifest, arrays) (SPEC section 7).

What the manifest and arrays of a document mean: :func:`to_parts` writes a
:class:`~staggered_cli.model.document.Document` as the manifest and arrays
that :mod:`staggered_cli.io.container` turns into bytes; :func:`from_parts`
reads them back, validating every field on the way in and migrating older
document versions (``DOCUMENT_VERSION``; version 1 had no layers).
"""

from __future__ import annotations

import hashlib
import logging
import re

import numpy as np

from ..contacts.constraint import Constraint
from ..errors import DataError, StaggeredError
from ..model.document import MAX_LAYERS, Document, part_of_targets, tree_has_loop, variable_layout
from ..model.kinds import ROTATION, TRANSLATION
from ..model.knots import Knots, Layer, Track
from ..motion import BvhMotion, MarkerMotion, frame_time_problem, rate_problem
from ..skeleton import POSITION_CHANNELS, ROTATION_CHANNELS
from .container import FORMAT_NAME, release_mapped

#: The schema's version (what the manifest and arrays mean): 2 has layers,
#: 3 partial poses (``pose_parts``, ``layer_pose_parts``).
DOCUMENT_VERSION = 3

log = logging.getLogger(__name__)


_TRACK_ARRAYS = (
    "knot_ptr",
    "knot_t",
    "knot_v",
    "knot_pose",
    "knot_editing",
    "tan_a",
    "tan_b",
    "samp_ptr",
    "samp_s",
    "samp_d",
)


def _flag(value, what: str) -> bool:
    if not isinstance(value, bool):
        raise ValueError(f"{what} must be true or false")
    return value


def _constraint_entry(c: Constraint) -> dict:
    entry = {"joint": c.joint, "start": float(c.start), "end": float(c.end)}
    if c.source_span != (float(c.start), float(c.end)):
        entry["source_start"], entry["source_end"] = c.source_span
    if c.pin:
        entry["pin"] = True
    return entry


def _layer_arrays(layer: Layer) -> dict[str, np.ndarray]:
    k = layer.knots
    return {
        "knot_ptr": k.ptr,
        "knot_t": k.t,
        "knot_v": k.v,
        "knot_pose": k.pose,
        "knot_editing": k.editing,
        "tan_a": layer.tan_a,
        "tan_b": layer.tan_b,
        "samp_ptr": layer.samp_ptr,
        "samp_s": layer.samp_s,
        "samp_d": layer.samp_d,
    }


def to_parts(doc: Document) -> tuple[dict, dict[str, np.ndarray]]:
    """The stored form of a document: a JSON-able manifest and numeric arrays.

    Version 3 (2 with the poses' parts): the base layer's poses are
    ``pose_t`` and ``priority``, the manifest's ``pose_parts`` (null or a
    body part such as ``"@left-arm"``, one per pose) says what each owns and
    ``layer_pose_parts`` the same for each layer above the base, layer
    ``lay >= 1`` has its poses in ``layer{lay}.pose_t``, and track ``n``'s layer
    ``lay`` is stored as ``track{n}.layer{lay}.{knot_ptr,knot_t,...}``.
    """
    arrays: dict[str, np.ndarray] = {"pose_t": doc.pose_t, "priority": doc.priority}
    for lay, pose_t in enumerate(doc.layer_pose_t, start=1):
        arrays[f"layer{lay}.pose_t"] = pose_t
    tracks = []
    for n, tr in enumerate(doc.tracks):
        tracks.append({"kind": tr.kind, "names": list(tr.names), "targets": [int(x) for x in tr.targets]})
        for lay, layer in enumerate(tr.layers):
            for key, val in _layer_arrays(layer).items():
                arrays[f"track{n}.layer{lay}.{key}"] = val
    for key, val in doc.signals.items():
        arrays[f"signal.{key}"] = np.asarray(val)
    manifest: dict = {
        "format": FORMAT_NAME,
        "version": DOCUMENT_VERSION,
        "layers": doc.n_layers,
        "source": {"kind": doc.kind, "name": doc.source_name, "sha256": doc.source_sha256},
        "frame_time": doc.frame_time,
        "frames": doc.n_frames,
        "tracks": tracks,
        "constraints": [_constraint_entry(c) for c in doc.constraints],
        "parameters": doc.parameters,
        "pose_parts": list(doc.pose_part),
        "layer_pose_parts": [list(p) for p in doc.layer_pose_part],
    }
    src = doc.source
    if isinstance(src, BvhMotion):
        sk = src.skeleton
        manifest["bvh"] = {
            "names": list(sk.names),
            "parents": [int(p) for p in sk.parents],
            "offsets": sk.offsets.tolist(),
            "channels": [list(c) for c in sk.channels],
            "end_parents": [int(p) for p in sk.end_parents],
            "end_offsets": sk.end_offsets.tolist(),
            "frame_time": src.frame_time,
            "frame_time_text": src.frame_time_text,
            "number_format": src.number_format,
        }
        arrays["source.channels"] = src.channels
        if src.source:  # the file's text, so that bake keeps its layout and numbers as written
            arrays["source.bvh"] = np.frombuffer(src.source, dtype=np.uint8)
    else:
        manifest["c3d"] = {"labels": list(src.labels), "rate": src.rate, "units": src.units}
        arrays["source.points"] = src.points
        arrays["source.c3d"] = np.frombuffer(src.source, dtype=np.uint8)
    return manifest, arrays


def from_parts(manifest: dict, arrays: dict[str, np.ndarray]) -> Document:
    """Rebuild and validate a document from its stored form.

    Raises DataError naming the first inconsistency (no source attached:
    the caller adds the file name).  A version 1 document (one layer, its
    arrays named ``track{n}.{key}``) is converted, and said so at ``-v``.
    """
    from ..skeleton import Skeleton

    def need(cond: bool, msg: str) -> None:
        if not cond:
            raise DataError(msg)

    def arr(key: str, ndim: int, dtype_kind: str = "f") -> np.ndarray:
        need(key in arrays, f"missing array {key!r}")
        a = arrays[key]
        need(isinstance(a, np.ndarray) and a.ndim == ndim, f"array {key!r} must have {ndim} dimension(s)")
        need(a.dtype.kind in dtype_kind, f"array {key!r} has dtype {a.dtype}, expected {dtype_kind!r} kind")
        return a

    need(isinstance(manifest, dict), "manifest is not a JSON object")
    need(manifest.get("format") == FORMAT_NAME, f"format is {str(manifest.get('format'))[:40]!r}, not {FORMAT_NAME!r}")
    version = manifest.get("version")
    need(type(version) is int, "version is missing")
    need(version >= 1, f"bad document version {version} (expected a whole number >= 1)")
    need(
        version <= DOCUMENT_VERSION,
        f"document version {version} is newer than this staggered reads ({DOCUMENT_VERSION}); upgrade staggered",
    )
    if version < DOCUMENT_VERSION:
        log.info(
            "document format version %d: converted to version %d (%s) on reading",
            version,
            DOCUMENT_VERSION,
            "one layer, every pose whole-body" if version == 1 else "every pose whole-body",
        )
    if version == 1:
        arrays = _from_version_1(arrays)
        n_layers = 1
    else:
        n_layers = manifest.get("layers")
        need(
            type(n_layers) is int and 1 <= n_layers <= MAX_LAYERS,
            f"layers must be a whole number from 1 to {MAX_LAYERS}, got {str(n_layers)[:20]}",
        )
    try:
        frames = _whole_number(manifest["frames"], "frames", 1, _MAX_INDEX)
        frame_time = float(manifest["frame_time"])
        src_info = manifest["source"]
        kind = src_info["kind"]
        track_info = manifest["tracks"]
        constraints = tuple(
            Constraint(
                str(c["joint"]),
                float(c["start"]),
                float(c["end"]),
                None if c.get("source_start") is None else float(c["source_start"]),
                None if c.get("source_end") is None else float(c["source_end"]),
                _flag(c.get("pin", False), "constraint pin"),
            )
            for c in manifest.get("constraints", [])
        )
        parameters = manifest.get("parameters", {})
    except (KeyError, TypeError, ValueError, OverflowError) as exc:
        raise DataError(f"manifest is incomplete ({type(exc).__name__}: {str(exc)[:60]})") from None
    need(frames >= 1 and np.isfinite(frame_time) and frame_time > 0, "frames and frame_time must be positive")
    problem = frame_time_problem(frame_time)
    need(problem is None, f"frame_time {frame_time:g} {problem}")
    need(kind in ("bvh", "c3d"), f"unknown source kind {str(kind)[:20]!r}")
    sha = src_info.get("sha256", "") if isinstance(src_info, dict) else None
    need(
        isinstance(sha, str) and (sha == "" or re.fullmatch(r"[0-9a-f]{64}", sha) is not None),
        "source sha256 is not a SHA-256 digest (64 lower-case hex digits)",
    )
    try:
        if kind == "bvh":
            b = manifest["bvh"]
            names = tuple(str(n) for n in b["names"])
            J = len(names)
            sk = Skeleton(
                names=names,
                parents=_whole_numbers(b["parents"], "bvh parents", -1, J - 1).reshape(J),
                offsets=np.array(b["offsets"], dtype=float).reshape(J, 3),
                channels=tuple(tuple(str(c) for c in ch) for ch in b["channels"]),
                end_parents=_whole_numbers(b["end_parents"], "bvh end_parents", 0, J - 1).reshape(-1),
                end_offsets=np.array(b["end_offsets"], dtype=float).reshape(-1, 3),
            )
            need(len(sk.channels) == J, "bvh channels do not match the joints")
            # names and channels are written back into a BVH header: they must read back
            need(len(set(names)) == J, "bvh joint names are not unique")
            need(all(_BVH_NAME.fullmatch(n) for n in names), "a bvh joint name is empty or has braces or line breaks")
            need(
                all(set(c) <= _BVH_CHANNELS and len(set(c)) == len(c) for c in sk.channels),
                "bvh channels hold an unknown or repeated channel name",
            )
            need(
                bool(np.all(np.abs(sk.offsets) <= _MAX_MAGNITUDE))
                and bool(np.all(np.abs(sk.end_offsets) <= _MAX_MAGNITUDE)),
                f"bvh offsets are not all finite numbers within ±{_MAX_MAGNITUDE:g}",
            )
            need(
                bool(np.all(sk.parents < np.arange(J))) and bool(np.all(sk.parents >= -1)),
                "bvh parents are not in hierarchy order",
            )
            need(bool(np.all((sk.end_parents >= 0) & (sk.end_parents < J))), "bvh end sites name unknown joints")
            need(len(sk.end_parents) == len(sk.end_offsets), "bvh end sites and their offsets differ in number")
            ch = arr("source.channels", 2)
            need(
                ch.shape == (frames, sum(len(c) for c in sk.channels)),
                f"source.channels has shape {ch.shape}, expected ({frames}, channels)",
            )
            text = b""
            if "source.bvh" in arrays:
                member = arr("source.bvh", 1, "u")
                text = member.tobytes()
                release_mapped(member)
            sha = str(manifest.get("source", {}).get("sha256", ""))
            need(
                not text or not sha or hashlib.sha256(text).hexdigest() == sha,
                "source.bvh is not the source file (its checksum differs from the manifest's)",
            )
            # source.channels are the numbers of source.bvh as read (what
            # extract stores), which the writer compares with
            source: BvhMotion | MarkerMotion = BvhMotion(
                sk,
                ch,
                float(b["frame_time"]),
                str(b["frame_time_text"]),
                str(b["number_format"]),
                source=text,
                source_values=ch if text else None,
            )
            need(abs(source.frame_time - frame_time) < 1e-12, "frame_time disagrees with the bvh header")
            need(_safe_format(source.number_format), "number_format is not a plain numeric format")
            need(
                _rows_all(ch, lambda b: np.abs(b) <= _MAX_MAGNITUDE),
                f"source.channels are not all finite numbers within ±{_MAX_MAGNITUDE:g}",
            )
            release_mapped(ch)  # checked: its pages come back when used (a step may not)
            text = source.frame_time_text
            need(
                text == ""
                or (_FRAME_TIME.fullmatch(text) is not None and abs(float(text) / source.frame_time - 1) < 1e-4),
                f"frame_time_text {text[:20]!r} is not the frame time",
            )
        else:
            c = manifest["c3d"]
            labels = tuple(str(x) for x in c["labels"])
            pts = arr("source.points", 3)
            need(
                pts.shape == (frames, len(labels), 3),
                f"source.points has shape {pts.shape}, expected ({frames}, {len(labels)}, 3)",
            )
            need(
                _rows_all(pts, lambda b: ~(np.abs(b) > _MAX_MAGNITUDE)),
                f"source.points hold values that are infinite or beyond ±{_MAX_MAGNITUDE:g}",
            )
            release_mapped(pts)
            member = arr("source.c3d", 1, "u")
            raw = member.tobytes()
            release_mapped(member)
            if raw:  # baking rewrites it: refuse a broken one now, naming the document
                from .c3d import check_c3d

                try:
                    check_c3d(raw, "source.c3d")
                except DataError as exc:
                    need(False, str(exc))
            rate = float(c["rate"])
            problem = rate_problem(rate) if np.isfinite(rate) else "is not a finite number"
            need(problem is None, f"c3d rate {rate:g} Hz {problem}")
            sha = src_info.get("sha256", "")
            if raw and sha:  # the embedded file is the source the manifest names
                need(
                    hashlib.sha256(raw).hexdigest() == sha,
                    "source.c3d does not match the source's sha256 in the manifest (altered or corrupted)",
                )
            source = MarkerMotion(labels, pts, rate, str(c.get("units", "")), raw)
            need(abs(1.0 / source.rate - frame_time) < 1e-9, "frame_time disagrees with the c3d rate")
    except (KeyError, TypeError, ValueError, OverflowError) as exc:
        raise DataError(f"source description is malformed ({type(exc).__name__}: {str(exc)[:60]})") from None
    pose_t = arr("pose_t", 1)
    priority = arr("priority", 1)
    K = len(pose_t)
    need(K >= 1 and priority.shape == (K,), "pose_t and priority must be non-empty and of equal length")
    need(
        bool(np.all(np.isfinite(pose_t))) and bool(np.all(np.diff(pose_t) > 0)),
        "pose times must be finite and strictly increasing",
    )
    need(not np.any(np.isnan(priority)), "priorities must not be NaN")
    duration = (frames - 1) * frame_time
    need(
        abs(pose_t[0]) < 1e-6 and abs(pose_t[-1] - duration) < 1e-6,
        f"pose times must run from the first frame to the last (0 to {duration:.4f} s)",
    )
    layer_pose_t = tuple(_checked_layer_poses(arrays, lay, duration, need, arr) for lay in range(1, n_layers))
    layout = variable_layout(source)
    if version >= 3:
        pose_part = _checked_parts(manifest.get("pose_parts"), "pose_parts", K, need)
        lay_parts = manifest.get("layer_pose_parts")
        need(
            isinstance(lay_parts, list) and len(lay_parts) == n_layers - 1,
            f"layer_pose_parts must be a list of {n_layers - 1} lists",
        )
        layer_pose_part = tuple(
            _checked_parts(p, f"layer_pose_parts[{n}]", len(t), need)
            for n, (p, t) in enumerate(zip(lay_parts, layer_pose_t, strict=True))
        )
    else:
        pose_part = (None,) * K
        layer_pose_part = tuple((None,) * len(t) for t in layer_pose_t)
    all_targets = np.concatenate([t for _, _, t in layout]) if layout else np.zeros(0, dtype=int)
    part_masks: dict[str, np.ndarray] = {}
    for part in {p for p in pose_part + tuple(q for qs in layer_pose_part for q in qs) if p is not None}:
        try:
            part_masks[part] = part_of_targets(source, all_targets, part)
        except StaggeredError as exc:
            need(False, f"pose part {part}: {exc.message}")

    def owns_of(parts: tuple) -> list[np.ndarray]:
        full = np.ones((len(parts), len(all_targets)), dtype=bool)
        for k, p in enumerate(parts):
            if p is not None:
                full[k] = part_masks[p]
        out, col = [], 0
        for _, names, _ in layout:
            out.append(full[:, col : col + len(names)])
            col += len(names)
        return out

    owns_by_layer = [owns_of(pose_part)] + [owns_of(p) for p in layer_pose_part]
    tracks = []
    need(isinstance(track_info, list), "tracks must be a list")
    need(len(track_info) == len(layout), f"{len(track_info)} tracks for the source's {len(layout)}")
    for n, info in enumerate(track_info):
        try:
            tkind = info["kind"]
            tnames = tuple(str(x) for x in info["names"])
            targets = _whole_numbers(info["targets"], f"track {n} targets", 0, _MAX_INDEX).reshape(len(tnames))
        except (KeyError, TypeError, ValueError, OverflowError):
            raise DataError(f"track {n} description is malformed") from None
        need(tkind in (TRANSLATION, ROTATION), f"track {n} has unknown kind {str(tkind)[:20]!r}")
        want_kind, want_names, want_targets = layout[n]
        need(
            tkind == want_kind and tnames == want_names and np.array_equal(targets, want_targets),
            f"track {n} does not hold the source's {want_kind} variables (kind, names or targets differ)",
        )
        layers = tuple(
            _checked_layer(
                n,
                lay,
                tkind,
                tnames,
                arrays,
                pose_t if lay == 0 else layer_pose_t[lay - 1],
                need,
                arr,
                owns_by_layer[lay][n],
            )
            for lay in range(n_layers)
        )
        tracks.append(Track(tkind, tnames, targets, layers))
    joints = set(source.skeleton.names) if isinstance(source, BvhMotion) else set(source.labels)
    half_frame = 0.5 * frame_time
    for c in constraints:
        need(c.joint in joints, f"constraint on unknown joint or marker {c.joint[:40]!r}")
        need(
            bool(np.isfinite(c.start) and np.isfinite(c.end))
            and -half_frame <= c.start <= c.end <= duration + half_frame,
            f"constraint on {c.joint[:40]!r} from {c.start:g} to {c.end:g} s is not within the clip",
        )
        s0, s1 = c.source_span
        need(
            bool(np.isfinite(s0) and np.isfinite(s1)) and -half_frame <= s0 <= s1 <= duration + half_frame,
            f"constraint on {c.joint[:40]!r}: its source span {s0:g} to {s1:g} s is not within the clip",
        )
    signals = _checked_signals(arrays, frames, sum(len(tr.names) for tr in tracks), need)
    if isinstance(parameters, dict):  # what `constraints --detect` reuses must be usable
        joints_param = parameters.get("contact_joints", [])
        need(
            isinstance(joints_param, list) and all(isinstance(j, str) for j in joints_param),
            "parameters: contact_joints is not a list of names",
        )
        tree = parameters.get("marker_tree", {})
        need(
            isinstance(tree, dict)
            and all(isinstance(k, str) and isinstance(v, str) for k, v in tree.items())
            and set(tree) | set(tree.values()) <= joints,
            "parameters: marker_tree is not a map of marker labels to marker labels",
        )
        need(not tree_has_loop(tree), "parameters: marker_tree has a loop")
        for key in ("min_contact", "contact_tolerance"):
            value = parameters.get(key, 0.0)
            need(
                type(value) in (int, float) and np.isfinite(value) and value >= 0,
                f"parameters: {key} is not a non-negative number",
            )
    return Document(
        pose_t=pose_t,
        priority=priority,
        tracks=tuple(tracks),
        layer_pose_t=layer_pose_t,
        source=source,
        source_name=str(src_info.get("name", "")),
        source_sha256=str(src_info.get("sha256", "")),
        constraints=constraints,
        signals=signals,
        parameters=parameters if isinstance(parameters, dict) else {},
        pose_part=pose_part,
        layer_pose_part=layer_pose_part,
    )


def _checked_parts(parts, what: str, K: int, need) -> tuple[str | None, ...]:
    """A manifest's list of pose parts: K entries, each null or a body part
    (``"@left-arm"``), the first and last null (they pin the clip's ends)."""
    from ..names import PARTS

    need(isinstance(parts, list) and len(parts) == K, f"{what} must be a list of {K} entries (one per pose)")
    need(
        all(p is None or (isinstance(p, str) and p.startswith("@") and p[1:] in PARTS) for p in parts),
        f"{what} holds something that is neither null nor a body part ({', '.join('@' + p for p in PARTS)})",
    )
    need(K < 1 or (parts[0] is None and parts[-1] is None), f"{what}: the first and last pose must be whole-body")
    return tuple(parts)


def _rows_all(a: np.ndarray, test) -> bool:
    """Whether the elementwise (or row-wise) ``test`` holds everywhere in
    ``a``, judged a block of rows at a time: no temporaries of a long clip's
    arrays."""
    if a.ndim == 0:
        return bool(test(a))
    rows = max(1, _CHECK_BLOCK // max(int(np.prod(a.shape[1:])), 1))
    return all(bool(np.all(test(a[lo : lo + rows]))) for lo in range(0, len(a), rows))


def _unit_rows(q: np.ndarray) -> np.ndarray:
    return np.abs(np.linalg.norm(q, axis=1) - 1) < 1e-6


#: Values checked at once by :func:`_rows_all`.
_CHECK_BLOCK = 1 << 18


def _safe_format(fmt: str) -> bool:
    return re.fullmatch(r"%\.\d{1,2}[fg]", fmt) is not None


#: Largest frame count or index a manifest may give (far beyond any clip, and
#: small enough for every integer array and float conversion).
_MAX_INDEX = 2**31 - 1


def _whole_number(value, what: str, lo: int, hi: int) -> int:
    """``value`` if it is a JSON whole number (not a float, not a bool) in
    ``[lo, hi]``; else a DataError naming ``what``."""
    if type(value) is not int or not lo <= value <= hi:
        shown = repr(value) if len(repr(value)) <= 24 else repr(value)[:20] + "..."
        raise DataError(f"{what} must be a whole number from {lo} to {hi}, got {shown}")
    return value


def _whole_numbers(values, what: str, lo: int, hi: int) -> np.ndarray:
    """An int array of a JSON list of whole numbers in ``[lo, hi]`` (floats
    such as 2.5 or 1e308 and bools are refused, not truncated)."""
    if not isinstance(values, list):
        raise DataError(f"{what} must be a list of whole numbers")
    for i, v in enumerate(values):
        _whole_number(v, f"{what}[{i}]", lo, hi)
    return np.array(values, dtype=np.int64)


#: Stored signals of known meaning and their shapes: T frames, V variables.
_SIGNAL_SHAPES = {"P": ("T",), "p": ("T", "V"), "weights": ("V",), "contact": ("T",)}


def _checked_signals(arrays: dict, frames: int, n_vars: int, need) -> dict[str, np.ndarray]:
    """The ``signal.*`` arrays: numeric and finite, and the known ones of
    their shape (plots and reprioritizing read them)."""
    signals = {}
    for key, val in arrays.items():
        if not key.startswith("signal."):
            continue
        name = key.split(".", 1)[1]
        need(isinstance(val, np.ndarray) and val.dtype.kind in "fiub", f"array {key!r} is not numeric")
        need(_rows_all(val, np.isfinite), f"array {key!r} holds values that are not finite")
        if name in _SIGNAL_SHAPES:
            dims = {"T": frames, "V": n_vars}
            want = tuple(dims[d] for d in _SIGNAL_SHAPES[name])
            need(val.shape == want, f"array {key!r} has shape {val.shape}, expected {want}")
        signals[name] = val
    return signals


#: Largest magnitude of a source value (the readers' limit) and of a fitted
#: one (knots, tangents, displacements; cubes of it stay finite): beyond them
#: the spline and FK math overflows.
_MAX_MAGNITUDE = 1e12
_MAX_FITTED = 1e100
_BVH_NAME = re.compile(r"[^\s{}]+( [^\s{}]+)*")
_BVH_CHANNELS = set(POSITION_CHANNELS) | set(ROTATION_CHANNELS)
_FRAME_TIME = re.compile(r"[+]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?")


def _from_version_1(arrays: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Version 1 arrays renamed as version 2's: ``track{n}.{key}`` is layer 0."""
    out = {}
    for key, val in arrays.items():
        head, _, rest = key.partition(".")
        if head.startswith("track") and head[5:].isdigit() and rest in _TRACK_ARRAYS:
            key = f"{head}.layer0.{rest}"
        out[key] = val
    return out


def _checked_layer_poses(arrays, lay: int, duration: float, need, arr) -> np.ndarray:
    """The pose times of layer ``lay >= 1``: strictly increasing, from the first
    frame to the last."""
    pose_t = arr(f"layer{lay}.pose_t", 1)
    need(
        len(pose_t) >= 2 and bool(np.all(np.isfinite(pose_t))) and bool(np.all(np.diff(pose_t) > 0)),
        f"layer{lay}.pose_t must hold at least two finite, strictly increasing times",
    )
    need(
        abs(pose_t[0]) < 1e-6 and abs(pose_t[-1] - duration) < 1e-6,
        f"layer{lay}.pose_t must run from the first frame to the last (0 to {duration:.4f} s)",
    )
    return pose_t


def _checked_layer(n, lay, kind, names, arrays, pose_t, need, arr, owns) -> Layer:
    """Layer ``lay`` of track ``n``, checked against its poses ``pose_t`` and
    what they own (``owns`` (K, V)): every variable has one extreme knot per
    pose that owns it, in pose order; the base layer's editing knots sit at
    their pose times, and a layer above it has none."""
    from ..model.knots import check_knot_order

    K = len(pose_t)
    V = len(names)
    D = 3 if kind == TRANSLATION else 4
    p = f"track{n}.layer{lay}."
    knot_ptr = arr(p + "knot_ptr", 1, "iu").astype(int)
    knot_t = arr(p + "knot_t", 1)
    knot_v = arr(p + "knot_v", 2)
    knot_pose = arr(p + "knot_pose", 1, "iu").astype(int)
    knot_editing = arr(p + "knot_editing", 1, "b")
    tan_a = arr(p + "tan_a", 2)
    tan_b = arr(p + "tan_b", 2)
    samp_ptr = arr(p + "samp_ptr", 1, "iu").astype(int)
    samp_s = arr(p + "samp_s", 1)
    samp_d = arr(p + "samp_d", 2)
    NK = len(knot_t)
    need(
        knot_ptr.shape == (V + 1,) and knot_ptr[0] == 0 and knot_ptr[-1] == NK, f"{p}knot_ptr does not index the knots"
    )
    need(bool(np.all(np.diff(knot_ptr) >= 1)), f"{p}knot_ptr gives a variable no knot")
    need(
        knot_v.shape == (NK, D) and knot_pose.shape == (NK,) and knot_editing.shape == (NK,),
        f"{p}knot arrays have inconsistent shapes",
    )
    need(tan_a.shape == (NK - V, 3) and tan_b.shape == (NK - V, 3), f"{p}tangents do not match the segments")
    NS = len(samp_s)
    need(
        samp_ptr.shape == (V + 1,) and samp_ptr[0] == 0 and samp_ptr[-1] == NS and bool(np.all(np.diff(samp_ptr) >= 0)),
        f"{p}samp_ptr does not index the samples",
    )
    need(samp_d.shape == (NS, D), f"{p}samp_d has the wrong shape")
    for a, label in (
        (knot_t, "knot times"),
        (knot_v, "knot values"),
        (tan_a, "tangents"),
        (tan_b, "tangents"),
        (samp_s, "samples"),
        (samp_d, "displacements"),
    ):
        need(_rows_all(a, np.isfinite), f"{p}{label} are not all finite")
        need(_rows_all(a, lambda b: np.abs(b) <= _MAX_FITTED), f"{p}{label} are beyond ±{_MAX_FITTED:g}")
    need(
        bool(np.all((knot_t >= pose_t[0] - 1e-6) & (knot_t <= pose_t[-1] + 1e-6))),
        f"{p}knot times lie outside the clip",
    )
    need(bool(np.all((knot_pose >= 0) & (knot_pose < K))), f"{p}knots name poses that do not exist")
    nseg = np.diff(knot_ptr) - 1
    # a variable at a time: no per-sample temporaries of a long clip
    inside, ordered = True, True
    for i in range(V):
        s_i = samp_s[samp_ptr[i] : samp_ptr[i + 1]]
        inside = inside and bool(np.all((s_i >= 0) & (s_i <= nseg[i])))
        ordered = ordered and bool(np.all(np.diff(s_i) >= 0))
    need(inside, f"{p}samples lie outside their variable's segments")
    need(ordered, f"{p}a variable's samples are not in order")
    if kind == ROTATION:
        need(
            _rows_all(knot_v, _unit_rows),
            f"{p}knot rotations are not unit quaternions",
        )
        need(
            _rows_all(samp_d, _unit_rows),
            f"{p}displacement rotations are not unit quaternions",
        )
    try:
        check_knot_order(knot_ptr, knot_t, names)
    except Exception as exc:  # KnotOrderError is a usage error when editing, a data error when read
        raise DataError(f"{p}{exc}") from None
    # every variable has one extreme knot per pose that owns it, in pose
    # order, and its editing knots sit at their pose's time (else
    # refinements are undefined)
    var = np.repeat(np.arange(V), np.diff(knot_ptr))
    ext = ~knot_editing.astype(bool)
    own_var, own_pose = np.nonzero(np.asarray(owns, dtype=bool).T)
    need(
        np.array_equal(var[ext], own_var) and np.array_equal(knot_pose[ext], own_pose),
        f"{p}knots do not give every variable one extreme knot per pose that owns it",
    )
    need(
        bool(np.all(np.asarray(owns, dtype=bool)[knot_pose, var])),
        f"{p}knots belong to poses that do not own their variable",
    )
    need(
        bool(np.all(np.abs(knot_t[~ext] - pose_t[knot_pose[~ext]]) < 1e-6)),
        f"{p}editing knots do not sit at their pose times",
    )
    need(lay == 0 or not bool(np.any(knot_editing)), f"{p}a layer above the base has editing knots")
    knots = Knots(knot_ptr, knot_t, knot_v, knot_pose, knot_editing.astype(bool))
    return Layer(knots, tan_a, tan_b, samp_ptr, samp_s, samp_d)
