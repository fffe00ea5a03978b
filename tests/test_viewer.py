"""`neo view`: the render state machine (no browser), and a real viewer server driven over
its websocket exactly as a browser page drives it (viser's wire protocol)."""

from __future__ import annotations

import json
import math
import socket
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from test_language import SPARSE  # the tiny scan's sparse cloud: looser clustering
from viewer_support import Page, Scenario, free_port, pixel_diff, until

from neoedit.viewer.render_loop import (
    Frame,
    RenderInterrupted,
    RenderLoop,
    RenderLoopConfig,
    ViewRequest,
    low_resolution,
)


class FakeClock:
    """A clock the test moves by hand (the loop's idea of 'the camera is still')."""

    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


class Frames:
    def __init__(self) -> None:
        self.frames: list[Frame] = []
        self.errors: list[Exception] = []
        self._cond = threading.Condition()

    def add(self, frame: Frame) -> None:
        with self._cond:
            self.frames.append(frame)
            self._cond.notify_all()

    def error(self, e: Exception) -> None:
        with self._cond:
            self.errors.append(e)
            self._cond.notify_all()

    def wait_error(self, timeout: float = 20.0) -> None:
        with self._cond:
            assert self._cond.wait_for(lambda: bool(self.errors), timeout)

    def wait(self, pred: Callable[[Frame], bool], timeout: float = 20.0) -> Frame:
        with self._cond:
            ok = self._cond.wait_for(lambda: any(pred(f) for f in self.frames), timeout)
            assert ok, (
                f"no such frame in {[(f.width, f.height, f.full, f.serial) for f in self.frames]}"
            )
            return next(f for f in self.frames if pred(f))


def _pose(x: float) -> np.ndarray:
    c2w = np.eye(4)
    c2w[0, 3] = x
    return c2w


W, H, RATE = 200, 100, 20_000.0  # a full frame takes 1 s of the fake timer, a moving one 0.1 s


def _loop(render, frames: Frames, clock: FakeClock, timer: FakeClock) -> RenderLoop:
    cfg = RenderLoopConfig(target_fps=10, still_s=0.5, min_side=4, initial_rays_per_s=RATE)
    return RenderLoop(render, frames.add, cfg, frames.error, clock=clock, timer=timer)


def test_low_resolution_is_sized_from_the_measured_speed():
    cfg = RenderLoopConfig(target_fps=10, min_side=24)
    w, h = low_resolution(640, 480, 10_000, cfg)  # 1000 rays per frame
    assert abs(w * h - 1000) < 60 and abs(w / h - 4 / 3) < 0.1
    assert low_resolution(640, 480, 1e9, cfg) == (640, 480)  # fast enough: full resolution
    assert low_resolution(640, 480, 10, cfg) == (32, 24)  # never below min_side
    assert low_resolution(40, 30, 10, cfg) == (32, 24)
    assert low_resolution(40, 20, 10, cfg) == (40, 20)  # already below min_side


def test_moving_renders_low_resolution_and_still_refines_to_full():
    clock, timer, frames = FakeClock(), FakeClock(), Frames()
    sizes: list[tuple[int, int]] = []

    def render(c2w, fov, w, h):
        sizes.append((w, h))
        timer.t += w * h / RATE  # a renderer of exactly RATE rays/s
        return np.full((h, w, 3), 0.5), np.ones((h, w))

    loop = _loop(render, frames, clock, timer).start()
    try:
        for k in range(5):  # the camera moves (the clock stands still: never 'still')
            serial = loop.update(ViewRequest(_pose(k), 1.0, W, H), moving=True)
            time.sleep(0.01)
        last = frames.wait(lambda f: f.serial == serial)
        assert loop.wait_idle(20)  # every moving frame rendered; waiting to be still
        assert frames.frames and not any(f.full for f in frames.frames)
        assert (last.width, last.height) == low_resolution(W, H, RATE, loop.cfg)
        assert last.width < W and last.rgb.shape == (last.height, last.width, 3)
        assert loop.rays_per_s == pytest.approx(RATE)
        clock.t = 1.0  # no camera change for longer than still_s: refine
        full = frames.wait(lambda f: f.full)
        assert (full.width, full.height, full.serial) == (W, H, serial)
        assert sizes[-1] == (W, H)
        n = len(sizes)
        assert loop.wait_idle(20)
        assert len(sizes) == n  # refined once, then idle
        # new content (another version) with the same camera: low resolution, then refined
        serial = loop.refresh()
        frames.wait(lambda f: f.serial == serial and f.full)
        assert sizes[n:] == [(last.width, last.height), (W, H)]
    finally:
        loop.stop()
    assert not frames.errors


