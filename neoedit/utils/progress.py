"""Progress bars for long work (rich); when the output is not a terminal (a log file, a
pipe, a job scheduler) long tasks print a plain line on stderr every tenth of the way or
half minute instead, so a log shows how far the work is without drawing bars into it."""

from __future__ import annotations

import contextlib
import os
import sys
import time
from collections.abc import Callable, Iterable, Iterator
from typing import Any, TypeVar

from rich import get_console
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


LOG_AFTER_S = 5.0
"""Without a terminal, a task prints its first line once it has run this long (short
tasks stay silent)."""
LOG_EVERY_S = 30.0
LOG_EVERY_FRACTION = 0.1


class _ListenedProgress(Progress):
    """A rich progress display that also tells the registered listeners (the viewer's page)
    how far its tasks are, and writes plain progress lines when there is no terminal."""

    def __init__(self, *columns: Any, **kwargs: Any) -> None:
        self._log = not kwargs.get("disable", False) and not get_console().is_terminal
        if self._log:  # rich would print its last frame into the log or pipe (stdout)
            kwargs["disable"] = True
        super().__init__(*columns, **kwargs)
        self._logged: dict[TaskID, tuple[float, float]] = {}  # task -> (time, fraction)

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
        if not _LISTENERS and not self._log:
            return
        task = next((t for t in self.tasks if t.id == task_id), None)
        if task is None:
            return
        fraction = min(max(task.completed / task.total if task.total else 0.0, 0.0), 1.0)
        if self._log:
            self._log_line(task, fraction)
        for listener in list(_LISTENERS):
            with contextlib.suppress(Exception):  # a listener never breaks the work
                listener(task.description, fraction)

    def _log_line(self, task: Any, fraction: float) -> None:
        """One plain line for ``task`` on stderr when it is due (see the module doc)."""
        now = time.monotonic()
        elapsed = task.elapsed or 0.0
        last = self._logged.get(task.id)
        if last is None:
            due = elapsed >= LOG_AFTER_S
        else:
            due = (
                fraction - last[1] >= LOG_EVERY_FRACTION - 1e-9
                or now - last[0] >= LOG_EVERY_S
                or (fraction >= 1.0 > last[1])
            )
        if not due:
            return
        self._logged[task.id] = (now, fraction)
        done = f"{task.completed:g}/{task.total:g} ({100 * fraction:.0f} %)" if task.total else ""
        left = task.time_remaining
        times = f"{_clock(elapsed)} elapsed" + (f", ~{_clock(left)} left" if left else "")
        status = str(task.fields.get("status") or "")
        line = " · ".join(x for x in (f"{task.description} {done}".strip(), times, status) if x)
        print(line, file=sys.stderr, flush=True)


@contextlib.contextmanager
def progress_listener(listener: Listener) -> Iterator[None]:
    """While inside, every progress bar (:func:`make_progress`) also reports to ``listener``."""
    _LISTENERS.append(listener)
    try:
        yield
    finally:
        _LISTENERS.remove(listener)


def _clock(seconds: float) -> str:
    s = int(round(seconds))
    return f"{s // 3600}:{s % 3600 // 60:02d}:{s % 60:02d}"


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
