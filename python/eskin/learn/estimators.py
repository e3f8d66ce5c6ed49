"""Kernel machines on tensor patterns: tensor-SVM, tensor-RLS, kernel k-means, 1-vs-all.

The estimators follow scikit-learn's conventions (``__init__`` stores parameters only, fitted
attributes end in ``_``, :func:`~sklearn.base.clone` and pipelines work). Patterns are tensors:
``X`` has shape ``(n, rows, cols, D)`` (any order >= 2 works), or is 2-D ``(n, n_features)``
together with ``tensor_shape`` (each row is reshaped, C order). A 2-D ``X`` without
``tensor_shape`` is read as ``n`` order-2 tensors of shape ``(1, n_features)``: the smallest
tensor view, which lets scikit-learn's estimator checks run (see ``docs/learning.md``).

The kernel is the paper's tensor kernel (``eskin.tensor_kernel``): per mode z a Gaussian of the
squared distance between the pattern subspaces, ``K = exp(-sum_z d_z / (2 sigma_z^2))``; see
``docs/learning.md`` for the whole learning side and readings R9-R17 and R23 of
``docs/paper-readings.md`` for how the paper is read.

Every fitted binary machine exposes the same attributes, the contract that deployment builds on:
``support_vectors_`` (n_sv, *tensor shape), ``dual_coef_`` (n_sv,) (alpha_i*y_i for the SVM,
beta_i for RLS), ``intercept_`` (float, 0 for RLS), ``alphas_`` and ``sigmas_`` (one per mode),
``classes_`` (2 labels; decision > 0 means ``classes_[1]``), ``amplitude_width_`` (0.0 without
the amplitude factor) and ``sv_log_energy_`` (n_sv,), with
``decision_function(x) = sum_i dual_coef_[i] K(sv_i, x) + intercept_``.

The amplitude-aware kernel (``amplitude=a``, off by default) multiplies the tensor kernel by a
Gaussian on the patterns' log energies (:func:`eskin.pattern_log_energy`):
``K(x, x') = K_tensor(x, x') exp(-(e(x) - e(x'))^2 / (2 w^2))`` with the width
``w = a * max(std of e over the training patterns, 0.05)``: ``a`` is in units of the training
set's spread of log energy, so the same grid suits every sensor.
"""

from __future__ import annotations

import inspect
import numbers
from dataclasses import dataclass

import numpy as np
import scipy.linalg
from sklearn.base import BaseEstimator, ClassifierMixin, ClusterMixin, clone
from sklearn.svm import SVC
from sklearn.utils.multiclass import check_classification_targets
from sklearn.utils.validation import check_is_fitted, check_random_state, validate_data

from .kernel import mode_distances, pattern_log_energy, resolve_alphas
from .parallel import run_calls

__all__ = [
    "TensorSVC",
    "TensorRLS",
    "KernelKMeans",
    "OneVsAllTouchClassifier",
    "TouchDecision",
    "kernel_from_distances",
    "kernel_kmeans",
]


# --------------------------------------------------------------------------------------------
# helpers shared with eskin.selection
# --------------------------------------------------------------------------------------------
def as_tensors(X: np.ndarray, tensor_shape) -> np.ndarray:
    """View validated float ``X`` as ``(n, *pattern shape)``.

    2-D ``X`` is reshaped to ``tensor_shape`` (or ``(1, n_features)`` when it is None); an
    N-D ``X`` is checked against ``tensor_shape`` when one is given.
    """
    if X.ndim == 2:
        n, n_features = X.shape
        if tensor_shape is None:
            return X.reshape(n, 1, n_features)
        shape = tuple(int(s) for s in tensor_shape)
        if len(shape) < 2 or int(np.prod(shape)) != n_features:
            raise ValueError(
                f"tensor_shape={tuple(tensor_shape)} does not fit X with {n_features} features "
                f"per row (it needs at least 2 modes whose product is {n_features})"
            )
        return X.reshape((n,) + shape)
    if X.ndim < 2:
        raise ValueError(f"X must have shape (n, rows, cols, D) or (n, features); got {X.shape}")
    if tensor_shape is not None and tuple(X.shape[1:]) != tuple(int(s) for s in tensor_shape):
        raise ValueError(
            f"X has pattern shape {tuple(X.shape[1:])} but tensor_shape={tuple(tensor_shape)}"
        )
    return X


def sigma_tuple(sigma, n_modes: int) -> tuple[float, ...]:
    """One sigma per mode from a positive float or a sequence of ``n_modes`` floats."""
    if isinstance(sigma, numbers.Real) and not isinstance(sigma, bool):
        values = (float(sigma),) * n_modes
    else:
        values = tuple(float(s) for s in np.asarray(sigma, dtype=float).ravel())
        if len(values) != n_modes:
            raise ValueError(f"sigma={sigma!r} must be one value or {n_modes} (one per mode)")
    if not all(np.isfinite(s) and s > 0 for s in values):
        raise ValueError(f"sigma must be positive and finite, got {sigma!r}")
    return values


