from neoedit.cameras.cameras import Cameras, look_at

__all__ = ["Cameras", "look_at"]
