"""House rules the code keeps (docs/architecture.md): no file-level import circle among
edgedsm's modules, counting the imports made inside functions (a circle deferred to call time
is still two modules that cannot be understood or moved apart), and modules of at most 500
lines."""

from __future__ import annotations

import ast
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
PACKAGES = (REPO / "edgedsm", REPO / "edgedsm_lab")
MAX_LINES = 500
#: Modules allowed over MAX_LINES, with their length when listed: each to be split, never to grow
#: (none left: the engine and the end-to-end bench were split).
OVERSIZED: dict[str, int] = {}


def _sources() -> list[Path]:
    return [path for package in PACKAGES for path in package.rglob("*.py")]


def _module_name(path: Path) -> str:
    parts = path.relative_to(REPO).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports(path: Path, modules: set[str]) -> set[str]:
    """The edgedsm modules ``path`` imports, anywhere in it (type-checking blocks aside)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    skipped = {id(node) for block in ast.walk(tree)
               if isinstance(block, ast.If) and "TYPE_CHECKING" in ast.unparse(block.test)
               for node in ast.walk(block)}
    found: set[str] = set()
    for node in ast.walk(tree):
        if id(node) in skipped:
            continue
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            for alias in node.names:  # a submodule imported from its package names the submodule
                submodule = f"{node.module}.{alias.name}"
                found.add(submodule if submodule in modules else node.module)
    return {name for name in found if name in modules}


def _circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    circles: list[list[str]] = []

    def visit(module: str) -> None:
        index[module] = low[module] = len(index)
        stack.append(module)
        for other in graph[module]:
            if other not in index:
                visit(other)
                low[module] = min(low[module], low[other])
            elif other in stack:
                low[module] = min(low[module], index[other])
        if low[module] == index[module]:
            component = []
            while True:
                other = stack.pop()
                component.append(other)
                if other == module:
                    break
            if len(component) > 1:
                circles.append(sorted(component))

    for module in sorted(graph):
        if module not in index:
            visit(module)
    return circles


def test_no_import_circle_between_modules() -> None:
    paths = {_module_name(path): path for path in _sources()}
    graph = {name: _imports(path, set(paths)) - {name} for name, path in paths.items()}
    assert _circles(graph) == []


def test_the_circle_finder_finds_a_deferred_circle() -> None:
    assert _circles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def test_modules_stay_short() -> None:
    lengths = {str(path.relative_to(REPO)): len(path.read_text(encoding="utf-8").splitlines())
               for path in _sources() if "sparkplug_b_pb2" not in path.name}
    over = {name: lines for name, lines in lengths.items() if lines > MAX_LINES}
    assert set(over) <= set(OVERSIZED), f"new modules over {MAX_LINES} lines: {set(over) - set(OVERSIZED)}"
    grown = {name: lines for name, lines in over.items() if lines > OVERSIZED[name]}
    assert grown == {}, f"oversized modules grew: {grown}"
