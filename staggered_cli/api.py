"""The public API: ``import staggered_cli as st``.

One function per command, document first; keywords are the command's
options with underscores, in the same units (seconds, degrees, file units).
Documents and motions are immutable values: each function returns a new one
and never changes its argument.  Errors are :class:`~staggered_cli.errors.StaggeredError`
(``DataError`` for bad data, ``UsageError`` for bad arguments); what an edit
cannot do as asked is a :class:`~staggered_cli.errors.StaggeredWarning`.

Nothing heavy is imported here: each function imports what it runs.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING, Any, BinaryIO

from .errors import StaggeredError, UsageError, arg

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from .batching import Result as BatchResult
    from .model.document import Document
    from .motion import BvhMotion, MarkerMotion

    Motion = BvhMotion | MarkerMotion

Triple = tuple[float, float, float]
Span = tuple[float, float]


def _number(value: Any, name: str) -> float:
    """``value`` as a finite float, or a UsageError naming ``name``."""
    import math

    try:
        x = float(value)
    except (TypeError, ValueError):
        raise UsageError(f"{arg(name)} must be a number, got {value!r}") from None
    if not math.isfinite(x):
        raise UsageError(f"{arg(name)} must be a finite number, got {value!r}")
    return x


def _names(value: str | Sequence[str] | None, name: str) -> list[str] | None:
    """Joint or marker names: a list, or a comma-separated string."""
    if value is None:
        return None
    items = value.split(",") if isinstance(value, str) else list(value)
    out = [str(x).strip() for x in items if str(x).strip()]
    if not out:
        raise UsageError(f"{arg(name)} names no joint or marker")
    return out


def _span(value: Span | None, name: str) -> Span | None:
    """``(A, B)`` seconds; None for either side is the clip's end."""
    import math

    if value is None:
        return None
    try:
        a, b = value
    except (TypeError, ValueError):
        raise UsageError(f"{arg(name)} must be a pair (A, B) of seconds, got {value!r}") from None
    lo = -math.inf if a is None else _number(a, name)
    hi = math.inf if b is None else _number(b, name)
    if lo > hi:
        raise UsageError(f"{arg(name)}: A must not exceed B, got ({lo:g}, {hi:g})")
    return lo, hi


def _triples(value: Mapping[str, Triple] | None, name: str) -> dict[str, Triple]:
    out: dict[str, Triple] = {}
    for joint, xyz in (value or {}).items():
        try:
            x, y, z = xyz
        except (TypeError, ValueError):
            raise UsageError(f"{arg(name)} {joint}: expected three numbers (x, y, z), got {xyz!r}") from None
        out[str(joint)] = (_number(x, name), _number(y, name), _number(z, name))
    return out


def _document(doc: Any, name: str = "doc") -> Document:
    from .model.document import Document

    if not isinstance(doc, Document):
        what = type(doc).__name__
        hint = ": run st.extract on it first" if what in ("BvhMotion", "MarkerMotion") else ""
        raise UsageError(f"{arg(name)} must be a staggered-pose Document, got {what}{hint}")
    return doc


def _pose_mask(doc: Document, poses: Sequence[int] | None, time: Span | None):
    from .ops.timing import select_poses

    chosen = None if poses is None else [int(k) for k in poses]
    if chosen is not None and not chosen:
        raise UsageError(f"{arg('poses')} names no pose")
    return select_poses(doc, chosen, _span(time, "time"))


# --------------------------------------------------------------------------- files


def read(source: str | os.PathLike | bytes | BinaryIO) -> Motion | Document:
    """Read a BVH, a C3D or a staggered-pose document, told apart by content.

    Parameters
    ----------
    source : str, path-like, bytes or binary file object
        A path (``"-"`` is standard input), the file's bytes, or a file
        opened in binary mode.

    Returns
    -------
    BvhMotion, MarkerMotion or Document
        A BVH clip (channels as written, degrees and file units), a C3D
        clip (points ``(T, M, 3)`` in file units, NaN in gaps) or a document.

    Raises
    ------
    DataError
        A missing, malformed or truncated file; the message names it.

    Examples
    --------
    >>> import staggered_cli as st
    >>> clip = st.read("data/samples/march.bvh")
    >>> clip.n_frames, round(clip.frame_time, 4)
    (121, 0.0333)
    """
    from .io.formats import read as io_read

    return io_read(source)


