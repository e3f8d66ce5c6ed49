"""Deployment: write a trained model as a ``.eskin`` file (or a C header) and run it in C++.

The file format is specified in ``docs/model-format.md``. In short: a 32-byte header (magic,
version, flags, size), four sections (preprocessing, classes, support-vector bases, machines) and a
CRC-32 trailer. Support vectors are stored as their per-mode subspace bases (all the kernel needs
at inference), deduplicated across the machines of a one-vs-all model.

Three entry points:

* :func:`export_model` writes a :class:`eskin.models.TouchModel` (or a plain :class:`ModelSpec`)
  to a file, float32 by default;
* :func:`write_c_header` writes the same bytes as a C header, for firmware without a file system;
* :class:`CompiledModel` loads a file into the C++ core and classifies raw windows with it.
"""

from __future__ import annotations

import json
import struct
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence, Union

import numpy as np

__all__ = [
    "MAGIC",
    "FORMAT_VERSION",
    "MachineSpec",
    "ModelSpec",
    "ModelFormatError",
    "CompiledModel",
    "export_model",
    "model_to_bytes",
    "spec_from_model",
    "write_c_header",
]

MAGIC = b"\x89ESKIN\r\n"
FORMAT_VERSION = 1
HEADER_BYTES = 32
FLAG_FLOAT64 = 1
NAME_BYTES = 32
_WINDOW_MODES = {"energy": 0, "none": 1}
_SHORT = {"interpolate": 0, "error": 1}
_SUBSAMPLE = {"algorithm2": 0, "even": 1}
_RULES = {"binary": 0, "one_vs_all": 1}

PathLike = Union[str, Path]


class ModelFormatError(ValueError):
    """A model file (or a model description) is invalid; the message names the field."""


@dataclass
class MachineSpec:
    """One binary machine: f(x) = sum_i dual_coef[i] K(support_vectors[i], x) + intercept.

    ``positive`` is the class index claimed when f(x) > 0; ``negative`` the class index when
    f(x) <= 0 for a binary model, -1 for a one-vs-all machine ("all the other classes").
    ``alphas`` and ``sigmas`` hold one value per tensor mode (rows, cols, D).
    """

    positive: int
    negative: int
    intercept: float
    alphas: tuple[int, ...]
    sigmas: tuple[float, ...]
    support_vectors: np.ndarray  # (n_sv, rows, cols, D)
    dual_coef: np.ndarray  # (n_sv,)


@dataclass
class ModelSpec:
    """Everything a ``.eskin`` file holds, before the support vectors become bases."""

    class_names: list[str]
    rule: str  # "binary" | "one_vs_all"
    machines: list[MachineSpec]
    D: int
    grid_shape: tuple[int, int]
    window: str = "energy"  # "energy" | "none"
    subsample: str = "algorithm2"  # "algorithm2" | "even"
    short: str = "interpolate"  # windows shorter than D: "interpolate" | "error"
    sample_rate_hz: float = 3000.0
    window_config: Any = None  # eskin.WindowConfig (or its fields as a mapping); None = default
    meta: dict[str, Any] = field(default_factory=dict)


# ----------------------------------------------------------------------------- validation


def _check_name(what: str, name: str) -> bytes:
    raw = str(name).encode("utf-8")
    if not raw or len(raw) >= NAME_BYTES or b"\x00" in raw:
        raise ModelFormatError(
            f"{what} {name!r}: must be a non-empty name of at most {NAME_BYTES - 1} UTF-8 bytes"
        )
    if any(c < 0x20 or c == 0x7F for c in raw):
        raise ModelFormatError(f"{what} {name!r}: contains control characters")
    return raw.ljust(NAME_BYTES, b"\x00")


