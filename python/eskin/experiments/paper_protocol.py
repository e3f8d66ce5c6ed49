"""The paper's experimental protocol (Section 5 of Gastaldo et al. 2014; readings R18-R23 of
``docs/paper-readings.md``).

:func:`run_experiment` runs, on one campaign file:

- the binary problems (presets A brush/washer, B brush/finger, C washer/finger, or any pairs of
  the campaign's classes) with participant-disjoint training/validation splits (45/20
  participants, 180/80 patterns on the paper's campaign), ``runs`` independent runs, D in ``Ds``,
  tensor-SVM and tensor-RLS selected by Maximal Discrepancy over the paper's grid (Tables 1-6);
- the same machines selected by conventional cross-validation on the same training sets and
  scored on the same validation sets (Figures 7 and 8, all problems, both machines);
- the three-class 1-vs-all experiment (Table 7);
- a vector baseline: an RBF SVM on the flattened subsampled window, same splits, same number of
  configurations, selected by the same cross-validation scheme;
- Algorithm 2 against evenly spaced subsampling (reading R18) on one D, all problems, one machine.

Everything is written to ``out_dir``: ``results.json`` (every number), ``report.md`` and PNG
figures (see :mod:`eskin.report`).

Protocol choices (documented in ``docs/experiments.md`` and in every ``results.json``):

- Analysis set: the recordings of run 2 (the paper's "second sampling") when the campaign has a
  run 2, otherwise every recording. On a campaign with exactly 70 participants (the paper's
  layout) the 5 participants with the worst signals are excluded, as the paper did: ranked by the
  mean number of bad taxels per recording (dead: standard deviation below 1 % of the recording's
  median taxel standard deviation; noisy: standard deviation outside the touch window above 4
  times the median over taxels), ties broken by the lowest median touch-window signal-to-noise
  ratio (power inside the detected window over power outside it). Other campaigns keep every
  participant unless ``exclude`` says otherwise (a number, or a list of participant ids).
- One participant split per run, shared by every problem, D, machine and selection method (so
  the MD-versus-CV and tensor-versus-vector comparisons are paired). The training share is 45 of
  65 participants (rounded, at least one participant on each side).
- Cross-validation (CV selection and the baseline) repeatedly splits the training set at random
  by participant (:class:`~eskin.CrossValidationSearch`: 10 splits holding out 30 % of the
  participants; ``cv={...}`` changes them), the same scheme and number of splits for both.
- Preprocessing runs once per (campaign, D): windows are detected once per recording, then
  subsampled for every D.
"""

from __future__ import annotations

import json
import math
import platform
import sys
import time
import zlib
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

from eskin._progress import progress_bar
from eskin.errors import ExperimentError
from eskin.experiments.paper_tables import PAPER_DS, PAPER_PROBLEMS
from eskin.learn.grids import (
    MACHINES,
    PAPER_ALPHAS,
    PAPER_LAMBDAS,
    PAPER_SIGMAS,
    QUICK_ALPHAS,
    QUICK_LAMBDAS,
    QUICK_SIGMAS,
    describe_params,
    fit_search,
    make_search,
    param_grid,
    selected_row,
    selection_table,
)
from eskin.learn.training_set import preprocess_campaign

SCHEMA = "eskin.experiment/1"


#: Paper's participant counts: 45 of 65 for training.
TRAIN_SHARE = 45 / 65


# --------------------------------------------------------------------------------------------
# configuration


@dataclass
class ProtocolConfig:
    """Every setting of one protocol run (stored in results.json)."""

    runs: int = 5
    Ds: tuple[int, ...] = (20, 50, 100)
    seed: int = 0
    quick: bool = False
    window: str = "energy"
    subsample: str = "algorithm2"
    problems: dict[str, tuple[str, ...]] = field(default_factory=dict)
    lambdas: tuple[float, ...] = PAPER_LAMBDAS
    sigmas: tuple[float, ...] = PAPER_SIGMAS
    alphas: tuple[str, ...] = PAPER_ALPHAS
    md: dict[str, Any] = field(default_factory=dict)
    cv: dict[str, Any] = field(default_factory=dict)
    train_share: float = TRAIN_SHARE
    multiclass: bool = True
    multiclass_D: int = 100
    baseline: bool = True
    compare_subsampling: bool = True
    compare_D: int = 100
    compare_machine: str = "rls"
    analysis_run: int | None = 2
    exclude: int | list[Any] | None = None
    #: protocol notes on settings adapted to the campaign (reported with the analysis set's)
    notes: list[str] = field(default_factory=list)

    @property
    def n_configurations(self) -> int:
        return len(self.lambdas) * len(self.sigmas) * len(self.alphas)


def quick_config(**overrides: Any) -> ProtocolConfig:
    """The reduced protocol of ``--quick``: 2 runs, a 2x2x2 grid, D in (20, 50), short MD."""
    cfg = ProtocolConfig(
        runs=2,
        Ds=(20, 50),
        quick=True,
        lambdas=QUICK_LAMBDAS,
        sigmas=QUICK_SIGMAS,
        alphas=QUICK_ALPHAS,
        md={"n_labelings": 3},
        cv={"n_splits": 3},
        multiclass_D=50,
        compare_D=50,
    )
    for k, v in overrides.items():
        setattr(cfg, k, v)
    return cfg


# --------------------------------------------------------------------------------------------
# small helpers


def task_seed(seed: int, *keys: Any) -> int:
    """A deterministic 31-bit seed for one task, from the protocol seed and the task's keys."""
    text = "/".join([str(seed), *map(str, keys)])
    return zlib.crc32(text.encode()) & 0x7FFFFFFF


def _jsonable(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _jsonable(obj.tolist())
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, np.floating):
        return _jsonable(float(obj))
    if isinstance(obj, np.bool_):
        return bool(obj)
    if isinstance(obj, float) and not math.isfinite(obj):
        return None if math.isnan(obj) else ("inf" if obj > 0 else "-inf")
    if isinstance(obj, Path):
        return str(obj)
    return obj


