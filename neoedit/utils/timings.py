"""Where the seconds of a long operation go: named stages timed by one context manager."""

from __future__ import annotations

import contextlib
import time
from collections.abc import Iterator, Mapping


class Timings(dict[str, float]):
    """Seconds per stage (``<stage>_s``) and other figures of one operation, as they go
    into a record (an edit's history entry)."""

    @contextlib.contextmanager
    def stage(self, name: str) -> Iterator[None]:
        """Time the block into ``<name>_s`` (seconds, rounded to 10 ms); a stage entered
        again adds to its time."""
        t = time.perf_counter()
        try:
            yield
        finally:
            key = f"{name}_s"
            self[key] = round(self.get(key, 0.0) + time.perf_counter() - t, 2)

    def merge(self, other: Mapping[str, float], prefix: str = "") -> Timings:
        """Add ``other``'s entries, each name prefixed; returns self."""
        self.update({f"{prefix}{k}": v for k, v in other.items()})
        return self
