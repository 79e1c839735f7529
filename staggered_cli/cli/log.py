"""Messages on standard error: the ``staggered_cli`` logger and its setup.

Used by the command line and by the batch workers (which run the commands
in-process); library code only logs to ``logging.getLogger(__name__)``.
"""

from __future__ import annotations

import logging
import sys

#: The program's name, as messages start.
PROG = "staggered"

log = logging.getLogger("staggered_cli")


class _StderrHandler(logging.Handler):
    """Logs to whatever ``sys.stderr`` is at the time of the call (so that
    CliRunner's captured stream is used in tests)."""

    def emit(self, record: logging.LogRecord) -> None:
        try:
            sys.stderr.write(self.format(record) + "\n")
        except Exception:  # logging must never take the command down
            self.handleError(record)


def configure_logging(verbose: int, quiet: int) -> None:
    """WARNING by default; each -v one level more (INFO, DEBUG), -q one less."""
    level = min(max(logging.WARNING - 10 * verbose + 10 * quiet, logging.DEBUG), logging.CRITICAL)
    handler = _StderrHandler()
    handler.setFormatter(logging.Formatter(f"{PROG}: %(levelname)s: %(message)s"))
    log.handlers[:] = [handler]
    log.setLevel(level)
    log.propagate = False