#: The smallest spread of the training patterns' log energies that the amplitude width is a
#: multiple of: a campaign whose touches all have about the same energy (spread below 0.05, i.e.
#: amplitudes within about 2.5 %) would otherwise get an arbitrarily narrow factor.
MIN_ENERGY_SPREAD = 0.05


#: The amplitude values the estimators accept (in spreads of log energy): beyond them the factor
#: is either a step that no test touch passes or 1 everywhere, and the deployable model format
#: bounds the width it stores.
AMPLITUDE_RANGE = (1e-2, 1e2)


def check_amplitude(amplitude) -> float | None:
    """``amplitude`` as a float in :data:`AMPLITUDE_RANGE`, or None (no amplitude factor);
    ValueError otherwise."""
    if amplitude is None:
        return None
    low, high = AMPLITUDE_RANGE
    if (
        isinstance(amplitude, (bool, np.bool_))
        or not isinstance(amplitude, numbers.Real)
        or not low <= amplitude <= high
    ):
        raise ValueError(
            f"amplitude must be None or a number in [{low:g}, {high:g}], got {amplitude!r}"
        )
    return float(amplitude)


def amplitude_width(amplitude, energies: np.ndarray) -> float:
    """The factor's width in log-energy units: ``amplitude`` times the spread (standard
    deviation, at least :data:`MIN_ENERGY_SPREAD`) of the training patterns' log energies;
    0.0 when ``amplitude`` is None."""
    a = check_amplitude(amplitude)
    if a is None:
        return 0.0
    spread = float(np.std(energies)) if len(energies) else 0.0
    return a * max(spread, MIN_ENERGY_SPREAD)


def amplitude_factor(e_a: np.ndarray, e_b: np.ndarray, width: float) -> np.ndarray | None:
    """``exp(-(e_a[i] - e_b[j])^2 / (2 width^2))``, shape (len(e_a), len(e_b)); None when the
    width is 0 (no factor)."""
    if not width > 0:
        return None
    diff = np.subtract.outer(np.asarray(e_a, float), np.asarray(e_b, float))
    with np.errstate(invalid="ignore", over="ignore"):
        factor = np.exp(-(diff * diff) / (2.0 * width * width))
    return np.nan_to_num(factor, nan=0.0)


def kernel_from_distances(dists: np.ndarray, sigmas) -> np.ndarray:
    """``K = exp(-sum_z d_z / (2 sigma_z^2))`` from per-mode distances ``(n_modes, n, m)``."""
    s = np.asarray(sigmas, dtype=float)
    weights = 1.0 / (2.0 * s * s)
    return np.exp(-np.tensordot(weights, dists, axes=1))


def _validate_fit(est, X, y):
    X, y = validate_data(est, X, y, allow_nd=True, dtype=np.float64)
    return as_tensors(X, est.tensor_shape), y


def _check_pattern_order(est, X, name: str | None = None) -> None:
    """A clear error for patterns of another order than the fitted ones (typically flattened
    rows, or one pattern without its batch axis), before scikit-learn's feature count check
    words it in features."""
    fitted = getattr(est, "tensor_shape_", None)
    if fitted is None or est.tensor_shape is not None:
        return
    fitted = tuple(fitted)
    if fitted == (1, getattr(est, "n_features_in_", None)):
        return  # fitted on 2-D rows (the (1, n_features) view): scikit-learn's checks apply
    shape = tuple(np.shape(X))
    if len(shape) == len(fitted) + 1:
        return
    dims = ", ".join(map(str, fitted))
    if shape == fitted:
        hint = f"one pattern needs the batch axis: X[np.newaxis], shape (1, {dims})"
    elif len(shape) == 2 and shape[1] == int(np.prod(fitted)):
        hint = f"its rows look flattened: X.reshape(-1, {dims}) undoes it"
    else:
        hint = f"expected (n, {dims})"
    raise ValueError(
        f"X has shape {shape}, but {name or type(est).__name__} was fitted on patterns of shape "
        f"{fitted}: {hint}"
    )


def _validate_predict(est, X):
    _check_pattern_order(est, X)
    X = validate_data(est, X, reset=False, allow_nd=True, dtype=np.float64)
    X = as_tensors(X, est.tensor_shape)
    if tuple(X.shape[1:]) != tuple(est.tensor_shape_):
        raise ValueError(
            f"X has pattern shape {tuple(X.shape[1:])}, but {type(est).__name__} was fitted "
            f"on patterns of shape {tuple(est.tensor_shape_)}"
        )
    return X


def binary_targets(y, name: str):
    """(classes, y as -1/+1 floats) for a two-class target; ``classes[1]`` maps to +1."""
    check_classification_targets(y)
    classes = np.unique(y)
    if classes.size != 2:
        raise ValueError(
            "Only binary classification is supported. "
            f"{name} is a binary machine: y has {classes.size} class(es) {classes.tolist()[:5]}; "
            "it needs exactly 2 (use OneVsAllTouchClassifier for more)"
        )
    return classes, np.where(y == classes[1], 1.0, -1.0)


