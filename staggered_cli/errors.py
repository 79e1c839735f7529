"""Errors and warnings of the library, and how a message names an argument.

No click import here: library code raises these, ``cli`` maps them to exit
codes (``UsageError`` -> 2, every other ``StaggeredError`` -> 1) and prints
warnings as one line each.

A message names an argument through :func:`arg`: the library shows the
Python keyword (``keep must be ...``), the command line the option
(``--keep must be ...``), from the same message.
"""

from __future__ import annotations

import re
import warnings

#: Marks an argument's name inside a message (ASCII unit separator).
_MARK = "\x1f"
_MARKED = re.compile(_MARK + "([^" + _MARK + "]*)" + _MARK)


def arg(name: str, option: str | None = None) -> str:
    """An argument's name as a message says it.

    Parameters
    ----------
    name : str
        The Python keyword (``"min_spacing"``).
    option : str, optional
        The command-line option when it is not ``--`` and the keyword with
        dashes (``"--from-bvh"`` for ``from_bvh`` is found by itself).

    Examples
    --------
    >>> from staggered_cli.errors import arg, python_text, cli_text
    >>> message = f"{arg('min_spacing')} must be positive"
    >>> python_text(message), cli_text(message)
    ('min_spacing must be positive', '--min-spacing must be positive')
    """
    return f"{_MARK}{name}{'|' + option if option else ''}{_MARK}"


def python_text(message: str) -> str:
    """``message`` with its marked arguments named as Python keywords."""
    return _MARKED.sub(lambda m: m.group(1).split("|")[0], message)


def cli_text(message: str) -> str:
    """``message`` with its marked arguments named as command-line options."""

    def option(m: re.Match) -> str:
        name, _, given = m.group(1).partition("|")
        return given or "--" + name.replace("_", "-")

    return _MARKED.sub(option, message)


class StaggeredError(Exception):
    """Base class: a problem with the user's data or request, not a bug.

    ``source`` names the file (or ``<stdin>``) the problem is in, when known;
    the message then reads ``source: message``.  ``str(err)`` names
    arguments as Python keywords; :meth:`cli_message` as options.

    Examples
    --------
    >>> import staggered_cli as st
    >>> try:
    ...     st.read(b"not motion capture")
    ... except st.StaggeredError as err:
    ...     print(err)
    <bytes>: not a BVH, C3D or staggered-poses document (unrecognized content)
    """

    exit_code = 1

    def __init__(self, message: str, source: str | None = None):
        super().__init__(message)
        self.message = message
        self.source = source

    def __str__(self) -> str:
        text = python_text(self.message)
        return f"{self.source}: {text}" if self.source else text

    def cli_message(self) -> str:
        """The message as the command line prints it (options, not keywords)."""
        text = cli_text(self.message)
        return f"{self.source}: {text}" if self.source else text

    def with_source(self, source: str) -> StaggeredError:
        """The same error attributed to ``source`` (kept if already set)."""
        if self.source is None:
            self.source = source
        return self


class DataError(StaggeredError):
    """A malformed, truncated or inconsistent input file or document (exit 1)."""


class UsageError(StaggeredError):
    """A bad argument or a request that cannot apply: an unknown joint, a pose
    out of range, a value out of bounds (exit 2)."""

    exit_code = 2


class KnotOrderError(UsageError):
    """An edit would make knots cross (SPEC invariant 3)."""


class StaggeredWarning(UserWarning):
    """An edit or a reading that could not be done exactly as asked: a
    contact the legs cannot reach, a pose the contact layer overrides, a
    succession with nothing to retime.  ``str(w)`` names arguments as
    Python keywords; the command line prints :func:`cli_text` of
    ``w.args[0]`` as ``staggered: WARNING: ...``.

    Examples
    --------
    Turn the library's warnings into errors:

    >>> import warnings
    >>> import staggered_cli as st
    >>> with warnings.catch_warnings():
    ...     warnings.simplefilter("error", st.StaggeredWarning)
    ...     doc = st.extract(st.read("data/samples/march.bvh"))
    >>> doc.n_poses > 2
    True
    """

    def __str__(self) -> str:
        return python_text(str(self.args[0])) if self.args else ""


def warn(message: str, *args: object, stacklevel: int = 2) -> None:
    """Issue a :class:`StaggeredWarning`; ``args`` are %-formatted into
    ``message`` as :mod:`logging` does."""
    if args:
        message = message % args
    warnings.warn(StaggeredWarning(message), stacklevel=stacklevel + 1)
