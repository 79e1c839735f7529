"""The ``staggered`` command group: global options, lazy subcommands and the
one error path.

Error path (the only place that turns exceptions into exit codes):

* :class:`~staggered_cli.errors.StaggeredError` -> ``staggered: <message>``
  on stderr, exit code ``err.exit_code`` (1 for data errors, 2 for usage);
* click's own usage errors -> click's message, exit 2;
* ``KeyboardInterrupt`` (Ctrl-C) -> one line, exit 130; SIGTERM is handled
  the same way (one line, exit 143 = 128 + SIGTERM): the write in progress
  removes its temporary file;
* a closed stdout pipe (``BrokenPipeError``) -> exit 141 (128 + SIGPIPE)
  without a message, as other Unix tools do, help text included;
* standard output closed (``>&-``) -> one line, exit 1, when a command
  writes to it;
* anything else is a bug: a one-line ``internal error`` message, exit 1.

``--debug`` lets the exception through so that Python prints the traceback.

Subcommands are imported only when used (``COMMANDS`` maps a name to
``"module:function"``), so ``staggered --help`` and shell completion do not
import NumPy, SciPy or Matplotlib.  Completion uses click's mechanism::

    eval "$(_STAGGERED_COMPLETE=bash_source staggered)"   # bash
    eval "$(_STAGGERED_COMPLETE=zsh_source staggered)"    # zsh
"""

from __future__ import annotations

import importlib
import io
import os
import sys

import click

from .. import __version__
from ..errors import StaggeredError
from .heap import reuse_freed_memory
from .log import PROG, configure_logging
from .options import INPUT_KEY

#: command name -> "module:attribute" of its click command.
COMMANDS: dict[str, str] = {
    "info": "staggered_cli.cli.info:info",
    "extract": "staggered_cli.cli.extract:extract",
    "cull": "staggered_cli.cli.cull:cull",
    "constraints": "staggered_cli.cli.constraints:constraints",
    "edit-pose": "staggered_cli.cli.edit_pose:edit_pose",
    "layer": "staggered_cli.cli.layer:layer",
    "detail": "staggered_cli.cli.detail:detail",
    "succession": "staggered_cli.cli.succession:succession",
    "randomize": "staggered_cli.cli.randomize:randomize",
    "bake": "staggered_cli.cli.bake:bake",
    "export-poses": "staggered_cli.cli.export_poses:export_poses",
    "new": "staggered_cli.cli.new:new",
    "plot": "staggered_cli.cli.plot:plot",
    "preview": "staggered_cli.cli.preview:preview",
    "view": "staggered_cli.cli.view:view",
    "batch": "staggered_cli.cli.batch:batch",
}

EXIT_INTERRUPTED = 130
EXIT_TERMINATED = 143
EXIT_BROKEN_PIPE = 141


class LazyGroup(click.Group):
    """A group whose subcommands are imported on first use."""

    def __init__(self, *args, lazy_commands: dict[str, str] | None = None, **kwargs):
        super().__init__(*args, **kwargs)
        self.lazy_commands = dict(lazy_commands or {})

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted(set(super().list_commands(ctx)) | set(self.lazy_commands))

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        if cmd_name in self.lazy_commands:
            module_name, attr = self.lazy_commands[cmd_name].split(":")
            command = getattr(importlib.import_module(module_name), attr)
            if not isinstance(command, click.Command):
                raise TypeError(f"{self.lazy_commands[cmd_name]} is not a click command")
            return command
        return super().get_command(ctx, cmd_name)


def _one_line(text: str) -> str:
    return " ".join(line.strip() for line in str(text).splitlines() if line.strip())


def _silence_stdout() -> None:
    """Point stdout at /dev/null so the interpreter's final flush into the
    closed pipe does not print 'Exception ignored ... BrokenPipeError'."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError, AttributeError):
        pass  # stdout is not a real file (tests): nothing will be flushed into a pipe


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised where the program is, so that it unwinds like Ctrl-C."""


def _on_sigterm(signum, frame) -> None:
    raise Terminated


def _handle_sigterm() -> None:
    import signal
    import threading

    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, _on_sigterm)


class StdoutClosed(StaggeredError):
    """Writing to a standard output that the shell closed."""


class _ClosedStdout(io.TextIOBase):
    """Standard output when the shell closed it (``>&-``): writing is an error."""

    def writable(self) -> bool:
        return True

    def write(self, text: str) -> int:
        raise StdoutClosed("standard output is closed: nothing can be written to it", source="<stdout>")