try:  # libsvm without SVC's per-call validation: about 4x faster on a 180 x 180 kernel
    from sklearn.svm import _libsvm as _sk_libsvm
except ImportError:  # pragma: no cover - private module moved; SVC is the fallback
    _sk_libsvm = None


def svm_train(K: np.ndarray, y_pm: np.ndarray, C: float, tol: float = 1e-3):
    """Train a C-SVM on a precomputed kernel; return (beta (n,), intercept, support indices).

    ``beta_i = alpha_i y_i`` (zero off the support), so ``f = K beta + b`` and the squared RKHS
    norm is ``beta^T K beta``; decision > 0 means label +1. This is exactly
    ``sklearn.svm.SVC(kernel="precomputed", C=C, tol=tol)`` (same libsvm call, same sign
    convention); model selection calls it thousands of times, so it skips SVC's per-call
    validation when sklearn's libsvm wrapper is importable.
    """
    K = np.ascontiguousarray(K, dtype=np.float64)
    y_pm = np.asarray(y_pm, dtype=np.float64)
    beta = np.zeros(K.shape[0])
    if y_pm.size == 0 or bool(np.all(y_pm == y_pm[0])):
        # one class only (e.g. a random MD labelling of a small set): libsvm returns no dual;
        # the solution is the constant machine f = y, with no support vector
        return beta, float(y_pm[0]) if y_pm.size else 0.0, np.zeros(0, dtype=np.intp)
    if _sk_libsvm is not None:
        # sklearn passes class indices (here 0 for -1, 1 for +1) and flips the binary signs
        # so that decision > 0 means classes_[1]
        _sk_libsvm.set_verbosity_wrap(0)
        support, _, _, dual, intercept, *_ = _sk_libsvm.fit(
            K, (y_pm > 0).astype(np.float64), svm_type=0, kernel="precomputed", C=float(C),
            tol=float(tol), cache_size=200.0, max_iter=-1, random_seed=0,
        )
        beta[support] = -dual[0]
        return beta, float(-intercept[0]), np.asarray(support, dtype=np.intp)
    svc = SVC(kernel="precomputed", C=float(C), tol=tol).fit(K, y_pm)
    beta[svc.support_] = svc.dual_coef_[0]
    return beta, float(svc.intercept_[0]), svc.support_


class _TensorKernelMachine(ClassifierMixin, BaseEstimator):
    """Binary kernel machine on the tensor kernel (shared fit/predict plumbing)."""

    amplitude = None  # what machines pickled before the amplitude factor had

    def __sklearn_tags__(self):
        tags = super().__sklearn_tags__()
        tags.classifier_tags.multi_class = False
        tags.input_tags.three_d_array = True
        return tags

    def _kernel_setup(self, X, distances=None, energies=None):
        """(training Gram matrix, the training patterns' log energies); sets the kernel's
        fitted settings. ``distances``/``energies``: the patterns' per-mode distances (at this
        machine's alphas) and log energies when already computed (the machines of a
        :class:`OneVsAllTouchClassifier` share them)."""
        self.tensor_shape_ = tuple(X.shape[1:])
        self.alphas_ = tuple(int(a) for a in resolve_alphas(self.tensor_shape_, self.alpha))
        self.sigmas_ = sigma_tuple(self.sigma, len(self.tensor_shape_))
        if energies is None:
            energies = pattern_log_energy(X)
        self.amplitude_width_ = amplitude_width(self.amplitude, energies)
        if distances is None:
            distances = mode_distances(X, alpha=self.alphas_)
        K = kernel_from_distances(distances, self.sigmas_)
        factor = amplitude_factor(energies, energies, self.amplitude_width_)
        return (K if factor is None else K * factor), energies

    def fit(self, X, y):
        """Fit on tensors ``X`` (n, *shape) (or 2-D with ``tensor_shape``) and 2-class ``y``."""
        return self._fit(X, y)

    def _fit(self, X, y, distances=None, energies=None):
        """:meth:`fit`, with the patterns' distances and log energies when already known."""
        X, y = _validate_fit(self, X, y)
        self.classes_, y_pm = binary_targets(y, type(self).__name__)
        self._check_regulariser()
        check_amplitude(self.amplitude)
        K, energies = self._kernel_setup(X, distances, energies)
        beta, intercept, support = self._train(K, y_pm)
        self.support_ = np.asarray(support, dtype=np.intp)
        self.support_vectors_ = np.ascontiguousarray(X[self.support_])
        self.sv_log_energy_ = np.ascontiguousarray(energies[self.support_])
        self.dual_coef_ = np.ascontiguousarray(beta[self.support_])
        self.intercept_ = float(intercept)
        return self

    def decision_function(self, X):
        """``f(x) = sum_i dual_coef_[i] K(sv_i, x) + intercept_``; > 0 means ``classes_[1]``."""
        check_is_fitted(self)
        X = _validate_predict(self, X)
        if self.dual_coef_.size == 0:
            return np.full(X.shape[0], self.intercept_)
        d = mode_distances(X, self.support_vectors_, alpha=self.alphas_)
        return self._decision_from(d, pattern_log_energy(X))

    def _decision_from(self, distances, energies):
        """Decision values from the per-mode distances of the patterns to the support vectors
        (n_modes, n, n_support) and the patterns' log energies."""
        if self.dual_coef_.size == 0:
            return np.full(distances.shape[1], self.intercept_)
        K = kernel_from_distances(distances, self.sigmas_)
        width = getattr(self, "amplitude_width_", 0.0)  # 0 in models pickled before the factor
        if width > 0:
            K *= amplitude_factor(energies, self.sv_log_energy_, width)
        return K @ self.dual_coef_ + self.intercept_

    def predict(self, X):
        """Class labels: ``classes_[1]`` where the decision value is > 0, else ``classes_[0]``."""
        f = self.decision_function(X)
        return self.classes_[(f > 0).astype(np.intp)]


