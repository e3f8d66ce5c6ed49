"""Deployable touch models: the model, and the files it is saved to and loaded from.

A :class:`TouchModel` bundles everything needed to classify a raw recording: the
preprocessing settings (D, window mode and detector configuration, subsampling method, sample
rate, grid shape), the class names, the fitted estimator (one binary tensor machine, or a
:class:`~eskin.estimators.OneVsAllTouchClassifier` for three or more classes) and the model
selection report. :func:`eskin.learn.training.train_model` makes one.

Files: :func:`save_model` / :func:`load_model` are the one function pair through which models
are written and read. The default container is a joblib (pickle) file holding a header dict
(``format``, ``format_version``, eskin version, classes, D, ...) and the model; loading checks the
header and says clearly what is wrong with a file that is not an eskin model. Like any pickle,
only load model files you trust. Other formats (the C++ ``.eskin`` file of :mod:`eskin.export`)
plug in by file suffix through :func:`register_model_format`.
"""

from __future__ import annotations

import contextlib
import importlib
import sys
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from eskin.errors import ModelFormatError, TrainingError
from eskin.learn.training_set import ArrayRecordings, preprocess_campaign, true_label_names

MODEL_FORMAT = "eskin.touch-model"
MODEL_FORMAT_VERSION = 1


@dataclass
class TouchModel:
    """A trained, deployable touch-modality classifier.

    ``estimator`` is one fitted binary machine (``classes_`` = [0, 1], decision > 0 means
    ``classes[1]``) for two classes, or a fitted OneVsAllTouchClassifier (``classes_`` =
    0..k-1, one machine per class) for three or more. Labels map to names through ``classes``.
    """

    classes: list[str]
    estimator: Any
    machine: str
    selection: str
    D: int
    window: str
    subsample: str
    sample_rate_hz: float
    grid_shape: tuple[int, int]
    window_config: Any = None
    short: str = "interpolate"
    selected: list[dict[str, Any]] = field(default_factory=list)
    selection_report: dict[str, Any] = field(default_factory=dict)
    training: dict[str, Any] = field(default_factory=dict)
    #: the calibrated decision rule (:class:`eskin.learn.calibration.Calibration`); None: the
    #: paper's rule (a model trained with --decision paper, or before the calibrated rule)
    calibration: Any = None

    @property
    def n_classes(self) -> int:
        return len(self.classes)

    @property
    def is_binary(self) -> bool:
        return len(self.classes) == 2

    @property
    def pattern_shape(self) -> tuple[int, int, int]:
        return (int(self.grid_shape[0]), int(self.grid_shape[1]), int(self.D))

    def header(self) -> dict[str, Any]:
        """The summary written in front of the model in a model file."""
        import eskin

        return {
            "format": MODEL_FORMAT,
            "format_version": MODEL_FORMAT_VERSION,
            "eskin_version": eskin.__version__,
            "classes": list(self.classes),
            "machine": self.machine,
            "selection": self.selection,
            "D": int(self.D),
            "window": self.window,
            "subsample": self.subsample,
            "short": getattr(self, "short", "interpolate"),
            "sample_rate_hz": float(self.sample_rate_hz),
            "grid_shape": [int(v) for v in self.grid_shape],
            "window_config": (
                self.window_config.to_dict()
                if hasattr(self.window_config, "to_dict")
                else self.window_config
            ),
        }

    # -- preprocessing and decisions ------------------------------------------------------
    def preprocess(self, data: Any, indices: Sequence[int] | None = None) -> np.ndarray:
        """Patterns (n, rows, cols, D) from a campaign, an :class:`ArrayRecordings` or raw
        signals (n, rows, cols, T), preprocessed as in training."""
        rec = (
            data if hasattr(data, "recording") else ArrayRecordings(data, None, self.sample_rate_hz)
        )
        idx = np.arange(len(rec)) if indices is None else np.asarray(indices, np.int64)
        shape = tuple(np.shape(rec.recording(int(idx[0])))[:2]) if len(idx) else self.grid_shape
        if tuple(int(v) for v in shape) != tuple(int(v) for v in self.grid_shape):
            raise TrainingError(
                f"the recordings have a {shape[0]}x{shape[1]} taxel grid; the model was trained "
                f"on {self.grid_shape[0]}x{self.grid_shape[1]}"
            )
        prep = preprocess_campaign(
            rec,
            idx,
            [(self.D, self.subsample)],
            window=self.window,
            config=self.window_config,
            short=getattr(self, "short", "interpolate"),
        )
        return prep.X[(self.D, self.subsample)]

    def _check_patterns(self, X: np.ndarray) -> np.ndarray:
        X = np.asarray(X, dtype=np.float64)
        if X.ndim != 4 or X.shape[1:] != self.pattern_shape:
            raise TrainingError(
                f"patterns must have shape (n, {', '.join(map(str, self.pattern_shape))}), "
                f"got {X.shape}"
            )
        return X

    def decision_function(self, X: np.ndarray) -> np.ndarray:
        """(n,) decision values for a binary model (> 0: classes[1]), (n, k) otherwise."""
        return np.asarray(self.estimator.decision_function(self._check_patterns(X)), float)

    def decide(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(class indices, decision values, don't-know flags, confidences) for preprocessed
        patterns: by the calibrated rule when the model has one (confidence: the label's
        normalised calibrated score), else by the paper's (confidence NaN)."""
        X = self._check_patterns(X)
        F = np.asarray(self.estimator.decision_function(X), float)
        cal = getattr(self, "calibration", None)
        if cal is not None:
            pred, conf, dk = cal.decide(F)
            return pred.astype(np.int64), F, dk, conf
        nan = np.full(len(F), np.nan)
        if self.is_binary:
            return (F > 0).astype(np.int64), F, np.zeros(len(F), bool), nan
        pred = np.asarray(self.estimator.predict(X)).astype(np.int64)
        dk = np.asarray(getattr(self.estimator, "dont_know_", np.zeros(len(pred), bool)), bool)
        return pred, F, dk, nan

    def predict_indices(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(class indices, decision values, don't-know flags) for preprocessed patterns."""
        return self.decide(X)[:3]

    def predict(self, X: np.ndarray) -> np.ndarray:
        """Class names of preprocessed patterns."""
        return np.asarray(self.classes, dtype=object)[self.predict_indices(X)[0]]

    def predict_recordings(
        self, data: Any, indices: Sequence[int] | None = None
    ) -> list[dict[str, Any]]:
        """Per-recording predictions of a campaign (or raw signals), ready for JSON.

        Each item: ``index`` (recording position in ``data``), ``label``, ``decision_values``
        (a list: one value for a binary model, > 0 meaning classes[1]; one per class
        otherwise), ``dont_know`` (the calibrated rule: confidence below the model's threshold;
        the paper's: no machine or several claimed the pattern), ``confidence`` (the calibrated
        rule's confidence in the label, None under the paper's rule), and ``true_label`` when
        ``data`` is a campaign whose modality names are known.
        """
        rec = (
            data if hasattr(data, "recording") else ArrayRecordings(data, None, self.sample_rate_hz)
        )
        idx = np.arange(len(rec)) if indices is None else np.asarray(indices, np.int64)
        X = self.preprocess(rec, idx)
        pred, F, dk, conf = self.decide(X)
        truth = true_label_names(rec, idx)
        out = []
        for j, i in enumerate(idx):
            item: dict[str, Any] = {
                "index": int(i),
                "label": self.classes[int(pred[j])],
                "decision_values": [float(v) for v in np.atleast_1d(F[j])],
                "dont_know": bool(dk[j]),
                "confidence": float(conf[j]) if np.isfinite(conf[j]) else None,
            }
            if truth[j] is not None:
                item["true_label"] = truth[j]
            out.append(item)
        return out


def error_rate(
    predictions: Sequence[Mapping[str, Any]], classes: Sequence[str]
) -> tuple[float, int]:
    """(error rate, count) over the predictions whose true label is one of ``classes``."""
    known = [p for p in predictions if p.get("true_label") in set(classes)]
    if not known:
        return float("nan"), 0
    return float(np.mean([p["label"] != p["true_label"] for p in known])), len(known)


# --------------------------------------------------------------------------------------------
# files

Saver = Callable[[TouchModel, Path], None]
Loader = Callable[[Path], TouchModel]
_FORMATS: dict[str, tuple[Saver, Loader]] = {}


def register_model_format(suffix: str, saver: Saver, loader: Loader) -> None:
    """Route :func:`save_model`/:func:`load_model` for files ending in ``suffix`` (e.g.
    ".eskin") to ``saver``/``loader``. Every other suffix uses the joblib container."""
    _FORMATS[suffix.lower()] = (saver, loader)


def _format_for(path: Path) -> tuple[Saver, Loader] | None:
    # eskin.deploy registers ".eskin" when it is imported (this layer does not import it)
    return _FORMATS.get(path.suffix.lower())


def save_model(model: TouchModel, path: str | Path) -> Path:
    """Write ``model`` to ``path`` (a joblib container: header dict + model; other formats by
    suffix, see :func:`register_model_format`). Returns the path."""
    import joblib

    if not isinstance(model, TouchModel):
        raise TypeError(f"save_model expects a TouchModel, got {type(model).__name__}")
    path = Path(path)
    fmt = _format_for(path)
    if fmt is not None:
        fmt[0](model, path)
        return path
    path.parent.mkdir(parents=True, exist_ok=True)
    from eskin._files import whole_file

    with whole_file(path) as tmp:  # a full disk leaves no partial model, and the old one
        joblib.dump({"header": model.header(), "model": model}, tmp, compress=3)
    return path


def load_model(path: str | Path) -> TouchModel:
    """Read a model written by :func:`save_model`, checking its header.

    Raises FileNotFoundError for a missing file and :class:`ModelFormatError` (a ValueError)
    for a file that is not an eskin model, has another format version, or is damaged.
    Loading unpickles: only load model files you trust.
    """
    import joblib

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"model file {path} does not exist")
    fmt = _format_for(path)
    if fmt is not None:
        return fmt[1](path)
    kind = _other_kind(path)
    if kind is not None:
        raise ModelFormatError(f"{path} is not an eskin model file: it is {kind}")
    try:
        with _renamed_modules():
            obj = joblib.load(path)
    except Exception as exc:
        raise ModelFormatError(
            f"{path} is not an eskin model file (cannot be read: {type(exc).__name__}: {exc})"
        ) from None
    if not isinstance(obj, dict) or not isinstance(obj.get("header"), dict):
        raise ModelFormatError(f"{path} is not an eskin model file (no header)")
    header = obj["header"]
    if header.get("format") != MODEL_FORMAT:
        raise ModelFormatError(
            f"{path} is not an eskin model file (format {header.get('format')!r}, expected "
            f"{MODEL_FORMAT!r})"
        )
    version = header.get("format_version")
    if version != MODEL_FORMAT_VERSION:
        raise ModelFormatError(
            f"{path}: model format version {version!r} is not supported (this eskin reads "
            f"version {MODEL_FORMAT_VERSION}); retrain the model or use the matching eskin"
        )
    model = obj.get("model")
    if not isinstance(model, TouchModel):
        raise ModelFormatError(f"{path}: the file holds no TouchModel")
    if list(model.classes) != list(header.get("classes", [])) or int(model.D) != header.get("D"):
        raise ModelFormatError(f"{path}: the header does not match the model it holds")
    return model


#: the first bytes of the other files eskin reads and writes, and what to call them
_SIGNATURES = (
    (b"\x89HDF\r\n\x1a\n", "an HDF5 file, not a model"),
    (b"\x89ESKIN\r\n", "an exported model (eskin export); name it .eskin to load it"),
    (b"ESKREPLY", "a replay file (eskin replay), not a model"),
    (b"ESKJRNL1", "a campaign writer's journal (eskin recover turns it into a campaign)"),
    (b"\x93NUMPY", "a numpy .npy array, not a model"),
)


def _other_kind(path: Path) -> str | None:
    """What a file that is not a joblib model is, from its first bytes (None: maybe a model)."""
    try:
        with open(path, "rb") as f:
            head = f.read(8)
    except OSError:
        return None
    for magic, kind in _SIGNATURES:
        if head.startswith(magic):
            return _campaign_or(path, kind) if magic.startswith(b"\x89HDF") else kind
    return None


def _campaign_or(path: Path, kind: str) -> str:
    """'an eskin campaign (...)' when the HDF5 file ``path`` says it is one, else ``kind``."""
    import h5py

    try:
        with h5py.File(path, "r") as f:
            fmt = f.attrs.get("format")
    except (OSError, RuntimeError, ValueError):
        return kind
    if isinstance(fmt, bytes):
        fmt = fmt.decode("utf-8", "replace")
    if fmt == "eskin-campaign":
        return ("an eskin campaign (a model is trained from one: `eskin train CAMPAIGN -o "
                "MODEL.joblib`)")
    return kind


#: modules whose classes model files written before the package's layers pickled by these paths
_RENAMED_MODULES = {
    "eskin.models": "eskin.learn.models",
    "eskin.estimators": "eskin.learn.estimators",
    "eskin.selection": "eskin.learn.selection",
    "eskin.kernel": "eskin.learn.kernel",
    "eskin.preprocess": "eskin.signal.preprocess",
}


@contextlib.contextmanager
def _renamed_modules() -> Iterator[None]:
    """While unpickling, the old module paths name the modules that now hold the classes."""
    added = [old for old in _RENAMED_MODULES if old not in sys.modules]
    for old in added:
        sys.modules[old] = importlib.import_module(_RENAMED_MODULES[old])
    try:
        yield
    finally:
        for old in added:
            sys.modules.pop(old, None)
