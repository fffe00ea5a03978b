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
        again adds to its time (summed unrounded: a thousand 4 ms steps make 4 s)."""
        t = time.perf_counter()
        try:
            yield
        finally:
            key = f"{name}_s"
            total = self.seconds(name) + time.perf_counter() - t
            self.__dict__.setdefault("_exact", {})[key] = total
            self[key] = round(total, 2)

    def seconds(self, name: str) -> float:
        """The unrounded time of stage ``name`` so far (0 before it ran)."""
        key, exact = f"{name}_s", self.__dict__.get("_exact", {})
        if key in exact and self.get(key) == round(exact[key], 2):
            return exact[key]
        return self.get(key, 0.0)  # set by hand (or merged): only its rounded value is known

    def merge(self, other: Mapping[str, float], prefix: str = "") -> Timings:
        """Add ``other``'s entries, each name prefixed; returns self."""
        self.update({f"{prefix}{k}": v for k, v in other.items()})
        return self
