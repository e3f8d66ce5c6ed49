"""At most N support vectors in a fitted model: a reduced set by projection.

The memory and the time of a decision on the controller grow with the number of distinct
support vectors the model stores (every machine of a 1-vs-all model reads the same table). A
fitted kernel machine is ``f(x) = <w, phi(x)> + b`` with ``w = sum_i beta_i phi(sv_i)``.
:func:`bound_support` keeps ``max_support`` of the model's distinct support vectors, ``S``, and
replaces each machine's ``w`` by its orthogonal projection onto the span of ``phi(S)`` in that
machine's own kernel: the closest function the kept patterns can express, with coefficients
``gamma = K_SS^+ K_S,sv beta`` (``K`` the machine's kernel, amplitude factor included) and the
intercept unchanged. This needs no training data: everything comes from the fitted machines.
With patterns to fit on (``X_fit``, what ``eskin train --max-support`` passes: the training
patterns), each machine's coefficients on the kept patterns are instead the least-squares fit
of its own decision values on those patterns, ``gamma = argmin ||K_X,S gamma - K_X,sv beta||``:
the same kept patterns, coefficients that reproduce the decisions where the data are rather than
``w`` everywhere (on simulated campaigns it loses far less accuracy at small budgets).

Which patterns are kept (``selection``): "greedy" (default) adds one pattern at a time, the
one whose addition removes the most of the machines' remaining ``||w_m - P_S w_m||^2`` (each
machine counted by its share of its own ``||w_m||^2``): kernel matching pursuit, computed with a
pivoted Cholesky factor of each machine's kernel; "coefficients" keeps the patterns carrying
the largest share of the machines' coefficients, ``sum_m |beta_m,i| / sum_j |beta_m,j|``. Both
give nested sets (the kept patterns of a budget are among those of any larger one). How much
accuracy each costs on unseen participants, against the number of support vectors, is measured
by ``benchmarks/support_budget.py`` (docs/learning.md, "At most N support vectors").
"""

from __future__ import annotations

import copy
from typing import Any

import numpy as np
import scipy.linalg

from .estimators import amplitude_factor, kernel_from_distances
from .kernel import mode_distances, pattern_log_energy

#: singular values of K_SS below this share of the largest are treated as zero (a kept pattern
#: the others already express adds nothing, instead of a huge pair of opposite coefficients)
RCOND = 1e-10


def _machines(estimator: Any) -> list[Any]:
    return list(estimator.estimators_) if hasattr(estimator, "estimators_") else [estimator]


def distinct_support(estimator: Any) -> tuple[np.ndarray, np.ndarray, list[np.ndarray]]:
    """(the distinct support vectors of every machine, their log energies, for each machine the
    row of each of its support vectors in that table)."""
    rows: dict[bytes, int] = {}
    patterns: list[np.ndarray] = []
    energies: list[float] = []
    where: list[np.ndarray] = []
    for m in _machines(estimator):
        sv = np.asarray(m.support_vectors_, dtype=np.float64)
        energy = getattr(m, "sv_log_energy_", None)
        idx = np.empty(len(sv), dtype=np.intp)
        for i, p in enumerate(sv):
            key = np.ascontiguousarray(p).tobytes()
            if key not in rows:
                rows[key] = len(patterns)
                patterns.append(p)
                energies.append(0.0 if energy is None else float(energy[i]))
            idx[i] = rows[key]
        where.append(idx)
    shape = np.shape(_machines(estimator)[0].support_vectors_)[1:]
    table = np.array(patterns, dtype=np.float64).reshape((len(patterns), *shape))
    return table, np.asarray(energies, dtype=np.float64), where


def _kernel(m: Any, a: np.ndarray, ea: np.ndarray, b: np.ndarray, eb: np.ndarray) -> np.ndarray:
    K = kernel_from_distances(mode_distances(a, b, alpha=m.alphas_), m.sigmas_)
    factor = amplitude_factor(ea, eb, float(getattr(m, "amplitude_width_", 0.0) or 0.0))
    return K if factor is None else K * factor


