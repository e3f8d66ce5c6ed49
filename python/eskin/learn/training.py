"""Training: :func:`train_model`, from a campaign or arrays to a :class:`TouchModel`.

It reads the training set (:mod:`eskin.learn.training_set`), trains the machines with the
settings a search selects (:mod:`eskin.learn.grids`) or with a recipe searched on the data
(:mod:`eskin.learn.recipes`), calibrates the decision rule and records how it was trained.
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from datetime import datetime, timezone
from typing import Any

import numpy as np

from eskin.data.limits import MAX_D, MIN_D
from eskin.errors import TrainingError
from eskin.learn.calibration import DEFAULT_REJECT
from eskin.learn.grids import (
    DEFAULT_AMPLITUDES,
    DEFAULT_D,
    MACHINES,
    PAPER_ALPHAS,
    PAPER_LAMBDAS,
    PAPER_SIGMAS,
    QUICK_ALPHAS,
    QUICK_LAMBDAS,
    QUICK_SIGMAS,
    SELECTIONS,
    describe_params,
    fit_search,
    make_search,
    param_grid,
    selected_row,
)
from eskin.learn.models import TouchModel
from eskin.learn.recipes import ALPHA_SPEC, one_vs_all_indices
from eskin.learn.training_set import (
    cv_groups,
    fillable_D,
    fit_grouped,
    group_labels,
    load_training_data,
    preprocess_campaign,
    require_touches,
    small_class_notes,
    touch_window_lengths,
    window_config_for_rate,
)


@dataclass(frozen=True)
class _Recipe:
    """How :func:`train_model` trains (its arguments of the same names, checked on creation)."""

    machine: str
    selection: str
    D: int
    window: str
    subsample: str
    negatives: str
    seed: int
    n_jobs: int
    group_by: str
    lambdas: Sequence[float] = PAPER_LAMBDAS
    sigmas: Sequence[float] = PAPER_SIGMAS
    alphas: Sequence[str] = PAPER_ALPHAS
    amplitudes: Sequence[float | None] = DEFAULT_AMPLITUDES
    md_options: Mapping[str, Any] | None = None
    cv_options: Mapping[str, Any] | None = None

    def __post_init__(self) -> None:
        if self.machine not in MACHINES:
            raise TrainingError(f"machine must be 'svm' or 'rls', got {self.machine!r}")
        if self.selection not in SELECTIONS:
            raise TrainingError(f"selection must be 'md' or 'cv', got {self.selection!r}")
        if self.negatives not in ("balanced", "all"):
            raise TrainingError(f"negatives must be 'balanced' or 'all', got {self.negatives!r}")
        if self.D is not None and not MIN_D <= int(self.D) <= MAX_D:
            raise TrainingError(f"D must be in [{MIN_D}, {MAX_D}] (what a .eskin model holds), "
                                f"got {self.D}")

    def with_grid(
        self,
        quick: bool,
        lambdas: Sequence[float],
        sigmas: Sequence[float],
        alphas: Sequence[str],
        amplitudes: Sequence[float | None],
        md_options: Mapping[str, Any] | None,
        cv_options: Mapping[str, Any] | None,
    ) -> _Recipe:
        """This recipe searching the given grid, or with ``quick`` the 2x2x2 grid (times the
        given amplitudes) and lighter selection options (3 labelings, 3 splits; given options
        win)."""
        if quick:
            lambdas, sigmas, alphas = QUICK_LAMBDAS, QUICK_SIGMAS, QUICK_ALPHAS
            md_options = {"n_labelings": 3, **dict(md_options or {})}
            cv_options = {"n_splits": 3, **dict(cv_options or {})}
        return replace(
            self,
            lambdas=lambdas,
            sigmas=sigmas,
            alphas=alphas,
            amplitudes=tuple(amplitudes),
            md_options=md_options,
            cv_options=cv_options,
        )


def _training_data(
    data: Any,
    labels: Any,
    classes: Sequence[str] | None,
    class_names: Sequence[str] | None,
    lengths: Any,
    sample_rate_hz: float,
    runs: Sequence[int] | None,
    group_by: str,
) -> tuple[Any, dict[str, Any], list[str], np.ndarray, np.ndarray, np.ndarray | None]:
    """(recordings, source info, classes learnt, indices of the recordings trained on, their
    labels 0..len(classes)-1, their ``group_by`` groups or None). The classes default to every
    class present and must be known, distinct, at least 2 and each recorded among the training
    recordings (only those of ``runs``, when given)."""
    rec, ids, names, parts, info = load_training_data(
        data, labels, class_names, lengths, sample_rate_hz
    )
    if group_by != "participant" and hasattr(rec, "modalities"):
        parts = group_labels(rec, group_by)
    present = [names[k] for k in sorted(set(ids.tolist())) if 0 <= k < len(names)]
    if classes is None:
        classes = present
    classes = [str(c) for c in classes]
    unknown = [c for c in classes if c not in names]
    if unknown:
        raise TrainingError(f"unknown class(es) {unknown}; the data has classes {names}")
    if len(set(classes)) != len(classes):
        raise TrainingError(f"classes must be distinct, got {classes}")
    if len(classes) < 2:
        raise TrainingError(f"at least 2 classes are needed, got {classes}")
    cls_ids = [names.index(c) for c in classes]
    mask = np.isin(ids, cls_ids)
    if runs is not None and hasattr(rec, "run"):
        mask &= np.isin(np.asarray(rec.run), list(runs))
    idx = np.flatnonzero(mask)
    missing = [c for c, k in zip(classes, cls_ids) if not np.any(ids[idx] == k)]
    if missing:
        raise TrainingError(f"no recording of class(es) {missing} in the training data")
    y_all = np.array([cls_ids.index(k) for k in ids[idx]], np.int64)
    groups = parts[idx] if parts is not None else None
    return rec, info, classes, idx, y_all, groups


def _default_D(recipe: _Recipe, rec: Any, idx: np.ndarray, window_config: Any, rate: float,
               notes: list[str]) -> _Recipe:
    """The recipe with D resolved: as given, else :data:`DEFAULT_D`, or the samples of the
    median training touch window (:func:`fillable_D`, at least 2) when that is shorter, with a
    note."""
    if recipe.D is not None:
        return recipe
    fill = fillable_D(touch_window_lengths(rec, idx, window=recipe.window, config=window_config,
                                           sample_rate_hz=rate))
    if fill is None or fill >= DEFAULT_D:
        return replace(recipe, D=DEFAULT_D)
    notes.append(
        f"the median training touch window is {fill} samples long: D = {fill} instead of "
        f"{DEFAULT_D} (a longer D would only stretch most touches by interpolation)"
    )
    return replace(recipe, D=fill)


def _training_patterns(
    data: Any, rec: Any, idx: np.ndarray, recipe: _Recipe, window_config: Any, rate: float
) -> tuple[np.ndarray, float]:
    """(the preprocessed patterns of the training recordings, seconds taken); refuses patterns
    without any touch."""
    key = (int(recipe.D), recipe.subsample)
    prep = preprocess_campaign(
        rec, idx, [key], window=recipe.window, config=window_config, sample_rate_hz=rate
    )
    X = prep.X[key]
    require_touches(X, data)
    return X, prep.seconds


def _selected_settings(machine: str, fitted_search: Any, ys: np.ndarray) -> dict[str, Any]:
    """What one fitted search chose, its selection terms and the size of its training set."""
    return {
        **describe_params(machine, fitted_search.best_params_, fitted_search.best_estimator_),
        "selection_terms": selected_row(fitted_search),
        "n_train": int(len(ys)),
        "n_positive": int(np.sum(ys == 1)),
    }


def _select_and_fit(
    recipe: _Recipe,
    X: np.ndarray,
    y_all: np.ndarray,
    classes: list[str],
    groups: np.ndarray | None,
    notes: list[str],
) -> tuple[Any, bool, list[dict[str, Any]], float]:
    """(fitted estimator, whether its splits were grouped, the settings each machine chose,
    seconds taken): one binary machine for 2 classes, else one 1-vs-all machine per class.
    Warnings about the splits are appended to ``notes``."""
    search = make_search(
        recipe.machine,
        recipe.selection,
        param_grid(recipe.lambdas, recipe.sigmas, recipe.alphas, recipe.amplitudes),
        seed=recipe.seed,
        md_options=recipe.md_options,
        cv_options=recipe.cv_options,
        n_jobs=recipe.n_jobs,
    )
    t0 = time.perf_counter()
    groups, group_notes = cv_groups(recipe.selection, groups, recipe.group_by)
    notes += group_notes
    if len(classes) == 2:
        _, grouped = fit_grouped(
            lambda g: fit_search(search, X, y_all, g), groups, recipe.group_by, notes
        )
        selected = [_selected_settings(recipe.machine, search, y_all)]
        return search.best_estimator_, grouped, selected, time.perf_counter() - t0
    from eskin.learn.estimators import OneVsAllTouchClassifier

    machine_indices = one_vs_all_indices(y_all, len(classes), recipe.negatives, recipe.seed)
    estimator, grouped = fit_grouped(
        lambda g: OneVsAllTouchClassifier(estimator=search).fit(
            X, y_all, machine_indices=machine_indices, groups=g
        ),
        groups,
        recipe.group_by,
        notes,
    )
    selected = [
        {
            "class": classes[k],
            **_selected_settings(recipe.machine, srch, (y_all[mi] == k).astype(int)),
        }
        for k, (srch, mi) in enumerate(zip(estimator.searches_, machine_indices))
    ]
    return estimator, grouped, selected, time.perf_counter() - t0


def _training_record(
    recipe: _Recipe,
    info: dict[str, Any],
    classes: list[str],
    y_all: np.ndarray,
    grouped: bool,
    notes: list[str],
    seconds: float,
) -> dict[str, Any]:
    """The model's ``training`` record: data source, pattern counts, grid, selection options,
    how the CV splits went, notes, time taken, creation time and eskin version."""
    import eskin

    split_by = (recipe.group_by if grouped else "recordings") if recipe.selection == "cv" else None
    return {
        **info,
        "n_patterns": int(len(y_all)),
        "patterns_per_class": {c: int(np.sum(y_all == k)) for k, c in enumerate(classes)},
        "grid": {
            "lambdas": list(map(float, recipe.lambdas)),
            "sigmas": list(map(float, recipe.sigmas)),
            "alphas": list(recipe.alphas),
            "amplitudes": list(recipe.amplitudes),
        },
        "md_options": dict(recipe.md_options or {}),
        "cv_options": dict(recipe.cv_options or {}),
        "cv_split_by": split_by,
        "negatives": recipe.negatives,
        "seed": recipe.seed,
        "notes": notes,
        "seconds": seconds,
        "created_utc": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "eskin_version": eskin.__version__,
    }


def _touch_model(
    recipe: _Recipe,
    classes: list[str],
    estimator: Any,
    selected: list[dict[str, Any]],
    training: dict[str, Any],
    rate: float,
    shape: tuple[int, ...],
    window_config: Any,
) -> TouchModel:
    """The trained :class:`TouchModel`."""
    return TouchModel(
        classes=classes,
        estimator=estimator,
        machine=recipe.machine,
        selection=recipe.selection,
        D=int(recipe.D),
        window=recipe.window,
        subsample=recipe.subsample,
        sample_rate_hz=rate,
        grid_shape=(int(shape[0]), int(shape[1])),
        window_config=window_config,
        selected=selected,
        selection_report={"lambda_shown": "lambda for both machines; the SVM uses C = 1/lambda"},
        training=training,
    )


# long: the public entry point documents every parameter; the body dispatches
def train_model(
    data: Any,
    labels: Any = None,
    *,
    classes: Sequence[str] | None = None,
    machine: str | None = None,
    selection: str = "cv",
    D: int | None = None,
    window: str = "energy",
    subsample: str | None = None,
    window_config: Any = None,
    lambdas: Sequence[float] = PAPER_LAMBDAS,
    sigmas: Sequence[float] = PAPER_SIGMAS,
    alphas: Sequence[str] = PAPER_ALPHAS,
    amplitudes: Sequence[float | None] = DEFAULT_AMPLITUDES,
    quick: bool = False,
    md_options: Mapping[str, Any] | None = None,
    cv_options: Mapping[str, Any] | None = None,
    negatives: str | None = None,
    runs: Sequence[int] | None = None,
    class_names: Sequence[str] | None = None,
    lengths: Sequence[int] | None = None,
    sample_rate_hz: float = 3000.0,
    seed: int = 0,
    n_jobs: int = 1,
    group_by: str = "participant",
    budget: Any = None,
    decision_us: float | str | None = "auto",
    recipe_options: Mapping[str, Any] | None = None,
    max_support: int | None = None,
    max_model_bytes: int | None = None,
    choose_hold: bool = True,
    decision: str = "calibrated",
    reject: float = DEFAULT_REJECT,
) -> TouchModel:
    """Select the recipe and its hyperparameters, fit on all the data: a :class:`TouchModel`.

    Parameters
    ----------
    data : a campaign path, a loaded Campaign, or raw signals (n, rows, cols, T) with ``labels``
        (class names, or integers indexing ``class_names``), ``lengths`` and ``sample_rate_hz``.
    classes : the classes to learn (default: every class). Two give one binary machine (> 0:
        ``classes[1]``); more give one 1-vs-all machine each (the paper's rule, Section 5.3).
    machine : "svm" (tensor-SVM, C = 1/lambda) or "rls" (tensor-RLS).
    selection : "cv" (default: 10 random splits holding out 30 % of the ``group_by`` groups;
        stratified splits of the recordings, with a note, when grouped ones are impossible;
        ``cv_options``: :class:`~eskin.CrossValidationSearch`) or "md" (Maximal Discrepancy,
        Algorithm 1; ``md_options``: :class:`~eskin.MaximalDiscrepancySearch`).
    D, window, subsample, window_config : preprocessing (see :func:`eskin.preprocess`); D
        None (default) is 100, or the median training touch window's samples when that is fewer
        (:func:`~eskin.learn.training_set.fillable_D`).
    lambdas, sigmas, alphas : the grid (default the paper's, 135 configurations); ``quick``
        replaces it by a 2x2x2 grid (for tests and demos).
    amplitudes : the amplitude-aware kernel's widths searched (None: the paper's kernel; a
        number: the factor's width in spreads of the training patterns' log energy, see
        :class:`~eskin.TensorSVC`), each multiplying the grid.
    negatives : what each 1-vs-all machine sees of the other classes: "all" their patterns
        (benchmarks/multiclass_study.py) or "balanced" (the paper: as many, seeded random).
    runs : only recordings of these runs (default: all).
    group_by : the label whose groups the CV splits keep apart: "participant" (default), "run",
        "direction" or an integer extra field.
    budget : a :class:`~eskin.learn.recipes.CandidateBudget`
        (:func:`eskin.deploy.target.candidate_budget`): only what fits it is chosen.
    decision_us : without ``budget``, the support vectors of the searched model take at most
        this many microseconds of a decision at the end of a touch on the host, estimated by a
        fixed count (:mod:`eskin.learn.host_budget`; the search trades D against alpha and the
        support vectors, which it bounds when needed); "auto" (the default): its
        ``HOST_DECISION_US`` = 80 us (plus 38-48 us for the input's bases on a 4x4 grid), or
        twice the input's bases where those take more (large grids:
        :func:`~eskin.learn.host_budget.default_cap_us`); None: no bound. Only a searched
        recipe is bounded.
    recipe_options : options of the :class:`~eskin.learn.recipes.RecipeSearch` (``eta``, ...).
    max_model_bytes : at most this many bytes in the model's float32 ``.eskin`` file (None,
        the default: no limit; ``eskin train --max-model-size MB``): a model whose support
        vectors would not fit keeps the most that do, as with ``max_support``.
    max_support : at most this many distinct support vectors in the model (all machines
        together; :func:`eskin.learn.support_budget.bound_support`). None: all of them.
    choose_hold : with the energy window, choose ``window_config.hold_s`` so that one training
        recording gives one live touch (:func:`eskin.learn.live_windows.choose_hold`); False
        keeps the given hold and only notes when live touches split.
    decision : "calibrated" (default: :mod:`eskin.learn.calibration`, a sigmoid per machine
        fitted on out-of-fold decision values, the label of the largest calibrated score,
        "don't know" below a confidence threshold) or "paper" (Section 5.3).
    reject : the calibrated rule's fraction of (out-of-fold) training touches flagged "don't
        know", in [0, 1); 0 never flags.

    Recipe search: with ``selection="cv"``, each of ``machine``, ``D``, ``subsample`` and
    ``negatives`` left None is searched by :class:`~eskin.learn.recipes.RecipeSearch`.
    With all four given, or ``selection="md"`` (the unset ones then svm, D 100 or the median
    touch window, algorithm2, all), each machine selects its own setting of the grid.
    """
    recipe_given = dict(machine=machine, D=D, subsample=subsample, negatives=negatives)
    common = dict(classes=classes, window=window, window_config=window_config, lambdas=lambdas,
                  sigmas=sigmas, alphas=alphas, amplitudes=amplitudes, quick=quick,
                  cv_options=cv_options, runs=runs, class_names=class_names, lengths=lengths,
                  sample_rate_hz=sample_rate_hz, seed=seed, n_jobs=n_jobs, group_by=group_by,
                  max_support=_checked_max_support(max_support),
                  max_model_bytes=_checked_max_bytes(max_model_bytes), choose_hold=choose_hold,
                  rule=_checked_rule(decision, reject))
    if selection == "cv" and None in recipe_given.values():
        return _train_searched(data, labels, **recipe_given, **common, budget=budget,
                               decision_us=decision_us, recipe_options=recipe_options)
    if budget is not None:
        raise TrainingError("a budget needs the recipe searched (selection cv, and at least one "
                            "of machine, D, subsample, negatives left to the search)")
    return _train_fixed(data, labels, selection=selection, md_options=md_options,
                        **recipe_given, **common)


def _checked_max_bytes(max_model_bytes: Any) -> int | None:
    """``max_model_bytes`` as an int (None: no limit); a TrainingError below 1."""
    if max_model_bytes is None:
        return None
    if isinstance(max_model_bytes, bool) or not float(max_model_bytes) >= 1:
        raise TrainingError(f"max_model_bytes must be a positive number, got {max_model_bytes!r}")
    return int(max_model_bytes)


def _checked_rule(decision: Any, reject: Any) -> tuple[str, float]:
    """(decision rule, reject fraction), checked before any training."""
    from eskin.learn.calibration import DECISION_RULES

    if decision not in DECISION_RULES:
        raise TrainingError(f"decision must be one of {DECISION_RULES}, got {decision!r}")
    try:
        r = float(reject)
    except (TypeError, ValueError):
        raise TrainingError(f"reject must be a number in [0, 1), got {reject!r}") from None
    if not 0 <= r < 1:
        raise TrainingError(f"reject must be in [0, 1), got {reject!r}")
    return str(decision), r


def _with_calibration(model: TouchModel, estimator: Any, X: np.ndarray, y_all: np.ndarray,
                      groups: np.ndarray | None, negatives: str, seed: int, n_jobs: int,
                      rule: tuple[str, float]) -> TouchModel:
    """``model`` with the calibrated rule fitted on out-of-fold values of ``estimator`` (the
    fitted machines, before any support budget), or as it is for the paper's rule."""
    from eskin.learn import calibration as cal

    decision, reject = rule
    if decision == "paper":
        model.training["decision"] = {"rule": "paper"}
        return model
    t0 = time.perf_counter()
    binary = len(model.classes) == 2
    indices = None if binary else one_vs_all_indices(y_all, len(model.classes), negatives, seed)
    notes = model.training.setdefault("notes", [])
    try:
        F, n_folds = cal.out_of_fold_values(estimator, X, y_all, groups, machine_indices=indices,
                                            seed=seed, n_jobs=n_jobs, notes=notes)
        model.calibration = cal.fit_calibration(F, y_all, reject, binary=binary, n_folds=n_folds)
    except TrainingError as exc:
        notes.append(f"the calibrated rule cannot be fitted ({exc}): the model keeps the "
                     "paper's rule")
        model.training["decision"] = {"rule": "paper", "calibration_failed": str(exc)}
        return model
    model.training["decision"] = {**model.calibration.report,
                                  "seconds": time.perf_counter() - t0}
    return model