def _validate_spec(spec: ModelSpec) -> None:
    rows, cols = (int(v) for v in spec.grid_shape)
    D = int(spec.D)
    if spec.rule not in _RULES:
        raise ModelFormatError(f"rule={spec.rule!r}: expected 'binary' or 'one_vs_all'")
    if spec.window not in _WINDOW_MODES:
        raise ModelFormatError(f"window={spec.window!r}: expected 'energy' or 'none'")
    if spec.subsample not in _SUBSAMPLE:
        raise ModelFormatError(f"subsample={spec.subsample!r}: expected 'algorithm2' or 'even'")
    if spec.short not in _SHORT:
        raise ModelFormatError(f"short={spec.short!r}: expected 'interpolate' or 'error'")
    if not (np.isfinite(spec.sample_rate_hz) and spec.sample_rate_hz > 0):
        raise ModelFormatError(f"sample_rate_hz={spec.sample_rate_hz!r}: must be finite and > 0")
    nc = len(spec.class_names)
    if len(set(spec.class_names)) != nc:
        raise ModelFormatError(f"class_names {spec.class_names!r}: repeated names")
    if spec.rule == "binary":
        if nc != 2 or len(spec.machines) != 1:
            raise ModelFormatError(
                f"binary model: needs 2 classes and 1 machine, got {nc} and {len(spec.machines)}"
            )
        m = spec.machines[0]
        if {m.positive, m.negative} != {0, 1}:
            raise ModelFormatError(
                f"binary machine classes ({m.positive}, {m.negative}) must be (1, 0) or (0, 1)"
            )
    else:
        if len(spec.machines) != nc or nc < 2:
            raise ModelFormatError(
                f"one_vs_all model: needs one machine per class ({nc}), got {len(spec.machines)}"
            )
        for k, m in enumerate(spec.machines):
            if m.positive != k or m.negative != -1:
                raise ModelFormatError(
                    f"one_vs_all machine {k}: positive/negative = ({m.positive}, {m.negative}), "
                    f"expected ({k}, -1)"
                )
    shape = (rows, cols, D)
    for k, m in enumerate(spec.machines):
        sv = np.asarray(m.support_vectors)
        if sv.ndim != 4 or sv.shape[1:] != shape or sv.shape[0] < 1:
            raise ModelFormatError(
                f"machine {k}: support_vectors shape {sv.shape}, expected (n>=1, {rows}, {cols}, {D})"
            )
        if not np.all(np.isfinite(sv)):
            raise ModelFormatError(f"machine {k}: support_vectors contain NaN or Inf")
        coef = np.asarray(m.dual_coef, dtype=np.float64).reshape(-1)
        if coef.shape[0] != sv.shape[0]:
            raise ModelFormatError(
                f"machine {k}: {coef.shape[0]} dual coefficients for {sv.shape[0]} support vectors"
            )
        if not np.all(np.isfinite(coef)) or not np.isfinite(m.intercept):
            raise ModelFormatError(f"machine {k}: dual_coef or intercept not finite")
        if len(m.alphas) != 3 or len(m.sigmas) != 3:
            raise ModelFormatError(f"machine {k}: alphas/sigmas need one value per mode (3)")
        for z in range(3):
            n_z = rows * cols * D // shape[z]
            q = min(shape[z], n_z)
            if not 1 <= int(m.alphas[z]) <= q:
                raise ModelFormatError(
                    f"machine {k}: alpha[{z}]={m.alphas[z]} out of range [1, Q={q}]"
                )
            if not (np.isfinite(m.sigmas[z]) and m.sigmas[z] > 0):
                raise ModelFormatError(f"machine {k}: sigma[{z}]={m.sigmas[z]} must be > 0")


def _window_fields(cfg: Any) -> dict[str, float]:
    """The detector settings as name -> float (an eskin.WindowConfig or a plain mapping)."""
    if cfg is None:
        from eskin.preprocess import WindowConfig

        cfg = WindowConfig()
    if hasattr(cfg, "to_array") and hasattr(cfg, "field_names"):
        return dict(zip(cfg.field_names(), (float(v) for v in cfg.to_array())))
    return {str(k): float(v) for k, v in dict(cfg).items()}


# ----------------------------------------------------------------------------- bases


def pattern_bases(
    tensors: np.ndarray, alphas: Sequence[int]
) -> tuple[np.ndarray, list[np.ndarray]]:
    """Per-mode subspace bases of patterns (n, rows, cols, D), as the C++ classifier computes them.

    Returns ``(ranks, bases)``: ranks (n, 3) int, and for each mode z an array (n, alpha_z, N_z)
    whose row k is basis column k (zero beyond the pattern's numerical rank). Computed by the
    compiled core, so that the stored bases and the ones computed at inference use the same
    unfolding and the same rules for ties and rank deficiency.
    """
    from eskin import _core

    X = np.ascontiguousarray(tensors, dtype=np.float64)
    ranks, bases = _core.model_pattern_bases(X, [int(a) for a in alphas])
    return np.asarray(ranks), [np.asarray(b) for b in bases]


# ----------------------------------------------------------------------------- writing


