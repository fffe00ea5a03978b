"""Layers point down: every import inside neoedit (lazy ones inside functions too) goes to
the same package or a lower layer. A new package must be given its layer here."""

from __future__ import annotations

import ast
from pathlib import Path

import neoedit

LAYERS = [
    ["errors"],
    ["utils", "__init__"],
    ["cameras", "storage"],
    ["geometry"],
    ["fields", "data"],
    ["rendering", "scene_checks", "records"],
    ["scene"],
    ["grasp", "eval", "export"],
    ["viz"],
    ["language", "sim"],
    ["training"],
    ["edit"],
    ["api", "bench", "viewer"],
    ["cli"],
    ["__main__"],
]
RANK = {name: rank for rank, names in enumerate(LAYERS) for name in names}


def imports(root: Path) -> list[tuple[str, str, str]]:
    """(importing package, imported package, file) of every neoedit import under ``root``."""
    found = []
    for file in sorted(root.rglob("*.py")):
        src = file.relative_to(root).parts[0].removesuffix(".py")
        for node in ast.walk(ast.parse(file.read_text())):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            else:
                continue
            for name in names:
                parts = name.split(".")
                if parts[0] == "neoedit" and len(parts) > 1 and parts[1] != src:
                    found.append((src, parts[1], str(file.relative_to(root))))
    return found


def test_every_import_goes_down_a_layer():
    root = Path(neoedit.__file__).parent
    edges = imports(root)
    assert len(edges) > 200  # the walk sees the package
    packages = {p.name.removesuffix(".py") for p in root.iterdir() if p.suffix == ".py" or (p / "__init__.py").is_file() or p.is_dir() and any(p.glob("*.py"))}  # fmt: skip
    assert packages <= RANK.keys(), f"give these a layer: {sorted(packages - RANK.keys())}"
    upward = [f"{f}: {src} -> {dst}" for src, dst, f in edges if RANK[dst] > RANK[src]]
    assert upward == [], "\n".join(upward)


def _module_graph(root: Path) -> dict[str, set[str]]:
    """Module -> the neoedit modules it imports (lazy imports inside functions included,
    imports under ``if TYPE_CHECKING:`` left out: they never run)."""

    def name(file: Path) -> str:
        parts = ["neoedit", *file.relative_to(root).with_suffix("").parts]
        return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)

    files = {name(f): f for f in sorted(root.rglob("*.py"))}
    graph: dict[str, set[str]] = {}
    for module, file in files.items():
        tree = ast.parse(file.read_text())
        typing_only = {
            id(n)
            for node in ast.walk(tree)
            if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test)
            for sub in node.body
            for n in ast.walk(sub)
        }
        deps: set[str] = set()
        for node in ast.walk(tree):
            if id(node) in typing_only:
                continue
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module, *(f"{node.module}.{a.name}" for a in node.names)]
            else:
                continue
            deps |= {n for n in names if n in files and n != module}
        graph[module] = deps
    return graph


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            part = stack[stack.index(v) :]
            del stack[stack.index(v) :]
            if len(part) > 1:
                found.append(sorted(part))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_no_module_imports_itself_through_others():
    """No import cycle between modules written as imports, not even one a lazy import
    inside a function would hide (``if TYPE_CHECKING:`` imports do not count; names
    resolved at run time by ``utils.lazy`` or ``importlib`` are not seen)."""
    graph = _module_graph(Path(neoedit.__file__).parent)
    assert len(graph) > 100 and sum(map(len, graph.values())) > 300
    assert _cycles(graph) == []
    # the check sees a cycle: two modules that import each other
    assert _cycles({"a": {"b"}, "b": {"a"}, "c": {"a"}}) == [["a", "b"]]


def test_every_lazy_export_resolves():
    """``import neoedit`` and the packages with lazy exports load names on first use: each
    listed name must exist where the table says (a moved class must not leave a dangling
    entry)."""
    import importlib

    for package in ("neoedit", "neoedit.edit", "neoedit.bench"):
        module = importlib.import_module(package)
        for name in module.__all__:
            assert getattr(module, name) is not None, f"{package}.{name}"