def _checked_max_support(max_support: Any) -> int | None:
    """None, or ``max_support`` checked (before any training: a TrainingError naming it)."""
    from eskin.learn.support_budget import check_max_support

    if max_support is None:
        return None
    try:
        return check_max_support(max_support)
    except (TypeError, ValueError) as exc:
        raise TrainingError(str(exc)) from None


def _with_support_budget(model: TouchModel, max_support: int | None, X: np.ndarray,
                         max_model_bytes: int | None = None) -> TouchModel:
    """``model`` with at most ``max_support`` distinct support vectors (None: as it is), and
    no more than a float32 model file of ``max_model_bytes`` holds
    (:func:`~eskin.learn.support_budget.support_for_size`), the machines' coefficients fitted
    to their decision values on the training patterns ``X``, and a record of it."""
    from eskin.learn.selection import _single_threaded_blas
    from eskin.learn.support_budget import bound_support, n_distinct_support, support_for_size

    before = n_distinct_support(model.estimator)
    by_size = False
    if max_model_bytes is not None:
        fit = support_for_size(model.estimator, max_model_bytes)
        if fit < before and (max_support is None or fit < max_support):
            max_support, by_size = fit, True
    if max_support is None:
        return model
    with _single_threaded_blas():  # small least squares: threads cost far more than they give
        model.estimator = bound_support(model.estimator, max_support, X_fit=X)
    model.training["support_budget"] = {
        "max_support": max_support,
        "support_vectors_before": before,
        "support_vectors": n_distinct_support(model.estimator),
    }
    if by_size:
        model.training["support_budget"]["by"] = "size"
        model.training["support_budget"]["max_model_bytes"] = max_model_bytes
    return model


