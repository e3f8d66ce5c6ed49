"""The tensor kernel of Gastaldo et al. (Sensors 2014, Appendix), computed by the C++ core.

A pattern is a tensor of order Z >= 2 (a touch: rows x cols x D samples). For each mode z the
pattern is unfolded into a d_z x N_z matrix and summarised by the subspace of its first
``alpha_z`` right-singular vectors. Two patterns are compared mode by mode through the
squared Frobenius distance of the projections onto those subspaces,

    d_z(a, b) = ||P_a - P_b||_F^2 = r_a + r_b - 2 ||V_a^T V_b||_F^2,

and the kernel is the product of Gaussian factors ``exp(-d_z / (2 sigma_z^2))``.

``mode_distances`` returns the distances, which do not depend on sigma: a sigma sweep is one
``kernel_from_distances`` (one ``exp``) per sigma. ``pattern_bases`` computes the per-pattern
bases once so that several distance/kernel evaluations (training set against itself, against
validation sets) reuse them. See ``docs/kernel.md`` for the conventions (column order of the
unfoldings, numerical rank, ties).
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Sequence
from typing import Union

import numpy as np

from eskin import _core

__all__ = [
    "PatternBases",
    "bases_mode_distances",
    "bases_tensor_kernel",
    "distance_plan",
    "kernel_from_distances",
    "mode_distances",
    "pattern_bases",
    "pattern_log_energy",
    "resolve_alphas",
    "tensor_kernel",
]

#: Per-pattern, per-mode orthonormal bases of a set of patterns (from :func:`pattern_bases`).
#: Attributes: ``count``, ``shape`` (one pattern's dimensions), ``alphas``, ``ranks`` ((n, Z) ints)
#: and ``mode_bases(z)`` -> (n, N_z, alpha_z) array (columns beyond a pattern's rank are zero).
PatternBases = _core.PatternBases

AlphaSpec = Union[int, str, Sequence[int]]
SigmaSpec = Union[float, Sequence[float]]


def _pattern_shape(shape: Sequence[int]) -> tuple[int, ...]:
    try:
        dims = tuple(int(d) for d in shape)
    except TypeError as exc:
        raise ValueError(f"shape={shape!r} is not a sequence of dimensions") from exc
    if len(dims) < 2:
        raise ValueError(
            f"shape={dims} has {len(dims)} mode(s); the tensor kernel needs patterns of order >= 2"
        )
    if any(d < 1 for d in dims):
        raise ValueError(f"shape={dims} has a dimension < 1")
    return dims


def _is_int(value: object) -> bool:
    return isinstance(value, numbers.Integral) and not isinstance(value, (bool, np.bool_))


def resolve_alphas(shape: Sequence[int], alpha: AlphaSpec = "full") -> tuple[int, ...]:
    """Number of singular vectors kept per mode, for patterns of dimensions ``shape``.

    ``shape`` is ONE pattern's shape (d1, ..., dZ), not the batch's. ``alpha`` is ``"full"``
    (Q_z = min(d_z, prod of the other dimensions)), ``"half"`` (floor(Q_z / 2), at least 1), an
    int used for every mode, or one int per mode. Every value must lie in [1, Q_z]; a larger int
    is an error, never silently clipped.
    """
    dims = _pattern_shape(shape)
    size = math.prod(dims)
    q = tuple(min(d, size // d) for d in dims)
    if isinstance(alpha, str):
        if alpha == "full":
            return q
        if alpha == "half":
            return tuple(max(1, qz // 2) for qz in q)
        raise ValueError(f"alpha={alpha!r}: expected 'full', 'half', an int or one int per mode")
    if _is_int(alpha):
        values = (int(alpha),) * len(dims)
    elif isinstance(alpha, (Sequence, np.ndarray)):
        values_list = list(alpha)
        if len(values_list) != len(dims):
            raise ValueError(
                f"alpha={alpha!r} has {len(values_list)} values but patterns of shape {dims} "
                f"have {len(dims)} modes"
            )
        if not all(_is_int(v) for v in values_list):
            raise ValueError(f"alpha={alpha!r}: every value must be an integer")
        values = tuple(int(v) for v in values_list)
    else:
        raise ValueError(f"alpha={alpha!r}: expected 'full', 'half', an int or one int per mode")
    for z, (a, qz) in enumerate(zip(values, q)):
        if a < 1 or a > qz:
            raise ValueError(
                f"alpha={a} for mode {z} is outside [1, Q_{z}={qz}] (pattern shape {dims}; "
                f"Q_z = min(d_z, product of the other dimensions))"
            )
    return values


def _resolve_sigmas(sigma: SigmaSpec, n_modes: int) -> list[float]:
    # ValueError (not TypeError) for every bad sigma: the API promises one error type
    if isinstance(sigma, (bool, np.bool_, str)):
        raise ValueError(f"sigma={sigma!r}: expected a positive number or one per mode")  # noqa: TRY004
    if isinstance(sigma, numbers.Real):
        values = [float(sigma)] * n_modes
    elif isinstance(sigma, (Sequence, np.ndarray)):
        values = [float(s) for s in np.asarray(sigma, dtype=float).ravel()]
        if len(values) != n_modes:
            raise ValueError(
                f"sigma={sigma!r} has {len(values)} values; expected one, or one per mode ({n_modes})"
            )
    else:
        raise ValueError(f"sigma={sigma!r}: expected a positive number or one per mode")  # noqa: TRY004
    for s in values:
        if not (math.isfinite(s) and s > 0):
            raise ValueError(f"sigma={s!r} must be a positive finite number")
    return values


def _as_patterns(X: object, name: str) -> np.ndarray:
    arr = np.asarray(X)
    if arr.dtype.kind not in "biuf":
        raise ValueError(f"{name} has dtype {arr.dtype}; expected real numbers")
    arr = np.ascontiguousarray(arr, dtype=np.float64)
    if arr.ndim < 3:
        raise ValueError(
            f"{name} has shape {arr.shape}: expected (n, d1, ..., dZ), a batch of patterns with "
            f"at least 2 modes"
        )
    return arr


def _threads(n_threads: int | None) -> int:
    if n_threads is None:
        return 0
    if not _is_int(n_threads) or n_threads < 1:
        raise ValueError(f"n_threads={n_threads!r} must be a positive int or None")
    return int(n_threads)


def _bases(arr: np.ndarray, alphas: tuple[int, ...], name: str, n_threads: int) -> PatternBases:
    try:
        return _core.compute_pattern_bases(arr, list(alphas), n_threads)
    except ValueError as exc:  # e.g. "pattern 3 contains NaN or Inf"
        raise ValueError(f"{name}: {exc}") from None


def pattern_bases(
    X: object, *, alpha: AlphaSpec = "full", n_threads: int | None = None
) -> PatternBases:
    """Per-mode subspace bases of every pattern of ``X`` (shape (n, d1, ..., dZ)).

    Compute them once and pass them to :func:`bases_mode_distances` /
    :func:`bases_tensor_kernel` to evaluate several kernels without repeating the SVDs.
    """
    arr = _as_patterns(X, "X")
    alphas = resolve_alphas(arr.shape[1:], alpha)
    return _bases(arr, alphas, "X", _threads(n_threads))


def _check_pair(bx: PatternBases, by: PatternBases | None) -> None:
    if not isinstance(bx, PatternBases):
        raise TypeError(f"expected PatternBases from eskin.kernel.pattern_bases, got {type(bx)}")
    if by is None:
        return
    if not isinstance(by, PatternBases):
        raise TypeError(f"expected PatternBases from eskin.kernel.pattern_bases, got {type(by)}")
    if tuple(bx.shape) != tuple(by.shape):
        raise ValueError(
            f"pattern shapes differ: X patterns {tuple(bx.shape)}, Y patterns {tuple(by.shape)}"
        )
    if tuple(bx.alphas) != tuple(by.alphas):
        raise ValueError(f"alphas differ: X {tuple(bx.alphas)}, Y {tuple(by.alphas)}")


def bases_mode_distances(
    bx: PatternBases, by: PatternBases | None = None, *, n_threads: int | None = None
) -> np.ndarray:
    """Per-mode squared distances (n_modes, n, m) between precomputed bases."""
    _check_pair(bx, by)
    return _core.mode_distances(bx, by, _threads(n_threads))


def bases_tensor_kernel(
    bx: PatternBases,
    by: PatternBases | None = None,
    *,
    sigma: SigmaSpec = 1.0,
    n_threads: int | None = None,
) -> np.ndarray:
    """Kernel matrix (n, m) between precomputed bases."""
    _check_pair(bx, by)
    sigmas = _resolve_sigmas(sigma, len(bx.shape))
    return _core.tensor_kernel(bx, by, sigmas, _threads(n_threads))


def _prepare(
    X: object, Y: object | None, alpha: AlphaSpec, n_threads: int | None
) -> tuple[PatternBases, PatternBases | None, int]:
    nt = _threads(n_threads)
    x = _as_patterns(X, "X")
    y = None
    if Y is not None:
        y = _as_patterns(Y, "Y")
        if y.shape[1:] != x.shape[1:]:
            raise ValueError(
                f"X patterns have shape {x.shape[1:]} but Y patterns have shape {y.shape[1:]} "
                f"(X.shape={x.shape}, Y.shape={y.shape})"
            )
    alphas = resolve_alphas(x.shape[1:], alpha)
    bx = _bases(x, alphas, "X", nt)
    by = None if y is None else _bases(y, alphas, "Y", nt)
    return bx, by, nt


def mode_distances(
    X: object,
    Y: object | None = None,
    *,
    alpha: AlphaSpec = "full",
    n_threads: int | None = None,
    max_bytes: int | None = None,
) -> np.ndarray:
    """Per-mode squared projection distances, shape (n_modes, n, m).

    ``X`` has shape (n, d1, ..., dZ), ``Y`` (m, d1, ..., dZ); ``Y=None`` means X against itself
    (symmetric, each pair computed once, zeros on the diagonal). The distances do not depend on
    sigma: ``kernel_from_distances(D, sigma)`` turns them into a kernel matrix. ``max_bytes``:
    the scratch memory of the pairwise kernel (the bases repacked for it), which then works
    block by block (:func:`distance_plan`); the same distances, bit for bit, for any limit.
    None: :data:`DEFAULT_SCRATCH_BYTES`, or two blocks of 8 patterns when they need more.
    """
    bx, by, nt = _prepare(X, Y, alpha, n_threads)
    if max_bytes is None:
        smallest = distance_plan(bx.shape, bx.alphas, 8, 8)["pack_bytes"]
        max_bytes = max(DEFAULT_SCRATCH_BYTES, smallest)
    try:
        return _core.mode_distances(bx, by, nt, _max_bytes(max_bytes))
    except ValueError as exc:
        raise ValueError(str(exc)) from None


#: The pairwise kernel's scratch memory by default (:func:`mode_distances`): the whole set of
#: patterns in one block for the paper's 4 x 4 skin, blocks of them for a large grid at a
#: large D (a 19 x 27 x 100 pattern at alpha Q packs into 16 MB).
DEFAULT_SCRATCH_BYTES = 256 << 20


def _max_bytes(max_bytes: int | None) -> int:
    if max_bytes is None:
        return 0
    if not _is_int(max_bytes) or max_bytes < 1:
        raise ValueError(f"max_bytes={max_bytes!r} must be a positive int or None")
    return int(max_bytes)


def distance_plan(
    shape: Sequence[int], alphas: Sequence[int], n: int, m: int | None = None,
    max_bytes: int | None = None,
) -> dict[str, int]:
    """How :func:`mode_distances` lays out its scratch memory for ``n`` patterns of ``shape``
    against ``m`` (None: against themselves) within ``max_bytes``: ``block`` patterns packed
    at once, ``row_blocks`` x ``col_blocks`` blocks, ``pack_bytes`` at most at once,
    ``pattern_bytes`` per packed pattern."""
    dims = _pattern_shape(shape)
    return dict(_core.plan_distances(list(dims), [int(a) for a in alphas], int(n),
                                     int(n if m is None else m), m is None,
                                     _max_bytes(max_bytes)))


def tensor_kernel(
    X: object,
    Y: object | None = None,
    *,
    sigma: SigmaSpec = 1.0,
    alpha: AlphaSpec = "full",
    n_threads: int | None = None,
) -> np.ndarray:
    """Tensor-kernel Gram matrix K[i, j] = prod_z exp(-d_z(X_i, Y_j) / (2 sigma_z^2)).

    ``sigma``: a positive number or one per mode. ``alpha``: see :func:`resolve_alphas`.
    ``n_threads``: worker threads (default: $ESKIN_NUM_THREADS, else all cores).
    """
    x_modes = np.ndim(X) - 1
    sigmas = _resolve_sigmas(sigma, max(x_modes, 1)) if x_modes >= 2 else None
    bx, by, nt = _prepare(X, Y, alpha, n_threads)
    assert sigmas is not None  # _prepare rejected fewer than 2 modes
    return _core.tensor_kernel(bx, by, sigmas, nt)


#: Added to a pattern's mean square before the logarithm, so that an all-zero pattern has a
#: finite log energy (log 1e-12 = -27.6). The deployed classifier uses the same constant.
LOG_ENERGY_FLOOR = 1e-12


def pattern_log_energy(X: object) -> np.ndarray:
    """Log energy of each pattern of ``X`` (shape (n, d1, ..., dZ)): ``log(mean(x^2) + 1e-12)``
    over all of a pattern's entries, shape (n,).

    The tensor kernel compares subspaces and is blind to amplitude (a tap and a punch with the
    same shape are the same pattern to it); the amplitude-aware kernel of the estimators
    multiplies it by a Gaussian on the difference of these log energies. The log makes the
    difference independent of the sensor's units (a gain multiplies every energy alike).
    """
    arr = _as_patterns(X, "X")
    flat = arr.reshape(arr.shape[0], -1)
    with np.errstate(over="ignore"):
        mean_square = np.einsum("ij,ij->i", flat, flat) / flat.shape[1]
    return np.log(mean_square + LOG_ENERGY_FLOOR)


def kernel_from_distances(distances: object, sigma: SigmaSpec = 1.0) -> np.ndarray:
    """Kernel matrix from per-mode distances (n_modes, n, m): exp(-sum_z d_z / (2 sigma_z^2))."""
    d = np.asarray(distances, dtype=np.float64)
    if d.ndim != 3:
        raise ValueError(f"distances has shape {d.shape}: expected (n_modes, n, m)")
    sigmas = np.asarray(_resolve_sigmas(sigma, d.shape[0]))
    coef = 1.0 / (2.0 * sigmas**2)
    return np.exp(-np.tensordot(coef, d, axes=1))
