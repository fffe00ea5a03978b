"""``neo bench``: the paper's tables regenerated on NEO-Sim, serially or on a Ray cluster.

Public API: :class:`BenchConfig` and :func:`run_bench`; the methods are listed in
:mod:`neoedit.bench.methods`, the budgets in :mod:`neoedit.bench.profiles`, the baselines
are :mod:`neoedit.bench.seal3d`, :mod:`neoedit.bench.nerfiller` and :mod:`neoedit.bench.dff`.
Exports load lazily (``neo move --method seal3d`` imports the baseline without the
benchmark runner).
"""

from __future__ import annotations

from neoedit.utils.lazy import lazy_exports

_EXPORTS = {"BenchConfig": "neoedit.bench.runner", "run_bench": "neoedit.bench.runner"}

__all__ = sorted(_EXPORTS)

__getattr__ = lazy_exports(__name__, _EXPORTS)
