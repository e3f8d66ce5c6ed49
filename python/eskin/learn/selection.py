"""Model selection for the tensor machines: Maximal Discrepancy (Algorithm 1) and CV.

:class:`MaximalDiscrepancySearch` picks the (lambda, sigma, alpha) that minimises the bound of
Eq. (6), ``pi_hat = v + chi + tau``, with the complexity ``chi`` estimated by the paper's
Algorithm 1 (read as readings R10-R17 of ``docs/paper-readings.md`` say; how the code follows
each is in ``docs/learning.md``).
:class:`CrossValidationSearch` is the conventional selection it is compared with (Section 4.2,
Figure 7): repeated random splits of the training set, optionally grouped by participant.

Both take a grid over ``lam`` (or ``C``), ``sigma``, ``alpha`` and ``amplitude`` (the
amplitude-aware kernel's width, None for the paper's kernel), for either machine: a grid in
``lam`` given to a :class:`~eskin.estimators.TensorSVC` means ``C = 1/lam`` (reading R9), and a grid
in ``C`` given to a :class:`~eskin.estimators.TensorRLS` means ``lam = 1/C``. Every
configuration's numbers are in ``cv_results_`` (a dict of arrays, one entry per configuration);
``best_params_`` are the estimator's own parameters (``C`` for the SVM, ``lam`` for RLS) and
``best_estimator_`` is refitted on all the data.

How the work is shared out: the per-mode distances are computed once per alpha
(``eskin.mode_distances``) and reused for every sigma (``K = exp(-sum_z d_z/(2 sigma_z^2))``).
The amplitude factor depends only on the patterns' log energies (computed once) and on
``amplitude``. The work is cut into (alpha, sigma, amplitude) blocks, run with joblib (``n_jobs``, any backend, Dask
included). Within a block, kernel k-means runs once, RLS goes through one eigendecomposition of
K reused for every lambda and every random labelling, and the SVM is libsvm on the precomputed
K. Every random draw is seeded from ``random_state`` and the configuration (or block) index,
never from the execution order, and BLAS runs single-threaded inside a block, so results are
identical for any ``n_jobs`` and backend.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

import numpy as np
from sklearn.base import BaseEstimator, ClassifierMixin, clone
from sklearn.model_selection import GroupShuffleSplit, ParameterGrid, StratifiedShuffleSplit
from sklearn.utils.validation import check_is_fitted, check_random_state, validate_data
from threadpoolctl import ThreadpoolController

from eskin.errors import ClassLeftOut

from .estimators import (
    KMEANS_METHODS,
    TensorRLS,
    TensorSVC,
    amplitude_factor,
    amplitude_width,
    as_tensors,
    binary_targets,
    check_amplitude,
    kernel_from_distances,
    kernel_kmeans,
    sigma_tuple,
    svm_train,
)
from .kernel import mode_distances, pattern_log_energy, resolve_alphas
from .parallel import run_calls

__all__ = [
    "MD_READINGS",
    "PAPER_GRID",
    "CrossValidationSearch",
    "MaximalDiscrepancySearch",
    "md_reading",
    "md_tau",
    "rls_eig_solve",
]

#: The paper's grid (Section 5.2, reading R21), in lambda for both machines.
PAPER_GRID = {
    "lam": [1e-3, 1e-2, 1e-1, 1e0, 1e1],
    "sigma": [2.0**k for k in range(-4, 5)],
    "alpha": [1, "half", "full"],
}

_SEARCHABLE = ("lam", "C", "sigma", "alpha", "amplitude")

#: Named readings of Algorithm 1: name -> (MaximalDiscrepancySearch options, what it means).
#: Each option is documented in the class and in docs/learning.md; docs/selection-study.md
#: measures them against each other and against cross-validation.
MD_READINGS: dict[str, tuple[dict, str]] = {
    "default": (
        {"clustering": "lloyd", "gamma0": "nearer", "reference": "clustering", "chi": "mean",
         "flip": "auto"},
        (
            "Algorithm 1 with the clustering reference; plain Lloyd kernel k-means from random "
            "labels (lowest inertia over restarts); Gamma_0 of the nearer of beta(+)/beta(-); "
            "random labellings flipping half of each class for the SVM (its bias cannot then "
            "fit a labelling by predicting its majority class) and a uniformly random half for "
            "RLS; chi averaged over the labellings"
        ),
    ),
    "kmeans++": (
        {"clustering": "kmeans++", "gamma0": "nearer", "reference": "clustering", "chi": "mean",
         "flip": "uniform"},
        (
            "Algorithm 1 with the clustering reference; kernel k-means by k-means++ seeding, "
            "Lloyd and Hartigan moves (lowest inertia over restarts); Gamma_0 of the nearer of "
            "beta(+)/beta(-); labellings flipping a uniformly random half; chi averaged over "
            "the random labellings (eskin's first reading)"
        ),
    ),
    "lloyd": (
        {"clustering": "lloyd", "gamma0": "nearer", "reference": "clustering", "chi": "mean",
         "flip": "uniform"},
        (
            "Algorithm 1 with the clustering reference; plain Lloyd kernel k-means from random "
            "labels (lowest inertia over restarts); Gamma_0 of the nearer of beta(+)/beta(-); "
            "labellings flipping a uniformly random half; chi averaged over the labellings"
        ),
    ),
    "balanced": (
        {"clustering": "balanced", "gamma0": "nearer", "reference": "clustering", "chi": "mean",
         "flip": "uniform"},
        (
            "Algorithm 1 with the clustering reference; size-constrained kernel 2-means (two "
            "equal halves); Gamma_0 of the nearer of beta(+)/beta(-); labellings flipping a "
            "uniformly random half; chi averaged"
        ),
    ),
    "true-norm": (
        {"reference": "true-norm", "chi": "mean", "flip": "uniform"},
        (
            "Anguita et al.'s hypothesis space: each random labelling (a uniformly random half "
            "flipped) is trained under the norm of the machine trained on the true labels "
            "(Gamma_0 = Gamma(RKM), no clustering); chi averaged"
        ),
    ),
    "same-lambda": (
        {"reference": "same-lambda", "chi": "mean", "flip": "uniform"},
        (
            "Anguita et al. in Tikhonov form: each random labelling (a uniformly random half "
            "flipped) is trained with the same lambda as the true labels (no norm constraint, "
            "no clustering); chi averaged"
        ),
    ),
}


def md_reading(name: str) -> dict:
    """The MaximalDiscrepancySearch options of a named reading (see :data:`MD_READINGS`)."""
    if name not in MD_READINGS:
        known = sorted(MD_READINGS)
        raise ValueError(f"unknown Maximal Discrepancy reading {name!r}; known: {known}")
    return dict(MD_READINGS[name][0])


def md_tau(n: int, delta: float) -> float:
    """Finite-sample term of Eq. (6): ``tau = 3 sqrt(ln(2/delta) / (2n))`` (reading R16)."""
    return 3.0 * math.sqrt(math.log(2.0 / delta) / (2.0 * n))


def rls_eig_solve(w: np.ndarray, Q: np.ndarray, Y: np.ndarray, lam: float) -> np.ndarray:
    """RLS coefficients ``(K + lam I)^-1 Y`` from the eigendecomposition ``K = Q diag(w) Q^T``.

    ``Y`` may be one target (n,) or several (n, m) columns.
    """
    C = Q.T @ Y
    scale = 1.0 / (w + lam)
    return Q @ (C * (scale if C.ndim == 1 else scale[:, None]))


# --------------------------------------------------------------------------------------------
# configurations
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class _Config:
    index: int
    lam: float  # effective lambda (C = 1/lam for the SVM)
    est_params: dict  # parameters for set_params on the estimator
    alphas: tuple  # resolved alpha per mode
    sigmas: tuple  # sigma per mode
    amplitude: float | None = None  # the amplitude factor's width (spreads of log energy)


def _machine_kind(estimator) -> str:
    if isinstance(estimator, TensorSVC):
        return "svm"
    if isinstance(estimator, TensorRLS):
        return "rls"
    raise TypeError(
        f"model selection supports TensorSVC and TensorRLS, got {type(estimator).__name__}"
    )


def _hashable(value):
    if isinstance(value, (list, tuple, np.ndarray)):
        return tuple(_hashable(v) for v in value)
    return value


def _configurations(estimator, param_grid, pattern_shape):
    kind = _machine_kind(estimator)
    grid = list(ParameterGrid(param_grid))
    if not grid:
        raise ValueError("param_grid is empty")
    base = estimator.get_params()
    configs = []
    for i, p in enumerate(grid):
        unknown = set(p) - set(_SEARCHABLE)
        if unknown:
            raise ValueError(
                f"param_grid key(s) {sorted(unknown)} cannot be searched; use lam (or C), "
                "sigma, alpha, amplitude"
            )
        if "lam" in p and "C" in p:
            raise ValueError("param_grid gives both lam and C; give one (C = 1/lam)")
        if "lam" in p:
            lam = float(p["lam"])
        elif "C" in p:
            lam = 1.0 / float(p["C"])
        else:
            lam = float(base["lam"]) if kind == "rls" else 1.0 / float(base["C"])
        if not (np.isfinite(lam) and lam > 0):
            raise ValueError(f"lambda must be positive and finite, got {lam!r} in {p}")
        params = {k: v for k, v in p.items() if k not in ("lam", "C")}
        if kind == "rls":
            params["lam"] = lam
        else:
            params["C"] = 1.0 / lam
        sigma = params.get("sigma", base["sigma"])
        alpha = params.get("alpha", base["alpha"])
        alphas = tuple(int(a) for a in resolve_alphas(pattern_shape, alpha))
        sigmas = sigma_tuple(sigma, len(pattern_shape))
        amplitude = check_amplitude(params.get("amplitude", base.get("amplitude")))
        configs.append(_Config(i, lam, params, alphas, sigmas, amplitude))
    return kind, configs


def _blocks(configs):
    """Group configurations by (alphas, sigmas, amplitude): one kernel per block."""
    blocks: dict = {}
    for c in configs:
        blocks.setdefault((c.alphas, c.sigmas, c.amplitude), []).append(c)
    return list(blocks.items())


def _amplitude_factors(configs, energies):
    """{amplitude: the (n, n) factor, or None without one} for every amplitude of the grid;
    the width is relative to the spread of ``energies`` (the search's training patterns, as
    in the refitted estimator)."""
    factors = {}
    for c in configs:
        if c.amplitude not in factors:
            width = amplitude_width(c.amplitude, energies)
            factors[c.amplitude] = amplitude_factor(energies, energies, width)
    return factors


def _kernel(dists, sigmas, factor):
    """The Gram matrix of one block: the tensor kernel, times the amplitude factor if any."""
    K = kernel_from_distances(dists, sigmas)
    return K if factor is None else K * factor


def _resolve_seed(random_state) -> int:
    if isinstance(random_state, (numbers.Integral, np.integer)) and not isinstance(
        random_state, bool
    ):
        return int(random_state)
    return int(check_random_state(random_state).randint(np.iinfo(np.int32).max))


def _rng(seed: int, *key: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence(entropy=seed, spawn_key=key))


_KEY_LABELLINGS = 0
_KEY_KMEANS = 1
_KEY_SPLITS = 2


def _random_labellings(y_pm, n_labelings, seed, config_index, flip="uniform"):
    """(n, N) labellings, each flipping the sign of a random half of ``y`` (reading R13).

    "uniform": a uniformly random half of all labels (reading R13; the class balance of the
    labelling varies). "stratified": half of each class, so every labelling keeps the class
    counts of ``y`` (a variant, see docs/learning.md).
    """
    rng = _rng(seed, _KEY_LABELLINGS, config_index)
    n = y_pm.size
    Y = np.repeat(y_pm[:, None], n_labelings, axis=1)
    if flip == "uniform":
        order = np.argsort(rng.random((n_labelings, n)), axis=1)[:, : n // 2]
        for j in range(n_labelings):
            Y[order[j], j] *= -1.0
        return Y
    for cls in (-1.0, 1.0):
        members = np.flatnonzero(y_pm == cls)
        order = np.argsort(rng.random((n_labelings, members.size)), axis=1)
        for j in range(n_labelings):
            Y[members[order[j, : members.size // 2]], j] *= -1.0
    return Y


def _errors(F, Y):
    """Classification error of decision values F against -1/+1 targets (f > 0 means +1)."""
    return np.mean(np.where(F > 0, 1.0, -1.0) != Y, axis=0)


# --------------------------------------------------------------------------------------------
# Algorithm 1, one (alpha, sigma) block
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class _MDSettings:
    n_labelings: int
    eps: float
    max_lambda_steps: int
    n_init: int
    max_iter: int
    flip: str = "uniform"
    clustering: str = "kmeans++"
    gamma0: str = "nearer"
    reference: str = "clustering"


_MD_CHOICES = {
    "clustering": KMEANS_METHODS,
    "gamma0": ("nearer", "larger"),
    "reference": ("clustering", "true-norm", "same-lambda"),
    "chi": ("mean", "max"),
}

_CONTROLLER: list = []


def _single_threaded_blas():
    """Context limiting BLAS to one thread (the library scan is done once per process)."""
    if not _CONTROLLER:
        _CONTROLLER.append(ThreadpoolController())
    return _CONTROLLER[0].limit(limits=1, user_api="blas")


def _md_block(kind, dists, sigmas, factor, y, configs, settings, seed, block_index):
    """Algorithm 1 for every lambda of one (alpha, sigma, amplitude) block.

    Returns one dict per configuration: v, the N errors v*, chi, Gamma_0, lambda steps, cap hits.
    """
    with _single_threaded_blas():
        K = _kernel(dists, sigmas, factor)  # I. the kernel
        y_cl = None
        if settings.reference == "clustering":
            # II. two clusters by kernel k-means; X(a) is cluster 0
            labels, _, _ = kernel_kmeans(
                K, 2, settings.n_init, settings.max_iter, _rng(seed, _KEY_KMEANS, block_index),
                method=settings.clustering,
            )
            y_cl = np.where(labels == 0, 1.0, -1.0)
        if kind == "rls":
            rows = _md_block_rls(K, y, y_cl, configs, settings, seed)
        else:
            rows = _md_block_svm(K, y, y_cl, configs, settings, seed)
        # the smaller cluster's share of the patterns (0.5: equal halves; NaN: no clustering)
        minority = np.nan if y_cl is None else float(min(np.mean(y_cl > 0), np.mean(y_cl < 0)))
        for r in rows:
            r["minority"] = minority
        return rows


def _nearer(beta_plus, beta_minus, beta_rkm):
    """Step VI (reading R12): whichever of beta(+), beta(-) is nearer to beta(RKM)."""
    dp = np.linalg.norm(beta_plus - beta_rkm)
    dm = np.linalg.norm(beta_minus - beta_rkm)
    return beta_plus if dp <= dm else beta_minus


def _gamma_0(K, beta_plus, beta_minus, beta_rkm, how):
    """Step VI: Gamma_0 of the nearer ("nearer", reading R12) or the larger of beta(+)/beta(-)."""
    if how == "larger":
        return max(float(beta_plus @ K @ beta_plus), float(beta_minus @ K @ beta_minus))
    ref = _nearer(beta_plus, beta_minus, beta_rkm)
    return float(ref @ K @ ref)


def _md_block_rls(K, y, y_cl, configs, settings, seed):
    w, Q = np.linalg.eigh(K)  # one eigendecomposition per (sigma, alpha)
    qy = Q.T @ y
    qa = None if y_cl is None else Q.T @ y_cl
    steps_grid = np.arange(settings.max_lambda_steps + 1)
    out = []
    for cfg in configs:
        lam = cfg.lam
        s = 1.0 / (w + lam)
        # III. RC on the true labels: beta = Q diag(1/(w+lam)) Q^T y; f = K beta
        c_rkm = qy * s
        beta_rkm = Q @ c_rkm
        v = float(_errors(Q @ (w * c_rkm), y))
        if settings.reference == "clustering":
            # IV./V. the cluster labelling and its swap (reading R11); VI. Gamma_0 = beta^T K beta
            gamma0 = _rls_gamma_0(w, Q, qa * s, -qa * s, beta_rkm, settings.gamma0)
        elif settings.reference == "true-norm":
            gamma0 = float(np.sum(w * c_rkm * c_rkm))
        else:  # "same-lambda": no constraint, every labelling keeps lambda
            gamma0 = np.inf
        # VII. N random labellings, one projection C = Q^T Y*
        Ystar = _random_labellings(y, settings.n_labelings, seed, cfg.index, settings.flip)
        C = Q.T @ Ystar
        lams = lam * settings.eps**steps_grid  # lambda_hat <- eps * lambda_hat (reading R14)
        ratio = w[:, None] / (w[:, None] + lams[None, :]) ** 2  # (n, steps+1)
        gammas = ratio.T @ (C * C)  # Gamma*(lambda_hat) for every step and labelling
        ok = gammas <= gamma0
        cap_hit = ~ok.any(axis=0)
        steps = np.where(cap_hit, settings.max_lambda_steps, np.argmax(ok, axis=0))
        lam_hat = lams[steps]
        F = Q @ (C * (w[:, None] / (w[:, None] + lam_hat[None, :])))
        errs = _errors(F, Ystar)
        out.append(
            dict(
                v=v,
                errors=errs,
                gamma0=gamma0,
                steps=steps,
                cap_hits=int(cap_hit.sum()),
                n_support=int(K.shape[0]),
            )
        )
    return out


def _rls_gamma_0(w, Q, c_plus, c_minus, beta_rkm, how):
    """Step VI for RLS from eigen-coordinates (``Gamma = sum_i w_i c_i^2``)."""
    g_plus, g_minus = float(np.sum(w * c_plus**2)), float(np.sum(w * c_minus**2))
    if how == "larger":
        return max(g_plus, g_minus)
    beta_plus, beta_minus = Q @ c_plus, Q @ c_minus
    return g_plus if _nearer(beta_plus, beta_minus, beta_rkm) is beta_plus else g_minus


def _svm_fit_gamma(K, y, C):
    beta, b, support = svm_train(K, y, C)
    return beta, b, float(beta @ K @ beta), support


def _first_true(pred, guess: int, kmax: int):
    """Smallest k in [0, kmax] with pred(k) true, for a predicate monotone in k; None if none.

    Starts at ``guess``, gallops away from it (1, 2, 4, ... steps), then bisects: 2 calls when
    the guess is right, O(log) otherwise.
    """
    g = min(max(int(guess), 0), kmax)
    if pred(g):
        lo, hi, step = -1, g, 1  # pred(lo) is false (k = -1 stands for "below the range")
        while hi - lo > 1:
            cand = max(hi - step, lo + 1)
            if pred(cand):
                hi, step = cand, step * 2
            else:
                lo = cand
                break
    else:
        lo, step = g, 1
        while True:
            if lo == kmax:
                return None
            cand = min(lo + step, kmax)
            if pred(cand):
                hi = cand
                break
            lo, step = cand, step * 2
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if pred(mid):
            hi = mid
        else:
            lo = mid
    return hi


def _svm_labelling(K, ystar, lam, gamma0, eps, max_steps, strategy, guess=0):
    """Steps VII.c-f for one labelling of the SVM: the first k with Gamma*(lam eps^k) <= Gamma_0.

    "linear" tries k = 0, 1, 2, ... as printed. "search" starts from ``guess`` (the k of the
    previous labelling) and gallops/bisects (:func:`_first_true`): the same k whenever Gamma*
    does not increase with lambda (the SVM's ||w||^2 is non-increasing in lambda = 1/C), with
    2 fits instead of k + 1 when the guess is right.
    Returns (training error on ystar, k, cap hit).
    """
    cache = {}

    def fit(k):
        if k not in cache:
            beta, b, gamma, _ = _svm_fit_gamma(K, ystar, 1.0 / (lam * eps**k))
            cache[k] = (beta, b, gamma)
        return cache[k]

    def err(k):
        beta, b, _ = fit(k)
        return float(_errors(K @ beta + b, ystar))

    if strategy == "linear":
        for k in range(max_steps + 1):
            if fit(k)[2] <= gamma0:
                return err(k), k, False
        return err(max_steps), max_steps, True
    k = _first_true(lambda k: fit(k)[2] <= gamma0, guess, max_steps)
    if k is None:
        return err(max_steps), max_steps, True
    return err(k), k, False


def _md_block_svm(K, y, y_cl, configs, settings, seed, strategy="search"):
    out = []
    for cfg in configs:
        C = 1.0 / cfg.lam
        beta_rkm, b, gamma_rkm, support = _svm_fit_gamma(K, y, C)  # III.
        v = float(_errors(K @ beta_rkm + b, y))
        if settings.reference == "clustering":
            beta_plus = _svm_fit_gamma(K, y_cl, C)[0]  # IV.
            beta_minus = _svm_fit_gamma(K, -y_cl, C)[0]  # V. (swapped, reading R11)
            gamma0 = _gamma_0(K, beta_plus, beta_minus, beta_rkm, settings.gamma0)  # VI.
        elif settings.reference == "true-norm":
            gamma0 = gamma_rkm
        else:  # "same-lambda"
            gamma0 = np.inf
        Ystar = _random_labellings(y, settings.n_labelings, seed, cfg.index, settings.flip)
        errs = np.empty(settings.n_labelings)
        steps = np.empty(settings.n_labelings, dtype=np.intp)
        hits = 0
        guess = 0
        for j in range(settings.n_labelings):
            errs[j], steps[j], hit = _svm_labelling(
                K, Ystar[:, j], cfg.lam, gamma0, settings.eps, settings.max_lambda_steps,
                strategy, guess,
            )
            guess = int(steps[j])
            hits += int(hit)
        out.append(
            dict(v=v, errors=errs, gamma0=gamma0, steps=steps, cap_hits=hits,
                 n_support=int(len(support)))
        )
    return out


# --------------------------------------------------------------------------------------------
# conventional cross-validation, one (alpha, sigma) block
# --------------------------------------------------------------------------------------------
def _cv_block(kind, dists, sigmas, factor, y, configs, splits):
    """Validation and training errors of every lambda of one block on every split."""
    with _single_threaded_blas():
        K = _kernel(dists, sigmas, factor)
        test_err = np.empty((len(configs), len(splits)))
        train_err = np.empty((len(configs), len(splits)))
        for s, (tr, te) in enumerate(splits):
            Ktr = K[np.ix_(tr, tr)]
            Kte = K[np.ix_(te, tr)]
            ytr, yte = y[tr], y[te]
            if kind == "rls":
                w, Q = np.linalg.eigh(Ktr)
                qy = Q.T @ ytr
                for i, cfg in enumerate(configs):
                    c = qy / (w + cfg.lam)
                    beta = Q @ c
                    train_err[i, s] = _errors(Q @ (w * c), ytr)
                    test_err[i, s] = _errors(Kte @ beta, yte)
            else:
                for i, cfg in enumerate(configs):
                    beta, b, _ = svm_train(Ktr, ytr, 1.0 / cfg.lam)
                    train_err[i, s] = _errors(Ktr @ beta + b, ytr)
                    test_err[i, s] = _errors(Kte @ beta + b, yte)
        return test_err, train_err


# --------------------------------------------------------------------------------------------
# the two searches
# --------------------------------------------------------------------------------------------
def _select(criterion, configs):
    """Lowest criterion; ties go to the simpler machine: larger lambda, then larger sigma,
    then no amplitude factor, then a wider one."""
    crit = np.asarray(criterion, dtype=float)
    best = np.nanmin(crit)
    cand = np.flatnonzero(crit <= best + 1e-12)

    def simplicity(i):
        amp = configs[i].amplitude
        return (-configs[i].lam, -float(np.mean(configs[i].sigmas)),
                -(math.inf if amp is None else amp), i)

    key = sorted(cand, key=simplicity)
    return int(key[0])


class _SearchBase(ClassifierMixin, BaseEstimator):
    """Shared plumbing: grid, distances per alpha, parallel blocks, refit, delegation."""

    def _estimator(self):
        return TensorSVC() if self.estimator is None else self.estimator

    def _grid(self):
        return PAPER_GRID if self.param_grid is None else self.param_grid

    def _prepare(self, X, y):
        X, y = validate_data(self, X, y, allow_nd=True, dtype=np.float64)
        Xt = as_tensors(X, getattr(self._estimator(), "tensor_shape", None))
        self.classes_, y_pm = binary_targets(y, type(self).__name__)
        kind, configs = _configurations(self._estimator(), self._grid(), Xt.shape[1:])
        dists = {}
        for cfg in configs:  # per-mode distances once per alpha, reused for every sigma
            if cfg.alphas not in dists:
                dists[cfg.alphas] = mode_distances(Xt, alpha=cfg.alphas)
        factors = _amplitude_factors(configs, pattern_log_energy(Xt))
        return X, y, y_pm, kind, configs, dists, factors

    def _prepare_distances(self, distances, y, pattern_shape, energies=None):
        """As :meth:`_prepare`, from per-mode distances given per resolved alpha tuple (and the
        patterns' log energies when the grid has an amplitude factor)."""
        y = np.asarray(y)
        self.classes_, y_pm = binary_targets(y, type(self).__name__)
        kind, configs = _configurations(self._estimator(), self._grid(), tuple(pattern_shape))
        if energies is None and any(c.amplitude is not None for c in configs):
            raise ValueError("the grid has an amplitude factor: give the patterns' energies")
        if energies is not None and np.shape(energies) != (y_pm.size,):
            raise ValueError(f"energies has shape {np.shape(energies)}, expected ({y_pm.size},)")
        dists = {}
        for cfg in configs:
            if cfg.alphas not in distances:
                raise ValueError(f"no distances given for alphas {cfg.alphas}")
            d = np.asarray(distances[cfg.alphas], dtype=np.float64)
            if d.shape != (len(pattern_shape), y_pm.size, y_pm.size):
                raise ValueError(
                    f"distances for alphas {cfg.alphas} have shape {d.shape}, expected "
                    f"{(len(pattern_shape), y_pm.size, y_pm.size)}"
                )
            dists[cfg.alphas] = d
        factors = _amplitude_factors(configs, np.zeros(0) if energies is None else energies)
        return None, y, y_pm, kind, configs, dists, factors

    def _base_results(self, configs):
        res = {
            "params": [dict(c.est_params) for c in configs],
            "lam": np.array([c.lam for c in configs]),
            "C": np.array([1.0 / c.lam for c in configs]),
            "alphas": [c.alphas for c in configs],
            "sigmas": [c.sigmas for c in configs],
            "amplitudes": [c.amplitude for c in configs],
        }
        grid = list(ParameterGrid(self._grid()))
        for key in sorted({k for p in grid for k in p}):
            res[f"param_{key}"] = np.array([p.get(key) for p in grid], dtype=object)
        return res

    def _finish(self, X, y, configs, criterion):
        self.best_index_ = _select(criterion, configs)
        self.best_params_ = dict(configs[self.best_index_].est_params)
        self.best_criterion_ = float(np.asarray(criterion)[self.best_index_])
        self.n_configurations_ = len(configs)
        if self.refit and X is not None:
            self.best_estimator_ = clone(self._estimator()).set_params(**self.best_params_)
            self.best_estimator_.fit(X, y)
        return self

    def _best(self):
        check_is_fitted(self, "best_index_")
        if not self.refit:
            raise AttributeError("refit=False: no best_estimator_ to predict with")
        return self.best_estimator_

    def decision_function(self, X):
        """Decision values of ``best_estimator_``."""
        return self._best().decision_function(X)

    def predict(self, X):
        """Labels from ``best_estimator_``."""
        return self._best().predict(X)


class MaximalDiscrepancySearch(_SearchBase):
    """Model selection by Maximal Discrepancy with the clustering reference (Algorithm 1).

    For every configuration (lambda, sigma, alpha):

    - v: training error of the machine trained on the true labels (step III);
    - Gamma_0 = beta^T K beta of whichever of beta(+) (cluster a -> +1, b -> -1) and beta(-)
      (the swapped labelling) is nearer to beta(RKM) (steps II, IV-VI);
    - N artificial labellings, each flipping a uniformly random half of the labels; each is
      trained with lambda_hat = lambda, then lambda_hat <- eps * lambda_hat until
      Gamma* <= Gamma_0 (at most ``max_lambda_steps`` times; ``cap_hits`` counts the labellings
      that reached the cap, whose last machine is then used), giving the errors v*;
    - chi = 1 - 2 mean(v*), tau = 3 sqrt(ln(2/delta) / (2n)), bound = v + chi + tau.

    The configuration with the lowest bound wins; ties go to the larger lambda, then the larger
    sigma.

    Parameters
    ----------
    estimator : TensorSVC or TensorRLS
        The machine; parameters absent from the grid come from it.
    param_grid : dict or list of dicts
        Over ``lam`` (or ``C``), ``sigma``, ``alpha``. Default: the paper's grid
        (:data:`PAPER_GRID`, lambda in {1e-3..1e1}, sigma in {2^-4..2^4}, alpha in
        {1, "half", "full"}).
    n_labelings : int
        N, the random labellings per configuration (default 10).
    eps : float
        Scaling coefficient of lambda_hat, > 1 (default 2).
    delta : float
        Confidence of tau (default 0.05).
    max_lambda_steps : int
        Cap on the lambda_hat multiplications per labelling (default 30, i.e. up to 2^30 lambda).
    flip : "auto", "uniform" or "stratified"
        Which half of the labels a random labelling flips: a uniformly random half (reading
        R13) or half of each class (keeps the class counts; see docs/learning.md); "auto"
        (default) is "stratified" for the SVM and "uniform" for RLS, what selected best in
        docs/selection-study.md.
    n_init, max_iter : int
        Kernel k-means restarts and Lloyd iterations (defaults 10, 100).
    clustering : "lloyd", "kmeans++", "lloyd-hartigan" or "balanced"
        Step II's kernel k-means (:func:`~eskin.learn.estimators.kernel_kmeans`): plain Lloyd
        from random labels (default); k-means++ seeding, Lloyd and Hartigan moves (eskin's first
        reading, whose low-inertia but unbalanced partitions give a small Gamma_0); Lloyd then
        Hartigan from random labels; or two equal halves (size-constrained).
    gamma0 : "nearer" or "larger"
        Step VI: Gamma_0 of whichever of beta(+)/beta(-) is nearer to beta(RKM) (default,
        reading R12), or the larger of their two norms.
    reference : "clustering", "true-norm" or "same-lambda"
        What bounds the random-label machines: the clustering reference Gamma_0 of steps II-VI
        (default, Algorithm 1); the norm of the machine trained on the true labels (Anguita et
        al.'s "same hypothesis space", Gamma_0 = Gamma(RKM), no clustering); or nothing - each
        labelling is trained with the configuration's own lambda (Tikhonov form).
    chi : "mean" or "max"
        chi = 1 - 2 mean(v*) (default, reading R15) or 1 - 2 min(v*) (the maximal discrepancy over
        the N labellings).
    n_jobs : int, optional
        joblib workers over (alpha, sigma) blocks; results do not depend on it.
    random_state : int, RandomState or None
        Seeds the labellings (per configuration index) and k-means (per block index).
    refit : bool
        Refit ``best_estimator_`` on all the data (default True).

    Attributes
    ----------
    cv_results_ : dict of arrays, one entry per configuration
        ``params``, ``param_<key>``, ``lam``, ``C``, ``alphas``, ``sigmas``, ``train_error``
        (v), ``mean_random_error`` (mean v*), ``random_errors`` (n_configs, N), ``chi``,
        ``tau``, ``bound``, ``criterion`` (= bound), ``rank_bound``, ``gamma_0``,
        ``mean_lambda_steps``, ``max_lambda_steps_used``, ``cap_hits``, ``n_support``,
        ``cluster_minority_share`` (the smaller k-means cluster's share of the patterns; NaN
        without the clustering reference).
    best_index_, best_params_, best_estimator_, best_criterion_ (the best bound), tau_,
    cap_hits_ (total over the grid), classes_, random_state_ (the seed used).
    """

    def __init__(
        self,
        estimator=None,
        param_grid=None,
        n_labelings=10,
        eps=2.0,
        delta=0.05,
        max_lambda_steps=30,
        flip="auto",
        n_init=10,
        max_iter=100,
        n_jobs=None,
        random_state=None,
        refit=True,
        clustering="lloyd",
        gamma0="nearer",
        reference="clustering",
        chi="mean",
    ):
        self.estimator = estimator
        self.param_grid = param_grid
        self.n_labelings = n_labelings
        self.eps = eps
        self.delta = delta
        self.max_lambda_steps = max_lambda_steps
        self.flip = flip
        self.n_init = n_init
        self.max_iter = max_iter
        self.clustering = clustering
        self.gamma0 = gamma0
        self.reference = reference
        self.chi = chi
        self.n_jobs = n_jobs
        self.random_state = random_state
        self.refit = refit

    def _check_params(self):
        if self.flip not in ("auto", "uniform", "stratified"):
            raise ValueError(
                f"flip must be 'auto', 'uniform' or 'stratified', got {self.flip!r}"
            )
        for name, allowed in _MD_CHOICES.items():
            if getattr(self, name) not in allowed:
                raise ValueError(f"{name} must be one of {allowed}, got {getattr(self, name)!r}")
        if not (isinstance(self.n_init, numbers.Integral) and self.n_init >= 1):
            raise ValueError(f"n_init must be a positive int, got {self.n_init!r}")
        if not (isinstance(self.n_labelings, numbers.Integral) and self.n_labelings >= 1):
            raise ValueError(f"n_labelings must be a positive int, got {self.n_labelings!r}")
        if not (np.isfinite(self.eps) and self.eps > 1):
            raise ValueError(f"eps must be > 1 (lambda_hat grows by it), got {self.eps!r}")
        if not 0 < self.delta < 1:
            raise ValueError(f"delta must be in (0, 1), got {self.delta!r}")
        if not (isinstance(self.max_lambda_steps, numbers.Integral)
                and self.max_lambda_steps >= 0):
            raise ValueError(
                f"max_lambda_steps must be an int >= 0, got {self.max_lambda_steps!r}"
            )

    def _flip(self, kind: str) -> str:
        if self.flip != "auto":
            return self.flip
        return "stratified" if kind == "svm" else "uniform"

    def describe_reading(self) -> str:
        """The reading of Algorithm 1 these options run, in words (for reports)."""
        opts = {
            "clustering": self.clustering,
            "gamma0": self.gamma0,
            "reference": self.reference,
            "chi": self.chi,
            "flip": self.flip,
        }
        name = next((k for k, (o, _) in MD_READINGS.items()
                     if all(opts[key] == val for key, val in o.items())), None)
        parts = [f"{k}={v}" for k, v in opts.items()]
        parts += [f"n_labelings={self.n_labelings}", f"n_init={self.n_init}"]
        head = f"reading {name!r}: {MD_READINGS[name][1]}" if name else "a custom reading"
        return f"{head} ({', '.join(parts)})"

    def fit(self, X, y):
        """Run Algorithm 1 for every configuration, select by the bound, refit the best."""
        self._check_params()
        return self._fit_prepared(*self._prepare(X, y))

    def fit_distances(self, distances, y, pattern_shape, energies=None):
        """As :meth:`fit` from precomputed per-mode distances, without refitting.

        ``distances`` maps each resolved alpha tuple of the grid (e.g. ``(1, 1, 1)``) to the
        ``(n_modes, n, n)`` array of :func:`eskin.mode_distances`; ``energies`` are the
        patterns' :func:`eskin.pattern_log_energy` (needed when the grid has an amplitude
        factor). Used by studies that reuse one distance computation for many searches.
        ``best_estimator_`` is not set.
        """
        self._check_params()
        return self._fit_prepared(
            *self._prepare_distances(distances, y, pattern_shape, energies)
        )

    def _fit_prepared(self, X, y, y_pm, kind, configs, dists, factors):
        n = y_pm.size
        self.random_state_ = _resolve_seed(self.random_state)
        settings = _MDSettings(
            int(self.n_labelings), float(self.eps), int(self.max_lambda_steps),
            int(self.n_init), int(self.max_iter), self._flip(kind), self.clustering, self.gamma0,
            self.reference,
        )
        blocks = _blocks(configs)
        # BLAS on one thread here too: with a threading backend the blocks' limits are
        # process-wide, and every nested limit must restore 1, not the caller's setting
        with _single_threaded_blas():
            results = list(
                run_calls(
                    _md_block,
                    [
                        (
                            (kind, dists[alphas], sigmas, factors[amp], y_pm, cfgs, settings,
                             self.random_state_, b),
                            {},
                        )
                        for b, ((alphas, sigmas, amp), cfgs) in enumerate(blocks)
                    ],
                    n_jobs=self.n_jobs,
                )
            )
        by_index = {}
        for (_, cfgs), res in zip(blocks, results):
            for cfg, r in zip(cfgs, res):
                by_index[cfg.index] = r
        rows = [by_index[c.index] for c in configs]
        tau = md_tau(n, self.delta)
        v = np.array([r["v"] for r in rows])
        errors = np.vstack([r["errors"] for r in rows])
        chi = 1.0 - 2.0 * (errors.mean(axis=1) if self.chi == "mean" else errors.min(axis=1))
        bound = v + chi + tau
        res = self._base_results(configs)
        steps = np.vstack([r["steps"] for r in rows])
        res.update(
            train_error=v,
            mean_random_error=errors.mean(axis=1),
            random_errors=errors,
            chi=chi,
            tau=np.full(len(configs), tau),
            bound=bound,
            criterion=bound,
            rank_bound=_rank(bound),
            gamma_0=np.array([r["gamma0"] for r in rows]),
            mean_lambda_steps=steps.mean(axis=1),
            max_lambda_steps_used=steps.max(axis=1),
            cap_hits=np.array([r["cap_hits"] for r in rows], dtype=np.intp),
            n_support=np.array([r["n_support"] for r in rows], dtype=np.intp),
            cluster_minority_share=np.array([r["minority"] for r in rows]),
        )
        self.cv_results_ = res
        self.tau_ = tau
        self.cap_hits_ = int(res["cap_hits"].sum())
        self.criterion_name_ = "bound"
        return self._finish(X, y, configs, bound)


def _rank(values):
    order = np.argsort(values, kind="stable")
    rank = np.empty(len(values), dtype=np.intp)
    rank[order] = np.arange(1, len(values) + 1)
    return rank


class CrossValidationSearch(_SearchBase):
    """Conventional selection (Section 4.2, Figure 7): repeated random splits of the training set.

    Each of ``n_splits`` splits holds out ``test_size`` of the training patterns (of the
    participants, when ``groups`` is given to ``fit``: no participant on both sides); every
    configuration is trained on the rest and scored on the held-out part. The configuration
    with the lowest mean held-out error wins (ties: larger lambda, then larger sigma). The
    splits are the same for every configuration.

    Parameters
    ----------
    estimator, param_grid, n_jobs, random_state, refit : as for MaximalDiscrepancySearch.
    n_splits : int
        Random splits (default 10).
    test_size : float
        Held-out fraction of patterns (or of groups) per split (default 0.3, about the paper's
        80/260).

    Attributes
    ----------
    cv_results_ : dict of arrays
        ``params``, ``param_<key>``, ``lam``, ``C``, ``alphas``, ``sigmas``,
        ``split<i>_test_error``, ``mean_test_error``, ``std_test_error``, ``mean_train_error``,
        ``criterion`` (= mean_test_error), ``rank_test_error``.
    best_index_, best_params_, best_estimator_, best_criterion_, splits_ (the (train, test)
    index pairs), classes_, random_state_.
    """

    def __init__(
        self,
        estimator=None,
        param_grid=None,
        n_splits=10,
        test_size=0.3,
        n_jobs=None,
        random_state=None,
        refit=True,
    ):
        self.estimator = estimator
        self.param_grid = param_grid
        self.n_splits = n_splits
        self.test_size = test_size
        self.n_jobs = n_jobs
        self.random_state = random_state
        self.refit = refit

    def fit(self, X, y, groups=None):
        """Score every configuration on the same random splits, select, refit the best."""
        self._check_splits()
        return self._fit_prepared(*self._prepare(X, y), groups)

    def fit_distances(self, distances, y, pattern_shape, groups=None, energies=None):
        """As :meth:`fit` from precomputed per-mode distances (see
        :meth:`MaximalDiscrepancySearch.fit_distances`), without refitting."""
        self._check_splits()
        return self._fit_prepared(
            *self._prepare_distances(distances, y, pattern_shape, energies), groups
        )

    def _check_splits(self):
        if not (isinstance(self.n_splits, numbers.Integral) and self.n_splits >= 1):
            raise ValueError(f"n_splits must be a positive int, got {self.n_splits!r}")

    def _fit_prepared(self, X, y, y_pm, kind, configs, dists, factors, groups):
        self.random_state_ = _resolve_seed(self.random_state)
        split_seed = int(_rng(self.random_state_, _KEY_SPLITS).integers(np.iinfo(np.int32).max))
        idx = np.zeros(y_pm.size)
        if groups is not None:
            groups = np.asarray(groups)
            if groups.shape[0] != y_pm.size:
                raise ValueError(f"groups has {groups.shape[0]} entries for {y_pm.size} patterns")
            splitter = GroupShuffleSplit(self.n_splits, test_size=self.test_size,
                                         random_state=split_seed)
            splits = list(splitter.split(idx, y_pm, groups))
        else:
            splitter = StratifiedShuffleSplit(self.n_splits, test_size=self.test_size,
                                              random_state=split_seed)
            splits = list(splitter.split(idx, y_pm))
        for i, (tr, _) in enumerate(splits):
            if np.unique(y_pm[tr]).size < 2:
                raise ClassLeftOut(
                    f"cross-validation split {i} left one class only in its training part; "
                    "use more groups, a smaller test_size or another random_state")
        self.splits_ = splits
        blocks = _blocks(configs)
        with _single_threaded_blas():  # see MaximalDiscrepancySearch.fit
            results = list(
                run_calls(
                    _cv_block,
                    [
                        ((kind, dists[alphas], sigmas, factors[amp], y_pm, cfgs, splits), {})
                        for (alphas, sigmas, amp), cfgs in blocks
                    ],
                    n_jobs=self.n_jobs,
                )
            )
        test_err = np.empty((len(configs), len(splits)))
        train_err = np.empty((len(configs), len(splits)))
        for (_, cfgs), (te, tr) in zip(blocks, results):
            for i, cfg in enumerate(cfgs):
                test_err[cfg.index] = te[i]
                train_err[cfg.index] = tr[i]
        res = self._base_results(configs)
        for s in range(len(splits)):
            res[f"split{s}_test_error"] = test_err[:, s]
        mean = test_err.mean(axis=1)
        res.update(
            mean_test_error=mean,
            std_test_error=test_err.std(axis=1),
            mean_train_error=train_err.mean(axis=1),
            criterion=mean,
            rank_test_error=_rank(mean),
        )
        self.cv_results_ = res
        self.criterion_name_ = "mean_test_error"
        return self._finish(X, y, configs, mean)