class TensorSVC(_TensorKernelMachine):
    """Tensor-SVM (paper Section 3.1): a C-SVM on the tensor kernel.

    Parameters
    ----------
    C : float
        Box constraint; the paper's grid is in lambda with ``C = 1/lambda`` (reading R9).
    sigma : float or sequence of float
        Kernel width, one for all modes or one per mode.
    alpha : int, "half", "full" or sequence of int
        Number of right-singular vectors kept per mode (see ``eskin.resolve_alphas``).
    tensor_shape : tuple of int, optional
        Pattern shape for 2-D ``X``.
    amplitude : float or None
        The amplitude-aware kernel's width in units of the training patterns' spread of log
        energy (see the module's docstring); None (default): the paper's tensor kernel.

    Fitted attributes: ``support_vectors_``, ``dual_coef_`` (alpha_i*y_i), ``intercept_``,
    ``support_`` (indices into the training set), ``alphas_``, ``sigmas_``, ``classes_``,
    ``tensor_shape_``, ``amplitude_width_``, ``sv_log_energy_``.
    """

    def __init__(self, C=1.0, sigma=1.0, alpha="half", tensor_shape=None, amplitude=None):
        self.C = C
        self.sigma = sigma
        self.alpha = alpha
        self.tensor_shape = tensor_shape
        self.amplitude = amplitude

    def _check_regulariser(self):
        if not (np.isfinite(self.C) and self.C > 0):
            raise ValueError(f"C must be positive and finite, got {self.C!r}")

    def _train(self, K, y_pm):
        return svm_train(K, y_pm, self.C)


class TensorRLS(_TensorKernelMachine):
    """Tensor-RLS (paper Section 3.1, reading R9): ``beta = (K + lam I)^-1 y``, labels -1/+1.

    The machine has no bias (``intercept_ = 0``) and every training pattern is a support vector.

    Parameters
    ----------
    lam : float
        Regularisation lambda > 0.
    sigma, alpha, tensor_shape, amplitude : as for :class:`TensorSVC`.
    """

    def __init__(self, lam=1.0, sigma=1.0, alpha="half", tensor_shape=None, amplitude=None):
        self.lam = lam
        self.sigma = sigma
        self.alpha = alpha
        self.tensor_shape = tensor_shape
        self.amplitude = amplitude

    def _check_regulariser(self):
        if not (np.isfinite(self.lam) and self.lam > 0):
            raise ValueError(f"lam must be positive and finite, got {self.lam!r}")

    def _train(self, K, y_pm):
        n = K.shape[0]
        A = K + self.lam * np.eye(n)
        beta = scipy.linalg.solve(A, y_pm, assume_a="pos")
        return beta, 0.0, np.arange(n)


# --------------------------------------------------------------------------------------------
# kernel k-means
# --------------------------------------------------------------------------------------------
def _kkm_distances(K, diag, labels, n_clusters):
    """Exact feature-space squared distances of every point to every cluster centroid.

    ``||phi(x_i) - m_c||^2 = K_ii - 2/|c| sum_{j in c} K_ij + 1/|c|^2 sum_{j,l in c} K_jl``.
    Empty clusters get +inf.
    """
    Z = np.zeros((K.shape[0], n_clusters))
    Z[np.arange(K.shape[0]), labels] = 1.0
    sizes = Z.sum(axis=0)
    KZ = K @ Z
    with np.errstate(divide="ignore", invalid="ignore"):
        cross = KZ / sizes
        cnorm = np.einsum("ic,ic->c", Z, KZ) / (sizes * sizes)
    dist = diag[:, None] - 2.0 * cross + cnorm[None, :]
    dist[:, sizes == 0] = np.inf
    return dist


