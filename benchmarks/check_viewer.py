"""Browser check of `neo view`: headless Chromium opens the page; its screenshot must show the
scene's render, not a blank canvas.

    python benchmarks/check_viewer.py                 # a tiny scene made here first (~30 s)
    python benchmarks/check_viewer.py --scene outputs/demo/plan/step_0 --query mug \
        --out docs/viewer.png                         # the README's picture (after make demo)

Needs a Chromium binary (Debian: ``apt-get install chromium``; or ``--chromium PATH`` /
``$CHROMIUM``). Without ``--scene`` a tiny NEO-Sim scene is simulated and trained for 300
steps in a temporary folder. The viewer is served in this process (as ``neo view`` serves
it, on a free port of 127.0.0.1); Chromium (headless, WebGL on SwiftShader) is driven over
its DevTools protocol: it opens the page, the check waits until the page's camera is the
first scan camera and the viewer has sent its refined image, then takes screenshots (polled
at growing intervals, not one fixed sleep) until one shows that image. ``--query`` types a
prompt into the page's query box and clicks Find (heat map, box and gizmo in the picture).

PASS when the canvas left of the side panel matches the image the server sent (mean
absolute difference < 0.05, > 85 % of the pixels within 10 %) and is not flat (standard
deviation > 5 of 255), the page's first view is the first scan camera, the side panel lists
the version and the query box, and the port is free again once the server stopped. Prints
the figures; exits 1 on FAIL. The screenshot is saved (``--out``, default
outputs/check_viewer.png).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import shlex
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))  # its sibling module, run as a script
from headless_chromium import (  # noqa: E402
    CHROMIUM_FLAGS,
    JS_CLICK,
    JS_CLOSE_NOTES,
    JS_FOCUS_PROMPT,
    JS_TEXT,
    Browser,
    find_chromium,
    until,
)

T_START = time.perf_counter()

# the part of the canvas compared (fractions of the window): left of the side panel, clear
# of the notifications (top left), the axes gizmo (bottom left) and the frustum of the
# first scan camera (the page's first view looks out of it: its edges frame the window)
REGION = (0.12, 0.15, 0.70, 0.85)  # x0, y0, x1, y1


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


# -- a tiny scene ---------------------------------------------------------------------------


def make_tiny_scene(root: Path, steps: int = 300) -> Path:
    """A tiny pick-and-place NEO-Sim scan (10 views at 96x72) trained for ``steps`` steps
    with the test suite's tiny field (tests/conftest.py); returns the scene folder."""
    from neoedit.fields.hashgrid import HashGridConfig
    from neoedit.fields.radiance import RadianceFieldConfig
    from neoedit.rendering.occupancy import OccupancyGridConfig
    from neoedit.rendering.renderer import RenderConfig
    from neoedit.sim.run import simulate_scene
    from neoedit.sim.spec import ScanSpec
    from neoedit.sim.suite import benchmark_scenes
    from neoedit.training.trainer import TrainConfig, train

    spec = next(s for s in benchmark_scenes("small", seed=0) if s.name == "pick_place_1")
    spec = dataclasses.replace(spec, scan=ScanSpec(width=96, height=72, n_train=10, n_eval=2))
    simulate_scene(spec, root / "sim")
    field = RadianceFieldConfig(
        hashgrid=HashGridConfig(n_levels=8, log2_hashmap_size=14, max_resolution=256),
        hidden_dim=32,
        hidden_dim_color=32,
    )
    cfg = TrainConfig(
        max_steps=steps, rays_per_batch=1024, eval_every=0, checkpoint_every=0, lr=2e-2
    )
    train(
        root / "sim" / "pre",
        root / "scene",
        cfg,
        field,
        RenderConfig(n_march_samples=192, n_coarse_samples=48, n_samples=24),
        OccupancyGridConfig(resolution=48, warmup_steps=32),
        device="cpu",
    )
    return root / "scene"


# -- the check ------------------------------------------------------------------------------


def region(image: np.ndarray) -> np.ndarray:
    h, w = image.shape[:2]
    x0, y0, x1, y1 = REGION
    return image[round(y0 * h) : round(y1 * h), round(x0 * w) : round(x1 * w)]


def compare(shot: np.ndarray, frame: np.ndarray) -> dict[str, float]:
    """The screenshot against the image the server sent (scaled to the window, as the
    canvas shows it), over :data:`REGION`."""
    from PIL import Image

    h, w = shot.shape[:2]
    sent = np.asarray(Image.fromarray(frame).resize((w, h), Image.BILINEAR))
    a, b = region(shot).astype(np.float64) / 255, region(sent).astype(np.float64) / 255
    diff = np.abs(a - b).max(-1)
    return {
        "mean_abs_diff": float(np.abs(a - b).mean()),
        "within_10pct": float((diff < 0.1).mean()),
        "shot_std": float(a.std() * 255),
        "sent_std": float(b.std() * 255),
    }


