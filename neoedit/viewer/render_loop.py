"""Streaming renders of one interactive view that stay responsive on a CPU.

A small state machine in a background thread (the scheme of nerfstudio's viewer):

* **moving** - the camera changed less than ``still_s`` ago: every new camera is rendered
  at a low resolution, sized from the measured rays/s so that a frame takes about
  ``1 / target_fps`` seconds;
* **still** - no camera change for ``still_s``: the view is refined, rendered once at full
  resolution;
* a camera change that arrives while a refinement runs makes it stale: the render function
  polls :meth:`RenderLoop.should_stop` (between ray chunks) and raises
  :class:`RenderInterrupted`, and a stale full-resolution frame is never shown.

The loop knows nothing of scenes or of the web page: it is given
``render(c2w, fov_y_rad, width, height) -> (rgb (H,W,3) float, depth (H,W))`` and
``on_frame(frame)``; every render error goes to ``on_error`` and the loop carries on.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from neoedit.utils.threads import apply_thread_budget

RenderFn = Callable[[np.ndarray, float, int, int], tuple[np.ndarray, np.ndarray]]
"""(camera-to-world (4,4) OpenGL, vertical field of view [rad], width, height) ->
(rgb (H,W,3) float in [0,1], depth (H,W) [m])."""


class RenderInterrupted(Exception):
    """Raised by a render function that noticed (``should_stop()``) its view went stale."""


@dataclass(frozen=True)
class ViewRequest:
    """A view to render: camera pose (OpenGL convention), vertical field of view and the
    full-resolution image size."""

    c2w: np.ndarray = field(repr=False)
    fov_y: float
    width: int
    height: int


@dataclass
class Frame:
    rgb: np.ndarray = field(repr=False)
    depth: np.ndarray = field(repr=False)
    width: int
    height: int
    full: bool
    """Rendered at the request's full resolution (a refinement, or a fast enough view)."""
    serial: int
    """Which request (camera or content change) this frame shows."""
    seconds: float


@dataclass
class RenderLoopConfig:
    target_fps: float = 10.0
    """Frame rate the low-resolution renders aim at while the camera moves."""
    still_s: float = 0.25
    """Seconds without a camera change before the view is refined to full resolution."""
    min_side: int = 24
    """Smallest short side of a low-resolution frame (pixels)."""
    initial_rays_per_s: float = 50_000.0
    """Speed assumed before the first render was measured."""
    smoothing: float = 0.5
    """Weight of the newest measurement in the running rays/s estimate."""


def low_resolution(
    width: int, height: int, rays_per_s: float, cfg: RenderLoopConfig
) -> tuple[int, int]:
    """(w, h) of a moving frame: the aspect of (width, height), about ``rays_per_s /
    target_fps`` pixels, at least ``min_side`` on the short side, at most the full size."""
    budget = max(rays_per_s, 1.0) / max(cfg.target_fps, 1e-3)
    scale = math.sqrt(budget / max(width * height, 1))
    scale = max(scale, cfg.min_side / max(min(width, height), 1))
    if scale >= 1.0:
        return width, height
    return max(1, round(width * scale)), max(1, round(height * scale))


