"""Deployment: write a trained model as a ``.eskin`` file (or a C header) and run it in C++.

The file format is specified in ``docs/model-format.md``. In short: a 32-byte header (magic,
version, flags, size), four sections (preprocessing, classes, support-vector bases, machines) and a
CRC-32 trailer; a model whose machines have an amplitude factor is format version 2 and has a
fifth section (the support vectors' log energies and the machines' amplitude widths); a model
with a bounded touch window (``WindowConfig.window_samples`` > 0) is format version 3, whose
preprocessing section holds that field too; a model with the calibrated decision rule is format
version 4 and has a section CALB (the machines' sigmoids and the confidence threshold). Support vectors are stored as their per-mode subspace bases (all the kernel needs
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

from eskin.errors import ModelFormatError
from eskin.learn.kernel import pattern_log_energy
from eskin.learn.training_set import true_label_names

__all__ = [
    "CompiledDecisions",
    "pattern_bases",
    "MAGIC",
    "FORMAT_VERSION",
    "FORMAT_VERSIONS",
    "format_version",
    "MachineSpec",
    "ModelSpec",
    "ModelFormatError",
    "CompiledModel",
    "compiled_engine",
    "export_model",
    "model_to_bytes",
    "spec_from_estimator",
    "spec_from_model",
    "write_c_header",
]

MAGIC = b"\x89ESKIN\r\n"
#: The versions written: 1 (the tensor kernel), 2 (some machine has an amplitude factor: section
#: AMPL), 3 (a bounded touch window: the window field ``window_samples``; AMPL as needed),
#: 4 (the calibrated decision rule: section CALB; the fields of version 3).
#: FORMAT_VERSION is the newest; each file is written in the lowest version that holds it.
FORMAT_VERSIONS = (1, 2, 3, 4)
FORMAT_VERSION = 4
#: CALB's rule field (the one calibrated rule) and its bound on slopes and offsets
_CALIBRATED_RULE = 1
_MAX_CALIBRATION = 1e6
#: The window field that format version 3 adds (older files leave it 0: every sample kept)
_V3_WINDOW_FIELD = "window_samples"
_MAX_LOG_ENERGY = 1e4
_AMPLITUDE_WIDTH_RANGE = (1e-6, 1e6)
HEADER_BYTES = 32
FLAG_FLOAT64 = 1
NAME_BYTES = 32
_WINDOW_MODES = {"energy": 0, "none": 1}
_SHORT = {"interpolate": 0, "error": 1}
_SUBSAMPLE = {"algorithm2": 0, "even": 1}
_RULES = {"binary": 0, "one_vs_all": 1}

PathLike = Union[str, Path]


@dataclass
class MachineSpec:
    """One binary machine: f(x) = sum_i dual_coef[i] K(support_vectors[i], x) + intercept.

    ``positive`` is the class index claimed when f(x) > 0; ``negative`` the class index when
    f(x) <= 0 for a binary model, -1 for a one-vs-all machine ("all the other classes").
    ``alphas`` and ``sigmas`` hold one value per tensor mode (rows, cols, D).

    ``amplitude_width`` w > 0 multiplies each kernel term by
    exp(-(e(x) - e(sv_i))^2 / (2 w^2)), e the log energy log(mean(x^2) + 1e-12); 0 (the default)
    is the plain tensor kernel. ``sv_log_energy`` holds e() of each support vector (as the
    estimator's ``sv_log_energy_``); None computes it from ``support_vectors``.
    """

    positive: int
    negative: int
    intercept: float
    alphas: tuple[int, ...]
    sigmas: tuple[float, ...]
    support_vectors: np.ndarray  # (n_sv, rows, cols, D)
    dual_coef: np.ndarray  # (n_sv,)
    amplitude_width: float = 0.0
    sv_log_energy: np.ndarray | None = None  # (n_sv,)


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
    #: the calibrated decision rule (an eskin.learn.calibration.Calibration: ``slopes``,
    #: ``offsets``, ``threshold``); None: the paper's rule
    calibration: Any = None


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
    nc = len(spec.class_names)
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
        if sv.shape[1:] != shape or sv.shape[0] < 1:  # (and so four axes)
            raise ModelFormatError(
                f"machine {k}: support_vectors shape {sv.shape}, expected (n>=1, {rows}, {cols}, {D})"
            )
        if not np.all(np.isfinite(sv)):
            raise ModelFormatError(f"machine {k}: support_vectors contain NaN or Inf")
        coef = np.asarray(m.dual_coef, dtype=np.float64).ravel()
        if len(coef) != len(sv):
            raise ModelFormatError(
                f"machine {k}: {len(coef)} dual coefficients for {len(sv)} support vectors"
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
        _validate_amplitude(k, m, sv.shape[0])


def _validate_amplitude(k: int, m: MachineSpec, n_sv: int) -> None:
    """The amplitude width (0, or within the loader's range) and the given log energies."""
    w = m.amplitude_width
    lo, hi = _AMPLITUDE_WIDTH_RANGE
    if not (np.isfinite(w) and (w == 0 or lo <= w <= hi)):
        raise ModelFormatError(
            f"machine {k}: amplitude_width={w!r} must be 0 (no amplitude factor) or within "
            f"[{lo:g}, {hi:g}]"
        )
    if m.sv_log_energy is None:
        return
    e = np.asarray(m.sv_log_energy, dtype=np.float64)
    if e.shape != (n_sv,):
        raise ModelFormatError(
            f"machine {k}: sv_log_energy shape {e.shape}, expected ({n_sv},) (one per support vector)"
        )
    bad = np.flatnonzero(~(np.abs(e) <= _MAX_LOG_ENERGY))
    if bad.size:
        raise ModelFormatError(
            f"machine {k}: sv_log_energy[{bad[0]}]={float(e[bad[0]])!r} is not finite or outside "
            f"[-{_MAX_LOG_ENERGY:g}, {_MAX_LOG_ENERGY:g}]"
        )


def format_version(spec: ModelSpec) -> int:
    """The version a spec is written in: 4 with the calibrated rule, else 3 with a bounded
    touch window (window_samples > 0), else 2 if some machine has an amplitude factor, else 1."""
    if spec.calibration is not None:
        return 4
    if float(_window_fields(spec.window_config).get(_V3_WINDOW_FIELD, 0.0)) != 0.0:
        return 3
    return 2 if _has_amplitude(spec) else 1


def _has_amplitude(spec: ModelSpec) -> bool:
    return any(float(m.amplitude_width) for m in spec.machines)  # each 0 or > 0 (validated)


def _window_fields(cfg: Any) -> dict[str, float]:
    """The detector settings as name -> float (an eskin.WindowConfig or a plain mapping)."""
    if cfg is None:
        from eskin.signal.preprocess import WindowConfig

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
    version = format_version(spec)
    unique, machine_terms = _unique_support_vectors(spec)
    alpha_store = tuple(max(int(m.alphas[z]) for m in spec.machines) for z in range(3))
    ranks, bases = bases_fn(np.stack(unique), alpha_store)

    meta_fields = {"format": "eskin-model", "dtype": dtype, **spec.meta}
    if _has_amplitude(spec):  # a version-1 file's meta (and every byte of it) is as it always was
        meta_fields["amplitude"] = True
        meta_fields["amplitude_widths"] = [float(m.amplitude_width) for m in spec.machines]
    meta = json.dumps(meta_fields, sort_keys=True, default=str).encode("utf-8")
    sections = [
        _section(b"PREP", _prep_section(spec)),
        _section(b"CLAS", _clas_section(spec)),
        _section(b"SVBS", _svbs_section(spec, len(unique), alpha_store, ranks, bases, real)),
        _section(b"MACH", _mach_section(spec, machine_terms, real)),
    ]
    if _has_amplitude(spec):
        sections.append(_section(b"AMPL", _ampl_section(spec, unique)))
    if spec.calibration is not None:
        sections.append(_section(b"CALB", _calb_section(spec)))
    sections.append(_section(b"meta", meta))
    body_len = HEADER_BYTES + sum(len(s) for s in sections)
    flags = FLAG_FLOAT64 if dtype == "float64" else 0
    header = MAGIC + struct.pack(
        "<HHIIIII", version, HEADER_BYTES, flags, body_len + 4, len(sections), 0, 0
    )
    body = header + b"".join(sections)
    blob = body + struct.pack("<I", zlib.crc32(body) & 0xFFFFFFFF)
    _check_loads(blob)
    return blob


def _check_loads(blob: bytes) -> None:
    """The format's one rule set is the C++ loader's (cpp/src/model_format.cpp, read through
    the compiled core): a model it would refuse is never written. (:func:`_validate_spec`
    only refuses a description earlier, naming its fields.)"""
    from eskin import _core

    try:
        _core.Model.from_bytes(blob)
    except _core.ModelFormatError as exc:
        raise ModelFormatError(f"the model would not load: {exc}") from None


def _unique_support_vectors(spec: ModelSpec) -> tuple[list[np.ndarray], list[dict[int, float]]]:
    """One table of unique support vectors, in order of first appearance, and each machine's
    terms as {table index: summed dual coefficient}."""
    table: dict[bytes, int] = {}
    unique: list[np.ndarray] = []
    machine_terms: list[dict[int, float]] = []
    for m in spec.machines:
        terms: dict[int, float] = {}
        sv = np.ascontiguousarray(m.support_vectors, dtype=np.float64)
        for x, c in zip(sv, np.asarray(m.dual_coef, dtype=np.float64).ravel()):
            key = x.tobytes()
            idx = table.get(key)
            if idx is None:
                idx = table[key] = len(unique)
                unique.append(x)
            terms[idx] = terms.get(idx, 0.0) + float(c)  # a repeated pattern: one term
        machine_terms.append(terms)
    return unique, machine_terms


def _table_log_energies(spec: ModelSpec, unique: list[np.ndarray]) -> np.ndarray:
    """e() of each support vector of the table: the machines' own values where they give them
    (the same tensor must have the same energy in every machine), else computed."""
    table = {x.tobytes(): i for i, x in enumerate(unique)}
    energy = np.full(len(unique), np.nan)
    owner = np.full(len(unique), -1)
    for k, m in enumerate(spec.machines):
        if m.sv_log_energy is None:
            continue
        sv = np.ascontiguousarray(m.support_vectors, dtype=np.float64)
        for j, (x, e) in enumerate(zip(sv, np.asarray(m.sv_log_energy, dtype=np.float64))):
            i = table[x.tobytes()]
            if owner[i] >= 0 and abs(energy[i] - e) > 1e-9 * (1.0 + abs(e)):
                raise ModelFormatError(
                    f"machine {k}: sv_log_energy[{j}]={float(e)!r}, but the same support vector "
                    f"has {float(energy[i])!r} in machine {owner[i]} (one pattern, one energy)"
                )
            if owner[i] < 0:
                energy[i], owner[i] = e, k
    missing = np.flatnonzero(owner < 0)
    if missing.size:
        energy[missing] = pattern_log_energy(np.stack([unique[i] for i in missing]))
    bad = np.flatnonzero(~(np.abs(energy) <= _MAX_LOG_ENERGY))
    if bad.size:
        raise ModelFormatError(
            f"support vector {bad[0]}: log energy {float(energy[bad[0]])!r} is not finite or "
            f"outside [-{_MAX_LOG_ENERGY:g}, {_MAX_LOG_ENERGY:g}]"
        )
    return energy


def _ampl_section(spec: ModelSpec, unique: list[np.ndarray]) -> bytes:
    """AMPL (format version 2): the support vectors' log energies, the machines' widths."""
    energy = _table_log_energies(spec, unique)
    widths = np.array([float(m.amplitude_width) for m in spec.machines], dtype="<f8")
    return (
        struct.pack("<II", len(unique), len(spec.machines))
        + energy.astype("<f8").tobytes()
        + widths.tobytes()
    )


def _calb_section(spec: ModelSpec) -> bytes:
    """CALB (format version 4): the rule, the confidence threshold, each machine's sigmoid."""
    cal = spec.calibration
    a = [float(v) for v in cal.slopes]
    b = [float(v) for v in cal.offsets]
    n = len(spec.machines)
    if (len(a), len(b)) != (n, n):
        raise ModelFormatError(
            f"calibration: {len(a)} slopes and {len(b)} offsets for {n} machines"
        )
    t = float(cal.threshold)
    if not 0.0 <= t <= 1.0:
        raise ModelFormatError(f"calibration: threshold={t!r} must be within [0, 1]")
    for k, (ak, bk) in enumerate(zip(a, b)):
        if not (0.0 <= ak <= _MAX_CALIBRATION and abs(bk) <= _MAX_CALIBRATION):
            raise ModelFormatError(
                f"calibration: machine {k}: slope={ak!r}, offset={bk!r} must be within "
                f"[0, {_MAX_CALIBRATION:g}] and [-{_MAX_CALIBRATION:g}, {_MAX_CALIBRATION:g}]"
            )
    out = struct.pack("<IId", _CALIBRATED_RULE, len(a), t)
    return out + b"".join(struct.pack("<dd", ak, bk) for ak, bk in zip(a, b))


def _prep_section(spec: ModelSpec) -> bytes:
    """PREP: grid, D, window/subsampling/short modes, sample rate, window_config fields."""
    rows, cols = (int(v) for v in spec.grid_shape)
    window_fields = _window_fields(spec.window_config)
    if format_version(spec) < 3:  # an unbounded window: the fields of versions 1 and 2
        window_fields.pop(_V3_WINDOW_FIELD, None)
    prep = struct.pack(
        "<IIIIIIII d",
        rows,
        cols,
        int(spec.D),
        _WINDOW_MODES[spec.window],
        _SUBSAMPLE[spec.subsample],
        _SHORT[spec.short],
        len(window_fields),
        0,
        float(spec.sample_rate_hz),
    )
    for name, value in window_fields.items():
        v = float(value)
        if not np.isfinite(v):
            raise ModelFormatError(f"window_config[{name!r}]={value!r} is not finite")
        prep += _check_name("window_config field", name) + struct.pack("<d", v)
    return prep


def _clas_section(spec: ModelSpec) -> bytes:
    """CLAS: the class names and the decision rule."""
    clas = struct.pack("<II", len(spec.class_names), _RULES[spec.rule])
    return clas + b"".join(_check_name("class name", n) for n in spec.class_names)


def _svbs_section(
    spec: ModelSpec, n_sv: int, alpha_store: tuple[int, ...], ranks: Any, bases: Any, real: Any
) -> bytes:
    """SVBS: the support patterns' per-mode bases (rank and basis per pattern and mode)."""
    rows, cols = (int(v) for v in spec.grid_shape)
    svbs = struct.pack("<II", 3, n_sv) + struct.pack("<3I", rows, cols, int(spec.D))
    svbs += struct.pack("<3I", *alpha_store)
    svbs += _pad8(np.ascontiguousarray(ranks, dtype="<u4").tobytes())
    for z in range(3):
        svbs += np.ascontiguousarray(bases[z], dtype=real).tobytes()
    return svbs


def _mach_section(spec: ModelSpec, machine_terms: list[dict[int, float]], real: Any) -> bytes:
    """MACH: per machine its classes, intercept, per-mode alpha and sigma, and its terms."""
    mach = struct.pack("<II", len(spec.machines), 0)
    for m, terms in zip(spec.machines, machine_terms):
        idx = sorted(terms)
        mach += struct.pack("<iiII d", m.positive, m.negative, len(idx), 0, float(m.intercept))
        for z in range(3):
            mach += struct.pack("<II d", int(m.alphas[z]), 0, float(m.sigmas[z]))
        mach += _pad8(np.asarray(idx, dtype="<u4").tobytes())
        mach += _pad8(np.asarray([terms[i] for i in idx], dtype=real).tobytes())
    return mach


# ----------------------------------------------------------------------------- from a TouchModel


def _machine_spec(est: Any, positive: int, negative: int, where: str) -> MachineSpec:
    for attr in ("support_vectors_", "dual_coef_", "intercept_", "alphas_", "sigmas_"):
        if not hasattr(est, attr):
            raise ModelFormatError(f"{where}: the estimator has no fitted attribute {attr!r}")
    sv = np.asarray(est.support_vectors_, dtype=np.float64)
    coef = np.asarray(est.dual_coef_, dtype=np.float64).ravel()
    if not len(sv):
        raise ModelFormatError(f"{where}: the machine has no support vectors; nothing to export")
    width = float(getattr(est, "amplitude_width_", 0.0) or 0.0)
    energy = getattr(est, "sv_log_energy_", None)
    if width > 0 and energy is None:
        raise ModelFormatError(
            f"{where}: amplitude_width_={width!r} but no fitted attribute 'sv_log_energy_'"
        )
    return MachineSpec(
        positive=positive,
        negative=negative,
        intercept=float(est.intercept_),
        alphas=tuple(int(a) for a in est.alphas_),
        sigmas=tuple(float(s) for s in est.sigmas_),
        support_vectors=sv,
        dual_coef=coef,
        amplitude_width=width,
        sv_log_energy=None if energy is None else np.asarray(energy, dtype=np.float64).ravel(),
    )


def spec_from_estimator(
    estimator: Any,
    class_names: Sequence[str],
    *,
    D: int,
    grid_shape: tuple[int, int],
    window: str = "energy",
    subsample: str = "algorithm2",
    short: str = "interpolate",
    sample_rate_hz: float = 3000.0,
    window_config: Any = None,
    meta: dict[str, Any] | None = None,
    calibration: Any = None,
) -> ModelSpec:
    """The :class:`ModelSpec` of a fitted estimator and the preprocessing it was trained with.

    ``estimator``: a fitted binary machine (TensorSVC / TensorRLS: ``classes_`` = [0, 1] index
    ``class_names``, f > 0 means ``classes_[1]``) or a fitted OneVsAllTouchClassifier whose
    ``classes_`` are 0..k-1 (machine k claims class k).
    """
    est = estimator
    classes = [str(c) for c in class_names]
    if hasattr(est, "estimators_"):
        if len(est.estimators_) != len(classes):
            raise ModelFormatError(
                f"one-vs-all estimator has {len(est.estimators_)} machines for {len(classes)} classes"
            )
        ids = [int(c) for c in np.asarray(est.classes_)]
        if ids != list(range(len(classes))):
            raise ModelFormatError(f"one-vs-all classes_ {ids} must be 0..{len(classes) - 1}")
        machines = [
            _machine_spec(m, k, -1, f"machine {k} ({classes[k]} vs rest)")
            for k, m in enumerate(est.estimators_)
        ]
        rule = "one_vs_all"
    else:
        if not hasattr(est, "classes_"):
            raise ModelFormatError("binary estimator without classes_: not fitted, nothing to "
                                   "export")
        cls = [int(c) for c in np.asarray(est.classes_)]
        if len(classes) != 2 or sorted(cls) != [0, 1]:
            raise ModelFormatError(
                f"binary estimator classes_ {cls} must be [0, 1] for the classes {classes}"
            )
        machines = [_machine_spec(est, cls[1], cls[0], "binary machine")]
        rule = "binary"
    import eskin

    return ModelSpec(
        class_names=classes,
        rule=rule,
        machines=machines,
        D=int(D),
        grid_shape=(int(grid_shape[0]), int(grid_shape[1])),
        window=str(window),
        subsample=str(subsample),
        short=str(short),
        sample_rate_hz=float(sample_rate_hz),
        window_config=window_config,
        meta={"eskin_version": eskin.__version__, "classes": classes, **dict(meta or {})},
        calibration=calibration,
    )


def spec_from_model(model: Any) -> ModelSpec:
    """The :class:`ModelSpec` of a trained :class:`eskin.models.TouchModel` (a binary machine
    for two classes, a OneVsAllTouchClassifier for more; see :func:`spec_from_estimator`)."""
    if isinstance(model, ModelSpec):
        return model
    # the sample rate too: the controller's touch window counts samples, so a model exported
    # at a rate it was not trained at would cut other windows than it learned on
    for attr in ("classes", "estimator", "D", "grid_shape", "window", "subsample",
                 "sample_rate_hz"):
        if not hasattr(model, attr):
            raise ModelFormatError(
                f"cannot export a {type(model).__name__}: expected an eskin.models.TouchModel "
                f"(missing {attr!r})"
            )
    return spec_from_estimator(
        model.estimator,
        model.classes,
        D=model.D,
        grid_shape=model.grid_shape,
        window=model.window,
        subsample=model.subsample,
        short=str(getattr(model, "short", "interpolate")),
        sample_rate_hz=float(model.sample_rate_hz),
        window_config=getattr(model, "window_config", None),
        meta={"machine": getattr(model, "machine", None),
              "selection": getattr(model, "selection", None)},
        calibration=getattr(model, "calibration", None),
    )


def export_model(model: Any, path: PathLike, dtype: str = "float32") -> Path:
    """Write a trained model (a TouchModel or a :class:`ModelSpec`) as a ``.eskin`` file.

    ``dtype`` is the precision of the stored bases and coefficients: "float32" (default, half
    the size) or "float64". The written file is read back by the C++ loader before returning,
    so a file that this function returns is one the controller can load. Returns the path.
    """
    data = model_to_bytes(spec_from_model(model), dtype)
    CompiledModel(data)  # the C++ validator must accept what we write
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    from eskin._files import write_whole

    write_whole(path, data)  # a full disk leaves no partial model
    return path


# ----------------------------------------------------------------------------- C header


def _c_ident(name: str) -> str:
    ident = "".join(c if c.isalnum() or c == "_" else "_" for c in name)
    if not ident or ident[0].isdigit():
        ident = "m_" + ident
    return ident


def write_c_header(model_or_file: Any, path: PathLike, *, name: str = "eskin_model",
                   dtype: str = "float32") -> Path:
    """Write a model as a C/C++ header for firmware without a file system.

    ``model_or_file``: a TouchModel / :class:`ModelSpec` (exported with ``dtype``) or the path
    of a ``.eskin`` file. The header holds the very bytes of the ``.eskin`` file as
    ``static const unsigned char <name>_data[]`` (and ``<name>_size``), plus macros describing
    it. The array is ``const`` (a controller's linker places it in flash) and 8-byte aligned, so
    that ``eskin::Model::view_bytes(<name>_data, <name>_size)`` reads the support-vector bases in
    place instead of copying them to RAM (``Model::from_bytes`` copies).
    """
    if isinstance(model_or_file, (str, Path)):
        src = Path(model_or_file)
        if not src.is_file():
            raise FileNotFoundError(f"model file {src} does not exist")
        data = src.read_bytes()
    elif isinstance(model_or_file, (bytes, bytearray)):
        data = bytes(model_or_file)
    else:
        data = model_to_bytes(spec_from_model(model_or_file), dtype)
    cm = CompiledModel(data)  # validates
    ident = _c_ident(name)
    guard = ident.upper() + "_H"
    lines = [
        f"/* {ident}: an eskin model (.eskin format version {cm.format_version}, "
        "docs/model-format.md)",
        f" * classes: {', '.join(cm.class_names)} ({cm.rule})",
        f" * grid {cm.grid_shape[0]}x{cm.grid_shape[1]}, D = {cm.D}, window {cm.window}, "
        f"subsample {cm.subsample}, {cm.sample_rate_hz:g} Hz",
        f" * {cm.n_support} support vectors, {'float64' if cm.is_float64 else 'float32'}, "
        f"{len(data)} bytes, CRC-32 0x{zlib.crc32(data[:-4]) & 0xFFFFFFFF:08x}",
        " * Load with eskin::Model::view_bytes(" + ident + "_data, " + ident + "_size): in",
        " * place, from flash (from_bytes copies it to RAM).",
        " * Generated by eskin.deploy.export.write_c_header (eskin export --c-header); do not",
        " * edit. */",
        f"#ifndef {guard}",
        f"#define {guard}",
        "",
        "#include <stddef.h>",
        "",
        f"#define {ident.upper()}_N_CLASSES {len(cm.class_names)}",
        f"#define {ident.upper()}_ROWS {cm.grid_shape[0]}",
        f"#define {ident.upper()}_COLS {cm.grid_shape[1]}",
        f"#define {ident.upper()}_D {cm.D}",
        f"#define {ident.upper()}_N_SUPPORT {cm.n_support}",
        "",
        f"static const char* const {ident}_class_names[{len(cm.class_names)}] = {{"
        + ", ".join(json.dumps(c) for c in cm.class_names)
        + "};",
        f"static const size_t {ident}_size = {len(data)};",
        "/* const: in flash; aligned for the float32/float64 bases read in place */",
        "#if defined(__cplusplus)",
        f"#define {ident.upper()}_ALIGN alignas(8)",
        "#elif defined(__STDC_VERSION__) && __STDC_VERSION__ >= 201112L",
        f"#define {ident.upper()}_ALIGN _Alignas(8)",
        "#else",
        f"#define {ident.upper()}_ALIGN __attribute__((aligned(8)))",
        "#endif",
        f"{ident.upper()}_ALIGN static const unsigned char {ident}_data[{len(data)}] = {{",
    ]
    for i in range(0, len(data), 16):
        chunk = data[i : i + 16]
        lines.append("  " + ", ".join(f"0x{b:02x}" for b in chunk) + ",")
    lines += ["};", "", f"#endif /* {guard} */", ""]
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines))
    return path


