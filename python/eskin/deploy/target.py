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

from dataclasses import dataclass, field, replace
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
    "instruction_counts",
    "instruction_margin",
    "instruction_model_error",
    "parse_budget",
    "program_image",
    "window_for_budget",
]


@dataclass(frozen=True)
class Target:
    """A controller class: its memories, and the program around the model (its clock is in the
    description: a decision's budget is counted in instructions)."""

    name: str
    description: str
    flash_bytes: int
    ram_bytes: int
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
        ws = int(cm.window_config["window_samples"])  # 0 in files before version 3
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

def instruction_counts(target: str = "cortex-m4") -> list[dict[str, Any]]:
    """The QEMU counts the cost model is fitted to (Cortex-M4F, mps2-an386, -icount shift=0),
    shipped as ``cortex_m4_counts.json`` and written by ``benchmarks/bench_device_budget.py
    --write``: per model its grid, rate, D, support vectors, alpha_store, amplitude factor,
    bounded detector window, machines, and the instructions of the push that ends a touch (the
    median over the run's decisions, ``instr_median``, and the largest, ``instr_max``, where it
    was recorded; the earlier 4x4 tables of docs/mcu.md recorded the median only)."""
    from importlib.resources import files

    name = target.replace("-", "_") + "_counts.json"
    return list(json.loads(files("eskin.deploy").joinpath(name).read_text())["counts"])


#: the fitted counts as (grid, D, support vectors, alpha_store, amplitude, bounded window,
#: kernel terms, median instructions) rows (the counts of :func:`instruction_counts` whose
#: kernel terms were recorded)
INSTRUCTION_CALIBRATION = tuple(
    (tuple(c["grid"]), int(c["D"]), int(c["n_support"]), tuple(c["alpha_store"]),
     bool(c["amplitude"]), bool(c["bounded_window"]), int(c["terms"]), float(c["instr_median"]))
    for c in instruction_counts() if c.get("terms") is not None)


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
                          bounded_window=True, terms=None) -> np.ndarray:
    """What a decision's work grows with: a constant and the taxels (the rest of the push: the
    detector's step), the tensor's size (taxels x D: the window's subsampling and the input's
    log energy), the QR of each mode's unfolding (sum_z L_z q_z^2, L and q its long and short
    side), the input's bases beyond it (:func:`_basis_terms`), the support vectors, the inner
    loops of their overlaps (:func:`overlap_instructions` per support vector, N_z the length of
    a mode-z basis vector), with the amplitude factor one more exponential per support vector,
    the machines' kernel terms (``terms``; None: every support vector in each of 3 machines),
    and with the bounded window a term in the tensor's size (the subsampling of the touch from
    the bounded buffer: fitted)."""
    dims = (int(grid_shape[0]), int(grid_shape[1]), int(D))
    size = dims[0] * dims[1] * dims[2]
    n_of = [size // d for d in dims]
    qr = float(sum(max(m, n) * min(m, n) ** 2 for m, n in zip(dims, n_of)))
    jacobi, columns = _basis_terms(dims, alphas)
    per_sv = sum(overlap_instructions(n, a) for n, a in zip(n_of, alphas))
    terms = 3 * n_support if terms is None else terms
    return np.array([1.0, dims[0] * dims[1], size, qr, jacobi, columns, n_support,
                     n_support * per_sv, n_support * float(bool(amplitude)), float(terms),
                     size * float(bool(bounded_window))], dtype=float)


def _features_of(c: dict[str, Any]) -> np.ndarray:
    return _instruction_features(c["grid"], c["D"], tuple(c["alpha_store"]), c["n_support"],
                                 c["amplitude"], c["bounded_window"], c["terms"])


def _fit(counts: list[dict[str, Any]]) -> np.ndarray:
    A = np.array([_features_of(c) for c in counts])
    y = np.array([float(c["instr_median"]) for c in counts])
    # each count weighed by its inverse: least squares on the relative error
    w = 1.0 / y
    return np.linalg.lstsq(A * w[:, None], y * w, rcond=None)[0]


#: the counts the model is fitted to: those whose kernel terms were recorded
_COUNTS = [c for c in instruction_counts() if c.get("terms") is not None]
_COEF = _fit(_COUNTS)


def decision_instructions(
    grid_shape, D: int, alphas, n_support: int, amplitude: bool = False,
    bounded_window: bool = True, terms: int | None = None,
) -> float:
    """Estimated Cortex-M4F instructions of one decision (least squares on the relative error
    of :func:`instruction_counts`; its error: :func:`instruction_model_error`; the bound is
    this times 1 + :func:`instruction_margin`); ``amplitude``: the machines have the amplitude
    factor; ``bounded_window``: the detector keeps the bounded window (``window_samples`` > 0,
    the default); ``terms``: the machines' kernel terms (None: every support vector in each of
    3 machines, the most a 3-class model has)."""
    return float(_instruction_features(grid_shape, D, tuple(alphas), n_support, amplitude,
                                       bounded_window, terms) @ _COEF)


def _bounded(window_config: Any) -> bool:
    """Whether a window configuration (a WindowConfig, a compiled model's fields, or None for
    the default) keeps the bounded window."""
    if window_config is None:
        return True
    if isinstance(window_config, dict):
        return float(window_config.get("window_samples", 0)) > 0
    return float(window_config.window_samples) > 0


def _observed(c: dict[str, Any]) -> float:
    """A count's largest decision where recorded, else its median."""
    return float(c["instr_max"] if c.get("instr_max") else c["instr_median"])


@functools.lru_cache(maxsize=None)
def _left_out() -> tuple[tuple[float, float], ...]:
    """(estimate of each count by the model fitted without it, the same without its grid)."""
    out = []
    for i, c in enumerate(_COUNTS):
        coef = _fit(_COUNTS[:i] + _COUNTS[i + 1:])
        others = [d for d in _COUNTS if tuple(d["grid"]) != tuple(c["grid"])]
        grid_est = float("nan")
        if len(others) >= len(_COEF):
            grid_est = float(_features_of(c) @ _fit(others))
        out.append((float(_features_of(c) @ coef), grid_est))
    return tuple(out)


def instruction_margin() -> float:
    """The cost model's margin: the largest left-out under-estimate of a decision over the
    counts, ``max(observed / estimate_without_it - 1)``, the observed figure being a run's
    largest decision where it was recorded (else its median) and the estimate that of the
    model fitted without that count. A model fits when ``estimate x (1 + margin)`` does."""
    return max(0.0, max(_observed(c) / est - 1.0 for c, (est, _) in zip(_COUNTS, _left_out())))


def instruction_model_error() -> dict[str, Any]:
    """The cost model's relative error on the QEMU counts (estimate / median - 1): the largest
    in sample, the largest when each count is predicted by the model fitted without it, the
    same per grid, and per grid when the model is fitted without any count of that grid (nan
    where the other grids' counts are too few to fit); the margin, and how many counts."""
    fit_err, loo = [], []
    per_grid: dict[str, float] = {}
    grid_out: dict[str, float | None] = {}
    for c, (est, g_est) in zip(_COUNTS, _left_out()):
        y = float(c["instr_median"])
        fit_err.append(abs(float(_features_of(c) @ _COEF) - y) / y)
        loo.append(abs(est - y) / y)
        g = "x".join(str(v) for v in c["grid"])
        per_grid[g] = max(per_grid.get(g, 0.0), abs(est - y) / y)
        if np.isnan(g_est):  # too few counts of the other grids to fit without this one
            grid_out.setdefault(g, None)
        else:
            grid_out[g] = max(grid_out.get(g, 0.0), abs(g_est - y) / y)
    return {"max_fit": max(fit_err), "max_leave_one_out": max(loo), "points": len(_COUNTS),
            "leave_one_out_by_grid": per_grid, "leave_grid_out": grid_out,
            "margin": instruction_margin()}


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
              "instr": TARGET_INSTRUCTIONS[base.name]}
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
    t = replace(base, name=name, flash_bytes=int(values["flash"]), ram_bytes=int(values["ram"]))
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
                                              _bounded(window_config), terms),
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
    RAM: ``window_config`` itself when it does, else with a bounded window's ``window_samples``
    halved (to even counts, down to 128) or a whole window's ``max_window_s`` lowered (in 0.01 s
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
            half = int(new.window_samples) // 4 * 2  # an even count, as the detector needs
            new = replace(new, window_samples=max(128, half))
        what = f"window_samples {int(cfg.window_samples)} -> {int(new.window_samples)}"
    else:  # the whole window is kept: a shorter longest window
        step = 0.01
        # (to the microsecond: 0.1 + 0.2 + 2 * 0.01 is 0.32000000000000006 in binary)
        floor = round(cfg.pad_before_s + cfg.lookback_s + 2 * cfg.frame_s, 6)
        while round(new.max_window_s - step, 6) >= floor and ram(new) > budget.ram_bytes:
            new = replace(new, max_window_s=round(new.max_window_s - step, 6))
        what = f"max_window_s {cfg.max_window_s:g} s -> {new.max_window_s:g} s"
    if ram(new) > budget.ram_bytes:
        raise ValueError(
            f"the detector's buffers alone exceed the RAM budget ({budget.ram_bytes} B) at "
            f"{rate:g} Hz on {rows}x{cols} taxels: raise the budget"
        )
    return new, (f"the detector's raw-sample buffers must leave room for a model: {what} to "
                 f"fit {budget.describe()}")