def _training_setup(
    data: Any, labels: Any, classes: Any, class_names: Any, lengths: Any, sample_rate_hz: float,
    runs: Any, group_by: str, window: str, window_config: Any, choose_hold: bool,
) -> tuple[Any, ...]:
    """The training data, its rate, the detector settings valid at that rate (written into the
    model explicitly, also with window="none": the compiled classifier builds its detector from
    them), the notes so far and the live-touch check: (rec, info, classes, idx, y_all, groups,
    rate, window_config, notes, live)."""
    rec, info, classes, idx, y_all, groups = _training_data(
        data, labels, classes, class_names, lengths, sample_rate_hz, runs, group_by
    )
    rate = float(getattr(rec, "sample_rate_hz", sample_rate_hz))
    window_config, notes = window_config_for_rate(window_config, rate)
    notes = (notes if window == "energy" else []) + small_class_notes(classes, y_all)
    window_config, live = _live_hold(rec, idx, window_config, rate, window, choose_hold, notes)
    return rec, info, classes, idx, y_all, groups, rate, window_config, notes, live


def _train_fixed(
    data: Any, labels: Any, *, classes: Sequence[str] | None, machine: str | None,
    selection: str, D: int | None, window: str, subsample: str | None, window_config: Any,
    lambdas: Sequence[float], sigmas: Sequence[float], alphas: Sequence[str],
    amplitudes: Sequence[float | None], quick: bool, md_options: Mapping[str, Any] | None,
    cv_options: Mapping[str, Any] | None, negatives: str | None, runs: Sequence[int] | None,
    class_names: Sequence[str] | None, lengths: Any, sample_rate_hz: float, seed: int,
    n_jobs: int, group_by: str, max_support: int | None, max_model_bytes: int | None,
    choose_hold: bool, rule: tuple[str, float],
) -> TouchModel:
    """train_model with the recipe given (or Maximal Discrepancy): each machine selects its
    own setting of the grid."""
    machine = machine or "svm"
    subsample = subsample or "algorithm2"
    negatives = negatives or "all"
    recipe = _Recipe(machine, selection, D, window, subsample, negatives, seed, n_jobs, group_by)
    recipe = recipe.with_grid(quick, lambdas, sigmas, alphas, amplitudes, md_options, cv_options)
    (rec, info, classes, idx, y_all, groups, rate, window_config, notes,
     live) = _training_setup(data, labels, classes, class_names, lengths, sample_rate_hz, runs,
                             group_by, window, window_config, choose_hold)
    recipe = _default_D(recipe, rec, idx, window_config, rate, notes)
    X, prep_seconds = _training_patterns(data, rec, idx, recipe, window_config, rate)
    estimator, grouped, selected, fit_seconds = _select_and_fit(
        recipe, X, y_all, classes, groups, notes
    )
    training = _training_record(
        recipe, info, classes, y_all, grouped, notes, fit_seconds + prep_seconds
    )
    training["live_touches"] = live
    model = _touch_model(recipe, classes, estimator, selected, training, rate, X.shape[1:],
                         window_config)
    model = _with_calibration(model, estimator, X, y_all, groups, recipe.negatives, recipe.seed,
                              n_jobs, rule)
    return _with_support_budget(model, max_support, X, max_model_bytes)