# ----------------------------------------------------------------------------- compiled model


@dataclass(frozen=True)
class CompiledDecisions:
    """Decisions of the C++ classifier on a batch of recordings.

    ``labels``: class names; ``label_indices``: indices into the model's classes;
    ``decision_values``: (n, n_machines) (one machine for a binary model, > 0 meaning the second
    class); ``dont_know``: the rule's flags; ``windows``: (n, 2) the [start, stop) touch window
    used, in samples; ``window_found``: False where the detector found no touch (the whole
    recording was used).
    """

    labels: np.ndarray
    label_indices: np.ndarray
    decision_values: np.ndarray
    dont_know: np.ndarray
    windows: np.ndarray
    window_found: np.ndarray
    #: the calibrated rule's confidence in each label (NaN under the paper's rule)
    confidence: np.ndarray | None = None


_STATUS = {
    -1: "its shape does not fit the model",
    -2: "no touch was detected (the model's detector has fallback = error)",
    -3: "it holds NaN or Inf values",
    -4: "its window is shorter than D (the model's short policy is error)",
    -5: "the basis computation failed",
}  # the core's other statuses (a null pointer, the reserved overflow) never come from here


class CompiledModel:
    """A ``.eskin`` model loaded into the C++ core: classify raw recordings as the controller does.

    ``CompiledModel(path_or_bytes)``; or :meth:`from_model` to compile a trained TouchModel in
    memory. Raises :class:`ModelFormatError` (a ValueError) naming the problem for a file that is
    not a valid model.
    """

    def __init__(self, source: Union[PathLike, bytes, bytearray]) -> None:
        from eskin import _core

        try:
            if isinstance(source, (bytes, bytearray)):
                self._model = _core.Model.from_bytes(bytes(source))
                self.path: Path | None = None
            else:
                self.path = Path(source)
                if not self.path.is_file():
                    raise FileNotFoundError(f"model file {self.path} does not exist")
                self._model = _core.Model.load(str(self.path))
        except _core.ModelFormatError as exc:
            raise ModelFormatError(str(exc)) from None
        self._clf = _core.Classifier(self._model)

    @classmethod
    def from_model(cls, model: Any, dtype: str = "float32") -> "CompiledModel":
        """Compile a TouchModel (or :class:`ModelSpec`) without writing a file."""
        return cls(model_to_bytes(spec_from_model(model), dtype))

    # -- description
    class_names = property(lambda self: list(self._model.class_names))
    classes = class_names
    rule = property(lambda self: self._model.rule)
    D = property(lambda self: int(self._model.D))
    grid_shape = property(lambda self: (int(self._model.rows), int(self._model.cols)))
    window = property(lambda self: self._model.window)
    subsample = property(lambda self: self._model.subsample)
    sample_rate_hz = property(lambda self: float(self._model.sample_rate_hz))
    window_config = property(lambda self: dict(self._model.window_config))
    n_support = property(lambda self: int(self._model.n_support))
    alpha_store = property(lambda self: tuple(self._model.alpha_store))
    is_float64 = property(lambda self: bool(self._model.is_float64))
    file_bytes = property(lambda self: int(self._model.file_bytes))
    machines = property(lambda self: list(self._model.machines))
    format_version = property(lambda self: int(self._model.format_version))
    #: "calibrated" (format version 4, section CALB) or "paper"
    decision_rule = property(lambda self: "calibrated" if self._model.calibrated else "paper")

    def calibration(self) -> Any:
        """The model's calibrated rule as an eskin.learn.calibration.Calibration (``reject``
        NaN: a file holds the threshold, not the fraction it was chosen for), or None."""
        if not self._model.calibrated:
            return None
        from eskin.learn.calibration import Calibration

        ms = self._model.machines
        return Calibration(tuple(float(m["calib_slope"]) for m in ms),
                           tuple(float(m["calib_offset"]) for m in ms),
                           float(self._model.reject_threshold), float("nan"),
                           self.rule == "binary")
    #: e() of each support vector (format version 2), else an empty array
    sv_log_energy = property(lambda self: np.asarray(self._model.sv_log_energy, dtype=np.float64))
    #: each machine's amplitude width (0: no amplitude factor)
    amplitude_widths = property(
        lambda self: tuple(float(m["amplitude_width"]) for m in self._model.machines)
    )

    def __repr__(self) -> str:
        return (
            f"CompiledModel(classes={self.class_names}, rule={self.rule!r}, D={self.D}, "
            f"n_support={self.n_support}, {'float64' if self.is_float64 else 'float32'})"
        )

    # -- decisions
    def _signals(self, signals: Any) -> np.ndarray:
        x = np.asarray(signals)
        x = x[None] if x.ndim == 3 else x  # one recording: a batch of one
        if x.ndim != 4 or x.shape[1:3] != self.grid_shape:
            raise ValueError(
                f"signals: expected shape (n, {self.grid_shape[0]}, {self.grid_shape[1]}, T) or "
                f"({self.grid_shape[0]}, {self.grid_shape[1]}, T), got {np.shape(signals)}"
            )
        return x  # int16, float32 and float64 as they are; the core casts any other to float64

    def classify(self, signals: Any, lengths: Any = None) -> CompiledDecisions:
        """Classify raw recordings (n, rows, cols, T) (or one (rows, cols, T)), int16 or float,
        with the model's own preprocessing (touch window, subsampling to D) in C++.
        ``lengths``: valid samples of each recording (default T)."""
        x = self._signals(signals)
        lab, val, dk, status, win, found, conf = self._clf.classify(
            x, None if lengths is None else np.asarray(lengths, dtype=np.int64)
        )
        return self._decisions(lab, val, dk, status, win, found, conf)

    def classify_tensors(self, X: Any) -> CompiledDecisions:
        """Classify already preprocessed patterns (n, rows, cols, D) (the machines only)."""
        X = np.asarray(X, dtype=np.float64)
        X = X[None] if X.ndim == 3 else X  # one pattern: a batch of one
        lab, val, dk, status, conf = self._clf.classify_tensors(np.ascontiguousarray(X))
        n = len(lab)
        return self._decisions(
            lab, val, dk, status, np.zeros((n, 2), np.int64), np.ones(n, bool), conf
        )

    def _decisions(self, lab, val, dk, status, win, found, conf) -> CompiledDecisions:
        bad = np.flatnonzero(np.asarray(status) != 0)
        if bad.size:
            i = int(bad[0])
            why = _STATUS.get(int(status[i]), f"status {int(status[i])}")
            raise ValueError(
                f"recording {i} cannot be classified: {why} ({bad.size} recording(s) failed)"
            )
        lab = np.asarray(lab, dtype=np.int64)
        names = np.asarray(self.class_names, dtype=object)[lab]
        return CompiledDecisions(names, lab, np.asarray(val), np.asarray(dk, bool),
                                 np.asarray(win), np.asarray(found, bool),
                                 np.asarray(conf, dtype=np.float64))

    def decision_function(self, signals: Any, lengths: Any = None) -> np.ndarray:
        """Decision values of raw recordings: (n,) for a binary model, (n, n_classes) otherwise."""
        return self._estimator_values(self.classify(signals, lengths).decision_values)

    def _estimator_values(self, v: np.ndarray) -> np.ndarray:
        """Decision values shaped as the Python estimators give them: (n,) for a binary model."""
        return v.ravel() if self.rule == "binary" else v

    def predict(self, signals: Any, lengths: Any = None) -> np.ndarray:
        """Class names of raw recordings."""
        return self.classify(signals, lengths).labels

    def predict_recordings(self, data: Any, indices: Any = None, *,
                           chunk: int = 32) -> list[dict[str, Any]]:
        """Per-recording decisions on a campaign (or raw signals (n, rows, cols, T)), in the
        format of :meth:`eskin.models.TouchModel.predict_recordings`: dicts with ``index``,
        ``label``, ``decision_values``, ``dont_know``, ``window`` and, for a campaign with
        modality labels, ``true_label``. Recordings are read ``chunk`` at a time."""
        is_campaign = hasattr(data, "recording")
        n_total = len(data) if is_campaign else int(np.shape(data)[0])
        idx = np.arange(n_total) if indices is None else np.asarray(indices, np.int64)
        lengths = np.asarray(data.lengths) if is_campaign else None
        truth = true_label_names(data, idx)
        out: list[dict[str, Any]] = []
        for c0 in range(0, len(idx), chunk):
            sel = idx[c0 : c0 + chunk]
            if is_campaign:
                recs = [np.asarray(data.recording(int(i))) for i in sel]
                lens = np.array([min(r.shape[-1], int(lengths[i])) for r, i in zip(recs, sel)])
                width = int(lens.max())  # each recording's valid samples, then zeros
                block = np.stack([np.pad(r[..., :n], ((0, 0), (0, 0), (0, width - n)))
                                  for r, n in zip(recs, lens)])
            else:
                block = np.asarray(data)[sel]
                lens = None
            d = self.classify(block, lens)
            for j, (i, true_label) in enumerate(zip(sel, truth[c0 : c0 + chunk])):
                item: dict[str, Any] = {
                    "index": int(i),
                    "label": str(d.labels[j]),
                    "decision_values": [float(v) for v in d.decision_values[j]],
                    "dont_know": bool(d.dont_know[j]),
                    "confidence": (float(d.confidence[j]) if np.isfinite(d.confidence[j])
                                   else None),
                    "window": [int(v) for v in d.windows[j]],
                }
                if true_label is not None:
                    item["true_label"] = true_label
                out.append(item)
        return out

    def stream(self, samples: Any, *, flush: bool = True, timed: bool = False) -> list[dict[str, Any]]:
        """Run the streaming classifier over samples (n_samples, rows*cols) (or a recording
        (rows, cols, T)), one sample at a time as the controller would. Returns the events:
        dicts with ``sample`` (samples seen when it happened), ``status_name`` and, for
        decisions, ``label`` (a class name), ``dont_know``, ``confidence`` (the calibrated
        rule's, None under the paper's rule), ``values`` and ``window``; with
        ``timed``, ``push_ns``: the wall time of the push that made the event (the latency from
        the touch's last sample to its label)."""
        from eskin import _core

        x = np.asarray(samples, dtype=np.float64)
        if x.ndim == 3:
            x = x.reshape(-1, x.shape[-1]).T
        sc = _core.StreamClassifier(self._model)
        events = sc.feed(np.ascontiguousarray(x), flush, timed)
        for e in events:
            if "label" in e:
                e["label"] = self.class_names[e["label"]]
            if "confidence" in e and not np.isfinite(e["confidence"]):
                e["confidence"] = None  # the paper's rule has no confidence
        return events


