"""How responsive `neo view` is on this machine: first image, frames while moving, refinement.

    python benchmarks/bench_viewer.py --scene outputs/bench_speed/scene

Through the viewer's own state and render loop (no browser): time from opening the scene to
its first image, the frame rate and frame size while the camera moves (a scan camera
orbiting for 3 s, a new pose every 20 ms, as a drag sends them), and the time from the last
move to the full-resolution image at 320x240 and 640x480. Run alone on an idle machine.
"""

from __future__ import annotations

import argparse
import platform
import shlex
import sys
import threading
import time
from pathlib import Path

import numpy as np

from neoedit.viewer.render_loop import Frame, RenderLoop, ViewRequest
from neoedit.viewer.state import ViewerState


def orbit(c2w: np.ndarray, angle: float) -> np.ndarray:
    """``c2w`` turned by ``angle`` radians about the world z axis through the origin."""
    c, s = np.cos(angle), np.sin(angle)
    rot = np.eye(4)
    rot[:2, :2] = [[c, -s], [s, c]]
    return rot @ c2w


def run(state: ViewerState, c2w: np.ndarray, fov_y: float, width: int, height: int) -> dict:
    frames: list[tuple[float, Frame]] = []
    full = threading.Event()

    def on_frame(frame: Frame) -> None:
        frames.append((time.perf_counter(), frame))
        if frame.full:
            full.set()

    loop = RenderLoop(state.render, on_frame).start()
    try:
        t0 = time.perf_counter()
        loop.update(ViewRequest(c2w, fov_y, width, height), moving=False)
        full.wait(120)
        first = frames[0][0] - t0
        frames.clear()
        full.clear()
        t_move = time.perf_counter()
        while time.perf_counter() - t_move < 3.0:
            angle = 0.3 * (time.perf_counter() - t_move)
            loop.update(ViewRequest(orbit(c2w, angle), fov_y, width, height), moving=True)
            time.sleep(0.02)
        t_stop = time.perf_counter()
        moving = [f for t, f in frames if t <= t_stop and not f.full]
        full.wait(120)
        refined = next(t for t, f in frames if f.full and t > t_stop) - t_stop
    finally:
        loop.stop()
    size = f"{moving[-1].rgb.shape[1]}x{moving[-1].rgb.shape[0]}" if moving else "-"
    return {
        "size": f"{width}x{height}",
        "first_image_s": round(first, 2),
        "fps_moving": round(len(moving) / 3.0, 1),
        "moving_frame": size,
        "full_after_stop_s": round(refined, 2),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--scene", type=Path, required=True)
    args = parser.parse_args()
    print("$ python " + shlex.join(sys.argv))
    print(f"machine: {platform.machine()}, {time.strftime('%Y-%m-%d')}")
    t0 = time.perf_counter()
    state = ViewerState(args.scene, "cpu")
    view = state.scan_views(limit=1)[0]
    print(f"scene opened in {time.perf_counter() - t0:.2f} s")
    for width, height in ((320, 240), (640, 480)):
        print(run(state, view.c2w, view.fov_y, width, height), flush=True)


if __name__ == "__main__":
    main()
