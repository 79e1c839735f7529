"""How the user names joints and markers: the one resolver every option uses.

A name given on the command line (``--joint``, ``--joints``, ``--chain``,
``--rotate J=...``, ``--contact-joints``, ``constraints --add J@A:B``, plot
rows) is resolved against the clip's own names by :func:`resolve`:

1. the exact name;
2. the name after a subject or namespace prefix, when exactly one name has
   it: ``LSHO`` is ``Male:LSHO`` in a CMU C3D, ``LeftArm`` is
   ``mixamorig:LeftArm`` in a Mixamo BVH;
3. a body part, ``@left-arm``, ``@right-arm``, ``@left-leg``, ``@right-leg``,
   ``@spine`` or ``@head`` (BVH only): the root joint of that part in this
   skeleton, found from the common naming schemes (CMU cgspeed and 3dsMax,
   Bandai Namco, GAMES-105, Mixamo, Xsens, SMPL and PyMO/GENEA-style
   ``b_l_shoulder``) and the hierarchy: the part's joint nearest the root.
   ``@left-arm`` is the left clavicle or shoulder (``LeftShoulder``,
   ``LeftCollar``, ``Shoulder_L``, ``lTorso_Clavicle``), ``@left-leg`` the
   first joint of the left leg (``LHipJoint``, ``UpperLeg_L``, ``lHip``),
   ``@spine`` the lowest spine joint, ``@head`` the base of the neck.

Anything else is a :class:`~staggered_cli.errors.UsageError` of one line
that suggests the closest names: those of the same side and body segment
(``LeftArm`` -> ``UpperArm_L`` on a Bandai Namco skeleton), else by spelling
(:mod:`difflib`).
"""

from __future__ import annotations

import difflib
import functools
import re
from collections.abc import Sequence

import numpy as np

from .errors import UsageError

#: The body parts ``@part`` may name.
PARTS = ("left-arm", "right-arm", "left-leg", "right-leg", "spine", "head")

_ARM = {"shoulder", "clavicle", "collar", "arm", "uparm", "upperarm", "forearm", "lowerarm", "elbow", "wrist", "hand"}
_LEG = {"hip", "upleg", "upperleg", "thigh", "leg", "knee", "lowerleg", "shin", "calf", "ankle", "foot", "toe", "toes"}
_HEAD = {"neck", "lowerneck", "upperneck", "head"}
_SPINE = {"spine", "back", "lowerback", "upperback", "chest", "torso", "abdomen", "waist"}
_XSENS_SPINE = {"l5", "l3", "t12", "t8"}  # Xsens vertebrae (``L5`` is not a left joint)
_WORDS = _ARM | _LEG | _HEAD | _SPINE

#: Names a part usually has, to rank the closest joints when none matches.
_EXAMPLES = {
    "arm": ("{S}Shoulder", "{S}Clavicle", "{S}Collar", "{S}UpperArm", "{S}Arm"),
    "leg": ("{S}UpLeg", "{S}UpperLeg", "{S}Hip", "{S}Thigh", "{S}Leg"),
    "spine": ("Spine", "LowerBack", "Chest", "Torso"),
    "head": ("Neck", "Head"),
}


def base_name(name: str) -> str:
    """``name`` without its subject or namespace prefix (``Male:LSHO`` -> ``LSHO``)."""
    return name.rpartition(":")[2]


def tokens(name: str) -> list[str]:
    """Lower-case words of a joint name: ``lTorso_Clavicle`` -> ``['l', 'torso',
    'clavicle']``, ``LHipJoint`` -> ``['l', 'hip', 'joint']``, ``lhand`` ->
    ``['l', 'hand']``."""
    return list(_tokens(name))


@functools.lru_cache(maxsize=4096)
def _tokens(name: str) -> tuple[str, ...]:
    """:func:`tokens`, kept: a body part is resolved for every partial pose
    an operation meets, each time over every joint name (extract --partial
    tries dozens)."""
    s = re.sub(r"([a-z0-9])([A-Z])", r"\1 \2", base_name(name))
    s = re.sub(r"([A-Z]+)([A-Z][a-z])", r"\1 \2", s)
    s = re.sub(r"([A-Za-z])(\d)|(\d)([A-Za-z])", lambda m: " ".join(g for g in m.groups() if g), s)
    out: list[str] = []
    for t in re.split(r"[^a-z0-9]+", s.lower()):
        if t and t not in _WORDS and t[0] in "lr" and t[1:] in _WORDS:
            out += [t[0], t[1:]]  # 3dsMax ``lhand``
        elif t and t not in _WORDS and _side_word(t):
            out += [_side_word(t), t[len(_side_word(t)) :]]  # ``leftelbow``
        elif t:
            out.append(t)
    return tuple(out)


def _side_word(t: str) -> str:
    """``'left'`` or ``'right'`` when ``t`` is one of them glued to a body word."""
    for word in ("left", "right"):
        if t.startswith(word) and t[len(word) :] in _WORDS:
            return word
    return ""