def _train_searched(
    data: Any, labels: Any, *, classes: Sequence[str] | None, machine: str | None,
    D: int | None, window: str, subsample: str | None, window_config: Any,
    lambdas: Sequence[float], sigmas: Sequence[float], alphas: Sequence[str],
    amplitudes: Sequence[float | None], quick: bool, cv_options: Mapping[str, Any] | None,
    negatives: str | None, runs: Sequence[int] | None, class_names: Sequence[str] | None,
    lengths: Any, sample_rate_hz: float, seed: int, n_jobs: int, group_by: str, budget: Any,
    decision_us: float | str | None, recipe_options: Mapping[str, Any] | None,
    max_support: int | None, max_model_bytes: int | None, choose_hold: bool,
    rule: tuple[str, float],
) -> TouchModel:
    """train_model with the recipe searched (see its docstring)."""
    from eskin.learn.recipes import MACHINES as R_MACHINES
    from eskin.learn.recipes import NEGATIVES, SEARCH_DS, SUBSAMPLES, RecipeSearch

    base = _Recipe(machine or "svm", "cv", D, window, subsample or "algorithm2",
                   negatives or "all", seed, n_jobs, group_by)
    base = base.with_grid(quick, lambdas, sigmas, alphas, amplitudes, None, cv_options)
    (rec, info, classes, idx, y_all, groups, rate, window_config, notes,
     live) = _training_setup(data, labels, classes, class_names, lengths, sample_rate_hz, runs,
                             group_by, window, window_config, choose_hold)
    t0 = time.perf_counter()
    recipes, cap_notes, patterns = _searched_patterns(
        rec, idx, ([machine] if machine else R_MACHINES, [D] if D else SEARCH_DS,
                   [subsample] if subsample else SUBSAMPLES,
                   [negatives] if negatives else NEGATIVES),
        fill=not D, window=window, window_config=window_config, rate=rate)
    notes += sorted(set(cap_notes))
    for X in patterns.values():
        require_touches(X, data)
    cv = dict(base.cv_options or {})
    options = {"n_splits": int(cv.get("n_splits", 10)), "test_size": float(cv.get("test_size", 0.3)),
               **dict(recipe_options or {})}
    groups, group_notes = cv_groups("cv", groups, group_by)
    notes += group_notes
    if budget is None and decision_us is not None:
        from eskin.learn.host_budget import host_budget

        budget = host_budget(next(iter(patterns.values())).shape[1:3], decision_us)

    def run(g: np.ndarray | None) -> RecipeSearch:
        return RecipeSearch(recipes, base.lambdas, base.sigmas, base.alphas, base.amplitudes,
                            budget=budget, seed=seed, n_jobs=n_jobs, **options).fit(
            patterns, y_all, g)

    search, grouped = fit_grouped(run, groups, group_by, notes)
    if search.collapse_note():
        notes.append(f"recipe search: {search.collapse_note()}")
    best = search.best_
    chosen = replace(base, machine=best.recipe.machine, D=best.recipe.D,
                     subsample=best.recipe.subsample, negatives=best.recipe.negatives)
    X = patterns[best.recipe.variant]
    estimator, selected = _fit_candidate(best, X, y_all, classes, seed)
    for s in selected:
        s["selection_terms"] = {"mean_test_error": float(search.best_error_),
                                "std_test_error": float(search.ranking_[0]["std"])}
    training = _training_record(chosen, info, classes, y_all, grouped, notes,
                                time.perf_counter() - t0)
    training["live_touches"] = live
    training["recipe_search"] = search.report()
    training["searched"] = [k for k, v in (("machine", machine), ("D", D),
                                           ("subsample", subsample), ("negatives", negatives))
                            if v is None]
    by_budget = search.best_bound_ is not None and (max_support is None
                                                     or search.best_bound_ < max_support)
    model = _with_calibration(
        _touch_model(chosen, classes, estimator, selected, training, rate, X.shape[1:],
                     window_config), estimator, X, y_all, groups if grouped else None,
        chosen.negatives, seed, n_jobs, rule)
    model = _with_support_budget(model, search.best_bound_ if by_budget else max_support, X,
                                 max_model_bytes)
    if by_budget:  # bounded by the search, to the most support vectors that fit the budget
        model.training["support_budget"]["by"] = "budget"
    return model


