"""The viewer's web page (viser): the wiring of :class:`~neoedit.viewer.state.ViewerState`
(what is shown) and one :class:`~neoedit.viewer.render_loop.RenderLoop` per open page
(streaming renders of its camera) to viser's scene and GUI.

The page: the render as the scene's background (with its depth, so the scan cameras'
frustums, the found box and the move gizmo sit in it), the versions (select, restore), a
query box, remove / move previews and a commit with its progress bar, RGB / depth and
relevancy toggles, the field of view and a PNG download of the view. Every callback runs
guarded: an error is a notification and a line in the page, never a dead server.
"""

from __future__ import annotations

import functools
import math
import threading
import time
import traceback
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any, Literal

import imageio.v3 as iio
import numpy as np
import torch
import viser

from neoedit.errors import NeoError
from neoedit.language.localize import NoMatch
from neoedit.utils.validate import shorten
from neoedit.viewer.panels import Panels
from neoedit.viewer.render_loop import Frame, RenderLoop, ViewRequest
from neoedit.viewer.state import ViewerConfig, ViewerState
from neoedit.viewer.view import ScanView, c2w_from_viser, viser_pose

FAR_M = 100.0
"""Depth given to background pixels where nothing is hit (behind every scene element)."""


def page_text(error: Exception) -> str:
    """An error as the page says it (plain text: the page does not read rich markup)."""
    if isinstance(error, OSError) and not isinstance(error, NeoError) and error.filename:
        return f"{error.strerror or error}: {error.filename}"
    return shorten(str(error), 2000)


class ClientView:
    """One open page: its render loop, fed by its camera, drawing its background."""

    def __init__(self, app: ViewerServer, client: viser.ClientHandle):
        self.app, self.client = app, client
        self.last: Frame | None = None
        self._last_error = ("", 0.0)
        self.loop = RenderLoop(self._render, self._show, app.state.cfg.loop, self._error)

    def _render(self, c2w: np.ndarray, fov_y: float, width: int, height: int):
        return self.app.state.render(c2w, fov_y, width, height, self.loop.should_stop)

    def _show(self, frame: Frame) -> None:
        image = (np.clip(frame.rgb, 0.0, 1.0) * 255).round().astype(np.uint8)
        depth = np.where(np.isfinite(frame.depth), frame.depth, FAR_M)
        fmt: Literal["png", "jpeg"] = "png" if frame.full else "jpeg"  # refined: lossless
        self.client.scene.set_background_image(image, format=fmt, depth=depth)
        self.last = frame

    def _error(self, error: Exception) -> None:
        text = page_text(error)
        if not isinstance(error, NeoError | OSError):
            traceback.print_exception(error)
            text = f"{type(error).__name__}: {text}"
        if self._last_error[0] == text and time.monotonic() - self._last_error[1] < 10:
            return  # the same failure on every frame: said once
        self._last_error = (text, time.monotonic())
        self.app.notify(self.client, "render failed", text, error=True)

    def request(self, moving: bool = True) -> None:
        """Render the page's camera now (``moving``: it is being moved)."""
        cam = self.client.camera
        w, h = int(cam.image_width), int(cam.image_height)
        if w <= 0 or h <= 0:
            return
        scale = min(1.0, self.app.state.cfg.max_side / max(w, h))
        size = (max(1, round(w * scale)), max(1, round(h * scale)))
        c2w = c2w_from_viser(cam.wxyz, cam.position)
        self.loop.update(ViewRequest(c2w, float(cam.fov), *size), moving)


