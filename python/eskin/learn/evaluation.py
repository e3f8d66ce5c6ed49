"""Nested, group-disjoint evaluation of a training recipe: how well will it work on a new person?

The campaign's recordings are cut into outer folds by a group label (participant by default,
or any integer label: run, direction, an integer extra field such as a sitting). Every fold
trains the recipe with :func:`eskin.train_model` on the other groups only - its whole model
selection included, so the selection never sees the test groups (nested evaluation) - and
predicts the held-out groups. The predictions of all folds are pooled into accuracy, balanced
accuracy (the mean per-class recall), per-class recall and the confusion matrix, with a 95 %
confidence interval from a bootstrap over groups (:func:`group_bootstrap_ci`).

Baselines (:mod:`eskin.learn.baselines`) run in the same folds on the same subsampled patterns.
Folds are independent tasks run through joblib, or on a Dask cluster (:mod:`eskin.learn.parallel`):
there the client reads the recordings the folds use and scatters them, as arrays, to every
worker once, so the workers never open the campaign file. Every random choice is seeded by the
fold, so the results do not depend on where or in which order the folds run.
"""

from __future__ import annotations

import contextlib
import time
import warnings
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from eskin.errors import EvaluationError

#: bootstrap resamples of the confidence interval
N_BOOTSTRAP = 2000
CI_METHOD = (
    "percentile bootstrap over groups ({n} resamples of the test groups with replacement, "
    "predictions of a group kept together); widened to include the point estimate if needed"
)


# --------------------------------------------------------------------------------------------
# folds


def make_folds(
    groups: np.ndarray, y: np.ndarray, n_folds: int | None = None, seed: int = 0
) -> list[tuple[np.ndarray, np.ndarray]]:
    """Outer folds ``(train indices, test indices)``; no group is on both sides of a fold.

    ``n_folds=None`` is leave-one-group-out (one fold per group, in group order). Otherwise
    ``n_folds`` folds of whole groups, balanced by class where the groups allow it
    (scikit-learn's StratifiedGroupKFold, shuffled with ``seed``); when that cannot make
    ``n_folds`` non-empty folds (too few recordings per class), the groups are dealt to the
    folds largest first, each to the fold with the fewest recordings (:func:`_dealt_folds`).
    Every recording is tested exactly once.
    """
    from sklearn.model_selection import LeaveOneGroupOut, StratifiedGroupKFold

    groups = np.asarray(groups)
    y = np.asarray(y)
    n_groups = len(np.unique(groups))
    if n_groups < 2:
        raise EvaluationError(
            f"a group-disjoint evaluation needs at least 2 groups, the data has {n_groups}"
        )
    if n_folds is None:
        tests = [te for _, te in LeaveOneGroupOut().split(y, y, groups)]
    else:
        if not 2 <= int(n_folds) <= n_groups:
            raise EvaluationError(
                f"--folds {n_folds}: must be in [2, {n_groups}] (the number of groups)"
            )
        splitter = StratifiedGroupKFold(n_splits=int(n_folds), shuffle=True, random_state=seed)
        try:
            with warnings.catch_warnings():  # "the least populated class has fewer members"
                warnings.simplefilter("ignore", UserWarning)
                tests = [te for _, te in splitter.split(y, y, groups)]
        except ValueError:
            tests = []
        if not tests or not all(len(te) for te in tests):  # failed, or a fold empty
            tests = _dealt_folds(groups, int(n_folds), seed)
    everything = np.arange(len(y))
    return [(np.setdiff1d(everything, te), np.sort(te)) for te in tests]


def _dealt_folds(groups: np.ndarray, n_folds: int, seed: int) -> list[np.ndarray]:
    """Test indices of ``n_folds`` folds: the groups, in a seeded random order and then
    largest first, each go to the fold with the fewest recordings so far."""
    uniq, inv, counts = np.unique(groups, return_inverse=True, return_counts=True)
    order = np.random.default_rng(seed).permutation(len(uniq))
    order = order[np.argsort(-counts[order], kind="stable")]
    load = np.zeros(n_folds, np.int64)
    fold_of = np.empty(len(uniq), np.int64)
    for g in order:
        f = int(np.argmin(load))
        fold_of[g] = f
        load[f] += counts[g]
    return [np.flatnonzero(fold_of[inv] == f) for f in range(n_folds)]


