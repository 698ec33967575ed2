"""The package's layering, read from the imports (docs/architecture.md).

Each layer imports only the layers below it; no module or subpackage import cycles; the
maths (``estimate``) never imports I/O, the front end or the pipeline; ``io`` knows nothing
of PCA; only the command line (``cli``) speaks of flags (imports argparse); no module over
900 lines; at most 8 modules at the top level.
"""

from __future__ import annotations

import ast
from collections import defaultdict
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "pcainterp_stream"
NAME = "pcainterp_stream"

# rank of each top-level module or subpackage; an import must go to a lower rank, or stay
# inside its own subpackage
LAYERS: dict[str, int] = {
    "errors": 0,
    "records": 0,
    "defaults": 0,
    "allocator": 0,
    "compiled": 0,
    "version": 0,
    "interrupt": 0,
    "io": 1,
    "estimate": 1,
    "frontend": 2,
    "synth": 2,
    "golden": 2,
    "evaluate": 3,
    "pipeline": 4,
    "cli": 5,
}
MAX_LINES = 900
MAX_TOP_LEVEL_MODULES = 8


def _module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _modules() -> dict[str, Path]:
    return {_module_name(path): path for path in PACKAGE.rglob("*.py")}


def _imports(path: Path, modules: dict[str, Path]) -> set[str]:
    """Modules of the package that ``path`` imports (at any depth of its code)."""
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            if not node.module.startswith(NAME):
                continue
            for alias in node.names:
                submodule = f"{node.module}.{alias.name}"
                found.add(submodule if submodule in modules else node.module)
        elif isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names if alias.name.startswith(NAME))
    return found


def _graph() -> dict[str, set[str]]:
    modules = _modules()
    return {name: _imports(path, modules) - {name} for name, path in modules.items()}


def _unit(module: str) -> str:
    """The layer unit of a module: its top-level module or subpackage name."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else ""


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Return one cycle per strongly connected component of more than one node (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for other in graph.get(node, ()):
            if other not in index:
                visit(other)
                low[node] = min(low[node], low[other])
            elif other in on_stack:
                low[node] = min(low[node], index[other])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.append(member)
                if member == node:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return found


def test_every_unit_has_a_layer() -> None:
    units = {_unit(name) for name in _modules()} - {""}
    assert units <= set(LAYERS), f"add {sorted(units - set(LAYERS))} to LAYERS and the docs"


def test_imports_go_down_the_layers() -> None:
    upward = []
    for module, imported in _graph().items():
        unit = _unit(module)
        if unit == "":
            continue  # the package's __init__: the public API, re-exported from estimate
        for other in imported:
            other_unit = _unit(other)
            if other_unit in ("", unit):
                continue
            if LAYERS[other_unit] >= LAYERS[unit]:
                upward.append(f"{module} -> {other}")
    assert upward == [], "imports that do not go to a lower layer:\n" + "\n".join(sorted(upward))


def test_no_module_import_cycles() -> None:
    assert _cycles(_graph()) == []


def test_no_subpackage_import_cycles() -> None:
    units: dict[str, set[str]] = defaultdict(set)
    for module, imported in _graph().items():
        units[_unit(module)].update(_unit(other) for other in imported)
    for unit in units:
        units[unit].discard(unit)
        units[unit].discard("")
    assert _cycles(units) == []


@pytest.mark.parametrize(
    ("lower", "forbidden"),
    [("estimate", {"io", "frontend", "pipeline", "evaluate", "synth", "cli"})],
)
def test_the_maths_imports_no_io(lower: str, forbidden: set[str]) -> None:
    offending = [
        f"{module} -> {other}"
        for module, imported in _graph().items()
        if _unit(module) == lower
        for other in imported
        if _unit(other) in forbidden
    ]
    assert offending == []


def test_io_knows_nothing_of_pca() -> None:
    offending = [
        f"{module} -> {other}"
        for module, imported in _graph().items()
        if _unit(module) == "io"
        for other in imported
        if _unit(other) == "estimate"
    ]
    assert offending == []


def _imports_argparse(path: Path) -> bool:
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import) and any(a.name == "argparse" for a in node.names):
            return True
        if isinstance(node, ast.ImportFrom) and node.module == "argparse":
            return True
    return False


def test_only_the_command_line_imports_argparse() -> None:
    outside = [
        name
        for name, path in _modules().items()
        if _unit(name) != "cli" and _imports_argparse(path)
    ]
    assert outside == [], "parse options in pcainterp_stream/cli/ and pass typed configs"
    assert _imports_argparse(PACKAGE / "cli" / "app.py")  # the check sees an import


def test_modules_are_short() -> None:
    long = {
        name: count
        for name, path in _modules().items()
        if (count := len(path.read_text().splitlines())) > MAX_LINES
    }
    assert long == {}


def test_top_level_is_small() -> None:
    top = [path.name for path in PACKAGE.glob("*.py")]
    assert len(top) <= MAX_TOP_LEVEL_MODULES, top
    subpackages = [path.name for path in PACKAGE.iterdir() if (path / "__init__.py").is_file()]
    assert len(subpackages) >= 4


def test_cycle_finder_finds_a_cycle() -> None:
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert _cycles({"a": {"b"}, "b": set()}) == []


def test_every_command_module_is_alike_and_listed() -> None:
    from pcainterp_stream.cli import COMMANDS, build_parser

    for name, module in COMMANDS.items():
        assert callable(module.add_parser), name
        assert callable(module.run), name
    commands = [
        path.stem
        for path in (PACKAGE / "cli").glob("*.py")
        if "def add_parser(" in path.read_text()
    ]
    assert sorted(commands) == sorted(
        module.__name__.rsplit(".", 1)[1] for module in COMMANDS.values()
    )
    choices = build_parser()._subparsers._group_actions[0].choices  # type: ignore[union-attr]
    assert list(choices) == list(COMMANDS)