class ViewerServer:
    """A viser server showing one scene (folder, store or store version) to every page
    that connects; bound to ``host`` (localhost by default)."""

    def __init__(
        self,
        scene: Path,
        host: str = "127.0.0.1",
        port: int = 8080,
        device: torch.device | str = "cpu",
        cfg: ViewerConfig | None = None,
        verbose: bool = True,
    ):
        self.state = ViewerState(Path(scene), device, cfg)
        self._views: dict[int, ClientView] = {}
        self._views_lock = threading.Lock()
        self._commit_thread: threading.Thread | None = None
        self._commit_start = threading.Lock()
        # a frame that finishes rendering after its tab closed is dropped, not worth a warning
        # (set once, process-wide: catch_warnings in the render threads would race)
        warnings.filterwarnings("ignore", "Queued a .* on a closed connection", UserWarning)
        self.server = viser.ViserServer(host=host, port=port, label="neo view", verbose=verbose)
        try:
            self.scan = self._scan_views()
            self._place_scan_cameras()
            self.panels = Panels(self)
            self.server.on_client_connect(self._connect)
            self.server.on_client_disconnect(self._disconnect)
        except BaseException:
            self.server.stop()
            raise

    # -- server ---------------------------------------------------------------------------
    @property
    def port(self) -> int:
        return self.server.get_port()

    @property
    def url(self) -> str:
        host = self.server.get_host()
        return f"http://{'localhost' if host == '0.0.0.0' else host}:{self.port}"

    def stop(self) -> None:
        """Stop every render loop and the server (its port is free again); a commit that is
        running is finished first (a version is never left half-written)."""
        commit = self._commit_thread
        if commit is not None and commit.is_alive():
            print("neo view: waiting for the running commit to finish ...", flush=True)
            commit.join()
        with self._views_lock:
            views, self._views = list(self._views.values()), {}
        for view in views:
            view.loop.stop()
        self.server.stop()

    def views(self) -> list[ClientView]:
        with self._views_lock:
            return list(self._views.values())

    def _connect(self, client: viser.ClientHandle) -> None:
        view = ClientView(self, client)
        with self._views_lock:
            self._views[client.client_id] = view
        view.loop.start()
        client.camera.on_update(self.guarded("camera")(lambda _: view.request(moving=True)))
        view.request(moving=False)

    def _disconnect(self, client: viser.ClientHandle) -> None:
        with self._views_lock:
            view = self._views.pop(client.client_id, None)
        if view is not None:
            view.loop.stop(timeout=0)

    def refresh(self) -> None:
        """Render every page again (the content or the display settings changed)."""
        for view in self.views():
            view.loop.refresh()

    # -- messages -------------------------------------------------------------------------
    def notify(
        self, client: viser.ClientHandle | None, title: str, body: str, error: bool = False
    ) -> None:
        """A notification on ``client``'s page (every page for None); errors stay until closed."""
        targets = [client] if client is not None else list(self.server.get_clients().values())
        for c in targets:
            try:
                if error:
                    c.add_notification(title, body, color="red")
                else:
                    c.add_notification(title, body, auto_close_seconds=6.0)
            except Exception:  # a page that just went away
                continue

    def guarded(self, title: str) -> Callable[[Callable[[Any], None]], Callable[[Any], None]]:
        """Decorator of page callbacks: a failure is said in the page, the server lives on."""

        def wrap(fn: Callable[[Any], None]) -> Callable[[Any], None]:
            @functools.wraps(fn)
            def run(event: Any) -> None:
                client = getattr(event, "client", None)
                try:
                    fn(event)
                except NoMatch as e:
                    self.panels.say(f"**No match.** {page_text(e)}")
                    self.notify(client, "no match", page_text(e), error=True)
                except (NeoError, OSError) as e:
                    self.panels.say(f"**{title} failed:** {page_text(e)}")
                    self.notify(client, f"{title} failed", page_text(e), error=True)
                except Exception as e:
                    traceback.print_exception(e)
                    text = f"{type(e).__name__}: {page_text(e)}"
                    self.panels.say(f"**{title} failed:** {text}")
                    self.notify(client, f"{title} failed", text, error=True)

            return run

        return wrap

    # -- cameras --------------------------------------------------------------------------
    def _scan_views(self) -> list[ScanView]:
        try:
            return self.state.scan_views()
        except NeoError as e:  # a scene whose cameras are gone still renders
            print(f"neo view: no scan cameras to show ({page_text(e)})")
            return []

    def _place_scan_cameras(self, limit: int = 64) -> None:
        """The scan's cameras as frustums (click one to look through it); the first view
        of every page is the first of them."""
        lo, hi = np.asarray(self.state.scene.meta.aabb_m, dtype=np.float64)
        self._center = (lo + hi) / 2
        scale = 0.03 * float(np.linalg.norm(hi - lo))
        step = max(1, math.ceil(len(self.scan) / limit))
        for view in self.scan[::step]:
            wxyz, position = viser_pose(view.c2w)
            frustum = self.server.scene.add_camera_frustum(
                f"/scan/camera_{view.index}",
                fov=view.fov_y,
                aspect=view.aspect,
                scale=scale,
                thickness=1.5,  # pixels: viser's default, 2 cm in the world, fills the view
                thickness_units="screen",  # from the first view (it sits in camera 0's frustum)
                color=(110, 110, 110),
                wxyz=wxyz,
                position=position,
            )
            on_click = functools.partial(self._frustum_clicked, view)
            frustum.on_click(self.guarded("camera")(on_click))
        if self.scan:
            first = self.scan[0]
            position, look_at = self._look(first)
            self.server.initial_camera.position = position
            self.server.initial_camera.look_at = look_at
            self.server.initial_camera.fov = first.fov_y

    def _look(self, view: ScanView) -> tuple[np.ndarray, np.ndarray]:
        """(position, look-at point on the optical axis, level with the scene's centre)."""
        position = view.c2w[:3, 3]
        forward = -view.c2w[:3, 2]
        distance = max(float((self._center - position) @ forward), 0.05)
        return position, position + forward * distance

    def _frustum_clicked(self, view: ScanView, event: Any) -> None:
        self.go_to(event.client, view)

    def go_to(self, client: viser.ClientHandle | None, view: ScanView) -> None:
        """Look through a scan camera (``client``'s page, every page for None)."""
        position, look_at = self._look(view)
        targets = [client] if client is not None else list(self.server.get_clients().values())
        for c in targets:
            with c.atomic():
                c.camera.fov = view.fov_y
                c.camera.position = position
                c.camera.look_at = look_at

    def set_fov(self, fov_deg: float) -> None:
        for c in self.server.get_clients().values():
            c.camera.fov = math.radians(fov_deg)

    # -- snapshots and commits --------------------------------------------------------------
    def snapshot_png(self, client_id: int | None = None) -> bytes:
        """The image last shown on a page (the first one for None), as PNG bytes."""
        views = self.views()
        view = next((v for v in views if client_id in (None, v.client.client_id)), None)
        if view is None or view.last is None:
            raise NeoError("nothing has been rendered yet")
        image = (np.clip(view.last.rgb, 0.0, 1.0) * 255).round().astype(np.uint8)
        return iio.imwrite("<bytes>", image, extension=".png")

    def commit(self, wait: bool = False) -> threading.Thread:
        """Run the pending edit in full in the background (the page stays usable); the new
        version is shown when it is written."""
        with self._commit_start:  # two quick clicks start one commit
            running = self._commit_thread is not None and self._commit_thread.is_alive()
            if running or self.state.committing:
                raise NeoError("a commit is already running: wait for it to finish")
            if self.state.pending is None:
                raise NeoError("nothing to commit: preview a removal or a move first")
            thread = threading.Thread(target=self.panels.run_commit, name="neo-commit", daemon=True)
            self._commit_thread = thread
            thread.start()
        if wait:
            thread.join()
        return thread


def serve(
    scene: Path,
    host: str = "127.0.0.1",
    port: int = 8080,
    device: torch.device | str = "cpu",
    cfg: ViewerConfig | None = None,
    ready: Callable[[ViewerServer], None] | None = None,
) -> None:
    """Serve the viewer until interrupted (Ctrl-C)."""
    app = ViewerServer(scene, host, port, device, cfg)
    try:
        if ready is not None:
            ready(app)
        while True:
            time.sleep(1.0)
    finally:
        app.stop()