def _searched_patterns(
    rec: Any, idx: np.ndarray, space: tuple, *, fill: bool, window: str, window_config: Any,
    rate: float,
) -> tuple[list[Any], list[str], dict[tuple[int, str], np.ndarray]]:
    """(the recipes of ``space`` (machines, Ds, subsamples, negatives) capped by the longest
    training recording and, with ``fill``, by the D the touch windows fill, the notes of the
    caps, the patterns of every recipe's variant). The touch windows are detected once: the
    recipes' Ds are preprocessed, their windows give the fillable D, and only a D that cap
    makes is preprocessed again."""
    from eskin.learn.recipes import recipe_space

    lens = np.asarray(rec.lengths)[idx]
    longest = int(lens.max()) if len(lens) else None
    first, _ = recipe_space(*space, longest=longest)
    prep = preprocess_campaign(rec, idx, sorted({r.variant for r in first}), window=window,
                               config=window_config, sample_rate_hz=rate)
    found = fillable_D(prep.windows[:, 1] - prep.windows[:, 0]) if fill else None
    recipes, cap_notes = recipe_space(*space, longest=longest, fill=found)
    variants = sorted({r.variant for r in recipes})
    patterns = {v: prep.X[v] for v in variants if v in prep.X}
    missing = [v for v in variants if v not in patterns]
    if missing:
        patterns.update(preprocess_campaign(rec, idx, missing, window=window,
                                            config=window_config, sample_rate_hz=rate).X)
    return recipes, cap_notes, patterns