def test_a_camera_move_interrupts_a_refinement():
    clock, timer, frames = FakeClock(), FakeClock(), Frames()
    entered = threading.Event()
    blocked: list[bool] = []

    def render(c2w, fov, w, h):
        timer.t += w * h / RATE
        if (w, h) == (W, H) and not blocked:
            blocked.append(True)
            entered.set()
            deadline = time.monotonic() + 20
            while not loop.should_stop():  # a renderer polls between ray chunks
                assert time.monotonic() < deadline, "the refinement was never interrupted"
                time.sleep(0.005)
            raise RenderInterrupted
        return np.full((h, w, 3), c2w[0, 3] / 10), np.ones((h, w))

    loop = _loop(render, frames, clock, timer).start()
    try:
        first = loop.update(ViewRequest(_pose(1), 1.0, W, H), moving=False)  # still: refine
        assert entered.wait(20)
        assert not loop.should_stop()  # nothing newer yet
        second = loop.update(ViewRequest(_pose(2), 1.0, W, H), moving=True)
        moving = frames.wait(lambda f: f.serial == second)
        assert loop.interrupted == 1
        assert not moving.full and np.allclose(moving.rgb, 0.2)
        # the stale refinement was never shown
        assert not any(f.full for f in frames.frames)
        assert all(f.serial in (first, second) for f in frames.frames)
        clock.t = 5.0
        full = frames.wait(lambda f: f.full)
        assert full.serial == second and np.allclose(full.rgb, 0.2)
    finally:
        loop.stop()
    assert not frames.errors


def test_render_errors_are_reported_and_the_loop_keeps_serving():
    clock, timer, frames = FakeClock(), FakeClock(), Frames()

    def render(c2w, fov, w, h):
        if c2w[0, 3] == 1:
            raise ValueError("broken view")
        return np.zeros((h, w, 3)), np.ones((h, w))

    loop = _loop(render, frames, clock, timer).start()
    try:
        loop.update(ViewRequest(_pose(1), 1.0, W, H), moving=False)
        frames.wait_error()
        assert "broken view" in str(frames.errors[0])
        serial = loop.update(ViewRequest(_pose(2), 1.0, W, H), moving=False)
        frames.wait(lambda f: f.serial == serial and f.full)
        assert len(frames.errors) == 1  # a failing view is not retried
    finally:
        loop.stop()
    assert not loop._thread.is_alive()


# -- a real server, driven like a browser (tests/viewer_support.py) --------------------------


@pytest.fixture
def store(move_scene: Path, tmp_path: Path) -> Path:
    """A scene store whose one version 'v0' is the tiny pick-and-place scene."""
    from neoedit.scene import load_scene, save_scene
    from neoedit.storage import SceneStore

    root = tmp_path / "store"
    SceneStore.create(root)
    save_scene(root / "v0", load_scene(move_scene))
    return root


def _viewer(scene: Path):
    from neoedit.edit.refine import RefineConfig
    from neoedit.edit.remove import RemoveConfig
    from neoedit.edit.views import VirtualViewConfig
    from neoedit.viewer.app import ViewerServer
    from neoedit.viewer.state import ViewerConfig

    fast = RemoveConfig(refine=RefineConfig(steps=30, rounds=1), views=VirtualViewConfig(turns=1))
    cfg = ViewerConfig(query=SPARSE, remove=fast, loop=RenderLoopConfig(still_s=0.05))
    return ViewerServer(scene, "127.0.0.1", free_port(), "cpu", cfg, verbose=False)


def _first_views(sc: Scenario, first_train: int) -> np.ndarray:
    """Frustums, the first view, and a camera's image equal to the scene's own render."""
    from neoedit.cameras.rays import CameraTensors

    frustum = sc.page.wait_for(lambda m: m["type"] == "CameraFrustumMessage")
    assert frustum["name"].startswith("/scan/camera_")
    start = sc.page.wait_for(lambda m: m["type"] == "SetCameraPositionMessage" and m["initial"])
    first = sc.cameras.camera_to_world[first_train][:3, 3]
    assert np.allclose(start["position"], first, atol=1e-6)
    plain = sc.look()
    w, h = sc.size
    assert plain.shape == (h, w, 3)
    cams = CameraTensors(sc.cameras)
    ref = sc.viewer.state.scene.render_image(cams, sc.view, h, w)["rgb"].clamp(0, 1).numpy()
    assert pixel_diff(plain, (ref * 255).round()) < 0.01
    assert pixel_diff(sc.look(sc.away), plain) > 0.01  # another camera, another picture
    assert pixel_diff(sc.look(), plain) < 0.005
    return plain


