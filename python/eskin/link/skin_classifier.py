"""The host's classifier of a whole skin: one stream classifier per patch, behind one object.

:class:`SkinClassifier` is the one place the skin listener (:mod:`eskin.link.skin_listener`)
classifies through: ``push(patch_id, samples)`` and ``flush(patch_id)`` return the touches of
that patch. Inside, each patch has its own streaming classifier (the compiled model's C++
``StreamClassifier``, what ``eskin listen --model`` and the controller run), built from the
patch's model; patches that share a model file share its loaded model, each keeping its own
stream state. :meth:`SkinClassifier.patch_view` gives a patch's classifier in the shape a
:class:`~eskin.link.listener.LinkListener` takes (``model=``), so one patch's link is the
single-patch case it always was.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from eskin.data.skin import Skin
from eskin.link.host_classifier import HostClassifier, Touch, load_host_classifier

__all__ = ["SkinClassifier"]


class SkinClassifier:
    """One streaming touch classifier per patch of ``skin`` that names a model (patches
    without one get no host decisions). ``backend`` as for ``eskin listen``."""

    def __init__(self, skin: Skin, backend: str = "auto") -> None:
        self.skin = skin
        loaded: dict[Path, Any] = {}
        self._by_patch: dict[str, HostClassifier] = {}
        for p in skin.patches:
            if p.model is None:
                continue
            if p.model not in loaded:
                loaded[p.model] = _load_model(p.model, backend)
            clf = load_host_classifier(loaded[p.model], backend)
            if tuple(clf.grid) != p.grid:
                raise ValueError(f"{p.model}: a {clf.grid[0]}x{clf.grid[1]} model for patch "
                                 f"{p.id!r}, whose grid is {p.grid[0]}x{p.grid[1]}")
            self._by_patch[p.id] = clf

    def has_model(self, patch_id: str) -> bool:
        return patch_id in self._by_patch

    def class_names(self, patch_id: str) -> list[str]:
        return list(self._by_patch[patch_id].class_names)

    def push(self, patch_id: str, samples: np.ndarray) -> list[Touch]:
        """The touches that ``samples`` (n, taxels) of patch ``patch_id`` complete."""
        return self._by_patch[patch_id].push(samples)

    def flush(self, patch_id: str) -> list[Touch]:
        return self._by_patch[patch_id].flush()

    def reset(self, patch_id: str) -> None:
        self._by_patch[patch_id].reset()

    def patch_view(self, patch_id: str) -> HostClassifier | None:
        """Patch ``patch_id``'s classifier as a LinkListener's host classifier (None without
        a model)."""
        if patch_id not in self._by_patch:
            return None
        return _PatchView(self, patch_id, self._by_patch[patch_id])


def _load_model(path: Path, backend: str) -> Any:
    """A model file once: the compiled model of a ``.eskin`` file, else the saved model."""
    if not path.is_file():
        raise FileNotFoundError(f"model file {path} does not exist")
    if path.suffix.lower() == ".eskin" and backend != "python":
        from eskin.deploy.export import CompiledModel

        return CompiledModel(path)
    from eskin.deploy import load_model

    return load_model(path)


class _PatchView(HostClassifier):
    """One patch of a :class:`SkinClassifier`, as the host classifier of one link."""

    def __init__(self, skin: SkinClassifier, patch_id: str, inner: HostClassifier) -> None:
        self._skin = skin
        self.patch_id = patch_id
        self.kind = inner.kind
        self.grid = inner.grid
        self.class_names = list(inner.class_names)
        self.sample_rate_hz = inner.sample_rate_hz
        # what max_touch_s reads (the window settings of the model)
        for attr in ("compiled", "model"):
            if hasattr(inner, attr):
                setattr(self, attr, getattr(inner, attr))

    def push(self, samples: np.ndarray) -> list[Touch]:
        return self._skin.push(self.patch_id, samples)

    def flush(self) -> list[Touch]:
        return self._skin.flush(self.patch_id)

    def reset(self) -> None:
        self._skin.reset(self.patch_id)
