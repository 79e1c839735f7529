"""The import graph tells the architecture (issues 16 and 33).

Arrows point inwards: the command line (``staggered_cli.cli``) is a face on
the library; the library's outer modules (the package root, ``batch``,
``pictures``) use the file formats (``staggered_cli.io``) and the operations
(``staggered_cli.ops``), which use the model and the math (``model/`` and
every other module of the package); never the other way.  The rules are
one table, :data:`RULES`; the exceptions that still stand are
:data:`KNOWN`, each with its reason, and the test fails as soon as one of
them no longer occurs (so that the table stays true).

Imports are read from the source with :mod:`ast`, imports inside functions
included, so a lazy import counts as much as one at the top of a module.
"""

from __future__ import annotations

import ast
from collections import defaultdict
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parent.parent / "staggered_cli"

#: The layers, outermost first.  A module is in the first layer that names
#: it or a package holding it ("staggered_cli" alone is the package root,
#: not its submodules); every module no layer names is the model and the math.
LAYERS: dict[str, tuple[str, ...]] = {
    "entry": ("staggered_cli.__main__",),
    "cli": ("staggered_cli.cli",),
    "batching": ("staggered_cli.batching",),
    "library": ("staggered_cli", "staggered_cli.api", "staggered_cli.pictures", "staggered_cli.viewer"),
    "io": ("staggered_cli.io",),
    "ops": ("staggered_cli.ops",),
}
MODEL = "model"

#: What each layer must not import, and why: the one table of the rules.
RULES: dict[str, dict[str, str]] = {
    MODEL: {
        "staggered_cli.cli": "the model knows no command line",
        "staggered_cli.io": "the model never reads or writes files",
        "staggered_cli.ops": "operations use the model, not the other way",
        "library": "the library's outer modules use the model, not the other way",
        "click": "nothing below the command line imports click",
    },
    "ops": {
        "staggered_cli.cli": "operations are pure functions under the command line",
        "staggered_cli.io": "operations go from value to value: io reads and writes",
        "library": "the library's outer modules use the operations, not the other way",
        "click": "nothing below the command line imports click",
    },
    "io": {
        "staggered_cli.cli": "io is the file boundary under the command line",
        "staggered_cli.ops": "io reads and writes values; it runs no operation",
        "library": "the library's outer modules use io, not the other way",
        "click": "nothing below the command line imports click",
    },
    "batching": {
        "staggered_cli.cli": "batch runs the public API; the command line is a face on it",
        "staggered_cli.ops": "a file goes through the public API: no operation is called around it",
        "click": "nothing below the command line imports click",
    },
    "library": {
        "staggered_cli.cli": "the library is what the command line calls, not the other way",
        "click": "nothing below the command line imports click",
    },
}

#: Exceptions that still stand, (module, imported): each with its reason.
KNOWN: dict[tuple[str, str], str] = {
    ("staggered_cli.io.container", "staggered_cli"): (
        "the package's __version__ in a 'newer than this staggered' message (a version module would end it)"
    ),
    ("staggered_cli.batching.pool", "staggered_cli.cli.heap"): (
        "its worker processes set up the heap as the command line does"
    ),
}


def _module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


SOURCES = {_module_name(p): p for p in sorted(PACKAGE.rglob("*.py"))}


