"""The settings a search tries, and the searches themselves.

The paper's grid (Section 5.2) and a quick grid in per-mode alpha terms (``"1"``, ``"Q/2"``,
``"Q"``), the amplitude factor's widths, and building and fitting the Maximal Discrepancy or
cross-validation search over them (shared by :func:`eskin.learn.training.train_model` and
:mod:`eskin.experiments`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from eskin.errors import TrainingError
from eskin.learn.recipes import ALPHA_SPEC

#: The paper's grid (Section 5.2). For the SVM, C = 1/lambda.
PAPER_LAMBDAS: tuple[float, ...] = (1e-3, 1e-2, 1e-1, 1e0, 1e1)
PAPER_SIGMAS: tuple[float, ...] = tuple(2.0**k for k in range(-4, 5))
PAPER_ALPHAS: tuple[str, ...] = ("1", "Q/2", "Q")

#: The amplitude-aware kernel's widths searched by default (None: the paper's kernel; a number:
#: the width in spreads of the training patterns' log energy, see eskin.TensorSVC). With the
#: factor in the grid the default recipe's held-out error on unseen participants of simulated
#: campaigns fell from 14.4 % to 11.3 % (99 units, docs/selection-study.md); "off" stays in the
#: grid for sensors whose amplitude says nothing about the touch.
DEFAULT_AMPLITUDES: tuple[float | None, ...] = (None, 1.0, 4.0)

QUICK_LAMBDAS: tuple[float, ...] = (1e-2, 1e0)
QUICK_SIGMAS: tuple[float, ...] = (2.0**-1, 2.0**1)
QUICK_ALPHAS: tuple[str, ...] = ("1", "Q/2")

#: D when the recordings allow it (the paper's largest; the study found it as good as 50 and
#: better than 20); with D=None, train_model takes the median training touch window's samples
#: when that is fewer (no point stretching most touches by interpolation; training_set.fillable_D).
DEFAULT_D = 100

MACHINES: tuple[str, ...] = ("svm", "rls")
SELECTIONS: tuple[str, ...] = ("md", "cv")


def alpha_value(label: str, shape: Sequence[int]) -> tuple[int, ...]:
    """Per-mode alpha of the grid labels "1", "Q/2", "Q" on patterns of ``shape``
    (``docs/paper-readings.md``, R8).

    Q_z = min(d_z, product of the other dimensions) is the rank bound of the mode-z unfolding
    (4, 4 and 16 for a 4x4xD pattern with D >= 16); Q_z/2 is rounded down and at least 1.
    """
    from eskin.learn.kernel import resolve_alphas

    if label not in ALPHA_SPEC:
        raise TrainingError(f"alpha label must be one of '1', 'Q/2', 'Q', got {label!r}")
    return tuple(int(a) for a in resolve_alphas(tuple(shape), ALPHA_SPEC[label]))


def alpha_label(alpha: Any) -> str | None:
    """The grid label ("1", "Q/2", "Q") of an estimator alpha value, or None."""
    for lab, spec in ALPHA_SPEC.items():
        if isinstance(alpha, str) == isinstance(spec, str) and alpha == spec:
            return lab
    return None


def param_grid(
    lambdas: Sequence[float] = PAPER_LAMBDAS,
    sigmas: Sequence[float] = PAPER_SIGMAS,
    alphas: Sequence[str] = PAPER_ALPHAS,
    amplitudes: Sequence[float | None] = (None,),
) -> dict[str, list[Any]]:
    """The search grid in lambda for both machines (the searches train the SVM with C =
    1/lambda, reading R9), sigma, alpha in the estimators' terms (1, "half", "full") and, unless
    it is only None (the paper's kernel), the amplitude factor's width."""
    for a in alphas:
        if a not in ALPHA_SPEC:
            raise TrainingError(f"alpha label must be one of '1', 'Q/2', 'Q', got {a!r}")
    if not lambdas or not sigmas or not alphas or not amplitudes:
        raise TrainingError(
            "the grid needs at least one lambda, one sigma, one alpha and one amplitude"
        )
    grid: dict[str, list[Any]] = {
        "lam": [float(v) for v in lambdas],
        "sigma": [float(v) for v in sigmas],
        "alpha": [ALPHA_SPEC[a] for a in alphas],
    }
    if list(amplitudes) != [None]:
        grid["amplitude"] = [_checked_amplitude(a) for a in amplitudes]
    return grid


def _checked_amplitude(value: Any) -> float | None:
    """``value`` (None, a number or its text) as the estimators' ``amplitude``; a TrainingError
    naming the accepted range otherwise."""
    from eskin.learn.estimators import AMPLITUDE_RANGE, check_amplitude

    if value is None:
        return None
    try:
        return check_amplitude(float(value))
    except (TypeError, ValueError):
        low, high = AMPLITUDE_RANGE
        raise TrainingError(
            f"amplitude must be 'off' or a number in [{low:g}, {high:g}], got {value!r}"
        ) from None


def parse_amplitudes(text: str) -> tuple[float | None, ...]:
    """Amplitude-factor widths from text such as "off", "1" or "off,1,4" ("off"/"none": the
    paper's kernel without the factor)."""
    values: list[float | None] = []
    for item in (t.strip() for t in str(text).split(",")):
        values.append(None if item.lower() in ("off", "none") else _checked_amplitude(item))
    return tuple(values)


def make_search(
    machine: str,
    selection: str,
    grid: Mapping[str, list[Any]],
    *,
    seed: int = 0,
    md_options: Mapping[str, Any] | None = None,
    cv_options: Mapping[str, Any] | None = None,
    n_jobs: int = 1,
) -> Any:
    """A Maximal Discrepancy or cross-validation search over ``grid`` for one tensor machine.

    CV searches are fitted with ``groups`` (participants) when known (:func:`fit_search`), so
    that no participant is on both sides of a split.
    """
    from eskin.learn.estimators import TensorRLS, TensorSVC
    from eskin.learn.selection import CrossValidationSearch, MaximalDiscrepancySearch

    if machine not in MACHINES:
        raise TrainingError(f"machine must be 'svm' or 'rls', got {machine!r}")
    est = TensorSVC() if machine == "svm" else TensorRLS()
    if selection == "md":
        return MaximalDiscrepancySearch(
            est, dict(grid), random_state=seed, n_jobs=n_jobs, **dict(md_options or {})
        )
    if selection == "cv":
        return CrossValidationSearch(
            est, dict(grid), random_state=seed, n_jobs=n_jobs, **dict(cv_options or {})
        )
    raise TrainingError(f"selection must be 'md' or 'cv', got {selection!r}")


def fit_search(search: Any, X: np.ndarray, y: np.ndarray, groups: np.ndarray | None) -> Any:
    """Fit a search; CV searches get the participant groups (when there are at least 2)."""
    from eskin.learn.selection import CrossValidationSearch

    if (
        isinstance(search, CrossValidationSearch)
        and groups is not None
        and len(np.unique(groups)) >= 2
    ):
        return search.fit(X, y, groups=groups)
    return search.fit(X, y)


def describe_params(
    machine: str, params: Mapping[str, Any], estimator: Any = None
) -> dict[str, Any]:
    """A selected setting in the paper's terms: lambda (and C for the SVM), sigma, alpha label,
    and the per-mode alphas the fitted estimator used."""
    alpha = params.get("alpha")
    lam = 1.0 / float(params["C"]) if "C" in params else float(params["lam"])
    out: dict[str, Any] = {
        "lambda": lam,
        "sigma": float(np.mean(np.atleast_1d(params["sigma"]))),
        "alpha": alpha_label(alpha),
        "alpha_value": alpha if isinstance(alpha, str) else np.atleast_1d(alpha).tolist(),
        "alphas": [int(a) for a in getattr(estimator, "alphas_", ())] or None,
        "amplitude": params.get("amplitude"),
    }
    if machine == "svm":
        out["C"] = 1.0 / lam
    return out


_TERMS = (
    "train_error",
    "chi",
    "tau",
    "bound",
    "mean_random_error",
    "cap_hits",
    "n_support",
    "gamma_0",
    "mean_test_error",
    "std_test_error",
    "mean_train_error",
)


def selected_row(search: Any) -> dict[str, float]:
    """The selection table's row of the chosen configuration (MD terms v = train_error, chi,
    tau, bound; or the CV error)."""
    res = getattr(search, "cv_results_", None)
    idx = getattr(search, "best_index_", None)
    if res is None or idx is None:
        return {}
    return {k: float(np.asarray(res[k], dtype=float)[idx]) for k in _TERMS if k in res}


def _plain(v: Any) -> Any:
    if isinstance(v, (tuple, list, np.ndarray)):
        return [_plain(x) for x in v]
    if isinstance(v, (np.integer, int)) and not isinstance(v, bool):
        return int(v)
    if isinstance(v, (np.floating, float)):
        return float(v)
    return v if isinstance(v, (str, bool)) or v is None else str(v)


def selection_table(search: Any) -> dict[str, list[Any]]:
    """The whole selection table (one entry per configuration) as JSON-friendly lists."""
    res = getattr(search, "cv_results_", None)
    if res is None:
        return {}
    out: dict[str, list[Any]] = {}
    for key, val in res.items():
        if key.startswith("param_"):
            out[key] = [_plain(v) for v in list(val)]
        elif key in _TERMS:
            out[key] = np.asarray(val, dtype=float).round(6).tolist()
    return out
