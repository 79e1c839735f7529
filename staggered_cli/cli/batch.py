"""``staggered batch``: extract -> steps -> bake over a whole mocap library.

The options are parsed here, each step with its own command's grammar
(the click command's ``make_context``: its options, types and messages),
and translated into API calls ``(name, kwargs)`` by :data:`TO_API`; then
:func:`staggered_cli.api.batch` runs them.  Every step, ``--extract-opts``
and ``--bake-opts`` is checked once, before any file is read.
"""

from __future__ import annotations

import os
import shlex
import sys

import click

from ..errors import StaggeredError, UsageError, cli_text
from .common import finite, int_list, name_list, time_range, triples
from .main import COMMANDS, PROG

#: Commands that read a document and write a document: the possible steps.
STEP_COMMANDS = ("cull", "edit-pose", "succession", "randomize", "layer", "detail")


def _optional(value, what: str):
    return None if value is None else finite(value, what)


def _cull(p: dict) -> tuple[str, dict]:
    return "cull", {
        "keep": p["keep"],
        "interval": time_range(p["interval"], "--interval"),
        "select": int_list(p["select"], "--select"),
        "add_time": [finite(t, "--add-time") for t in p["add_times"]],
        "part": p["part"],
        "by": p["by"],
        "ignore_contacts": p["ignore_contacts"],
    }


def _succession(p: dict) -> tuple[str, dict]:
    return "succession", {
        "offset": finite(p["offset"], "--offset"),
        "power": finite(p["power"], "--power"),
        "joint": p["joint"],
        "chain": name_list(p["chain"]),
        "poses": int_list(p["poses"], "--poses"),
        "time": time_range(p["time"], "--time"),
        "clamp": p["clamp"],
    }


def _randomize(p: dict) -> tuple[str, dict]:
    return "randomize", {
        "tau": finite(p["tau"], "--tau"),
        "seed": p["seed"],
        "joints": name_list(p["joints"]),
        "subtree": p["subtree"],
        "poses": int_list(p["poses"], "--poses"),
        "time": time_range(p["time"], "--time"),
        "clamp": p["clamp"],
    }


def _detail(p: dict) -> tuple[str, dict]:
    return "detail", {
        "gain": finite(p["gain"], "--gain"),
        "joints": name_list(p["joints"]),
        "subtree": p["subtree"],
        "time": time_range(p["time"], "--time"),
    }


def _layer(p: dict) -> tuple[str, dict]:
    if p["list_"]:
        raise click.UsageError("'layer --list' does not turn a document into a document")
    if p["add"] == (p["remove"] is not None):
        raise click.UsageError("give one of --add or --remove")
    if p["remove"] is not None:
        if p["keep"] is not None or p["times"] is not None:
            raise click.UsageError("--keep and --times go with --add")
        return "remove_layer", {"layer": p["remove"]}
    if p["times"] is not None:
        values = [v.strip() for v in p["times"].split(",") if v.strip()]
        return "add_layer", {"keep": p["keep"], "times": [finite(v, "--times") for v in values]}
    return "add_layer", {"keep": p["keep"]}


def _edit_pose(p: dict) -> tuple[str, dict]:
    return "edit_pose", {
        "pose": p["pose"],
        "layer": p["layer"],
        "on": p["on"],
        "rotate": triples(p["rotate"], "--rotate"),
        "translate": triples(p["translate"], "--translate"),
        "exaggerate": _optional(p["exaggerate"], "--exaggerate"),
        "relative_to": p["relative_to"],
        "ease": _optional(p["ease"], "--ease"),
        "joints": name_list(p["joints"]),
        "subtree": p["subtree"],
        "from_bvh": p["from_bvh"],
        "frame": p["frame"],
        "root": p["root"],
        "all": p["all_poses"],
        "time": _optional(p["new_time"], "--time"),
        "shift": _optional(p["shift"], "--shift"),
    }


def _extract(p: dict) -> tuple[str, dict]:
    from .extract import _names

    keys = ("smoothing", "filter_width", "refine_window", "min_contact", "contact_tolerance", "significance")
    return "extract", {
        "contact_joints": _names(p["contact_joints"]),
        **{k: p[k] for k in keys},
        "min_spacing": p["min_spacing"],
    }


def _bake(p: dict) -> tuple[str, dict]:
    return "bake", {
        "fps": _optional(p["fps"], "--fps"),
        "layers": p["layers"],
        "ik": not p["no_ik"],
        "ik_blend": finite(p["ik_blend"], "--ik-blend"),
    }


#: Command name -> the API call its parsed options (``ctx.params``) make.
TO_API = {
    "cull": _cull,
    "edit-pose": _edit_pose,
    "succession": _succession,
    "randomize": _randomize,
    "layer": _layer,
    "detail": _detail,
    "extract": _extract,
    "bake": _bake,
}


