"""The steps of a batch: calls of the public API, checked before any file.

A step is ``(name, kwargs)``: the name of a function of
:mod:`staggered_cli.api` that turns a document into a document
(:data:`STEP_FUNCTIONS`) and its keyword arguments, e.g. ``("cull",
{"keep": "30%"})``.  Steps are plain values, so that they travel to the
worker processes.

:func:`check_call` checks a call's values once, before any file is read:
it runs the function on *nothing*, a stand-in document (or clip) that stops
the call the moment the function reads it.  Everything the function checks
before it looks at the document (``keep`` a count or a share, ``power``
positive, the options of extract and bake) is checked as the real call
would; a value that depends on the document (a joint's name, a pose index)
is checked on each file.
"""

from __future__ import annotations

import inspect
from collections.abc import Iterable, Mapping
from typing import Any

from ..errors import StaggeredError, UsageError, arg

#: (API function name, keyword arguments).
Step = tuple[str, dict[str, Any]]

#: API functions that turn a document into a document: the possible steps.
STEP_FUNCTIONS = (
    "cull",
    "edit_pose",
    "succession",
    "randomize",
    "add_layer",
    "remove_layer",
    "detail",
    "constraints",
)


class _Reached(BaseException):
    """The call read the stand-in: its values passed every check made before.
    (A BaseException, so that no ``except Exception`` on the way swallows it.)"""


def _touch(self, name):
    raise _Reached


def _nothing(cls):
    """An instance of a subclass of ``cls`` that stops any call reading it."""
    stand_in = type(f"Nothing{cls.__name__}", (cls,), {"__getattribute__": _touch, "__repr__": lambda s: "nothing"})
    return object.__new__(stand_in)


def _stand_in(name: str):
    if name == "extract":
        from ..motion import BvhMotion

        return _nothing(BvhMotion)
    from ..model.document import Document

    return _nothing(Document)


def check_call(name: str, kwargs: Mapping[str, Any] | None) -> dict[str, Any]:
    """Check ``api.<name>(x, **kwargs)`` without a document or clip ``x``.

    Returns ``kwargs`` as a dict.  Raises ``UsageError`` (the function's own
    message, naming the argument) for a keyword the function does not take
    or a value it refuses before it reads ``x``.
    """
    from .. import api

    kwargs = dict(kwargs or {})
    function = getattr(api, name)
    params = list(inspect.signature(function).parameters)[1:]
    unknown = [k for k in kwargs if k not in params]
    if unknown:
        raise UsageError(f"{name} takes no argument {unknown[0]!r} (it takes {', '.join(params)})")
    try:
        function(_stand_in(name), **kwargs)
    except _Reached:
        pass
    except StaggeredError as err:
        raise UsageError(err.message) from None
    except (TypeError, ValueError) as err:
        raise UsageError(f"{name}: {err}") from None
    return kwargs


def check_steps(steps: Iterable[Step] | None, what: str = "steps") -> tuple[Step, ...]:
    """``steps`` as a tuple of ``(name, kwargs)``, each checked by :func:`check_call`.

    Raises ``UsageError`` naming the argument ``what`` and the step (from 1).
    """
    out: list[Step] = []
    for i, item in enumerate(steps or (), start=1):
        try:
            name, kwargs = item
        except (TypeError, ValueError):
            raise UsageError(f"{arg(what)}: step {i} must be a pair (name, kwargs), got {item!r}") from None
        if name not in STEP_FUNCTIONS:
            why = "extract and bake are implied" if name in ("extract", "bake") else "not a document step"
            raise UsageError(f"{arg(what)}: step {i} ({name!r}): {why} (steps: {', '.join(STEP_FUNCTIONS)})")
        if not isinstance(kwargs, Mapping):
            raise UsageError(f"{arg(what)}: step {i} ({name!r}): kwargs must be a dict, got {type(kwargs).__name__}")
        try:
            out.append((name, check_call(name, kwargs)))
        except UsageError as err:
            raise UsageError(f"{arg(what)}: step {i} ({name!r}): {err.message}") from None
    return tuple(out)
