"""Helpers of the viewer tests: a stand-in for the browser page that speaks viser's
websocket protocol, and the scenario a server test walks through."""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np


class Page:
    """A stand-in for the browser page: viser's websocket protocol (msgpack messages up;
    windows of zstd-compressed msgpack down)."""

    def __init__(self, port: int):
        import viser
        from websockets.sync.client import connect

        self.ws = connect(
            f"ws://127.0.0.1:{port}",
            subprotocols=[f"viser-v{viser.__version__}"],
            max_size=None,
            open_timeout=30,
        )
        self.messages: list[dict[str, Any]] = []
        self._cond = threading.Condition()
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        import msgspec
        import zstandard

        unzip = zstandard.ZstdDecompressor()
        try:
            while True:
                raw = self.ws.recv()
                size = int.from_bytes(raw[:8], "little")
                packed = int.from_bytes(raw[8:16], "little")
                window = msgspec.msgpack.decode(
                    unzip.decompress(raw[16 : 16 + packed], max_output_size=size)
                )
                with self._cond:
                    self.messages.extend(window["messages"])
                    self._cond.notify_all()
        except Exception:  # closed
            return

    def send(self, message: Any) -> None:
        import msgspec

        self.ws.send(msgspec.msgpack.encode(message.as_serializable_dict()))

    def mark(self) -> int:
        with self._cond:
            return len(self.messages)

    def wait_for(
        self, pred: Callable[[dict[str, Any]], bool], since: int = 0, timeout: float = 120.0
    ) -> dict[str, Any]:
        def found():
            return next((m for m in self.messages[since:] if pred(m)), None)

        with self._cond:
            assert self._cond.wait_for(lambda: found() is not None, timeout), (
                f"no such message; got {[m['type'] for m in self.messages[since:]]}"
            )
            return found()  # type: ignore[return-value]

    def image(self, since: int, full: bool = True, quiet_s: float = 1.0) -> np.ndarray:
        """The background image the page settles on after message ``since``: the last
        refined (lossless) one once no new image came for ``quiet_s``; with ``full`` False,
        the first image of any kind."""
        import imageio.v3 as iio

        def background(m: dict[str, Any]) -> bool:
            return m["type"] == "BackgroundImageMessage" and m["rgb_data"] is not None

        msg = self.wait_for(lambda m: background(m) and (m["format"] == "png" or not full), since)
        while full:
            n = self.mark()
            time.sleep(quiet_s)
            with self._cond:
                later = [m for m in self.messages[n:] if background(m)]
            if not later:
                break
            msg = next((m for m in reversed(later) if m["format"] == "png"), msg)
        assert msg["depth_data"] is not None  # the render's depth, for compositing
        return np.asarray(iio.imread(msg["rgb_data"]))[..., :3]

    def uuid(self, label: str, kind: str | None = None) -> str:
        """The id of the control labelled ``label`` (of message type ``kind``)."""
        msg = self.wait_for(
            lambda m: (
                "uuid" in m
                and "value" in m  # an input, not a folder
                and m.get("props", {}).get("label") == label
                and kind in (None, m["type"])
            )
        )
        return msg["uuid"]

    def set(self, label: str, value: Any, kind: str | None = None) -> None:
        from viser._messages import GuiUpdateMessage

        self.send(GuiUpdateMessage(self.uuid(label, kind), {"value": value}))

    def click(self, label: str) -> None:
        self.set(label, True, "GuiButtonMessage")

    def look(self, c2w_gl: np.ndarray, fov_y: float, width: int, height: int) -> None:
        """Move the page's camera (OpenCV pose, as the browser reports it)."""
        from viser._messages import ViewerCameraMessage

        from neoedit.viewer.view import viser_pose

        wxyz, position = viser_pose(c2w_gl)
        look_at = position - c2w_gl[:3, 2]
        self.send(
            ViewerCameraMessage(
                tuple(wxyz),
                tuple(position),
                fov_y,
                0.01,
                1000.0,
                height,
                width,
                tuple(look_at),
                (0.0, 0.0, 1.0),
            )  # fmt: skip
        )

    def close(self) -> None:
        self.ws.close()
        self._reader.join(5)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def until(pred: Callable[[], bool], timeout: float = 120.0) -> None:
    deadline = time.monotonic() + timeout
    while not pred():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.05)


def pixel_diff(a: np.ndarray, b: np.ndarray, mask: np.ndarray | None = None) -> float:
    d = np.abs(a.astype(np.float64) - b.astype(np.float64)).mean(-1) / 255
    return float(d[mask].mean() if mask is not None else d.mean())


@dataclass
class Scenario:
    """A running viewer, a page connected to it and the scan camera the page looks through
    (the one that sees the object best)."""

    viewer: Any
    page: Page
    store: Path
    cameras: Any
    view: int
    away: np.ndarray  # another scan camera
    fov: float

    @property
    def size(self) -> tuple[int, int]:
        return int(self.cameras.width[self.view]), int(self.cameras.height[self.view])

    def look(self, c2w: np.ndarray | None = None) -> np.ndarray:
        """Point the page's camera (the chosen view by default); the image it settles on."""
        mark = self.page.mark()
        c2w = self.cameras.camera_to_world[self.view] if c2w is None else c2w
        self.page.look(c2w, self.fov, *self.size)
        return self.page.image(mark)

    def after(self, action: Callable[[], None]) -> np.ndarray:
        """Do ``action`` in the page; the image the page settles on after it."""
        mark = self.page.mark()
        action()
        return self.page.image(mark)