def _kkm_plus_plus(K, diag, n_clusters, rng):
    """k-means++ seeding in feature space; returns initial labels (nearest seed point)."""
    n = K.shape[0]
    seeds = [int(rng.integers(n))]
    d2 = np.maximum(diag + diag[seeds[0]] - 2.0 * K[:, seeds[0]], 0.0)
    for _ in range(1, n_clusters):
        total = d2.sum()
        if total > 0:
            nxt = int(rng.choice(n, p=d2 / total))
        else:  # every point coincides in feature space: any other point
            nxt = int(rng.choice(np.setdiff1d(np.arange(n), seeds)))
        seeds.append(nxt)
        d2 = np.minimum(d2, np.maximum(diag + diag[nxt] - 2.0 * K[:, nxt], 0.0))
    seed_d = diag[:, None] + diag[seeds][None, :] - 2.0 * K[:, seeds]
    # nearest seed; exact ties (a kernel that sees no structure, e.g. K = I) are broken at
    # random, not towards the first cluster, which would give a degenerate n-1 / 1 split
    tied = seed_d <= seed_d.min(axis=1, keepdims=True)
    labels = np.argmax(tied * rng.random(tied.shape), axis=1)
    labels[seeds] = np.arange(n_clusters)
    return labels


def _kkm_lloyd(K, diag, labels, n_clusters, max_iter):
    """Lloyd iterations: every point to its nearest centroid until no label changes."""
    n = K.shape[0]
    rows = np.arange(n)
    n_iter = 0
    for n_iter in range(1, int(max_iter) + 1):
        dist = _kkm_distances(K, diag, labels, n_clusters)
        new = np.argmin(dist, axis=1)
        # keep a point's label on exact ties, so the iteration cannot cycle
        new = np.where(dist[rows, new] < dist[rows, labels], new, labels)
        counts = np.bincount(new, minlength=n_clusters)
        for c in np.flatnonzero(counts == 0):  # an emptied cluster takes the farthest point
            own = dist[rows, new]
            far = int(np.argmax(np.where(counts[new] > 1, own, -np.inf)))
            counts[new[far]] -= 1
            new[far] = c
            counts[c] = 1
        if np.array_equal(new, labels):
            break
        labels = new
    return labels, n_iter


def _kkm_single_moves(K, diag, labels, n_clusters, max_moves):
    """Hartigan refinement: move single points while a move lowers the inertia.

    Moving x from cluster A (size a > 1) to B (size b) changes the inertia by exactly
    ``b/(b+1) d(x, m_B) - a/(a-1) d(x, m_A)`` (the centroids move too); the best improving move
    is applied until none is left. Lloyd stops at points where no such move is checked. The
    cluster sums are updated in O(n) per move.
    """
    n = K.shape[0]
    rows = np.arange(n)
    labels = labels.copy()
    Z = np.zeros((n, n_clusters))
    Z[rows, labels] = 1.0
    KZ = K @ Z  # sum_{j in c} K_ij
    S = np.einsum("ic,ic->c", Z, KZ)  # sum_{j,l in c} K_jl
    sizes = Z.sum(axis=0)
    for _ in range(int(max_moves)):
        with np.errstate(divide="ignore", invalid="ignore"):
            dist = diag[:, None] - 2.0 * KZ / sizes + S / (sizes * sizes)
            own = dist[rows, labels]
            a = sizes[labels]
            leave = np.where(a > 1, a / (a - 1.0) * own, -np.inf)  # a singleton stays
            enter = np.where(sizes > 0, sizes / (sizes + 1.0) * dist, diag[:, None] * 0.0)
        delta = enter - leave[:, None]
        delta[rows, labels] = np.inf
        i, c = np.unravel_index(int(np.argmin(delta)), delta.shape)
        if not delta[i, c] < -1e-12 * max(1.0, float(np.abs(own).sum())):
            break
        src = labels[i]
        S[src] += -2.0 * KZ[i, src] + K[i, i]
        S[c] += 2.0 * KZ[i, c] + K[i, i]
        KZ[:, src] -= K[:, i]
        KZ[:, c] += K[:, i]
        sizes[src] -= 1.0
        sizes[c] += 1.0
        labels[i] = c
    return labels


def _kkm_random_labels(n, n_clusters, rng):
    """Every point to a uniformly random cluster (each cluster keeps at least one point)."""
    labels = rng.integers(n_clusters, size=n)
    labels[rng.permutation(n)[:n_clusters]] = np.arange(n_clusters)
    return labels


def _kkm_balanced(K, diag, rng, max_iter):
    """Size-constrained 2-means: halves of floor(n/2) and ceil(n/2) points.

    Starts from a random balanced split; each step computes both centroid distances and gives
    cluster 0 the floor(n/2) points with the smallest ``d(x, m_0) - d(x, m_1)`` (the optimal
    assignment for fixed centroids under the size constraint; stable sort, so deterministic),
    until no label changes. The inertia never increases, so it stops at a fixed point.
    """
    n = K.shape[0]
    half = n // 2
    labels = np.ones(n, dtype=np.intp)
    labels[rng.permutation(n)[:half]] = 0
    for _ in range(int(max_iter)):
        dist = _kkm_distances(K, diag, labels, 2)
        order = np.argsort(dist[:, 0] - dist[:, 1], kind="stable")
        new = np.ones(n, dtype=np.intp)
        new[order[:half]] = 0
        if np.array_equal(new, labels):
            break
        labels = new
    return labels


#: The kernel k-means readings (reading R17 leaves the seeding and the local search open).
KMEANS_METHODS = ("kmeans++", "lloyd", "lloyd-hartigan", "balanced")