def passed(f: dict[str, float]) -> bool:
    return f["mean_abs_diff"] < 0.05 and f["within_10pct"] > 0.85 and f["shot_std"] > 5.0


def settled_frame(app: Any, since: int, quiet_s: float, timeout: float) -> Any:
    """The page's last refined frame of a request after ``since``, once no new frame came
    for ``quiet_s``."""
    deadline = time.monotonic() + timeout
    seen: tuple[Any, float] | None = None
    while time.monotonic() < deadline:
        views = app.views()
        last = views[0].last if views else None
        if last is not None and last.full and last.serial > since:
            if seen is None or seen[0] is not last:
                seen = (last, time.monotonic())
            elif time.monotonic() - seen[1] >= quiet_s:
                return last
        time.sleep(0.05)
    raise TimeoutError(f"no refined frame of the page within {timeout:.0f} s")


def as_uint8(frame: Any) -> np.ndarray:
    return (np.clip(frame.rgb, 0.0, 1.0) * 255).round().astype(np.uint8)


def type_query(app: Any, browser: Browser, prompt: str, since: int, timeout: float) -> Any:
    """Type ``prompt`` into the page's query box and click Find, as a user does; the
    refined frame with the query's heat map."""
    if not browser.evaluate(JS_FOCUS_PROMPT):
        raise RuntimeError("no 'prompt' text box in the page")
    browser.call("Input.insertText", text=prompt)
    until(lambda: app.panels.prompt.value == prompt, 10, "the prompt to reach the server")
    if not browser.evaluate(JS_CLICK % json.dumps("Find")):
        raise RuntimeError("no 'Find' button in the page")
    t0 = time.perf_counter()
    until(lambda: app.state.query_result is not None, timeout, f"the query {prompt!r}")
    frame = settled_frame(app, since, 1.0, timeout)
    score = app.state.query_result.score
    print(
        f"typed {prompt!r} and clicked Find: found in {time.perf_counter() - t0:.1f} s "
        f"(score {score:.2f})"
    )
    return frame


def poll_screenshot(
    app: Any, browser: Browser, frame: Any, timeout: float
) -> tuple[np.ndarray, dict[str, float], int]:
    """Screenshots at growing intervals until one shows the image the server sent."""
    if browser.evaluate(JS_CLOSE_NOTES):  # the 'software WebGL' notice covers the canvas
        time.sleep(1.0)  # (it slides out)
    deadline, wait, tries = time.monotonic() + timeout, 0.25, 0
    while True:
        tries += 1
        views = app.views()
        last = views[0].last if views else None
        if last is not None and last.full:
            frame = last  # (the newest refined image)
        shot = browser.screenshot()
        figures = compare(shot, as_uint8(frame))
        if passed(figures) or time.monotonic() + wait > deadline:
            return shot, figures, tries
        time.sleep(wait)
        wait = min(2 * wait, 4.0)


def save_png(image: np.ndarray, path: Path) -> None:
    from PIL import Image

    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(image).save(path, optimize=True)


def _serves(url: str) -> bool:
    try:
        with urllib.request.urlopen(url, timeout=2) as r:
            return r.status == 200
    except OSError:
        return False


def _released(port: int) -> bool:
    with socket.socket() as sock:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            sock.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


