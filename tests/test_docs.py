"""Every code block of README.md and docs/*.md runs.

The conventions (docs/development.md states them for writers):

- Every code block is fenced and tagged.  ``sh``, ``bash`` and ``console``
  blocks are commands; ``pycon`` blocks are Python sessions; the tags of
  :data:`SKIPPED` (output listings, document JSON, Makefile fragments,
  messages, commands for other shells or machines) are not run.  Any other
  tag, or an indented code block, fails :func:`test_blocks_are_fenced_and_tagged`.
- The shell blocks of one file run in order, each with bash
  ``set -euo pipefail``, in one fresh temporary folder laid out like a
  checkout: ``data/`` (the repository's samples), ``../shared/mocap``,
  ``Makefile``, ``pyproject.toml`` and ``.venv`` (for ``make batch``) are
  links to the real ones, and ``staggered`` is on ``PATH``.  A block writes
  only under ``out/`` (the file's first block makes it), so a later block of
  the same file may read what an earlier one wrote.  Every block must exit 0.
- In a ``console`` block, ``$ `` starts a command (a line ending in ``\\``
  continues it on the next, which may start with ``> ``) and the lines up to the next command are its expected
  output, standard output and standard error together, compared with
  doctest's rules (``...`` matches anything).
- The ``pycon`` blocks of one file run as one doctest (names carry over from
  block to block) in such a folder, after the file's shell blocks.
"""

from __future__ import annotations

import doctest
import os
import re
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared"
DOC_FILES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]

SHELL = {"sh", "bash", "console"}
PYTHON = {"pycon"}
# the tags that are not run, in one place
SKIPPED = {
    "text",  # output, messages, commands that cannot run here (install, make test, ssh hosts)
    "json",  # a document's or `info --json`'s shape
    "make",  # Makefile fragments
    "zsh",  # shell completion for other shells
    "fish",
}
# linked into the temporary folder, as in a checkout
LINKS = {name: ROOT / name for name in ("data", "Makefile", "pyproject.toml", ".venv")}
# the Slurm example in docs/batch.md runs as task 5 of an array of 8 (one BVH file of ../shared/mocap)
ENV = {"SLURM_ARRAY_TASK_ID": "5", "SLURM_ARRAY_TASK_COUNT": "8", "SLURM_CPUS_PER_TASK": "2", "MPLBACKEND": "Agg"}
README_LINES = 300
FIRST_COMMAND_BY = 40


@dataclass(frozen=True)
class Block:
    path: Path
    line: int  # of the opening fence, from 1
    tag: str
    text: str

    def where(self) -> str:
        return f"{self.path.relative_to(ROOT)}:{self.line}"


FENCE = re.compile(r"^(?P<indent> *)(?P<fence>`{3,}|~{3,})(?P<info>.*)$")


def blocks(path: Path) -> list[Block]:
    """The fenced code blocks of a Markdown file, in order (a fence inside a
    list item may be indented: the indent is removed from its lines)."""
    out, lines, i = [], path.read_text().splitlines(), 0
    while i < len(lines):
        m = FENCE.match(lines[i])
        if not m:
            i += 1
            continue
        indent, fence, info = len(m["indent"]), m["fence"], m["info"].strip()
        body, j = [], i + 1
        while j < len(lines) and not re.match(rf"^ *{re.escape(fence[0])}{{{len(fence)},}}\s*$", lines[j]):
            body.append(lines[j][indent:] if lines[j][:indent].strip() == "" else lines[j])
            j += 1
        assert j < len(lines), f"{path.relative_to(ROOT)}:{i + 1}: unclosed code fence"
        out.append(Block(path, i + 1, info.split()[0] if info else "", "\n".join(body) + "\n"))
        i = j + 1
    return out