def side(name: str) -> str:
    """``'left'``, ``'right'`` or ``''`` as the name says."""
    if base_name(name).lower() in _XSENS_SPINE:
        return ""
    toks = set(tokens(name))
    left, right = bool(toks & {"left", "l"}), bool(toks & {"right", "r"})
    return "left" if left and not right else "right" if right and not left else ""


def _is_part(name: str, part: str) -> bool:
    toks = set(tokens(name))
    if part in ("spine", "head"):
        if side(name):
            return False
        if part == "spine":
            return bool(toks & _SPINE) or base_name(name).lower() in _XSENS_SPINE
        return bool(toks & _HEAD)
    where, limb = part.split("-")
    return side(name) == where and bool(toks & (_ARM if limb == "arm" else _LEG))


def _depths(parents: np.ndarray) -> np.ndarray:
    depth = np.zeros(len(parents), dtype=int)
    for j, p in enumerate(parents):  # parents come before children
        depth[j] = depth[p] + 1 if p >= 0 else 0
    return depth


def body_part(part: str, names: Sequence[str], parents: np.ndarray) -> int:
    """Index of the root joint of body part ``part`` (one of :data:`PARTS`).

    The part's joints are those whose names say so (side and limb words);
    its root is the one nearest the skeleton's root, the other joints of the
    part lying below it.  ``UsageError`` (one line naming the closest
    joints) when the skeleton has no such joints.
    """
    if part not in PARTS:
        raise UsageError(f"unknown body part @{part} (parts: {', '.join('@' + p for p in PARTS)})")
    parents = np.asarray(parents, dtype=int)
    found = [j for j, n in enumerate(names) if parents[j] >= 0 and _is_part(n, part)]
    if not found:
        raise UsageError(f"no joint of this skeleton is @{part} (closest: {', '.join(_closest_to_part(part, names))})")
    depth = _depths(parents)
    top = min(depth[j] for j in found)
    roots = [j for j in found if depth[j] == top]
    if len(roots) > 1:  # siblings: the one with most of the part below it
        below = [sum(_is_ancestor(parents, r, j) for j in found) for r in roots]
        roots = [roots[int(np.argmax(below))]]
    return int(roots[0])


def _is_ancestor(parents: np.ndarray, a: int, j: int) -> bool:
    while j >= 0:
        if j == a:
            return True
        j = int(parents[j])
    return False


def _closest_to_part(part: str, names: Sequence[str], n: int = 3) -> list[str]:
    where, _, limb = part.rpartition("-")
    examples = [e.format(S=where.capitalize()) for e in _EXAMPLES[limb]]

    def score(nm: str) -> float:
        return max(difflib.SequenceMatcher(None, e.lower(), base_name(nm).lower()).ratio() for e in examples)

    return sorted(names, key=lambda nm: -score(nm))[:n]


def resolve(name: str, names: Sequence[str], parents: np.ndarray | None = None, *, what: str = "joint") -> int:
    """Index in ``names`` of the joint or marker the user calls ``name``.

    Parameters
    ----------
    name : an exact name, a name without its subject prefix, or a body part
        ``@left-arm`` (see the module docstring).
    names : (N,) the clip's joint names or marker labels.
    parents : (N,) parent indices of a skeleton (-1 at the root); None for
        markers, which have no body parts.
    what : ``'joint'`` or ``'marker'``, for the message.
    """
    names = list(names)
    if name in names:
        count = names.count(name)
        if count > 1:  # a C3D may repeat a label: editing "the first one" would leave the others alone
            raise UsageError(f"{what} label {name!r} is ambiguous: {count} {what}s share it")
        return names.index(name)
    if name.startswith("@"):
        if parents is None:
            raise UsageError(f"body part {name!r} needs a BVH skeleton; name the {what}s of this file")
        return body_part(name[1:].strip().lower(), names, parents)
    same = [j for j, n in enumerate(names) if base_name(n) == name]
    if len(same) == 1:
        return same[0]
    if len(same) > 1:
        raise UsageError(f"{what} {name!r} is ambiguous: {', '.join(names[j] for j in same[:4])}")
    raise UsageError(unknown_message(name, names, what))


def resolve_name(name: str, names: Sequence[str], parents: np.ndarray | None = None, *, what: str = "joint") -> str:
    """The clip's own name for ``name`` (see :func:`resolve`)."""
    return list(names)[resolve(name, names, parents, what=what)]