class RenderLoop:
    """Renders the latest :class:`ViewRequest` in a background thread (see the module)."""

    def __init__(
        self,
        render: RenderFn,
        on_frame: Callable[[Frame], None],
        cfg: RenderLoopConfig | None = None,
        on_error: Callable[[Exception], None] | None = None,
        clock: Callable[[], float] = time.monotonic,
        timer: Callable[[], float] = time.perf_counter,
    ):
        self.cfg = cfg or RenderLoopConfig()
        self._render, self._on_frame, self._on_error = render, on_frame, on_error
        self._clock, self._timer = clock, timer
        self._cond = threading.Condition()
        self._request: ViewRequest | None = None
        self._serial = 0
        self._moved_at = -math.inf
        self._low_done = 0  # serial whose low-resolution frame was rendered
        self._full_done = 0  # serial whose full-resolution frame was rendered (or failed)
        self._refining: int | None = None  # serial of the refinement running now
        self._stopped = False
        self._idle = False  # the thread waits with nothing it could render now
        self._rays_per_s = float(self.cfg.initial_rays_per_s)
        self.interrupted = 0
        """Refinements abandoned because the view changed."""
        self._thread = threading.Thread(target=self._run, name="neo-render-loop", daemon=True)

    # -- what the page tells the loop -----------------------------------------------------
    def start(self) -> RenderLoop:
        self._thread.start()
        return self

    def update(self, request: ViewRequest, moving: bool = True) -> int:
        """A new camera (``moving``: the user is moving it; False: a jump to a still view).
        Returns the request's serial."""
        with self._cond:
            self._request = request
            self._serial += 1
            self._idle = False
            if moving:
                self._moved_at = self._clock()
            self._cond.notify_all()
            return self._serial

    def refresh(self) -> int:
        """Same camera, new content (another version, a preview, a display setting)."""
        with self._cond:
            self._serial += 1
            self._idle = False
            self._cond.notify_all()
            return self._serial

    def should_stop(self) -> bool:
        """True while a refinement runs whose view is stale (or the loop is stopping): the
        render function should raise :class:`RenderInterrupted`."""
        with self._cond:
            return self._stopped or (self._refining is not None and self._refining != self._serial)

    def stop(self, timeout: float = 10.0) -> None:
        with self._cond:
            self._stopped = True
            self._cond.notify_all()
        if self._thread.is_alive() and threading.current_thread() is not self._thread:
            self._thread.join(timeout)

    def wait_idle(self, timeout: float = 30.0) -> bool:
        """Block until the loop has rendered everything it can now (it waits for a new
        camera, or for the camera to be still long enough to refine); False on timeout."""
        with self._cond:
            return self._cond.wait_for(lambda: self._idle or self._stopped, timeout)

    @property
    def serial(self) -> int:
        with self._cond:
            return self._serial

    @property
    def rays_per_s(self) -> float:
        with self._cond:
            return self._rays_per_s

    # -- the thread -----------------------------------------------------------------------
    def _next_job(self) -> tuple[int, ViewRequest, bool] | None:
        """Block until there is work: (serial, request, refinement?); None when stopped."""
        with self._cond:
            while not self._stopped:
                req, serial = self._request, self._serial
                if req is not None and self._low_done < serial:
                    self._low_done = serial
                    return serial, req, False
                if req is not None and self._full_done < serial:
                    wait_s = self._moved_at + self.cfg.still_s - self._clock()
                    if wait_s <= 0:
                        self._full_done = serial
                        self._refining = serial
                        return serial, req, True
                    self._wait(min(wait_s, 0.1))  # re-read the clock (it may be a test's)
                    continue
                self._wait(None)
            return None

    def _wait(self, timeout: float | None) -> None:
        """Wait for work (the lock held), telling :meth:`wait_idle` the loop is idle."""
        self._idle = True
        self._cond.notify_all()
        self._cond.wait(timeout)

    def _run(self) -> None:
        apply_thread_budget()
        while (job := self._next_job()) is not None:
            serial, req, refine = job
            w, h = (req.width, req.height)
            if not refine:
                w, h = low_resolution(req.width, req.height, self.rays_per_s, self.cfg)
            try:
                t = self._timer()
                rgb, depth = self._render(req.c2w, req.fov_y, w, h)
                seconds = self._timer() - t
            except RenderInterrupted:
                with self._cond:
                    self._refining = None
                    self.interrupted += 1
                continue
            except Exception as e:  # shown in the page; the loop keeps serving
                with self._cond:
                    self._refining = None
                    self._full_done = max(self._full_done, serial)  # no retry of a failing view
                if self._on_error is not None:
                    self._on_error(e)
                continue
            at_full = (w, h) == (req.width, req.height)
            self._publish(Frame(rgb, depth, w, h, at_full, serial, seconds), refinement=refine)

    def _publish(self, frame: Frame, refinement: bool) -> None:
        with self._cond:
            self._refining = None
            if frame.seconds > 0:
                measured = frame.width * frame.height / frame.seconds
                a = self.cfg.smoothing
                self._rays_per_s = a * measured + (1 - a) * self._rays_per_s
            if frame.full and frame.serial == self._serial:
                self._full_done = max(self._full_done, frame.serial)  # nothing left to refine
            stale = refinement and frame.serial != self._serial
        if stale:  # (a low-resolution frame of a moving camera is the best there is: shown)
            return
        try:
            self._on_frame(frame)
        except Exception as e:  # e.g. the page went away: report, keep serving
            if self._on_error is not None:
                self._on_error(e)