def _imports(path: Path) -> set[str]:
    """Every module ``path`` imports (absolute names), at any depth of its code.

    ``from X import y`` imports the module ``X.y`` if there is one (as in
    ``from .. import quat``), else the module ``X``.
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
            for alias in node.names:
                sub = f"{module}.{alias.name}"
                found.add(sub if sub in SOURCES else module)
    return found


GRAPH = {module: _imports(path) for module, path in SOURCES.items()}


def _under(name: str, package: str) -> bool:
    return name == package or name.startswith(package + ".")


def _layer(module: str) -> str:
    for layer, names in LAYERS.items():
        for name in names:
            if module == name or (name != "staggered_cli" and _under(module, name)):
                return layer
    return MODEL


def _breaks(module: str, imported: str, forbidden: str) -> bool:
    """Whether ``module`` importing ``imported`` goes against ``forbidden``
    (a package or module, or a layer's name)."""
    if forbidden in LAYERS:
        return _under(imported, "staggered_cli") and _layer(imported) == forbidden != _layer(module)
    return _under(imported, forbidden)


def _violations(graph: dict[str, set[str]]) -> dict[tuple[str, str], str]:
    """(module, imported module) -> the rule it breaks, over the whole graph."""
    out = {}
    for module, imported in graph.items():
        for forbidden, why in RULES.get(_layer(module), {}).items():
            for name in imported:
                if _breaks(module, name, forbidden):
                    out[(module, name)] = why
    return out


def test_the_graph_sees_the_whole_package():
    expected = {
        "staggered_cli.model.document",
        "staggered_cli.ops.bake",
        "staggered_cli.cli.main",
        "staggered_cli.io.bvh",
    }
    assert expected <= set(GRAPH)
    # the parser resolves relative imports: ops/bake's ``from ..model.document import Document``
    assert "staggered_cli.model.document" in GRAPH["staggered_cli.ops.bake"]
    assert _layer("staggered_cli.model.kinds") == MODEL and _layer("staggered_cli.quat") == MODEL
    assert _layer("staggered_cli.ops.cull") == "ops" and _layer("staggered_cli.io.schema") == "io"
    assert _layer("staggered_cli") == "library" and _layer("staggered_cli.api") == "library"
    assert _layer("staggered_cli.cli.heap") == "cli"
    # every layer's rules are about names that exist
    for rules in RULES.values():
        for forbidden in rules:
            assert forbidden in LAYERS or forbidden == "click" or forbidden in GRAPH, forbidden


def test_every_import_follows_the_arrows():
    found = _violations(GRAPH)
    against = sorted(
        f"{module} imports {imported}: {why}"
        for (module, imported), why in found.items()
        if (module, imported) not in KNOWN
    )
    assert not against, "imports against the arrows:\n" + "\n".join(against)
    gone = sorted(set(KNOWN) - set(found))
    assert not gone, f"known exceptions that no longer occur, remove them from KNOWN: {gone}"


@pytest.mark.parametrize(
    ("module", "imported", "rule"),
    [
        # the lazy import io/document.py had until issue 33 (from_parts
        # checked a marker tree with ops.marker_chain.tree_has_loop)
        ("staggered_cli.io.schema", "staggered_cli.ops.marker_chain", "staggered_cli.ops"),
        ("staggered_cli.io.container", "staggered_cli.cli.options", "staggered_cli.cli"),
        ("staggered_cli.model.knots", "staggered_cli.io.files", "staggered_cli.io"),
        ("staggered_cli.model.document", "staggered_cli.ops.cull", "staggered_cli.ops"),
        ("staggered_cli.ops.cull", "staggered_cli.io.schema", "staggered_cli.io"),
        ("staggered_cli.ops.bake", "staggered_cli.cli.common", "staggered_cli.cli"),
        ("staggered_cli.quat", "staggered_cli.pictures", "library"),
        ("staggered_cli.io.bvh", "staggered_cli.api", "library"),
        ("staggered_cli.batching.run", "staggered_cli.ops.cull", "staggered_cli.ops"),
        ("staggered_cli.batching.steps", "staggered_cli.cli.batch", "staggered_cli.cli"),
        ("staggered_cli.ops.extract", "click", "click"),
        ("staggered_cli.pictures.preview", "staggered_cli.cli.main", "staggered_cli.cli"),
    ],
)
def test_the_rules_catch_an_import_against_the_arrows(module, imported, rule):
    """Each rule fails on the import it forbids, added to a copy of the graph."""
    graph = {m: set(names) for m, names in GRAPH.items()}
    assert (module, imported) not in _violations(graph)
    graph[module].add(imported)
    assert _violations(graph).get((module, imported)) == RULES[_layer(module)][rule]


def test_inward_imports_are_allowed():
    """The arrows point inwards: none of these is a violation."""
    allowed = [
        ("staggered_cli.io.schema", "staggered_cli.model.document"),
        ("staggered_cli.ops.bake", "staggered_cli.model.evaluate"),
        ("staggered_cli.pictures.curves", "staggered_cli.ops.bake"),
        ("staggered_cli.cli.bake", "staggered_cli.io.files"),
        ("staggered_cli.model.fit", "staggered_cli.quat_rows"),
    ]
    graph = {m: set(names) for m, names in GRAPH.items()}
    before = set(_violations(graph))
    for module, imported in allowed:
        graph[module].add(imported)
    assert set(_violations(graph)) == before


#: Calls that read, write, create or remove files (only io's job), by the
#: module or method they are called on.
FILE_CALLS = {
    "os": {"open", "makedirs", "mkdir", "unlink", "remove", "replace", "rename", "rmdir", "fsync", "scandir", "walk"},
    "shutil": {"copy", "copyfile", "copy2", "move", "rmtree", "copytree"},
    "tempfile": {"mkstemp", "mkdtemp", "NamedTemporaryFile", "TemporaryDirectory", "TemporaryFile"},
    "np": {"load", "save", "savez", "savez_compressed", "fromfile", "loadtxt", "savetxt"},
}
#: Methods only a path has.
PATH_METHODS = {"read_bytes", "write_bytes", "read_text", "write_text", "mkdir", "touch", "unlink", "rmdir", "iterdir"}

#: Modules outside io that still touch files, (module, call): each with its reason.
KNOWN_FILES: dict[tuple[str, str], str] = {
    ("staggered_cli.cli.main", "os.open"): "points stdout at os.devnull when the reader of a pipe is gone",
}


def _file_calls(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    # names bound to staggered_cli.io modules (``files.read_bytes`` is io's function)
    io_names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and "io" in node.module.split("."):
            io_names |= {alias.asname or alias.name for alias in node.names}
    found = set()
    for node in ast.walk(tree):
        if not isinstance(node, ast.Call):
            continue
        f = node.func
        if isinstance(f, ast.Name) and f.id == "open":
            found.add("open")
        elif isinstance(f, ast.Attribute):
            base = ast.unparse(f.value)
            if f.attr in FILE_CALLS.get(base, ()) or (f.attr in PATH_METHODS and base not in io_names):
                found.add(f"{base}.{f.attr}")
    return found


def test_only_io_touches_files():
    found = {(module, call) for module, path in SOURCES.items() if _layer(module) != "io" for call in _file_calls(path)}
    against = sorted(found - set(KNOWN_FILES))
    assert not against, f"file access outside staggered_cli.io (module, call): {against}"
    gone = sorted(set(KNOWN_FILES) - found)
    assert not gone, f"known file access that no longer occurs, remove it from KNOWN_FILES: {gone}"


def test_the_file_rule_sees_a_file_opened_outside_io(tmp_path):
    source = tmp_path / "mod.py"
    source.write_text(
        "import os\nfrom ..io import files\n\ndef f(p):\n    files.read_bytes(p)\n    with open(p) as h:\n"
        "        os.unlink(p)\n    p.write_text('x')\n    'a'.replace('a', 'b')\n",
        encoding="utf-8",
    )
    assert _file_calls(source) == {"open", "os.unlink", "p.write_text"}


#: Public names defined in more than one module outside the command line
#: (whose commands are named for their operations), and why that is right.
SHARED_NAMES: dict[str, str] = {
    "mul": "quat's (..., 4) product and quat_rows' product of (4, n) rows: one algebra, two layouts",
    "log": "quat's and quat_rows' logarithm: one algebra, two layouts",
    "exp": "quat's and quat_rows' exponential: one algebra, two layouts",
    "pose_values": "ops.edit_pose's of a base pose, ops.layers' of a layer's pose (issue 32's to merge)",
}


def test_one_owner_per_concept():
    """A public function or class is defined in one module: a second
    definition of a name is a second owner of its concept."""
    owners = defaultdict(set)
    for module, path in SOURCES.items():
        if _layer(module) in ("cli", "entry") or module == "staggered_cli.api":
            continue  # the commands and the public API are faces on the operations, named as them
        for node in ast.parse(path.read_text(encoding="utf-8")).body:
            if isinstance(node, ast.FunctionDef | ast.ClassDef) and not node.name.startswith("_"):
                owners[node.name].add(module)
    shared = {name: sorted(mods) for name, mods in owners.items() if len(mods) > 1}
    against = {name: mods for name, mods in shared.items() if name not in SHARED_NAMES}
    assert not against, f"names defined by more than one module: {against}"
    gone = sorted(set(SHARED_NAMES) - set(shared))
    assert not gone, f"shared names that are no longer shared, remove them from SHARED_NAMES: {gone}"


#: A clip's file layout: set by the readers, read by the writers alone.
LAYOUT = ("frame_time_text", "number_format")


def test_only_the_file_formats_read_a_clip_s_layout():
    """The operations and the model carry a BVH's layout (the frame time as
    written, the number format) along with ``BvhMotion.with_channels``; only
    ``staggered_cli.io`` reads it (and motion.py, which defines it)."""
    readers = set()
    for module, path in SOURCES.items():
        if _layer(module) not in ("ops", MODEL) or module == "staggered_cli.motion":
            continue
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        if any(isinstance(n, ast.Attribute) and n.attr in LAYOUT for n in ast.walk(tree)):
            readers.add(module)
    assert readers == set(), f"modules that read a clip's file layout: {sorted(readers)}"
