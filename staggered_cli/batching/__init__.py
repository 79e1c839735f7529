"""Batch processing of a mocap library: extract, steps and bake per file.

For every BVH and C3D file under an input folder (recursively, any case of
the extension) :func:`staggered_cli.batch` (``st.batch``) runs the same
pipeline as the shell form::

    staggered extract IN/rel -o - | staggered STEP1 - -o - | ... | staggered bake - -o OUT/rel

through the public API, one process per worker.  A step is an API call
``(name, kwargs)``, e.g. ``("cull", {"keep": "30%"})``, run as
``getattr(staggered_cli.api, name)(doc, **kwargs)``; the command line parses
its ``--steps`` words with each command's own grammar into such calls.

(The package is ``batching``, not ``batch``: ``staggered_cli.batch`` is the
API function.)  One job per module:

* :mod:`.steps`: what a step is, and checking every step once, before any file;
* :mod:`.plan`: finding the inputs, sharding them, what is up to date;
* :mod:`.run`: one file through the API (and what each stage did);
* :mod:`.pool`: the worker processes, which survive a crash of one file;
* :mod:`.results`: the statuses and the summary table.
"""

from __future__ import annotations

from .plan import EXTENSIONS, Job, find_inputs, parse_shard, plan, shard_of
from .pool import run_batch
from .results import BUILT, FAILED, SKIPPED, STATUSES, TODO, UNCHANGED, Result, counts, summary_table
from .run import Plan, run_file
from .steps import STEP_FUNCTIONS, Step, check_call, check_steps

__all__ = [
    "BUILT",
    "EXTENSIONS",
    "FAILED",
    "Job",
    "Plan",
    "Result",
    "SKIPPED",
    "STATUSES",
    "STEP_FUNCTIONS",
    "Step",
    "TODO",
    "UNCHANGED",
    "check_call",
    "check_steps",
    "counts",
    "find_inputs",
    "parse_shard",
    "plan",
    "run_batch",
    "run_file",
    "shard_of",
    "summary_table",
]
