"""Headless Chromium driven over its DevTools protocol (a websocket): start it on one page,
evaluate JavaScript, take screenshots. Used by ``benchmarks/check_viewer.py`` (the browser
check of ``neo view``) and its test.
"""

from __future__ import annotations

import base64
import io
import json
import os
import shutil
import subprocess
import time
import urllib.request
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")

# Headless Chromium has no GPU here: WebGL (three.js, viser's canvas) runs on SwiftShader
# through ANGLE, which Chromium only allows when told so (--enable-unsafe-swiftshader).
CHROMIUM_FLAGS = (
    "--headless=new",
    "--no-sandbox",  # root in a container
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
    "--hide-scrollbars",
    "--mute-audio",
    "--no-first-run",
    "--no-default-browser-check",
    "--disable-extensions",
    "--disable-background-networking",
    "--disable-dev-shm-usage",
)


def find_chromium(explicit: str | None = None) -> str | None:
    """The Chromium binary: ``explicit``, ``$CHROMIUM`` or the first of the usual names."""
    for name in (explicit, os.environ.get("CHROMIUM"), *CHROMIUM_NAMES):
        if name and (path := shutil.which(name)):
            return path
    return None


def until(pred: Callable[[], Any], timeout: float, what: str, step: float = 0.1) -> Any:
    deadline = time.monotonic() + timeout
    while not (value := pred()):
        if time.monotonic() > deadline:
            raise TimeoutError(f"timed out after {timeout:.0f} s waiting for {what}")
        time.sleep(step)
    return value


class Browser:
    """Headless Chromium with one page, driven over the DevTools protocol (a websocket)."""

    def __init__(self, binary: str, width: int, height: int, profile: Path):
        self.cmd = [
            binary,
            *CHROMIUM_FLAGS,
            f"--window-size={width},{height}",
            f"--user-data-dir={profile}",
            "--remote-debugging-port=0",
            "about:blank",
        ]
        self.log = open(profile.parent / "chromium.log", "wb")  # noqa: SIM115
        self.proc = subprocess.Popen(self.cmd, stdout=self.log, stderr=subprocess.STDOUT)
        self._id = 0
        self.ws: Any = None
        try:
            port_file = profile / "DevToolsActivePort"
            until(lambda: self._alive() and port_file.exists(), 60, "Chromium's DevTools port")
            port = int(until(lambda: port_file.read_text().split("\n")[0], 10, "the port"))
            with urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=10) as r:
                pages = [t for t in json.load(r) if t["type"] == "page"]
            from websockets.sync.client import connect

            self.ws = connect(pages[0]["webSocketDebuggerUrl"], max_size=None, open_timeout=30)
        except BaseException:
            self.close()
            raise

    def _alive(self) -> bool:
        if self.proc.poll() is not None:
            raise RuntimeError(f"Chromium exited ({self.proc.returncode}); see {self.log.name}")
        return True

    def call(self, method: str, timeout: float = 60.0, **params: Any) -> dict[str, Any]:
        self._id += 1
        self.ws.send(json.dumps({"id": self._id, "method": method, "params": params}))
        deadline = time.monotonic() + timeout
        while True:
            msg = json.loads(self.ws.recv(timeout=max(0.1, deadline - time.monotonic())))
            if msg.get("id") == self._id:
                if "error" in msg:
                    raise RuntimeError(f"{method}: {msg['error']}")
                return msg.get("result", {})

    def evaluate(self, js: str) -> Any:
        result = self.call("Runtime.evaluate", expression=js, returnByValue=True)
        return result.get("result", {}).get("value")

    def screenshot(self) -> np.ndarray:
        from PIL import Image

        data = base64.b64decode(self.call("Page.captureScreenshot", format="png")["data"])
        return np.asarray(Image.open(io.BytesIO(data)).convert("RGB"))

    def close(self) -> None:
        if self.ws is not None:
            try:
                self.call("Browser.close", timeout=5)
                self.ws.close()
            except Exception:  # (already gone)
                pass
        try:
            self.proc.wait(10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait(10)
        self.log.close()


JS_TEXT = "document.body ? document.body.innerText : ''"
JS_CLOSE_NOTES = """(() => { let n = 0;
  for (const b of document.querySelectorAll('.mantine-Notification-root button')) { b.click(); n++; }
  return n; })()"""
JS_FOCUS_PROMPT = """(() => {
  for (const el of document.querySelectorAll('label, div, p')) {
    if (el.childElementCount === 0 && el.textContent.trim() === 'prompt') {
      let row = el.parentElement;
      for (let i = 0; i < 4 && row; i++, row = row.parentElement) {
        const input = row.querySelector('input[type="text"], input:not([type]), textarea');
        if (input) { input.focus(); input.select(); return true; }
      }
    }
  }
  return false; })()"""
JS_CLICK = """((label) => {
  for (const b of document.querySelectorAll('button')) {
    if (b.textContent.trim() === label) { b.click(); return true; }
  }
  return false; })(%s)"""
