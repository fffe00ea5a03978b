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


def test_every_lazy_export_resolves():
    """``import neoedit`` and the packages with lazy exports load names on first use: each
    listed name must exist where the table says (a moved class must not leave a dangling
    entry)."""
    import importlib

    for package in ("neoedit", "neoedit.edit", "neoedit.bench"):
        module = importlib.import_module(package)
        for name in module.__all__:
            assert getattr(module, name) is not None, f"{package}.{name}"