def indented_code(path: Path) -> list[int]:
    """Lines that start an indented (unfenced, untagged) code block: four
    spaces or more after a blank line, outside fences and list items."""
    found, in_fence, prev_blank, in_list = [], None, True, False
    for n, line in enumerate(path.read_text().splitlines(), 1):
        m = FENCE.match(line)
        if in_fence:
            if m and m["fence"][0] == in_fence[0] and len(m["fence"]) >= len(in_fence) and not m["info"].strip():
                in_fence = None
            continue
        if m:
            in_fence = m["fence"]
            continue
        if re.match(r"^\s*([-*]|\d+\.) ", line):
            in_list = True
        elif line.strip() and not line.startswith(" "):
            in_list = False
        indent = len(line) - len(line.lstrip(" "))
        if prev_blank and line.strip() and indent >= (6 if in_list else 4):
            found.append(n)
        prev_blank = not line.strip()
    return found


def all_blocks() -> list[Block]:
    return [b for p in DOC_FILES for b in blocks(p)]


def checkout(tmp: Path) -> Path:
    """A temporary folder laid out like a checkout beside ../shared."""
    work = tmp / "staggered"
    work.mkdir()
    for name, target in LINKS.items():
        (work / name).symlink_to(target)
    if SHARED.is_dir():
        (tmp / "shared").symlink_to(SHARED)
    return work


def environment() -> dict[str, str]:
    """This environment with ``staggered`` on PATH, without what an outer
    make (``make test``) passes to its children."""
    env = {k: v for k, v in os.environ.items() if k not in ("MAKEFLAGS", "MFLAGS", "MAKELEVEL", "MAKEOVERRIDES")}
    env.update(ENV)
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    return env


MARK = "@@staggered-docs-command {}@@"


def console_script(text: str) -> tuple[str, list[tuple[str, str]]]:
    """A console block as a script that marks where each command's output
    starts, and its (command, expected output) pairs."""
    pairs: list[list[str]] = []
    lines = text.splitlines()
    i = 0
    while i < len(lines):
        line = lines[i]
        if line.startswith("$ "):
            cmd = [line[2:]]
            while cmd[-1].endswith("\\") and i + 1 < len(lines):
                i += 1
                cmd.append(lines[i][2:] if lines[i].startswith("> ") else lines[i])
            pairs.append(["\n".join(cmd), ""])
        else:
            assert pairs, f"console block output before any command: {line!r}"
            pairs[-1][1] += line + "\n"
        i += 1
    script = "exec 2>&1\n" + "".join(f"echo '{MARK.format(k)}'\n{cmd}\n" for k, (cmd, _) in enumerate(pairs))
    return script, [(c, e) for c, e in pairs]


def run_shell(block: Block, cwd: Path) -> None:
    if block.tag == "console":
        script, pairs = console_script(block.text)
    else:
        script, pairs = block.text, []
    start = time.perf_counter()
    r = subprocess.run(
        ["bash", "-c", "set -euo pipefail\n" + script],
        cwd=cwd,
        env=environment(),
        capture_output=True,
        text=True,
        timeout=300,
    )
    seconds = time.perf_counter() - start
    assert r.returncode == 0, (
        f"{block.where()}: the {block.tag} block exited {r.returncode} after {seconds:.1f} s\n"
        f"--- block\n{block.text}--- stdout\n{r.stdout[-3000:]}--- stderr\n{r.stderr[-3000:]}"
    )
    if not pairs:
        return
    outputs = re.split(r"^@@staggered-docs-command \d+@@\n", r.stdout, flags=re.M)[1:]
    assert len(outputs) == len(pairs), (block.where(), r.stdout)
    checker = doctest.OutputChecker()
    for (cmd, expected), got in zip(pairs, outputs, strict=True):
        want = "\n".join(x.rstrip() for x in expected.rstrip("\n").splitlines())
        have = "\n".join(x.rstrip() for x in got.rstrip("\n").splitlines())
        assert checker.check_output(want + "\n", have + "\n", doctest.ELLIPSIS), (
            f"{block.where()}: `{cmd}` printed\n{have}\n--- the block shows\n{want}"
        )


def outside_out(cwd: Path) -> list[str]:
    return sorted(p.name for p in cwd.iterdir() if p.name not in LINKS and p.name != "out")