def _kkm_restart(K, diag, n_clusters, max_iter, rng, method):
    n = K.shape[0]
    if method == "balanced":
        return _kkm_balanced(K, diag, rng, max_iter), 0
    if method == "kmeans++":
        labels = _kkm_plus_plus(K, diag, n_clusters, rng)
    else:
        labels = _kkm_random_labels(n, n_clusters, rng)
    labels, n_iter = _kkm_lloyd(K, diag, labels, n_clusters, max_iter)
    if method in ("kmeans++", "lloyd-hartigan"):
        labels = _kkm_single_moves(K, diag, labels, n_clusters, max_moves=n)
    return labels, n_iter


def kernel_kmeans(
    K, n_clusters=2, n_init=10, max_iter=100, random_state=None, method="kmeans++"
):
    """Kernel k-means on a Gram matrix: the exact feature-space algorithm, seeded restarts.

    ``method`` says how each restart runs:

    - "kmeans++": k-means++ seeding in feature space, Lloyd iterations (assignment to the
      nearest centroid; distances include the centroid-norm term) until no label changes, then
      single-point (Hartigan) moves while one lowers the inertia, which escapes the poor fixed
      points Lloyd can stop at. An emptied cluster takes the point farthest from its centroid.
    - "lloyd": plain Lloyd iterations from uniformly random labels.
    - "lloyd-hartigan": random labels, Lloyd, then the Hartigan moves.
    - "balanced": two clusters of floor(n/2) and ceil(n/2) points (size-constrained Lloyd from a
      random balanced split, see :func:`_kkm_balanced`); ``n_clusters`` must be 2.

    The restart with the lowest inertia (sum of squared feature-space distances to the own
    centroid) wins; ties keep the earlier restart.

    Returns ``(labels, inertia, n_iter)`` (n_iter: Lloyd iterations of the winning restart).
    """
    K = np.asarray(K, dtype=np.float64)
    n = K.shape[0]
    if K.ndim != 2 or K.shape[1] != n:
        raise ValueError(f"K must be a square Gram matrix, got shape {K.shape}")
    if not 1 <= n_clusters <= n:
        raise ValueError(f"n_clusters={n_clusters} must be between 1 and n_samples={n}")
    if method not in KMEANS_METHODS:
        raise ValueError(f"method must be one of {KMEANS_METHODS}, got {method!r}")
    if method == "balanced" and n_clusters != 2:
        raise ValueError(f"method='balanced' makes 2 clusters, got n_clusters={n_clusters}")
    rng = np.random.default_rng(random_state)
    diag = np.diag(K).copy()
    best = (None, np.inf, 0)
    for _ in range(int(n_init)):
        labels, n_iter = _kkm_restart(K, diag, n_clusters, max_iter, rng, method)
        dist = _kkm_distances(K, diag, labels, n_clusters)
        inertia = float(np.maximum(dist[np.arange(n), labels], 0.0).sum())
        if best[0] is None or inertia < best[1] - 1e-12 * max(1.0, abs(best[1])):
            best = (labels.copy(), inertia, n_iter)
    return best