# --------------------------------------------------------------------------------------------
# problems, analysis set, splits


def resolve_problems(
    problems: Mapping[str, Sequence[str]] | Sequence[str | Sequence[str]] | None,
    class_names: Sequence[str],
) -> dict[str, tuple[str, ...]]:
    """Turn the ``problems`` option into {name: (class, class, ...)} checked against the campaign.

    ``None``: the paper's presets A, B, C when the campaign has the classes brush, washer and
    finger, otherwise every pair of the campaign's classes. A sequence may hold preset names
    ("A"), comma-separated class lists ("brush,washer") or tuples of class names.
    """
    names = list(class_names)
    out: dict[str, tuple[str, ...]] = {}
    if problems is None:
        if all(c in names for pair in PAPER_PROBLEMS.values() for c in pair):
            return dict(PAPER_PROBLEMS)
        for i, a in enumerate(names):
            for b in names[i + 1 :]:
                out[f"{a} vs {b}"] = (a, b)
        if not out:
            raise ExperimentError(
                f"the campaign has {len(names)} class(es) {names}: at least 2 are needed"
            )
        return out
    items: Iterable[tuple[str, Sequence[str]]]
    if isinstance(problems, Mapping):
        items = problems.items()
    else:
        parsed = []
        for p in problems:
            if isinstance(p, str) and p in PAPER_PROBLEMS:
                parsed.append((p, PAPER_PROBLEMS[p]))
            elif isinstance(p, str):
                cls = tuple(c.strip() for c in p.split(",") if c.strip())
                parsed.append((" vs ".join(cls), cls))
            else:
                cls = tuple(p)
                parsed.append((" vs ".join(cls), cls))
        items = parsed
    for name, cls in items:
        cls = tuple(cls)
        if len(cls) < 2 or len(set(cls)) != len(cls):
            raise ExperimentError(f"problem {name!r} needs at least 2 distinct classes, got {cls}")
        unknown = [c for c in cls if c not in names]
        if unknown:
            raise ExperimentError(
                f"problem {name!r}: unknown class(es) {unknown}; the campaign has {names}"
            )
        out[str(name)] = cls
    return out


def split_participants(
    participants: Sequence[Any], n_train: int, seed: int
) -> tuple[np.ndarray, np.ndarray]:
    """Split the distinct participant ids into (train, test), disjoint, seeded.

    ``n_train`` participants go to training, the rest to testing; both sides sorted.
    """
    ids = np.unique(np.asarray(participants))
    if not 1 <= n_train < len(ids):
        raise ExperimentError(
            f"cannot put {n_train} of {len(ids)} participants in training "
            "(at least one on each side)"
        )
    rng = np.random.default_rng(seed)
    perm = rng.permutation(len(ids))
    return np.sort(ids[perm[:n_train]]), np.sort(ids[perm[n_train:]])


def n_train_participants(n_participants: int, share: float = TRAIN_SHARE) -> int:
    """45 of 65 on the paper's campaign; the same share elsewhere, one at least on each side."""
    if n_participants < 2:
        raise ExperimentError(
            f"the analysis set has {n_participants} participant(s); a participant-disjoint "
            "split needs at least 2"
        )
    return int(min(max(round(n_participants * share), 1), n_participants - 1))


