"""Preprocessing of Section 5.1: the touch window and Algorithm 2 subsampling.

A recording ``S`` (rows x cols x T, usually 4 x 4 x 21000 int16 ADC codes) becomes a tensor
``L`` (rows x cols x D, float64) in two steps, both in the C++ core (``eskin._core``):

1. the touch window ``[start, stop)``: an energy detector (short-time energy summed over the
   taxels against a running robust noise floor, with hysteresis, a hold time and padding), see
   :class:`WindowConfig` and ``docs/preprocessing.md``;
2. subsampling of the window to D samples: Algorithm 2 of the paper
   (``interval = floor(S/D)``, samples ``(d-1)*interval``, d = 1..D, the faithful default) or
   evenly spaced indices ``round(d*(S-1)/(D-1))`` spanning the whole window.

The same detector runs on a live stream (:class:`TouchDetector`), one sample at a time, and
gives the same windows as the batch functions.
"""

from __future__ import annotations

import math
import numbers
import sys
import types
from dataclasses import asdict, dataclass, fields, replace
from typing import Any, Iterable, Optional, Sequence, Union

import numpy as np

from eskin import _core
from eskin.data import limits
from eskin.data.limits import MAX_D

__all__ = [
    "WindowConfig",
    "TouchWindow",
    "TouchWindows",
    "TouchDetector",
    "preprocess",
    "detect_windows",
    "detect_touches",
    "subsample",
    "subsample_indices",
]

_WINDOW_MODES = {"energy": 0, "none": 1}
_METHODS = {"algorithm2": 0, "even": 1}
_SHORT = {"interpolate": 0, "error": 1}
_COMBINE = ("sum", "max", "trimmed")
_SELECT = ("energy", "first", "span")
_FALLBACK = ("whole", "error")
# recordings read at a time from a lazy (h5py) dataset
_CHUNK = 32
# at rates where the DC blocker's cutoff is not below Nyquist, it moves to rate / this
DC_CUTOFF_RATE_DIVISOR = 10.0
#: the fewest warm-up frames whose median is the first noise floor (with one sample per frame the
#: first frame's energy is zero, the DC blocker starting as the running mean: one or two warm-up
#: frames would make the floor zero and the detector fire on the first frame, for ever)
MIN_WARMUP_FRAMES = 5
#: the fewest frames of idle energy the noise floor is the median of
MIN_NOISE_FRAMES = 10