def _one_line(text: str) -> str:
    return " ".join(line.strip() for line in str(text).splitlines() if line.strip())


def _command(name: str) -> click.Command:
    import importlib

    module_name, attr = COMMANDS[name].split(":")
    return getattr(importlib.import_module(module_name), attr)


def to_call(name: str, words: list[str], where: str) -> tuple[str, dict]:
    """Parse ``words`` with command ``name``'s own options, translate them
    into an API call and check its values (no file is read).

    Raises ``UsageError`` (one line starting with ``where``).
    """
    from ..batching import check_call

    if any(w == "-o" or w.startswith(("-o", "--output")) for w in words):
        raise UsageError(f"{where}: a step takes no -o: the batch passes each step's output to the next")
    command = _command(name)
    try:
        # a FILE here would be read instead of the previous stage's output
        probe = command.make_context(name, list(words), resilient_parsing=True)
        given = probe.params.get("input_path")
    except click.exceptions.ClickException:
        given = None  # the full parse below reports it
    if given is not None:
        raise UsageError(f"{where}: a step takes no FILE: the batch feeds it the previous stage's output")
    try:
        ctx = command.make_context(name, [*words, "-"])
        function, kwargs = TO_API[name](ctx.params)
        return function, check_call(function, kwargs)
    except click.exceptions.Exit:
        raise UsageError(f"{where}: not a step (for help: staggered {name} --help)") from None
    except click.exceptions.ClickException as err:
        raise UsageError(f"{where}: {_one_line(err.format_message())}") from None
    except StaggeredError as err:
        raise UsageError(f"{where}: {_one_line(cli_text(err.message))}") from None


def parse_steps(text: str | None, option: str = "--steps") -> list[tuple[str, dict]]:
    """``'cmd opts|cmd opts|...'`` -> API calls, each checked before any file is read.

    Raises ``UsageError``: one line naming the option and the step (an
    unknown or unsuitable command, a FILE or ``-o`` in the step, an option
    or value the command refuses).
    """
    steps: list[tuple[str, dict]] = []
    if text is None or not text.strip():
        return steps
    for i, part in enumerate(text.split("|"), start=1):
        part = part.strip()
        where = f"{option}: step {i} ({part!r})" if part else f"{option}: step {i}"
        try:
            words = shlex.split(part)
        except ValueError as err:
            raise UsageError(f"{where}: {err}") from None
        if not words:
            raise UsageError(f"{where}: empty step (two '|' in a row, or a '|' at an end)")
        name, args = words[0], words[1:]
        if name not in STEP_COMMANDS:
            if name in ("extract", "bake"):
                what = f"{name!r} is not a step: extract and bake are implied (see --{name}-opts)"
            elif name in COMMANDS:
                what = f"{name!r} does not turn a document into a document"
            else:
                what = f"unknown command {name!r}"
            raise UsageError(f"{where}: {what} (steps: {', '.join(STEP_COMMANDS)})")
        if name == "layer" and "--list" in args:
            raise UsageError(f"{where}: 'layer --list' does not turn a document into a document")
        steps.append(to_call(name, args, where))
    return steps


def parse_opts(text: str | None, name: str) -> dict | None:
    """``--extract-opts`` / ``--bake-opts``: the command's own options -> API keywords."""
    if text is None:
        return None
    option = f"--{name}-opts"
    try:
        words = shlex.split(text)
    except ValueError as err:
        raise UsageError(f"{option}: {err}") from None
    return to_call(name, words, f"{option} ({text!r})")[1]


def _progress_wanted() -> bool:
    """A bar only on a terminal, and not with -q."""
    import logging

    stream = sys.stderr
    quiet = logging.getLogger("staggered_cli").getEffectiveLevel() > logging.WARNING
    return not quiet and stream is not None and stream.isatty()


STEPS_HELP = (
    "e.g. 'cull --keep 30%|succession --joint @left-arm --offset 0.03 --power 1.5 --clamp' "
    "(each step a document command with its options; shell quoting; no FILE or -o)"
)


