"""The speed paths agree with their references: the compiled march with the PyTorch one, the
fast renderer with closed forms and with the training sampler; thread options."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from neoedit.cameras.rays import CameraTensors, RayBundle
from neoedit.data import load_scene_data
from neoedit.errors import NeoError
from neoedit.geometry import OrientedBox
from neoedit.rendering.intervals import cut_boxes, near_far_intervals
from neoedit.rendering.march import march_occupied, march_occupied_torch, march_render
from neoedit.rendering.occupancy import (
    OccupancyGrid,
    OccupancyGridConfig,
    rebuild_grid,
    refresh_grid,
)
from neoedit.rendering.renderer import render_image
from neoedit.scene import load_scene
from neoedit.utils.threads import parse_threads, resolve_threads, set_wait_policy
from tests.test_rendering import RecordingSphere, SphereField, sphere_rays


def _rays(n: int, seed: int) -> RayBundle:
    g = torch.Generator().manual_seed(seed)
    origins = (torch.rand(n, 3, generator=g) - 0.5) * 3.0
    directions = torch.nn.functional.normalize(torch.randn(n, 3, generator=g), dim=-1)
    return RayBundle(origins, directions, torch.ones(n))


def _intervals(rays: RayBundle, boxes: list[OrientedBox]):
    t0 = torch.zeros(len(rays))
    intervals = near_far_intervals(t0, t0 + 3.0)
    return cut_boxes(intervals, rays.origins, rays.directions, boxes) if boxes else intervals


@settings(max_examples=25, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    fill=st.floats(0.05, 0.9),
    boxes=st.lists(
        st.builds(
            OrientedBox,
            st.tuples(st.floats(-0.5, 0.5), st.floats(-0.5, 0.5), st.floats(-0.5, 0.5)),
            st.tuples(st.floats(0.1, 0.8), st.floats(0.1, 0.8), st.floats(0.1, 0.8)),
            st.floats(-180, 180),
        ),
        max_size=2,
    ),
)
def test_compiled_march_matches_the_pytorch_march(seed, fill, boxes):
    pytest.importorskip("numba")
    rays = _rays(300, seed)
    intervals = _intervals(rays, boxes)
    grid = OccupancyGrid(OccupancyGridConfig(resolution=16), torch.tensor([[-1.0] * 3, [1.0] * 3]))
    mask = torch.rand((16, 16, 16), generator=torch.Generator().manual_seed(seed)) < fill
    t_ref, n_ref = march_occupied_torch(rays, intervals, grid, mask, 128)
    t_fast, n_fast = march_occupied(rays, intervals, grid, mask, 128, backend="numba")
    # a bin centre exactly on a cell face may fall either way in float32: allow a rare miss
    same = n_ref == n_fast
    assert same.float().mean() >= 0.98
    assert (n_ref - n_fast).abs().max() <= 1
    cols = torch.arange(128)[None, :] < n_ref[same, None]
    torch.testing.assert_close(t_fast[same][cols], t_ref[same][cols], atol=2e-5, rtol=0)


class _Blobs(torch.nn.Module):
    """A density with structure at every scale of the test grid: two Gaussian blobs."""

    def density(self, pts: torch.Tensor) -> torch.Tensor:
        a = torch.exp(-((pts - 0.3) ** 2).sum(-1) / 0.05)
        b = torch.exp(-((pts + 0.4) ** 2).sum(-1) / 0.2)
        return 40.0 * a + 5.0 * b


@settings(max_examples=20, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    fill=st.floats(0.05, 1.0),
    n_query=st.sampled_from([1, 4, 16, 48, 200]),
    jitter=st.booleans(),
    n_boxes=st.integers(0, 2),
    resolution=st.sampled_from([16, 24]),
)
def test_compiled_training_sampler_matches_the_pytorch_one(
    seed, fill, n_query, jitter, n_boxes, resolution
):
    """The training sampler's compiled proposal draws the bins the PyTorch reference draws
    (same random numbers), with every interval layout: up to two cut boxes (three pieces
    of a ray), empty rays, more queries than occupied bins, a grid resolution that is not a
    power of two."""
    pytest.importorskip("numba")
    from neoedit.rendering.coarse import fine_edges

    rays = _rays(300, seed)
    boxes = [
        OrientedBox((0.2, 0.0, -0.1), (0.5, 0.7, 0.4), 30.0),
        OrientedBox((-0.4, 0.3, 0.2), (0.3, 0.3, 0.6), -50.0),
    ][:n_boxes]
    intervals = _intervals(rays, boxes)
    intervals.ends[::17] = intervals.starts[::17]  # some rays have no valid domain at all
    r = resolution
    grid = OccupancyGrid(OccupancyGridConfig(resolution=r), torch.tensor([[-1.0] * 3, [1.0] * 3]))
    mask = torch.rand((r, r, r), generator=torch.Generator().manual_seed(seed)) < fill
    grid.occupied.copy_(mask)
    edges = {
        backend: fine_edges(
            _Blobs(),
            grid,
            rays,
            intervals,
            96,
            n_query,
            12,
            jitter,
            torch.Generator().manual_seed(seed),
            backend=backend,
        )  # fmt: skip
        for backend in ("torch", "numba")
    }
    ref, fast = edges["torch"], edges["numba"]
    assert fast.shape == ref.shape == (300, 13)
    assert (fast[:, 1:] >= fast[:, :-1]).all()  # front to back
    assert (fast >= 0).all() and (fast <= intervals.total[:, None] + 1e-5).all()
    # float32 rounding of the CDF moves an edge by a small part of a march bin where the
    # weights are only the uniform floor; a bin centre exactly on a cell face may fall either
    # way: allow a rare miss
    tolerance = 0.05 * intervals.total[:, None] / 96 + 1e-5
    close = ((fast - ref).abs() <= tolerance).all(-1)
    assert close.float().mean() >= 0.99, (~close).sum()
    assert float((fast - ref).abs().median()) < 1e-6
    assert (fast[::17] == 0).all()


def test_the_compiled_sampler_keeps_nan_and_refuses_no_queries():
    """A NaN density reaches the edges as in the reference (not read as an empty bin); a
    ray with a NaN origin reads no grid cell (its bins are empty); no queries is an error."""
    pytest.importorskip("numba")
    from neoedit.rendering.coarse import fine_edges

    class NanField(_Blobs):
        def density(self, pts: torch.Tensor) -> torch.Tensor:
            return torch.full(pts.shape[:1], float("nan"))

    rays = _rays(20, 0)
    rays.origins[0], rays.directions[0] = torch.tensor([-1.5, 0.0, 0.0]), torch.tensor([1.0, 0, 0])
    intervals = _intervals(rays, [])
    grid = OccupancyGrid(OccupancyGridConfig(resolution=8), torch.tensor([[-1.0] * 3, [1.0] * 3]))
    for backend in ("torch", "numba"):
        out = fine_edges(NanField(), grid, rays, intervals, 32, 8, 6, backend=backend)
        assert torch.isnan(out[0]).any(), backend  # ray 0 crosses the (all occupied) grid
        with pytest.raises(ValueError, match="at least one"):
            fine_edges(_Blobs(), grid, rays, intervals, 32, 0, 6, backend=backend)
    rays.origins[3] = float("nan")
    out = fine_edges(_Blobs(), grid, rays, intervals, 32, 8, 6, backend="numba")
    assert torch.isfinite(out).all()
    even = torch.linspace(0.0, 3.0, 7)  # no density anywhere on it: evenly spaced edges
    torch.testing.assert_close(out[3], even, atol=1e-5, rtol=0)


def test_march_render_matches_closed_form_sphere():
    radius, sigma = 0.5, 4.0
    field = SphereField(radius, sigma)
    rays, expected, expected_depth = sphere_rays(radius, sigma)
    n = len(rays)
    grid = OccupancyGrid(OccupancyGridConfig(resolution=64), field.aabb)
    refresh_grid(grid, field.density)
    intervals = near_far_intervals(torch.full((n,), 2.0), torch.full((n,), 4.0))
    out = march_render(field, grid, rays, intervals, 2048, torch.zeros(3), dilated=True)
    torch.testing.assert_close(out["accumulation"], expected, atol=4e-3, rtol=0)
    torch.testing.assert_close(out["rgb"][:, 0], expected, atol=4e-3, rtol=0)
    torch.testing.assert_close(out["depth"], expected_depth, atol=8e-3, rtol=0)
    # the occupied cells alone (the default) can only skip slivers of cells that the grid's
    # probes missed: never more, and little less, than the exact value
    core = march_render(field, grid, rays, intervals, 2048, torch.zeros(3))["accumulation"]
    assert torch.all(core <= expected + 4e-3)
    torch.testing.assert_close(core, expected, atol=0.02, rtol=0)
    assert (core - expected).abs().mean() < 2e-3


def test_early_termination_queries_less_and_changes_nothing_visible():
    field = RecordingSphere(0.4, 400.0)  # opaque: rays stop right after entering
    grid = OccupancyGrid(OccupancyGridConfig(resolution=32), field.aabb)
    refresh_grid(grid, field.density)
    n = 400
    g = torch.Generator().manual_seed(0)
    origins = torch.cat([(torch.rand(n, 2, generator=g) - 0.5) * 0.8, torch.full((n, 1), -3.0)], 1)
    rays = RayBundle(origins, torch.tensor([[0.0, 0.0, 1.0]]).repeat(n, 1), torch.ones(n))
    intervals = near_far_intervals(torch.full((n,), 2.0), torch.full((n,), 4.0))
    field.queried.clear()
    full = march_render(field, grid, rays, intervals, 512, torch.zeros(3), stop_transmittance=0.0)
    n_full = sum(len(q) for q in field.queried)
    field.queried.clear()
    fast = march_render(field, grid, rays, intervals, 512, torch.zeros(3))
    n_fast = sum(len(q) for q in field.queried)
    assert n_fast < 0.5 * n_full
    torch.testing.assert_close(fast["rgb"], full["rgb"], atol=2e-3, rtol=0)
    torch.testing.assert_close(fast["depth"], full["depth"], atol=1e-3, rtol=0)


def _psnr(a: torch.Tensor, b: torch.Tensor) -> float:
    return -10 * math.log10(float(torch.mean((a - b) ** 2)))


def test_fast_render_agrees_with_the_training_sampler(trained: Path, sim_root: Path):
    scene = load_scene(trained)
    data = load_scene_data(sim_root / "removal_1" / "pre")
    cams = CameraTensors(data.cameras, torch.device("cpu"))
    fast_cfg = scene.meta.render
    slow_cfg = type(fast_cfg)(**{**vars(fast_cfg), "fast_render": False})
    for i in data.split["test"]:
        gt = torch.as_tensor(data.images[i]).float() / 255.0
        args = (scene.field, scene.grid, cams, int(i), data.height, data.width)
        fast = render_image(*args, fast_cfg, scene.background)
        slow = render_image(*args, slow_cfg, scene.background)
        assert _psnr(fast["rgb"], slow["rgb"]) > 30.0
        assert _psnr(fast["rgb"], gt) > _psnr(slow["rgb"], gt) - 0.5


def test_training_ends_with_the_fields_own_grid(trained: Path):
    """The saved grid holds the trained field's density (not the running maximum): rebuilt
    from the loaded field, (almost) the same cells are occupied; a grid that still remembers
    densities the field no longer has is corrected without losing a surface."""
    scene = load_scene(trained)
    saved = scene.grid.occupied.clone()
    rebuild_grid(scene.grid, scene.field.density, seed=0)
    assert float((scene.grid.occupied == saved).float().mean()) > 0.97  # measured 0.984
    scene.grid.density += 50.0
    scene.grid.refresh_mask()
    assert bool(scene.grid.occupied.all())
    rebuild_grid(scene.grid, scene.field.density, seed=0)
    occupied = scene.grid.occupied
    assert float(occupied[saved].float().mean()) > 0.95  # the surfaces kept (measured 0.97)
    assert int(occupied.sum()) <= 1.1 * int(saved.sum())  # the stale fog is gone
    assert scene.meta.history[-1]["rays_per_s"] > 0


def test_thread_options(monkeypatch: pytest.MonkeyPatch):
    monkeypatch.delenv("NEO_THREADS", raising=False)
    assert resolve_threads(None) >= 1
    assert resolve_threads(3) == 3
    monkeypatch.setenv("NEO_THREADS", "2")
    assert resolve_threads(None) == 2
    assert resolve_threads(1) == 1  # the option wins over the environment
    for bad in ("0", "-1", "two"):
        monkeypatch.setenv("NEO_THREADS", bad)
        with pytest.raises(NeoError, match="NEO_THREADS"):
            resolve_threads(None)
    for bad in ("0", "x", ""):
        with pytest.raises(NeoError, match="--threads"):
            parse_threads(bad)
    env: dict[str, str] = {}
    set_wait_policy(env)
    assert env == {"GOMP_SPINCOUNT": "1000"}
    env = {"OMP_WAIT_POLICY": "ACTIVE"}
    set_wait_policy(env)
    assert env == {"OMP_WAIT_POLICY": "ACTIVE"}  # a user's choice is kept


def test_cli_threads_option(sim_root: Path, capsys: pytest.CaptureFixture[str]):
    from neoedit.cli import main, pop_threads
    from neoedit.utils.threads import configure_threads

    assert pop_threads(["info", "x", "--threads", "2"]) == (["info", "x"], "2")
    assert pop_threads(["--threads=1", "info"]) == (["info"], "1")
    data = str(sim_root / "removal_1" / "pre")
    assert main(["info", data, "--threads", "0"]) == 2
    assert "--threads must be a positive integer" in capsys.readouterr().err
    before = torch.get_num_threads()
    try:
        assert main(["info", data, "--threads", "1"]) == 0
        assert torch.get_num_threads() == 1
    finally:
        configure_threads(before)


def test_the_warmup_compiles_what_training_and_renders_call(
    trained: Path, sim_root: Path, monkeypatch: pytest.MonkeyPatch
):
    """``make setup``'s warm-up (``python -m neoedit.rendering.warmup``) calls every compiled
    kernel with the argument types (dtype, dimensions, layout) a training step and both
    renders pass, so numba's cache holds what they need: recorded per call, not read off
    the dispatchers (earlier tests in this process compiled them already)."""
    numba = pytest.importorskip("numba")
    from neoedit.fields import _hashgrid_numba
    from neoedit.rendering import _march_numba
    from neoedit.rendering.renderer import render_rays
    from neoedit.rendering.warmup import compile_kernels

    seen: dict[str, set[tuple]] = {}
    modules = {_hashgrid_numba: ("_forward", "_backward")}
    modules[_march_numba] = ("_march_bins", "_coarse_points", "_fine_edges")
    for module, names in modules.items():
        for name in names:
            kernel = getattr(module, name)

            def recording(*args, _kernel=kernel, _name=name):  # type: ignore[no-untyped-def]
                seen.setdefault(_name, set()).add(tuple(numba.typeof(a) for a in args))
                return _kernel(*args)

            monkeypatch.setattr(module, name, recording)
    assert compile_kernels()
    warmed, seen = seen, {}
    assert len(warmed) == 5, sorted(warmed)
    scene = load_scene(trained)
    data = load_scene_data(sim_root / "removal_1" / "pre")
    cams = CameraTensors(data.cameras, torch.device("cpu"))
    fast_cfg = scene.meta.render
    slow_cfg = dataclasses.replace(fast_cfg, fast_render=False)
    for cfg in (fast_cfg, slow_cfg):
        render_image(scene.field, scene.grid, cams, 0, 8, 8, cfg, scene.background)
    rays = cams.image_rays(1, data.height, data.width)[:256]
    gen = torch.Generator().manual_seed(0)
    out = render_rays(
        scene.field, scene.grid, rays, slow_cfg, scene.background, jitter=True, generator=gen
    )
    out["rgb"].sum().backward()  # the hash table's gradient
    assert len(seen) == 5, sorted(seen)
    for name, types in seen.items():
        assert types <= warmed[name], (name, types - warmed[name])


def test_the_warmup_without_numba_compiles_nothing(monkeypatch, capsys):
    """Without numba (the PyTorch paths) the set-up step has nothing to compile and says so."""
    from neoedit.rendering import warmup

    monkeypatch.setattr(warmup, "numba_available", lambda: False)
    assert warmup.compile_kernels() == []
    warmup.main()
    assert "numba is not installed" in capsys.readouterr().out
