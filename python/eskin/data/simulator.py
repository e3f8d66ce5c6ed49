"""A physics-based simulator of the paper's e-skin and of its 70-participant campaign.

Everything here is SIMULATED data: files written by :func:`simulate` carry ``source="simulated"``
and every report built on them must say so. ``docs/simulator.md`` gives the model, its
assumptions with their sources and figures, and the calibration of ``difficulty``.

The chain, per recording (sample-exact and seeded):

1. a stimulus (finger, paintbrush or washer) as a set of elliptical contacts, each with a
   normal force F_c(t) and a centre moving along a horizontal or vertical line;
2. the contact stress spread through the 2 mm PDMS layer (a Gaussian of width ~ thickness, the
   Boussinesq point-load spread) and integrated over each of the 16 square electrodes (analytic
   erf integrals): the normal force on taxel (i, j);
3. PVDF charge Q = d33 F, charge amplifier V = Q / C_f, the band-pass of the front end
   (CA high-pass 2.5 Hz, BPF 0.3 Hz - 1.5 kHz), simulated at 2x the DAQ rate and then sampled at
   3000 samples/s (no anti-alias filter beyond the 1.5 kHz low-pass, as on the DAQ board);
4. amplifier noise, mains hum, drift, taxel gain mismatch, a dead or noisy taxel at a low rate;
5. a 16-bit ADC with clipping, stored as int16 counts.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy import signal as sps
from scipy.special import erf

MODALITIES = ("brush", "finger", "washer")
#: every gesture the simulator can make: the paper's three, and a press-and-hold (a fingertip
#: pressed down, held still, released; see docs/simulator.md)
GESTURES = (*MODALITIES, "press")
BRUSH, FINGER, WASHER, PRESS = 0, 1, 2, 3

# the calibrated difficulty: the default of simulate() and SimulatorConfig
DEFAULT_DIFFICULTY = 1.0
# variability level at difficulty 1: the scale found by benchmarks/calibrate_simulator.py so that
# the paper's protocol lands in the paper's error ranges (docs/simulator.md, "Calibration")
CALIBRATED_LEVEL = 0.9


@dataclass(frozen=True)
class SimulatorConfig:
    """Every number of the simulated chain (units in the names). See docs/simulator.md."""

    # --- campaign and acquisition (paper, Sections 2 and 5.1)
    sample_rate_hz: float = 3000.0
    duration_s: float = 7.0
    oversample: int = 2  # analog part simulated at oversample * sample_rate_hz
    # --- sensor geometry (paper: 7 cm PVDF disc, 16 square electrodes, 2 mm PDMS)
    rows: int = 4
    cols: int = 4
    disc_diameter_mm: float = 70.0
    electrode_mm: float = 8.0  # assumed (not given in the paper)
    pitch_mm: float = 12.0  # assumed: the 4x4 grid spans 44 mm, inside the 70 mm disc
    pdms_thickness_mm: float = 2.0
    spread_per_thickness: float = 0.48  # Gaussian sigma / depth of the Boussinesq spread
    # --- transduction and front end
    d33_pc_per_n: float = 33.0  # |d33| of MEAS PVDF film
    feedback_pf: float = 22.0  # charge-amplifier feedback capacitance (assumed)
    ca_highpass_hz: float = 2.5
    bpf_highpass_hz: float = 0.3
    bpf_lowpass_hz: float = 1500.0
    adc_bits: int = 16
    adc_range_v: float = 5.0  # +-range of the ADC
    # --- noise and faults
    amp_noise_v: float = 0.5e-3  # rms at the amplifier output
    adc_noise_lsb: float = 0.7
    mains_hz: float = 50.0
    hum_v_min: float = 0.2e-3
    hum_v_max: float = 3.0e-3
    drift_v: float = 3.0e-3
    gain_mismatch: float = 0.12  # lognormal sigma of the per-taxel sensitivity
    p_dead_taxel: float = 0.01  # per recording
    p_noisy_taxel: float = 0.02  # per recording
    # --- participants' style (lognormal sigmas are scaled by the difficulty)
    style_force_sigma: float = 0.45
    style_speed_sigma: float = 0.40
    gesture_jitter_sigma: float = 0.15
    practice_jitter_factor: float = 1.8  # run 1 is more variable
    onset_min_s: float = 0.3
    onset_max_s: float = 2.2
    tremor_min: float = 0.01
    tremor_max: float = 0.05
    # --- finger sliding
    finger_force_n: float = 1.2
    finger_speed_mm_s: float = 80.0
    finger_semi_axis_mm: float = 8.5  # pad contact semi-axis at 1 N (grows as F^(1/3), Hertz)
    finger_aspect: float = 0.7
    ridge_pitch_mm: float = 0.5
    ridge_depth: float = 0.06  # relative normal-force modulation by the ridges
    stick_slip_rate_hz: float = 8.0  # relaxation oscillation of skin on PDMS at 60 mm/s
    stick_slip_depth: float = 0.4  # relative normal-force swing of one stick-slip cycle
    # --- paintbrush brushing
    brush_force_n: float = 0.25
    brush_speed_mm_s: float = 150.0
    brush_width_mm: float = 22.0
    brush_footprint_mm: float = 8.0
    brush_bristle_groups: int = 8
    brush_bristle_depth: float = 1.0  # relative broadband force fluctuation per group
    brush_band_hz: tuple[float, float] = (15.0, 1200.0)
    # --- washer rolling (a steel washer rolled on its rim)
    washer_force_n: float = 1.5
    washer_speed_mm_s: float = 22.0
    washer_diameter_mm: float = 20.0
    washer_thickness_mm: float = 1.6
    washer_contact_mm: float = 2.0  # Hertz half-width along the rolling direction
    washer_runout: float = 0.12  # once-per-revolution force modulation
    washer_defects: tuple[tuple[float, float], ...] = (
        (0.4, 0.45), (1.9, 0.25), (3.3, 0.6), (5.1, 0.3))  # (angle rad, relative height)
    washer_defect_mm: float = 0.4
    # --- press-and-hold (the "press" gesture): a fingertip pressed, held still, released
    press_force_n: float = 2.0
    press_rise_s: float = 0.15  # the press, minimum-jerk
    press_hold_s: float = 0.5  # held still: a piezo sensor sees (almost) nothing
    press_release_s: float = 0.1
    press_tremor: float = 0.1  # tremor while holding, relative to the participant's sliding one
    # --- the gestures recorded, in campaign order (names of GESTURES)
    modalities: tuple[str, ...] = MODALITIES
    # --- atypical gestures (probability per participant and modality, scaled by difficulty)
    p_brush_pressed: float = 0.07
    p_finger_tip: float = 0.10
    p_finger_feather: float = 0.05
    p_washer_flat: float = 0.10
    # --- the single knob: 0 = clean and well separated, 1 = calibrated, 2 = harder
    difficulty: float = DEFAULT_DIFFICULTY

    def __post_init__(self) -> None:
        for name in ("sample_rate_hz", "duration_s", "electrode_mm", "pitch_mm",
                     "pdms_thickness_mm", "d33_pc_per_n", "feedback_pf", "adc_range_v"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"SimulatorConfig.{name} must be positive, got {v!r}")
        if not (math.isfinite(self.difficulty) and 0 <= self.difficulty <= 5):
            raise ValueError(f"SimulatorConfig.difficulty must be in [0, 5], got {self.difficulty}")
        if self.rows < 1 or self.cols < 1:
            raise ValueError(f"grid must be at least 1x1, got {self.rows}x{self.cols}")
        if self.oversample < 1:
            raise ValueError(f"oversample must be >= 1, got {self.oversample}")
        if not 2 <= self.adc_bits <= 16:
            raise ValueError(f"adc_bits must be in [2, 16] (stored as int16), got {self.adc_bits}")
        unknown = [m for m in self.modalities if m not in GESTURES]
        if unknown or not self.modalities or len(set(self.modalities)) != len(self.modalities):
            raise ValueError(f"SimulatorConfig.modalities = {self.modalities!r}: distinct names "
                             f"of {GESTURES}, at least one")
        for name in ("press_rise_s", "press_hold_s", "press_release_s", "press_force_n"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"SimulatorConfig.{name} must be positive, got {v!r}")
        if self.electrode_mm > self.pitch_mm:
            raise ValueError("electrode_mm must not exceed pitch_mm (electrodes would overlap)")
        nyq = self.sample_rate_hz * self.oversample / 2
        if not 0 < self.ca_highpass_hz < nyq or not 0 < self.bpf_highpass_hz < nyq:
            raise ValueError("high-pass corners must lie between 0 and the simulation Nyquist")
        if not 0 < self.bpf_lowpass_hz < nyq:
            raise ValueError(
                f"bpf_lowpass_hz must be below {nyq} Hz (oversample * rate / 2), "
                f"got {self.bpf_lowpass_hz}")

    @property
    def level(self) -> float:
        """The variability multiplier used by the model: difficulty x CALIBRATED_LEVEL."""
        return self.difficulty * CALIBRATED_LEVEL

    @property
    def n_samples(self) -> int:
        return int(round(self.duration_s * self.sample_rate_hz))

    @property
    def volts_per_count(self) -> float:
        return self.adc_range_v / 2 ** (self.adc_bits - 1)

    def to_json(self) -> str:
        return json.dumps(dataclasses.asdict(self), sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> SimulatorConfig:
        d = json.loads(text)
        for k in ("brush_band_hz", "modalities"):
            if k in d:
                d[k] = tuple(d[k])
        if "washer_defects" in d:
            d["washer_defects"] = tuple(tuple(x) for x in d["washer_defects"])
        return cls(**d)


def acquisition_config(config: SimulatorConfig | None = None, *,
                       grid: tuple[int, int] | None = None, rate_hz: float | None = None,
                       duration_s: float | None = None,
                       modalities: tuple[str, ...] | None = None) -> SimulatorConfig:
    """``config`` (default the paper's) with another grid, rate, duration or gestures.

    A grid keeps the paper's sensed area (the 4 x 4 electrodes' 44 mm span, 8 mm electrodes at
    12 mm pitch): its pitch and electrodes scale by 4 / max(rows, cols). A rate whose
    simulation Nyquist (``oversample`` x rate / 2) is not above the front end's 1.5 kHz low-pass
    moves the low-pass to 0.8 of that Nyquist (the DAQ's anti-alias filter)."""
    cfg = config or SimulatorConfig()
    changes: dict[str, Any] = {}
    if grid is not None:
        rows, cols = (int(v) for v in grid)
        if not (1 <= rows <= 255 and 1 <= cols <= 255):
            raise ValueError(f"grid {rows}x{cols}: rows and columns must be in 1..255")
        scale = 4.0 / max(rows, cols)
        changes.update(rows=rows, cols=cols, pitch_mm=12.0 * scale, electrode_mm=8.0 * scale)
    if rate_hz is not None:
        if not (math.isfinite(rate_hz) and 10.0 <= rate_hz <= 100_000.0):
            raise ValueError(f"rate {rate_hz:g} Hz: must be in [10, 100000] Hz")
        nyq = float(rate_hz) * cfg.oversample / 2
        changes.update(sample_rate_hz=float(rate_hz),
                       bpf_lowpass_hz=min(cfg.bpf_lowpass_hz, 0.8 * nyq))
    if duration_s is not None:
        if not (math.isfinite(duration_s) and 1.0 <= duration_s <= 60.0):
            raise ValueError(f"duration {duration_s:g} s: must be in [1, 60] s")
        changes["duration_s"] = float(duration_s)
    if modalities is not None:
        changes["modalities"] = tuple(str(m) for m in modalities)
    return dataclasses.replace(cfg, **changes)


# --------------------------------------------------------------------------- styles


@dataclass
class ParticipantStyle:
    """How one simulated participant touches: drawn once per participant."""

    force: np.ndarray  # per modality force multiplier
    speed: np.ndarray  # per modality speed multiplier
    onset_s: float
    forward: tuple[bool, bool]  # travels +u on horizontal / vertical lines
    tilt_rad: float
    finger_size: float
    ridge_pitch: float
    tremor: float
    tremor_hz: float
    brush_strokes: int
    atypical: dict[str, bool] = field(default_factory=dict)


def _participant_style(cfg: SimulatorConfig, rng: np.random.Generator) -> ParticipantStyle:
    d = cfg.level
    common_f = rng.normal(0.0, cfg.style_force_sigma * d)
    common_v = rng.normal(0.0, cfg.style_speed_sigma * d)
    force = np.exp(common_f + rng.normal(0.0, 0.5 * cfg.style_force_sigma * d, 3))
    speed = np.exp(common_v + rng.normal(0.0, 0.5 * cfg.style_speed_sigma * d, 3))
    atyp_p = {"brush_pressed": cfg.p_brush_pressed, "finger_tip": cfg.p_finger_tip,
              "finger_feather": cfg.p_finger_feather, "washer_flat": cfg.p_washer_flat}
    draws = rng.random(4)
    atypical = {k: bool(u < min(1.0, p * d)) for (k, p), u in zip(atyp_p.items(), draws)}
    if atypical["finger_tip"] and atypical["finger_feather"]:
        atypical["finger_feather"] = False
    return ParticipantStyle(
        force=force, speed=speed,
        onset_s=float(rng.uniform(cfg.onset_min_s, cfg.onset_max_s)),
        forward=(bool(rng.random() < 0.85), bool(rng.random() < 0.8)),
        tilt_rad=float(rng.normal(0.0, math.radians(3.0) * max(d, 0.2))),
        finger_size=float(np.exp(rng.normal(0.0, 0.12 * max(d, 0.1)))),
        ridge_pitch=float(cfg.ridge_pitch_mm * np.exp(rng.normal(0.0, 0.1))),
        tremor=float(rng.uniform(cfg.tremor_min, cfg.tremor_max)),
        tremor_hz=float(rng.uniform(7.0, 12.0)),
        brush_strokes=int(rng.choice([1, 2, 3, 4], p=[0.25, 0.35, 0.25, 0.15])),
        atypical=atypical,
    )


# --------------------------------------------------------------------------- signal helpers


def _smoothstep(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * x * (10 - 15 * x + 6 * x * x)  # minimum-jerk profile


def _slow_noise(rng: np.random.Generator, n: int, fs: float, cutoff_hz: float) -> np.ndarray:
    """Unit-rms low-pass noise (for slow force and speed fluctuations)."""
    sos = sps.butter(2, cutoff_hz, "lowpass", fs=fs, output="sos")
    x = sps.sosfilt(sos, rng.standard_normal(n + int(fs / cutoff_hz)))[-n:]
    return x / (np.std(x) + 1e-12)


def _band_noise(rng: np.random.Generator, shape: tuple[int, int], fs: float,
                band: tuple[float, float]) -> np.ndarray:
    """Unit-variance noise in ``band`` (Hz), its upper edge kept below 0.45 fs (and the lower
    below half the upper) so that low sample rates keep what of the band they can hold."""
    high = min(float(band[1]), 0.45 * fs)
    low = min(float(band[0]), 0.5 * high)
    sos = sps.butter(2, (low, high), "bandpass", fs=fs, output="sos")
    x = sps.sosfilt(sos, rng.standard_normal(shape), axis=-1)
    return x / (np.std(x, axis=-1, keepdims=True) + 1e-12)


def _stick_slip(rng: np.random.Generator, n: int, fs: float, rate_hz: float
                ) -> tuple[np.ndarray, np.ndarray]:
    """Unit sawtooth of stick-slip (load up, slip) at ~rate_hz with jittered cycles, and the
    slip impulses (for the ringing that follows each slip)."""
    mean_iv = fs / max(rate_hz, 0.1)
    iv = rng.gamma(6.0, mean_iv / 6.0, int(n / mean_iv * 1.5) + 8)
    ev = np.cumsum(iv)
    ev = ev[ev < n]
    bounds = np.concatenate([[0.0], ev, [float(n)]])
    idx = np.arange(n)
    k = np.searchsorted(ev, idx, side="right")
    saw = (idx - bounds[k]) / np.maximum(bounds[k + 1] - bounds[k], 1.0) - 0.5
    imp = np.zeros(n)
    imp[ev.astype(np.int64)] = 1.0
    return saw, imp


def _electrode_weights(centre: np.ndarray, sigma: np.ndarray, pos: np.ndarray,
                       half: float) -> np.ndarray:
    """Fraction of a Gaussian (centre, sigma) line load falling on each electrode interval.

    centre, sigma: (..., k); pos: (m,) electrode centres. Returns (..., k, m).
    """
    s = np.sqrt(2.0) * sigma[..., None]
    c = centre[..., None]
    return 0.5 * (erf((pos + half - c) / s) - erf((pos - half - c) / s))


@dataclass
class _Contact:
    """One elliptical contact: force (n_fine,), offsets and sigmas in mm (scalars or (n_c,))."""

    force: np.ndarray
    along: float
    across: float
    sigma_along: float | np.ndarray
    sigma_across: float | np.ndarray


@dataclass
class RecordingTruth:
    """Ground truth of one simulated recording."""

    contact_interval: tuple[int, int]
    speed_mm_s: float
    force_n: float
    line_mm: float
    variant: str
    dead_taxel: int = -1
    noisy_taxel: int = -1
    clipped: bool = False


# --------------------------------------------------------------------------- press-and-hold


def _press_path(cfg: SimulatorConfig, rng: np.random.Generator, style: ParticipantStyle,
                jitter: float) -> dict[str, Any]:
    """Where and when a press-and-hold happens: a point on the grid, held still (the path of
    a stroke that does not move: ``t_move`` is the hold), timings jittered per recording."""
    half = min(max(cfg.rows, cfg.cols) * cfg.pitch_mm / 2, cfg.disc_diameter_mm / 2) * 0.6
    line, u = (float(v) for v in rng.uniform(-half, half, 2))
    t_press = cfg.press_rise_s * math.exp(rng.normal(0.0, 0.5 * jitter))
    t_hold = cfg.press_hold_s * math.exp(rng.normal(0.0, 0.5 * jitter))
    t_release = cfg.press_release_s * math.exp(rng.normal(0.0, 0.5 * jitter))
    # the envelope reaches full force 0.8 t_press after the onset and holds t_move from there
    fixed = 0.8 * t_press + t_hold + t_release
    onset = max(0.1, style.onset_s * math.exp(rng.normal(0.0, 0.5 * jitter + 0.1)))
    onset = min(onset, max(0.05, cfg.duration_s - 0.25 - fixed))
    return dict(line=line, u0=u, u1=u, speed=0.0, strokes=1, onset=onset, t_press=t_press,
                t_release=t_release, t_pause=0.0, t_move=t_hold)


def _press_envelope(cfg: SimulatorConfig, p: dict[str, Any], style: ParticipantStyle,
                    t: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Relative normal force of a press-and-hold: a minimum-jerk rise, a hold, a release. A
    finger resting on the skin trembles far less than one stroking it (``press_tremor`` of
    the participant's tremor), so the hold is quiet for a piezo sensor, which sees changes."""
    up = _smoothstep((t - p["onset"]) / p["t_press"])
    t_end = p["onset"] + 0.8 * p["t_press"] + p["t_move"]
    down = 1.0 - _smoothstep((t - t_end) / p["t_release"])
    tremor = cfg.press_tremor * style.tremor
    return up * down * (1.0 + tremor * np.sin(2 * np.pi * style.tremor_hz * t
                                                 + rng.uniform(0, 6.3)))


def _press_axes(cfg: SimulatorConfig, style: ParticipantStyle, force: float
                ) -> tuple[float, float]:
    """Contact sigmas (along, across) of a pressed fingertip: half a sliding pad's size."""
    a = 0.5 * cfg.finger_semi_axis_mm * style.finger_size * max(force, 0.05) ** (1 / 3)
    return a / 2.0, cfg.finger_aspect * a / 2.0


# --------------------------------------------------------------------------- the simulator


class _Chain:
    """The parts that do not change between recordings (filters, geometry, sensor gains)."""

    def __init__(self, cfg: SimulatorConfig, seed: int):
        self.cfg = cfg
        self.fs = cfg.sample_rate_hz
        self.fs_fine = cfg.sample_rate_hz * cfg.oversample
        self.n = cfg.n_samples
        self.n_fine = self.n * cfg.oversample
        # coarse kinematic grid: one point per block of `block` fine samples
        self.block = max(1, int(round(self.fs_fine / 500.0)))
        self.n_coarse = -(-self.n_fine // self.block)
        self.t_coarse = np.arange(self.n_coarse + 1) * self.block / self.fs_fine
        self.t_fine = np.arange(self.n_fine) / self.fs_fine
        self.x_pos = (np.arange(cfg.cols) - (cfg.cols - 1) / 2) * cfg.pitch_mm
        self.y_pos = ((cfg.rows - 1) / 2 - np.arange(cfg.rows)) * cfg.pitch_mm
        self.spread = cfg.spread_per_thickness * cfg.pdms_thickness_mm
        self.sensor = _Sensor(cfg, seed, self.fs_fine)

    # ---- kinematics
    def _path(self, rng: np.random.Generator, style: ParticipantStyle, modality: int,
              direction: int, jitter: float, variant: str) -> dict[str, Any]:
        cfg = self.cfg
        r_disc = cfg.disc_diameter_mm / 2
        grid_half = max(cfg.rows, cfg.cols) * cfg.pitch_mm / 2
        line = float(rng.uniform(-0.95, 0.95) * min(grid_half, r_disc * 0.7))
        u_lim = min(r_disc - 3.0, 0.95 * math.sqrt(max(r_disc**2 - line**2, 1.0)))
        u0 = -u_lim + rng.uniform(0.0, 8.0)
        u1 = u_lim - rng.uniform(0.0, 8.0)
        forward = style.forward[direction if direction in (0, 1) else 0]
        if rng.random() < 0.1 * cfg.level:
            forward = not forward
        if not forward:
            u0, u1 = u1, u0
        base_speed = {BRUSH: cfg.brush_speed_mm_s, FINGER: cfg.finger_speed_mm_s,
                      WASHER: cfg.washer_speed_mm_s}[modality]
        if variant == "finger_feather":
            base_speed *= 2.0
        speed = base_speed * style.speed[modality] * math.exp(rng.normal(0.0, jitter))
        strokes = style.brush_strokes if modality == BRUSH else 1
        if modality != BRUSH and rng.random() < 0.05 * cfg.level:
            strokes = 2  # an occasional back-and-forth
        length = abs(u1 - u0)
        t_press = float(rng.uniform(0.06, 0.25))
        t_release = float(rng.uniform(0.05, 0.2))
        t_pause = float(rng.uniform(0.04, 0.15))
        t_move = strokes * length / speed
        onset = max(0.1, style.onset_s * math.exp(rng.normal(0.0, 0.5 * jitter + 0.1)))
        budget = cfg.duration_s - 0.25
        fixed = t_press + t_release + (strokes - 1) * t_pause
        if onset + fixed + t_move > budget:  # hurry up to finish within the 7 s window
            t_move = max(0.3, budget - onset - fixed)
            if onset + fixed + t_move > budget:
                onset = max(0.05, budget - fixed - t_move)
        speed = strokes * length / t_move
        return dict(line=line, u0=u0, u1=u1, speed=speed, strokes=strokes, onset=onset,
                    t_press=t_press, t_release=t_release, t_pause=t_pause, t_move=t_move)

    def _along(self, p: dict[str, Any], t: np.ndarray, rng: np.random.Generator,
               jitter: float) -> np.ndarray:
        """Position along the line (mm) at times t: minimum-jerk strokes, back and forth."""
        u = np.full(t.shape, p["u0"], dtype=float)
        seg = p["t_move"] / p["strokes"]
        t_start = p["onset"] + 0.8 * p["t_press"]
        for k in range(p["strokes"]):
            a, b = (p["u0"], p["u1"]) if k % 2 == 0 else (p["u1"], p["u0"])
            t0 = t_start + k * (seg + p["t_pause"])
            # speed irregularity: a smooth monotone warp of the normalised time
            tau = np.clip((t - t0) / seg, 0.0, 1.0)
            wobble = 0.04 * (1 + jitter * 3) * np.sin(2 * np.pi * (tau * rng.uniform(1, 3))
                                                       + rng.uniform(0, 2 * np.pi))
            tau = np.clip(tau + wobble * tau * (1 - tau) * 4, 0.0, 1.0)
            inside = t >= t0
            u = np.where(inside, a + (b - a) * _smoothstep(tau), u)
        return u

    def _envelope(self, p: dict[str, Any], rng: np.random.Generator, style: ParticipantStyle,
                  slow_depth: float) -> np.ndarray:
        """Normal-force envelope (relative, 0..~1) on the fine grid, with tremor."""
        t = self.t_fine
        t0 = p["onset"]
        t_end_move = t0 + 0.8 * p["t_press"] + p["t_move"] + (p["strokes"] - 1) * p["t_pause"]
        up = _smoothstep((t - t0) / p["t_press"])
        down = 1.0 - _smoothstep((t - t_end_move) / p["t_release"])
        env = up * down
        slow = _slow_noise(rng, self.n_coarse + 1, 500.0, 2.0)
        env = env * (1.0 + slow_depth * np.interp(t, self.t_coarse, slow))
        env *= 1.0 + style.tremor * np.sin(2 * np.pi * style.tremor_hz * t + rng.uniform(0, 6.3))
        if p["strokes"] > 1:  # lighter touch at each turnaround
            seg = p["t_move"] / p["strokes"]
            for k in range(1, p["strokes"]):
                tc = t0 + 0.8 * p["t_press"] + k * seg + (k - 0.5) * p["t_pause"]
                env *= 1.0 - 0.6 * np.exp(-0.5 * ((t - tc) / (0.5 * p["t_pause"] + 0.02)) ** 2)
        return np.clip(env, 0.0, None)

    # ---- the three modalities
    def _finger(self, rng: np.random.Generator, style: ParticipantStyle, p: dict[str, Any],
                force: float, variant: str, speed_fine: np.ndarray,
                moving: np.ndarray) -> list[_Contact]:
        cfg = self.cfg
        env = self._envelope(p, rng, style, 0.12)
        a = cfg.finger_semi_axis_mm * style.finger_size * max(force, 0.05) ** (1 / 3)
        ridge_depth, ss_depth, ss_rate = cfg.ridge_depth, cfg.stick_slip_depth, cfg.stick_slip_rate_hz
        if variant == "finger_tip":  # fingertip and nail: a small, stiff contact
            a *= 0.45
            ridge_depth *= 0.3
            ss_depth *= 1.5
        elif variant == "finger_feather":  # a light, fast stroke with the fingertip
            a *= 0.6
            ss_rate *= 2.0
        fs = self.fs_fine
        # fingerprint ridges: f = v / pitch, phase-integrated
        phase = 2 * np.pi * np.cumsum(speed_fine) / fs / style.ridge_pitch
        phase += 0.3 * np.cumsum(rng.standard_normal(self.n_fine)) / math.sqrt(fs)
        ridge = ridge_depth * (0.7 + 0.3 * rng.random()) * np.sin(phase) * moving
        # stick-slip: a relaxation oscillation (slow loading, sudden slip, ringing); its rate
        # grows with sliding speed and force
        v_rel = max(p["speed"], 1.0) / 60.0
        rate = ss_rate * math.sqrt(v_rel) * (0.7 + 0.3 * min(force, 3.0))
        saw, slips = _stick_slip(rng, self.n_fine, fs, rate)
        f0 = rng.uniform(60.0, 160.0)
        r = math.exp(-1.0 / (0.008 * fs))
        ring = sps.lfilter([1.0 - r], [1.0, -2 * r * math.cos(2 * math.pi * f0 / fs), r * r],
                           slips)
        f_total = force * env * (1.0 + ridge + ss_depth * moving * (saw + 2.0 * ring))
        return [_Contact(f_total, 0.0, 0.0, a / 2.0, cfg.finger_aspect * a / 2.0)]

    def _brush(self, rng: np.random.Generator, style: ParticipantStyle, p: dict[str, Any],
               force: float, variant: str, moving: np.ndarray) -> list[_Contact]:
        cfg = self.cfg
        env = self._envelope(p, rng, style, 0.25)
        groups = max(1, cfg.brush_bristle_groups)
        width = cfg.brush_width_mm * math.exp(rng.normal(0.0, 0.15))
        foot = cfg.brush_footprint_mm * math.exp(rng.normal(0.0, 0.2))
        depth = cfg.brush_bristle_depth
        if variant == "brush_pressed":  # pressed hard: bristles splay and pin, less flicking
            force *= 4.0
            depth *= 0.3
            width *= 0.8
        noise = _band_noise(rng, (groups, self.n_fine), self.fs_fine, cfg.brush_band_hz)
        # bristle flicks: sparse sharp releases, independent per group
        flicks = (rng.random((groups, self.n_fine)) < 25.0 / self.fs_fine) * rng.exponential(
            2.0, (groups, self.n_fine))
        flicks = sps.lfilter([1.0], [1.0, -math.exp(-1.0 / (0.0015 * self.fs_fine))], flicks,
                             axis=-1)
        active = 0.4 + 0.6 * moving  # bristles fluctuate most while sliding
        offsets = (np.arange(groups) + 0.5) / groups - 0.5
        contacts = []
        for g in range(groups):
            fg = force / groups * env * np.clip(
                1.0 + depth * active * (noise[g] + 0.5 * flicks[g]), 0.0, None)
            contacts.append(_Contact(
                fg, float(rng.normal(0.0, foot / 4)), float(offsets[g] * width
                                                            + rng.normal(0.0, 0.5)),
                foot / 2.0, 0.5 * width / groups + 0.5))
        return contacts

    def _washer(self, rng: np.random.Generator, style: ParticipantStyle, p: dict[str, Any],
                force: float, variant: str, u_fine: np.ndarray,
                moving: np.ndarray) -> list[_Contact]:
        cfg = self.cfg
        env = self._envelope(p, rng, style, 0.15)
        radius = cfg.washer_diameter_mm / 2
        if variant == "washer_flat":  # slid flat on its face: a ring of contact, scraping
            ring = 6
            contacts = []
            noise = _band_noise(rng, (ring, self.n_fine), self.fs_fine, (30.0, 600.0))
            for k in range(ring):
                ang = 2 * np.pi * k / ring + rng.uniform(0, 0.5)
                fk = force / ring * env * np.clip(1 + 0.3 * moving * noise[k], 0.0, None)
                contacts.append(_Contact(fk, 0.75 * radius * math.cos(ang),
                                         0.75 * radius * math.sin(ang), 1.5, 1.5))
            return contacts
        travelled = np.abs(u_fine - u_fine[0])
        theta = travelled / radius + rng.uniform(0, 2 * np.pi)
        mod = 1.0 + cfg.washer_runout * np.sin(theta + rng.uniform(0, 6.3)) \
            + 0.3 * cfg.washer_runout * np.sin(2 * theta + rng.uniform(0, 6.3))
        rim = np.zeros(self.n_fine)
        w = cfg.washer_defect_mm / radius
        for ang, height in cfg.washer_defects:
            dist = np.angle(np.exp(1j * (theta - ang)))  # wrapped angular distance
            rim += height * np.exp(-0.5 * (dist / w) ** 2)
        # a rigid rim landing on the elastomer: a short impact at touch-down
        t_rel = self.t_fine - p["onset"]
        impact = np.where(t_rel >= 0, np.exp(-np.maximum(t_rel, 0.0) / 0.004), 0.0)
        f_total = force * (env * (mod + rim * moving) + rng.uniform(0.3, 1.0) * impact)
        half_along = cfg.washer_contact_mm * max(force, 0.05) ** (1 / 3) / 1.15
        tilt = rng.normal(0.0, 0.3)  # a tilted washer touches with one edge
        return [_Contact(f_total, 0.0, tilt, half_along / 2.0,
                         max(0.3, cfg.washer_thickness_mm / 2 * (1 - min(abs(tilt), 0.6))))]

    # ---- one recording
    def record(self, rng: np.random.Generator, style: ParticipantStyle, modality: int,
               direction: int, run: int) -> tuple[np.ndarray, RecordingTruth]:
        cfg = self.cfg
        d = cfg.level
        modality = GESTURES.index(cfg.modalities[modality])  # the gesture of this campaign id
        practice = run == 1
        jitter = cfg.gesture_jitter_sigma * d * (cfg.practice_jitter_factor if practice else 1.0)
        variant = "typical"
        for key in {BRUSH: ("brush_pressed",), FINGER: ("finger_tip", "finger_feather"),
                    WASHER: ("washer_flat",), PRESS: ()}[modality]:
            habit = style.atypical.get(key, False)
            if practice:  # during practice, habits are less settled
                habit = habit if rng.random() < 0.7 else rng.random() < 0.5 * getattr(
                    cfg, f"p_{key}") * d
            if habit:
                variant = key
                break
        if modality == PRESS:
            p = _press_path(cfg, rng, style, jitter)
        else:
            p = self._path(rng, style, modality, direction, jitter, variant)
        base_force = {BRUSH: cfg.brush_force_n, FINGER: cfg.finger_force_n,
                      WASHER: cfg.washer_force_n, PRESS: cfg.press_force_n}[modality]
        if variant == "finger_feather":
            base_force *= 0.2
        habit_of = FINGER if modality == PRESS else modality  # a press is made with a finger
        force = base_force * style.force[habit_of] * math.exp(rng.normal(0.0, jitter))

        u_coarse = self._along(p, self.t_coarse, rng, jitter)
        u_fine = np.interp(self.t_fine, self.t_coarse, u_coarse)
        speed_fine = np.abs(np.gradient(u_fine)) * self.fs_fine
        moving = np.clip(speed_fine / (0.2 * p["speed"] + 1e-9), 0.0, 1.0)

        if modality == PRESS:  # a finger: its force multiplier, a fingertip's contact
            contacts = [_Contact(force * _press_envelope(cfg, p, style, self.t_fine, rng), 0.0,
                                 0.0, *_press_axes(cfg, style, force))]
        elif modality == FINGER:
            contacts = self._finger(rng, style, p, force, variant, speed_fine, moving)
        elif modality == BRUSH:
            contacts = self._brush(rng, style, p, force, variant, moving)
        else:
            contacts = self._washer(rng, style, p, force, variant, u_fine, moving)

        taxel_force = self._project(contacts, u_coarse, p, style, direction)
        volts = self.sensor.front_end(taxel_force, rng)
        counts, truth_extra = self.sensor.noise_and_adc(volts, rng)

        t0 = p["onset"]
        t_end = t0 + 0.8 * p["t_press"] + p["t_move"] + (p["strokes"] - 1) * p["t_pause"] \
            + p["t_release"]
        on = int(np.clip(math.floor(t0 * self.fs), 0, self.n))
        off = int(np.clip(math.ceil(t_end * self.fs), on, self.n))
        truth = RecordingTruth(
            contact_interval=(on, off), speed_mm_s=float(p["speed"]), force_n=float(force),
            line_mm=float(p["line"]), variant=variant, **truth_extra)
        return counts, truth

    def _project(self, contacts: list[_Contact], u_coarse: np.ndarray, p: dict[str, Any],
                 style: ParticipantStyle, direction: int) -> np.ndarray:
        """Normal force on each taxel, (rows*cols, n_fine), from the moving contacts."""
        cfg = self.cfg
        half = cfg.electrode_mm / 2
        nc = len(contacts)
        along = u_coarse[None, :] + np.array([c.along for c in contacts])[:, None]
        across = (p["line"] + math.tan(style.tilt_rad) * u_coarse)[None, :] \
            + np.array([c.across for c in contacts])[:, None]
        s_al = np.sqrt(np.array([c.sigma_along for c in contacts], float) ** 2 + self.spread**2)
        s_ac = np.sqrt(np.array([c.sigma_across for c in contacts], float) ** 2 + self.spread**2)
        s_al = np.broadcast_to(s_al[:, None], along.shape)
        s_ac = np.broadcast_to(s_ac[:, None], across.shape)
        if direction == 1:  # vertical: along = y, across = x
            wy = _electrode_weights(along, s_al, self.y_pos, half)  # (nc, K+1, rows)
            wx = _electrode_weights(across, s_ac, self.x_pos, half)
        else:
            wx = _electrode_weights(along, s_al, self.x_pos, half)
            wy = _electrode_weights(across, s_ac, self.y_pos, half)
        w = (wy[..., :, None] * wx[..., None, :]).reshape(nc, len(u_coarse), -1)  # (nc,K+1,16)
        # linear interpolation of the weights inside each block, as two batched products
        blk = self.block
        k = self.n_coarse
        f = np.stack([c.force for c in contacts])  # (nc, n_fine)
        pad = k * blk - self.n_fine
        if pad:
            f = np.pad(f, ((0, 0), (0, pad)))
        f = f.reshape(nc, k, blk).transpose(1, 2, 0)  # (k, blk, nc)
        frac = (np.arange(blk) / blk)[None, :, None]
        w0 = w[:, :k].transpose(1, 0, 2)  # (k, nc, 16)
        w1 = w[:, 1:k + 1].transpose(1, 0, 2)
        out = np.matmul(f * (1 - frac), w0) + np.matmul(f * frac, w1)  # (k, blk, 16)
        return out.reshape(k * blk, -1)[: self.n_fine].T


class _Sensor:
    """The one sensor of the campaign and its electronics: taxel gains and mains pickup, the
    charge amplifier and band-pass filters, amplifier noise, drift, faulty taxels, the ADC."""

    def __init__(self, cfg: SimulatorConfig, seed: int, fs_fine: float):
        self.cfg = cfg
        self.fs = cfg.sample_rate_hz
        self.n = cfg.n_samples
        self.sos = np.concatenate([
            sps.butter(1, cfg.ca_highpass_hz, "highpass", fs=fs_fine, output="sos"),
            sps.butter(1, cfg.bpf_highpass_hz, "highpass", fs=fs_fine, output="sos"),
            sps.butter(2, cfg.bpf_lowpass_hz, "lowpass", fs=fs_fine, output="sos"),
        ])
        # charge-amplifier volts per newton on a taxel
        self.v_per_n = cfg.d33_pc_per_n / cfg.feedback_pf
        # taxel sensitivity mismatch: a property of the one sensor used in the campaign
        srng = np.random.default_rng([seed, 0x5E45])
        self.gain = np.exp(srng.normal(0.0, cfg.gain_mismatch, (cfg.rows, cfg.cols)))
        self.hum_coupling = srng.uniform(0.5, 1.5, (cfg.rows, cfg.cols))

    def front_end(self, taxel_force: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """PVDF charge -> charge amplifier -> band-pass -> sampled at the DAQ rate (volts)."""
        gain = self.gain.reshape(-1, 1) * np.exp(rng.normal(0.0, 0.02, (taxel_force.shape[0], 1)))
        v = sps.sosfilt(self.sos, taxel_force * (self.v_per_n * gain), axis=-1)
        return v[:, :: self.cfg.oversample][:, : self.n]

    def noise_and_adc(self, volts: np.ndarray, rng: np.random.Generator
                       ) -> tuple[np.ndarray, dict[str, Any]]:
        cfg = self.cfg
        d = cfg.level
        n_tax, n = volts.shape
        t = np.arange(n) / self.fs
        noise_scale = 0.5 + 0.5 * d
        amp = cfg.amp_noise_v * noise_scale * np.exp(rng.normal(0.0, 0.2, (n_tax, 1)))
        hum = math.exp(rng.uniform(math.log(cfg.hum_v_min), math.log(cfg.hum_v_max))) * noise_scale
        ph = rng.uniform(0, 2 * np.pi)
        coupling = self.hum_coupling.reshape(-1, 1)
        mains = (np.sin(2 * np.pi * cfg.mains_hz * t + ph)
                 + 0.3 * np.sin(2 * np.pi * 3 * cfg.mains_hz * t + 3 * ph + rng.uniform(0, 1)))
        v = volts + hum * coupling * mains[None, :]
        # drift: a slow random walk per channel (amplifier offset, temperature), 10 points/s
        walk = np.cumsum(rng.standard_normal((n_tax, int(n / self.fs * 10) + 2)), axis=1)
        walk -= walk.mean(axis=1, keepdims=True)
        walk *= cfg.drift_v * noise_scale / (np.std(walk) + 1e-12)
        pos = t * 10.0
        i0 = np.minimum(pos.astype(np.int64), walk.shape[1] - 2)
        frac = pos - i0
        v += walk[:, i0] * (1.0 - frac) + walk[:, i0 + 1] * frac
        extra: dict[str, Any] = {}
        u = rng.random(2)
        white = np.sqrt((amp / cfg.volts_per_count) ** 2 + cfg.adc_noise_lsb**2)  # counts rms
        if u[0] < cfg.p_dead_taxel * max(d, 0.0):  # broken trace: only pickup and ADC noise
            k = int(rng.integers(n_tax))
            v[k] = 3 * hum * mains
            white[k] = cfg.adc_noise_lsb + 0.3 * amp[k, 0] / cfg.volts_per_count
            extra["dead_taxel"] = k
        if u[1] < cfg.p_noisy_taxel * max(d, 0.0):  # a bad contact: loud, crackling
            k = int(rng.integers(n_tax))
            crackle = (rng.random(n) < 0.002) * rng.normal(0.0, 0.05, n)
            v[k] += sps.lfilter([1.0], [1.0, -0.95], crackle)
            white[k] *= 10.0
            extra["noisy_taxel"] = k
        counts = np.rint(v / cfg.volts_per_count + white * rng.standard_normal((n_tax, n)))
        lim = 2 ** (cfg.adc_bits - 1)
        extra["clipped"] = bool(np.any(counts >= lim - 1) or np.any(counts <= -lim))
        counts = np.clip(counts, -lim, lim - 1)
        if cfg.adc_bits < 16:
            counts *= 2 ** (16 - cfg.adc_bits)
        return counts.astype(np.int16).reshape(cfg.rows, cfg.cols, n), extra


# --------------------------------------------------------------------------- campaign


def _job_list(participants: int, runs: tuple[int, ...],
              n_modalities: int = len(MODALITIES)) -> list[tuple[int, int, int, int]]:
    """(participant, run, modality, direction) in the paper's acquisition order."""
    return [(p, r, m, d) for p in range(1, participants + 1) for r in runs
            for m in range(n_modalities) for d in (0, 1)]


def _simulate_one(args: tuple[Any, ...]) -> tuple[Any, RecordingTruth]:
    """One recording: (config, seed, job[, compression level]) -> (int16 array, or the
    EncodedRecording when a compression level is given, truth)."""
    cfg, seed, (participant, run, modality, direction) = args[:3]
    chain = _chain_for(cfg, seed)
    style = _participant_style(cfg, np.random.default_rng([seed, participant, 0x57]))
    rng = np.random.default_rng([seed, participant, run, modality, direction, 0xA1])
    rec, truth = chain.record(rng, style, modality, direction, run)
    if len(args) > 3:
        from eskin.data.campaign import encode_recording

        rec = encode_recording(rec, grid_shape=(cfg.rows, cfg.cols), n_samples=cfg.n_samples,
                               compression_level=args[3])
    return rec, truth


_CHAIN_CACHE: dict[tuple[str, int], _Chain] = {}


def _chain_for(cfg: SimulatorConfig, seed: int) -> _Chain:
    key = (cfg.to_json(), seed)
    chain = _CHAIN_CACHE.get(key)
    if chain is None:
        _CHAIN_CACHE.clear()
        chain = _CHAIN_CACHE[key] = _Chain(cfg, seed)
    return chain


def iter_recordings(participants: int = 70, seed: int = 0, *,
                    config: SimulatorConfig | None = None, runs: tuple[int, ...] = (1, 2),
                    n_jobs: int = 1, _encode: Any = ()) -> Iterator[tuple[
                        tuple[int, int, int, int], np.ndarray, RecordingTruth]]:
    """Yield ((participant, run, modality, direction), int16 (rows, cols, T), truth) in order.

    With ``n_jobs`` > 1, joblib worker processes simulate ahead while the caller consumes.
    """
    cfg = config or SimulatorConfig()
    jobs = _job_list(int(participants), tuple(runs), len(cfg.modalities))
    if n_jobs <= 1:
        for job in jobs:
            yield (job, *_simulate_one((cfg, seed, job, *_encode)))
        return
    from joblib import Parallel, delayed

    # joblib is the package's one parallelism route; results come back in job order, with
    # 2 * n_jobs + 1 recordings dispatched at a time
    results = Parallel(n_jobs=n_jobs, return_as="generator", pre_dispatch=2 * n_jobs + 1)(
        delayed(_simulate_one)((cfg, seed, job, *_encode)) for job in jobs
    )
    for job, (rec, truth) in zip(jobs, results):
        yield job, rec, truth


def simulate(
    path: str | os.PathLike[str],
    participants: int = 70,
    seed: int = 0,
    difficulty: float | None = None,
    *,
    config: SimulatorConfig | None = None,
    runs: tuple[int, ...] = (1, 2),
    n_jobs: int = 1,
    overwrite: bool = False,
    progress: Callable[[int, int], None] | None = None,
) -> Path:
    """Simulate a campaign and write it to ``path`` (an eskin campaign file, source="simulated").

    ``participants`` x the modalities (``config.modalities``, default the paper's three) x 2
    directions x ``len(runs)`` recordings, in the paper's order (per participant: run 1 then
    run 2; per run: brush, finger, washer; horizontal then vertical). ``difficulty``
    (default: the calibrated value, see docs/simulator.md) overrides ``config.difficulty``. Same arguments -> identical file content, whatever ``n_jobs``.
    Writes the true contact interval of each recording and the simulator settings
    (``simulator_config`` JSON attribute).
    """
    from eskin.data.campaign import CampaignWriter

    if int(participants) < 1:
        raise ValueError(f"participants must be >= 1, got {participants}")
    if not runs or any(not 1 <= int(r) <= 255 for r in runs):
        raise ValueError(f"runs must be a non-empty tuple of run numbers in [1, 255], got {runs}")
    cfg = config or SimulatorConfig()
    if difficulty is not None:
        cfg = dataclasses.replace(cfg, difficulty=float(difficulty))
    total = int(participants) * len(cfg.modalities) * 2 * len(runs)
    attrs = {
        "simulator_config": cfg.to_json(),
        "simulator_seed": int(seed),
        "simulator_participants": int(participants),
        "difficulty": float(cfg.difficulty),
        "simulator_level": float(cfg.level),
        "description": "SIMULATED campaign (eskin physics-based simulator); not recorded data",
    }
    # a taxel index (-1: none) fits int8 up to 127 taxels; larger grids (19x27) need int16
    taxel = np.int8 if cfg.rows * cfg.cols <= 127 else np.int16
    extra_fields = {"speed_mm_s": np.float32, "force_n": np.float32, "line_mm": np.float32,
                    "variant": np.uint8, "dead_taxel": taxel, "noisy_taxel": taxel,
                    "clipped": np.uint8}
    variants = ["typical", "brush_pressed", "finger_tip", "finger_feather", "washer_flat"]
    attrs["variant_names"] = variants
    with CampaignWriter(path, grid_shape=(cfg.rows, cfg.cols), n_samples=cfg.n_samples,
                        sample_rate_hz=cfg.sample_rate_hz, volts_per_count=cfg.volts_per_count,
                        modalities=list(cfg.modalities), source="simulated", attrs=attrs,
                        contact_interval=True, overwrite=overwrite,
                        extra_fields=extra_fields, durable=False, on_error="discard") as w:
        for k, ((participant, run, modality, direction), rec, truth) in enumerate(
                iter_recordings(participants, seed, config=cfg, runs=runs, n_jobs=n_jobs,
                                _encode=(w.compression_level,))):
            w.append(rec, modality=modality, participant=participant, direction=direction,
                     run=run, contact_interval=truth.contact_interval, extra={
                         "speed_mm_s": truth.speed_mm_s, "force_n": truth.force_n,
                         "line_mm": truth.line_mm, "variant": variants.index(truth.variant),
                         "dead_taxel": truth.dead_taxel, "noisy_taxel": truth.noisy_taxel,
                         "clipped": truth.clipped})
            if progress is not None:
                progress(k + 1, total)
    return Path(path)