def _live_hold(rec: Any, idx: np.ndarray, window_config: Any, rate: float, window: str,
               choose: bool, notes: list[str]) -> tuple[Any, dict[str, Any] | None]:
    """(window_config with the hold time chosen for one live touch per training recording,
    the record of the choice); notes added to ``notes``. Nothing to choose with window none."""
    if window != "energy":
        return window_config, None
    from eskin.learn.live_windows import choose_hold

    choice = choose_hold(rec, idx, window_config, rate, choose=choose)
    notes += choice.notes
    return choice.config, choice.record


def _fit_candidate(
    best: Any, X: np.ndarray, y_all: np.ndarray, classes: list[str], seed: int
) -> tuple[Any, list[dict[str, Any]]]:
    """(the fitted estimator of a recipe-search candidate, the settings of its machines)."""
    from eskin.learn.estimators import OneVsAllTouchClassifier, TensorRLS, TensorSVC

    alpha = ALPHA_SPEC[best.alpha]
    if best.recipe.machine == "svm":
        est = TensorSVC(C=1.0 / best.lam, sigma=best.sigma, alpha=alpha, amplitude=best.amplitude)
        params = {"C": 1.0 / best.lam, "sigma": best.sigma, "alpha": alpha,
                  "amplitude": best.amplitude}
    else:
        est = TensorRLS(lam=best.lam, sigma=best.sigma, alpha=alpha, amplitude=best.amplitude)
        params = {"lam": best.lam, "sigma": best.sigma, "alpha": alpha,
                  "amplitude": best.amplitude}
    if len(classes) == 2:
        est.fit(X, y_all)
        return est, [{**describe_params(best.recipe.machine, params, est),
                      "n_train": int(len(y_all)), "n_positive": int(np.sum(y_all == 1))}]
    indices = one_vs_all_indices(y_all, len(classes), best.recipe.negatives, seed)
    ova = OneVsAllTouchClassifier(estimator=est).fit(X, y_all, machine_indices=indices)
    selected = []
    for k, (m, mi) in enumerate(zip(ova.estimators_, indices)):
        selected.append({"class": classes[k],
                         **describe_params(best.recipe.machine, params, m),
                         "n_train": int(len(mi)), "n_positive": int(np.sum(y_all[mi] == k))})
    return ova, selected