def _first_view(app: Any) -> float:
    """Distance (m) from the page's camera to the first scan camera (the page's first view)."""
    views = app.views()
    if not views or not app.scan:
        return 0.0 if views else float("nan")  # (a scene without scan cameras: any view)
    position = np.asarray(views[0].client.camera.position, dtype=np.float64)
    return float(np.linalg.norm(position - app.scan[0].c2w[:3, 3]))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--scene", type=Path, help="a trained scene (default: a tiny one)")
    parser.add_argument("--out", type=Path, default=Path("outputs/check_viewer.png"))
    parser.add_argument("--query", help="type this prompt into the page and click Find")
    parser.add_argument("--size", type=int, nargs=2, default=(1280, 800), metavar=("W", "H"))
    parser.add_argument("--max-side", type=int, default=640, help="as neo view --max-side")
    parser.add_argument("--chromium", help="Chromium binary (default: $CHROMIUM or on PATH)")
    parser.add_argument("--timeout", type=float, default=180.0, help="for each wait (s)")
    args = parser.parse_args(argv)
    print("$ python " + shlex.join(["benchmarks/check_viewer.py", *(argv or sys.argv[1:])]))
    binary = find_chromium(args.chromium)
    if binary is None:
        print("FAIL: no Chromium binary (apt-get install chromium, or --chromium PATH)")
        return 1
    version = subprocess.run([binary, "--version"], capture_output=True, text=True).stdout
    print(f"browser: {version.strip()} ({binary}) {' '.join(CHROMIUM_FLAGS)}")
    try:
        ok = check(args, binary)
    except Exception as e:  # a timeout, Chromium gone, the page without its controls
        print(f"FAIL: {type(e).__name__}: {e}")
        ok = False
    print(f"wall time: {time.perf_counter() - T_START:.1f} s")
    print("PASS" if ok else "FAIL")
    return 0 if ok else 1


def check(args: argparse.Namespace, binary: str) -> bool:
    from neoedit.utils.threads import configure_threads
    from neoedit.viewer.app import ViewerServer
    from neoedit.viewer.state import ViewerConfig

    configure_threads()  # as every neo verb does
    with tempfile.TemporaryDirectory(prefix="check_viewer_") as tmp_str:
        tmp = Path(tmp_str)
        scene = args.scene
        if scene is None:
            t0 = time.perf_counter()
            scene = make_tiny_scene(tmp / "tiny")
            print(f"tiny scene simulated and trained in {time.perf_counter() - t0:.1f} s")
        t0 = time.perf_counter()
        port = free_port()
        cfg = ViewerConfig(max_side=args.max_side)
        app = ViewerServer(scene, "127.0.0.1", port, "cpu", cfg, verbose=False)
        browser = None
        try:
            url = app.url
            until(lambda: _serves(url), 30, f"the page at {url}")
            print(f"neo view {scene} served at {url} in {time.perf_counter() - t0:.1f} s")
            profile = tmp / "profile"
            profile.mkdir()
            browser = Browser(binary, *args.size, profile)
            t_page = time.perf_counter()
            browser.call("Page.enable")
            browser.call(  # the page exactly W x H (a headless window's viewport is smaller)
                "Emulation.setDeviceMetricsOverride",
                width=args.size[0],
                height=args.size[1],
                deviceScaleFactor=1,
                mobile=False,
            )
            browser.call("Page.navigate", url=url + "/")
            until(app.views, args.timeout, "the page to connect")
            # the page first reports viser's default camera (5 m out on -x), then the
            # initial one the viewer sets (the first scan camera): wait for that one
            until(lambda: _first_view(app) < 1e-3, args.timeout, "the first scan camera")
            frame = settled_frame(app, app.views()[0].loop.serial - 1, 1.0, args.timeout)
            print(
                f"page connected; refined {frame.width}x{frame.height} image sent "
                f"{time.perf_counter() - t_page:.1f} s after opening the page"
            )
            if args.query:
                frame = type_query(app, browser, args.query, frame.serial, args.timeout)
            t_shot = time.perf_counter()
            shot, figures, tries = poll_screenshot(app, browser, frame, min(args.timeout, 60.0))
            print(
                f"screenshots: {tries} in {time.perf_counter() - t_shot:.1f} s "
                f"({args.size[0]}x{args.size[1]})"
            )
            text = browser.evaluate(JS_TEXT) or ""
            first_view_m = _first_view(app)
        finally:
            if browser is not None:
                browser.close()
            app.stop()
        released = _released(port)

    save_png(shot, args.out)
    print(f"screenshot: {args.out} ({args.out.stat().st_size / 1024:.0f} kB)")
    print(
        "canvas vs the image the server sent (left of the panel): "
        f"mean abs diff {figures['mean_abs_diff']:.3f} (< 0.05), "
        f"pixels within 10 % {figures['within_10pct']:.3f} (> 0.85), "
        f"std {figures['shot_std']:.1f} (> 5; sent image {figures['sent_std']:.1f})"
    )
    camera_ok = first_view_m < 1e-3
    panel_ok = all(word in text for word in (app.state.selected, "Versions", "Query", "Find"))
    print(
        f"first view at the first scan camera: {camera_ok} ({first_view_m:.1e} m); side panel "
        f"lists {app.state.selected!r}, Versions, Query, Find: {panel_ok}; "
        f"port {port} released: {released}"
    )
    return passed(figures) and camera_ok and panel_ok and released


if __name__ == "__main__":
    sys.exit(main())
