"""The import graph tells the architecture (issue 16).

Arrows point inwards: the command line (``staggered_cli.cli``) and the file
formats (``staggered_cli.io``) use the operations (``staggered_cli.ops``),
which use the model and the math (every other module of the package); never
the other way.  Imports are read from the source with :mod:`ast`, imports
inside functions included, so a lazy import counts as much as one at the
top of a module.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parent.parent / "staggered_cli"

#: Top-level modules outside the model, and why.
OUTER = {
    "staggered_cli.__main__": "the entry point: runs the command line",
    "staggered_cli.batching": "runs the API over a library (checked below: it must not import cli)",
    "staggered_cli.plots": "draws documents into PNG files: bakes them (ops) and writes (io)",
}

#: Known exceptions, (module, imported module): none since the format
#: schema moved to io/document.py (the test fails while one is listed but unused).
KNOWN: set[tuple[str, str]] = set()


def _module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports(path: Path) -> set[str]:
    """Every module ``path`` imports (absolute names), at any depth of its code.

    ``from X import y`` counts as importing ``X`` and ``X.y`` (``y`` may be a
    submodule, as in ``from .. import io``).
    """
    name = _module_name(path)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), filename=str(path))):
        if isinstance(node, ast.Import):
            found |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package
                for _ in range(node.level - 1):
                    base = base.rpartition(".")[0]
                module = f"{base}.{node.module}" if node.module else base
            else:
                module = node.module or ""
            found.add(module)
            found |= {f"{module}.{alias.name}" for alias in node.names}
    return found


def _graph() -> dict[str, set[str]]:
    return {_module_name(p): _imports(p) for p in sorted(PACKAGE.rglob("*.py"))}


GRAPH = _graph()


def _under(name: str, package: str) -> bool:
    return name == package or name.startswith(package + ".")


def _layer(module: str) -> str:
    for layer in ("cli", "io", "ops"):
        if _under(module, f"staggered_cli.{layer}"):
            return layer
    if module == "staggered_cli" or any(_under(module, outer) for outer in OUTER):
        return "outer"
    return "model"


def _violations(layers: tuple[str, ...], forbidden: tuple[str, ...]) -> set[tuple[str, str]]:
    out = set()
    for module, imported in GRAPH.items():
        if _layer(module) not in layers:
            continue
        for name in imported:
            for package in forbidden:
                if _under(name, package):
                    # the module itself, not the name imported from it
                    target = name if name in GRAPH else name.rpartition(".")[0]
                    out.add((module, target if _under(target, package) else package))
    return out


def test_the_graph_sees_the_whole_package():
    expected = {"staggered_cli.document", "staggered_cli.ops.bake", "staggered_cli.cli.main", "staggered_cli.io.bvh"}
    assert expected <= set(GRAPH)
    # the parser resolves relative imports: ops/bake's ``from ..document import Document``
    assert "staggered_cli.document" in GRAPH["staggered_cli.ops.bake"]
    assert _layer("staggered_cli.kinds") == "model" and _layer("staggered_cli.ops.cull") == "ops"


@pytest.mark.parametrize(
    ("layers", "forbidden"),
    [
        (("ops", "model"), ("staggered_cli.cli",)),
        (("ops", "model"), ("staggered_cli.io",)),
        (("model",), ("staggered_cli.ops",)),
    ],
    ids=["no-cli", "no-io", "model-no-ops"],
)
def test_ops_the_model_and_the_math_import_no_outer_layer(layers, forbidden):
    found = _violations(layers, forbidden)
    known = {pair for pair in KNOWN if any(_under(pair[1], f) for f in forbidden)}
    against = sorted(found - known)
    assert not against, f"imports against the arrows (module, imported): {against}"
    gone = sorted(known - found)
    assert not gone, f"known exceptions that no longer occur, remove them from KNOWN: {gone}"


def test_batch_does_not_import_the_command_line():
    modules = [m for m in GRAPH if _under(m, "staggered_cli.batching")]
    assert len(modules) >= 5  # the package, steps, plan, run, pool, results
    found = {(m, name) for m in modules for name in GRAPH[m] if _under(name, "staggered_cli.cli")}
    assert not found, found
    # a file goes through the public API: no operation is called around it
    found = {(m, name) for m in modules for name in GRAPH[m] if _under(name, "staggered_cli.ops")}
    assert not found, found


#: A clip's file layout: set by the readers, read by the writers alone.
LAYOUT = ("frame_time_text", "number_format")


def test_only_the_file_formats_read_a_clip_s_layout():
    """The operations and the model carry a BVH's layout (the frame time as
    written, the number format) along with ``BvhMotion.with_channels``; only
    ``staggered_cli.io`` reads it (and motion.py, which defines it)."""
    readers = set()
    for path in sorted(PACKAGE.rglob("*.py")):
        module = _module_name(path)
        if _layer(module) not in ("ops", "model") or module == "staggered_cli.motion":
            continue
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        if any(isinstance(n, ast.Attribute) and n.attr in LAYOUT for n in ast.walk(tree)):
            readers.add(module)
    assert readers == set(), f"modules that read a clip's file layout: {sorted(readers)}"