def binary_split(
    labels: np.ndarray,
    participants: np.ndarray,
    classes: Sequence[int],
    train_participants: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Positions (into the analysis set) of the training and validation patterns of a problem.

    Every pattern of the problem's classes whose participant is in ``train_participants`` trains;
    every other pattern of those classes validates.
    """
    in_problem = np.isin(labels, np.asarray(classes))
    in_train = np.isin(participants, train_participants)
    return np.flatnonzero(in_problem & in_train), np.flatnonzero(in_problem & ~in_train)


def one_vs_all_training_set(
    labels: np.ndarray,
    participants: np.ndarray,
    positive: int,
    classes: Sequence[int],
    train_participants: np.ndarray,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray]:
    """Table 7's training set of the machine for class ``positive`` (reading R23).

    All patterns of ``positive`` from the training participants (90 on the paper's campaign),
    plus as many patterns drawn at random from the training participants' other classes (or all
    of them when there are fewer). Returns (positions, y) with y = 1 for positives, 0 otherwise.
    """
    in_train = np.isin(participants, train_participants) & np.isin(labels, np.asarray(classes))
    pos = np.flatnonzero(in_train & (labels == positive))
    others = np.flatnonzero(in_train & (labels != positive))
    n_neg = min(len(pos), len(others))
    neg = np.sort(rng.choice(others, size=n_neg, replace=False))
    idx = np.concatenate([pos, neg])
    y = np.concatenate([np.ones(len(pos), int), np.zeros(n_neg, int)])
    order = np.argsort(idx, kind="stable")
    return idx[order], y[order]


@dataclass
class AnalysisSet:
    """The recordings the protocol uses (positions into the campaign) and how they were chosen."""

    indices: np.ndarray
    labels: np.ndarray
    participants: np.ndarray
    class_names: list[str]
    run: int | None
    excluded: list[Any]
    exclusion_rule: str
    notes: list[str]
    scores: dict[str, dict[str, float]]

    def summary(self) -> dict[str, Any]:
        return {
            "n_patterns": int(len(self.indices)),
            "n_participants": int(len(np.unique(self.participants))),
            "run": self.run,
            "participants": np.unique(self.participants).tolist(),
            "excluded_participants": list(self.excluded),
            "exclusion_rule": self.exclusion_rule,
            "participant_scores": self.scores,
            "classes": self.class_names,
            "patterns_per_class": {
                c: int(np.sum(self.labels == k)) for k, c in enumerate(self.class_names)
            },
            "notes": self.notes,
        }


# --------------------------------------------------------------------------------------------
# preprocessing, once per (campaign, D)


def choose_analysis_set(
    campaign: Any,
    *,
    run: int | None = 2,
    classes: Sequence[str] | None = None,
) -> tuple[np.ndarray, int | None, list[str]]:
    """Candidate recordings: run ``run`` when the campaign has it, else all (with a note)."""
    notes: list[str] = []
    n = len(campaign)
    runs = np.asarray(campaign.run) if getattr(campaign, "run", None) is not None else None
    mask = np.ones(n, bool)
    used_run: int | None = None
    if run is not None and runs is not None and np.any(runs == run):
        mask &= runs == run
        used_run = int(run)
        if len(np.unique(runs)) > 1:
            notes.append(
                f"analysis set = run {run} only (the paper's second sampling); "
                f"{int(np.sum(runs != run))} recordings of other runs not used"
            )
    else:
        notes.append(
            f"the campaign has no run {run}: every recording is used"
            if run is not None
            else "every recording is used"
        )
    if classes is not None:
        ids = [list(campaign.modalities).index(c) for c in classes]
        mask &= np.isin(np.asarray(campaign.modality), ids)
    return np.flatnonzero(mask), used_run, notes


def _exclusion(
    participants: np.ndarray,
    dead: np.ndarray,
    snr_db: np.ndarray,
    exclude: int | list[Any] | None,
) -> tuple[list[Any], str, dict[str, dict[str, float]]]:
    ids = np.unique(participants)
    scores: dict[str, dict[str, float]] = {}
    for p in ids:
        m = participants == p
        s = snr_db[m]
        s = s[np.isfinite(s)]
        scores[str(p)] = {
            "mean_bad_taxels": float(np.mean(dead[m])),
            "median_window_snr_db": float(np.median(s)) if s.size else float("nan"),
        }
    if exclude is None:
        k = 5 if len(ids) == 70 else 0
        auto = True
    elif isinstance(exclude, (int, np.integer)):
        k = int(exclude)
        auto = False
    else:
        chosen = list(exclude)
        unknown = [p for p in chosen if p not in set(ids.tolist())]
        if unknown:
            raise ExperimentError(f"exclude: unknown participant(s) {unknown}")
        return chosen, f"excluded as asked: {chosen}", scores
    if k <= 0:
        rule = (
            "no participant excluded (the paper's 5 exclusions apply to its 70-participant "
            f"campaign; this analysis set has {len(ids)})"
            if auto
            else "no participant excluded"
        )
        return [], rule, scores
    if k >= len(ids) - 1:
        raise ExperimentError(f"cannot exclude {k} of {len(ids)} participants")

    def key(p: Any) -> tuple[float, float, str]:
        sc = scores[str(p)]
        snr = sc["median_window_snr_db"]
        return (-sc["mean_bad_taxels"], snr if math.isfinite(snr) else float("inf"), str(p))

    chosen = sorted(ids.tolist(), key=key)[:k]
    rule = (
        f"excluded the {k} participants with the most bad taxels per recording (dead: std "
        "< 1 % of the recording's median taxel std; noisy: std outside the touch window > 4x "
        "the median over taxels), ties broken by the lowest median touch-window SNR"
        + (" (the paper dropped 5 of 70 as outliers)" if auto else "")
    )
    return chosen, rule, scores


# --------------------------------------------------------------------------------------------
# learning tasks (module level so that joblib can ship them to worker processes)


def _confusion(y_true: np.ndarray, y_pred: np.ndarray, k: int) -> list[list[int]]:
    m = np.zeros((k, k), np.int64)
    np.add.at(m, (np.asarray(y_true, int), np.asarray(y_pred, int)), 1)
    return m.tolist()


def binary_task(
    key: dict[str, Any],
    Xtr: np.ndarray,
    ytr: np.ndarray,
    gtr: np.ndarray,
    Xva: np.ndarray,
    yva: np.ndarray,
    cfg: ProtocolConfig,
    seed: int,
) -> dict[str, Any]:
    """Select (MD or CV) and fit one tensor machine, score it on the validation patterns."""
    t0, c0 = time.perf_counter(), time.process_time()
    machine, selection = key["machine"], key["selection"]
    grid = param_grid(cfg.lambdas, cfg.sigmas, cfg.alphas)
    search = make_search(machine, selection, grid, seed=seed, md_options=cfg.md, cv_options=cfg.cv)
    fit_search(search, Xtr, ytr, gtr)
    best = search.best_estimator_
    pred = np.asarray(best.predict(Xva)).astype(int)
    err = float(np.mean(pred != yva))
    return {
        **key,
        "seed": seed,
        "n_train": int(len(ytr)),
        "n_val": int(len(yva)),
        "error": err,
        "error_pct": 100.0 * err,
        "selected": describe_params(machine, search.best_params_, best),
        "selection_terms": selected_row(search),
        "n_support": int(np.asarray(getattr(best, "support_vectors_", np.empty(0))).shape[0]),
        "confusion": _confusion(yva, pred, 2),
        "y_pred": pred.tolist(),
        "table": selection_table(search),
        "seconds": time.perf_counter() - t0,
        "cpu_seconds": time.process_time() - c0,
    }


def multiclass_task(
    key: dict[str, Any],
    Xtr: np.ndarray,
    ytr: np.ndarray,
    machine_indices: list[np.ndarray],
    Xte: np.ndarray,
    yte: np.ndarray,
    cfg: ProtocolConfig,
    seed: int,
) -> dict[str, Any]:
    """Table 7: one MD-selected machine per class (each on its own balanced training set),
    combined by the paper's 1-vs-all rule."""
    from eskin.learn.estimators import OneVsAllTouchClassifier

    t0, c0 = time.perf_counter(), time.process_time()
    machine = key["machine"]
    grid = param_grid(cfg.lambdas, cfg.sigmas, cfg.alphas)
    search = make_search(machine, "md", grid, seed=seed, md_options=cfg.md)
    ova = OneVsAllTouchClassifier(estimator=search).fit(Xtr, ytr, machine_indices=machine_indices)
    selected = []
    for k, (srch, mi) in enumerate(zip(ova.searches_, machine_indices)):
        selected.append(
            {
                **describe_params(machine, srch.best_params_, srch.best_estimator_),
                "selection_terms": selected_row(srch),
                "n_train": int(len(mi)),
                "n_positive": int(np.sum(ytr[mi] == ova.classes_[k])),
            }
        )
    F = np.asarray(ova.decision_function(Xte))
    pred = np.asarray(ova.predict(Xte)).astype(int)
    dont_know = np.asarray(ova.dont_know_, bool)
    n_classes = len(ova.classes_)
    err = float(np.mean(pred != yte))
    return {
        **key,
        "seed": seed,
        "n_test": int(len(yte)),
        "error": err,
        "error_pct": 100.0 * err,
        "selected": selected,
        "confusion": _confusion(yte, pred, n_classes),
        "dont_know_rate": float(np.mean(dont_know)) if dont_know.size else 0.0,
        "decision_values": np.round(F, 6).tolist(),
        "y_pred": pred.tolist(),
        "seconds": time.perf_counter() - t0,
        "cpu_seconds": time.process_time() - c0,
    }


def cv_splits(
    groups: np.ndarray, y: np.ndarray, n_splits: int, test_size: float, seed: int
) -> list[tuple[np.ndarray, np.ndarray]]:
    """Repeated participant-grouped random splits (the same scheme as CrossValidationSearch);
    splits whose training part holds one class only are skipped."""
    from sklearn.model_selection import GroupShuffleSplit, StratifiedShuffleSplit

    idx = np.zeros(len(y))
    if len(np.unique(groups)) >= 2:
        it = GroupShuffleSplit(n_splits, test_size=test_size, random_state=seed).split(
            idx, y, groups
        )
    else:
        it = StratifiedShuffleSplit(n_splits, test_size=test_size, random_state=seed).split(idx, y)
    out = [(tr, te) for tr, te in it if len(np.unique(y[tr])) == 2]
    if not out:
        raise ExperimentError("no cross-validation split keeps both classes in training")
    return out


def _baseline_grid(cfg: ProtocolConfig) -> dict[str, list[Any]]:
    return {
        "C": [1.0 / lam for lam in cfg.lambdas],
        "gamma_scale": [float(s) ** -2 for s in cfg.sigmas],
        "normalise": ["none", "pattern", "feature"][: len(cfg.alphas)],
    }


def _unit_rows(A: np.ndarray) -> np.ndarray:
    return A / np.maximum(np.linalg.norm(A, axis=1, keepdims=True), 1e-300)


def _normalise(Xtr: np.ndarray, Xte: np.ndarray, how: str) -> tuple[np.ndarray, np.ndarray]:
    if how == "pattern":
        return _unit_rows(Xtr), _unit_rows(Xte)
    if how == "feature":
        mu = Xtr.mean(axis=0)
        sd = Xtr.std(axis=0)
        sd[sd <= 0] = 1.0
        return (Xtr - mu) / sd, (Xte - mu) / sd
    return Xtr, Xte


def _sqdist(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    d = (A**2).sum(1)[:, None] + (B**2).sum(1)[None, :] - 2 * A @ B.T
    return np.maximum(d, 0.0)


def baseline_task(
    key: dict[str, Any],
    Xtr: np.ndarray,
    ytr: np.ndarray,
    gtr: np.ndarray,
    Xva: np.ndarray,
    yva: np.ndarray,
    cfg: ProtocolConfig,
    seed: int,
) -> dict[str, Any]:
    """The vector baseline: an RBF SVM on the flattened (rows*cols*D) subsampled window.

    Same number of configurations as the tensor grid (C = 1/lambda; gamma = 2^-2k / median
    squared distance, k over the sigma exponents; input normalisation none / per pattern / per
    feature standing in for the alpha axis), selected by cross-validation with the same scheme
    and number of participant-grouped random splits as the tensor machines' CV selection.
    """
    from eskin.learn.estimators import svm_train

    t0, c0 = time.perf_counter(), time.process_time()
    grid = _baseline_grid(cfg)
    cvo = {"n_splits": 10, "test_size": 0.3, **cfg.cv}
    folds = cv_splits(gtr, ytr, int(cvo["n_splits"]), float(cvo["test_size"]), seed)
    Atr = Xtr.reshape(len(Xtr), -1)
    Ava = Xva.reshape(len(Xva), -1)
    y_pm = np.where(ytr == 1, 1.0, -1.0)
    norms, gscales, Cs = grid["normalise"], grid["gamma_scale"], grid["C"]
    errors = np.zeros((len(norms), len(gscales), len(Cs), len(folds)))
    for i, how in enumerate(norms):
        for f, (tr, te) in enumerate(folds):
            a, b = _normalise(Atr[tr], Atr[te], how)
            dtr, dte = _sqdist(a, a), _sqdist(b, a)
            med = max(float(np.median(dtr[np.triu_indices(len(a), 1)])), 1e-300)
            for j, gs in enumerate(gscales):
                K, Kte = np.exp(-(gs / med) * dtr), np.exp(-(gs / med) * dte)
                for k, C in enumerate(Cs):
                    beta, b0, _ = svm_train(K, y_pm[tr], C)
                    errors[i, j, k, f] = np.mean((Kte @ beta + b0 > 0) != (ytr[te] == 1))
    mean = errors.mean(axis=3)
    # lowest CV error; ties go to the simpler machine: smaller C, then wider kernel
    cand = [
        (mean[i, j, k], Cs[k], gscales[j], i, j, k)
        for i in range(len(norms))
        for j in range(len(gscales))
        for k in range(len(Cs))
    ]
    e_best, _, _, i, j, k = min(cand)
    p = {"C": Cs[k], "gamma_scale": gscales[j], "normalise": norms[i]}
    a, b = _normalise(Atr, Ava, p["normalise"])
    dtr = _sqdist(a, a)
    med = max(float(np.median(dtr[np.triu_indices(len(a), 1)])), 1e-300)
    g = p["gamma_scale"] / med
    beta, b0, support = svm_train(np.exp(-g * dtr), y_pm, p["C"])
    pred = (np.exp(-g * _sqdist(b, a)) @ beta + b0 > 0).astype(int)
    err = float(np.mean(pred != yva))
    return {
        **key,
        "seed": seed,
        "n_train": int(len(ytr)),
        "n_val": int(len(yva)),
        "error": err,
        "error_pct": 100.0 * err,
        "selected": {**p, "gamma": g, "lambda": 1.0 / p["C"], "cv_error": float(e_best)},
        "n_configurations": len(cand),
        "n_support": int(len(support)),
        "confusion": _confusion(yva, pred, 2),
        "seconds": time.perf_counter() - t0,
        "cpu_seconds": time.process_time() - c0,
    }


# --------------------------------------------------------------------------------------------
# the protocol


def _versions() -> dict[str, str]:
    import joblib
    import sklearn

    import eskin

    return {
        "eskin": eskin.__version__,
        "numpy": np.__version__,
        "scikit-learn": sklearn.__version__,
        "joblib": joblib.__version__,
        "python": sys.version.split()[0],
        "platform": platform.platform(),
    }


def _campaign_info(campaign: Any, path: Path) -> dict[str, Any]:
    sig_shape = tuple(int(s) for s in np.shape(campaign.recording(0))[:2]) if len(campaign) else ()
    source = str(getattr(campaign, "source", "unknown"))
    attrs = getattr(campaign, "attrs", {}) or {}
    return {
        "path": str(path),
        "source": source,
        "simulated": source == "simulated",
        "n_recordings": int(len(campaign)),
        "grid_shape": list(sig_shape),
        "sample_rate_hz": float(campaign.sample_rate_hz),
        "modalities": list(campaign.modalities),
        "n_participants": int(len(np.unique(np.asarray(campaign.participant)))),
        "attrs": {str(k): _jsonable(v) for k, v in dict(attrs).items() if _small_attr(v)},
    }


def _small_attr(v: Any) -> bool:
    if isinstance(v, (str, bytes)):
        return len(v) < 2000
    return np.size(v) <= 64


def _call(fn: Callable[..., Any], *args: Any) -> Any:
    return fn(*args)


def _run_tasks(
    tasks: list[tuple[Any, tuple[Any, ...]]],
    n_jobs: int,
    progress: Any,
    label: str,
) -> list[dict[str, Any]]:
    from eskin.learn.parallel import run_calls

    results: list[dict[str, Any]] = []
    task_id = progress.add_task(label, total=len(tasks))
    gen = run_calls(_call, [((fn, *args), {}) for fn, args in tasks], n_jobs=n_jobs, unordered=True)
    for res in gen:
        results.append(res)
        progress.update(task_id, advance=1)
    return results


def run_experiment(
    campaign_path: str | Path,
    out_dir: str | Path,
    runs: int | None = None,
    quick: bool = False,
    Ds: Sequence[int] | None = None,
    seed: int = 0,
    n_jobs: int = 1,
    window: str = "energy",
    subsample: str = "algorithm2",
    problems: Any = None,
    *,
    progress: bool = True,
    figures: bool = True,
    **options: Any,
) -> dict[str, Any]:
    """Run the paper's protocol on a campaign file and write results.json, report.md, figures.

    Parameters
    ----------
    campaign_path : HDF5 campaign file (see :func:`eskin.load_campaign`).
    out_dir : output folder (created).
    runs : independent participant splits (default 5; 2 with ``quick``).
    quick : reduced grid (2 lambdas x 2 sigmas x 2 alphas), 2 runs, D in (20, 50), short MD:
        a smoke test, not the paper's protocol.
    Ds : subsampled window lengths (default (20, 50, 100); (20, 50) with ``quick``).
    seed : every random choice (splits, negatives, MD labellings) derives from it.
    n_jobs : worker processes (joblib; -1 = all cores). Tasks are whole selections.
    window : "energy" (the touch-window detector) or "none" (recordings already cut).
    subsample : "algorithm2" (the paper's, default) or "even" (reading R18).
    problems : binary problems (see :func:`resolve_problems`); default the paper's A, B, C.
    options : any :class:`ProtocolConfig` field (e.g. ``md={"n_labelings": 10}``,
        ``multiclass=False``, ``baseline=False``, ``exclude=[...]``, ``cv={"n_splits": 10}``).

    Returns the results dictionary also written to ``out_dir/results.json``.
    """
    from eskin.data.campaign import load_campaign
    from eskin.experiments.report import write_report

    t_start = time.perf_counter()
    campaign_path = Path(campaign_path)
    out_dir = Path(out_dir)
    cfg = _protocol_config(quick, runs, Ds, seed, window, subsample, options)
    campaign = load_campaign(campaign_path)
    if len(campaign) == 0:
        raise ExperimentError(f"{campaign_path}: the campaign holds no recordings")
    if Ds is None:  # the defaults: the valid ones for this grid and these recordings
        adapt_default_Ds(cfg, campaign.grid_shape, int(np.max(campaign.lengths)))
    check_window_lengths(cfg.Ds, campaign.grid_shape, int(np.max(campaign.lengths)))
    names = [str(m) for m in campaign.modalities]
    cfg.problems = resolve_problems(problems, names)

    with progress_bar(progress) as prog:
        results = _protocol(campaign, campaign_path, cfg, names, n_jobs, prog)
    results["seconds_total"] = time.perf_counter() - t_start
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "results.json").write_text(json.dumps(_jsonable(results), indent=1))
    write_report(results, out_dir, figures=figures)
    return results


def adapt_default_Ds(cfg: ProtocolConfig, grid_shape: tuple[int, int], longest: int) -> None:
    """Keep the default D values that :func:`check_window_lengths` accepts for this grid and
    these recordings; when none is left (e.g. --quick's 20 and 50 on an 8x8 grid of 64 taxels),
    take the smallest of the paper's D values that is, else D = the number of taxels. The
    change is noted in ``cfg.notes``; given D values are never changed (they are checked)."""
    taxels = int(grid_shape[0]) * int(grid_shape[1])
    ok = [D for D in cfg.Ds if taxels <= D <= longest]
    if not ok:
        ok = [min([D for D in PAPER_DS if taxels <= D <= longest] or [taxels])]
    if tuple(ok) == tuple(cfg.Ds):
        return
    cfg.notes.append(
        f"D in {{{', '.join(map(str, ok))}}} instead of the default {{"
        f"{', '.join(map(str, cfg.Ds))}}}: D must be at least the {taxels} taxels of the "
        f"{grid_shape[0]}x{grid_shape[1]} grid and at most the longest recording ({longest} "
        f"samples)")
    cfg.Ds = tuple(ok)
    if cfg.multiclass_D not in cfg.Ds:
        cfg.multiclass_D = max(cfg.Ds)
    if cfg.compare_D not in cfg.Ds:
        cfg.compare_D = max(cfg.Ds)


def check_window_lengths(Ds: Sequence[int], grid_shape: tuple[int, int], longest: int) -> None:
    """Refuse the D values whose results could not be set beside the paper's: below the number
    of taxels the time mode's rank is D, not rows x cols, so the alpha grid {1, Q/2, Q} means
    something else; beyond the longest recording every touch would only be interpolated."""
    taxels = int(grid_shape[0]) * int(grid_shape[1])
    grid = f"{grid_shape[0]}x{grid_shape[1]}"
    for D in Ds:
        if D < taxels:
            raise ExperimentError(
                f"D = {D} is below the {taxels} taxels of the {grid} grid: the time mode of a "
                f"touch then has rank at most {D} instead of {taxels}, so the alpha grid "
                f"{{1, Q/2, Q}} is not the paper's and its tables cannot be compared; the paper "
                f"uses D in {{{', '.join(map(str, PAPER_DS))}}}"
            )
        if D > longest:
            raise ExperimentError(
                f"D = {D} is longer than every recording (at most {longest} samples): every "
                f"touch window would be stretched to D samples by interpolation, which adds "
                f"nothing; the paper uses D in {{{', '.join(map(str, PAPER_DS))}}}"
            )


def _protocol_config(
    quick: bool,
    runs: int | None,
    Ds: Sequence[int] | None,
    seed: int,
    window: str,
    subsample: str,
    options: dict[str, Any],
) -> ProtocolConfig:
    """The protocol's settings: the paper's (or the quick ones) with the caller's changes,
    checked."""
    cfg = quick_config() if quick else ProtocolConfig()
    if runs is not None:
        cfg.runs = int(runs)
    if Ds is not None:
        cfg.Ds = tuple(int(d) for d in Ds)
        if cfg.multiclass_D not in cfg.Ds:
            cfg.multiclass_D = max(cfg.Ds)
        if cfg.compare_D not in cfg.Ds:
            cfg.compare_D = max(cfg.Ds)
    cfg.seed, cfg.window, cfg.subsample = int(seed), window, subsample
    for k, v in options.items():
        if not hasattr(cfg, k):
            raise ExperimentError(f"unknown option {k!r}")
        setattr(cfg, k, v)
    if cfg.runs < 1:
        raise ExperimentError(f"runs must be >= 1, got {cfg.runs}")
    if not cfg.Ds or min(cfg.Ds) < 1:
        raise ExperimentError(f"Ds must be positive integers, got {cfg.Ds}")
    if subsample not in ("algorithm2", "even"):
        raise ExperimentError(f"subsample must be 'algorithm2' or 'even', got {subsample!r}")
    return cfg


def _protocol(
    campaign: Any,
    campaign_path: Path,
    cfg: ProtocolConfig,
    names: list[str],
    n_jobs: int,
    prog: Any,
) -> dict[str, Any]:
    other = "even" if cfg.subsample == "algorithm2" else "algorithm2"
    analysis, X, prep, keep = _prepare_analysis_set(campaign, cfg, names, other, prog)
    parts = analysis.participants
    n_parts = len(np.unique(parts))
    n_tr = n_train_participants(n_parts, cfg.train_share)
    if n_parts != 65:
        analysis.notes.append(
            f"{n_parts} participants in the analysis set (the paper had 65): "
            f"{n_tr} train / {n_parts - n_tr} validate per run"
        )
    splits = _participant_splits(cfg, parts, n_tr)
    tasks_bin, tasks_base, problem_info = _binary_tasks(cfg, names, analysis, X, splits, other)
    tasks_mc, mc_info = _multiclass_tasks(cfg, names, analysis, X, splits)

    # heaviest first: multiclass (several searches each), then the tensor searches, baselines
    out = _run_tasks(tasks_mc + tasks_bin + tasks_base, n_jobs, prog, "selection + fitting")
    binary, subs, base, mc = _sorted_task_results(out, cfg)

    from eskin.experiments.report import summarise
    from eskin.learn.selection import MaximalDiscrepancySearch

    results: dict[str, Any] = {
        "schema": SCHEMA,
        "created_utc": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "versions": _versions(),
        "campaign": _campaign_info(campaign, campaign_path),
        "protocol": {
            **asdict(cfg),
            "n_configurations": cfg.n_configurations,
            "train_participants_per_run": n_tr,
            "validation_participants_per_run": n_parts - n_tr,
            "machines": list(MACHINES),
            "md_reading": MaximalDiscrepancySearch().set_params(**cfg.md).describe_reading(),
            "parameter_note": "lambda is reported for both machines; the SVM is "
            "trained with C = 1/lambda (docs/paper-readings.md, R9)",
        },
        "analysis_set": analysis.summary(),
        "preprocessing": {
            "seconds": prep.seconds,
            "window": cfg.window,
            "windows": prep.windows[keep],
            "recordings": analysis.indices,
        },
        "problems": problem_info,
        "splits": splits,
        "binary": binary,
        "baseline": base,
        "subsampling": {
            "main": cfg.subsample,
            "other": other,
            "D": cfg.compare_D,
            "machine": cfg.compare_machine,
            "rows": _subsampling_rows(subs, binary, cfg.subsample, other),
        }
        if cfg.compare_subsampling
        else None,
        "multiclass": {**mc_info, "runs": mc},
    }
    results["summary"] = summarise(results)
    return results


def _prepare_analysis_set(
    campaign: Any, cfg: ProtocolConfig, names: list[str], other: str, prog: Any
) -> tuple[AnalysisSet, dict[tuple[int, str], np.ndarray], Any, np.ndarray]:
    """Preprocess the candidate recordings once per (D, subsampling) variant and drop the
    excluded participants: the analysis set, its tensors by variant, the preprocessing
    result and the mask of kept candidates."""
    cand, used_run, notes = choose_analysis_set(campaign, run=cfg.analysis_run)
    if len(cand) == 0:
        raise ExperimentError("no recording left in the analysis set")

    variants = [(D, cfg.subsample) for D in cfg.Ds]
    if cfg.compare_subsampling:
        variants.append((cfg.compare_D, other))
    task_pp = prog.add_task("preprocessing", total=len(cand))

    def on_chunk(k: int) -> None:
        prog.update(task_pp, advance=k)

    prep = preprocess_campaign(
        campaign, cand, variants, window=cfg.window, stats=True, on_chunk=on_chunk
    )

    labels_all = np.asarray(campaign.modality)[cand].astype(int)
    parts_all = np.asarray(campaign.participant)[cand]
    excluded, rule, scores = _exclusion(parts_all, prep.bad_taxels, prep.snr_db, cfg.exclude)
    keep = ~np.isin(parts_all, np.asarray(excluded, dtype=parts_all.dtype))
    analysis = AnalysisSet(
        indices=cand[keep],
        labels=labels_all[keep],
        participants=parts_all[keep],
        class_names=names,
        run=used_run,
        excluded=[_jsonable(p) for p in excluded],
        exclusion_rule=rule,
        notes=notes + cfg.notes + (prep.notes if cfg.window == "energy" else []),
        scores=scores,
    )
    X = {k: v[keep] for k, v in prep.X.items()}
    return analysis, X, prep, keep


def _participant_splits(cfg: ProtocolConfig, parts: np.ndarray, n_tr: int) -> list[dict]:
    """One random train/validation split of the participants per run."""
    splits = []
    for r in range(cfg.runs):
        tr_p, te_p = split_participants(parts, n_tr, task_seed(cfg.seed, "split", r))
        splits.append({"run": r + 1, "train_participants": tr_p, "test_participants": te_p})
    return splits


Tasks = list[tuple[Any, tuple[Any, ...]]]


def _binary_tasks(
    cfg: ProtocolConfig,
    names: list[str],
    analysis: AnalysisSet,
    X: dict[tuple[int, str], np.ndarray],
    splits: list[dict],
    other: str,
) -> tuple[Tasks, Tasks, dict[str, Any]]:
    """The binary problems' tasks (tensor machines, and the vector baseline): one per problem,
    run, D, machine and selection method; records each split's recordings in ``splits``."""
    tasks_bin: Tasks = []
    tasks_base: Tasks = []
    problem_info = {}
    labels, parts = analysis.labels, analysis.participants
    for pname, cls in cfg.problems.items():
        ids = [names.index(c) for c in cls]
        problem_info[pname] = {"classes": list(cls), "class_ids": ids}
        if len(ids) != 2:
            raise ExperimentError(
                f"problem {pname!r} has {len(ids)} classes; binary problems need 2"
            )
        for sp in splits:
            r = sp["run"]
            tr, va = binary_split(labels, parts, ids, sp["train_participants"])
            if len(tr) == 0 or len(va) == 0:
                raise ExperimentError(
                    f"problem {pname!r}, run {r}: empty training or validation set"
                )
            ytr = (labels[tr] == ids[1]).astype(int)
            yva = (labels[va] == ids[1]).astype(int)
            if len(np.unique(ytr)) < 2:
                raise ExperimentError(
                    f"problem {pname!r}, run {r}: training set has one class only"
                )
            sp.setdefault("problems", {})[pname] = {
                "train": analysis.indices[tr],
                "val": analysis.indices[va],
            }
            data = (tr, ytr, va, yva)
            _add_cell_tasks(tasks_bin, tasks_base, cfg, X, pname, r, data, parts, other)
    return tasks_bin, tasks_base, problem_info


def _add_cell_tasks(
    tasks_bin: Tasks,
    tasks_base: Tasks,
    cfg: ProtocolConfig,
    X: dict[tuple[int, str], np.ndarray],
    pname: str,
    r: int,
    data: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    parts: np.ndarray,
    other: str,
) -> None:
    """The tasks of one problem and run: every D x machine x selection method, the baseline
    per D, and the subsampling comparison."""
    tr, ytr, va, yva = data
    for D in cfg.Ds:
        XD = X[(D, cfg.subsample)]
        for machine in MACHINES:
            for selection in ("md", "cv"):
                key = {
                    "problem": pname,
                    "run": r,
                    "D": D,
                    "machine": machine,
                    "selection": selection,
                    "subsample": cfg.subsample,
                }
                s = task_seed(cfg.seed, pname, r, D, machine, selection)
                tasks_bin.append((binary_task, (key, XD[tr], ytr, parts[tr], XD[va], yva, cfg, s)))
        if cfg.baseline:
            key = {
                "problem": pname,
                "run": r,
                "D": D,
                "machine": "vector-rbf-svm",
                "selection": "cv",
                "subsample": cfg.subsample,
            }
            s = task_seed(cfg.seed, pname, r, D, "baseline")
            tasks_base.append((baseline_task, (key, XD[tr], ytr, parts[tr], XD[va], yva, cfg, s)))
    if cfg.compare_subsampling:
        XD = X[(cfg.compare_D, other)]
        key = {
            "problem": pname,
            "run": r,
            "D": cfg.compare_D,
            "machine": cfg.compare_machine,
            "selection": "md",
            "subsample": other,
        }
        # same seed as the main run of this cell: only the subsampling differs
        s = task_seed(cfg.seed, pname, r, cfg.compare_D, cfg.compare_machine, "md")
        tasks_bin.append((binary_task, (key, XD[tr], ytr, parts[tr], XD[va], yva, cfg, s)))


def _multiclass_tasks(
    cfg: ProtocolConfig,
    names: list[str],
    analysis: AnalysisSet,
    X: dict[tuple[int, str], np.ndarray],
    splits: list[dict],
) -> tuple[Tasks, dict[str, Any]]:
    """The 1-vs-all tasks (one per run and machine) when the analysis set has 3 or more
    classes; records each split's recordings in ``splits``."""
    tasks_mc: Tasks = []
    labels, parts = analysis.labels, analysis.participants
    mc_info: dict[str, Any] = {"ran": False}
    present = sorted(set(labels.tolist()))
    if cfg.multiclass and len(present) >= 3:
        D = cfg.multiclass_D
        XD = X[(D, cfg.subsample)]
        mc_info = {"ran": True, "D": D, "classes": [names[k] for k in present]}
        for sp in splits:
            r = sp["run"]
            rng = np.random.default_rng(task_seed(cfg.seed, "multiclass-negatives", r))
            train_sets = [
                one_vs_all_training_set(labels, parts, k, present, sp["train_participants"], rng)
                for k in present
            ]
            in_cls = np.isin(labels, present)
            in_tr = np.isin(parts, sp["train_participants"])
            tr_all = np.flatnonzero(in_tr & in_cls)
            te = np.flatnonzero(~in_tr & in_cls)
            remap = {k: j for j, k in enumerate(present)}
            y_tr = np.array([remap[k] for k in labels[tr_all]], int)
            y_te = np.array([remap[k] for k in labels[te]], int)
            machine_indices = [np.searchsorted(tr_all, idx) for idx, _ in train_sets]
            sp["multiclass"] = {
                "train": {
                    names[k]: analysis.indices[idx] for k, (idx, _) in zip(present, train_sets)
                },
                "test": analysis.indices[te],
            }
            for machine in MACHINES:
                key = {"run": r, "D": D, "machine": machine, "selection": "md"}
                s = task_seed(cfg.seed, "multiclass", r, machine)
                tasks_mc.append(
                    (
                        multiclass_task,
                        (key, XD[tr_all], y_tr, machine_indices, XD[te], y_te, cfg, s),
                    )
                )
    elif cfg.multiclass:
        mc_info = {
            "ran": False,
            "reason": f"the analysis set has {len(present)} class(es); "
            "the 1-vs-all experiment needs 3 or more",
        }
    return tasks_mc, mc_info


def _sorted_task_results(
    out: list[dict[str, Any]], cfg: ProtocolConfig
) -> tuple[list[dict], list[dict], list[dict], list[dict]]:
    """The tasks' results in table order: binary (main subsampling), binary with the other
    subsampling, baselines, multiclass."""
    pnames = list(cfg.problems)

    def sort_key(d: dict[str, Any]) -> tuple[Any, ...]:
        p = d.get("problem")
        m = d["machine"]
        return (
            pnames.index(p) if p in pnames else -1,
            d["run"],
            d["D"],
            MACHINES.index(m) if m in MACHINES else 9,
            d["selection"],
            str(d.get("subsample", "")),
        )

    binary = sorted(
        [
            d
            for d in out
            if "problem" in d and d["machine"] in MACHINES and d["subsample"] == cfg.subsample
        ],
        key=sort_key,
    )
    subs = sorted(
        [
            d
            for d in out
            if "problem" in d and d["machine"] in MACHINES and d["subsample"] != cfg.subsample
        ],
        key=sort_key,
    )
    base = sorted([d for d in out if d.get("machine") == "vector-rbf-svm"], key=sort_key)
    mc = sorted([d for d in out if "problem" not in d], key=sort_key)
    return binary, subs, base, mc


def _subsampling_rows(
    subs: list[dict], binary: list[dict], main_method: str, other: str
) -> list[dict[str, Any]]:
    """The subsampling comparison: each cell of the other method beside the main one."""
    sub_rows = []
    for d in subs:
        main = next(
            b
            for b in binary
            if b["problem"] == d["problem"]
            and b["run"] == d["run"]
            and b["D"] == d["D"]
            and b["machine"] == d["machine"]
            and b["selection"] == "md"
        )
        sub_rows.append(
            {
                "problem": d["problem"],
                "run": d["run"],
                "D": d["D"],
                "machine": d["machine"],
                f"error_{main_method}": main["error"],
                f"error_{other}": d["error"],
                f"selected_{other}": d["selected"],
                "seconds": d["seconds"],
                "cpu_seconds": d["cpu_seconds"],
            }
        )
    return sub_rows