def write(
    value: Document | Motion,
    dest: str | os.PathLike | BinaryIO,
    *,
    format: str | None = None,
    force: bool = False,
    unit_scale: float | None = None,
    keys: str | None = None,
) -> None:
    """Write a document (NPZ or JSON), a BVH motion or a C3D motion, or a
    motion as glTF 2.0.

    Parameters
    ----------
    value : Document, BvhMotion or MarkerMotion
    dest : str, path-like or binary file object
        A path (``"-"`` is standard output) or a file opened for binary
        writing.  A path is written atomically: complete, or not there.
    format : {"npz", "json", "glb", "gltf"}, optional
        For a document: the default is JSON when ``dest`` ends in ``.json``,
        else NPZ.  For a motion: ``"glb"`` (binary glTF) or ``"gltf"`` (JSON
        glTF, the buffer in it as base64); the default is glTF when ``dest``
        ends in ``.glb`` or ``.gltf``, else the motion's own format.
    force : bool
        Replace an existing file (refused otherwise).
    unit_scale : float, optional
        glTF only: metres per file unit (glTF is in metres).  The default is
        the C3D's POINT:UNITS, else the unit (m, cm, mm, CMU's 1/0.45 inch,
        inch, dm) that makes the figure 1.0 to 2.2 m tall.
    keys : {"dense", "poses"}, optional
        glTF only: ``"dense"`` (the default, for a motion) keys every frame,
        LINEAR.  ``"poses"`` (for a BVH document of one layer) keys each
        joint at its own knots of the staggered poses, CUBICSPLINE, fitted
        to follow the splines (displacement maps and contacts are not in
        these keys).

    Raises
    ------
    UsageError
        ``dest`` exists without ``force``; its name says another kind (a
        document named ``.bvh``, a BVH named ``.c3d``); a ``unit_scale``
        that is not positive or makes the figure shorter than 1 cm or
        taller than 1 km.
    DataError
        A motion with values glTF's 32-bit floats cannot hold.

    Examples
    --------
    >>> import io
    >>> import staggered_cli as st
    >>> buffer = io.BytesIO()
    >>> st.write(st.read("data/samples/march.bvh"), buffer)
    >>> from pathlib import Path
    >>> buffer.getvalue() == Path("data/samples/march.bvh").read_bytes()
    True

    The same motion as binary glTF, a skinned skeleton in metres:

    >>> st.write(st.read("data/samples/march.bvh"), "out/doctest/march.glb", force=True)
    >>> Path("out/doctest/march.glb").read_bytes()[:4]
    b'glTF'

    Or the staggered poses of a document as keys (each joint at its own times):

    >>> st.write(st.extract(st.read("data/samples/march.bvh")), "out/doctest/march_poses.glb",
    ...          keys="poses", force=True)
    """
    from .io.formats import write as io_write

    io_write(value, dest, format=format, force=force, unit_scale=unit_scale, keys=keys)


# --------------------------------------------------------------------------- extract


def extract(
    motion: Motion,
    *,
    contact_joints: str | Sequence[str] | None = None,
    smoothing: float | None = None,
    filter_width: float | None = None,
    refine_window: float = 0.25,
    min_contact: float = 0.1,
    contact_tolerance: float = 0.03,
    significance: float = 0.5,
    min_spacing: float | None = None,
    partial: bool = False,
) -> Document:
    """Find the staggered poses, refinements, contacts, splines and
    displacement maps of a dense clip (the paper's section 4).

    Parameters
    ----------
    motion : BvhMotion or MarkerMotion
        What :func:`read` returned for a BVH or C3D file.
    contact_joints : str or list of str, optional
        Joints (BVH) or marker labels (C3D) to find contacts on; default the
        feet and toes, or the lowest markers.  ``@left-leg`` style parts work.
    smoothing : float, optional
        Laplacian smoothing of the curvature signals, seconds (0.025).
    filter_width : float, optional
        Tent filter full base width of the pose probability, seconds.
        Default 0.15, shorter for fast motion: times the clip's stride (the
        median time between a foot's contacts) over 1 s, at least a third.
    refine_window : float
        Largest timing refinement, seconds.
    min_contact : float
        Shortest contact, seconds.
    contact_tolerance : float
        How still a planted joint stays, a fraction of the figure height.
    significance : float
        Motion a pose needs, in figure heights per second summed over the
        body (0 keeps every local maximum).
    min_spacing : float, optional
        Fewest seconds between two poses.  Default 0.1, scaled by the
        clip's tempo as ``filter_width`` is.  ``doc.parameters`` records
        the values used.
    partial : bool
        Partition the poses among the body parts (``doc.pose_part``): a
        whole-body pose there for one part only becomes that part's partial
        pose, and the knots freed (no more) go to the parts' own partial
        poses at their features, where they earn them (BVH only).

    Returns
    -------
    Document
        Baking it gives the clip back exactly.

    Examples
    --------
    >>> import staggered_cli as st
    >>> doc = st.extract(st.read("data/samples/march.bvh"))
    >>> doc.n_poses, len(doc.constraints)
    (24, 8)
    >>> st.write(st.bake(doc), "out/doctest/march.bvh", force=True)
    >>> from pathlib import Path
    >>> Path("out/doctest/march.bvh").read_bytes() == Path("data/samples/march.bvh").read_bytes()
    True
    """
    from .motion import BvhMotion, MarkerMotion
    from .ops.extract import MAX_EXTRACT_VALUES, check_options
    from .ops.extract import extract as op

    if not isinstance(motion, BvhMotion | MarkerMotion):
        what = type(motion).__name__
        hint = ": it is already a document" if what == "Document" else ""
        raise UsageError(f"{arg('motion')} must be a BVH or C3D clip (st.read), got {what}{hint}")
    options = dict(
        smoothing=smoothing,
        filter_width=filter_width,
        refine_window=refine_window,
        min_contact=min_contact,
        contact_tolerance=contact_tolerance,
        significance=significance,
        min_spacing=min_spacing,
    )
    check_options(**options)  # the options before the clip (a batch checks them so, on no clip)
    if isinstance(motion, BvhMotion) and motion.channels.size > MAX_EXTRACT_VALUES:
        raise UsageError(
            f"{arg('motion')} has {motion.channels.size:,} channel values, more than extract's "
            f"limit of {MAX_EXTRACT_VALUES:,}: split the clip"
        )
    return op(
        motion,
        source_name=motion.name,
        source_bytes=motion.source or None,
        contact_joints=_names(contact_joints, "contact_joints"),
        partial=bool(partial),
        **options,
    )