#: The cost model's margin (:func:`instruction_margin`): a candidate or a model fits the
#: instruction budget when its estimate times (1 + INSTRUCTION_MARGIN) does.
INSTRUCTION_MARGIN = instruction_margin()


def candidate_budget(
    budget: Budget, grid_shape, rate: float, window_config: Any, n_classes: int,
    max_support: int | None = None,
) -> Any:
    """The :class:`~eskin.learn.recipes.CandidateBudget` of a budget: a candidate fits when
    its estimated flash, RAM and instructions (:func:`estimate_model`, with its expected
    support vectors, at most ``max_support`` when the model will be bounded to that many) are
    within the budget, the instructions times (1 + :data:`INSTRUCTION_MARGIN`). Without
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
                and est["instructions"] * (1 + INSTRUCTION_MARGIN) <= budget.instructions)

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
    instructions from the cost model with its margin; (fits, the figures: ``instructions`` is
    the bound, estimate x (1 + :data:`INSTRUCTION_MARGIN`), ``estimate`` the estimate)."""
    from eskin.deploy.export import CompiledModel

    cm = CompiledModel(model_bytes)
    b = device_budget(cm, budget.target)
    instr = decision_instructions(cm.grid_shape, cm.D, tuple(cm.alpha_store), cm.n_support,
                                  bool(cm.sv_log_energy.size), _bounded(cm.window_config),
                                  sum(len(m["coef"]) for m in cm.machines))
    bound = instr * (1 + INSTRUCTION_MARGIN)
    figures = {"flash": b.flash_total, "ram": b.ram_total, "instructions": bound,
               "estimate": instr}
    return (b.flash_total <= budget.flash_bytes and b.ram_total <= budget.ram_bytes
            and bound <= budget.instructions), figures
