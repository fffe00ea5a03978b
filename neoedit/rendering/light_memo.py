"""The room's light on rays rendered before, kept for the next render of the same rays.

A room (:class:`~neoedit.fields.room.RoomField`) costs about three quarters of a view of a
real capture, and no edit trains it (patches are local to the box). Yet the same rays are
rendered again and again: an edit's report renders every view before and after, its
refinement rounds march the same virtual views, the viewer re-renders a still camera. So
renders that do not train the room keep its light per chunk of rays here, keyed by the
room's weights (:meth:`~neoedit.fields.room.RoomField.weights_key`: shared by deep copies,
renewed when a parameter changes), its settings and the rays' bytes; a later render of the
same chunk computes only the rays the earlier one skipped. Least recently used entries go
first; an entry stays on the device it was computed on.
"""

from __future__ import annotations

import hashlib
import threading
from collections import OrderedDict
from dataclasses import dataclass

import torch


@dataclass
class RoomLightEntry:
    """The room's light on a chunk of N rays: premultiplied colour in front of the box
    (N,3), the box's share (N,), the light from behind it (N,3), and which rays hold them."""

    front_rgb: torch.Tensor
    front_trans: torch.Tensor
    back_rgb: torch.Tensor
    done: torch.Tensor

    @classmethod
    def empty(cls, n: int, device: torch.device) -> RoomLightEntry:
        z = torch.zeros(n, 3, device=device)
        return cls(
            z,
            torch.ones(n, device=device),
            z.clone(),
            torch.zeros(n, dtype=torch.bool, device=device),
        )

    @property
    def nbytes(self) -> int:
        return sum(
            t.element_size() * t.numel()
            for t in (self.front_rgb, self.front_trans, self.back_rgb, self.done)
        )


def ray_key(
    revision: int, settings: str, origins: torch.Tensor, directions: torch.Tensor, near_m: float
) -> tuple:
    """The memo's key of a chunk of rays (origins, directions (N,3)) seen by a room with
    weights ``revision`` and sampling ``settings`` (its config's repr)."""
    h = hashlib.blake2b(digest_size=16)
    h.update(settings.encode())
    for t in (origins, directions):
        h.update(t.detach().float().contiguous().cpu().numpy().tobytes())
    return revision, len(origins), float(near_m), h.digest()


class LightMemo:
    """A bounded least-recently-used store of :class:`RoomLightEntry`. The store itself is
    locked; an entry is completed in place, which two threads may both do (they write the
    same values)."""

    def __init__(self, max_bytes: int = 128 << 20):
        self.max_bytes = max_bytes
        self._entries: OrderedDict[tuple, RoomLightEntry] = OrderedDict()
        self._bytes = 0
        self._lock = threading.Lock()

    def lookup(self, key: tuple) -> RoomLightEntry | None:
        with self._lock:
            entry = self._entries.get(key)
            if entry is not None:
                self._entries.move_to_end(key)
            return entry

    def store(self, key: tuple, entry: RoomLightEntry) -> None:
        with self._lock:
            old = self._entries.pop(key, None)
            self._bytes -= old.nbytes if old is not None else 0
            if entry.nbytes > self.max_bytes:
                return
            self._entries[key] = entry
            self._bytes += entry.nbytes
            while self._bytes > self.max_bytes:
                _, dropped = self._entries.popitem(last=False)
                self._bytes -= dropped.nbytes

    def clear(self) -> None:
        with self._lock:
            self._entries.clear()
            self._bytes = 0

    def __len__(self) -> int:
        return len(self._entries)


MEMO = LightMemo()
"""The process's memo of room light (renders without gradients use it)."""
