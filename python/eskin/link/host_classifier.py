"""Host classifiers for the live stream: a streaming touch detector (and, with a model, the
classifier) fed with int16 samples as they arrive.

:func:`load_host_classifier` prefers the compiled path (``eskin.export.CompiledModel``: the very
C++ stream classifier the controller runs), and falls back to ``eskin.preprocess.TouchDetector``
plus a TouchModel's Python machines when the compiled core has no model support.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["HostClassifier", "Touch", "load_host_classifier"]


@dataclass(frozen=True)
class Touch:
    """A touch found by a host classifier, in its own sample count (from its last reset)."""

    start: int
    stop: int
    label_index: int = -1
    values: tuple[float, ...] = ()
    dont_know: bool = False


class HostClassifier:
    """A streaming touch detector (+ classifier) fed with int16 samples ``(n, n_taxels)``.

    ``push`` returns the touches completed by the samples, with their windows in samples since
    the last ``reset``; ``flush`` ends a touch in progress. ``class_names`` is empty for a bare
    detector (windows only, ``label_index`` -1).
    """

    kind = "detector"

    def __init__(self, grid: tuple[int, int], sample_rate_hz: float = 3000.0,
                 config: Any = None) -> None:
        from eskin.signal.preprocess import TouchDetector

        self.grid = (int(grid[0]), int(grid[1]))
        self.class_names: list[str] = []
        self.sample_rate_hz = float(sample_rate_hz)
        self._det = TouchDetector(self.grid, self.sample_rate_hz, config)

    def push(self, samples: np.ndarray) -> list[Touch]:
        return [Touch(w.start, w.stop) for w in self._det.push(samples)]

    def flush(self) -> list[Touch]:
        return [Touch(w.start, w.stop) for w in self._det.flush()]

    def reset(self) -> None:
        self._det.reset()

    def label(self, t: Touch) -> str | None:
        """The class a touch was decided as: one of ``class_names``, None for label -1 (a
        bare detector's touches, which have no class)."""
        return self.class_names[t.label_index] if t.label_index >= 0 else None


class _PythonModelClassifier(HostClassifier):
    """eskin.preprocess.TouchDetector + a TouchModel's Python machines."""

    kind = "python"

    def __init__(self, model: Any) -> None:
        from eskin.signal.preprocess import TouchDetector

        self.model = model
        self.grid = (int(model.grid_shape[0]), int(model.grid_shape[1]))
        self.class_names = [str(c) for c in model.classes]
        self.sample_rate_hz = float(model.sample_rate_hz)
        self._det = TouchDetector(self.grid, self.sample_rate_hz, model.window_config,
                                  D=int(model.D), subsample=str(model.subsample))

    def _classify(self, windows: list) -> list[Touch]:
        out = []
        for w in windows:
            pred, F, dk = self.model.predict_indices(np.asarray(w.tensor)[None])
            values = tuple(float(v) for v in np.atleast_1d(np.asarray(F)[0]))
            out.append(Touch(w.start, w.stop, int(pred[0]), values, bool(dk[0])))
        return out

    def push(self, samples: np.ndarray) -> list[Touch]:
        return self._classify(self._det.push(samples))

    def flush(self) -> list[Touch]:
        return self._classify(self._det.flush())


class _CompiledClassifier(HostClassifier):
    """The C++ stream classifier of eskin.export.CompiledModel (what the controller runs)."""

    kind = "compiled"

    def __init__(self, compiled: Any) -> None:
        from eskin import _core

        self.compiled = compiled
        self.grid = tuple(int(v) for v in compiled.grid_shape)  # type: ignore[assignment]
        self.class_names = [str(c) for c in compiled.class_names]
        self.sample_rate_hz = float(compiled.sample_rate_hz)
        self._sc = _core.StreamClassifier(compiled._model)

    def _events(self, events: list) -> list[Touch]:
        out = []
        for e in events:
            if "label" not in e:
                continue  # an error status: the touch was dropped by the classifier
            start, stop = (int(v) for v in e["window"])
            out.append(Touch(start, stop, int(e["label"]),
                              tuple(float(v) for v in e["values"]), bool(e["dont_know"])))
        return out

    def push(self, samples: np.ndarray) -> list[Touch]:
        x = np.ascontiguousarray(samples.reshape(samples.shape[0], -1), dtype=np.float64)
        return self._events(self._sc.feed(x, False))

    def flush(self) -> list[Touch]:
        k = self.grid[0] * self.grid[1]
        return self._events(self._sc.feed(np.zeros((0, k)), True))

    def reset(self) -> None:
        self._sc.reset()


def load_host_classifier(model: Any, backend: str = "auto") -> HostClassifier:
    """A host classifier from a model file path, a TouchModel or a CompiledModel.

    ``backend``: "compiled" (the C++ stream classifier; needs eskin.export), "python"
    (TouchDetector + the TouchModel's machines) or "auto" (compiled when available).
    """
    if backend not in ("auto", "compiled", "python"):
        raise ValueError(f"backend must be 'auto', 'compiled' or 'python', got {backend!r}")
    if isinstance(model, HostClassifier):
        return model
    try:
        from eskin.deploy.export import CompiledModel
    except ImportError:
        CompiledModel = None  # type: ignore[assignment,misc]
    if isinstance(model, (str, os.PathLike)):
        path = Path(model)
        if not path.is_file():
            raise FileNotFoundError(f"model file {path} does not exist")
        if path.suffix.lower() == ".eskin" and CompiledModel is not None and backend != "python":
            return _CompiledClassifier(CompiledModel(path))
        from eskin.deploy import load_model

        model = load_model(path)
    if CompiledModel is not None and isinstance(model, CompiledModel):
        if backend == "python":
            raise ValueError("a compiled .eskin model runs on the compiled backend only")
        return _CompiledClassifier(model)
    for attr in ("classes", "estimator", "D", "grid_shape"):
        if not hasattr(model, attr):
            raise ValueError(
                f"model must be a model file, a TouchModel or a CompiledModel, not "
                f"{type(model).__name__}"
            )
    if backend != "python" and CompiledModel is not None:
        compiled = getattr(getattr(model, "estimator", None), "compiled", None)
        if compiled is not None:  # a .eskin file loaded as a TouchModel
            return _CompiledClassifier(compiled)
        try:
            return _CompiledClassifier(CompiledModel.from_model(model))
        except (ValueError, TypeError, AttributeError):
            if backend == "compiled":
                raise
    elif backend == "compiled":
        raise RuntimeError("the compiled backend needs eskin.export (not available)")
    return _PythonModelClassifier(model)


def max_touch_s(classifier: HostClassifier | None) -> float:
    """The longest touch window ``classifier`` can report, in seconds (7 s without a model or
    a window setting)."""
    cfg = None
    if classifier is not None:
        m = getattr(classifier, "model", None)
        cfg = getattr(m, "window_config", None) if m is not None else None
        if cfg is None and getattr(classifier, "compiled", None) is not None:
            value = classifier.compiled.window_config.get("max_window_s")  # type: ignore
            return float(value) if value is not None else 7.0
    return float(getattr(cfg, "max_window_s", 7.0) or 7.0)