# --------------------------------------------------------------------------------------------
# scores and their interval


def confusion_matrix(y_true: np.ndarray, y_pred: np.ndarray, n_classes: int) -> np.ndarray:
    """(n_classes, n_classes) counts: row = true class, column = predicted class."""
    cm = np.zeros((n_classes, n_classes), np.int64)
    np.add.at(cm, (np.asarray(y_true, np.int64), np.asarray(y_pred, np.int64)), 1)
    return cm


def scores_from_confusion(cm: np.ndarray) -> tuple[float, float, np.ndarray]:
    """(accuracy, balanced accuracy, per-class recall) of a confusion matrix; the balanced
    accuracy averages the recall of the classes that have test recordings (nan recall for the
    others)."""
    acc, bal, recall = _scores(cm)
    return float(acc), float(bal), recall


def _scores(cms: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(accuracy, balanced accuracy, per-class recall) of confusion matrices (..., k, k): one,
    or a bootstrap's resamples at once. A recall is 0/0 (nan) for a class without recordings
    and left out of the balance; no recordings at all give nan."""
    cms = np.asarray(cms, dtype=np.float64)
    diag = np.einsum("...ii->...i", cms)
    with np.errstate(invalid="ignore"):  # 0 / 0: nan
        recall = diag / cms.sum(axis=-1)
        acc = diag.sum(axis=-1) / cms.sum(axis=(-2, -1))
        present = ~np.isnan(recall)
        bal = np.where(present, recall, 0.0).sum(axis=-1) / present.sum(axis=-1)
    return acc, bal, recall


def group_bootstrap_ci(
    y_true: np.ndarray,
    y_pred: np.ndarray,
    groups: np.ndarray,
    n_classes: int,
    *,
    n_boot: int = N_BOOTSTRAP,
    level: float = 0.95,
    seed: int = 0,
) -> dict[str, list[float]]:
    """Percentile bootstrap intervals of accuracy and balanced accuracy over groups.

    Recordings of one group (one person) are not independent, so the unit resampled is the
    group: each resample draws as many groups as there are, with replacement, and pools their
    predictions. An interval that misses the point estimate (possible with very few groups)
    is widened to include it. The resamples are the rows of
    ``np.random.default_rng(np.random.SeedSequence([seed, 7])).integers(0, G, size=(n_boot, G))``
    (indices into the sorted distinct groups), so that anyone can redo them. Returns
    ``{"accuracy": [low, high], "balanced_accuracy": [...]}``.
    """
    y_true = np.asarray(y_true, np.int64)
    y_pred = np.asarray(y_pred, np.int64)
    uniq, inv = np.unique(np.asarray(groups), return_inverse=True)
    G, k = len(uniq), int(n_classes)
    per_group = np.zeros((G, k * k))
    np.add.at(per_group, (inv, y_true * k + y_pred), 1.0)
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 7]))
    draws = rng.integers(0, G, size=(int(n_boot), G))
    weights = np.zeros((int(n_boot), G))
    np.add.at(weights, (np.repeat(np.arange(int(n_boot)), G), draws.ravel()), 1.0)
    acc, bal, _ = _scores((weights @ per_group).reshape(int(n_boot), k, k))
    point_acc, point_bal, _ = scores_from_confusion(confusion_matrix(y_true, y_pred, k))
    q = [(1 - level) / 2 * 100, (1 + level) / 2 * 100]
    out = {}
    for name, values, point in (
        ("accuracy", acc, point_acc),
        ("balanced_accuracy", bal, point_bal),
    ):
        low, high = np.percentile(values, q)
        out[name] = [float(min(low, point)), float(max(high, point))]
    return out


def summarise(
    y_true: np.ndarray,
    y_pred: np.ndarray,
    groups: np.ndarray,
    classes: Sequence[str],
    seed: int = 0,
) -> dict[str, Any]:
    """Pooled scores of out-of-fold predictions: accuracy, balanced accuracy, their 95 %
    intervals, per-class recall and the confusion matrix (rows true, columns predicted)."""
    cm = confusion_matrix(y_true, y_pred, len(classes))
    acc, bal, recall = scores_from_confusion(cm)
    ci = group_bootstrap_ci(y_true, y_pred, groups, len(classes), seed=seed)
    return {
        "accuracy": acc,
        "balanced_accuracy": bal,
        "ci95": ci["accuracy"],
        "ci95_balanced_accuracy": ci["balanced_accuracy"],
        "per_class_recall": {
            c: (None if np.isnan(r) else float(r)) for c, r in zip(classes, recall)
        },
        "confusion": cm.tolist(),
    }


# --------------------------------------------------------------------------------------------
# one fold


@dataclass(frozen=True)
class FoldTask:
    """Everything one outer fold needs; picklable, so a fold can run on another machine."""

    number: int
    source: Any  # a campaign path (str), a Campaign, or _Parts (arrays given to run_fold)
    train_idx: np.ndarray
    test_idx: np.ndarray
    classes: tuple[str, ...]
    recipe: dict[str, Any]
    group_name: str
    baselines: tuple[str, ...]
    seed: int
    n_jobs: int
    #: the live figure, when asked for: an object with ``fold(model, test campaign, classes,
    #: seed) -> dict`` (eskin.link.live_scores.LiveScoring; this layer never imports it)
    live: Any = None


@dataclass(frozen=True)
class _Parts:
    """A campaign's settings; its per-recording arrays travel beside it (:func:`_parts`)."""

    modalities: tuple[str, ...]
    sample_rate_hz: float
    volts_per_count: float
    source: str
    attrs: dict[str, Any]
    path: str | None


_ARRAYS = ("signals", "lengths", "modality", "participant", "direction", "run")


def _parts(camp: Any, used: np.ndarray) -> tuple[_Parts, dict[str, Any]]:
    """(settings, arrays) of the recordings ``used`` of ``camp``, read into memory: what a
    worker needs to rebuild them as a Campaign (:func:`_from_parts`)."""
    from eskin.data.limits import memory_problem

    n, rows, cols, t = camp.signals.shape
    problem = memory_problem(len(used) * rows * cols * t * 2,
                             "sending the recordings to the cluster")
    if problem:
        raise EvaluationError(f"{camp.path or 'campaign'}: {problem}")
    part = camp.subset(used).load()
    arrays: dict[str, Any] = {k: np.asarray(getattr(part, k)) for k in _ARRAYS}
    arrays["contact_interval"] = part.contact_interval
    arrays["extras"] = dict(part.extras)
    meta = _Parts(tuple(part.modalities), part.sample_rate_hz, part.volts_per_count,
                  part.source, dict(part.attrs), part.path)
    return meta, arrays


def _from_parts(meta: _Parts, arrays: Mapping[str, Any]) -> Any:
    from eskin.data.campaign import Campaign

    return Campaign(
        *(arrays[k] for k in _ARRAYS), contact_interval=arrays["contact_interval"],
        modalities=meta.modalities, sample_rate_hz=meta.sample_rate_hz,
        volts_per_count=meta.volts_per_count, source=meta.source, attrs=meta.attrs,
        extras=arrays["extras"], path=meta.path, _validated=True,
    )


@contextlib.contextmanager
def _opened(source: Any, arrays: Mapping[str, Any] | None = None) -> Iterator[Any]:
    """The campaign of a path (closed afterwards), of settings and arrays, or the given one."""
    if isinstance(source, _Parts):
        yield _from_parts(source, arrays)  # type: ignore[arg-type]
    elif isinstance(source, (str, Path)):
        from eskin.data.campaign import load_campaign

        with load_campaign(source) as camp:
            yield camp
    else:
        yield source


def _class_ids(campaign: Any, idx: np.ndarray, classes: Sequence[str]) -> np.ndarray:
    names = [str(m) for m in campaign.modalities]
    lookup = np.array([classes.index(n) if n in classes else -1 for n in names])
    return lookup[np.asarray(campaign.modality)[idx].astype(np.int64)]


def _inner_estimate(selected: Sequence[Mapping[str, Any]]) -> float | None:
    """Mean over the fold's machines of the inner CV error of the selected setting (None when
    the selection is not cross-validation)."""
    errs = [s.get("selection_terms", {}).get("mean_test_error") for s in selected]
    errs = [float(e) for e in errs if e is not None]
    return float(np.mean(errs)) if errs else None


def run_fold(task: FoldTask, **arrays: Any) -> dict[str, Any]:
    """Train the recipe on the fold's training groups, predict its test groups (and run the
    baselines on the same patterns). ``arrays``: the recordings, when ``task.source`` holds
    only the campaign's settings (a fold on a cluster). Returns the fold's record (predictions
    included)."""
    from eskin.learn.training import train_model
    from eskin.learn.training_set import group_labels

    with _opened(task.source, arrays) as camp:
        return _fold_record(task, camp, group_labels(camp, task.group_name), train_model)


def _fold_record(task: FoldTask, camp: Any, groups: np.ndarray, train_model: Any) -> dict:
    t0 = time.perf_counter()
    train, test = camp.subset(task.train_idx), camp.subset(task.test_idx)
    model = train_model(
        train,
        classes=list(task.classes),
        seed=task.seed,
        n_jobs=task.n_jobs,
        group_by=task.group_name,
        **task.recipe,
    )
    X_test = model.preprocess(test)
    pred, _, dont_know, confidence = model.decide(X_test)
    y_test = _class_ids(camp, task.test_idx, task.classes)
    record = {
        "fold": task.number,
        "train_groups": sorted(int(g) for g in np.unique(groups[task.train_idx])),
        "test_groups": sorted(int(g) for g in np.unique(groups[task.test_idx])),
        "n_train": len(task.train_idx),
        "n_test": len(task.test_idx),
        "accuracy": float(np.mean(pred == y_test)),
        "selected": _plain(model.selected),
        "trained_with": trained_with(model),
        "inner_cv_error": _inner_estimate(model.selected),
        "notes": list(model.training.get("notes", [])),
        "live_touches": _plain(model.training.get("live_touches")),
        "support_budget": model.training.get("support_budget"),
        "y_true": y_test.tolist(),
        "y_pred": pred.astype(np.int64).tolist(),
        "dont_know": np.asarray(dont_know, bool).tolist(),
        "confidence": [float(c) if np.isfinite(c) else None for c in confidence],
        "baselines": {},
    }
    if task.live is not None:
        record["live"] = task.live.fold(model, test, task.classes, task.seed)
    if task.baselines:
        from eskin.learn.baselines import run_baseline

        X_train = model.preprocess(train)
        y_train = _class_ids(camp, task.train_idx, task.classes)
        for name in task.baselines:
            b_pred, settings = run_baseline(
                name, X_train, y_train, groups[task.train_idx], X_test, seed=task.seed
            )
            record["baselines"][name] = {
                "accuracy": float(np.mean(b_pred == y_test)),
                "selected": _plain(settings),
                "y_pred": np.asarray(b_pred, np.int64).tolist(),
            }
    record["seconds"] = time.perf_counter() - t0
    return record


def trained_with(model: Any) -> dict[str, Any]:
    """The recipe a trained model really ran (the given options and train_model's defaults
    together): machine, selection, D, window, subsampling, amplitudes, negatives, version."""
    training = model.training
    return {
        "machine": model.machine,
        "selection": model.selection,
        "D": int(model.D),
        "window": model.window,
        "subsample": model.subsample,
        "amplitudes": list(training.get("grid", {}).get("amplitudes", [None])),
        "negatives": training.get("negatives"),
        "hold_s": getattr(model.window_config, "hold_s", None),
        "eskin_version": training.get("eskin_version"),
    }


def _folds_trained_with(records: list[dict[str, Any]]) -> dict[str, Any]:
    """Per setting, its value if every fold ran the same, else the list of the folds' values."""
    out: dict[str, Any] = {}
    for key in records[0]["trained_with"] if records else ():
        values = [r["trained_with"][key] for r in records]
        out[key] = values[0] if all(v == values[0] for v in values) else values
    return out


def _plain(v: Any) -> Any:
    """JSON-friendly copy (numpy scalars and arrays to Python numbers and lists)."""
    if isinstance(v, Mapping):
        return {str(k): _plain(x) for k, x in v.items()}
    if isinstance(v, (list, tuple, np.ndarray)):
        return [_plain(x) for x in v]
    if isinstance(v, np.integer):  # (a bool, numpy's or Python's, is not one)
        return int(v)
    if isinstance(v, (np.floating, float)):
        return None if np.isnan(v) else float(v)
    return v


# --------------------------------------------------------------------------------------------
# the whole evaluation


def _recordings(
    camp: Any, classes: Sequence[str] | None, runs: Sequence[int] | None
) -> tuple[np.ndarray, list[str]]:
    """Indices of the recordings to evaluate on and the class names (campaign order)."""
    names = [str(m) for m in camp.modalities]
    present = [names[k] for k in sorted(set(np.asarray(camp.modality).tolist()))]
    chosen = list(present if classes is None else [str(c) for c in classes])
    unknown = [c for c in chosen if c not in names]
    if unknown:
        raise EvaluationError(f"unknown class(es) {unknown}; the campaign has {names}")
    if len(set(chosen)) < 2:
        raise EvaluationError(f"at least 2 classes are needed, got {chosen}")
    mask = np.isin(np.asarray(camp.modality), [names.index(c) for c in chosen])
    if runs is not None:
        mask &= np.isin(np.asarray(camp.run), list(runs))
    return np.flatnonzero(mask), chosen


def plan_folds(
    campaign: Any,
    *,
    groups: str = "participant",
    n_folds: int | None = None,
    classes: Sequence[str] | None = None,
    runs: Sequence[int] | None = None,
    seed: int = 0,
) -> tuple[list[tuple[np.ndarray, np.ndarray]], list[str], np.ndarray]:
    """(folds as campaign indices, class names, group label of every recording)."""
    from eskin.learn.training_set import group_labels

    idx, names = _recordings(campaign, classes, runs)
    labels = group_labels(campaign, groups)
    y = _class_ids(campaign, idx, names)
    local = make_folds(labels[idx], y, n_folds, seed)
    folds = [(idx[tr], idx[te]) for tr, te in local]
    for k, (tr, _) in enumerate(folds):
        present = set(_class_ids(campaign, tr, names).tolist())
        missing = [c for j, c in enumerate(names) if j not in present]
        if missing:
            raise EvaluationError(
                f"fold {k + 1}: no training recording of class(es) {missing} once its test "
                f"{groups} group(s) are held out; every class needs recordings from at least "
                f"2 {groups} groups (leave such a class out with --classes)"
            )
    return folds, names, labels


def evaluate_recipe(
    campaign: Any,
    *,
    recipe: Mapping[str, Any] | None = None,
    groups: str = "participant",
    n_folds: int | None = None,
    classes: Sequence[str] | None = None,
    runs: Sequence[int] | None = None,
    baselines: Sequence[str] = (),
    seed: int = 0,
    n_jobs: int = 1,
    inner_jobs: int = 1,
    on_fold: Callable[[dict[str, Any], int], None] | None = None,
    live: Any = None,
) -> dict[str, Any]:
    """Nested group-disjoint evaluation of ``recipe`` (keyword arguments of
    :func:`eskin.train_model`) on ``campaign`` (a path or a loaded campaign).

    ``groups`` names the label that makes the folds (default participant); ``n_folds=None``
    is leave-one-group-out. Folds run as joblib tasks (``n_jobs``; the active joblib backend,
    e.g. Dask, decides where), each training with ``inner_jobs`` workers; ``on_fold(record,
    n_folds)`` is called as each fold finishes. ``live``: the live figure's scorer
    (:class:`eskin.link.live_scores.LiveScoring`), run in every fold on its held-out recordings
    and pooled into ``result["live"]``. Returns the result
    written by :func:`eskin.learn.evaluation_report.write_evaluation`.
    """
    from eskin.learn.baselines import check_baselines
    from eskin.learn.parallel import dask_client, share

    t0 = time.perf_counter()
    baselines = check_baselines(baselines)
    shared: dict[str, Any] = {}
    with _opened(campaign) as camp:
        folds, names, labels = plan_folds(
            camp, groups=groups, n_folds=n_folds, classes=classes, runs=runs, seed=seed
        )
        path = camp.path
        source = str(campaign) if isinstance(campaign, (str, Path)) else campaign
        if dask_client() is not None:
            # the workers get the recordings from here (no shared filesystem): the ones the
            # folds use, scattered once to every worker; fold indices into them
            used = np.unique(np.concatenate([np.concatenate(f) for f in folds]))
            source, arrays = _parts(camp, used)
            shared = share(arrays)
    run_folds = folds
    if shared:
        run_folds = [(np.searchsorted(used, tr), np.searchsorted(used, te)) for tr, te in folds]
    recipe = {
        k: v
        for k, v in dict(recipe or {}).items()
        if k not in ("classes", "seed", "n_jobs", "group_by")
    }
    tasks = [
        FoldTask(
            k, source, tr, te, tuple(names), recipe, groups, tuple(baselines), seed, inner_jobs,
            live,
        )
        for k, (tr, te) in enumerate(run_folds)
    ]
    records = _run_folds(tasks, n_jobs, on_fold, shared)
    result = _pooled(records, folds, labels, names, baselines, seed)
    if live is not None:
        result["live"] = live.pool([r["live"] for r in sorted(records, key=lambda r: r["fold"])])
    result.update(
        {
            "campaign": path,
            "groups": groups,
            "scheme": "leave-one-group-out" if n_folds is None else f"{n_folds} grouped folds",
            "n_groups": len(np.unique(labels[np.concatenate([te for _, te in folds])])),
            "recipe": _plain(_recorded(recipe)),
            "trained_with": _folds_trained_with(result["folds"]),
            "seed": int(seed),
            "seconds": time.perf_counter() - t0,
        }
    )
    return result


def _recorded(recipe: Mapping[str, Any]) -> dict[str, Any]:
    """The recipe as recorded in the result: a budget by its description, detector settings by
    their fields."""
    out = dict(recipe)
    if out.get("budget") is not None:
        out["budget"] = getattr(out["budget"], "description", str(out["budget"]))
    if hasattr(out.get("window_config"), "to_dict"):
        out["window_config"] = out["window_config"].to_dict()
    return out


def _run_folds(
    tasks: list[FoldTask],
    n_jobs: int,
    on_fold: Callable[[dict[str, Any], int], None] | None,
    shared: Mapping[str, Any],
) -> list[dict[str, Any]]:
    """Every fold's record, in the order they finish; ``on_fold(record, n_folds)`` after each.
    ``shared``: the recordings as :func:`eskin.learn.parallel.share` made them (or nothing)."""
    from eskin.learn.parallel import run_calls

    done: Iterable[dict[str, Any]] = run_calls(
        run_fold, [((t,), shared) for t in tasks], n_jobs=n_jobs, unordered=True
    )
    records = []
    for record in done:
        records.append(record)
        if on_fold is not None:
            on_fold(record, len(tasks))
    return records


def _without_predictions(record: dict[str, Any]) -> dict[str, Any]:
    """A copy of a fold record less its per-recording predictions (its own and its baselines')."""
    def without(d: Mapping[str, Any], *keys: str) -> dict[str, Any]:
        return {k: v for k, v in d.items() if k not in keys}

    out = without(record, "y_true", "y_pred", "dont_know", "confidence")
    if "live" in record:
        out["live"] = without(record["live"], "per_recording")
    if "baselines" in record:
        out["baselines"] = {name: without(b, "y_pred") for name, b in record["baselines"].items()}
    return out


def _pooled(
    records: list[dict[str, Any]],
    folds: list[tuple[np.ndarray, np.ndarray]],
    labels: np.ndarray,
    names: list[str],
    baselines: Sequence[str],
    seed: int,
) -> dict[str, Any]:
    """Scores of the pooled out-of-fold predictions, per fold records, baselines. The fold
    records are read, never changed: the result's folds are copies without the predictions
    (which the result holds pooled)."""
    records = sorted(records, key=lambda r: r["fold"])
    test_idx = np.concatenate([folds[r["fold"]][1] for r in records])
    y_true = np.concatenate([r["y_true"] for r in records]).astype(np.int64)
    y_pred = np.concatenate([r["y_pred"] for r in records]).astype(np.int64)
    g = labels[test_idx]
    result: dict[str, Any] = {
        "classes": list(names),
        "n_recordings": len(test_idx),
        **summarise(y_true, y_pred, g, names, seed),
        "ci_method": CI_METHOD.format(n=N_BOOTSTRAP),
    }
    result["baselines"] = {}
    for name in baselines:
        b_pred = np.concatenate([r["baselines"][name]["y_pred"] for r in records])
        result["baselines"][name] = summarise(y_true, b_pred.astype(np.int64), g, names, seed)
    result["folds"] = [_without_predictions(r) for r in records]
    result["predictions"] = {
        "index": test_idx.tolist(),
        "group": g.tolist(),
        "true": y_true.tolist(),
        "predicted": y_pred.tolist(),
    }
    if all("dont_know" in r for r in records):
        flagged = np.concatenate([np.asarray(r["dont_know"], bool) for r in records])
        result["predictions"]["dont_know"] = flagged.tolist()
        result["dont_know"] = dont_know_scores(y_true, y_pred, flagged)
    confidence = [c for r in records for c in r.get("confidence", [None] * len(r["y_true"]))]
    if confidence and all(c is not None for c in confidence):
        result["predictions"]["confidence"] = confidence
        result["risk_coverage"] = risk_coverage(y_true, y_pred, np.asarray(confidence))
    return result


def risk_coverage(y_true: np.ndarray, y_pred: np.ndarray, confidence: np.ndarray,
                  points: int = 20) -> dict[str, list[float]]:
    """The risk-coverage curve of selective classification: decide only the most confident
    recordings (a share ``coverage`` of them) and flag the rest "don't know"; ``error`` is the
    error on the decided ones, at coverages 1/points, 2/points, ..., 1 (ties in confidence are
    broken by recording order). A confidence that ranks errors last gives a curve that falls
    as the coverage shrinks; an uninformative one stays flat at the overall error."""
    right = np.asarray(y_true) == np.asarray(y_pred)
    order = np.argsort(-np.asarray(confidence, float), kind="stable")
    cum_wrong = np.cumsum(~right[order])
    n = len(right)
    coverage, error = [], []
    for k in range(1, points + 1):
        m = max(1, int(round(n * k / points)))
        coverage.append(m / n)
        error.append(float(cum_wrong[m - 1] / m))
    return {"coverage": coverage, "error": error}


def dont_know_scores(y_true: np.ndarray, y_pred: np.ndarray, flagged: np.ndarray) -> dict:
    """The share of "don't know" decisions and the accuracy on the decided and the flagged
    recordings (None where there are none)."""
    right = np.asarray(y_true) == np.asarray(y_pred)
    flagged = np.asarray(flagged, bool)
    return {
        "flagged": float(flagged.mean()) if flagged.size else 0.0,
        "n_flagged": int(flagged.sum()),
        "accuracy_decided": float(right[~flagged].mean()) if (~flagged).any() else None,
        "accuracy_flagged": float(right[flagged].mean()) if flagged.any() else None,
    }
