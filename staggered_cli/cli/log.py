"""Messages on standard error: the ``staggered_cli`` logger and its setup.

Used by the command line and by the batch workers (which run the commands
in-process); library code only logs to ``logging.getLogger(__name__)``.
"""

from __future__ import annotations

import logging
import sys
import warnings

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


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """Print a :class:`~staggered_cli.errors.StaggeredWarning` as the command
    line says it (``staggered: WARNING: ...``, options named as options);
    other warnings as Python would."""
    from ..errors import StaggeredWarning, cli_text

    if isinstance(message, StaggeredWarning) or (isinstance(category, type) and issubclass(category, StaggeredWarning)):
        text = str(message.args[0]) if isinstance(message, Warning) and message.args else str(message)
        log.warning("%s", cli_text(text))
    else:
        _PYTHON_SHOW(message, category, filename, lineno, file, line)


_PYTHON_SHOW = warnings.showwarning


def configure_logging(verbose: int, quiet: int) -> None:
    """WARNING by default; each -v one level more (INFO, DEBUG), -q one less.

    The library's warnings (:class:`~staggered_cli.errors.StaggeredWarning`)
    are printed every time they are issued, as one log line each."""
    from ..errors import StaggeredWarning

    warnings.simplefilter("always", StaggeredWarning)
    warnings.showwarning = _show_warning
    level = min(max(logging.WARNING - 10 * verbose + 10 * quiet, logging.DEBUG), logging.CRITICAL)
    handler = _StderrHandler()
    handler.setFormatter(logging.Formatter(f"{PROG}: %(levelname)s: %(message)s"))
    log.handlers[:] = [handler]
    log.setLevel(level)
    log.propagate = False