# --------------------------------------------------------------------------- poses


def check_keep(keep: str | int) -> None:
    """Refuse a ``keep`` that is neither a count nor a percentage (before
    any document is read: a batch checks its steps so)."""
    from .ops.cull import keep_count

    keep_count(str(keep), 1)


def cull(
    doc: Document,
    *,
    keep: str | int | None = None,
    interval: Span | None = None,
    select: Sequence[int] | None = None,
    add_time: float | Sequence[float] = (),
    part: str | None = None,
    by: str = "error",
    ignore_contacts: bool = False,
) -> Document:
    """Keep fewer poses (first and last always); the baked motion does not change.

    Parameters
    ----------
    doc : Document
    keep : int or str, optional
        Keep exactly N poses (``12``) or a share of them (``"30%"``), ranked
        ``by``; within ``interval`` or ``select`` when given.
    interval : (float, float), optional
        Keep the poses between A and B seconds.
    select : list of int, optional
        Keep these pose indices.
    add_time : float or list of float
        Add an unrefined pose at each of these times, seconds.
    part : str, optional
        With ``add_time``: add *partial poses* that own only this body part's
        variables (``"@left-arm"``, ``"@right-arm"``, ``"@left-leg"``,
        ``"@right-leg"``, ``"@spine"``, ``"@head"``; BVH only); the other
        variables keep their knots exactly.  Partial poses count, rank and
        can be selected like the others.
    by : {"error", "paper"}
        ``"error"``: the N poses whose spline layer fits best; ``"paper"``:
        the paper's priority.
    ignore_contacts : bool
        Rank every pose alike (by default poses on contact changes go last).

    Examples
    --------
    >>> import staggered_cli as st
    >>> doc = st.extract(st.read("data/samples/march.bvh"))
    >>> st.cull(doc, keep="50%").n_poses
    12
    >>> st.cull(doc, keep=4, add_time=1.5).n_poses
    5
    >>> arm = st.cull(doc, add_time=[0.55, 1.0], part="@left-arm")
    >>> [p for p in arm.pose_part if p]
    ['@left-arm', '@left-arm']
    >>> bool((st.bake(arm).channels == st.bake(doc).channels).all())
    True
    """
    from .model.document import canonical_part
    from .ops.cull import add_pose, base_motion, choose, keep_poses

    doc = _document(doc)
    times = [add_time] if isinstance(add_time, int | float) else list(add_time)
    times = [_number(t, "add_time") for t in times]
    choosing = keep is not None or interval is not None or select is not None
    if not choosing and not times:
        raise UsageError(f"say what to keep: {arg('keep')}, {arg('interval')}, {arg('select')}, or {arg('add_time')}")
    if keep is not None:
        check_keep(keep)
    span = _span(interval, "interval")
    chosen = None if select is None else [int(k) for k in select]
    if chosen is not None and not chosen:
        raise UsageError(f"{arg('select')} names no pose")
    if part is not None:
        part = canonical_part(part)
        if not times:
            raise UsageError(f"{arg('part')} says what the poses of {arg('add_time')} own: give {arg('add_time')}")
        doc.part_mask(part)  # BVH, and a part this skeleton has: refused before any work
    if choosing:
        motion = base_motion(doc)  # ranking and refitting both read it: evaluated once
        mask = choose(
            doc,
            keep=None if keep is None else str(keep),
            interval=span,
            select=chosen,
            ignore_contacts=ignore_contacts,
            by=by,
            motion=motion,
        )
        doc = keep_poses(doc, mask, motion)
        del motion
    for t in times:
        doc = add_pose(doc, t, part)
    return doc


