"""``neo view``: a web viewer of a scene's versions (needs ``pip install 'neoedit[viewer]'``)."""

from __future__ import annotations

import dataclasses
import socket
from dataclasses import dataclass
from pathlib import Path

import tyro
from rich.console import Console
from rich.markup import escape

from neoedit.edit.relocate import MoveConfig
from neoedit.edit.remove import RemoveConfig
from neoedit.errors import NeoError
from neoedit.language.localize import QueryConfig
from neoedit.viewer.render_loop import RenderLoopConfig

console = Console()

LOCAL_HOSTS = ("127.0.0.1", "localhost", "::1")


@dataclass
class ViewCommand:
    """Serve a web page (viser) showing a scene: orbit the render (low resolution while the
    camera moves, refined when it stops), pick any version of a store and make it current,
    find an object by name (relevancy heat map + box), preview its removal or a move (drag
    the gizmo) at once, and commit the full edit as a new version with a progress bar. The
    page is served on localhost only unless --host says otherwise."""

    scene: tyro.conf.Positional[Path]
    """Scene folder, scene store (its current version first) or store version."""
    host: str = "127.0.0.1"
    """Address to listen on (127.0.0.1: this machine only; 0.0.0.0: every network)."""
    port: int = 8080
    """Port of the page (the next free one if it is taken)."""
    max_side: int = 640
    """Longest side of a refined frame in pixels (the page's size, scaled down to this)."""
    fps: float = 10.0
    """Frame rate aimed at while the camera moves (sets the low resolution)."""
    query: QueryConfig = dataclasses.field(default_factory=QueryConfig)
    remove: RemoveConfig = dataclasses.field(default_factory=RemoveConfig)
    """How a committed removal is made (as neo remove)."""
    move: MoveConfig = dataclasses.field(default_factory=MoveConfig)
    """How a committed move is made (as neo move)."""
    device: str = "auto"

    def run(self) -> None:
        self.query.check()  # before any loading or training
        from neoedit.utils.device import resolve_device
        from neoedit.viewer import require_viser, serve
        from neoedit.viewer.state import ViewerConfig

        require_viser()
        if not 1 <= self.port <= 65535:
            raise NeoError(f"--port must be in 1..65535, got {self.port}")
        if not 16 <= self.max_side <= 4096 or not 0 < self.fps <= 120:
            raise NeoError("--max-side must be in 16..4096 and --fps in (0, 120]")
        if not Path(self.scene).exists():
            raise NeoError(f"scene not found: {self.scene}")
        check_bindable(self.host, self.port)
        cfg = ViewerConfig(
            query=self.query,
            remove=self.remove,
            move=self.move,
            loop=RenderLoopConfig(target_fps=self.fps),
            max_side=self.max_side,
        )
        if self.host not in LOCAL_HOSTS:
            console.print(
                f"[yellow]warning:[/] serving on {escape(self.host)}: anyone who can reach this "
                "machine can view and edit the scene (there is no login)"
            )

        def ready(app) -> None:
            console.print(
                f"neo view: {escape(str(self.scene))} at [bold]{app.url}[/] (Ctrl-C to stop)"
            )

        serve(self.scene, self.host, self.port, resolve_device(self.device), cfg, ready)


def check_bindable(host: str, port: int) -> None:
    """A host this machine can serve on (viser waits forever for one it cannot bind); a
    taken port is fine (viser moves on to the next free one)."""
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
    except socket.gaierror as e:
        raise NeoError(f"--host {host!r} cannot be resolved ({e.strerror})") from None
    family, _, _, _, address = infos[0]
    with socket.socket(family, socket.SOCK_STREAM) as sock:
        try:
            sock.bind((address[0], 0))  # any free port: only the address is checked
        except OSError as e:
            raise NeoError(f"cannot serve on --host {host!r}: {e.strerror}") from None