class _TableKernels:
    """The kernel of the support table with itself and of the fitting patterns with the table,
    computed once per kernel setting (the machines of a 1-vs-all model share one) and sliced
    for each machine's support vectors and the kept rows."""

    def __init__(self, table: np.ndarray, energies: np.ndarray,
                 X_fit: np.ndarray | None = None) -> None:
        self.table, self.energies, self.X_fit = table, energies, X_fit
        self.e_fit = None if X_fit is None else pattern_log_energy(X_fit)
        self._made: dict[tuple, np.ndarray] = {}

    def _get(self, m: Any, of_fit: bool) -> np.ndarray:
        width = float(getattr(m, "amplitude_width_", 0.0) or 0.0)
        key = (of_fit, tuple(m.alphas_), tuple(m.sigmas_), width)
        if key not in self._made:
            a, ea = (self.X_fit, self.e_fit) if of_fit else (self.table, self.energies)
            self._made[key] = _kernel(m, a, ea, self.table, self.energies)
        return self._made[key]

    def square(self, m: Any) -> np.ndarray:
        """K(table, table) in ``m``'s kernel."""
        return self._get(m, False)

    def of_fit(self, m: Any) -> np.ndarray:
        """K(X_fit, table) in ``m``'s kernel."""
        return self._get(m, True)


def _project_rows(m: Any, kernels: _TableKernels, keep: np.ndarray, rows: np.ndarray) -> None:
    """:func:`project_machine` onto the table rows ``keep``, the machine's support vectors
    being the table rows ``rows``, from the table's kernels."""
    coef = np.asarray(m.dual_coef_, dtype=np.float64).reshape(-1)
    if coef.size == 0 or len(keep) == 0:
        gamma = np.zeros(len(keep))
    elif kernels.X_fit is not None:
        K = kernels.of_fit(m)
        gamma = scipy.linalg.lstsq(K[:, keep], K[:, rows] @ coef, cond=RCOND)[0]
    else:
        K = kernels.square(m)[keep]
        gamma = scipy.linalg.lstsq(K[:, keep], K[:, rows] @ coef, cond=RCOND)[0]
    m.support_vectors_ = np.ascontiguousarray(kernels.table[keep])
    m.sv_log_energy_ = np.ascontiguousarray(kernels.energies[keep])
    m.dual_coef_ = np.ascontiguousarray(gamma)
    m.support_ = np.full(len(keep), -1, dtype=np.intp)  # no longer training rows


def project_machine(m: Any, patterns: np.ndarray, energies: np.ndarray,
                    X_fit: np.ndarray | None = None) -> None:
    """Replace the fitted machine ``m``'s support by ``patterns`` (with their log energies),
    its coefficients by the projection of its ``w`` onto their span (in place); with
    ``X_fit`` (patterns, e.g. the training set), by the least-squares fit of its decision values
    on them instead."""
    coef = np.asarray(m.dual_coef_, dtype=np.float64).reshape(-1)
    sv = np.asarray(m.support_vectors_, dtype=np.float64)
    e_sv = np.asarray(getattr(m, "sv_log_energy_", np.zeros(len(sv))), dtype=np.float64)
    if coef.size == 0 or len(patterns) == 0:
        gamma = np.zeros(len(patterns))
    elif X_fit is not None:
        e_fit = pattern_log_energy(X_fit)
        target = _kernel(m, X_fit, e_fit, sv, e_sv) @ coef
        A = _kernel(m, X_fit, e_fit, patterns, energies)
        gamma = scipy.linalg.lstsq(A, target, cond=RCOND)[0]
    else:
        K_pp = _kernel(m, patterns, energies, patterns, energies)
        rhs = _kernel(m, patterns, energies, sv, e_sv) @ coef
        gamma = scipy.linalg.lstsq(K_pp, rhs, cond=RCOND)[0]
    m.support_vectors_ = np.ascontiguousarray(patterns)
    m.sv_log_energy_ = np.ascontiguousarray(energies)
    m.dual_coef_ = np.ascontiguousarray(gamma)
    m.support_ = np.full(len(patterns), -1, dtype=np.intp)  # no longer training rows


def _coefficient_order(estimator: Any, n_table: int, where: list[np.ndarray]) -> np.ndarray:
    """Table rows by their share of the machines' coefficients, largest first."""
    score = np.zeros(n_table)
    for m, idx in zip(_machines(estimator), where):
        mass = np.abs(np.asarray(m.dual_coef_, dtype=np.float64).reshape(-1))
        if mass.sum() > 0:
            np.add.at(score, idx, mass / mass.sum())
    return np.argsort(-score, kind="stable")