def edit_pose(
    doc: Document,
    pose: int | None = None,
    *,
    layer: int = 0,
    on: str = "true",
    rotate: Mapping[str, Triple] | None = None,
    translate: Mapping[str, Triple] | None = None,
    exaggerate: float | None = None,
    relative_to: str | int = "average",
    ease: float | None = None,
    joints: str | Sequence[str] | None = None,
    subtree: bool = False,
    from_bvh: str | os.PathLike | BvhMotion | None = None,
    frame: int | None = None,
    root: bool = False,
    all: bool = False,
    time: float | None = None,
    shift: float | None = None,
) -> Document:
    """Edit one pose; the motion changes only between its neighbouring knots
    and the capture's detail rides along (the paper's section 5.1).

    Parameters
    ----------
    doc : Document
    pose : int
        Pose index (negative counts from the end), of ``layer``.
    layer : int
        0 edits the staggered poses; L >= 1 a layer added with :func:`add_layer`.
    on : {"true", "extreme"}
        Edit the true pose at t_k, or the non-staggered pose (extreme values).
    rotate : dict of str to (rx, ry, rz), optional
        Degrees about each joint's local axes (XYZ order).
    translate : dict of str to (x, y, z), optional
        File units, for joints with position channels or markers.
    exaggerate : float, optional
        Scale the pose's difference from ``relative_to`` by W (1 unchanged).
    relative_to : {"prev", "next", "average"} or int
        The reference pose of ``exaggerate``.
    ease : float, optional
        Scale the inner spline controls on both sides (0 linear, >1 hold).
    joints, subtree : optional
        Restrict ``exaggerate``, ``from_bvh`` and ``ease`` to these joints
        (and their descendants).
    from_bvh : path or BvhMotion, optional
        Set the pose from ``frame`` of a BVH with the same skeleton; with
        ``all=True`` frame k sets pose k for every pose.
    root : bool
        Take the root's place and heading from ``from_bvh`` too, or
        exaggerate them too (kept by default).
    time, shift : float, optional
        Move the pose to ``time`` seconds, or by ``shift`` seconds.

    Examples
    --------
    >>> import staggered_cli as st
    >>> doc = st.extract(st.read("data/samples/march.bvh"))
    >>> edited = st.edit_pose(doc, 3, rotate={"LeftArm": (0, 0, 20)})
    >>> changed = st.bake(edited).channels != st.bake(doc).channels
    >>> bool(changed.any()), bool(changed[0].any())
    (True, False)
    """
    from .model.document import check_pose_index
    from .ops import edit_pose as ops
    from .ops.layers import ease as ease_op

    doc = _document(doc)
    rot = _triples(rotate, "rotate")
    tra = _triples(translate, "translate")
    w = None if exaggerate is None else _number(exaggerate, "exaggerate")
    x = None if ease is None else _number(ease, "ease")
    ops.check_values(w, x)
    names = _names(joints, "joints")
    ops.check_request(
        pose=pose,
        all_poses=all,
        rotate=bool(rot),
        translate=bool(tra),
        exaggerate=w,
        ease=x,
        from_bvh=from_bvh,
        frame=frame,
        root=root,
        layer=layer,
        time=time,
        shift=shift,
        joints=bool(names),
        subtree=subtree,
    )
    if all:
        return _apply_pose_file(doc, from_bvh, on, names, subtree)[0]
    k = check_pose_index(doc, int(pose), layer)
    values = None
    if from_bvh is not None:
        other, source = _pose_file(from_bvh)
        try:
            values = ops.values_from_motion(doc, other, int(frame), names, subtree)
        except StaggeredError as err:  # about the pose file, not the document
            if source:
                raise err.with_source(source) from None
            raise
    doc = ops.edit_pose(
        doc,
        k,
        on=on,
        rotate=rot,
        translate=tra,
        exaggerate=w,
        relative_to=str(relative_to),
        joints=names,
        subtree=subtree,
        values=values,
        root=root,
        layer=layer,
    )
    if x is not None:
        masks = ops.joint_mask(doc, names, subtree) if names else None
        doc = ease_op(doc, k, x, layer=layer, masks=masks)
    if time is not None or shift is not None:
        t0 = doc.poses_of(layer)[k]
        t = _number(time, "time") if time is not None else t0 + _number(shift, "shift")
        if layer:
            from .ops.layers import retime_layer_pose

            doc = retime_layer_pose(doc, layer, k, t)
        else:
            from .ops.timing import retime_pose

            doc = retime_pose(doc, k, t)
    return doc


def _pose_file(from_bvh) -> tuple[BvhMotion, str]:
    """The BVH ``from_bvh`` names (a path) or is, and its name for messages."""
    from .motion import BvhMotion

    if not isinstance(from_bvh, str | os.PathLike):  # a clip read already: ops says what it must be
        return from_bvh, getattr(from_bvh, "name", "")
    from .io.files import display_name
    from .io.formats import read as io_read

    name = display_name(os.fspath(from_bvh))
    other = io_read(from_bvh)
    if not isinstance(other, BvhMotion):
        raise UsageError(f"{arg('from_bvh')} {name} is not a BVH file")
    return other, name


def _apply_pose_file(doc, from_bvh, on, names, subtree):
    """``from_bvh=..., all=True``: frame k of the file sets pose k where it
    changed.  Returns the document, the poses and the joints changed."""
    from .ops.pose_file import apply_pose_file

    other, name = _pose_file(from_bvh)
    return apply_pose_file(doc, other, on=on, joints=names, subtree=subtree, name=name)


def succession(
    doc: Document,
    *,
    offset: float,
    power: float = 1.0,
    joint: str | None = None,
    chain: str | Sequence[str] | None = None,
    poses: Sequence[int] | None = None,
    time: Span | None = None,
    clamp: bool = False,
) -> Document:
    """Stagger the timing down a limb: ``r[k,i] += offset * depth(i) ** power``.

    Parameters
    ----------
    doc : Document
    offset : float
        Seconds per unit of depth (negative: the limb leads).
    power : float
        Nonlinearity (1 is Neff and Fiume's linear succession).
    joint : str, optional
        The joint at depth 0 (BVH; its subtree follows), or a part such as
        ``"@left-arm"``.
    chain : str or list of str, optional
        An explicit order instead (C3D markers): depths 0, 1, 2, ...
    poses : list of int, optional
        Only these poses (default: all but the first and last).
    time : (float, float), optional
        Only the poses between A and B seconds.
    clamp : bool
        Stop knots short of their neighbours instead of refusing.

    Examples
    --------
    >>> import staggered_cli as st
    >>> doc = st.extract(st.read("data/samples/march.bvh"))
    >>> loose = st.succession(doc, joint="LeftArm", offset=0.03, power=1.5, clamp=True)
    >>> loose.n_poses == doc.n_poses
    True
    """
    from .ops.timing import succession as op

    doc = _document(doc)
    s = _number(offset, "offset")
    p = _number(power, "power")
    if p <= 0:
        raise UsageError(f"{arg('power')} must be positive, got {power}")
    if (joint is None) == (chain is None):
        raise UsageError(f"give exactly one of {arg('joint')} and {arg('chain')}")
    return op(doc, s, p, joint=joint, chain=_names(chain, "chain"), poses=_pose_mask(doc, poses, time), clamp=clamp)