class KernelKMeans(ClusterMixin, BaseEstimator):
    """Kernel k-means (the exact feature-space algorithm, reading R17), seeded restarts.

    Parameters
    ----------
    n_clusters : int
        Number of clusters (2 in Algorithm 1).
    n_init : int
        Restarts; the lowest inertia wins.
    max_iter : int
        Lloyd iterations per restart.
    method : "kmeans++", "lloyd", "lloyd-hartigan" or "balanced"
        How a restart runs (see :func:`kernel_kmeans`): k-means++ seeding, Lloyd and Hartigan
        moves (default); Lloyd from random labels; the same followed by Hartigan moves; or two
        equal halves (size-constrained, 2 clusters only).
    kernel : "tensor" or "precomputed"
        "tensor": X holds tensor patterns and the tensor kernel with ``sigma``/``alpha`` is
        used; "precomputed": X is the Gram matrix (fit) or the cross-kernel K(X_new, X_fit)
        (predict).
    sigma, alpha, tensor_shape : kernel parameters as for :class:`TensorSVC`.
    random_state : int, RandomState, Generator or None.

    Fitted attributes: ``labels_``, ``inertia_``, ``n_iter_``, ``cluster_sizes_``.
    """

    def __init__(
        self,
        n_clusters=2,
        n_init=10,
        max_iter=100,
        kernel="tensor",
        sigma=1.0,
        alpha="half",
        tensor_shape=None,
        random_state=None,
        method="kmeans++",
    ):
        self.n_clusters = n_clusters
        self.n_init = n_init
        self.max_iter = max_iter
        self.method = method
        self.kernel = kernel
        self.sigma = sigma
        self.alpha = alpha
        self.tensor_shape = tensor_shape
        self.random_state = random_state

    def __sklearn_tags__(self):
        tags = super().__sklearn_tags__()
        tags.input_tags.pairwise = self.kernel == "precomputed"
        tags.input_tags.three_d_array = self.kernel == "tensor"
        return tags

    def _seed(self):
        rs = self.random_state
        if isinstance(rs, np.random.Generator):
            return rs
        if rs is None or isinstance(rs, (numbers.Integral, np.integer)):
            return rs
        return int(check_random_state(rs).randint(np.iinfo(np.int32).max))

    def fit(self, X, y=None):
        """Cluster ``X`` (tensor patterns, or a Gram matrix with kernel="precomputed")."""
        if self.kernel not in ("tensor", "precomputed"):
            raise ValueError(f"kernel must be 'tensor' or 'precomputed', got {self.kernel!r}")
        if self.kernel == "precomputed":
            K = validate_data(self, X, dtype=np.float64)
            if K.shape[0] != K.shape[1]:
                raise ValueError(f"a precomputed kernel must be square, got shape {K.shape}")
        else:
            X = as_tensors(validate_data(self, X, allow_nd=True, dtype=np.float64),
                           self.tensor_shape)
            self.tensor_shape_ = tuple(X.shape[1:])
            self.alphas_ = tuple(int(a) for a in resolve_alphas(self.tensor_shape_, self.alpha))
            self.sigmas_ = sigma_tuple(self.sigma, len(self.tensor_shape_))
            self.X_fit_ = X
            K = kernel_from_distances(mode_distances(X, alpha=self.alphas_), self.sigmas_)
        if not (isinstance(self.n_clusters, numbers.Integral) and self.n_clusters >= 1):
            raise ValueError(f"n_clusters must be a positive int, got {self.n_clusters!r}")
        if self.n_clusters > K.shape[0]:
            raise ValueError(
                f"n_samples={K.shape[0]} should be >= n_clusters={self.n_clusters}"
            )
        labels, inertia, n_iter = kernel_kmeans(
            K, self.n_clusters, self.n_init, self.max_iter, self._seed(), method=self.method
        )
        self.labels_ = labels
        self.inertia_ = inertia
        self.n_iter_ = n_iter
        Z = np.zeros((K.shape[0], self.n_clusters))
        Z[np.arange(K.shape[0]), labels] = 1.0
        self.cluster_sizes_ = Z.sum(axis=0).astype(np.intp)
        self._assign = Z / np.maximum(self.cluster_sizes_, 1)
        self._centroid_norms = np.einsum("ic,ic->c", self._assign, K @ self._assign)
        return self

    def predict(self, X):
        """Nearest centroid in feature space (``K(x, x)`` is constant over clusters)."""
        check_is_fitted(self)
        if self.kernel == "precomputed":
            Kx = validate_data(self, X, reset=False, dtype=np.float64)
        else:
            X = as_tensors(
                validate_data(self, X, reset=False, allow_nd=True, dtype=np.float64),
                self.tensor_shape,
            )
            if tuple(X.shape[1:]) != self.tensor_shape_:
                raise ValueError(
                    f"X has pattern shape {tuple(X.shape[1:])}, fitted on {self.tensor_shape_}"
                )
            Kx = kernel_from_distances(
                mode_distances(X, self.X_fit_, alpha=self.alphas_), self.sigmas_
            )
        return np.argmin(self._centroid_norms[None, :] - 2.0 * Kx @ self._assign, axis=1)


# --------------------------------------------------------------------------------------------
# 1-vs-all
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class TouchDecision:
    """Outcome of the 1-vs-all rule for a batch of patterns.

    ``labels``: the assigned classes; ``decision_values`` (n, n_classes): f of every machine;
    ``n_claims``: how many machines claimed each pattern (f > 0); ``dont_know``: True where the
    rule fell back to the largest f because no machine, or more than one, claimed the pattern.
    """

    labels: np.ndarray
    decision_values: np.ndarray
    n_claims: np.ndarray
    dont_know: np.ndarray


def one_vs_all_rule(decision_values: np.ndarray):
    """The paper's rule (Section 5.3, reading R23) on an (n, n_classes) array of f values.

    Returns ``(class index, n_claims, dont_know)``: if exactly one machine claims the pattern
    (f > 0), its class; otherwise the machine with the largest f (first on ties), flagged
    "don't know".
    """
    f = np.asarray(decision_values, dtype=float)
    claims = f > 0
    n_claims = claims.sum(axis=1)
    index = np.where(n_claims == 1, np.argmax(claims, axis=1), np.argmax(f, axis=1))
    return index, n_claims, n_claims != 1


def _fit_machine(estimator, X, y_pm, groups=None, shared=None):
    """A fitted clone of ``estimator`` on (X, y_pm); ``shared``: (the distances of every
    pattern of the classifier, their log energies, this machine's indices) for a kernel
    machine, which slices them instead of computing its own."""
    est = clone(estimator)
    if shared is not None:
        dists, energies, ix = shared
        return est._fit(X, y_pm, dists[:, ix][:, :, ix], energies[ix])
    if groups is not None and "groups" in inspect.signature(est.fit).parameters:
        return est.fit(X, y_pm, groups=groups)  # a search that splits by group
    return est.fit(X, y_pm)


