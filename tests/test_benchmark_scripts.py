"""The scripts under benchmarks/ are not run by the suite (they take minutes to hours), so
nothing else notices when a refactor moves a name they import: each one is loaded here (its
imports and definitions; ``main`` is not called)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

SCRIPTS = sorted((Path(__file__).parent.parent / "benchmarks").glob("*.py"))


def test_the_benchmark_scripts_are_found():
    assert len(SCRIPTS) >= 10


@pytest.mark.parametrize("script", SCRIPTS, ids=[s.stem for s in SCRIPTS])
def test_a_benchmark_script_loads(script: Path, monkeypatch: pytest.MonkeyPatch):
    monkeypatch.syspath_prepend(str(script.parent))  # as when run: its siblings importable
    spec = importlib.util.spec_from_file_location(f"_bench_{script.stem}", script)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)  # imports every name the script uses at load time
    if '__name__ == "__main__"' in script.read_text():  # a script, not a helper module
        assert callable(getattr(module, "main", None)), f"{script.name} has no main()"