def randomize(
    doc: Document,
    *,
    tau: float,
    seed: int,
    joints: str | Sequence[str] | None = None,
    subtree: bool = False,
    poses: Sequence[int] | None = None,
    time: Span | None = None,
    clamp: bool = False,
) -> Document:
    """Add random offsets ``uniform(-tau, tau)`` seconds to the refinements.

    Parameters
    ----------
    doc : Document
    tau : float
        Bound of the offsets, seconds.
    seed : int
        The same seed gives the same document.
    joints, subtree : optional
        Only these joints or markers (and their descendants).
    poses, time, clamp :
        As in :func:`succession`.

    Examples
    --------
    >>> import staggered_cli as st
    >>> doc = st.extract(st.read("data/samples/march.bvh"))
    >>> a = st.randomize(doc, tau=0.02, seed=7)
    >>> b = st.randomize(doc, tau=0.02, seed=7)
    >>> bool((st.bake(a).channels == st.bake(b).channels).all())
    True
    """
    from .ops.timing import randomize as op

    doc = _document(doc)
    t = _number(tau, "tau")
    if t < 0:
        raise UsageError(f"{arg('tau')} must not be negative, got {tau}")
    if int(seed) < 0:
        raise UsageError(f"{arg('seed')} must not be negative, got {seed}")
    names = _names(joints, "joints")
    if subtree and not names:
        raise UsageError(f"{arg('subtree')} needs {arg('joints')}: it adds the descendants of the joints named there")
    return op(doc, t, int(seed), joints=names, subtree=subtree, poses=_pose_mask(doc, poses, time), clamp=clamp)


# --------------------------------------------------------------------------- layers


def add_layer(doc: Document, *, keep: str | int | None = None, times: Sequence[float] | None = None) -> Document:
    """Stack a layer of identity offsets over the motion (it does not change).

    Parameters
    ----------
    doc : Document
    keep : int or str, optional
        The layer's poses are N (or P%) of the current poses, as
        :func:`cull` ranks them (a partial pose gives a partial layer pose,
        with offsets in its part only).
    times : list of float, optional
        Or the layer's poses are at these times, seconds.

    Examples
    --------
    >>> import staggered_cli as st
    >>> doc = st.add_layer(st.extract(st.read("data/samples/march.bvh")), keep=4)
    >>> doc.n_layers
    2
    >>> arm = st.edit_pose(doc, 1, layer=1, rotate={"LeftArm": (0, 0, 15)})
    >>> bool((st.bake(st.remove_layer(arm, 1)).channels == st.bake(doc).channels).all())
    True
    """
    from .ops import layers as ops
    from .ops.cull import choose

    doc = _document(doc)
    if (keep is None) == (times is None):
        raise UsageError(f"give the layer's poses: {arg('keep')} or {arg('times')}")
    if keep is not None:
        check_keep(keep)
        mask = choose(doc, keep=str(keep))
        parts = tuple(p for p, m in zip(doc.pose_part, mask, strict=True) if m)
        return ops.add_layer(doc, doc.pose_t[mask], parts)
    values = [_number(t, "times") for t in times]
    if not values:
        raise UsageError(f"{arg('times')}: give at least one time")
    return ops.add_layer(doc, ops.layer_times(doc, values))


def remove_layer(doc: Document, layer: int) -> Document:
    """The document without layer ``layer`` (1 and up): the motion as it was
    before that layer, exactly.

    Examples
    --------
    >>> import staggered_cli as st
    >>> doc = st.extract(st.read("data/samples/march.bvh"))
    >>> st.remove_layer(st.add_layer(doc, times=[0.5, 2.0]), 1).n_layers
    1
    """
    from .ops import layers as ops

    return ops.remove_layer(_document(doc), int(layer))


def detail(
    doc: Document,
    *,
    gain: float,
    joints: str | Sequence[str] | None = None,
    subtree: bool = False,
    time: Span | None = None,
) -> Document:
    """Scale the displacement maps (the capture's detail over the splines).

    Parameters
    ----------
    doc : Document
    gain : float
        0 the splines alone, 1 unchanged, 0.5 softens, 1.5 accentuates.
    joints, subtree : optional
        Only these joints or markers (and their descendants).
    time : (float, float), optional
        Only between A and B seconds (eased in and out over 0.1 s).

    Examples
    --------
    >>> import staggered_cli as st
    >>> doc = st.extract(st.read("data/samples/march.bvh"))
    >>> smooth = st.bake(st.detail(doc, gain=0), ik=False)
    >>> splines = st.bake(doc, layers="splines", ik=False)
    >>> bool(abs(smooth.channels - splines.channels).max() < 1e-6)
    True
    """
    from .ops.edit_pose import joint_mask
    from .ops.layers import check_gain
    from .ops.layers import detail as op

    doc = _document(doc)
    g = _number(gain, "gain")
    check_gain(g)
    names = _names(joints, "joints")
    if subtree and not names:
        raise UsageError(f"{arg('subtree')} needs {arg('joints')}: it adds the descendants of the joints named there")
    masks = joint_mask(doc, names, subtree) if names else None
    return op(doc, g, masks=masks, time_range=_span(time, "time"))


# --------------------------------------------------------------------------- contacts


