"""Progress bars for long work (rich), quiet when output is not a terminal."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Callable, Iterable, Iterator
from typing import Any, TypeVar

from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TaskID,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)

T = TypeVar("T")

Listener = Callable[[str, float], None]
"""(task description, fraction done in [0, 1]) -> None."""
_LISTENERS: list[Listener] = []


class _ListenedProgress(Progress):
    """A rich progress display that also tells the registered listeners (the viewer's page)
    how far its tasks are."""

    def add_task(self, description: str, *args: Any, **kwargs: Any) -> TaskID:
        task = super().add_task(description, *args, **kwargs)
        self._tell(task)
        return task

    def update(self, task_id: TaskID, **kwargs: Any) -> None:
        super().update(task_id, **kwargs)
        self._tell(task_id)

    def advance(self, task_id: TaskID, advance: float = 1) -> None:
        super().advance(task_id, advance)
        self._tell(task_id)

    def _tell(self, task_id: TaskID) -> None:
        if not _LISTENERS:
            return
        task = next((t for t in self.tasks if t.id == task_id), None)
        if task is None:
            return
        fraction = min(max(task.completed / task.total if task.total else 0.0, 0.0), 1.0)
        for listener in list(_LISTENERS):
            with contextlib.suppress(Exception):  # a listener never breaks the work
                listener(task.description, fraction)


@contextlib.contextmanager
def progress_listener(listener: Listener) -> Iterator[None]:
    """While inside, every progress bar (:func:`make_progress`) also reports to ``listener``."""
    _LISTENERS.append(listener)
    try:
        yield
    finally:
        _LISTENERS.remove(listener)


QUIET_ENV = "NEO_QUIET"
"""Set to 1 (``neo --quiet``): no progress bars (results and errors only)."""


def make_progress(transient: bool = False) -> Progress:
    return _ListenedProgress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        TextColumn("{task.fields[status]}"),
        transient=transient,
        disable=os.environ.get(QUIET_ENV) == "1",
    )


def track(items: Iterable[T], description: str, total: int | None = None) -> Iterator[T]:
    """Iterate with a progress bar (``status`` field left empty)."""
    if total is None and hasattr(items, "__len__"):
        total = len(items)  # type: ignore[arg-type]
    with make_progress(transient=True) as progress:
        task = progress.add_task(description, total=total, status="")
        for item in items:
            yield item
            progress.advance(task)