@dataclass(frozen=True)
class WindowConfig:
    """Parameters of the energy touch detector (mirrors the C++ POD ``eskin::WindowConfig``).

    Times are in seconds and converted to samples with the sample rate when the detector is
    built, so one configuration serves any rate. ``to_array()`` / ``from_array()`` give the flat
    float64 form (field order :data:`WindowConfig.field_names`) stored in model files; the three
    choice fields are stored as their index (``combine``: sum=0, max=1, trimmed=2; ``select``:
    energy=0, first=1, span=2; ``fallback``: whole=0, error=1).

    Frame energy ``E`` = mean over a frame of the squared DC-blocked signal, summed over the
    taxels (``combine="sum"``; or the max, or the sum without the largest taxel: "trimmed").
    The noise floor is the ``noise_quantile`` of the last ``noise_window_s`` of
    idle frames (at least ``min_noise_energy``). A touch is triggered by a frame with
    ``E > on_factor * floor``; its onset moves back over the preceding frames with
    ``E > off_factor * floor`` (at most ``lookback_s``); it stays on while
    ``E > max(off_factor * floor, release_fraction * peak)`` and ends after ``hold_s`` below
    that (and once ``pad_after_s`` has elapsed); touches shorter than ``min_duration_s`` are
    dropped; the window is ``[onset - pad_before_s, offset + pad_after_s)``, at most
    ``max_window_s`` long. For one window per recording, ``select`` takes the span of the
    touches holding at least ``span_fraction`` of the strongest one's energy ("span"), the
    most energetic touch ("energy") or the first ("first"). See docs/preprocessing.md.
    """

    frame_s: float = 0.010
    dc_cutoff_hz: float = 5.0
    combine: str = "sum"
    noise_window_s: float = 1.0
    noise_quantile: float = 0.5
    warmup_s: float = 0.1
    min_noise_energy: float = 0.0
    on_factor: float = 4.0
    off_factor: float = 2.0
    release_fraction: float = 1e-3
    lookback_s: float = 0.3
    hold_s: float = 0.15
    min_duration_s: float = 0.05
    pad_before_s: float = 0.05
    pad_after_s: float = 0.05
    max_window_s: float = 7.0
    select: str = "span"
    span_fraction: float = 0.05
    fallback: str = "whole"
    #: The bounded window: samples per taxel a stream keeps of a window (an even count >= 2).
    #: A longer window is kept at half the time resolution each time the buffer fills (every
    #: 2nd, then 4th, ... sample), and Algorithm 2's indices over the whole window read the kept
    #: sample at or before each; the batch functions read a recording the same way, so a model
    #: sees the same tensors in training and on a controller. 0 = every sample up to
    #: ``max_window_s`` (the detector's RAM then grows with it). docs/preprocessing.md.
    window_samples: float = 1024

    def __post_init__(self) -> None:
        for name, choices in (("combine", _COMBINE), ("select", _SELECT), ("fallback", _FALLBACK)):
            value = getattr(self, name)
            if value not in choices:
                raise ValueError(f"WindowConfig.{name} = {value!r}: must be one of {choices}")
        for f in fields(self):
            if f.name in ("combine", "select", "fallback"):
                continue
            value = getattr(self, f.name)
            if isinstance(value, bool) or not isinstance(value, numbers.Real):
                raise ValueError(f"WindowConfig.{f.name} = {value!r}: must be a number")
            if not math.isfinite(float(value)):
                raise ValueError(f"WindowConfig.{f.name} = {value!r}: must be finite")
            object.__setattr__(self, f.name, float(value))

    @classmethod
    def field_names(cls) -> tuple[str, ...]:
        return tuple(f.name for f in fields(cls))

    def to_array(self) -> np.ndarray:
        """The flat float64 form, in the C++ field order."""
        out = []
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name == "combine":
                value = _COMBINE.index(value)
            elif f.name == "select":
                value = _SELECT.index(value)
            elif f.name == "fallback":
                value = _FALLBACK.index(value)
            out.append(float(value))
        return np.asarray(out, dtype=np.float64)

    @classmethod
    def from_array(cls, values: Any) -> "WindowConfig":
        """Inverse of :meth:`to_array`."""
        a = np.asarray(values, dtype=np.float64)
        names = cls.field_names()
        if a.shape != (len(names),):
            raise ValueError(
                f"WindowConfig array: expected shape ({len(names)},), got {a.shape}"
            )
        kw: dict[str, Any] = {}
        for name, v in zip(names, a.tolist()):
            if name in ("combine", "select", "fallback"):
                choices = {"combine": _COMBINE, "select": _SELECT, "fallback": _FALLBACK}[name]
                if v != int(v) or not 0 <= int(v) < len(choices):
                    raise ValueError(f"WindowConfig array: {name} = {v} is not a valid index")
                kw[name] = choices[int(v)]
            else:
                kw[name] = v
        return cls(**kw)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "WindowConfig":
        unknown = set(d) - set(cls.field_names())
        if unknown:
            raise ValueError(f"WindowConfig: unknown fields {sorted(unknown)}")
        return cls(**d)

    def for_rate(self, sample_rate_hz: float) -> tuple["WindowConfig", list[str]]:
        """This configuration made valid and meaningful at ``sample_rate_hz``, and a note for
        each change.

        Times convert to samples at any rate (a frame is at least one sample). The DC
        blocker's cutoff must stay below half the rate: where ``dc_cutoff_hz >= sample_rate_hz
        / 2`` (the default 5 Hz at 10 Hz or less) it becomes a tenth of the rate (1 Hz at 10
        Hz), which still removes the offset and the slow drift of a low-rate sensor. The
        settings counted in frames keep a floor (:func:`_frame_floors`): at least
        :data:`MIN_WARMUP_FRAMES` warm-up frames and :data:`MIN_NOISE_FRAMES` noise-floor
        frames, and a pad or a lookback that is not zero at least one frame; the defaults,
        meant for kHz rates (a 10 ms frame of 30 samples), are above them down to 50 Hz. Any
        other invalid value is the caller's and raises ValueError naming the field.
        """
        rate = _rate(sample_rate_hz)
        notes = []
        cfg = self
        if cfg.dc_cutoff_hz >= rate / 2:
            new = rate / DC_CUTOFF_RATE_DIVISOR
            notes.append(
                f"WindowConfig.dc_cutoff_hz = {cfg.dc_cutoff_hz:g} Hz is not below half the "
                f"sample rate {rate:g} Hz: using {new:g} Hz (a tenth of the rate)"
            )
            cfg = replace(cfg, dc_cutoff_hz=new)
        frame = int(cfg.resolve(rate)["frame_len"]) / rate
        changes = _frame_floors(cfg, rate, frame)
        for name, (value, why) in changes.items():
            notes.append(
                f"WindowConfig.{name} = {getattr(cfg, name):g} s at {rate:g} Hz (a frame of "
                f"{frame:g} s) is {why}: using {value:g} s"
            )
        cfg = replace(cfg, **{name: value for name, (value, _) in changes.items()})
        cfg.resolve(rate)
        return cfg, notes

    def resolve(self, sample_rate_hz: float = 3000.0) -> dict[str, Any]:
        """The parameters in samples/frames at a rate (validates the configuration)."""
        return dict(_core.window_config_resolve(self.to_array(), _rate(sample_rate_hz)))


