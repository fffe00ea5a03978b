"""CPU thread budget and wait policy of a neo process.

Two OpenMP runtimes live in one neo process: PyTorch's bundled libgomp (matrix products,
element-wise ops) and the system libgomp behind numba's parallel kernels (the hash grid).
Each keeps its idle threads spinning for a while (libgomp's default: 300 000 spins), so
with two neo processes on two cores the spinning threads of one steal the cores the other
needs. Measured on 2 cores, two trainings side by side: 16x slower each with the default,
1.9x with ``GOMP_SPINCOUNT=1000`` (alone: as fast as the default), 1.5x with
``OMP_WAIT_POLICY=PASSIVE`` (alone: 12 % slower). neo therefore sets
``GOMP_SPINCOUNT=1000`` unless the user chose a wait policy. Both runtimes read it when they
load, so :func:`set_wait_policy` runs on ``import neoedit`` (before torch and numba load).

The knobs a user has: ``--threads N`` on every verb or ``NEO_THREADS=N`` (threads of
torch, numba and COLMAP; default: the cores this process may use), and ``OMP_WAIT_POLICY`` /
``GOMP_SPINCOUNT`` (kept when set).
"""

from __future__ import annotations

import os
from collections.abc import MutableMapping

from neoedit.errors import NeoError

ENV_VAR = "NEO_THREADS"
DEFAULT_SPINCOUNT = "1000"


def set_wait_policy(environ: MutableMapping[str, str] = os.environ) -> None:
    """Short OpenMP spin-waits unless the environment already sets a wait policy."""
    if "OMP_WAIT_POLICY" not in environ and "GOMP_SPINCOUNT" not in environ:
        environ["GOMP_SPINCOUNT"] = DEFAULT_SPINCOUNT


def available_cores() -> int:
    """Cores this process may run on (its CPU affinity, not the machine's count)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def resolve_threads(requested: int | None, environ: MutableMapping[str, str] = os.environ) -> int:
    """The thread count: ``requested`` (``--threads``), else ``$NEO_THREADS``, else the
    available cores. Anything but a positive integer is a clear error."""
    if requested is not None:
        return _positive(str(requested), "--threads")
    text = environ.get(ENV_VAR, "").strip()
    return _positive(text, f"${ENV_VAR}") if text else available_cores()


def parse_threads(text: str) -> int:
    """The value of ``--threads`` as given on the command line."""
    return _positive(text, "--threads")


def _positive(text: str, source: str) -> int:
    try:
        n = int(text)
    except ValueError:
        n = 0
    if n < 1:
        raise NeoError(f"{source} must be a positive integer, got {text!r}")
    limit = max_threads()
    if n > limit:
        raise NeoError(
            f"{source} {n} is more than {OVERSUBSCRIPTION}x this machine's "
            f"{os.cpu_count() or 1} cores; give at most {limit}"
        )
    return n


OVERSUBSCRIPTION = 4
"""Most threads per core a user may ask for: more only slows the work down, and torch's
thread pool crashes the process (signal 11) at ~10^5 threads."""


def max_threads() -> int:
    return OVERSUBSCRIPTION * (os.cpu_count() or 1)


_BUDGET: list[int] = []
"""The budget :func:`configure_threads` set (empty: none set)."""
_CHOSEN: list[int] = []
"""The count given to :func:`configure_threads` explicitly (``--threads``; empty: none)."""


def configure_threads(requested: int | None = None) -> int:
    """Apply the thread budget to torch and numba (in this thread; other threads that run
    numba kernels call :func:`apply_thread_budget`); returns it."""
    import torch

    n = resolve_threads(requested)
    _BUDGET[:] = [n]
    _CHOSEN[:] = [] if requested is None else [n]
    # numba first: starting its OpenMP threads sets the thread count of a libgomp that
    # torch may share (it does once another library loaded the system libgomp first), so
    # torch's count set before it would be reset to every core
    apply_thread_budget()
    torch.set_num_threads(n)
    return n


def thread_budget() -> int:
    """The budget :func:`configure_threads` set in this process, else what it would set:
    the thread count other native libraries (COLMAP) are given."""
    return _BUDGET[0] if _BUDGET else resolve_threads(None)


def chosen_threads(environ: MutableMapping[str, str] = os.environ) -> int | None:
    """The thread count the user chose (``--threads`` of this process, else
    ``$NEO_THREADS``), or None when neither was given: what a process handing work to
    other processes (``neo bench``'s Ray workers) passes on to them."""
    if _CHOSEN:
        return _CHOSEN[0]
    return resolve_threads(None, environ) if environ.get(ENV_VAR, "").strip() else None


def apply_thread_budget() -> None:
    """numba's thread count is per thread: a worker thread (the viewer's render loop, its
    commit) calls this first so its kernels keep to the process's budget."""
    if not _BUDGET:
        return
    try:
        import numba
    except ImportError:
        return
    numba.set_num_threads(min(_BUDGET[0], numba.config.NUMBA_NUM_THREADS))  # type: ignore[attr-defined]