def _queries(sc: Scenario, name: str, truth: Any, plain: np.ndarray) -> Any:
    """A prompt matching nothing says so; the object's name gives its box, the move gizmo
    and the relevancy heat map."""
    page, state = sc.page, sc.viewer.state
    page.set("prompt", "quantum chromodynamics lecture")
    mark = page.mark()
    page.click("Find")
    note = page.wait_for(lambda m: m["type"] == "NotificationShowMessage", mark)
    assert note["props"]["title"] == "no match"
    assert "no object matched" in note["props"]["body"]
    assert state.query_result is None
    page.image(mark)  # (re-rendered without any query)
    page.set("prompt", name)
    mark = page.mark()
    page.click("Find")
    box = page.wait_for(lambda m: m["type"] == "BoxMessage" and m["name"] == "/found/box", mark)
    page.wait_for(lambda m: m["type"] == "TransformControlsMessage", mark)
    found = state.query_result
    assert found is not None and found.prompt == name
    assert np.linalg.norm(np.subtract(found.box.center_m, truth.center_m)[:2]) < 0.05
    assert np.allclose(box["props"]["dimensions"], found.box.size_m, atol=1e-6)
    assert pixel_diff(page.image(mark), plain) > 0.02  # the heat map is drawn over the render
    return found


def _previews(sc: Scenario, found: Any, plain: np.ndarray) -> None:
    """Heat map off, the instant removal, depth, a PNG download, a move preview."""
    import imageio.v3 as iio

    from neoedit.geometry.masks import project_box_mask

    page, state = sc.page, sc.viewer.state
    assert pixel_diff(sc.after(lambda: page.set("relevancy heat-map", False)), plain) < 0.005
    removed = sc.after(lambda: page.click("Preview removal"))
    assert state.pending is not None and state.pending.kind == "remove"
    changed = np.abs(removed.astype(int) - plain.astype(int)).max(-1) > 25
    inside = project_box_mask(sc.cameras, sc.view, found.box)
    far = ~project_box_mask(sc.cameras, sc.view, found.box.grown(0.03))
    assert changed[inside].sum() >= 5  # the object is gone
    assert pixel_diff(removed, plain, far) < 0.005  # the rest is as it was
    depth = sc.after(lambda: page.set("show", "Depth"))
    assert pixel_diff(depth, removed) > 0.05 and depth.std() > 5
    assert pixel_diff(sc.after(lambda: page.set("show", "RGB")), removed) < 0.005
    mark = page.mark()
    page.click("Save view as PNG")
    download = page.wait_for(lambda m: m["type"] == "FileTransferStartDownload", mark)
    assert download["filename"].endswith(".png") and download["mime_type"] == "image/png"
    part = page.wait_for(lambda m: m["type"] == "FileTransferPart", mark)
    assert np.array_equal(np.asarray(iio.imread(part["content"]))[..., :3], removed)

    def move() -> None:
        page.set("translate (m)", [0.06, 0.0, 0.0])
        page.set("yaw (deg)", 30.0)
        page.click("Preview move")

    sc.after(move)
    until(lambda: state.pending is not None and state.pending.kind == "move")
    shift = np.subtract(state.pending.target.center_m, found.box.center_m)[:2]
    assert np.linalg.norm(shift - [0.06, 0.0]) < 0.03


def _commit(sc: Scenario) -> None:
    """The removal committed in full in the background: the page keeps rendering, the
    progress bar moves, the new version is listed, current and shown."""
    from neoedit.scene import load_scene
    from neoedit.storage import SceneStore

    page, viewer = sc.page, sc.viewer
    page.click("Preview removal")
    until(lambda: viewer.state.pending is not None and viewer.state.pending.kind == "remove")
    progress = page.wait_for(lambda m: m["type"] == "GuiProgressBarMessage")["uuid"]
    mark = page.mark()
    page.click("Commit")
    until(lambda: viewer._commit_thread is not None)
    thread = viewer._commit_thread
    until(lambda: viewer.state.committing or not thread.is_alive())
    moved = page.mark()
    page.look(sc.away, sc.fov, *sc.size)  # the page stays usable while the edit trains
    page.image(moved, full=False)
    assert thread.is_alive()  # the frame came while the edit was still training
    thread.join(900)
    assert not thread.is_alive()
    note = page.wait_for(
        lambda m: (
            m["type"] == "NotificationShowMessage"
            and m["props"]["title"] in ("committed", "commit failed")
        ),
        mark,
    )
    assert note["props"]["title"] == "committed", note["props"]["body"]
    bar = [
        m["updates"]["value"]
        for m in page.messages[mark:]
        if m["type"] == "GuiUpdateMessage" and m["uuid"] == progress and "value" in m["updates"]
    ]
    assert bar and max(bar) > 0  # the progress bar moved
    store = SceneStore(sc.store)
    assert store.names() == ["v0", "remove_1"] and store.current == "remove_1"
    assert viewer.state.selected == "remove_1" and viewer.state.pending is None
    assert load_scene(sc.store / "remove_1").meta.edits[-1].type == "remove"
    page.wait_for(
        lambda m: m["type"] == "GuiUpdateMessage" and "remove_1" in m["updates"].get("options", ()),
        mark,
    )
    # another version selected in the list is shown; restore makes it current
    page.set("version", "v0")
    until(lambda: viewer.state.selected == "v0")
    page.click("Make current (restore)")
    until(lambda: SceneStore(sc.store).current == "v0")


