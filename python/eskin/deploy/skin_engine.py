"""The whole skin on one host: many patches, one engine (the C++ ``eskin::SkinEngine``).

Each patch is a stream of multi-taxel samples (int16 ADC codes) with its own touch detector;
the models (:class:`~eskin.deploy.export.CompiledModel`) are shared: one for every patch, or one
per patch through ``patch_model``. Every decision is the one a ``StreamClassifier`` of the
patch's model makes on the same samples; it also carries the patch, the touch's position on the
body when a layout is given, and a skin event id shared by touches on adjacent patches whose
windows overlap in time. See docs/skin-engine.md.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from .export import CompiledModel, PathLike

__all__ = ["SkinDecision", "SkinEngine"]


@dataclass(frozen=True)
class SkinDecision:
    """One touch of the skin, classified."""

    patch: int
    model: int  #: index into the engine's models
    label: int
    class_name: str
    dont_know: bool
    confidence: float  #: NaN under the paper's rule
    window: tuple[int, int]  #: [start, stop) in samples of the patch's stream
    sample: int  #: samples of the patch consumed when the touch ended
    event: int  #: skin event id (shared by overlapping touches on adjacent patches)
    position: tuple[float, ...] | None  #: energy-weighted centroid; None without a layout
    values: tuple[float, ...]  #: per-machine decision values


def _model(m: CompiledModel | PathLike, i: int) -> CompiledModel:
    if isinstance(m, CompiledModel):
        return m
    if isinstance(m, (str, bytes, bytearray)) or hasattr(m, "__fspath__"):
        return CompiledModel(m)
    raise ValueError(f"models[{i}]: a CompiledModel or a .eskin path, got {type(m).__name__}")


def _codes(a: Any, what: str) -> np.ndarray:
    """int16 ADC codes: integers within int16 are converted, anything else refused."""
    x = np.asarray(a)
    if x.dtype == np.int16:
        return np.ascontiguousarray(x)
    if x.dtype.kind not in "iu":
        raise ValueError(f"{what}: dtype {x.dtype}, expected int16 ADC codes")
    if x.size and (x.min() < -32768 or x.max() > 32767):
        raise ValueError(
            f"{what}: value {x.min() if x.min() < -32768 else x.max()} "
            "is outside the int16 codes [-32768, 32767]"
        )
    return np.ascontiguousarray(x, dtype=np.int16)


def _positions(positions: Sequence[Any] | None, taxels: list[int]) -> tuple[int, list[float]]:
    if positions is None:
        return 0, []
    if len(positions) != len(taxels):
        raise ValueError(f"positions: {len(positions)} patches, the skin has {len(taxels)}")
    dims = None
    flat: list[np.ndarray] = []
    for p, (pos, k) in enumerate(zip(positions, taxels)):
        a = np.asarray(pos, dtype=np.float64)
        a = a.reshape(-1, a.shape[-1]) if a.ndim >= 2 else a
        if a.ndim != 2 or a.shape[0] != k or a.shape[1] not in (2, 3):
            raise ValueError(
                f"positions[{p}]: shape {np.shape(pos)}, expected ({k}, 2) or ({k}, 3)"
                " (one 2-D or 3-D position per taxel)"
            )
        if dims is not None and a.shape[1] != dims:
            raise ValueError(f"positions[{p}]: {a.shape[1]} coordinates, patch 0 has {dims}")
        if not np.isfinite(a).all():
            raise ValueError(f"positions[{p}]: not finite")
        dims = a.shape[1]
        flat.append(a.ravel())
    return int(dims or 0), np.concatenate(flat).tolist()


class SkinEngine:
    """Many patch streams over shared models, in C++ (see the module's documentation).

    ``models``: one CompiledModel (or .eskin path) or a list of them. ``patch_model``: the model
    index of each patch (its length is the number of patches), or None with ``n_patches``
    patches all on the first model. ``positions``: None, or per patch an array of its taxels'
    2-D or 3-D positions (shape (taxels, d) or (rows, cols, d)). ``adjacency``: pairs of
    adjacent patches. ``chunk_samples``: samples per patch an interleaved block is cut into
    (0: eight detector frames). ``window_buffers``: 0, each patch keeps its own window buffer;
    n, a pool of n shared by the patches touched at the same time (a touch that starts while all
    are taken is not classified: :attr:`unbuffered`). ``window_chunk_samples``: 0, whole
    buffers; c, the same n windows' worth of samples cut into chunks of c samples that a touch
    takes as its window grows and gives back as it halves and ends, so memory follows each
    touch's kept samples (a touch that finds no free chunk is not classified). Every other
    decision is the same; docs/skin-engine.md.
    """

    def __init__(
        self,
        models: CompiledModel | PathLike | Sequence[CompiledModel | PathLike],
        patch_model: Sequence[int] | None = None,
        n_patches: int | None = None,
        positions: Sequence[Any] | None = None,
        adjacency: Iterable[tuple[int, int]] | None = None,
        chunk_samples: int = 0,
        window_buffers: int = 0,
        window_chunk_samples: int = 0,
    ) -> None:
        from eskin import _core

        many = isinstance(models, (list, tuple))
        self.models: list[CompiledModel] = [
            _model(m, i) for i, m in enumerate(models if many else [models])
        ]
        if patch_model is None:
            if n_patches is None:
                raise ValueError("n_patches: give the number of patches, or patch_model")
            table: list[int] = []
        else:
            table = [int(v) for v in patch_model]
            if n_patches is not None and n_patches != len(table):
                raise ValueError(f"n_patches = {n_patches}: patch_model has {len(table)} patches")
            n_patches = len(table)
        for i, m in enumerate(table):
            if not 0 <= m < len(self.models):
                raise ValueError(
                    f"patch_model[{i}] = {m}: must be a model index in [0, {len(self.models)})"
                )
        taxels = [
            int(np.prod(self.models[table[p] if table else 0].grid_shape))
            for p in range(int(n_patches))
        ]
        dims, flat = _positions(positions, taxels)
        pairs = [(int(a), int(b)) for a, b in (adjacency or [])]
        self._engine = _core.SkinEngine(
            [m._model for m in self.models],
            table,
            int(n_patches),
            dims,
            flat,
            pairs,
            int(chunk_samples),
            int(window_buffers),
            int(window_chunk_samples),
        )
        self._dims = dims
        self._names = [m.class_names for m in self.models]
        self._machines = [len(m.machines) for m in self.models]

    # -- description
    n_patches = property(lambda self: int(self._engine.n_patches))
    total_taxels = property(lambda self: int(self._engine.total_taxels))
    #: bytes of the largest patch's state (detector, events, positions, decision buffer share)
    bytes_per_patch = property(lambda self: int(self._engine.bytes_per_patch))
    #: touches whose classification failed (dropped, as a StreamClassifier drops them)
    dropped = property(lambda self: int(self._engine.dropped))
    #: shared window buffers: touches not classified because every buffer was taken (among
    #: :attr:`dropped`), and the most buffers (chunks) in use at once
    unbuffered = property(lambda self: int(self._engine.unbuffered))
    window_buffers_peak = property(lambda self: int(self._engine.window_buffers_peak))
    #: the shared pool: its buffers (chunks), those in use now, and the samples one holds
    window_pool_size = property(lambda self: int(self._engine.window_pool_size))
    window_pool_in_use = property(lambda self: int(self._engine.window_pool_in_use))
    window_pool_samples = property(lambda self: int(self._engine.window_pool_samples))

    def patch_taxels(self, patch: int) -> int:
        return int(self._engine.patch_taxels(patch))

    def samples_seen(self, patch: int) -> int:
        return int(self._engine.samples_seen(patch))

    def in_touch(self, patch: int) -> bool:
        return bool(self._engine.in_touch(patch))

    # -- streams
    def push(self, patch: int, samples: Any) -> list[SkinDecision]:
        """Samples of one patch, (n, taxels) or (n, rows, cols) int16 codes."""
        x = _codes(samples, f"samples of patch {patch}")
        return self._decisions(self._engine.push(patch, x.reshape(len(x), -1) if x.ndim > 2 else x))

    def push_interleaved(self, block: Any) -> list[SkinDecision]:
        """Samples of every patch: (n, total_taxels), each row patch after patch, or
        (n, patches, taxels) when every patch has as many taxels. Decisions come ordered by the
        sample at which their touch ended, then by patch, whatever the block size."""
        x = _codes(block, "block")
        return self._decisions(
            self._engine.push_interleaved(x.reshape(len(x), -1) if x.ndim > 2 else x)
        )

    def flush(self) -> list[SkinDecision]:
        """End of the streams: the touches in progress end now."""
        return self._decisions(self._engine.flush())

    def reset(self) -> None:
        self._engine.reset()

    def _decisions(self, c: dict[str, np.ndarray]) -> list[SkinDecision]:
        out = []
        for i in range(len(c["patch"])):
            m = int(c["model"][i])
            label = int(c["label"][i])
            n = self._machines[m]
            out.append(
                SkinDecision(
                    patch=int(c["patch"][i]),
                    model=m,
                    label=label,
                    class_name=self._names[m][label],
                    dont_know=bool(c["dont_know"][i]),
                    confidence=float(c["confidence"][i]),
                    window=(int(c["window"][i, 0]), int(c["window"][i, 1])),
                    sample=int(c["sample"][i]),
                    event=int(c["event"][i]),
                    position=tuple(float(v) for v in c["position"][i, : self._dims])
                    if self._dims
                    else None,
                    values=tuple(float(v) for v in c["values"][i, :n]),
                )
            )
        return out
