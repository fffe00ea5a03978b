"""Shared fixtures: tiny simulated scenes generated once per test session."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from neoedit.sim.spec import ScanSpec
from neoedit.sim.suite import benchmark_scenes

TINY_SCAN = ScanSpec(width=64, height=48, n_train=10, n_eval=3)


def tiny_scene(name: str):
    spec = next(s for s in benchmark_scenes("small", seed=0) if s.name == name)
    return dataclasses.replace(spec, scan=TINY_SCAN)


@pytest.fixture(scope="session")
def sim_root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A removal scene and a pick-and-place scene of the small profile."""
    from neoedit.sim.run import simulate_scene

    root = tmp_path_factory.mktemp("neosim")
    for name in ("removal_1", "pick_place_1"):
        simulate_scene(tiny_scene(name), root / name)
    return root