def _greedy_order(estimator: Any, table: np.ndarray, energies: np.ndarray,
                  where: list[np.ndarray], count: int,
                  kernels: _TableKernels | None = None) -> np.ndarray:
    """The first ``count`` table rows chosen one at a time, each the one whose addition removes
    the most of the machines' remaining ``||w_m - P_S w_m||^2`` (each machine's share of its
    own ``||w_m||^2``): kernel matching pursuit, by a pivoted Cholesky factor per machine."""
    n = len(table)
    kernels = kernels or _TableKernels(table, energies)
    state = []
    for m, idx in zip(_machines(estimator), where):
        beta = np.zeros(n)
        np.add.at(beta, idx, np.asarray(m.dual_coef_, dtype=np.float64).reshape(-1))
        K = kernels.square(m)
        resid = K @ beta  # <w - P_S w, phi(x_i)> for every row, S empty
        norm = float(beta @ resid)
        if norm > 0:
            state.append((K, resid, np.diag(K).copy(), np.zeros((n, count)), norm))
    chosen: list[int] = []
    free = np.ones(n, dtype=bool)
    for t in range(count):
        gain = np.zeros(n)
        for K, resid, diag, G, norm in state:
            ok = diag > RCOND * np.max(np.diag(K))
            gain[ok] += resid[ok] ** 2 / diag[ok] / norm
        gain[~free] = -1.0
        j = int(np.argmax(gain))  # ties: the earlier row
        chosen.append(j)
        free[j] = False
        for K, resid, diag, G, _ in state:
            if diag[j] <= RCOND * np.max(np.diag(K)):
                continue  # phi(x_j) adds nothing for this machine
            g = (K[:, j] - G[:, :t] @ G[j, :t]) / np.sqrt(diag[j])
            G[:, t] = g
            resid -= g * (resid[j] / g[j])
            np.subtract(diag, g * g, out=diag)
    return np.asarray(chosen, dtype=np.intp)


#: how :func:`bound_support` chooses the kept patterns
SELECTIONS = ("greedy", "coefficients")


def kept_patterns(estimator: Any, max_support: int, selection: str = "greedy",
                  kernels: _TableKernels | None = None) -> np.ndarray:
    """Rows of :func:`distinct_support`'s table that :func:`bound_support` keeps (sorted)."""
    if selection not in SELECTIONS:
        raise ValueError(f"selection must be one of {SELECTIONS}, got {selection!r}")
    table, energies, where = distinct_support(estimator)
    count = min(int(max_support), len(table))
    if selection == "coefficients":
        order = _coefficient_order(estimator, len(table), where)[:count]
    else:
        order = _greedy_order(estimator, table, energies, where, count, kernels)
    return np.sort(order)


def check_max_support(max_support: Any) -> int:
    """``max_support`` as an int; TypeError if it is not a whole number, ValueError below 1."""
    if isinstance(max_support, bool) or not isinstance(max_support, (int, np.integer)):
        raise TypeError(f"max_support must be a whole number, got {max_support!r}")
    if max_support < 1:
        raise ValueError(f"max_support must be at least 1, got {max_support}")
    return int(max_support)


def bound_support(estimator: Any, max_support: int, selection: str = "greedy",
                  X_fit: np.ndarray | None = None) -> Any:
    """A copy of the fitted ``estimator`` (a TensorSVC/TensorRLS or a OneVsAllTouchClassifier)
    with at most ``max_support`` distinct support vectors over all its machines (see the
    module's docstring); the estimator itself when it already has no more."""
    max_support = check_max_support(max_support)
    table, energies, where = distinct_support(estimator)
    if len(table) <= max_support:
        return estimator
    kernels = _TableKernels(table, energies, X_fit)
    keep = kept_patterns(estimator, max_support, selection, kernels)
    out = copy.deepcopy(estimator)
    for m, rows in zip(_machines(out), where):
        _project_rows(m, kernels, keep, rows)
    return out


def n_distinct_support(estimator: Any) -> int:
    """The number of distinct support vectors over all the machines (what a model stores)."""
    return len(distinct_support(estimator)[0])

#: bytes of a model file beside its support vectors' bases: headers, preprocessing, classes,
#: calibration and meta (a few KB; a generous bound)
MODEL_FIXED_BYTES = 64 * 1024


def support_bytes(estimator: Any) -> int:
    """Bytes one distinct support vector takes in a float32 ``.eskin`` file of ``estimator``:
    its bases at the largest alpha of every mode over the machines (4 bytes a value, sum over
    modes of N_z x alpha_z), its ranks and log energy, and a coefficient and index per machine."""
    machines = _machines(estimator)
    shape = tuple(int(d) for d in machines[0].tensor_shape_)
    size = int(np.prod(shape))
    store = [max(int(m.alphas_[z]) for m in machines) for z in range(len(shape))]
    values = sum(size // d * a for d, a in zip(shape, store))
    return 4 * values + 4 * len(shape) + 8 + 8 * len(machines)


def support_for_size(estimator: Any, max_bytes: int) -> int:
    """The most distinct support vectors a float32 model of ``estimator``'s machines can hold
    in ``max_bytes`` (:func:`support_bytes` each, beside :data:`MODEL_FIXED_BYTES`), at least 1."""
    return max(1, (int(max_bytes) - MODEL_FIXED_BYTES) // support_bytes(estimator))
