"""`neo view` in a real browser: headless Chromium opens the page of a tiny trained scene and
its screenshot must show the render the server sent (benchmarks/check_viewer.py). Skipped
when no Chromium binary is installed (``apt-get install chromium``)."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "benchmarks" / "check_viewer.py"


def _check_viewer():
    spec = importlib.util.spec_from_file_location("check_viewer", SCRIPT)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


check_viewer = _check_viewer()


def test_a_blank_or_other_canvas_fails_the_screenshot_comparison():
    from PIL import Image

    cv = check_viewer
    y, x = np.mgrid[0:40, 0:64] / 16.0
    wave = np.stack([np.sin(np.pi * x), np.cos(np.pi * y), np.sin(np.pi * (x + y))], -1)
    sent = ((wave + 1) * 127.5).astype(np.uint8)  # the image the server sent
    shown = np.asarray(Image.fromarray(sent).resize((1280, 800), Image.BILINEAR))  # the canvas
    assert cv.passed(cv.compare(shown, sent))
    blank = np.full_like(shown, 255)
    figures = cv.compare(blank, sent)
    assert not cv.passed(figures) and figures["shot_std"] < 1
    assert not cv.passed(cv.compare(np.roll(shown, 320, axis=1), sent))


@pytest.mark.slow
@pytest.mark.skipif(
    check_viewer.find_chromium() is None,
    reason="no Chromium binary (apt-get install chromium): the browser check did not run",
)
def test_the_page_shows_the_scene_in_headless_chromium(trained: Path, tmp_path: Path):
    pytest.importorskip("viser")
    pytest.importorskip("websockets")
    out = tmp_path / "page.png"
    cmd = [sys.executable, str(SCRIPT), "--scene", str(trained), "--out", str(out)]
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout[-4000:] + proc.stderr[-4000:]
    assert proc.stdout.rstrip().endswith("PASS")
    assert out.stat().st_size > 10_000
