"""The host budget: by default, a searched model's decision, bounded as campaigns grow.

A tensor-SVM keeps the training patterns on its margin as support vectors, and their number
grows with the campaign (with the search on the built-in simulator: about 45 distinct support
vectors at 10 participants, 340 at 70), and with it the time of every decision. Unless lifted
(``train_model(decision_us=None)``, ``--decision-us 0``; docs/learning.md) and without a
controller's budget, :func:`host_budget` gives the recipe search
(:class:`~eskin.learn.recipes.RecipeSearch`) a budget on the host, by default
:data:`HOST_DECISION_US`: a candidate fits when the support vectors' share of its estimated
decision time (:func:`support_us`, what grows with the campaign) is at most the cap; one
expected to need more is kept with its support vectors bounded to the most that fit
(:func:`eskin.learn.support_budget.bound_support` after the fit) when that keeps at least half
of them, else dropped. Like a controller's budget it trades D against alpha and the support
vectors (the order of preference then leaves D out, :func:`~eskin.learn.recipes.budget_preference`).
The input's bases are left out of the cap: a fixed cost of the grid and D that the campaign
does not change (:data:`HOST_US_INPUT` plus :data:`HOST_NS_PER_ENTRY` per entry of the
pattern: 38-48 us on a 4x4 grid at D = 20-100).

The cost of one decision of the compiled classifier (``cpp/src/model*.cpp``) at the end of a
touch, the time that matters (from the touch's last sample to its label): the window's
subsampling and the input's bases (one eigen-solve per mode unfolding, a fixed cost per D and
grid), then per distinct support vector and mode z the overlap of the input's alpha_z basis
vectors with the support vector's stored ones (N_z alpha_z entries, N_z = (rows cols D) / d_z;
nothing for a mode whose alpha reaches N_z: a full-rank subspace is all of R^N_z), and the
machines' sums. Between two touches the stream and the rest of the host take the caches, so a
model's stored bases come from memory at each decision: what a support vector costs follows the
entries of its bases read per decision (:func:`basis_entries`, float32), at about the host's
memory bandwidth. :func:`host_decision_us` is :data:`HOST_NS_PER_SV` per support vector plus
:data:`HOST_NS_PER_BASIS_ENTRY` per entry of its bases, plus the input's share: a
deterministic count (the same on any host and at any load, so training is reproducible), its
figures fitted to the compiled classifier's end-of-touch decision times on the 2-core
development host (``benchmarks/host_budget_fit.py``: float32 models of 4x4 patterns at D = 20,
50 and 100 and alpha 1, Q/2 and Q with 150 and 336 support vectors, two runs at load average
8-9; the input's share from the same host's times of the input's bases with the caches
emptied, which the script's models of few support vectors confirm). ``benchmarks/bench_inference.py --model`` measures the decision of a trained model.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence

from eskin.errors import TrainingError

__all__ = ["HOST_DECISION_US", "HOST_INPUT_FACTOR", "basis_entries", "default_cap_us", "host_budget",
           "host_decision_us", "input_us", "support_us"]

#: the default cap on the support vectors' share of a decision at the end of a touch on the
#: host (microseconds): the searched model of the built-in 70-participant campaign then
#: decides within 100 us at the end of a touch (D = 20, alpha Q, about 216 support vectors),
#: 0.5 points below a cap of 180 on the mean of five splits and 1.55 below no budget on the
#: mean of twenty (docs/learning.md, "The host budget"; benchmarks/decision_cap_study.py)
HOST_DECISION_US = 80.0
#: the default budget ("auto") lets the support vectors take this many times the input's own
#: share where that is more than HOST_DECISION_US: on a large grid the input's bases alone
#: take over 80 us (19 x 27 at D = 18: about 110 us), and a cap below them would leave no
#: candidate with half its support vectors
HOST_INPUT_FACTOR = 2.0
#: nanoseconds per entry (float32) of a support vector's stored bases, read from memory and
#: multiplied into its overlaps with the input's
HOST_NS_PER_BASIS_ENTRY = 0.39
#: nanoseconds per support vector besides its bases (the kernel value, the amplitude factor,
#: the machines' terms, its ranks and distances)
HOST_NS_PER_SV = 120.0
#: microseconds of the input's bases and the window's subsampling whatever the pattern's size
HOST_US_INPUT = 35.0
#: nanoseconds per entry of the input's pattern (rows x cols x D) on top of HOST_US_INPUT
HOST_NS_PER_ENTRY = 8.0


def basis_entries(grid_shape: Sequence[int], D: int, alphas: Sequence[int]) -> int:
    """Entries of one support vector's bases that a decision reads: sum over the modes z of
    N_z alpha_z (none where alpha_z reaches N_z)."""
    rows, cols = (int(v) for v in grid_shape)
    dims = (rows, cols, int(D))
    size = rows * cols * int(D)
    total = 0
    for d, a in zip(dims, alphas):
        n = size // d
        if int(a) < n:
            total += n * int(a)
    return total


def host_decision_us(grid_shape: Sequence[int], D: int, alphas: Sequence[int],
                     n_support: int) -> float:
    """Estimated microseconds of one decision at the end of a touch on the host of a model with
    ``n_support`` distinct support vectors at D and the per-mode ``alphas``."""
    per_sv = HOST_NS_PER_SV + basis_entries(grid_shape, D, alphas) * HOST_NS_PER_BASIS_ENTRY
    return (_input_ns(grid_shape, D) + int(n_support) * per_sv) / 1e3


def _input_ns(grid_shape: Sequence[int], D: int) -> float:
    rows, cols = (int(v) for v in grid_shape)
    return HOST_US_INPUT * 1e3 + rows * cols * int(D) * HOST_NS_PER_ENTRY


def input_us(grid_shape: Sequence[int], D: int) -> float:
    """The input's share of :func:`host_decision_us`: its bases and the window's subsampling,
    a fixed cost of the grid and D."""
    return _input_ns(grid_shape, D) / 1e3


def default_cap_us(grid_shape: Sequence[int], D: int) -> float:
    """The default budget's cap ("auto") at D: :data:`HOST_DECISION_US`, or
    :data:`HOST_INPUT_FACTOR` times the input's own share where that is larger."""
    return max(HOST_DECISION_US, HOST_INPUT_FACTOR * input_us(grid_shape, D))


