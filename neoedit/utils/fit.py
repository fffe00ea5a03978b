"""The one fitting loop: steps of (loss -> backward -> optimiser step) with a progress bar.

Scene training has its own richer loop (grid updates, evaluation, checkpoints); every other
optimisation — the removal patch, distillation, the language field — runs through
:func:`fit`, so schedules, progress and the loss readout behave the same everywhere.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import torch
from rich.progress import Progress, TaskID

from neoedit.errors import NeoError
from neoedit.utils.progress import make_progress

LossFn = Callable[[int], torch.Tensor]
"""step -> scalar loss (with a graph to the parameters being fitted)."""


def check_finite_loss(value: float, step: int, what: str, knob: str) -> None:
    """Stop an optimisation whose loss stopped being a number: one more step would write
    NaN into every weight it touches (and the save would refuse the broken field)."""
    if not math.isfinite(value):
        raise NeoError(f"{what} diverged at step {step} (the loss is {value}); lower {knob}")


def fit(
    optimizer: torch.optim.Optimizer,
    steps: int,
    loss_fn: LossFn,
    label: str,
    lr_scale: Callable[[int], float] | None = None,
    status: Callable[[int, float], str] | None = None,
    bar: tuple[Progress, TaskID] | None = None,
) -> float:
    """Run ``steps`` optimisation steps of ``loss_fn``; returns the final smoothed loss.

    ``lr_scale(step)`` multiplies every group's initial learning rate (a schedule);
    ``status(step, loss)`` is the progress-bar text; ``bar`` continues an existing bar
    (several stages under one bar) instead of opening one."""
    base_lr = [g["lr"] for g in optimizer.param_groups]
    ema: float | None = None

    def run(progress: Progress, task: TaskID) -> None:
        nonlocal ema
        for step in range(steps):
            if lr_scale is not None:
                scale = lr_scale(step)
                for g, lr in zip(optimizer.param_groups, base_lr, strict=True):
                    g["lr"] = lr * scale
            loss = loss_fn(step)
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
            value = float(loss.detach())
            check_finite_loss(value, step, label, "its learning rate")
            ema = value if ema is None else 0.9 * ema + 0.1 * value
            text = status(step, ema) if status is not None else f"loss {ema:.4f}"
            progress.update(task, advance=1, status=text)

    if bar is not None:
        run(*bar)
    else:
        with make_progress() as progress:
            run(progress, progress.add_task(label, total=steps, status=""))
    return float(ema or 0.0)
