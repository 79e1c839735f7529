"""Errors the command line turns into one-line messages.

No click import here: library code raises these, ``cli`` maps them to exit
codes (``UsageError`` -> 2, every other ``StaggeredError`` -> 1).
"""

from __future__ import annotations


class StaggeredError(Exception):
    """Base class: a problem with the user's data or request, not a bug.

    ``source`` names the file (or ``<stdin>``) the problem is in, when known;
    the message then reads ``source: message``.
    """

    exit_code = 1

    def __init__(self, message: str, source: str | None = None):
        super().__init__(message)
        self.message = message
        self.source = source

    def __str__(self) -> str:
        return f"{self.source}: {self.message}" if self.source else self.message

    def with_source(self, source: str) -> StaggeredError:
        """The same error attributed to ``source`` (kept if already set)."""
        if self.source is None:
            self.source = source
        return self


class DataError(StaggeredError):
    """A malformed, truncated or inconsistent input file or document."""


class UsageError(StaggeredError):
    """A bad option value or a request that cannot apply (unknown joint, pose out of range)."""

    exit_code = 2


class KnotOrderError(UsageError):
    """An edit would make knots cross (SPEC invariant 3)."""