def constraints(
    doc: Document,
    *,
    add: Sequence[tuple[str, float, float]] = (),
    remove: Sequence[int] = (),
    detect: bool = False,
    contact_joints: str | Sequence[str] | None = None,
    min_contact: float | None = None,
    contact_tolerance: float | None = None,
) -> Document:
    """Add, remove or re-detect the contact constraints the bake enforces.

    The list is ``doc.constraints`` (and ``info(doc)["constraints"]``).
    Edits apply in this order: ``detect`` (replaces the constraints on the
    joints it looks at), ``remove`` (indices in the list as given), ``add``
    (planted by the user: held still).  The result is sorted by start time.

    Parameters
    ----------
    doc : Document
    add : list of (joint, start, end)
        Plant ``joint`` from ``start`` to ``end`` seconds.
    remove : list of int
        Constraint indices to drop.
    detect : bool
        Re-detect contacts on the source motion.
    contact_joints, min_contact, contact_tolerance : optional
        What ``detect`` looks at, as :func:`extract` takes them.

    Examples
    --------
    >>> import staggered_cli as st
    >>> doc = st.extract(st.read("data/samples/march.bvh"))
    >>> fewer = st.constraints(doc, remove=[0])
    >>> len(fewer.constraints) == len(doc.constraints) - 1
    True
    """
    from .ops.constraints import edit_constraints

    doc = _document(doc)
    if not detect and (contact_joints is not None or min_contact is not None or contact_tolerance is not None):
        raise UsageError(
            f"{arg('contact_joints')}, {arg('min_contact')} and {arg('contact_tolerance')} go with {arg('detect')}"
        )
    if detect and remove:
        raise UsageError(f"{arg('remove')} refers to the listed constraints: run it apart from {arg('detect')}")
    spans = []
    for item in add:
        try:
            joint, start, end = item
        except (TypeError, ValueError):
            raise UsageError(f"{arg('add')} takes (joint, start, end) triples, got {item!r}") from None
        a, b = _number(start, "add"), _number(end, "add")
        if a > b:
            raise UsageError(f"{arg('add')}: start must not exceed end in {item!r}")
        spans.append((str(joint), a, b))
    return edit_constraints(
        doc,
        add=spans,
        remove=[int(k) for k in remove],
        detect=detect,
        contact_joints=_names(contact_joints, "contact_joints"),
        min_contact=None if min_contact is None else _number(min_contact, "min_contact"),
        contact_tolerance=None if contact_tolerance is None else _number(contact_tolerance, "contact_tolerance"),
    )


# --------------------------------------------------------------------------- key poses


def new(motion: BvhMotion, *, times: Sequence[float] | None = None) -> Document:
    """A document whose poses are the frames of a sparse BVH (key poses
    blocked in a DCC): cubic splines through the keys, empty displacement maps.

    Parameters
    ----------
    motion : BvhMotion
        One frame per key.
    times : list of float, optional
        Seconds of each key, from 0, increasing (default: the file's frame times).

    Examples
    --------
    >>> import staggered_cli as st
    >>> doc = st.extract(st.read("data/samples/march.bvh"))
    >>> keys = st.export_poses(doc)
    >>> blocked = st.new(keys, times=list(doc.pose_t))
    >>> blocked.n_poses == doc.n_poses
    True
    """
    import numpy as np

    from .motion import BvhMotion
    from .ops.pose_file import new_document

    if not isinstance(motion, BvhMotion):
        raise UsageError(f"{arg('motion')}: new reads key poses from a BVH, got {type(motion).__name__}")
    t = None if times is None else np.array([_number(x, "times") for x in times])
    if t is not None and not len(t):
        raise UsageError(f"{arg('times')}: give at least one time")
    return new_document(motion, t, source_name=motion.name, source_bytes=motion.source or None)


def export_poses(doc: Document, *, on: str = "true") -> BvhMotion:
    """The document's poses as a BVH clip with one frame per pose, in the
    source's hierarchy, channels and number format: edit it in a DCC and
    bring it back with ``edit_pose(doc, from_bvh=..., all=True)``.

    Examples
    --------
    >>> import staggered_cli as st
    >>> doc = st.extract(st.read("data/samples/march.bvh"))
    >>> st.export_poses(doc).n_frames == doc.n_poses
    True
    """
    from .ops.pose_file import export_poses as op

    return op(_document(doc), on=on)


# --------------------------------------------------------------------------- bake


def bake(
    doc: Document,
    *,
    fps: float | None = None,
    layers: str = "all",
    ik: bool = True,
    ik_blend: float = 0.1,
    move_plants: bool = False,
) -> Motion:
    """The document's dense motion: splines, displacement maps, stacked
    layers and the contact layer.

    Parameters
    ----------
    doc : Document
    fps : float, optional
        Output frame rate (default: the source's).
    layers : {"all", "splines"}
        ``"splines"`` bakes the splines alone: the smooth motion the poses capture.
    ik : bool
        Apply the contact (IK) layer.
    ik_blend : float
        Seconds over which the contact layer fades in and out.
    move_plants : bool
        The edits moved the figure as a whole: planted contacts move with
        them, horizontally (by default they stay on their captured path).

    Returns
    -------
    BvhMotion or MarkerMotion
        Of the source's kind; :func:`write` writes it.

    Examples
    --------
    >>> import staggered_cli as st
    >>> doc = st.extract(st.read("data/samples/march.bvh"))
    >>> st.bake(doc, fps=60).n_frames
    241
    """
    from .ops.bake import bake as op

    doc = _document(doc)
    rate = None if fps is None else _number(fps, "fps")
    blend = _number(ik_blend, "ik_blend")
    if blend < 0:
        raise UsageError(f"{arg('ik_blend')} must not be negative, got {ik_blend}")
    return op(doc, fps=rate, layers=layers, ik=ik, ik_blend=blend, move_plants=bool(move_plants))


