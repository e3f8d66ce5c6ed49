"""Recording every patch of a skin into one campaign file, each recording with its ``patch``.

Each patch's link keeps its own :class:`~eskin.link.recorder.StreamRecorder` (what it records
and when: one recording per replay segment, or per touch); :class:`SkinRecorder` gives them one
:class:`~eskin.data.campaign.CampaignWriter` to append to, behind a lock (the patches' links
run in their own threads), adding the ``patch`` field (docs/dataset-format.md). The writer is
opened by the first recording of any patch; every other patch must then record on the same
grid, rate, class names and recording length, or its first recording is refused with a message
naming the patch.
"""

from __future__ import annotations

import json
import threading
from pathlib import Path
from typing import Any, Optional

import numpy as np

from eskin.link.recorder import StreamRecorder

__all__ = ["PatchRecorder", "SkinRecorder"]

#: the writer settings every patch must share
_SHARED = ("grid_shape", "n_samples", "sample_rate_hz", "volts_per_count", "modalities",
           "contact_interval")


class SkinRecorder:
    """One campaign file for the recordings of every patch (``patch_ids``, in skin order)."""

    def __init__(self, path: Path, patch_ids: list[str], *, overwrite: bool,
                 attrs: dict[str, Any]) -> None:
        self.path = Path(path)
        self.patch_ids = list(patch_ids)
        self.overwrite = bool(overwrite)
        self.attrs = {**attrs, "patches": json.dumps(self.patch_ids)}
        self._lock = threading.Lock()
        self._writer: Any = None
        self._settings: Optional[dict[str, Any]] = None
        self._first: str = ""
        self.recordings = 0

    def recorder(self, patch_id: str, **kwargs: Any) -> PatchRecorder:
        """The StreamRecorder of patch ``patch_id`` (``kwargs``: StreamRecorder's)."""
        return PatchRecorder(self, patch_id, self.path, overwrite=self.overwrite, **kwargs)

    def writer_for(self, patch_id: str, settings: dict[str, Any]) -> _PatchWriter:
        with self._lock:
            if self._writer is None:
                self._open(patch_id, settings)
            else:
                self._check(patch_id, settings)
            return _PatchWriter(self, self.patch_ids.index(patch_id))

    def _open(self, patch_id: str, settings: dict[str, Any]) -> None:
        from eskin.data.campaign import CampaignWriter

        attrs = {k: v for k, v in settings["attrs"].items() if k not in ("port", "replay_file")}
        settings = {**settings, "attrs": {**attrs, **self.attrs},
                    "extra_fields": {**settings["extra_fields"], "patch": np.uint16}}
        self._writer = CampaignWriter(self.path, **settings)
        self._settings, self._first = settings, patch_id

    def _check(self, patch_id: str, settings: dict[str, Any]) -> None:
        assert self._settings is not None
        for key in _SHARED:
            mine, theirs = settings[key], self._settings[key]
            if (list(mine) if isinstance(mine, (list, tuple)) else mine) != (
                    list(theirs) if isinstance(theirs, (list, tuple)) else theirs):
                raise ValueError(
                    f"{self.path}: patch {patch_id!r} records {key}={mine!r}, patch "
                    f"{self._first!r} {theirs!r}: one campaign holds one {key}")

    def append(self, patch: int, rec: np.ndarray, **kwargs: Any) -> int:
        with self._lock:
            kwargs["extra"] = {**kwargs["extra"], "patch": patch}
            index = self._writer.append(rec, **kwargs)
            self.recordings += 1
            return index

    def keep(self) -> str:
        with self._lock:
            return self._writer.keep() if self._writer is not None else ""

    def close(self) -> None:
        """Finish the campaign file (after every patch's link has stopped)."""
        with self._lock:
            if self._writer is not None:
                self._writer.close()


class _PatchWriter:
    """What one patch's recorder sees of the shared writer."""

    def __init__(self, skin: SkinRecorder, patch: int) -> None:
        self._skin = skin
        self.patch = patch
        self.modalities = skin._writer.modalities
        self.grid_shape = skin._writer.grid_shape

    def append(self, rec: np.ndarray, **kwargs: Any) -> int:
        return self._skin.append(self.patch, rec, **kwargs)

    def keep(self) -> str:
        return self._skin.keep()

    def close(self) -> None:
        """The skin's recorder closes the file once, after every patch."""


class PatchRecorder(StreamRecorder):
    """A patch's StreamRecorder appending to its skin's one campaign."""

    def __init__(self, skin: SkinRecorder, patch_id: str, path: Path, **kwargs: Any) -> None:
        super().__init__(path, **kwargs)
        self.skin = skin
        self.patch_id = patch_id

    def make_writer(self, settings: dict[str, Any]) -> Any:
        return self.skin.writer_for(self.patch_id, settings)