def _shared_distances(estimator, X):
    """(per-mode distances of all of ``X``, their log energies) for the machines of a
    one-vs-all classifier of kernel machines, computed once for all of them (each machine's
    are a slice); None for a search (it computes its own)."""
    if not isinstance(estimator, _TensorKernelMachine):
        return None
    X = as_tensors(np.asarray(X, dtype=np.float64), estimator.tensor_shape)
    alphas = tuple(int(a) for a in resolve_alphas(tuple(X.shape[1:]), estimator.alpha))
    return mode_distances(X, alpha=alphas), pattern_log_energy(X)


class OneVsAllTouchClassifier(ClassifierMixin, BaseEstimator):
    """Multi-class touch recognition with one binary machine per class (paper Section 5.3).

    Machine k is trained on "class k" (+1) against the rest (-1). A pattern goes to the class
    whose machine alone claims it (f > 0); otherwise (none or several claim it) to the machine
    with the largest f, and the pattern is flagged "don't know".

    Parameters
    ----------
    estimator : binary estimator, optional
        A :class:`TensorSVC` / :class:`TensorRLS`, or a selection search
        (:class:`~eskin.selection.MaximalDiscrepancySearch`, ...) whose ``best_estimator_`` is
        kept. Default ``TensorSVC()``.
    n_jobs : int, optional
        Machines trained in parallel (joblib).

    Fitted attributes: ``classes_``, ``estimators_`` (binary machine k has ``classes_ = [-1,
    1]``, positive = ``classes_[k]``), ``searches_`` (the fitted searches, or None), and
    ``dont_know_``: the flags of the most recent ``predict``/``decide`` call.
    """

    def __init__(self, estimator=None, n_jobs=None):
        self.estimator = estimator
        self.n_jobs = n_jobs

    def __sklearn_tags__(self):
        tags = super().__sklearn_tags__()
        tags.input_tags.three_d_array = True
        return tags

    def fit(self, X, y, *, machine_indices=None, groups=None):
        """Train one machine per class.

        ``machine_indices``: optional sequence (one per class, in ``np.unique(y)`` order) of
        index arrays into ``X``: machine k trains only on those patterns (the paper's 3-class
        protocol gives each machine its own balanced 180-pattern set, reading R23).
        ``groups``: optional group label per pattern (e.g. participant), handed (restricted to
        each machine's patterns) to an estimator whose ``fit`` takes ``groups``, such as
        :class:`~eskin.CrossValidationSearch`, so that its splits keep groups apart.
        """
        X, y = validate_data(self, X, y, allow_nd=True, dtype=np.float64)
        check_classification_targets(y)
        self.classes_ = np.unique(y)
        if self.classes_.size < 2:
            raise ValueError(
                f"OneVsAllTouchClassifier needs at least 2 classes; y has {self.classes_.size} class"
            )
        estimator = TensorSVC() if self.estimator is None else self.estimator
        if machine_indices is None:
            subsets = [np.arange(len(y))] * self.classes_.size
        else:
            if len(machine_indices) != self.classes_.size:
                raise ValueError(
                    f"machine_indices has {len(machine_indices)} entries, one per class "
                    f"({self.classes_.size}) is needed"
                )
            subsets = [np.asarray(ix, dtype=np.intp) for ix in machine_indices]
        if groups is not None and len(groups) != len(y):
            raise ValueError(f"groups has {len(groups)} entries for {len(y)} patterns")
        shared = _shared_distances(estimator, X)
        fitted = list(
            run_calls(
                _fit_machine,
                [
                    (
                        (
                            estimator,
                            X[ix],
                            np.where(y[ix] == c, 1, -1),
                            None if groups is None else np.asarray(groups)[ix],
                            None if shared is None else (*shared, ix),
                        ),
                        {},
                    )
                    for c, ix in zip(self.classes_, subsets)
                ],
                n_jobs=self.n_jobs,
            )
        )
        self.estimators_ = [getattr(m, "best_estimator_", m) for m in fitted]
        self.searches_ = [m if hasattr(m, "best_estimator_") else None for m in fitted]
        self._last = {"dont_know": None}
        return self

    def decision_function(self, X):
        """Decision values of every machine, shape (n, n_classes); column k > 0 claims class k."""
        check_is_fitted(self)
        _check_pattern_order(self.estimators_[0], X, type(self).__name__)
        X = validate_data(self, X, reset=False, allow_nd=True, dtype=np.float64)
        return np.column_stack([m.decision_function(X) for m in self.estimators_])

    def decide(self, X) -> TouchDecision:
        """Labels, per-machine decision values, claim counts and "don't know" flags."""
        f = self.decision_function(X)
        index, n_claims, dont_know = one_vs_all_rule(f)
        self._last["dont_know"] = dont_know
        return TouchDecision(self.classes_[index], f, n_claims, dont_know)

    def predict(self, X):
        """Class labels by the paper's rule; the flags are then in ``dont_know_``."""
        return self.decide(X).labels

    @property
    def dont_know_(self):
        """"Don't know" flags (no machine or several claimed) of the last predict/decide."""
        check_is_fitted(self)
        return self._last["dont_know"]