# --------------------------------------------------------------------------- looking


def info(value: Document | Motion) -> dict[str, Any]:
    """What a document, a BVH or a C3D holds: the dict ``info --json`` prints.

    Examples
    --------
    >>> import staggered_cli as st
    >>> summary = st.info(st.read("data/samples/march.bvh"))
    >>> summary["kind"], summary["frames"], summary["joints"]
    ('bvh', 121, 17)
    """
    from .io.summary import summarize

    return summarize(value)


def plot(
    doc: Document,
    *,
    kind: str = "signals",
    joints: str | Sequence[str] | None = None,
    time: Span | None = None,
    name: str | None = None,
) -> Figure:
    """A matplotlib Figure of the document: ``"signals"`` (evidence and pose
    probability), ``"timing"`` (the dope sheet of the knots) or ``"curves"``.

    Examples
    --------
    >>> import staggered_cli as st
    >>> fig = st.plot(st.extract(st.read("data/samples/march.bvh")), kind="timing")
    >>> len(fig.axes) >= 1
    True
    """
    from . import pictures

    doc = _document(doc)
    return pictures.plot_figure(
        doc, kind, name=name or doc.source_name, joints=_names(joints, "joints"), time=_span(time, "time")
    )


def preview(
    value: Document | Motion,
    *,
    compare: Document | Motion | None = None,
    at: str = "poses",
    count: int | None = None,
    name: str | None = None,
    compare_name: str | None = None,
) -> Figure:
    """Stick figures (side and front views) at the pose times, or at
    ``count`` evenly spaced frames (``at="frames"``); ``compare`` is drawn
    over in another colour.

    Examples
    --------
    >>> import staggered_cli as st
    >>> clip = st.read("data/samples/march.bvh")
    >>> fig = st.preview(clip, at="frames", count=4)
    >>> len(fig.axes)
    8
    """
    from . import pictures

    if at not in ("poses", "frames"):
        raise UsageError(f"{arg('at')} must be 'poses' or 'frames', got {at!r}")
    return pictures.preview_figure(
        value, compare=compare, at=at, count=count, name=name or _name_of(value), compare_name=compare_name
    )


def view(
    value: Document | Motion,
    *,
    compare: Document | Motion | Sequence[Document | Motion] | None = None,
    name: str | None = None,
    compare_names: Sequence[str] | None = None,
) -> str:
    """A self-contained HTML page that plays ``value`` (a clip, or a
    document as it bakes) in the browser: 3D playback, orbit, a timeline
    to scrub with the pose times and, for a document, its staggered timing
    (as ``plot(kind="timing")`` draws it).  ``compare``: other motions
    drawn over it in other colours.  The page needs no network and no
    server: write it to an ``.html`` file and open it.

    Parameters
    ----------
    value : Document, BvhMotion or MarkerMotion
        Its poses (a document's) drive the timeline.
    compare : one or a sequence of Document, BvhMotion or MarkerMotion, optional
    name, compare_names : str, optional
        Shown in the page's title and legend (default: the motions' own names).

    Returns
    -------
    str
        The page's HTML: the motion travels in it as float32 in base64
        (about 4/3 of 12 bytes per point and frame).

    Examples
    --------
    >>> import staggered_cli as st
    >>> clip = st.read("data/samples/march.bvh")
    >>> page = st.view(st.extract(clip), compare=clip)
    >>> page.startswith("<!doctype html>"), "staggered-meta" in page
    (True, True)
    """
    from .io.page import page_pieces
    from .model.document import Document
    from .motion import BvhMotion, MarkerMotion
    from .viewer import page_data

    kinds = (Document, BvhMotion, MarkerMotion)
    others = () if compare is None else (compare,) if isinstance(compare, kinds) else tuple(compare)
    for i, x in enumerate((value, *others)):
        if not isinstance(x, kinds):
            what = "value" if i == 0 else "compare"
            raise UsageError(f"{arg(what)} must be a Document, a BvhMotion or a MarkerMotion, got {type(x).__name__}")
    names = (name or _name_of(value), *(compare_names or ()))
    meta, blobs = page_data(value, compare=others, names=tuple(str(n or "") for n in names))
    return b"".join(page_pieces(meta, blobs)).decode("utf-8")


def _name_of(value) -> str:
    return getattr(value, "name", "") or getattr(value, "source_name", "") or ""


# --------------------------------------------------------------------------- library