@click.command("batch")
@click.argument("in_dir", metavar="IN_DIR", type=click.Path(file_okay=False, path_type=str))
@click.argument("out_dir", metavar="OUT_DIR", type=click.Path(file_okay=False, path_type=str))
@click.option("--steps", metavar="'CMD OPTS|CMD OPTS|...'", help=f"Steps between extract and bake, {STEPS_HELP}.")
@click.option("--steps-bvh", metavar="'CMD OPTS|...'", help="Steps for BVH files instead of --steps.")
@click.option("--steps-c3d", metavar="'CMD OPTS|...'", help="Steps for C3D files instead of --steps.")
@click.option("--extract-opts", metavar="'OPTS'", help="Options of extract, e.g. '--min-spacing 0.15'.")
@click.option("--bake-opts", metavar="'OPTS'", help="Options of bake, e.g. '--fps 30'.")
@click.option(
    "-j", "--jobs", type=click.IntRange(min=1), default=None, metavar="N", help="Worker processes.  [default: CPUs]"
)
@click.option(
    "--shard",
    metavar="I/N",
    help="Only the I-th of N parts of the file list, numbered from 1 (as `sbatch --array=1-N`): "
    "the same parts on every machine, for a job array or several hosts.",
)
@click.option("--force", is_flag=True, help="Rebuild every output, even one newer than its input.")
@click.option("--dry-run", is_flag=True, help="Check the steps and list what would be built; build nothing.")
@click.option("-v", "--verbose", is_flag=True, help="Say what each stage did for each file (as `staggered -v batch`).")
@click.pass_context
def batch(
    ctx, in_dir, out_dir, steps, steps_bvh, steps_c3d, extract_opts, bake_opts, jobs, shard, force, dry_run, verbose
):
    """Bake every BVH and C3D under IN_DIR into the same tree under OUT_DIR.

    Each file goes through `extract FILE | STEP | ... | bake -o OUT_DIR/FILE`
    with the commands' own options, through the library (`st.batch`).
    --steps-bvh and --steps-c3d replace --steps for that kind of file (a
    body part such as @left-arm names a skeleton's joint; C3D files have
    markers).  Outputs newer than their input are skipped (unless --force);
    a failing file leaves no output and the others go on.  A summary table
    goes to standard output: built, unchanged (the output holds the input's
    bytes), skipped (up to date) or failed.  The exit code is 1 if any file
    failed, 2 for bad usage (checked before any file).

    --shard I/N splits the files into N parts by a hash of their path
    relative to IN_DIR and builds the I-th: N runs (on N machines sharing
    the folders) build every file exactly once.
    """
    import logging
    import time

    from .. import api
    from .. import batching as B
    from ..batching import parse_shard

    start = time.perf_counter()
    part = parse_shard(shard) if shard is not None else None
    common = parse_steps(steps)
    bvh = parse_steps(steps_bvh, "--steps-bvh") if steps_bvh is not None else None
    c3d = parse_steps(steps_c3d, "--steps-c3d") if steps_c3d is not None else None
    extract_kw = parse_opts(extract_opts, "extract")
    bake_kw = parse_opts(bake_opts, "bake")
    level = logging.getLogger("staggered_cli").getEffectiveLevel()
    verbose = verbose or level <= logging.INFO
    quiet = level > logging.WARNING
    of_shard = f" (shard {part[0]}/{part[1]})" if part else ""
    workers = jobs or os.cpu_count() or 1
    options = dict(steps=common, steps_bvh=bvh, steps_c3d=c3d, extract_opts=extract_kw, bake_opts=bake_kw, shard=part)
    if dry_run:
        results = api.batch(in_dir, out_dir, **options, force=force, dry_run=True)
        for line in B.summary_table(results, cli=True):
            click.echo(line)
        todo = sum(r.status == B.TODO for r in results)
        click.echo(f"{len(results)} files{of_shard}: {todo} to build, {len(results) - todo} up to date (dry run)")
        return

    bar = None
    if _progress_wanted():
        from tqdm import tqdm

        todo, _ = B.plan(in_dir, out_dir, force, shard=part)  # the bar's length (a walk of the folder)
        if todo:
            bar = tqdm(total=len(todo), unit="file", file=sys.stderr, dynamic_ncols=True, leave=False)

    def report(result) -> None:
        lines = [] if quiet else [f"{PROG}: {result.rel}: WARNING: {m}" for m in result.cli_messages]
        if verbose:
            lines += [f"{PROG}: {result.rel}: {line}" for line in result.stages]
        if result.status == B.FAILED:
            lines.append(f"{PROG}: {result.rel}: {result.cli_reason}")
        for line in lines:
            if bar is not None:
                bar.write(line, file=sys.stderr)
            else:
                click.echo(line, err=True)
        if bar is not None:
            bar.set_postfix_str(result.rel, refresh=False)
            bar.update(1)

    try:
        results = api.batch(in_dir, out_dir, **options, jobs=workers, force=force, on_result=report)
    finally:
        if bar is not None:
            bar.close()
    for line in B.summary_table(results, cli=True):
        click.echo(line)
    n = B.counts(results)
    todo = len(results) - n[B.SKIPPED]
    used = min(workers, max(todo, 1))
    click.echo(
        f"{len(results)} files{of_shard}: {n[B.BUILT]} built, {n[B.UNCHANGED]} unchanged, {n[B.SKIPPED]} skipped, "
        f"{n[B.FAILED]} failed in {time.perf_counter() - start:.1f} s with {used} job{'s' if used > 1 else ''}"
    )
    if n[B.FAILED]:
        ctx.exit(1)