@pytest.mark.slow
def test_viewer_server_renders_queries_previews_and_commits(store: Path, sim_root: Path):
    pytest.importorskip("viser")
    pytest.importorskip("websockets")
    from neoedit.geometry import OrientedBox
    from neoedit.geometry.masks import project_box_mask
    from neoedit.scene import load_scene

    action = json.loads((sim_root / "pick_place_1" / "scene.json").read_text())["actions"][0]
    cameras, _, split = load_scene(store).scan_cameras()
    train = [int(i) for i in split["train"]]
    truth = OrientedBox.from_dict(action["source_box"])
    view = max(train, key=lambda i: int(project_box_mask(cameras, i, truth).sum()))
    away = cameras.camera_to_world[train[0] if view != train[0] else train[-1]]
    fov = 2 * math.atan(cameras.height[view] / (2 * cameras.fy[view]))
    viewer = _viewer(store)
    port = viewer.port
    page = Page(port)
    try:
        sc = Scenario(viewer, page, store, cameras, view, away, fov)
        plain = _first_views(sc, train[0])
        found = _queries(sc, action["object"], truth, plain)
        _previews(sc, found, plain)
        _commit(sc)
    finally:
        page.close()
        viewer.stop()
    # the port is free again
    with socket.socket() as sock:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind(("127.0.0.1", port))
    with pytest.raises(OSError):
        Page(port)


def test_viewer_on_a_plain_scene_folder_lists_one_version(move_scene: Path):
    from neoedit.errors import NeoError
    from neoedit.viewer.state import ViewerState

    state = ViewerState(move_scene, "cpu")
    versions = state.versions()
    assert [v.name for v in versions] == [move_scene.name] and versions[0].edit == "train"
    with pytest.raises(NeoError, match="plain scene folder"):
        state.restore(move_scene.name)
    with pytest.raises(NeoError, match="find an object first"):
        state.preview_remove()
    with pytest.raises(NeoError, match="nothing to commit"):
        state.commit()


def test_previews_are_sketches_whatever_the_commit_options(move_scene: Path):
    """The viewer's previews sketch the library's own edits: a move preview works with an
    option that only a committed move reads (``reuse_removal_patch``), and the version shown
    is never changed by a preview."""
    import dataclasses

    from test_language import SPARSE  # the tiny scan's sparse cloud: looser clustering

    from neoedit.edit.motion import MoveConfig
    from neoedit.viewer.state import ViewerConfig, ViewerState

    move = dataclasses.replace(MoveConfig(), reuse_removal_patch=True)
    cfg = ViewerConfig(query=SPARSE, move=move)
    state = ViewerState(move_scene, "cpu", cfg)
    state.query("red mug")
    shown = state.scene
    moves_before = list(shown.meta.moves)
    pending = state.preview_move(np.array([0.05, 0.0, 0.0]), 20.0)
    assert pending is not None and pending.kind == "move" and len(pending.scene.meta.moves) == 1
    assert pending.scene.field is shown.field and shown.meta.moves == moves_before
    removal = state.preview_remove()
    assert removal.scene.meta.cut_boxes and not shown.meta.cut_boxes


def test_view_command_without_viser_is_one_clear_error(monkeypatch, capsys, tmp_path: Path):
    import builtins

    from neoedit.cli import main

    real_import = builtins.__import__

    def no_viser(name, *args, **kwargs):
        if name == "viser" or name.startswith("viser."):
            raise ImportError("No module named 'viser'")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_viser)
    assert main(["view", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "pip install 'neoedit[viewer]'" in err
