"""``staggered batch``: extract -> steps -> bake over a whole mocap library."""

from __future__ import annotations

import os
import sys

import click

from .main import COMMANDS, PROG


def _progress_wanted() -> bool:
    """A bar only on a terminal, and not with -q."""
    import logging

    stream = sys.stderr
    quiet = logging.getLogger("staggered_cli").getEffectiveLevel() > logging.WARNING
    return not quiet and stream is not None and stream.isatty()


@click.command("batch")
@click.argument("in_dir", metavar="IN_DIR", type=click.Path(file_okay=False, path_type=str))
@click.argument("out_dir", metavar="OUT_DIR", type=click.Path(file_okay=False, path_type=str))
@click.option(
    "--steps",
    metavar="'CMD OPTS|CMD OPTS|...'",
    help="Document steps between extract and bake, e.g. 'cull --keep 30%|succession --joint "
    "LeftShoulder --offset 0.02 --power 2' (shell quoting; no FILE or -o).",
)
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
@click.pass_context
def batch(ctx, in_dir, out_dir, steps, jobs, shard, force, dry_run):
    """Bake every BVH and C3D under IN_DIR into the same tree under OUT_DIR.

    Each file goes through `extract FILE | STEP | ... | bake -o OUT_DIR/FILE`
    in-process, with the commands' own options.  Outputs newer than their
    input are skipped (unless --force); a failing file leaves no output and
    the others go on.  A summary table goes to standard output; the exit
    code is 1 if any file failed, 2 for bad usage (checked before any file).

    --shard I/N splits the files into N parts by a hash of their path
    relative to IN_DIR and builds the I-th: N runs (on N machines sharing
    the folders) build every file exactly once.
    """
    import time

    from .. import batch as B

    start = time.perf_counter()
    part = B.parse_shard(shard) if shard is not None else None
    parsed = B.parse_steps(steps, COMMANDS)
    todo, skipped = B.plan(in_dir, out_dir, force, shard=part)
    of_shard = f" (shard {part[0]}/{part[1]})" if part else ""
    workers = jobs or os.cpu_count() or 1
    if dry_run:
        results = skipped + [B.Result(job.rel, B.TODO) for job in todo]
        for line in B.summary_table(results):
            click.echo(line)
        click.echo(f"{len(results)} files{of_shard}: {len(todo)} to build, {len(skipped)} up to date (dry run)")
        return

    bar = None
    if todo and _progress_wanted():
        from tqdm import tqdm

        bar = tqdm(total=len(todo), unit="file", file=sys.stderr, dynamic_ncols=True, leave=False)

    def report(result) -> None:
        lines = [f"{PROG}: {result.rel}: {m.removeprefix(PROG + ': ')}" for m in result.messages]
        if result.status == B.FAILED:
            lines.append(f"{PROG}: {result.rel}: {result.reason}")
        for line in lines:
            if bar is not None:
                bar.write(line, file=sys.stderr)
            else:
                click.echo(line, err=True)
        if bar is not None:
            bar.set_postfix_str(result.rel, refresh=False)
            bar.update(1)

    try:
        results = skipped + B.run_batch(todo, parsed, workers, COMMANDS, on_result=report)
    finally:
        if bar is not None:
            bar.close()
    for line in B.summary_table(results):
        click.echo(line)
    n = B.counts(results)
    used = min(workers, max(len(todo), 1))
    click.echo(
        f"{len(results)} files{of_shard}: {n[B.DONE]} done, {n[B.SKIPPED]} skipped, {n[B.FAILED]} failed "
        f"in {time.perf_counter() - start:.1f} s with {used} job{'s' if used > 1 else ''}"
    )
    if n[B.FAILED]:
        ctx.exit(1)