def _frame_floors(cfg: WindowConfig, rate: float, frame: float) -> dict[str, tuple[float, str]]:
    """The settings of ``cfg`` below their floor in frames of ``frame`` seconds at ``rate``:
    name -> (the floor in seconds, why). See :meth:`WindowConfig.for_rate`."""

    def samples(seconds: float) -> int:  # the C++ conversion (llround)
        return int(np.floor(seconds * rate + 0.5))

    def frames(n: int) -> str:
        return f"{n} frame{'s' if n != 1 else ''}"

    frame_len = samples(frame)
    out: dict[str, tuple[float, str]] = {}
    warmup = max(1, -(-samples(cfg.warmup_s) // frame_len))
    if warmup < MIN_WARMUP_FRAMES:
        out["warmup_s"] = (
            MIN_WARMUP_FRAMES * frame,
            f"{frames(warmup)}, fewer than the {MIN_WARMUP_FRAMES} whose median is the first floor",
        )
    noise = samples(cfg.noise_window_s) // frame_len
    if noise < MIN_NOISE_FRAMES:
        out["noise_window_s"] = (
            MIN_NOISE_FRAMES * frame,
            f"{frames(noise)}, fewer than the {MIN_NOISE_FRAMES} the noise floor is the median of",
        )
    for name in ("pad_before_s", "pad_after_s", "lookback_s"):
        value = getattr(cfg, name)
        if value > 0 and samples(value) < frame_len:
            out[name] = (frame, "less than one frame")
    return out


@dataclass(frozen=True)
class TouchWindow:
    """One touch found by :class:`TouchDetector` (sample indices from the stream start)."""

    start: int
    stop: int
    onset: int
    offset: int
    energy: float
    truncated: bool
    tensor: Optional[np.ndarray] = None  # (rows, cols, D) when the detector was given D
    stride: int = 1  # the bounded window kept every stride-th sample (WindowConfig.window_samples)


@dataclass(frozen=True)
class TouchWindows:
    """Per-recording detector results of :func:`detect_touches` (arrays of length n)."""

    start: np.ndarray
    stop: np.ndarray
    onset: np.ndarray
    offset: np.ndarray
    energy: np.ndarray
    truncated: np.ndarray
    found: np.ndarray
    stride: np.ndarray  # the bounded window's decimation (1 = every sample)

    @property
    def windows(self) -> np.ndarray:
        return np.stack([self.start, self.stop], axis=1)


# --------------------------------------------------------------------------- argument checks


def _rate(sample_rate_hz: Any) -> float:
    if isinstance(sample_rate_hz, bool) or not isinstance(sample_rate_hz, numbers.Real):
        raise ValueError(f"sample_rate_hz = {sample_rate_hz!r}: must be a number")
    r = float(sample_rate_hz)
    if not (math.isfinite(r) and r > 0):
        raise ValueError(f"sample_rate_hz = {sample_rate_hz!r}: must be finite and > 0")
    return r


def _check_D(D: Any) -> int:
    if isinstance(D, bool) or not isinstance(D, numbers.Integral):
        raise ValueError(f"D = {D!r}: must be an integer >= 1")
    if int(D) < 1:
        raise ValueError(f"D = {D!r}: must be an integer >= 1")
    if int(D) > MAX_D:
        raise ValueError(f"D = {D!r}: over the limit of {MAX_D:,} samples per window")
    return int(D)


def _config(config: Any) -> np.ndarray:
    if config is None:
        return WindowConfig().to_array()
    if isinstance(config, WindowConfig):
        return config.to_array()
    if isinstance(config, dict):
        return WindowConfig.from_dict(config).to_array()
    raise ValueError(f"config must be a WindowConfig, a dict or None, not {type(config).__name__}")


def _choice(name: str, value: Any, table: dict[str, int]) -> int:
    if value not in table:
        raise ValueError(f"{name} = {value!r}: must be one of {tuple(table)}")
    return table[value]


def _threads(n_threads: Optional[int]) -> int:
    if n_threads is None:
        return 0
    if isinstance(n_threads, bool) or not isinstance(n_threads, numbers.Integral) or n_threads < 0:
        raise ValueError(f"n_threads = {n_threads!r}: must be a non-negative integer or None")
    return int(n_threads)


class _Batch:
    """signals normalised to (n, rows, cols, T) with lengths; lazily sliced when not in memory."""

    def __init__(self, signals: Any, lengths: Any) -> None:
        if isinstance(signals, (list, tuple)):
            signals = np.asarray(signals)
        shape = getattr(signals, "shape", None)
        dtype = getattr(signals, "dtype", None)
        if shape is None or dtype is None:
            raise ValueError(
                f"signals must be an array (n, rows, cols, T) or (rows, cols, T), "
                f"not {type(signals).__name__}"
            )
        shape = tuple(int(s) for s in shape)
        if len(shape) == 3:
            self.single = True
            self.source = signals
            n = 1
            rows, cols, T = shape
        elif len(shape) == 4:
            self.single = False
            self.source = signals
            n, rows, cols, T = shape
        else:
            raise ValueError(
                f"signals must have shape (n, rows, cols, T) or (rows, cols, T), got {shape}"
            )
        if rows < 1 or cols < 1 or T < 1:
            raise ValueError(f"signals has an empty grid or time axis: shape {shape}")
        dtype = np.dtype(dtype)
        if not (dtype.kind in "iub" or dtype.kind == "f"):
            raise ValueError(f"signals must be integer or real, got dtype {dtype}")
        self.dtype = dtype
        self.n, self.rows, self.cols, self.T = n, rows, cols, T
        self.lengths = self._lengths(lengths)

    def _lengths(self, lengths: Any) -> Optional[np.ndarray]:
        if lengths is None:
            return None
        a = np.asarray(lengths)
        if self.single and a.ndim == 0:
            a = a.reshape(1)
        if a.shape != (self.n,):
            raise ValueError(f"lengths must have shape ({self.n},), got {a.shape}")
        if a.dtype.kind == "f":
            if not np.all(np.isfinite(a)) or np.any(a != np.round(a)):
                raise ValueError("lengths must be integers")
        elif a.dtype.kind not in "iu":
            raise ValueError(f"lengths must be integers, got dtype {a.dtype}")
        a = a.astype(np.int64)
        bad = np.flatnonzero((a < 1) | (a > self.T))
        if bad.size:
            i = int(bad[0])
            raise ValueError(f"lengths[{i}] = {int(a[i])}: must be in [1, T = {self.T}]")
        return a

    def chunks(self) -> Iterable[tuple[int, np.ndarray, Optional[np.ndarray]]]:
        """(first index, (m, n_taxels, T) int16 or float64 C-contiguous, lengths or None)."""
        K = self.rows * self.cols
        in_memory = isinstance(self.source, np.ndarray)
        step = self.n if in_memory else _CHUNK
        for i0 in range(0, self.n, max(step, 1)):
            i1 = min(self.n, i0 + step)
            if self.single:
                block = np.asarray(self.source)[None]
            else:
                block = np.asarray(self.source[i0:i1])
            block = block.reshape(i1 - i0, K, self.T)
            if block.dtype != np.int16:
                block = block.astype(np.float64, copy=False)
            block = np.ascontiguousarray(block)
            lens = None if self.lengths is None else self.lengths[i0:i1]
            yield i0, block, lens


def _raise_indexed(err: Exception, i0: int) -> None:
    """Re-raise a core error with the recording index shifted to the batch's numbering."""
    msg = str(err)
    if i0 and msg.startswith("signals["):
        j = msg.index("]")
        msg = f"signals[{int(msg[8:j]) + i0}]{msg[j + 1:]}"
    raise type(err)(msg) from None


# --------------------------------------------------------------------------- batch API


def detect_touches(
    signals: Any,
    lengths: Any = None,
    sample_rate_hz: float = 3000.0,
    config: Union[WindowConfig, dict, None] = None,
    *,
    n_threads: Optional[int] = None,
) -> TouchWindows:
    """Run the touch detector on every recording; all per-recording results (one touch each,
    chosen by ``config.select``; ``found`` is False where the fallback window was used)."""
    rate = _rate(sample_rate_hz)
    cfg = _config(config)
    b = _Batch(signals, lengths)
    nt = _threads(n_threads)
    infos, energies = [], []
    for i0, block, lens in b.chunks():
        try:
            info, energy = _core.detect_windows(block, lens, rate, cfg, nt)
        except (ValueError, RuntimeError) as err:
            _raise_indexed(err, i0)
        infos.append(info)
        energies.append(energy)
    info = np.concatenate(infos) if infos else np.zeros((0, 7), np.int64)
    energy = np.concatenate(energies) if energies else np.zeros(0)
    return TouchWindows(
        start=info[:, 0].copy(),
        stop=info[:, 1].copy(),
        onset=info[:, 2].copy(),
        offset=info[:, 3].copy(),
        energy=energy,
        truncated=info[:, 4].astype(bool),
        found=info[:, 5].astype(bool),
        stride=info[:, 6].copy(),
    )


def detect_windows(
    signals: Any,
    lengths: Any = None,
    sample_rate_hz: float = 3000.0,
    config: Union[WindowConfig, dict, None] = None,
    *,
    n_threads: Optional[int] = None,
) -> np.ndarray:
    """Touch windows ``[start, stop)`` (sample indices), int64 (n, 2); (2,) for a single
    recording (rows, cols, T). Where no touch is found the window is the whole recording
    ``[0, length)`` (``config.fallback = "whole"``) or a RuntimeError is raised ("error")."""
    w = detect_touches(signals, lengths, sample_rate_hz, config, n_threads=n_threads).windows
    return w[0] if np.ndim(signals) == 3 else w


def preprocess(
    signals: Any,
    D: int = 100,
    *,
    lengths: Any = None,
    sample_rate_hz: float = 3000.0,
    window: Union[str, np.ndarray, Sequence] = "energy",
    subsample: str = "algorithm2",
    config: Union[WindowConfig, dict, None] = None,
    short: str = "interpolate",
    n_threads: Optional[int] = None,
    return_windows: bool = False,
) -> Any:
    """Recordings -> (n, rows, cols, D) float64 tensors (the paper's phi).

    signals: (n, rows, cols, T) or one recording (rows, cols, T) (then the result is
    (rows, cols, D)); int16 ADC codes (kept as codes) or real values; an h5py dataset is read a
    few recordings at a time. lengths: valid samples per recording (default T).
    window: "energy" (the detector, see :class:`WindowConfig`), "none" (the whole valid
    recording), an (n, 2) array of given ``[start, stop)`` windows (read sample by sample), or
    the detector's windows with their bounded-window strides: :class:`TouchWindows` from
    :func:`detect_touches` or an (n, 3) ``[start, stop, stride]`` array. Detected windows
    passed back this way give exactly the tensors of ``window="energy"`` (the tensors a stream
    classifier computes); passed as (n, 2) they lose the stride.
    subsample: "algorithm2" (the paper, default) or "even".
    short: what to do when a window has fewer than D samples: "interpolate" (linear
    interpolation at D evenly spaced points) or "error".
    return_windows: also return the (n, 2) int64 windows used.
    """
    D = _check_D(D)
    rate = _rate(sample_rate_hz)
    cfg = _config(config)
    method = _choice("subsample", subsample, _METHODS)
    short_policy = _choice("short", short, _SHORT)
    nt = _threads(n_threads)
    b = _Batch(signals, lengths)
    problem = limits.memory_problem(
        b.n * b.rows * b.cols * D * 8, f"the output ({b.n}, {b.rows}, {b.cols}, D={D}) float64"
    )
    if problem:
        raise ValueError(f"D = {D!r}: {problem}")
    given: Optional[np.ndarray] = None
    if isinstance(window, str):
        mode = _choice("window", window, _WINDOW_MODES)
    else:
        mode = 2
        if isinstance(window, TouchWindows):
            window = np.stack([window.start, window.stop, window.stride], axis=1)
        given = np.asarray(window)
        if b.single and given.shape in ((2,), (3,)):
            given = given.reshape(1, -1)
        if given.ndim != 2 or given.shape not in ((b.n, 2), (b.n, 3)) or given.dtype.kind not in "iu":
            raise ValueError(
                f"window must be 'energy', 'none', TouchWindows or an integer array of shape "
                f"({b.n}, 2) [start, stop) or ({b.n}, 3) [start, stop, stride], "
                f"got {given.dtype} {given.shape}"
            )
        given = given.astype(np.int64)
    outs, wins = [], []
    for i0, block, lens in b.chunks():
        g = None if given is None else given[i0 : i0 + block.shape[0]]
        try:
            out, info, _ = _core.preprocess(
                block, lens, D, mode, method, short_policy, rate, cfg, g, nt
            )
        except (ValueError, RuntimeError) as err:
            _raise_indexed(err, i0)
        outs.append(out)
        wins.append(info[:, :2])
    if outs:
        out = np.concatenate(outs).reshape(b.n, b.rows, b.cols, D)
        w = np.concatenate(wins)
    else:
        out = np.zeros((0, b.rows, b.cols, D))
        w = np.zeros((0, 2), np.int64)
    if b.single:
        out, w = out[0], w[0]
    return (out, w) if return_windows else out


def subsample(
    signals: Any,
    D: int = 100,
    *,
    method: str = "algorithm2",
    short: str = "interpolate",
    windows: Any = None,
    lengths: Any = None,
) -> np.ndarray:
    """Subsample already windowed recordings (or given ``windows``; default the whole valid
    length) to D samples: (n, rows, cols, D) float64, or (rows, cols, D) for one recording."""
    return preprocess(
        signals,
        D,
        lengths=lengths,
        window="none" if windows is None else windows,
        subsample=method,
        short=short,
    )


def subsample_indices(S: int, D: int, method: str = "algorithm2") -> np.ndarray:
    """The D (0-based) indices into a window of S >= D samples that ``method`` keeps."""
    D = _check_D(D)
    if isinstance(S, bool) or not isinstance(S, numbers.Integral) or S < D:
        raise ValueError(f"S = {S!r}: must be an integer >= D = {D}")
    return _core.subsample_indices(int(S), D, _choice("method", method, _METHODS))


# --------------------------------------------------------------------------- streaming


class TouchDetector:
    """The streaming touch detector: push samples as they arrive, get touches when they end.

    ``grid`` is (rows, cols) (or the number of taxels). ``push(samples)`` takes one sample
    (rows, cols) / (n_taxels,) or a block (n, rows, cols) / (n, n_taxels), int16 or real, and
    returns the list of :class:`TouchWindow` completed by it; with ``D`` given each carries its
    (rows, cols, D) tensor. ``flush()`` ends a touch in progress (end of stream). Sample indices
    count from the first sample pushed (or the last ``reset()``). The C++ detector allocates
    everything at construction; pushing never allocates in the core.
    """

    def __init__(
        self,
        grid: Union[int, tuple[int, int]] = (4, 4),
        sample_rate_hz: float = 3000.0,
        config: Union[WindowConfig, dict, None] = None,
        *,
        D: Optional[int] = None,
        subsample: str = "algorithm2",
        short: str = "interpolate",
    ) -> None:
        if isinstance(grid, numbers.Integral) and not isinstance(grid, bool):
            grid = (1, int(grid))
        try:
            rows, cols = (int(g) for g in grid)  # type: ignore[union-attr]
        except (TypeError, ValueError):
            raise ValueError(f"grid = {grid!r}: must be (rows, cols) or a taxel count") from None
        if rows < 1 or cols < 1:
            raise ValueError(f"grid = {grid!r}: must be positive")
        self.grid = (rows, cols)
        self.sample_rate_hz = _rate(sample_rate_hz)
        self.config = config if isinstance(config, WindowConfig) else (
            WindowConfig() if config is None else WindowConfig.from_dict(config)
        )
        self.D = None if D is None else _check_D(D)
        self.subsample = subsample
        self.short = short
        self._det = _core.TouchDetector(
            rows * cols,
            self.sample_rate_hz,
            self.config.to_array(),
            0 if self.D is None else self.D,
            _choice("subsample", subsample, _METHODS),
            _choice("short", short, _SHORT),
        )

    @property
    def n_taxels(self) -> int:
        return self.grid[0] * self.grid[1]

    @property
    def samples_seen(self) -> int:
        return int(self._det.samples_seen)

    @property
    def in_touch(self) -> bool:
        return bool(self._det.in_touch)

    @property
    def noise_floor(self) -> float:
        return float(self._det.noise_floor)

    def _wrap(self, found: list) -> list[TouchWindow]:
        out = []
        for start, stop, onset, offset, energy, truncated, tensor, stride in found:
            if tensor is not None:
                tensor = np.asarray(tensor).reshape(self.grid[0], self.grid[1], -1)
            out.append(
                TouchWindow(int(start), int(stop), int(onset), int(offset), float(energy),
                            bool(truncated), tensor, int(stride))
            )
        return out

    def push(self, samples: Any) -> list[TouchWindow]:
        a = np.asarray(samples)
        K = self.n_taxels
        if a.dtype.kind not in "iubf":
            raise ValueError(f"samples must be integer or real, got dtype {a.dtype}")
        if a.shape in ((K,), self.grid):
            a = a.reshape(1, K)
        elif a.ndim == 3 and a.shape[1:] == self.grid:
            a = a.reshape(a.shape[0], K)
        elif not (a.ndim == 2 and a.shape[1] == K):
            raise ValueError(
                f"samples must be (n, {self.grid[0]}, {self.grid[1]}), (n, {K}) or one sample, "
                f"got shape {a.shape}"
            )
        if a.dtype != np.int16:
            a = a.astype(np.float64, copy=False)
            bad = ~np.isfinite(a)
            if bad.any():
                i, k = np.argwhere(bad)[0]
                raise ValueError(
                    f"samples[{int(i)}] has a non-finite value at taxel {int(k)}; nothing was "
                    f"pushed from this block"
                )
        return self._wrap(self._det.push(np.ascontiguousarray(a)))

    def flush(self) -> list[TouchWindow]:
        return self._wrap(self._det.flush())

    def reset(self) -> None:
        self._det.reset()


# ``eskin.preprocess`` names both this module and its main function. Importing the module (for
# instance ``from eskin.preprocess import WindowConfig``) makes the attribute ``eskin.preprocess``
# the module, so the module itself is made callable: ``eskin.preprocess(signals, D)`` works
# whichever of the two the attribute holds.
class _CallableModule(types.ModuleType):
    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        return preprocess(*args, **kwargs)


sys.modules[__name__].__class__ = _CallableModule