def _interrupted(err: KeyboardInterrupt) -> int:
    if isinstance(err, Terminated):
        click.echo(f"{PROG}: terminated", err=True)
        return EXIT_TERMINATED
    click.echo(f"\n{PROG}: interrupted", err=True)
    return EXIT_INTERRUPTED


class StaggeredGroup(LazyGroup):
    """The root group: maps every exception to a message and an exit code."""

    def main(self, args=None, prog_name=None, complete_var=None, standalone_mode=True, **extra):
        """Like click's, but click's own usage errors are one line too."""
        if not standalone_mode:
            return super().main(args, prog_name, complete_var, standalone_mode=False, **extra)
        _handle_sigterm()
        if sys.stdout is None:
            sys.stdout = _ClosedStdout()
        try:
            rv = super().main(args, prog_name, complete_var, standalone_mode=False, **extra)
        except click.exceptions.NoArgsIsHelpError as err:
            click.echo(err.ctx.get_help() if err.ctx is not None else err.format_message())
            sys.exit(0)
        except click.exceptions.UsageError as err:
            where = (err.ctx.command_path if err.ctx is not None else "").split(" ", 1)[1:]
            prefix = f"{PROG}: {where[0]}" if where else PROG
            click.echo(f"{prefix}: {_one_line(err.format_message())} (see --help)", err=True)
            sys.exit(err.exit_code)
        except click.exceptions.ClickException as err:
            click.echo(f"{PROG}: {_one_line(err.format_message())}", err=True)
            sys.exit(err.exit_code)
        except click.exceptions.Abort:
            click.echo(f"{PROG}: aborted", err=True)
            sys.exit(1)
        except KeyboardInterrupt as err:  # before or after a command ran
            sys.exit(_interrupted(err))
        except StdoutClosed as err:  # while writing help
            click.echo(f"{PROG}: {_one_line(err.cli_message())}", err=True)
            sys.exit(err.exit_code)
        sys.exit(rv if isinstance(rv, int) else 0)

    def make_context(self, info_name, args, parent=None, **extra):
        # --help and --version print while the arguments are parsed: click
        # would turn a closed pipe there into exit 1
        try:
            return super().make_context(info_name, args, parent, **extra)
        except BrokenPipeError:
            _silence_stdout()
            sys.exit(EXIT_BROKEN_PIPE)

    def invoke(self, ctx: click.Context):
        debug = bool(ctx.params.get("debug"))
        try:
            result = super().invoke(ctx)
            if sys.stdout is not None:
                sys.stdout.flush()  # a closed pipe shows up here, not at exit
            return result
        except (click.exceptions.ClickException, click.exceptions.Exit, click.exceptions.Abort):
            raise
        except StaggeredError as err:
            if debug:
                raise
            if err.source is None and ctx.meta.get(INPUT_KEY) is not None:
                from ..io.files import display_name

                err.with_source(display_name(ctx.meta[INPUT_KEY]))  # the file the problem is about
            click.echo(f"{PROG}: {_one_line(err.cli_message())}", err=True)
            ctx.exit(err.exit_code)
        except KeyboardInterrupt as err:
            ctx.exit(_interrupted(err))
        except BrokenPipeError:
            _silence_stdout()
            ctx.exit(EXIT_BROKEN_PIPE)
        except Exception as err:
            if debug:
                raise
            click.echo(
                f"{PROG}: internal error: {type(err).__name__}: {_one_line(str(err))} "
                "(run with --debug for the traceback)",
                err=True,
            )
            ctx.exit(1)


@click.group(
    cls=StaggeredGroup,
    lazy_commands=COMMANDS,
    context_settings={"help_option_names": ["-h", "--help"]},
)
@click.version_option(__version__, "--version", prog_name=PROG, message="%(prog)s %(version)s")
@click.option("-v", "--verbose", count=True, help="More messages on stderr (repeat for debug output).")
@click.option("-q", "--quiet", count=True, help="Fewer messages on stderr: errors only.")
@click.option("--debug", is_flag=True, help="Show the Python traceback of an error.")
@click.pass_context
def cli(ctx: click.Context, verbose: int, quiet: int, debug: bool) -> None:
    """Editable staggered poses from dense motion capture (BVH, C3D).

    FILE arguments accept '-' for standard input and '-o -' writes to
    standard output. Exit codes: 0 success, 1 bad data, 2 bad usage.
    """
    configure_logging(verbose, quiet)
    reuse_freed_memory()
    ctx.ensure_object(dict)
    ctx.obj["debug"] = debug


def main() -> None:
    """Entry point of ``python -m staggered_cli``."""
    cli(prog_name=PROG)