# ----------------------------------------------------------------------------- model files


class _CompiledMachines:
    """An estimator-like view of a CompiledModel, so that a ``.eskin`` file loads back as a
    TouchModel (Python preprocessing, C++ machines)."""

    def __init__(self, compiled: CompiledModel) -> None:
        self.compiled = compiled
        self.classes_ = np.arange(len(compiled.class_names))
        self._dont_know = np.zeros(0, bool)

    def decision_function(self, X: np.ndarray) -> np.ndarray:
        return self.compiled._estimator_values(self.compiled.classify_tensors(X).decision_values)

    def predict(self, X: np.ndarray) -> np.ndarray:
        d = self.compiled.classify_tensors(X)
        self._dont_know = d.dont_know
        return d.label_indices

    @property
    def dont_know_(self) -> np.ndarray:
        return self._dont_know


def compiled_engine(model: Any) -> CompiledModel:
    """The C++ classifier of a model: the one a ``.eskin`` file was loaded into, or the
    TouchModel compiled in memory in float64 (so that its labels equal the Python model's).
    Used by ``eskin predict --engine cpp``."""
    est = getattr(model, "estimator", None)
    if isinstance(est, _CompiledMachines):
        return est.compiled
    return CompiledModel.from_model(model, dtype="float64")


def _save_eskin(model: Any, path: Path) -> None:
    export_model(model, path)


def _load_eskin(path: Path) -> Any:
    from eskin.learn.models import TouchModel

    cm = CompiledModel(path)
    try:
        from eskin.signal.preprocess import WindowConfig

        cfg = WindowConfig.from_array(np.array(list(cm.window_config.values())))
    except Exception:  # noqa: BLE001 - keep the mapping if the dataclass cannot take it
        cfg = cm.window_config
    return TouchModel(
        classes=cm.class_names,
        estimator=_CompiledMachines(cm),
        machine="compiled",
        selection="compiled",
        D=cm.D,
        window=cm.window,
        subsample=cm.subsample,
        sample_rate_hz=cm.sample_rate_hz,
        grid_shape=cm.grid_shape,
        window_config=cfg,
        training={"source": str(path), "format": "eskin-model"},
        calibration=cm.calibration(),
    )


def _register() -> None:
    try:
        from eskin.learn.models import register_model_format
    except ImportError:  # the learning stack is not there: export works without it
        return
    register_model_format(".eskin", _save_eskin, _load_eskin)


_register()
