"""Shared fixtures: tiny simulated scenes and fields, built once per test run (shared by the
pytest-xdist workers, see :func:`built_once`)."""

from __future__ import annotations

import dataclasses
import os
import shutil
import string
import tempfile
from collections.abc import Callable
from pathlib import Path

import pytest
import torch
from filelock import FileLock
from hypothesis import settings

from neoedit.fields.hashgrid import HashGridConfig
from neoedit.fields.radiance import RadianceFieldConfig
from neoedit.rendering.occupancy import OccupancyGridConfig
from neoedit.rendering.renderer import RenderConfig
from neoedit.sim.spec import ScanSpec
from neoedit.sim.suite import benchmark_scenes
from neoedit.training.trainer import TrainConfig, train
from neoedit.utils.threads import configure_threads

# messages are checked as printed: rich wraps them at the terminal width (80 columns when
# there is no terminal), so a long temporary path would break a line inside a checked phrase
os.environ["COLUMNS"] = "250"

# derived simulator assets (a mug's convex parts) are cached outside the user's home
os.environ.setdefault(
    "NEOEDIT_CACHE", os.path.join(tempfile.gettempdir(), f"neoedit-test-cache-{os.getuid()}")
)

# under pytest-xdist (make test runs two workers on two cores) each worker keeps to one
# thread, so the workers do not fight over the cores
if os.environ.get("PYTEST_XDIST_WORKER"):
    os.environ.setdefault("NEO_THREADS", "1")
    configure_threads()

# property tests draw the same examples on every run (CI must not fail by chance)
settings.register_profile("deterministic", derandomize=True, database=None, deadline=None)
settings.load_profile("deterministic")


TINY_SCAN = ScanSpec(width=64, height=48, n_train=10, n_eval=3)
TINY_FIELD = RadianceFieldConfig(
    hashgrid=HashGridConfig(n_levels=8, log2_hashmap_size=14, max_resolution=256),
    hidden_dim=32,
    hidden_dim_color=32,
)
TINY_RENDER = RenderConfig(n_march_samples=192, n_coarse_samples=48, n_samples=24)
TINY_GRID = OccupancyGridConfig(resolution=48, warmup_steps=32)


def tiny_train(
    data: Path,
    out: Path,
    steps: int,
    resume: bool = False,
    language=None,
    data_cfg=None,
    **options,
):
    """Train the tiny test configuration on CPU (no evaluation, one checkpoint at the end);
    ``options``: more :class:`TrainConfig` fields."""
    cfg = TrainConfig(
        max_steps=steps,
        rays_per_batch=1024,
        eval_every=0,
        eval_views=2,
        checkpoint_every=0,
        lr=2e-2,
        **options,
    )
    return train(
        data,
        out,
        cfg,
        TINY_FIELD,
        TINY_RENDER,
        TINY_GRID,
        device="cpu",
        resume=resume,
        language=language,
        data_cfg=data_cfg,
    )


def tiny_trainer(data_path: Path, near_m: float, cfg: TrainConfig):
    """An in-memory Trainer of the tiny field on a dataset (constant background: RGBA data)
    that has run ``cfg.max_steps`` steps; nothing is saved."""
    from neoedit.data import load_scene_data
    from neoedit.scene import Scene, SceneMeta
    from neoedit.training.defaults import scene_box
    from neoedit.training.trainer import Trainer

    data = load_scene_data(data_path)
    meta = SceneMeta(
        data_path=str(data_path),
        aabb_m=scene_box(data),
        background_rgb=list(data.background_rgb),
        field=dataclasses.replace(TINY_FIELD, learned_background=False),
        grid=TINY_GRID,
        render=dataclasses.replace(TINY_RENDER, near_m=near_m),
    )
    trainer = Trainer(data, Scene.create(meta), cfg, None, torch.device("cpu"))
    for step in range(cfg.max_steps):
        trainer.step(step)
    return trainer


def tiny_scene(name: str):
    spec = next(s for s in benchmark_scenes("small", seed=0) if s.name == name)
    return dataclasses.replace(spec, scan=TINY_SCAN)


def tiny_clip_vocab() -> dict[str, int]:
    """A character-level CLIP BPE vocabulary (no merges) for tiny random test models."""
    chars = list(string.ascii_lowercase + string.digits + " ;,.-'")
    tokens = ["<|startoftext|>", "<|endoftext|>", *chars, *[c + "</w>" for c in chars]]
    return {t: i for i, t in enumerate(tokens)}


HEAVY_FIRST = (
    "test_bench.py",
    "test_import.py",
    "test_history.py",
    "test_move.py",
    "test_conventions_train.py",
    "test_batch.py",
    "test_training.py",
    "test_colour_fidelity.py",
    "test_nerfiller.py",
    "test_bad_inputs.py",
    "test_background.py",
    "test_pose_refinement.py",
    "test_align.py",
)
"""The longest test files (measured: 25-235 s each of ~1,150 s on 2 cores), run first. With
``--dist loadfile --no-loadscope-reorder`` (make test) pytest-xdist hands whole files to its
workers in this collection order, so the short files fill the end and both workers finish
together (xdist's own order, most tests first, left one worker idle for the last ~70 s).
A file missing here only runs later: the order changes the wall time, never the results."""


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    rank = {name: i for i, name in enumerate(HEAVY_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))  # stable: same within


def built_once(factory: pytest.TempPathFactory, name: str, build: Callable[[Path], None]) -> Path:
    """``build(path)`` once per test run, shared by every pytest-xdist worker: the first
    worker to ask builds it under a file lock, the others wait and reuse the result (a
    session fixture alone is built once per worker). Users of the path must not change it."""
    if os.environ.get("PYTEST_XDIST_WORKER") is None:
        out = factory.mktemp(name) / name
        build(out)
        return out
    root = factory.getbasetemp().parent / f"shared-{name}"  # the run's folder, all workers
    root.mkdir(exist_ok=True)
    out, done = root / name, root / "built"
    with FileLock(str(root / "lock")):
        if not done.exists():
            shutil.rmtree(out, ignore_errors=True)  # what a failed build left
            build(out)
            done.touch()
    return out


@pytest.fixture(scope="session")
def sim_root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A removal scene and a pick-and-place scene of the small profile."""
    from neoedit.sim.run import simulate_scene

    def build(root: Path) -> None:
        for name in ("removal_1", "pick_place_1"):
            simulate_scene(tiny_scene(name), root / name)

    return built_once(tmp_path_factory, "neosim", build)


@pytest.fixture(scope="session")
def trained(sim_root: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The tiny removal_1 pre scan trained for 400 steps (radiance field only)."""
    return built_once(
        tmp_path_factory,
        "pre",
        lambda out: tiny_train(sim_root / "removal_1" / "pre", out, steps=400),
    )


@pytest.fixture(scope="session")
def move_scene(sim_root: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The tiny pick-and-place pre scan with a label-teacher language field."""
    from neoedit.language.training import LanguageTrainConfig

    language = LanguageTrainConfig(rays=16384, steps=150, batch=2048)
    return built_once(
        tmp_path_factory,
        "move_pre",
        lambda out: tiny_train(
            sim_root / "pick_place_1" / "pre", out, steps=400, language=language
        ),
    )