#: Body segments a joint name may say, by its words: a joint is named for the
#: bone it moves (CMU ``LeftArm``, Bandai ``UpperArm_L``) or for where it
#: sits (3dsMax ``LeftShoulder``, GAMES-105 ``lElbow``), so some words say two.
_SEGMENT_WORDS = {
    "clavicle": {"clavicle"}, "collar": {"clavicle"}, "shoulder": {"clavicle", "upperarm"},
    "arm": {"upperarm"}, "uparm": {"upperarm"}, "upperarm": {"upperarm"},
    "forearm": {"forearm"}, "lowarm": {"forearm"}, "lowerarm": {"forearm"}, "elbow": {"forearm"},
    "hand": {"hand"}, "wrist": {"hand"},
    "finger": {"finger"}, "fingers": {"finger"}, "fingerbase": {"finger"}, "thumb": {"finger"}, "index": {"finger"},
    "hip": {"thigh"}, "upleg": {"thigh"}, "upperleg": {"thigh"}, "thigh": {"thigh"},
    "leg": {"shin"}, "lowleg": {"shin"}, "lowerleg": {"shin"}, "shin": {"shin"}, "calf": {"shin"}, "knee": {"shin"},
    "foot": {"foot"}, "ankle": {"foot"}, "toe": {"toe"}, "toes": {"toe"}, "toebase": {"toe"},
    "spine": {"spine"}, "back": {"spine"}, "lowerback": {"spine"}, "upperback": {"spine"}, "chest": {"spine"},
    "torso": {"spine"}, "abdomen": {"spine"}, "waist": {"spine"}, "neck": {"neck"}, "head": {"head"},
}
#: When a name says several segments, the one furthest out along its limb wins
#: (``LeftHandIndex1`` is a finger, ``lTorso_Clavicle`` a clavicle).
_SEGMENT_ORDER = ("finger", "toe", "hand", "foot", "forearm", "upperarm", "clavicle", "shin", "thigh", "head", "neck")
_NEIGHBOURS = {
    frozenset(p)
    for p in (
        ("clavicle", "upperarm"), ("upperarm", "forearm"), ("forearm", "hand"), ("hand", "finger"),
        ("thigh", "shin"), ("shin", "foot"), ("foot", "toe"), ("spine", "neck"), ("neck", "head"),
    )
}
_COMPOUND = {"up", "upper", "low", "lower", "fore"}


def segments(name: str) -> frozenset[str]:
    """The body segments (``'upperarm'``, ``'shin'``, ...) a joint name says:
    ``LeftArm`` and ``UpperArm_L`` -> ``{'upperarm'}``, ``LeftShoulder`` ->
    ``{'clavicle', 'upperarm'}``, ``Root`` -> ``{}``."""
    toks = tokens(name)
    words = []
    for i, t in enumerate(toks):
        if t in _COMPOUND and i + 1 < len(toks) and toks[i + 1] in ("arm", "leg"):
            continue
        if t in ("arm", "leg", "base") and i and toks[i - 1] in _COMPOUND | {"toe", "finger"}:
            t = toks[i - 1] + t
        words.append(t)
    found: set[str] = set()
    for w in words:
        found |= _SEGMENT_WORDS.get(w, set())
    for seg in _SEGMENT_ORDER:  # the segment furthest out, with what its word also says
        for w in words:
            if seg in _SEGMENT_WORDS.get(w, ()):
                return frozenset(_SEGMENT_WORDS[w])
    return frozenset(found)


def _by_meaning(name: str, names: Sequence[str], n: int = 3) -> list[str]:
    """The names of the same side and body segment as ``name`` (then of a
    neighbouring segment), closest spelling first; [] when ``name`` says no segment."""
    want = segments(name)
    if not want:
        return []
    where = side(name)
    scored = []
    for other in dict.fromkeys(names):
        if where and side(other) != where:
            continue
        have = segments(other)
        if have == want:
            score = 3
        elif have & want:
            score = 2
        elif any(frozenset((a, b)) in _NEIGHBOURS for a in want for b in have):
            score = 1
        else:
            continue
        spelling = difflib.SequenceMatcher(None, name.lower(), base_name(other).lower()).ratio()
        scored.append((-score, -spelling, other))
    return [other for *_, other in sorted(scored)[:n]]


def unknown_message(name: str, names: Sequence[str], what: str = "joint") -> str:
    """``unknown joint 'LeftArmm' (did you mean: LeftArm, LeftForeArm?)``, or a
    few of the names when none is close.

    Names of the same side and body segment come first (``LeftArm`` on a
    Bandai Namco skeleton suggests ``UpperArm_L``), then close spellings.
    """
    near = _by_meaning(name, names) if what == "joint" else []
    if not near:
        lower = {}
        for n in names:
            lower.setdefault(n.lower(), n)
            lower.setdefault(base_name(n).lower(), n)
        close = difflib.get_close_matches(name.lower(), list(lower), n=6, cutoff=0.6)
        near = list(dict.fromkeys(lower[c] for c in close))[:3]
    if near:
        return f"unknown {what} {name!r} (did you mean: {', '.join(near)}?)"
    shown = ", ".join(list(names)[:8]) + (", ..." if len(names) > 8 else "")
    return f"unknown {what} {name!r} ({what}s: {shown})"
