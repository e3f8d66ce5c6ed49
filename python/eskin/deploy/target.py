"""Controller targets of an exported model: does it fit, and what to trade when it does not.

:func:`device_budget` estimates the flash and RAM that the device build of the core
(``ESKIN_DEVICE``, docs/mcu.md) needs for a model: flash holds the program and the ``.eskin``
bytes (the support-vector bases are read in place, ``eskin::Model::view_bytes``); RAM holds the
stream detector's raw-sample buffers (int16 ADC codes: the pre-onset ring and the bounded
window buffer, ``WindowConfig.window_samples`` per taxel, or the longest window when it is 0), the input's tensor and bases, the distance table and the model's small tables. The
terms follow the allocations of the device build; ``make mcu`` prints the measured heap beside
the estimate for its model.
"""

from __future__ import annotations

import functools
import json

from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = [
    "INSTRUCTION_CALIBRATION",
    "TARGETS",
    "Budget",
    "DeviceBudget",
    "Target",
    "candidate_budget",
    "decision_instructions",
    "device_budget",
    "instruction_model_error",
    "parse_budget",
    "program_image",
    "window_for_budget",
]


@dataclass(frozen=True)
class Target:
    """A controller class: its memories and clock, and the program around the model."""

    name: str
    description: str
    flash_bytes: int
    ram_bytes: int
    clock_hz: float
    program_flash_bytes: int  # code and constants of the program without its model
    program_ram_bytes: int  # statics and the reserved stack


def program_image(target: str = "cortex-m4") -> dict[str, Any]:
    """The device program around a model, measured on its linked image
    (``tools/mcu_image_size.py --write``, shipped as ``cortex_m4_program.json``): its flash
    without the model (``program_flash_bytes``), its statics (``program_statics_bytes``; both
    rounded up to a whole KiB), its stack reserve (``stack_bytes``) and what was measured."""
    from importlib.resources import files

    name = target.replace("-", "_") + "_program.json"
    return json.loads(files("eskin.deploy").joinpath(name).read_text())


_PROGRAM = program_image("cortex-m4")

TARGETS: dict[str, Target] = {
    "cortex-m4": Target(
        name="cortex-m4",
        description="Cortex-M4F, STM32F4 class: 1 MB flash, 128 KB RAM, 168 MHz",
        flash_bytes=1 << 20,
        ram_bytes=128 << 10,
        clock_hz=168e6,
        # the `make mcu` program without its model (core, newlib-nano with printf, semihosting),
        # from its linked image; statics and the stack reserve
        program_flash_bytes=int(_PROGRAM["program_flash_bytes"]),
        program_ram_bytes=int(_PROGRAM["program_statics_bytes"]) + int(_PROGRAM["stack_bytes"]),
    ),
}

_MALLOC_OVERHEAD = 4096  # allocator headers and the small vectors of the model's description


@dataclass(frozen=True)
class DeviceBudget:
    """Flash and RAM of a model on a target, by part (bytes)."""

    target: Target
    flash: dict[str, int]
    ram: dict[str, int]
    advice: list[str] = field(default_factory=list)

    @property
    def flash_total(self) -> int:
        return sum(self.flash.values())

    @property
    def ram_total(self) -> int:
        return sum(self.ram.values())

    @property
    def fits(self) -> bool:
        return (
            self.flash_total <= self.target.flash_bytes and self.ram_total <= self.target.ram_bytes
        )

    def report(self) -> list[str]:
        """Human-readable lines: totals against the target, the parts, and what to trade."""
        t = self.target
        lines = [
            f"target {t.name} ({t.description})",
            f"flash {self.flash_total} of {t.flash_bytes} bytes: "
            + ", ".join(f"{k} {v}" for k, v in self.flash.items()),
            f"RAM   {self.ram_total} of {t.ram_bytes} bytes: "
            + ", ".join(f"{k} {v}" for k, v in self.ram.items()),
        ]
        if not self.fits:
            lines.append("does not fit; to trade: " + "; ".join(self.advice))
        return lines


