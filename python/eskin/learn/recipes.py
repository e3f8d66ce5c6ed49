"""Choosing the training recipe on the user's own data: successive halving over recipes.

A *recipe* is how a model is made from recordings: the machine (tensor-SVM or tensor-RLS), the
subsampled length D, the subsampling method and the negatives each one-vs-all machine sees (all
the other classes' patterns, or as many random ones as its class has). A *candidate* is a recipe
with one setting of the grid (lambda, sigma, alpha, amplitude), shared by its machines.

:class:`RecipeSearch` picks the candidate with the lowest **multi-class** error on
participant-grouped cross-validation splits (no participant on both sides of a split), the error
`eskin evaluate` measures on unseen people. Scoring every candidate on every split would cost
the grid times the recipes (24 x 405 settings); the search instead runs **successive halving**
(Jamieson and Talwalkar 2016; scikit-learn's ``HalvingGridSearchCV``) with the cross-validation
splits as the resource: every candidate is scored on the first split, the best third on two
splits, the best third of those on four, the best third of those on all of them (each round a
third of the candidates on twice the splits: the first rounds, with the most candidates, cost
the fewest fits; ``growth``). Every candidate is scored on the same splits in
the same order, so the estimates of the survivors are comparable and the last round's are the
plain ``n_splits``-fold figures. The first round samples the same share of the grid for every
recipe (seeded), so each recipe is judged on the same settings.

What is shared: the patterns are preprocessed once per (D, subsampling) and the per-mode
distances once per (D, subsampling, alpha) for all the training patterns; every split, setting
and machine slices the same Gram matrix (one per sigma and amplitude width). With every negative,
the one-vs-all machines of a split share their training set: tensor-RLS solves all of them with
one Cholesky factorisation per lambda.

The choice: cross-validation on a few dozen people cannot rank two dozen recipes reliably (the
lowest of many noisy estimates is lower by luck as often as by merit), so the search keeps an
order of preference among recipes (:func:`recipe_preference`: the larger D, then tensor-SVM,
Algorithm 2 subsampling and every negative, the order that was best on average over the
simulated campaigns of ``benchmarks/selection_study.py``) and chooses the most preferred recipe
whose best candidate is **not significantly worse** than the lowest-error candidate, by the
corrected resampled t-test of Nadeau and Bengio (2003) on the paired split errors (one-sided,
level ``significance``): the variance of the mean difference over J random splits holding out a
share of the groups is (1/J + n_test/n_train) times the splits' variance, not 1/J of it, as the
splits overlap. The most preferred recipe (of those with a candidate that fits the budget) is
the likeliest choice: the first round scores it on the whole grid, not the sample, and the best
third of its own candidates stays in every round beside the best third of all. Within the chosen recipe, among its final candidates whose error is
within one held-out pattern (over all the splits together) of its best, the one with the fewest
expected support vectors wins. A budget (:class:`CandidateBudget`, see :mod:`eskin.deploy.target` for the cost
model) removes candidates whose compiled model would not fit the controller before they are
ranked, or keeps one with its support vectors bounded to the most that fit (at least half of
those it is expected to need; :func:`eskin.learn.support_budget.bound_support` after the fit).
Under a budget (a controller's, or the host's of :mod:`eskin.learn.host_budget`, on by
default) the order of preference leaves D out (:func:`budget_preference`): the budget trades D
against alpha and the support vectors, and the larger D that is safest without one held on to
alpha 1 at D = 100 where alpha Q at D = 50 (at D = 20 under the host's) did better on unseen
people.

Every random choice (splits, the grid sample, balanced negatives) is seeded, never taken from
the execution order; the work of a round is cut into (D, subsampling, alpha) tasks run through
joblib (any backend, Dask included) with the patterns shipped to the workers, so results are
identical for any ``n_jobs`` and backend.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from eskin.errors import ClassLeftOut, TrainingError

__all__ = [
    "Candidate",
    "Recipe",
    "RecipeSearch",
    "corrected_paired_t",
    "recipe_preference",
    "recipe_space",
]

MACHINES = ("svm", "rls")
SUBSAMPLES = ("algorithm2", "even")
NEGATIVES = ("all", "balanced")
#: grid label -> the alpha value given to the estimators (see :func:`eskin.resolve_alphas`)
ALPHA_SPEC: dict[str, Any] = {"1": 1, "Q/2": "half", "Q": "full"}
#: grids of at most this many settings are scored whole in the first round
SMALL_GRID = 24
#: D values searched by default (the paper's), each capped by the longest training recording
SEARCH_DS = (20, 50, 100)
#: A machine whose decision values on a split's held-out patterns all lie within this of its
#: intercept (the targets are +-1, so this is a thousandth of the label scale) tells those
#: patterns nothing apart: its kernel has collapsed (sigma too small for the patterns'
#: distances, every held-out kernel value near 0), and the label would be decided by noise. Such
#: a candidate's split counts as error 1.0.
COLLAPSE_TOLERANCE = 1e-3
#: Bytes the per-mode distances of one (D, subsampling, alpha) may take by default: the
#: patterns' bases, the packed blocks of the pairwise kernel and the distances themselves
#: (``RecipeSearch(memory_limit=...)``, ``eskin train --memory-limit``).
DEFAULT_MEMORY_LIMIT = 512 << 20


def pattern_distances(
    X: np.ndarray, alpha: str, memory_limit: int | None
) -> tuple[np.ndarray, np.ndarray]:
    """(the per-mode distances of the patterns ``X`` at the grid's ``alpha`` summed over the
    modes, their log energies): all a kernel of the tensor family needs (K = exp(-sum / (2
    sigma^2))). Within ``memory_limit`` bytes (None: no limit): the pairwise kernel packs the
    patterns block by block in what the bases and the distances leave of it
    (:func:`distance_scratch`)."""
    from eskin.learn.kernel import mode_distances, pattern_log_energy, resolve_alphas

    alphas = resolve_alphas(X.shape[1:], ALPHA_SPEC[alpha])
    scratch = None
    if memory_limit is not None:
        scratch = distance_scratch(X.shape, alphas, memory_limit,
                                   f"D = {X.shape[-1]}, alpha {alpha}")
    d = mode_distances(X, alpha=alphas, max_bytes=scratch)
    return d.sum(axis=0), pattern_log_energy(X)


def distance_memory(shape: Sequence[int], alphas: Sequence[int]) -> tuple[int, int]:
    """(bytes of the bases and distances of ``shape[0]`` patterns of shape ``shape[1:]`` at
    ``alphas``, bytes of the smallest blocked plan of the pairwise kernel's scratch memory)."""
    from eskin.learn.kernel import distance_plan

    n, dims = int(shape[0]), [int(d) for d in shape[1:]]
    size = math.prod(dims)
    bases = n * sum(size // d * int(a) for d, a in zip(dims, alphas)) * 8
    distances = (len(dims) + 1) * n * n * 8  # per mode, and their sum
    smallest = distance_plan(dims, alphas, 8, 8)["pack_bytes"]  # a row and a column block of 8
    try:  # short of memory, a projection mode may be packed as its (smaller) bases
        smallest = distance_plan(dims, alphas, 8, 8, max_bytes=smallest - 1)["pack_bytes"]
    except ValueError:
        pass
    return bases + distances, int(smallest)


def distance_scratch(shape: Sequence[int], alphas: Sequence[int], limit: int, what: str) -> int:
    """The scratch bytes left to the pairwise kernel by ``limit`` once the bases and the
    distances of the patterns are counted (:func:`distance_memory`); a TrainingError naming
    ``what`` when not even its smallest blocks fit."""
    fixed, smallest = distance_memory(shape, alphas)
    if fixed + smallest > limit:
        raise TrainingError(
            f"the distances of {shape[0]} patterns at {what} need at least "
            f"{(fixed + smallest) / 2**20:.0f} MiB, more than the memory limit of "
            f"{limit / 2**20:.0f} MiB: give a smaller D or alpha, or raise --memory-limit")
    return int(limit - fixed)


def collapsed(F: np.ndarray, intercepts: np.ndarray) -> bool:
    """Whether some machine's held-out values ``F[:, k]`` all lie within
    :data:`COLLAPSE_TOLERANCE` of its intercept."""
    if F.shape[0] == 0:
        return False
    spread = np.max(np.abs(F - np.asarray(intercepts, dtype=np.float64)[None, :]), axis=0)
    return bool(np.any(spread < COLLAPSE_TOLERANCE))


@dataclass(frozen=True, order=True)
class Recipe:
    """How a model is made: machine, D, subsampling and the negatives of the one-vs-all machines."""

    machine: str
    D: int
    subsample: str
    negatives: str

    def __post_init__(self) -> None:
        if self.machine not in MACHINES:
            raise TrainingError(f"machine must be 'svm' or 'rls', got {self.machine!r}")
        if self.subsample not in SUBSAMPLES:
            raise TrainingError(f"subsample must be one of {SUBSAMPLES}, got {self.subsample!r}")
        if self.negatives not in NEGATIVES:
            raise TrainingError(f"negatives must be 'all' or 'balanced', got {self.negatives!r}")
        if int(self.D) < 1:
            raise TrainingError(f"D must be >= 1, got {self.D}")

    @property
    def variant(self) -> tuple[int, str]:
        return (int(self.D), self.subsample)

    def label(self) -> str:
        return f"{self.machine} D={self.D} {self.subsample} negatives={self.negatives}"


@dataclass(frozen=True)
class Candidate:
    """A recipe with one grid setting (alpha is a grid label: "1", "Q/2" or "Q")."""

    recipe: Recipe
    lam: float
    sigma: float
    alpha: str
    amplitude: float | None

    def label(self) -> str:
        amp = "off" if self.amplitude is None else f"{self.amplitude:g}"
        return (f"{self.recipe.label()}, lambda={self.lam:g}, sigma={self.sigma:g}, "
                f"alpha={self.alpha}, amplitude={amp}")

    def as_dict(self) -> dict[str, Any]:
        return {**asdict(self.recipe), "lambda": float(self.lam), "sigma": float(self.sigma),
                "alpha": self.alpha, "amplitude": self.amplitude}


def recipe_space(
    machines: Sequence[str] = MACHINES,
    Ds: Sequence[int] = SEARCH_DS,
    subsamples: Sequence[str] = SUBSAMPLES,
    negatives: Sequence[str] = NEGATIVES,
    *,
    longest: int | None = None,
    fill: int | None = None,
) -> tuple[list[Recipe], list[str]]:
    """(the recipes of the given choices, notes). A D longer than ``longest`` (the longest
    training recording, when given) becomes ``longest``, and one longer than ``fill`` (the D
    most touch windows fill, :func:`eskin.learn.training_set.fillable_D`) becomes ``fill``: a
    longer D would only stretch every touch by interpolation."""
    notes = []
    capped = []
    for D in Ds:
        D = int(D)
        if longest is not None and D > longest:
            notes.append(f"the training recordings are at most {longest} samples long: D = "
                         f"{max(2, longest)} instead of {D}")
            D = max(2, int(longest))
        if fill is not None and D > fill:
            notes.append(f"the median training touch window is {fill} samples long: D = "
                         f"{max(2, fill)} instead of {D}")
            D = max(2, int(fill))
        if D not in capped:
            capped.append(D)
    recipes = sorted({Recipe(m, D, s, n) for m in machines for D in capped for s in subsamples
                      for n in negatives})
    if not recipes:
        raise TrainingError("the recipe search has no recipe to try")
    return recipes, notes


def recipe_preference(recipe: Recipe) -> tuple:
    """Sort key of the order of preference among recipes the cross-validation cannot tell
    apart: the larger D first, then tensor-SVM before tensor-RLS, Algorithm 2 before even
    subsampling, every negative before balanced ones."""
    return (-int(recipe.D), MACHINES.index(recipe.machine), SUBSAMPLES.index(recipe.subsample),
            NEGATIVES.index(recipe.negatives))


def budget_preference(recipe: Recipe) -> tuple:
    """The order of preference under a controller's budget: :func:`recipe_preference` without
    D. A budget trades D against alpha and the support vectors (at the cortex-m4 budget D =
    100 fits at alpha 1 only, D = 50 at alpha Q with about 60 support vectors), so the larger D
    is no longer the safer choice: the recipes of one machine, subsampling and negatives are
    one family, and the family's lowest-error candidate stands for it."""
    return recipe_preference(recipe)[1:]


def corrected_paired_t(diffs: Sequence[float], test_share: float) -> tuple[float, float]:
    """(t, one-sided p) of the corrected resampled t-test (Nadeau and Bengio 2003) that the mean
    of ``diffs`` (paired differences over J random splits, each holding out ``test_share`` of
    the data) is above zero: t = mean / sqrt((1/J + test_share / (1 - test_share)) * var), var
    with J - 1 degrees of freedom. A zero variance gives t = +-inf (p 0 or 1) for a non-zero
    mean, t = 0 and p = 0.5 for a zero mean."""
    from scipy.stats import t as student_t

    d = np.asarray(diffs, dtype=np.float64)
    J = len(d)
    if J < 2:
        raise TrainingError("the paired test needs at least two splits")
    mean, var = float(d.mean()), float(d.var(ddof=1))
    share = float(test_share)
    se = math.sqrt((1.0 / J + share / (1.0 - share)) * var)
    if se == 0.0:
        t = 0.0 if mean == 0.0 else math.copysign(math.inf, mean)
    else:
        t = mean / se
    return t, float(student_t.sf(t, J - 1))


# --------------------------------------------------------------------------------------------
# scoring candidates on splits (the work of one task: one (D, subsampling, alpha))


def one_vs_all_indices(
    y_all: np.ndarray, n_classes: int, negatives: str, seed: int
) -> list[np.ndarray]:
    """The sorted training indices of each 1-vs-all machine: its class's patterns, and all the
    others or ("balanced") as many seeded random ones of the other classes."""
    rng = np.random.default_rng(seed)
    machine_indices = []
    for k in range(n_classes):
        pos = np.flatnonzero(y_all == k)
        neg = np.flatnonzero(y_all != k)
        if negatives == "balanced" and len(neg) > len(pos):
            neg = np.sort(rng.choice(neg, size=len(pos), replace=False))
        machine_indices.append(np.sort(np.concatenate([pos, neg])))
    return machine_indices


def _machine_subsets(y: np.ndarray, n_classes: int, negatives: str, seed: int) -> list[np.ndarray]:
    """Sorted training indices of each machine (as eskin.train_model draws them)."""
    if n_classes == 2:  # one machine, on every pattern
        return [np.arange(len(y))]
    return one_vs_all_indices(y, n_classes, negatives, seed)


def _binary_targets(y: np.ndarray, n_classes: int) -> np.ndarray:
    """(n, machines) -1/+1 targets: one column for two classes (+1 = class 1), else one per
    class."""
    if n_classes == 2:  # its target +1 is class 1
        return np.where(y == 1, 1.0, -1.0)[:, None]
    return np.stack([np.where(y == k, 1.0, -1.0) for k in range(n_classes)], axis=1)


def _predict(F: np.ndarray, n_classes: int) -> np.ndarray:
    from eskin.learn.estimators import one_vs_all_rule

    if n_classes == 2:  # the sign of the one machine
        return (F[:, 0] > 0).astype(np.int64)
    return one_vs_all_rule(F)[0]


def _split_machines(
    y: np.ndarray, n_classes: int, negatives: Sequence[str], splits: list, split_ids: list[int],
    seed: int,
) -> dict[tuple[str, int], list[np.ndarray]]:
    """{(negatives, split id): the training indices of each machine on that split}, each drawn
    once for a task (the machines' subsets as eskin.train_model draws them, cut to the split's
    training part). With every negative the machines share one array (the same object), so
    their Gram blocks are sliced once."""
    out: dict[tuple[str, int], list[np.ndarray]] = {}
    for neg in sorted(set(negatives)):
        subsets = _machine_subsets(y, n_classes, neg, seed)
        for s in split_ids:
            tr = splits[s][0]
            if neg == "all":
                out[(neg, s)] = [tr] * len(subsets)
            else:
                mask = np.zeros(len(y), bool)
                mask[tr] = True
                out[(neg, s)] = [sub[mask[sub]] for sub in subsets]
    return out


def _score_task(
    dist_sum: np.ndarray,
    energies: np.ndarray,
    y: np.ndarray,
    n_classes: int,
    candidates: list[Candidate],
    splits: list[tuple[np.ndarray, np.ndarray]],
    split_ids: list[int],
    seed: int,
) -> dict[tuple[Candidate, int], tuple[float, int, bool]]:
    """{(candidate, split id): (multi-class held-out error, support vectors of its machines
    together, whether a machine's kernel collapsed)} for candidates sharing one (D,
    subsampling, alpha), from the patterns' per-mode distances summed over the modes and their
    log energies. The machines' index sets are drawn once per task, the Gram blocks of a split
    sliced once per kernel and shared by the recipes whose machines train on them."""
    import scipy.linalg

    from eskin.learn.estimators import svm_train
    from eskin.learn.selection import _single_threaded_blas

    out: dict[tuple[Candidate, int], tuple[float, int, bool]] = {}
    with _single_threaded_blas():
        Y = _binary_targets(y, n_classes)
        trains = _split_machines(y, n_classes, [c.recipe.negatives for c in candidates], splits,
                                 split_ids, seed)
        blocks = _SplitBlocks(dist_sum, energies, trains, splits)
        by_kernel: dict[tuple[float, float | None], list[Candidate]] = {}
        for c in candidates:
            by_kernel.setdefault((c.sigma, c.amplitude), []).append(c)
        for (sigma, amp), cands in sorted(by_kernel.items(), key=lambda kv: (kv[0][0],
                                                                             kv[0][1] or 0)):
            grams: dict[tuple[str, int], list] = {}
            for recipe in sorted({c.recipe for c in cands}):
                mine = [c for c in cands if c.recipe == recipe]
                for s in split_ids:
                    key = (recipe.negatives, s)
                    if key not in grams:
                        grams[key] = blocks.grams(key, sigma, amp)
                    res = _score_split(grams[key], Y, y, n_classes, recipe, mine, splits[s],
                                       svm_train, scipy.linalg)
                    for c, r in zip(mine, res):
                        out[(c, s)] = r
    return out


class _SplitBlocks:
    """The blocks of the patterns' summed distances (and of the amplitude factors) that each
    split's machines train and predict on, sliced once per task: a kernel is then the
    exponential of these blocks, not of the whole matrix. Machines given the same index array
    share their blocks (the same objects)."""

    def __init__(self, dist_sum: np.ndarray, energies: np.ndarray,
                 trains: Mapping[tuple[str, int], list[np.ndarray]], splits: list) -> None:
        self.dist_sum, self.energies, self.trains, self.splits = dist_sum, energies, trains, splits
        self._cut: dict[tuple, list[tuple]] = {}
        self._factors: dict[float, float] = {}  # amplitude -> the factor's width
        self._exp: dict[tuple, list[tuple]] = {}  # the Gaussians of one sigma, per machine set
        self._exp_sigma: float | None = None

    def _sliced(self, M: np.ndarray, key: tuple[str, int], name: Any) -> list[tuple]:
        """(indices, M[train, train], M[held-out, train]) of each machine of ``key``."""
        if (name, key) not in self._cut:
            te = self.splits[key[1]][1]
            made: dict[int, tuple] = {}
            for trk in self.trains[key]:
                if id(trk) not in made:
                    made[id(trk)] = (trk, M[np.ix_(trk, trk)], M[np.ix_(te, trk)])
            self._cut[(name, key)] = [made[id(trk)] for trk in self.trains[key]]
        return self._cut[(name, key)]

    def _gaussians(self, key: tuple[str, int], sigma: float) -> list[tuple]:
        """(indices, exp(-dist / (2 sigma^2)) of the training block, of the held-out block) per
        machine of ``key``: computed once per sigma and shared by its amplitude widths (the
        blocks of the sigma before are dropped)."""
        if sigma != self._exp_sigma:
            self._exp, self._exp_sigma = {}, sigma
        if key not in self._exp:
            g = -0.5 / (sigma * sigma)
            made: dict[int, tuple] = {}
            for trk, Dtr, Dte in self._sliced(self.dist_sum, key, "distances"):
                if id(trk) not in made:
                    made[id(trk)] = (trk, _gaussian(Dtr, g), _gaussian(Dte, g))
            self._exp[key] = [made[id(trk)] for trk in self.trains[key]]
        return self._exp[key]

    def grams(self, key: tuple[str, int], sigma: float, amp: float | None) -> list[tuple]:
        """(training indices, training Gram block, held-out-by-training block) per machine."""
        from eskin.learn.estimators import amplitude_factor, amplitude_width

        gauss = self._gaussians(key, sigma)
        if amp is None:
            return gauss
        if (amp, key) not in self._cut:  # the factor's blocks, not the whole matrix sliced
            e, te = self.energies, self.splits[key[1]][1]
            width = self._factors.setdefault(amp, amplitude_width(amp, e))
            made: dict[int, tuple] = {}
            for trk in self.trains[key]:
                if id(trk) not in made:
                    made[id(trk)] = (trk, amplitude_factor(e[trk], e[trk], width),
                                     amplitude_factor(e[te], e[trk], width))
            self._cut[(amp, key)] = [made[id(trk)] for trk in self.trains[key]]
        made = {}
        out = []
        for (trk, Etr, Ete), (_, Ftr, Fte) in zip(gauss, self._cut[(amp, key)]):
            if id(trk) not in made:
                made[id(trk)] = (trk, Etr * Ftr, Ete * Fte)
            out.append(made[id(trk)])
        return out


def _gaussian(dist: np.ndarray, g: float) -> np.ndarray:
    """exp(g dist), in one new array."""
    K = np.multiply(dist, g)
    np.exp(K, out=K)
    return K


def _score_split(blocks, Y, y, n_classes, recipe, cands, split, svm_train, linalg):
    """(error, support vectors, whether a machine collapsed) of each candidate of one recipe
    and kernel on one split, from its machines' Gram blocks (:meth:`_SplitBlocks.grams`)."""
    tr, te = split
    results = []
    if recipe.machine == "rls" and recipe.negatives == "all":
        # the machines share their training set: one factorisation per lambda for all of them
        _, Ktr, Kte = blocks[0]
        for c in cands:
            A = Ktr + c.lam * np.eye(len(tr))
            B = linalg.cho_solve(linalg.cho_factor(A, lower=True, check_finite=False),
                                 Y[tr], check_finite=False)
            F = Kte @ B
            results.append((float(np.mean(_predict(F, n_classes) != y[te])), len(tr),
                            collapsed(F, np.zeros(F.shape[1]))))
        return results
    # a C-SVM solution none of whose dual coefficients sits at the box bound C is also the
    # solution for every larger C (its optimality conditions do not involve C): the candidates
    # are fitted by increasing C and such a machine stands for the larger C's
    free: list[tuple | None] = [None] * len(blocks)
    by_C = sorted(range(len(cands)), key=lambda i: (-cands[i].lam, i))
    results: list[tuple | None] = [None] * len(cands)
    reach, trained = _kernel_reach(blocks) if recipe.machine == "svm" else (math.inf, 0)
    for i in by_C:
        c = cands[i]
        if reach / c.lam < COLLAPSE_TOLERANCE:
            results[i] = (1.0, trained, True)  # collapsed whatever the fit: none is made
            continue
        F = np.empty((len(te), Y.shape[1]))
        b0 = np.zeros(Y.shape[1])
        used = np.zeros(len(y), bool)
        for k, (trk, Ktr, Kte) in enumerate(blocks):
            yk = Y[trk, k]
            if recipe.machine == "rls":
                beta = _solve_pos(Ktr, c.lam, yk, linalg)
                b, support = 0.0, np.arange(len(trk))
            elif free[k] is not None:
                beta, b, support = free[k]
            else:
                beta, b, support = svm_train(Ktr, yk, 1.0 / c.lam)
                if len(support) and np.max(np.abs(beta[support])) < 1.0 / c.lam:
                    free[k] = (beta, b, support)
            F[:, k] = Kte[:, support] @ beta[support] + b
            b0[k] = b
            used[trk[support]] = True
        results[i] = (float(np.mean(_predict(F, n_classes) != y[te])), int(used.sum()),
                      collapsed(F, b0))
    return results


def _solve_pos(K: np.ndarray, lam: float, y: np.ndarray, linalg: Any) -> np.ndarray:
    """(K + lam I)^-1 y by LAPACK's Cholesky solver (posv), K symmetric positive
    semi-definite; numpy's LinAlgError when K + lam I is not positive definite."""
    A = K + lam * np.eye(len(K))
    _, x, info = linalg.lapack.dposv(A, y, lower=False, overwrite_a=True)
    if info != 0:
        raise np.linalg.LinAlgError(f"K + lambda I is not positive definite (lambda = {lam:g}: "
                                    f"the leading minor of order {info} is not)")
    return x


def _kernel_reach(blocks: list[tuple]) -> tuple[float, int]:
    """(the largest sum of a held-out pattern's kernel values over a machine's training
    patterns, over the machines; the training patterns of the machines together).

    A C-SVM's dual coefficients are at most C, so a machine's held-out decision values lie
    within C times that sum of its intercept: when C times it is below
    :data:`COLLAPSE_TOLERANCE`, every machine of the candidate has collapsed, whatever its fit
    (its scores are error 1.0 and no fit is made). Its kernel is then the identity to within
    that tolerance on the training patterns too, where every training pattern is a support
    vector: the count the fit would give."""
    made: dict[int, float] = {}
    used: set[int] = set()
    for trk, _, Kte in blocks:
        if id(trk) not in made:
            made[id(trk)] = math.inf if Kte.shape[0] == 0 else float(Kte.sum(axis=1).max())
            used.update(trk.tolist())
    return max(made.values()), len(used)


# --------------------------------------------------------------------------------------------
# the search


@dataclass
class CandidateBudget:
    """Whether a candidate's compiled model fits a controller: ``fits(candidate, n_support)``
    with the expected support vectors of the whole model (a callable built by
    :mod:`eskin.deploy.target` from its cost model; this layer only calls it)."""

    fits: Callable[[Candidate, int], bool]
    description: str = ""
    #: optional ``largest(candidate, n_support)``: the most support vectors, at most
    #: ``n_support``, with which the candidate's model fits (0: none). With it, a candidate
    #: expected to need more is kept with its support vectors bounded to that many
    #: (:func:`eskin.learn.support_budget.bound_support`), when the bound keeps at least
    #: ``keep_share`` of them.
    largest: Callable[[Candidate, int], int] | None = None
    keep_share: float = 0.5
    #: whether the budget trades D against alpha and the support vectors (a controller's and
    #: the host's: the order of preference then leaves D out, :func:`budget_preference`);
    #: False keeps :func:`recipe_preference`
    trades_D: bool = True


@dataclass
class _Row:
    candidate: Candidate
    errors: dict[int, float] = field(default_factory=dict)
    support: dict[int, int] = field(default_factory=dict)
    fits: bool = True
    bound: int | None = None  # support vectors the model is bounded to under the budget
    collapsed: set[int] = field(default_factory=set)  # splits where a machine's kernel collapsed

    @property
    def mean(self) -> float:
        return float(np.mean(list(self.errors.values())))


def _record_scores(rows: Mapping[Candidate, _Row],
                   res: Mapping[tuple[Candidate, int], tuple[float, int, bool]]) -> None:
    """A task's scores into the rows; a split where a machine's kernel collapsed counts as
    error 1.0."""
    for (c, s), (err, nsv, flat) in res.items():
        rows[c].errors[s] = 1.0 if flat else err
        rows[c].support[s] = nsv
        if flat:
            rows[c].collapsed.add(s)


def _collapse_note(collapsed: Sequence[tuple[Candidate, list[int]]]) -> str | None:
    """The note on the candidates whose kernel collapsed on some split, or None."""
    if not collapsed:
        return None
    n, splits = len(collapsed), sum(len(s) for _, s in collapsed)
    return (f"{n} candidate{'s' if n != 1 else ''} had a collapsed kernel on {splits} "
            f"split{'s' if splits != 1 else ''} (a machine's held-out decision values all within "
            f"{COLLAPSE_TOLERANCE:g} of its intercept), counted as error 1.0 there")


def _check_budget(budget: CandidateBudget, row: _Row, expected: int) -> None:
    """Whether the row's candidate, expected to need ``expected`` support vectors, fits the
    budget: as it is, or bounded to the most that fit (``row.bound``) when that keeps at least
    ``budget.keep_share`` of them."""
    row.fits, row.bound = budget.fits(row.candidate, expected), None
    if row.fits or budget.largest is None:
        return
    most = int(budget.largest(row.candidate, expected))
    if most >= max(1, math.ceil(budget.keep_share * expected)):
        row.fits, row.bound = True, most


def _preferred_recipe(
    rows: Mapping[Candidate, _Row], final: list[Candidate], splits: list, tolerance: float,
    significance: float, key: Callable[[Recipe], tuple] = recipe_preference,
) -> tuple[Recipe, dict[str, Any]]:
    """(the recipe of the best candidate of the most preferred family (recipes of one ``key``)
    of the last round that is not significantly worse than the lowest-error candidate
    ``final[0]``, the record of the test)."""
    lowest = final[0]
    share = float(np.mean([len(te) / (len(tr) + len(te)) for tr, te in splits]))
    ids = sorted(rows[lowest].errors)
    for family in sorted({key(c.recipe) for c in final}):
        own = next(c for c in final if key(c.recipe) == family)  # final is sorted by error
        recipe = own.recipe
        diffs = [rows[own].errors[s] - rows[lowest].errors[s] for s in ids]
        gap = float(np.mean(diffs))
        within = gap <= tolerance + 1e-12  # less than one held-out pattern worse: kept (p = 1)
        t, p = (0.0, 1.0) if within else corrected_paired_t(diffs, share)
        if p >= significance:
            return recipe, {
                "recipe": recipe.label(), "lowest": lowest.recipe.label(),
                "gap": round(gap, 6), "within_one_pattern": within,
                "t": round(float(t), 4) if math.isfinite(t) else None,
                "p": round(float(p), 6), "significance": significance,
            }
    raise AssertionError("the lowest-error candidate's own recipe always qualifies")


def _whole_grid(grid: Sequence[tuple], key: Callable[[Recipe], tuple], alive: list[Candidate],
                rows: Mapping[Candidate, _Row], rank: Callable[[_Row], tuple]
                ) -> list[Candidate]:
    """The candidates of the likeliest choice not scored yet: the most preferred recipe (by
    ``key``) that fits gets the whole ``grid``, not the sample. Under a budget that trades D the
    most preferred family holds a recipe per D: its recipe ranked first on the sample (by
    ``rank``) gets the whole grid (the others of the family keep their sample)."""
    top = min(key(c.recipe) for c in alive)
    family = [c for c in alive if key(c.recipe) == top]
    recipe = min(family, key=lambda c: rank(rows[c])).recipe
    return [Candidate(recipe, *g) for g in grid if Candidate(recipe, *g) not in rows]


class RecipeSearch:
    """Successive halving over recipes and grid settings by grouped cross-validation.

    Parameters
    ----------
    recipes : the recipes to choose from (:func:`recipe_space`).
    lambdas, sigmas, alphas, amplitudes : the grid (alpha labels "1", "Q/2", "Q"; amplitude
        None for the paper's kernel); one setting is shared by a model's machines.
    n_splits, test_size : the cross-validation (splits holding out ``test_size`` of the groups).
    eta : the halving factor (each round keeps the best 1/eta of its candidates).
    growth : the factor of the splits from one round to the next (1, growth, growth^2, ...,
        then all ``n_splits``): each round scores a third of the candidates on twice the
        splits by default, so the candidates of the first rounds, the most, are scored on the
        fewest splits.
    first_share : the share of the grid every recipe is scored on in the first round (the same
        seeded sample for every recipe; a grid of at most :data:`SMALL_GRID` settings whole).
    budget : optional :class:`CandidateBudget`; candidates that do not fit are dropped.
    significance : the level of the paired test that lets a recipe other than the most
        preferred one be chosen (see the module docstring); None: the lowest error wins.
    seed, n_jobs : seeds of every random choice; joblib workers (any backend).

    Attributes after :meth:`fit`: ``best_`` (the chosen Candidate), ``best_error_``,
    ``best_bound_`` (the support vectors its model is bounded to under the budget, or None),
    ``ranking_`` (the final round's candidates, best first: candidate, error, std, splits,
    support vectors), ``recipe_table_`` (per recipe: its best, ties broken as the ranking's),
    ``rounds_`` (candidates and splits per round), ``n_evaluations_`` (candidate-split scores),
    ``splits_``, ``seconds_``.
    """

    def __init__(
        self,
        recipes: Sequence[Recipe],
        lambdas: Sequence[float],
        sigmas: Sequence[float],
        alphas: Sequence[str],
        amplitudes: Sequence[float | None],
        *,
        n_splits: int = 10,
        test_size: float = 0.3,
        eta: int = 3,
        growth: int = 2,
        first_share: float = 0.10,
        budget: CandidateBudget | None = None,
        significance: float | None = 0.05,
        seed: int = 0,
        n_jobs: int | None = 1,
        memory_limit: int | None = DEFAULT_MEMORY_LIMIT,
    ) -> None:
        if not recipes:
            raise TrainingError("the recipe search has no recipe to try")
        if (int(n_splits) < 1 or int(eta) < 2 or int(growth) < 2
                or not 0 < float(first_share) <= 1):
            raise TrainingError("n_splits must be >= 1, eta and growth >= 2 and first_share "
                                "in (0, 1]")
        self.recipes = list(dict.fromkeys(recipes))  # each once, in the order given
        self.grid = [(float(la), float(s), str(a), am) for la in lambdas for s in sigmas
                     for a in alphas for am in amplitudes]
        if not self.grid:
            raise TrainingError("the grid needs at least one lambda, sigma, alpha and amplitude")
        self.n_splits, self.test_size, self.eta = int(n_splits), float(test_size), int(eta)
        self.growth = int(growth)
        self.first_share, self.budget = float(first_share), budget
        if significance is not None and not 0 < float(significance) < 1:
            raise TrainingError(f"significance must be in (0, 1) or None, got {significance}")
        self.significance = None if significance is None else float(significance)
        self.seed, self.n_jobs = int(seed), n_jobs
        self.memory_limit = None if memory_limit is None else int(memory_limit)

    # -- plan ------------------------------------------------------------------------------
    def _splits(self, y: np.ndarray, groups: np.ndarray | None) -> list:
        from sklearn.model_selection import (
            GroupShuffleSplit,
            ShuffleSplit,
            StratifiedShuffleSplit,
        )

        idx = np.zeros(len(y))
        if groups is not None:
            sp = GroupShuffleSplit(self.n_splits, test_size=self.test_size,
                                   random_state=self.seed)
            splits = list(sp.split(idx, y, groups))
        else:
            sp = StratifiedShuffleSplit(self.n_splits, test_size=self.test_size,
                                        random_state=self.seed)
            try:
                splits = list(sp.split(idx, y))
            except ValueError:  # too few recordings to hold out one of each class
                sp = ShuffleSplit(self.n_splits, test_size=self.test_size,
                                  random_state=self.seed)
                splits = list(sp.split(idx, y))
        for i, (tr, _) in enumerate(splits):
            if np.unique(y[tr]).size < np.unique(y).size:
                lacking = sorted(set(np.unique(y).tolist()) - set(np.unique(y[tr]).tolist()))
                raise ClassLeftOut(
                    f"cross-validation split {i} left class {lacking[0]} out of its training "
                    "part; use more groups, a smaller test_size or another random_state")
        return [(np.sort(tr), np.sort(te)) for tr, te in splits]

    def _schedule(self) -> list[int]:
        """Splits scored after each round: 1, growth, growth^2, ..., then all n_splits
        (instead of the last power of growth below it)."""
        sched, r = [], 1
        while r * self.growth <= self.n_splits:
            sched.append(r)
            r *= self.growth
        return sched + [self.n_splits]

    def _first_candidates(self) -> list[Candidate]:
        rng = np.random.default_rng(np.random.SeedSequence([self.seed, 22]))
        # a small grid is scored whole (a share of it would leave each recipe a setting or two)
        m = max(math.ceil(self.first_share * len(self.grid)), min(len(self.grid), SMALL_GRID))
        picks = np.sort(rng.choice(len(self.grid), size=min(m, len(self.grid)), replace=False))
        return [Candidate(r, *self.grid[i]) for r in self.recipes for i in picks]

    # -- run -------------------------------------------------------------------------------
    def fit(
        self,
        patterns: Mapping[tuple[int, str], np.ndarray],
        y: np.ndarray,
        groups: np.ndarray | None = None,
    ) -> RecipeSearch:
        """Run the search on ``patterns`` ({(D, subsample): (n, rows, cols, D) array} for every
        recipe's variant), class indices ``y`` (0..k-1) and the groups the splits keep apart."""
        from eskin.learn.parallel import run_calls, share

        t0 = time.perf_counter()
        y = np.asarray(y, np.int64)
        n_classes = int(y.max()) + 1 if len(y) else 0
        if n_classes < 2 or np.unique(y).tolist() != list(range(n_classes)):
            raise TrainingError(f"y must hold the class indices 0..k-1 of k >= 2 classes, each "
                                f"at least once: got {np.unique(y).tolist()}")
        missing = {r.variant for r in self.recipes} - set(patterns)
        if missing:
            raise TrainingError(f"no patterns for the variants {sorted(missing)}")
        self.splits_ = self._splits(y, groups)
        rows = {c: _Row(c) for c in self._first_candidates()}
        alive = list(rows)
        # the tasks' data: on a Dask cluster scattered to every worker once, for every round
        common = share({"y": y, "splits": self.splits_})
        distances: dict[tuple[int, str, str], dict[str, Any]] = {}
        self.rounds_, self.n_evaluations_ = [], 0

        def score(cands: list[Candidate], split_ids: list[int]) -> list[Candidate]:
            """Score the candidates on the splits; the ones that fit the budget."""
            tasks: dict[tuple[int, str, str], list[Candidate]] = {}
            for c in cands:
                tasks.setdefault((*c.recipe.variant, c.alpha), []).append(c)
            for key in tasks:
                if key not in distances:  # once per (D, subsampling, alpha), for every round
                    dist_sum, energies = self._distances(patterns[key[:2]], key[2])
                    distances[key] = share({"dist_sum": dist_sum, "energies": energies})
            # one task per (D, subsampling, alpha) and split: the recipes and their inner folds
            calls = [((), {**distances[key], **common, "n_classes": n_classes,
                           "candidates": group, "split_ids": [s], "seed": self.seed})
                     for key, group in sorted(tasks.items()) for s in split_ids]
            for res in run_calls(_score_task, calls, n_jobs=self.n_jobs):
                _record_scores(rows, res)
            self.n_evaluations_ += len(cands) * len(split_ids)
            if self.budget is None:
                return cands
            for c in cands:
                _check_budget(self.budget, rows[c], self._expected_support(rows[c], len(y)))
            return [c for c in cands if rows[c].fits]

        done = 0
        schedule = self._schedule()
        for r, upto in enumerate(schedule):
            new = list(range(done, upto))
            scored = list(alive)
            alive = score(alive, new)
            if r == 0 and self.significance is not None and alive:
                more = _whole_grid(self.grid, self._preference_key(), alive, rows, self._key)
                for c in more:
                    rows[c] = _Row(c)
                scored += more
                alive += score(more, new)
            if not alive:
                raise TrainingError(
                    f"no candidate fits the budget ({self.budget.description}); the "
                    f"smallest needs {min(self._expected_support(rows[c], len(y)) for c in scored)} "
                    "support vectors: record fewer patterns per class, or raise the budget"
                )
            done = upto
            self.rounds_.append({"candidates": len(alive), "splits": upto})
            alive = sorted(alive, key=lambda c: self._key(rows[c]))
            if r < len(schedule) - 1:
                alive = self._survivors(alive)
        self._finish(rows, alive, len(y))
        self.collapsed_ = [(r.candidate, sorted(r.collapsed)) for r in rows.values() if r.collapsed]
        self.seconds_ = time.perf_counter() - t0
        return self

    def _survivors(self, ranked: list[Candidate]) -> list[Candidate]:
        """The best 1/eta of the ranked candidates and, when a preference applies, the best
        1/eta of the most preferred recipe's own (so that it reaches the last round)."""
        keep = ranked[: max(1, math.ceil(len(ranked) / self.eta))]
        if self.significance is None:
            return keep
        key = self._preference_key()
        top = min(key(c.recipe) for c in ranked)
        mine = [c for c in ranked if key(c.recipe) == top]
        kept = set(keep) | set(mine[: max(1, math.ceil(len(mine) / self.eta))])
        return [c for c in ranked if c in kept]

    def _distances(self, X: np.ndarray, alpha: str) -> tuple[np.ndarray, np.ndarray]:
        """:func:`pattern_distances` within :attr:`memory_limit`."""
        return pattern_distances(X, alpha, self.memory_limit)

    def _key(self, row: _Row) -> tuple:
        c = row.candidate
        # ties: the simpler machine (larger lambda, larger sigma, no amplitude factor, smaller D)
        return (row.mean, -c.lam, -c.sigma, c.amplitude is not None, c.recipe.D,
                c.recipe.label(), c.alpha)

    def _preference_key(self) -> Callable[[Recipe], tuple]:
        """:func:`recipe_preference`, or :func:`budget_preference` under a budget."""
        if self.budget is None or not self.budget.trades_D:
            return recipe_preference
        return budget_preference

    def _expected_support(self, row: _Row, n: int) -> int:
        """Support vectors of the model trained on all ``n`` patterns, from the splits' counts
        (scaled by the share of patterns the splits trained on)."""
        share = np.mean([len(self.splits_[s][0]) for s in row.support]) / n
        return int(math.ceil(np.mean(list(row.support.values())) / share))

    def _finish(self, rows: dict[Candidate, _Row], final: list[Candidate], n: int) -> None:
        # equally good: less than one held-out pattern apart over all the splits together
        tolerance = 1.0 / sum(len(te) for _, te in self.splits_)
        lowest = final[0]
        recipe, self.preference_ = lowest.recipe, None
        if self.significance is not None and len(self.splits_) >= 2:
            recipe, self.preference_ = _preferred_recipe(rows, final, self.splits_, tolerance,
                                                         self.significance,
                                                         self._preference_key())
        mine = [c for c in final if c.recipe == recipe]
        best_err = rows[mine[0]].mean
        tied = [c for c in mine if rows[c].mean <= best_err + tolerance + 1e-12]
        best = min(tied, key=lambda c: (self._expected_support(rows[c], n), self._key(rows[c])))
        self.best_ = best
        self.best_error_ = rows[best].mean
        self.best_bound_ = rows[best].bound
        self.tolerance_ = tolerance

        def entry(c: Candidate) -> dict[str, Any]:
            row = rows[c]
            errs = np.array(list(row.errors.values()))
            return {"candidate": c, "error": float(errs.mean()), "std": float(errs.std()),
                    "splits": len(errs), "support_vectors": self._expected_support(row, n),
                    "support_bound": row.bound, "split_errors": [row.errors[s] for s in sorted(row.errors)]}

        self.ranking_ = [entry(best)] + [entry(c) for c in final if c != best]
        # per recipe, its candidate scored on the most splits, then of the lowest error, then
        # the one the ranking's tie-break prefers (the simpler machine, self._key)
        per_recipe: dict[Recipe, list[Candidate]] = {}
        for c, row in rows.items():
            if row.errors and (self.budget is None or row.fits):
                per_recipe.setdefault(c.recipe, []).append(c)
        table = [entry(min(cs, key=lambda c: (-len(rows[c].errors), self._key(rows[c]))))
                 for cs in per_recipe.values()]
        self.recipe_table_ = sorted(table, key=lambda e: (-e["splits"], e["error"]))

    # -- reports ---------------------------------------------------------------------------
    def collapse_note(self) -> str | None:
        """What the search says when some candidate's kernel collapsed, else None."""
        return _collapse_note(self.collapsed_)

    def report(self, runners_up: int = 3) -> dict[str, Any]:
        """JSON-friendly record: the choice, its estimate, the runners-up (the best candidate of
        each other recipe, furthest round first), the rounds and the cost."""

        def plain(e: Mapping[str, Any]) -> dict[str, Any]:
            return {**e["candidate"].as_dict(), "cv_error": round(e["error"], 6),
                    "cv_std": round(e["std"], 6), "splits": e["splits"],
                    "support_vectors": e["support_vectors"],
                    **({} if e.get("support_bound") is None
                       else {"support_bound": e["support_bound"]})}

        best = self.ranking_[0]
        others = [e for e in self.recipe_table_ if e["candidate"].recipe != self.best_.recipe]
        return {
            "method": (f"successive halving over {len(self.recipes)} recipes x "
                       f"{len(self.grid)} settings (eta {self.eta}, first round "
                       f"{self.first_share:g} of the grid), multi-class error on "
                       f"{self.n_splits} participant-grouped splits"
                       + ("" if self.significance is None else
                          f"; the most preferred recipe not significantly worse than the "
                          f"lowest error (corrected paired t-test, level "
                          f"{self.significance:g})")),
            "chosen": plain(best),
            "runners_up": [plain(e) for e in others[:runners_up]],
            "recipes": [plain(e) for e in self.recipe_table_],
            "rounds": list(self.rounds_),
            "evaluations": int(self.n_evaluations_),
            "tie_tolerance": round(float(self.tolerance_), 6),
            "budget": None if self.budget is None else self.budget.description,
            "preference": self.preference_,
            "collapsed": self.collapse_note(),
            "seconds": round(float(self.seconds_), 3),
        }
