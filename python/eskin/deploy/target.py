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

from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["TARGETS", "DeviceBudget", "Target", "device_budget"]


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


TARGETS: dict[str, Target] = {
    "cortex-m4": Target(
        name="cortex-m4",
        description="Cortex-M4F, STM32F4 class: 1 MB flash, 128 KB RAM, 168 MHz",
        flash_bytes=1 << 20,
        ram_bytes=128 << 10,
        clock_hz=168e6,
        # the `make mcu` program without its model (core, newlib-nano with printf, semihosting)
        program_flash_bytes=116 << 10,
        program_ram_bytes=(3 << 10) + (8 << 10),
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
    from eskin import _core
    from eskin.deploy.export import CompiledModel

    if isinstance(target, str) and target not in TARGETS:
        raise ValueError(f"unknown target {target!r} (known: {', '.join(TARGETS)})")
    t = TARGETS[target] if isinstance(target, str) else target
    cm = model if isinstance(model, CompiledModel) else CompiledModel(model)
    rows, cols = cm.grid_shape
    taxels, D = rows * cols, cm.D
    real = 8 if cm.is_float64 else 4
    p = _core.window_config_resolve(
        np.array([cm.window_config[k] for k in _core.WINDOW_CONFIG_FIELDS]), cm.sample_rate_hz
    )
    ring = p["pad_before"] + (p["lookback_frames"] + 1) * p["frame_len"]
    # the window buffer: window_samples kept samples (the bounded window), or max_window when 0
    samples = (ring + p["window_capacity"]) * taxels * 2
    detector = 2 * (2 * p["noise_frames"] + max(1, p["lookback_frames"]) + 2 * taxels) * 8
    size = taxels * D
    dims = (rows, cols, D)
    n_of = [size // d for d in dims]
    q = [min(d, n) for d, n in zip(dims, n_of)]
    bases = sum(n * a for n, a in zip(n_of, cm.alpha_store))
    machines = cm.machines
    groups = len({tuple(m["alphas"]) for m in machines})
    terms = sum(len(m["coef"]) for m in machines)
    workspace = (
        size * 8 + bases * real + 2 * size * 4 + 2 * max(q) ** 2 * 4 + max(n_of) * 4 + 16 * 64
    )
    tables = groups * cm.n_support * 3 * 4 + cm.n_support * 3 * 4 + terms * 12
    if cm.sv_log_energy.size:
        # the amplitude factor: the support vectors' log energies (double) and the classifier's
        # squared gaps to the input's (float)
        tables += cm.n_support * (8 + 4)
    flash = {"model": cm.file_bytes, "program": t.program_flash_bytes}
    ram = {
        "detector samples": samples,
        "detector state": detector,
        "input workspace": workspace,
        "model tables": tables + _MALLOC_OVERHEAD,
        "statics and stack": t.program_ram_bytes,
    }
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