def device_budget(model: Any, target: str | Target = "cortex-m4") -> DeviceBudget:
    """Flash and RAM of a model (a :class:`~eskin.deploy.CompiledModel`, or ``.eskin`` bytes or
    path) on ``target`` (a name of :data:`TARGETS` or a :class:`Target`)."""
    from eskin.deploy.export import CompiledModel

    if isinstance(target, str) and target not in TARGETS:
        raise ValueError(f"unknown target {target!r} (known: {', '.join(TARGETS)})")
    t = TARGETS[target] if isinstance(target, str) else target
    cm = model if isinstance(model, CompiledModel) else CompiledModel(model)
    rows, cols = cm.grid_shape
    taxels, D = rows * cols, cm.D
    real = 8 if cm.is_float64 else 4
    size = taxels * D
    dims = (rows, cols, D)
    n_of = [size // d for d in dims]
    bases = sum(n * a for n, a in zip(n_of, cm.alpha_store))
    machines = cm.machines
    groups = len({tuple(m["alphas"]) for m in machines})
    terms = sum(len(m["coef"]) for m in machines)
    flash = {"model": cm.file_bytes, "program": t.program_flash_bytes}
    ram = _ram_terms(rows, cols, D, tuple(cm.alpha_store), cm.n_support, terms, groups,
                     bool(cm.sv_log_energy.size), real, cm.window_config, cm.sample_rate_hz, t)
    samples = ram["detector samples"]
    advice = []
    if sum(flash.values()) > t.flash_bytes:
        advice += [
            (
                f"the bases take {cm.n_support * bases * real} bytes (n_sv x sum_z N_z alpha_z x "
                f"{real}): a smaller D shrinks the (rows) and (cols) modes, N = {n_of[0]} and "
                f"{n_of[1]}"
            ),
            f"a smaller alpha (alpha_store {tuple(cm.alpha_store)})",
            (
                "fewer support vectors (a tensor-SVM keeps only its support vectors, tensor-RLS "
                f"every training pattern: {cm.n_support} here)"
            ),
            "float32 instead of float64"
            if cm.is_float64
            else "float16 bases would halve them (not in the model format)",
        ]
    if sum(ram.values()) > t.ram_bytes:
        from eskin import _core

        p = _core.window_config_resolve(
            np.array([cm.window_config[k] for k in _core.WINDOW_CONFIG_FIELDS]), cm.sample_rate_hz
        )
        per = taxels * 2 * cm.sample_rate_hz / 10
        ws = int(cm.window_config.get("window_samples", 0))
        advice += [
            (
                f"the detector keeps lookback_s + pad_before_s of raw samples and a window "
                f"buffer of {p['window_capacity']} samples per taxel ({samples} bytes in all; "
                f"{per:.0f} bytes per 0.1 s of ring): "
                + (
                    f"lower --window-samples ({ws}) or lookback_s "
                    if ws
                    else f"bound the window with --window-samples (max_window_s "
                    f"{cm.window_config['max_window_s']:g} s is kept whole now) or lower lookback_s "
                )
                + f"({cm.window_config['lookback_s']:g} s) in training"
            ),
        ]
    return DeviceBudget(t, flash, ram, advice)


# --------------------------------------------------------------------------------------------
# instructions per decision: a cost model calibrated on QEMU counts

#: QEMU counts (Cortex-M4F, mps2-an386, -icount shift=0; tables in docs/mcu.md): (D, support
#: vectors, alpha_store, amplitude factor, bounded detector window, median instructions of the
#: push that ends a touch), 3-class models, 4x4 grid at 3 kHz. Rows 1-8: the tensor-RLS MCU
#: presets of `benchmarks/bench_mcu.py` (the default grid's amplitude choice) and rows 9-22:
#: tensor-SVMs of `bench_mcu.py --part svm`, alpha 1 to (4, 4, 16), with the default bounded
#: window (``window_samples`` 1024); rows 23-24: models of `eskin train --target cortex-m4` on
#: 10 simulated participants (docs/mcu.md); rows 25-27: tensor-SVMs on the same participants
#: with every sample of a 0.5 s window kept (``window_samples`` 0).
INSTRUCTION_CALIBRATION: tuple[tuple[int, int, tuple[int, int, int], bool, bool, float], ...] = (
    (20, 36, (1, 1, 1), True, True, 0.5662e6),
    (50, 36, (1, 1, 1), True, True, 0.8143e6),
    (100, 36, (1, 1, 1), True, True, 1.2846e6),
    (20, 84, (1, 1, 1), True, True, 0.6332e6),
    (50, 84, (1, 1, 1), True, True, 0.9434e6),
    (20, 36, (2, 2, 8), False, True, 0.6278e6),
    (50, 36, (4, 4, 16), False, True, 0.7892e6),
    (100, 36, (2, 2, 8), False, True, 1.3586e6),
    (20, 35, (1, 1, 1), True, True, 0.5560e6),
    (20, 79, (1, 1, 1), True, True, 0.6241e6),
    (20, 84, (1, 1, 1), False, True, 0.5804e6),
    (50, 36, (1, 1, 1), True, True, 0.8032e6),
    (50, 58, (1, 1, 1), True, True, 0.8596e6),
    (20, 60, (2, 2, 8), True, True, 0.7957e6),
    (100, 36, (1, 1, 1), True, True, 1.2528e6),
    (100, 81, (1, 1, 1), True, True, 1.4744e6),
    (50, 36, (4, 4, 16), True, True, 0.8925e6),
    (50, 84, (4, 4, 16), True, True, 1.4384e6),
    (20, 84, (4, 4, 16), True, True, 0.6433e6),
    (50, 60, (2, 2, 8), True, True, 1.1322e6),
    (100, 36, (2, 2, 8), True, True, 1.5185e6),
    (50, 60, (4, 4, 16), False, True, 1.0606e6),
    (50, 120, (1, 1, 1), True, True, 1.0930e6),
    (50, 63, (4, 4, 16), True, True, 1.1989e6),
    (20, 120, (1, 1, 1), True, False, 0.6907e6),
    (50, 118, (1, 1, 1), True, False, 1.0077e6),
    (20, 120, (4, 4, 16), True, False, 0.7965e6),
)


def _tiles(alpha: int) -> list[int]:
    """The device's overlap tiles along one side: blocks of 4 columns, then the 1-3 left."""
    return [4] * (alpha // 4) + ([alpha % 4] if alpha % 4 else [])


def overlap_instructions(n: int, alpha: int) -> int:
    """Instructions of the inner loops of one mode's overlap with one support vector on the
    device (cpp/src/model_overlap.cpp, ``overlap_f32_tiled``): each tile of kb x lb dot products
    passes once over the n entries, loading kb + lb values and doing kb * lb multiply-adds and
    the loop's compare and branch (4 x 4: 26 instructions for 16 multiply-adds). A mode whose
    alpha reaches n costs nothing: a full-rank subspace is all of R^n and the distance is the
    ranks' difference (cpp/src/model.cpp); a rank-deficient one is counted as full here."""
    if alpha >= n:
        return 0
    return sum(n * (kb + lb + kb * lb + 2) for kb in _tiles(alpha) for lb in _tiles(alpha))


def _basis_terms(dims, alphas) -> tuple[float, float]:
    """What the input's bases cost on the device (cpp/src/scalar_bases.hpp), beyond what grows
    with D alone: the Jacobi sweeps over each mode's q x q factor (q^3; none for a mode whose
    alpha reaches the basis length N with more rows than N, where a well-conditioned factor
    proves full rank), and the alpha output columns formed through the QR's reflectors when
    the unfolding has fewer rows than N (alpha L q)."""
    size = int(np.prod(dims))
    jacobi = columns = 0.0
    for m, a in zip(dims, alphas):
        n = size // m  # the basis length N of this mode
        q, L = min(m, n), max(m, n)
        if not (m > n and a >= n):
            jacobi += q ** 3
        if m <= n:
            columns += a * L * q
    return jacobi, columns


def _instruction_features(grid_shape, D, alphas, n_support, amplitude=False,
                          bounded_window=True) -> np.ndarray:
    """What a decision's work grows with: a constant (the rest of the push), D (the window's
    subsampling, the QR of each unfolding), the input's bases (:func:`_basis_terms`), the
    support vectors, the inner loops of their overlaps (:func:`overlap_instructions` per
    support vector, N_z the length of a mode-z basis vector), with the amplitude factor one
    more exponential per support vector, and with the bounded window a term in D (the
    subsampling of the touch from the bounded buffer: fitted)."""
    dims = (int(grid_shape[0]), int(grid_shape[1]), int(D))
    size = dims[0] * dims[1] * dims[2]
    n_of = [size // d for d in dims]
    jacobi, columns = _basis_terms(dims, alphas)
    per_sv = sum(overlap_instructions(n, a) for n, a in zip(n_of, alphas))
    return np.array([1.0, D, jacobi, columns, n_support, n_support * per_sv,
                     n_support * float(bool(amplitude)), D * float(bool(bounded_window))],
                    dtype=float)


def _fit(points) -> np.ndarray:
    A = np.array([_instruction_features((4, 4), D, a, n, amp, bw)
                  for D, n, a, amp, bw, _ in points])
    y = np.array([p[5] for p in points])
    return np.linalg.lstsq(A, y, rcond=None)[0]


_COEF = _fit(INSTRUCTION_CALIBRATION)


def decision_instructions(
    grid_shape, D: int, alphas, n_support: int, amplitude: bool = False,
    bounded_window: bool = True,
) -> float:
    """Estimated Cortex-M4F instructions of one decision (least squares on
    :data:`INSTRUCTION_CALIBRATION`; its error: :func:`instruction_model_error`);
    ``amplitude``: the machines have the amplitude factor; ``bounded_window``: the detector
    keeps the bounded window (``window_samples`` > 0, the default)."""
    return float(_instruction_features(grid_shape, D, tuple(alphas), n_support, amplitude,
                                       bounded_window) @ _COEF)


def _bounded(window_config: Any) -> bool:
    """Whether a window configuration (a WindowConfig, a compiled model's fields, or None for
    the default) keeps the bounded window."""
    if window_config is None:
        return True
    if isinstance(window_config, dict):
        return float(window_config.get("window_samples", 0)) > 0
    return float(getattr(window_config, "window_samples", 0)) > 0


def instruction_model_error() -> dict[str, float]:
    """The cost model's relative error on the QEMU counts: largest in-sample error and largest
    leave-one-out error (each count predicted by the model fitted without it)."""
    pts = list(INSTRUCTION_CALIBRATION)
    fit_err, loo_err = [], []
    for i, (D, n, a, amp, bw, y) in enumerate(pts):
        fit_err.append(abs(decision_instructions((4, 4), D, a, n, amp, bw) - y) / y)
        coef = _fit(pts[:i] + pts[i + 1:])
        loo_err.append(abs(float(_instruction_features((4, 4), D, a, n, amp, bw) @ coef) - y)
                       / y)
    return {"max_fit": max(fit_err), "max_leave_one_out": max(loo_err), "points": len(pts)}


# --------------------------------------------------------------------------------------------
# budgets: what a trained model may use


@dataclass(frozen=True)
class Budget:
    """Flash, RAM (bytes) and median instructions per decision a model may use on a controller;
    the program around the model comes from ``target``."""

    target: Target
    flash_bytes: int
    ram_bytes: int
    instructions: float

    def describe(self) -> str:
        return (f"{self.target.name}: flash {self.flash_bytes} B, RAM {self.ram_bytes} B, "
                f"{self.instructions / 1e6:g} M instructions per decision")


#: instructions per decision of the targets (a decision within 10 ms at 168 MHz, CPI 1-1.5:
#: docs/mcu.md)
TARGET_INSTRUCTIONS = {"cortex-m4": 1.5e6}

_UNITS = {"": 1, "K": 1 << 10, "M": 1 << 20, "G": 1 << 30}


def _size(text: str, key: str, decimal: bool) -> float:
    t = text.strip().upper().removesuffix("B") if not decimal else text.strip().upper()
    unit = t[-1:] if t[-1:] in ("K", "M", "G") else ""
    number = t[: len(t) - len(unit)]
    try:
        value = float(number)
    except ValueError:
        raise ValueError(f"--budget {key}={text}: not a number (e.g. {key}=1M, 128K)") from None
    if not np.isfinite(value) or value <= 0:
        raise ValueError(f"--budget {key}={text}: must be positive")
    scale = {"": 1, "K": 1e3, "M": 1e6, "G": 1e9}[unit] if decimal else _UNITS[unit]
    return value * scale


def parse_budget(text: str | None, target: str | None = None) -> Budget:
    """A budget from ``--target NAME`` and/or ``--budget flash=1M,ram=128K,instr=1.5M`` (sizes
    in binary units, instructions in decimal ones; given keys override the target's)."""
    if target is not None and target not in TARGETS:
        raise ValueError(f"--target {target}: unknown target (known: {', '.join(TARGETS)})")
    base = TARGETS[target or "cortex-m4"]
    values = {"flash": float(base.flash_bytes), "ram": float(base.ram_bytes),
              "instr": TARGET_INSTRUCTIONS.get(base.name, 1.5e6)}
    if text is not None and not any(t.strip() for t in text.split(",")):
        raise ValueError(f"--budget {text!r} is empty: give flash=..,ram=..,instr=.. (or "
                         f"leave --budget out for the target's own budget)")
    given: set[str] = set()
    for item in [t for t in (text or "").split(",") if t.strip()]:
        key, sep, value = item.partition("=")
        key = key.strip().lower()
        if not sep or key not in values:
            raise ValueError(f"--budget {text}: expected flash=..,ram=..,instr=.. (got {item!r})")
        if key in given:
            raise ValueError(f"--budget {text}: {key} is given twice")
        given.add(key)
        values[key] = _size(value, key, decimal=key == "instr")
    name = base.name if text is None else f"{base.name} (budget {text})"
    t = Target(name, base.description, int(values["flash"]), int(values["ram"]), base.clock_hz,
               base.program_flash_bytes, base.program_ram_bytes)
    return Budget(t, int(values["flash"]), int(values["ram"]), float(values["instr"]))


def _stored_alphas(grid_shape, D: int, alpha: str) -> tuple[int, ...]:
    from eskin.learn.grids import alpha_value

    return alpha_value(alpha, (int(grid_shape[0]), int(grid_shape[1]), int(D)))


def estimate_model(
    budget: Budget, grid_shape, D: int, alphas, n_support: int, n_machines: int,
    amplitude: bool, window_config: Any, rate: float,
) -> dict[str, float]:
    """Estimated flash, RAM (bytes) and instructions per decision of a float32 model of one
    alpha group (the terms of :func:`device_budget`, the file from its sections)."""
    rows, cols = (int(v) for v in grid_shape)
    dims = (rows, cols, int(D))
    size = rows * cols * int(D)
    n_of = [size // d for d in dims]
    bases = sum(n * a for n, a in zip(n_of, alphas))
    terms = n_support * n_machines  # at most: every support vector in every machine
    file_bytes = 1800 + n_support * (4 * bases + (8 if amplitude else 0)) + terms * 8
    ram = _ram_terms(rows, cols, int(D), tuple(alphas), n_support, terms, 1, amplitude, 4,
                     window_config, rate, budget.target)
    return {
        "flash": file_bytes + budget.target.program_flash_bytes,
        "ram": sum(ram.values()),
        "instructions": decision_instructions(grid_shape, D, alphas, n_support, amplitude,
                                              _bounded(window_config)),
    }


def _ram_terms(rows, cols, D, alpha_store, n_support, terms, groups, amplitude, real,
               window_config, rate, t: Target) -> dict[str, int]:
    """RAM by part (bytes) of a model on the device build (see :func:`device_budget`)."""
    from eskin import _core

    taxels = rows * cols
    if hasattr(window_config, "to_array"):  # a WindowConfig (its words as the core's codes)
        values = np.asarray(window_config.to_array(), dtype=float)
    else:  # a compiled model's numeric fields
        values = np.array([window_config[k] for k in _core.WINDOW_CONFIG_FIELDS], dtype=float)
    p = _core.window_config_resolve(values, float(rate))
    ring = p["pad_before"] + (p["lookback_frames"] + 1) * p["frame_len"]
    # the window buffer: window_samples kept samples (the bounded window), or max_window when 0
    samples = (ring + p["window_capacity"]) * taxels * 2
    detector = 2 * (2 * p["noise_frames"] + max(1, p["lookback_frames"]) + 2 * taxels) * 8
    size = taxels * D
    dims = (rows, cols, D)
    n_of = [size // d for d in dims]
    q = [min(d, n) for d, n in zip(dims, n_of)]
    bases = sum(n * a for n, a in zip(n_of, alpha_store))
    workspace = (
        size * 8 + bases * real + 2 * size * 4 + 2 * max(q) ** 2 * 4 + max(n_of) * 4 + 16 * 64
    )
    tables = groups * n_support * 3 * 4 + n_support * 3 * 4 + terms * 12
    if amplitude:
        tables += n_support * (8 + 4)
    return {
        "detector samples": int(samples),
        "detector state": int(detector),
        "input workspace": int(workspace),
        "model tables": int(tables + _MALLOC_OVERHEAD),
        "statics and stack": int(t.program_ram_bytes),
    }


def window_for_budget(
    budget: Budget, grid_shape, rate: float, window_config: Any, D_min: int = 20,
    n_support: int = 100,
) -> tuple[Any, str | None]:
    """The detector settings whose raw-sample buffers leave room for a model in the budget's
    RAM: ``window_config`` itself when it does, else with ``max_window_s`` lowered (in 0.01 s
    steps, not below what pad_before_s and lookback_s need) until the detector and the smallest
    model the search may choose (D ``D_min``, alpha 1, ``n_support`` support vectors) fit; the
    search then keeps only the models that fit beside it. (settings, a note on what was
    lowered, or None)."""
    from eskin.signal.preprocess import WindowConfig

    cfg = window_config if isinstance(window_config, WindowConfig) else (
        WindowConfig() if window_config is None else WindowConfig.from_dict(dict(window_config)))
    rows, cols = (int(v) for v in grid_shape)
    alphas = _stored_alphas(grid_shape, D_min, "1")

    def ram(c) -> int:
        return sum(_ram_terms(rows, cols, D_min, alphas, n_support, 3 * n_support, 1, True, 4,
                              c, rate, budget.target).values())

    if ram(cfg) <= budget.ram_bytes:
        return cfg, None
    from dataclasses import replace

    new = cfg
    if getattr(cfg, "window_samples", 0):  # a bounded window: fewer kept samples per taxel
        while new.window_samples > 128 and ram(new) > budget.ram_bytes:
            new = replace(new, window_samples=int(new.window_samples) // 2)
        what = f"window_samples {cfg.window_samples} -> {new.window_samples}"
    else:  # the whole window is kept: a shorter longest window
        step = 0.01
        floor = cfg.pad_before_s + cfg.lookback_s + 2 * cfg.frame_s
        while new.max_window_s - step >= floor and ram(new) > budget.ram_bytes:
            new = replace(new, max_window_s=round(new.max_window_s - step, 6))
        what = f"max_window_s {cfg.max_window_s:g} s -> {new.max_window_s:g} s"
    if ram(new) > budget.ram_bytes:
        raise ValueError(
            f"the detector's buffers alone exceed the RAM budget ({budget.ram_bytes} B) at "
            f"{rate:g} Hz on {rows}x{cols} taxels: raise the budget"
        )
    return new, (f"the detector's raw-sample buffers must leave room for a model: {what} to "
                 f"fit {budget.describe()}")


#: The share of the instruction budget the search leaves free for the cost model's error: it is
#: within 4 % on the tensor-SVMs with alpha above 1 it is fitted to (up to 7 % on the others),
#: and a model estimated at the budget counted 1.494 M of 1.5 M on QEMU.
INSTRUCTION_MARGIN = 0.05


def candidate_budget(
    budget: Budget, grid_shape, rate: float, window_config: Any, n_classes: int,
    max_support: int | None = None,
) -> Any:
    """The :class:`~eskin.learn.recipes.CandidateBudget` of a budget: a candidate fits when
    its estimated flash, RAM and instructions (:func:`estimate_model`, with its expected
    support vectors, at most ``max_support`` when the model will be bounded to that many) are
    within the budget, the instructions :data:`INSTRUCTION_MARGIN` under it. Without
    ``max_support`` the search may also bound a candidate itself: ``largest`` gives the most
    support vectors with which its model still fits."""
    from eskin.learn.recipes import CandidateBudget

    machines = 1 if n_classes == 2 else n_classes

    @functools.lru_cache(maxsize=None)
    def fit_of(D: int, alpha: str, amplitude: bool, n_support: int) -> bool:
        alphas = _stored_alphas(grid_shape, D, alpha)
        est = estimate_model(budget, grid_shape, D, alphas, n_support, machines, amplitude,
                             window_config, rate)
        return (est["flash"] <= budget.flash_bytes and est["ram"] <= budget.ram_bytes
                and est["instructions"] <= budget.instructions * (1 - INSTRUCTION_MARGIN))

    def fit_at(candidate, n_support: int) -> bool:
        # what the estimate depends on (the grid's lambda and sigma do not enter it)
        return fit_of(int(candidate.recipe.D), candidate.alpha, candidate.amplitude is not None,
                      int(n_support))

    def fits(candidate, n_support: int) -> bool:
        if max_support is not None:
            n_support = min(int(n_support), int(max_support))
        return fit_at(candidate, n_support)

    def largest(candidate, n_support: int) -> int:
        """The most support vectors (at most ``n_support``) with which the model fits; 0 when
        not even one does (the estimates grow with the count: bisection)."""
        if fit_at(candidate, n_support):
            return int(n_support)
        lo, hi = 0, int(n_support)  # fit_at(lo) or lo == 0; not fit_at(hi)
        while hi - lo > 1:
            mid = (lo + hi) // 2
            lo, hi = (mid, hi) if fit_at(candidate, mid) else (lo, mid)
        return lo

    return CandidateBudget(fits, budget.describe(),
                           largest=largest if max_support is None else None)


def training_budget(
    budget: Budget, grid_shape, rate: float, window_config: Any, n_classes: int,
    max_support: int | None = None,
) -> tuple[Any, Any, str | None]:
    """What ``eskin train --target/--budget`` gives the recipe search: (the detector settings
    that leave room for a model, :func:`window_for_budget`; the :class:`CandidateBudget` of the
    candidates beside them, :func:`candidate_budget`; the note on what was lowered, or None)."""
    config, note = window_for_budget(budget, grid_shape, rate, window_config)
    return (config, candidate_budget(budget, grid_shape, rate, config, n_classes, max_support),
            note)


def model_fits(model_bytes: bytes, budget: Budget) -> tuple[bool, dict[str, float]]:
    """Whether a compiled model fits the budget: flash and RAM from :func:`device_budget`,
    instructions from the cost model; (fits, the three figures)."""
    from eskin.deploy.export import CompiledModel

    cm = CompiledModel(model_bytes)
    b = device_budget(cm, budget.target)
    instr = decision_instructions(cm.grid_shape, cm.D, tuple(cm.alpha_store), cm.n_support,
                                  bool(cm.sv_log_energy.size), _bounded(cm.window_config))
    figures = {"flash": b.flash_total, "ram": b.ram_total, "instructions": instr}
    return (b.flash_total <= budget.flash_bytes and b.ram_total <= budget.ram_bytes
            and instr <= budget.instructions), figures
