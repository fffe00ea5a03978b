"""``neo view``: a web viewer (viser) of a scene's versions: look at any version, find an
object by name, preview a removal or a move at once and commit it as a new version.

The render loop (:mod:`.render_loop`) and what the page shows (:mod:`.state`) need no
browser; the page itself (:mod:`.app`) needs the optional ``viser`` package
(``pip install 'neoedit[viewer]'``).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

from neoedit.errors import NeoError
from neoedit.viewer.render_loop import (
    Frame,
    RenderInterrupted,
    RenderLoop,
    RenderLoopConfig,
    ViewRequest,
)

if TYPE_CHECKING:
    from neoedit.viewer.app import ViewerServer
    from neoedit.viewer.state import ViewerConfig

VISER_MISSING = "the viewer needs viser: pip install 'neoedit[viewer]'"


def require_viser() -> None:
    """One clear error when the optional viewer dependency is not installed."""
    try:
        import viser  # noqa: F401
    except ImportError:
        raise NeoError(VISER_MISSING) from None


def serve(
    scene: Path,
    host: str = "127.0.0.1",
    port: int = 8080,
    device: Any = "cpu",
    cfg: ViewerConfig | None = None,
    ready: Any = None,
) -> None:
    """Serve the viewer of ``scene`` on ``host:port`` until interrupted (Ctrl-C)."""
    require_viser()
    from neoedit.viewer.app import serve as _serve

    _serve(Path(scene), host, port, device, cfg, ready)


def __getattr__(name: str) -> Any:
    if name == "ViewerServer":
        require_viser()
        from neoedit.viewer.app import ViewerServer

        return ViewerServer
    if name in ("ViewerConfig", "ViewerState"):
        from neoedit.viewer import state

        return getattr(state, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "Frame",
    "RenderInterrupted",
    "RenderLoop",
    "RenderLoopConfig",
    "ViewRequest",
    "ViewerConfig",
    "ViewerServer",
    "require_viser",
    "serve",
]