def batch(
    in_dir: str | os.PathLike,
    out_dir: str | os.PathLike,
    *,
    steps: Sequence[tuple[str, Mapping[str, Any]]] = (),
    steps_bvh: Sequence[tuple[str, Mapping[str, Any]]] | None = None,
    steps_c3d: Sequence[tuple[str, Mapping[str, Any]]] | None = None,
    extract_opts: Mapping[str, Any] | None = None,
    bake_opts: Mapping[str, Any] | None = None,
    jobs: int = 1,
    shard: str | tuple[int, int] | None = None,
    force: bool = False,
    dry_run: bool = False,
    verbose: bool = False,
    on_result: Callable[[BatchResult], None] | None = None,
) -> list[BatchResult]:
    """Extract, edit and bake every BVH and C3D under ``in_dir`` into the
    same tree under ``out_dir``, in ``jobs`` worker processes.

    Each file goes through ``bake(step_n(... step_1(extract(read(file)))))``
    and is written atomically.  An output newer than its input is skipped
    (unless ``force``); a file that fails leaves no output and the others go
    on.  Every step and option is checked once, before any file is read.

    Parameters
    ----------
    in_dir, out_dir : str or path-like
        ``out_dir`` must not lie inside ``in_dir``.
    steps : list of (str, dict)
        Calls between extract and bake, for every file: the name of a
        document -> document function of this module (``cull``,
        ``edit_pose``, ``succession``, ``randomize``, ``add_layer``,
        ``remove_layer``, ``detail``, ``constraints``) and its keywords,
        e.g. ``[("cull", {"keep": "30%"})]``.
    steps_bvh, steps_c3d : list of (str, dict), optional
        The steps for BVH files, or for C3D files, instead of ``steps``
        (a body part such as ``@left-arm`` names a skeleton's joint; C3D
        files have markers).
    extract_opts, bake_opts : dict, optional
        Keywords of :func:`extract` and :func:`bake` (``{"fps": 30}``).
    jobs : int
        Worker processes (a crash in one fails its file only).
    shard : str or (int, int), optional
        ``"I/N"``: only the I-th of N parts of the file list, split by a
        hash of each path, the same on every machine.
    force : bool
        Rebuild outputs that are up to date.
    dry_run : bool
        Check the steps and return what would be built (status ``todo``).
    verbose : bool
        Print what each stage did for each file on standard error, as files finish.
    on_result : callable, optional
        Called with each file's result as it finishes (in this process).

    Returns
    -------
    list of Result
        One per file, sorted by path: ``rel`` (the path under both
        folders), ``status`` (``built``; ``unchanged``: the output holds the
        input's bytes; ``skipped``: up to date; ``failed``), ``seconds``,
        ``reason`` (why it failed), ``messages`` (warnings) and ``stages``
        (one line per stage: what it did).

    Raises
    ------
    UsageError
        A bad step, option or folder, before any file is read.

    Examples
    --------
    >>> import shutil, tempfile
    >>> import staggered_cli as st
    >>> library = tempfile.mkdtemp()
    >>> _ = shutil.copy("data/samples/march.bvh", library)
    >>> results = st.batch(library, "out/doctest/batch", force=True,
    ...                    steps_bvh=[("cull", {"keep": "50%"}),
    ...                               ("succession", {"joint": "@left-arm", "offset": 0.03, "clamp": True})],
    ...                    bake_opts={"fps": 60})
    >>> [(r.rel, r.status) for r in results]
    [('march.bvh', 'built')]
    >>> results[0].stages[1].split(",")[0]
    'cull: 12 of 24 poses kept'
    >>> st.read("out/doctest/batch/march.bvh").n_frames
    241
    >>> st.batch(library, "out/doctest/batch", steps=[("cull", {"keep": "0"})])
    Traceback (most recent call last):
    ...
    staggered_cli.errors.UsageError: steps: step 1 ('cull'): keep must keep at least one pose, got '0'
    """
    import functools
    import sys

    from .batching import TODO, Plan, Result, check_call, check_steps, parse_shard, plan, run_batch

    part = None if shard is None else parse_shard(shard)
    if isinstance(steps, str) or isinstance(steps_bvh, str) or isinstance(steps_c3d, str):
        raise UsageError(f"{arg('steps')} are (name, kwargs) pairs, e.g. [('cull', {{'keep': '30%'}})], not a string")
    common = check_steps(steps, "steps")
    todo_plan = Plan(
        steps_bvh=common if steps_bvh is None else check_steps(steps_bvh, "steps_bvh"),
        steps_c3d=common if steps_c3d is None else check_steps(steps_c3d, "steps_c3d"),
        extract_opts=_checked_opts("extract", extract_opts, "extract_opts", check_call),
        bake_opts=_checked_opts("bake", bake_opts, "bake_opts", check_call),
    )
    workers = int(jobs)
    if workers < 1:
        raise UsageError(f"{arg('jobs')} must be at least 1, got {jobs}")
    todo, skipped = plan(os.fspath(in_dir), os.fspath(out_dir), force, shard=part)
    if dry_run:
        return sorted(skipped + [Result(job.rel, TODO) for job in todo], key=lambda r: r.rel)

    def report(result: Result) -> None:
        if verbose:
            for line in result.stages:
                print(f"{result.rel}: {line}", file=sys.stderr)
        if on_result is not None:
            on_result(result)

    from .batching import run as _run

    work = functools.partial(_run.run_file, plan=todo_plan)  # looked up now: tests wrap it to inject faults
    results = skipped + run_batch(todo, work, workers, on_result=report)
    return sorted(results, key=lambda r: r.rel)


def _checked_opts(name: str, opts: Mapping[str, Any] | None, what: str, check) -> dict[str, Any]:
    if opts is not None and not isinstance(opts, Mapping):
        raise UsageError(f"{arg(what)} must be a dict of {name}'s keywords, got {type(opts).__name__}")
    try:
        return check(name, opts)
    except UsageError as err:
        raise UsageError(f"{arg(what)}: {err.message}") from None


__all__ = [
    "read",
    "write",
    "extract",
    "cull",
    "edit_pose",
    "succession",
    "randomize",
    "add_layer",
    "remove_layer",
    "detail",
    "constraints",
    "new",
    "export_poses",
    "bake",
    "info",
    "plot",
    "preview",
    "view",
    "batch",
]
