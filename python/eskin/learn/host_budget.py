"""The host budget: on request, a searched model's decision bounded as the campaign grows.

A tensor-SVM keeps the training patterns on its margin as support vectors, and their number
grows with the campaign (with the default search on the simulator: about 100 distinct support
vectors at 10 participants, 650 at 70), and with it the time of every decision. On request
(``train_model(decision_us=...)``, ``--decision-us``; not by default, docs/learning.md) and
without a controller's budget, :func:`host_budget` gives the recipe search
(:class:`~eskin.learn.recipes.RecipeSearch`) a budget on this host: a candidate fits when the
support vectors' share of its estimated decision time (:func:`support_us`, what grows with the
campaign) is at most the cap (e.g. :data:`HOST_DECISION_US`); one expected to need more is kept
with its support vectors bounded to the most that fit
(:func:`eskin.learn.support_budget.bound_support` after the fit) when that keeps at least
half of them, else dropped. The input's bases are left out of the budget:
a fixed cost of the grid and D that the campaign does not change, and one this estimate models
only roughly (4 ns per pattern entry fits a 4x4 grid; an 8x8 grid at D = 100 took about 10 ms a
decision with 120 support vectors on the busy development host, BENCHMARKS.md).

The cost of one decision of the compiled classifier (``cpp/src/model*.cpp``): the input's
bases (one thin SVD per mode unfolding, a fixed cost per D and grid), then per distinct
support vector and mode z the overlap of the input's alpha_z basis vectors with the support
vector's, N_z alpha_z^2 multiply-adds over the N_z = (rows cols D) / d_z entries of a basis
vector (nothing for a mode whose alpha reaches N_z: a full-rank subspace is all of R^N_z), and
the machines' sums. :func:`host_decision_us` is that count of multiply-adds times
:data:`HOST_NS_PER_MAC`, plus :data:`HOST_NS_PER_SV` per support vector and the bases' share:
a deterministic estimate (the same on any host, so training stays reproducible), set from the
compiled classifier's decision times on the 2-core development host (float32 models of 4x4
patterns at D = 100, 350-420 support vectors at alpha 1, Q/2 and Q: about 0.5, 0.8 and 1-2 us
per support vector on a busy machine; 1.0 us per support vector for a 652-support-vector
default model at alpha Q on an idle one). ``benchmarks/bench_peers.py`` measures the decision
time of the default models it trains (BENCHMARKS.md).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence

from eskin.errors import TrainingError

__all__ = ["HOST_DECISION_US", "host_budget", "host_decision_us", "overlap_macs", "support_us"]

#: a cap on the support vectors' share of a decision on the host (microseconds)
HOST_DECISION_US = 100.0
#: nanoseconds per multiply-add of the support vectors' overlaps (float32, one core)
HOST_NS_PER_MAC = 0.06
#: nanoseconds per support vector besides its overlaps (its bases' loads, the kernel value,
#: the amplitude factor, the machines' terms)
HOST_NS_PER_SV = 300.0
#: nanoseconds per entry of the input's pattern (rows x cols x D) for its bases
HOST_NS_PER_ENTRY = 4.0


def overlap_macs(grid_shape: Sequence[int], D: int, alphas: Sequence[int]) -> int:
    """Multiply-adds of the overlaps of one support vector with the input: sum over the modes
    z of N_z alpha_z^2 (none where alpha_z reaches N_z)."""
    rows, cols = (int(v) for v in grid_shape)
    dims = (rows, cols, int(D))
    size = rows * cols * int(D)
    total = 0
    for d, a in zip(dims, alphas):
        n = size // d
        if int(a) < n:
            total += n * int(a) * int(a)
    return total


def host_decision_us(grid_shape: Sequence[int], D: int, alphas: Sequence[int],
                     n_support: int) -> float:
    """Estimated microseconds of one decision on the host of a model with ``n_support``
    distinct support vectors at D and the per-mode ``alphas``."""
    rows, cols = (int(v) for v in grid_shape)
    bases = rows * cols * int(D) * HOST_NS_PER_ENTRY
    per_sv = HOST_NS_PER_SV + overlap_macs(grid_shape, D, alphas) * HOST_NS_PER_MAC
    return (bases + int(n_support) * per_sv) / 1e3


def support_us(grid_shape: Sequence[int], D: int, alphas: Sequence[int],
               n_support: int) -> float:
    """The support vectors' share of :func:`host_decision_us` (what grows with the campaign;
    the input's bases are a fixed cost of the grid and D)."""
    return host_decision_us(grid_shape, D, alphas, n_support) - host_decision_us(
        grid_shape, D, alphas, 0)


def host_budget(grid_shape: Sequence[int], max_us: float = HOST_DECISION_US):
    """The :class:`~eskin.learn.recipes.CandidateBudget` of a decision whose support vectors
    take at most ``max_us`` microseconds on the host (:func:`support_us`). Unlike a
    controller's, it keeps the search's order of preference (the larger D first): it bounds
    the support vectors, not D."""
    from eskin.learn.grids import alpha_value
    from eskin.learn.recipes import CandidateBudget

    if not (math.isfinite(float(max_us)) and float(max_us) > 0):
        raise TrainingError(f"the host decision budget must be a positive number of "
                            f"microseconds, got {max_us!r}")
    grid = tuple(int(v) for v in grid_shape)

    @functools.lru_cache(maxsize=None)
    def fit_at(D: int, alpha: str, n_support: int) -> bool:
        return support_us(grid, D, alpha_value(alpha, (*grid, int(D))), n_support) <= float(max_us)

    def fits(candidate, n_support: int) -> bool:
        return fit_at(int(candidate.recipe.D), candidate.alpha, int(n_support))

    def largest(candidate, n_support: int) -> int:
        """The most support vectors (at most ``n_support``) that fit; 0 when none does."""
        D, alpha = int(candidate.recipe.D), candidate.alpha
        if fit_at(D, alpha, int(n_support)):
            return int(n_support)
        per_sv = support_us(grid, D, alpha_value(alpha, (*grid, D)), 1)
        return max(0, min(int(n_support), int(float(max_us) // per_sv)))

    return CandidateBudget(fits, f"host: support vectors' share of a decision at most "
                                 f"{float(max_us):g} us (estimated)",
                           largest=largest, trades_D=False)