def test_blocks_are_fenced_and_tagged():
    bad = [f"{b.where()}: tag {b.tag!r}" for b in all_blocks() if b.tag not in SHELL | PYTHON | SKIPPED]
    bad += [f"{p.relative_to(ROOT)}:{n}: indented code block" for p in DOC_FILES for n in indented_code(p)]
    assert not bad, "\n".join(bad)


def test_readme_is_short_and_starts_with_a_command():
    readme = ROOT / "README.md"
    n = len(readme.read_text().splitlines())
    assert n < README_LINES, f"README.md has {n} lines"
    first = next(b for b in blocks(readme) if b.tag in SHELL)
    assert first.line <= FIRST_COMMAND_BY, f"the README's first command is at line {first.line}"


SLUG_DROP = re.compile(r"[^\w\- ]", re.UNICODE)


def anchors(path: Path) -> set[str]:
    """GitHub's heading anchors of a Markdown file."""
    out = set()
    in_fence = False
    for line in path.read_text().splitlines():
        if FENCE.match(line):
            in_fence = not in_fence
        elif not in_fence and line.startswith("#"):
            title = line.lstrip("#").strip().replace("`", "")
            out.add(SLUG_DROP.sub("", title.lower()).replace(" ", "-"))
    return out


def test_links_point_at_files_and_headings():
    bad = []
    for path in DOC_FILES:
        text = re.sub(r"```.*?```", "", path.read_text(), flags=re.S)
        for target in re.findall(r"\]\(([^)\s]+)\)", text):
            if re.match(r"[a-z]+:", target):
                continue
            file, _, anchor = target.partition("#")
            dest = (path.parent / file).resolve() if file else path
            if not dest.exists():
                bad.append(f"{path.relative_to(ROOT)}: {target} (no such file)")
            elif anchor and dest.suffix == ".md" and anchor not in anchors(dest):
                bad.append(f"{path.relative_to(ROOT)}: {target} (no such heading)")
    index = (ROOT / "docs" / "README.md").read_text()
    pages = [p for p in DOC_FILES[1:] if p.name != "README.md"]
    bad += [f"docs/README.md does not link {p.name}" for p in pages if f"({p.name})" not in index]
    assert not bad, "\n".join(bad)


SHELL_FILES = [p for p in DOC_FILES if any(b.tag in SHELL for b in blocks(p))]


@pytest.mark.parametrize("path", SHELL_FILES, ids=[str(p.relative_to(ROOT)) for p in SHELL_FILES])
def test_shell_blocks(path, tmp_path):
    shell = [b for b in blocks(path) if b.tag in SHELL]
    cwd = checkout(tmp_path)
    samples = sorted(os.listdir(ROOT / "data" / "samples"))
    for block in shell:
        run_shell(block, cwd)
    assert outside_out(cwd) == [], f"{path.name}: blocks wrote outside out/"
    assert sorted(os.listdir(ROOT / "data" / "samples")) == samples, f"{path.name}: blocks wrote into data/samples"


PYTHON_FILES = [p for p in DOC_FILES if any(b.tag in PYTHON for b in blocks(p))]


@pytest.mark.parametrize("path", PYTHON_FILES, ids=[str(p.relative_to(ROOT)) for p in PYTHON_FILES])
def test_python_blocks(path, tmp_path, monkeypatch):
    cwd = checkout(tmp_path)
    for block in blocks(path):  # the shell blocks first: the Python ones may read what they wrote
        if block.tag in SHELL:
            run_shell(block, cwd)
    monkeypatch.chdir(cwd)
    (cwd / "out").mkdir(exist_ok=True)  # where examples write, as the shell blocks' `mkdir -p out`
    parser = doctest.DocTestParser()
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    globs: dict = {"__name__": "__docs__"}
    for block in (b for b in blocks(path) if b.tag in PYTHON):
        test = parser.get_doctest(block.text, globs, block.where(), str(path), block.line)
        runner.run(test, clear_globs=False)
        globs = test.globs
    result = runner.summarize(verbose=False)
    assert result.failed == 0 and result.attempted > 0, f"{path.relative_to(ROOT)}: {result}"