def support_us(grid_shape: Sequence[int], D: int, alphas: Sequence[int],
               n_support: int) -> float:
    """The support vectors' share of :func:`host_decision_us` (what grows with the campaign;
    the input's bases are a fixed cost of the grid and D)."""
    return host_decision_us(grid_shape, D, alphas, n_support) - host_decision_us(
        grid_shape, D, alphas, 0)


def host_budget(grid_shape: Sequence[int], max_us: float | str = "auto"):
    """The :class:`~eskin.learn.recipes.CandidateBudget` of a decision whose support vectors
    take at most ``max_us`` microseconds on the host (:func:`support_us`); ``"auto"`` (the
    default of ``eskin train``): :func:`default_cap_us` at each candidate's D. Like a
    controller's, it trades D against alpha and the support vectors."""
    from eskin.learn.grids import alpha_value
    from eskin.learn.recipes import CandidateBudget

    auto = max_us == "auto"
    if not auto and (isinstance(max_us, str) or not math.isfinite(max_us) or max_us <= 0):
        raise TrainingError(f"the host decision budget must be a positive number of "
                            f"microseconds or 'auto', got {max_us!r}")
    grid = tuple(int(v) for v in grid_shape)

    def cap(D: int) -> float:
        return default_cap_us(grid, D) if auto else float(max_us)

    @functools.lru_cache(maxsize=None)
    def fit_at(D: int, alpha: str, n_support: int) -> bool:
        return support_us(grid, D, alpha_value(alpha, (*grid, int(D))), n_support) <= cap(D)

    def fits(candidate, n_support: int) -> bool:
        return fit_at(int(candidate.recipe.D), candidate.alpha, int(n_support))

    def largest(candidate, n_support: int) -> int:
        """The most support vectors (at most ``n_support``) that fit; 0 when none does."""
        D, alpha = int(candidate.recipe.D), candidate.alpha
        if fit_at(D, alpha, int(n_support)):
            return int(n_support)
        per_sv = support_us(grid, D, alpha_value(alpha, (*grid, D)), 1)
        return max(0, min(int(n_support), int(cap(D) // per_sv)))

    what = (f"at most {HOST_DECISION_US:g} us, or {HOST_INPUT_FACTOR:g} times the input's "
            f"bases where those take more" if auto else f"at most {float(max_us):g} us")
    return CandidateBudget(fits, f"host: support vectors' share of a decision {what} "
                                 f"(estimated)",
                           largest=largest, trades_D=True)

