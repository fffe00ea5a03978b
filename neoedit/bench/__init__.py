"""``neo bench``: the paper's tables regenerated on NEO-Sim, serially or on a Ray cluster.

Public API: :class:`BenchConfig` and :func:`run_bench`; the methods are listed in
:mod:`neoedit.bench.methods`, the budgets in :mod:`neoedit.bench.profiles`.
"""

from neoedit.bench.runner import BenchConfig, run_bench

__all__ = ["BenchConfig", "run_bench"]