def _section(tag: bytes, payload: bytes) -> bytes:
    pad = (-len(payload)) % 8
    return struct.pack("<4sI", tag, len(payload)) + payload + b"\x00" * pad


def _pad8(b: bytes) -> bytes:
    return b + b"\x00" * ((-len(b)) % 8)


def model_to_bytes(spec: ModelSpec, dtype: str = "float32", *, bases_fn=None) -> bytes:
    """Serialise a :class:`ModelSpec` to the ``.eskin`` byte layout.

    ``bases_fn(tensors, alphas) -> (ranks, bases)`` defaults to :func:`pattern_bases` (the compiled
    core); tests of the format alone may pass another one.
    """
    bases_fn = pattern_bases if bases_fn is None else bases_fn
    if dtype not in ("float32", "float64"):
        raise ModelFormatError(f"dtype={dtype!r}: expected 'float32' or 'float64'")
    _validate_spec(spec)
    real = np.dtype("<f8") if dtype == "float64" else np.dtype("<f4")
    rows, cols = (int(v) for v in spec.grid_shape)
    D = int(spec.D)

    # one table of unique support vectors, in order of first appearance
    table: dict[bytes, int] = {}
    unique: list[np.ndarray] = []
    machine_terms: list[dict[int, float]] = []
    for m in spec.machines:
        terms: dict[int, float] = {}
        sv = np.ascontiguousarray(m.support_vectors, dtype=np.float64)
        for x, c in zip(sv, np.asarray(m.dual_coef, dtype=np.float64).reshape(-1)):
            key = x.tobytes()
            idx = table.get(key)
            if idx is None:
                idx = table[key] = len(unique)
                unique.append(x)
            terms[idx] = terms.get(idx, 0.0) + float(c)  # a repeated pattern: one term
        machine_terms.append(terms)
    alpha_store = tuple(max(int(m.alphas[z]) for m in spec.machines) for z in range(3))
    ranks, bases = bases_fn(np.stack(unique), alpha_store)

    prep = struct.pack(
        "<IIIIIIII d",
        rows,
        cols,
        D,
        _WINDOW_MODES[spec.window],
        _SUBSAMPLE[spec.subsample],
        _SHORT[spec.short],
        len(_window_fields(spec.window_config)),
        0,
        float(spec.sample_rate_hz),
    )
    for name, value in _window_fields(spec.window_config).items():
        v = float(value)
        if not np.isfinite(v):
            raise ModelFormatError(f"window_config[{name!r}]={value!r} is not finite")
        prep += _check_name("window_config field", name) + struct.pack("<d", v)

    clas = struct.pack("<II", len(spec.class_names), _RULES[spec.rule])
    clas += b"".join(_check_name("class name", n) for n in spec.class_names)

    n_sv = len(unique)
    svbs = struct.pack("<II", 3, n_sv) + struct.pack("<3I", rows, cols, D)
    svbs += struct.pack("<3I", *alpha_store)
    svbs += _pad8(np.ascontiguousarray(ranks, dtype="<u4").tobytes())
    for z in range(3):
        svbs += np.ascontiguousarray(bases[z], dtype=real).tobytes()

    mach = struct.pack("<II", len(spec.machines), 0)
    for m, terms in zip(spec.machines, machine_terms):
        idx = sorted(terms)
        mach += struct.pack("<iiII d", m.positive, m.negative, len(idx), 0, float(m.intercept))
        for z in range(3):
            mach += struct.pack("<II d", int(m.alphas[z]), 0, float(m.sigmas[z]))
        mach += _pad8(np.asarray(idx, dtype="<u4").tobytes())
        mach += _pad8(np.asarray([terms[i] for i in idx], dtype=real).tobytes())

    meta = json.dumps(
        {"format": "eskin-model", "dtype": dtype, **spec.meta}, sort_keys=True, default=str
    ).encode("utf-8")
    sections = [
        _section(b"PREP", prep),
        _section(b"CLAS", clas),
        _section(b"SVBS", svbs),
        _section(b"MACH", mach),
        _section(b"meta", meta),
    ]
    body_len = HEADER_BYTES + sum(len(s) for s in sections)
    flags = FLAG_FLOAT64 if dtype == "float64" else 0
    header = MAGIC + struct.pack(
        "<HHIIIII", FORMAT_VERSION, HEADER_BYTES, flags, body_len + 4, len(sections), 0, 0
    )
    body = header + b"".join(sections)
    return body + struct.pack("<I", zlib.crc32(body) & 0xFFFFFFFF)
