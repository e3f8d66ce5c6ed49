"""Tests of eskin.preprocess: Algorithm 2 against a direct numpy transcription, the even and
S < D rules, detector invariants, streaming == batch, errors."""

from __future__ import annotations

import h5py
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import eskin
from eskin import _core
from eskin.signal import _preprocess_numpy as _ref
from eskin.signal.preprocess import (
    TouchDetector,
    WindowConfig,
    detect_touches,
    detect_windows,
    preprocess,
    subsample,
    subsample_indices,
)

RATE = 3000.0


def algorithm2_numpy(S_bar: np.ndarray, D: int) -> np.ndarray:
    """Algorithm 2 of the paper, transcribed literally (1-based p, as printed)."""
    S_i = S_bar.shape[2]
    interval = S_i // D
    L = np.empty(S_bar.shape[:2] + (D,))
    p = 1
    for d in range(1, D + 1):
        L[:, :, d - 1] = S_bar[:, :, p - 1]
        p = p + interval
    return L


def even_numpy(S_bar: np.ndarray, D: int) -> np.ndarray:
    S = S_bar.shape[2]
    if D == 1:
        return S_bar[:, :, :1].astype(float)
    idx = [(2 * d * (S - 1) + (D - 1)) // (2 * (D - 1)) for d in range(D)]
    return S_bar[:, :, idx].astype(float)


def recording(
    T: int, bursts: list[tuple[int, int, float]], seed: int, grid=(4, 4), noise=20.0
) -> np.ndarray:
    """int16 (rows, cols, T): noise, per-taxel offsets, 80 Hz bursts [a, b) of an amplitude."""
    rng = np.random.default_rng(seed)
    rows, cols = grid
    x = rng.normal(0.0, noise, (rows, cols, T))
    x += rng.integers(-500, 500, (rows, cols, 1))
    t = np.arange(T)
    for a, b, amp in bursts:
        gain = 1.0 + 0.05 * np.arange(rows * cols).reshape(rows, cols, 1)
        x[:, :, a:b] += amp * gain * np.sin(2 * np.pi * 80.0 * t[a:b] / RATE)
    return np.round(x).astype(np.int16)


# --------------------------------------------------------------------------- subsampling


@pytest.mark.parametrize("S", [100, 101, 150, 199, 200, 999, 4321, 21000])
@pytest.mark.parametrize("D", [1, 20, 50, 100])
def test_algorithm2_matches_the_paper_transcription(S, D):
    rng = np.random.default_rng(S * 1000 + D)
    x = rng.integers(-30000, 30000, (4, 4, S), dtype=np.int16)
    got = subsample(x, D)
    np.testing.assert_array_equal(got, algorithm2_numpy(x, D))
    assert got.dtype == np.float64 and got.shape == (4, 4, D)
    np.testing.assert_array_equal(subsample_indices(S, D), np.arange(D) * (S // D))


def test_algorithm2_remainder_keeps_only_the_first_D_samples():
    # D <= S < 2D: interval 1, the rest of the touch is dropped (docs/paper-readings.md, R18)
    x = np.arange(150, dtype=float).reshape(1, 1, 150)
    np.testing.assert_array_equal(subsample(x, 100)[0, 0], np.arange(100))
    # the even alternative spans the whole window
    ev = subsample(x, 100, method="even")[0, 0]
    assert ev[0] == 0 and ev[-1] == 149
    np.testing.assert_array_equal(ev, even_numpy(x, 100)[0, 0])


@pytest.mark.parametrize("S,D", [(100, 100), (101, 100), (21000, 100), (5, 2), (7, 1)])
def test_even_indices(S, D):
    rng = np.random.default_rng(S + D)
    x = rng.normal(size=(2, 3, S))
    np.testing.assert_array_equal(subsample(x, D, method="even"), even_numpy(x, D))


def test_short_window_interpolates_or_errors():
    rng = np.random.default_rng(3)
    x = rng.normal(size=(4, 4, 37))
    got = subsample(x, 100)
    pos = np.arange(100) * 36 / 99
    want = np.stack([np.interp(pos, np.arange(37), v) for v in x.reshape(16, 37)]).reshape(
        4, 4, 100
    )
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(got[..., 0], x[..., 0])
    np.testing.assert_array_equal(got[..., -1], x[..., -1])
    # the method does not matter when S < D
    np.testing.assert_array_equal(subsample(x, 100, method="even"), got)
    with pytest.raises(ValueError, match="shorter than D"):
        subsample(x, 100, short="error")


def test_subsample_uses_lengths_and_given_windows():
    rng = np.random.default_rng(4)
    x = rng.integers(-100, 100, (3, 2, 2, 500), dtype=np.int16)
    lengths = np.array([500, 320, 211])
    got = subsample(x, 50, lengths=lengths)
    for i in range(3):
        np.testing.assert_array_equal(got[i], algorithm2_numpy(x[i, :, :, : lengths[i]], 50))
    windows = np.array([[10, 400], [0, 320], [100, 211]])
    got = subsample(x, 20, windows=windows, lengths=lengths)
    for i, (a, b) in enumerate(windows):
        np.testing.assert_array_equal(got[i], algorithm2_numpy(x[i, :, :, a:b], 20))


@settings(max_examples=60, deadline=None)
@given(
    S=st.integers(1, 3000),
    D=st.integers(1, 200),
    method=st.sampled_from(["algorithm2", "even"]),
    rows=st.integers(1, 4),
    cols=st.integers(1, 5),
)
def test_subsample_invariants(S, D, method, rows, cols):
    rng = np.random.default_rng(S * 7 + D)
    x = rng.integers(-1000, 1000, (rows, cols, S)).astype(np.int16)
    out = subsample(x, D, method=method)
    assert out.shape == (rows, cols, D) and out.dtype == np.float64
    if S >= D:
        idx = subsample_indices(S, D, method)
        assert idx[0] == 0 and np.all(np.diff(idx) > 0) and idx[-1] <= S - 1
        if method == "algorithm2":
            # Algorithm 2 never reaches the tail: the last interval's rest plus the remainder
            assert S - 1 - idx[-1] == (S // D - 1) + S % D
        else:
            assert idx[-1] == S - 1 or D == 1
        np.testing.assert_array_equal(out, x[:, :, idx].astype(float))
    else:
        # interpolation stays within each taxel's range and hits both ends
        lo, hi = x.min(axis=2, keepdims=True), x.max(axis=2, keepdims=True)
        assert np.all(out >= lo - 1e-9) and np.all(out <= hi + 1e-9)
        np.testing.assert_array_equal(out[..., 0], x[..., 0])


# --------------------------------------------------------------------------- config


def test_window_config_mirrors_the_cpp_struct():
    assert WindowConfig.field_names() == tuple(_core.WINDOW_CONFIG_FIELDS)
    np.testing.assert_array_equal(WindowConfig().to_array(), _core.window_config_defaults())
    c = WindowConfig(on_factor=6.0, combine="max", select="span", fallback="error")
    assert WindowConfig.from_array(c.to_array()) == c
    assert WindowConfig.from_dict(c.to_dict()) == c
    r = WindowConfig().resolve(3000.0)
    assert r["frame_len"] == 30 and r["max_window"] == 21000 and r["pad_before"] == 150
    assert WindowConfig().resolve(1000.0)["frame_len"] == 10


@pytest.mark.parametrize(
    "kw,match",
    [
        (dict(combine="mean"), "combine"),
        (dict(select="last"), "select"),
        (dict(on_factor=float("nan")), "on_factor"),
        (dict(hold_s="long"), "hold_s"),
    ],
)
def test_window_config_rejects_bad_fields(kw, match):
    with pytest.raises(ValueError, match=match):
        WindowConfig(**kw)


@pytest.mark.parametrize(
    "kw,match",
    [
        (dict(on_factor=1.0), "on_factor"),
        (dict(frame_s=0.0), "frame_s"),
        (dict(noise_quantile=2.0), "noise_quantile"),
        (dict(max_window_s=0.01), "max_window_s"),
    ],
)
def test_window_config_values_checked_when_used(kw, match):
    x = recording(3000, [], 0)
    with pytest.raises(ValueError, match=match):
        detect_windows(x, config=WindowConfig(**kw))


def test_window_config_from_array_errors():
    with pytest.raises(ValueError, match="shape"):
        WindowConfig.from_array(np.zeros(3))
    a = WindowConfig().to_array()
    a[2] = 5
    with pytest.raises(ValueError, match="combine"):
        WindowConfig.from_array(a)
    with pytest.raises(ValueError, match="unknown"):
        WindowConfig.from_dict({"bogus": 1})


# --------------------------------------------------------------------------- detector


def test_detects_a_burst_with_known_onset_and_offset():
    x = recording(21000, [(4500, 10500, 120.0)], 1)
    t = detect_touches(x[None])
    assert t.found[0] and not t.truncated[0]
    assert abs(t.onset[0] - 4500) <= 30 and abs(t.offset[0] - 10500) <= 60
    assert t.start[0] == t.onset[0] - 150 and t.stop[0] == t.offset[0] + 150
    np.testing.assert_array_equal(detect_windows(x), [t.start[0], t.stop[0]])
    assert detect_windows(x[None]).shape == (1, 2) and detect_windows(x).dtype == np.int64


def test_no_touch_gives_the_whole_recording_or_an_error():
    x = recording(6000, [], 2)
    t = detect_touches(x[None], lengths=[5000])
    assert not t.found[0]
    np.testing.assert_array_equal(t.windows, [[0, 5000]])
    with pytest.raises(RuntimeError, match="no touch"):
        detect_windows(x, config=WindowConfig(fallback="error"))


def test_any_grid_and_rate():
    # a 2 x 3 grid at 1 kHz; times are in seconds so the same config applies
    rate = 1000.0
    rng = np.random.default_rng(5)
    x = rng.normal(0, 1.0, (2, 3, 5000))
    t = np.arange(5000)
    x[:, :, 2000:3000] += 8 * np.sin(2 * np.pi * 40 * t[2000:3000] / rate)
    w = detect_windows(x, sample_rate_hz=rate)
    assert abs(w[0] - (2000 - 50)) <= 10 and abs(w[1] - (3000 + 50)) <= 20
    out = preprocess(x, 20, sample_rate_hz=rate)
    # a window longer than WindowConfig.window_samples (1024) is read as the bounded buffer kept
    # it: window sample t is sample (t // stride) * stride
    stride = int(detect_touches(x[None], sample_rate_hz=rate).stride[0])
    assert stride == 2
    S = w[1] - w[0]
    kept = x[:, :, w[0] : w[1]][:, :, (np.arange(S) // stride) * stride]
    np.testing.assert_array_equal(out, algorithm2_numpy(kept, 20))
    unbounded = WindowConfig(window_samples=0)
    np.testing.assert_array_equal(
        preprocess(x, 20, sample_rate_hz=rate, config=unbounded),
        algorithm2_numpy(x[:, :, w[0] : w[1]], 20),
    )


def test_for_rate_keeps_the_kHz_defaults_and_floors_the_frame_counts_at_low_rates():
    assert WindowConfig().for_rate(3000.0) == (WindowConfig(), [])
    assert WindowConfig().for_rate(50.0) == (WindowConfig(), [])  # 5 warm-up frames already
    cfg, notes = WindowConfig().for_rate(10.0)  # a frame is one 0.1 s sample
    assert cfg == WindowConfig(dc_cutoff_hz=1.0, warmup_s=0.5)
    assert notes[1] == ("WindowConfig.warmup_s = 0.1 s at 10 Hz (a frame of 0.1 s) is 1 frame, "
                        "fewer than the 5 whose median is the first floor: using 0.5 s")
    r = cfg.resolve(10.0)
    assert (r["warmup_frames"], r["noise_frames"], r["pad_before"], r["lookback_frames"]) == (
        5, 10, 1, 3)
    cfg, notes = WindowConfig().for_rate(5.0)  # the 0.05 s pads would round to no sample
    assert cfg == WindowConfig(dc_cutoff_hz=0.5, warmup_s=1.0, noise_window_s=2.0,
                               pad_before_s=0.2, pad_after_s=0.2)
    assert len(notes) == 5 and "pad_after_s = 0.05 s at 5 Hz (a frame of 0.2 s) is less" in notes[4]
    r = cfg.resolve(5.0)
    assert (r["warmup_frames"], r["noise_frames"], r["pad_before"], r["pad_after"]) == (5, 10, 1, 1)
    given = WindowConfig(warmup_s=0.0, pad_before_s=0.0, lookback_s=0.0)
    cfg, _ = given.for_rate(10.0)  # no pad and no lookback stay none
    assert (cfg.warmup_s, cfg.pad_before_s, cfg.lookback_s) == (0.5, 0.0, 0.0)


def test_at_10_hz_the_window_holds_the_touch_not_the_recording():
    """A 1 s touch in a 7 s recording at 10 Hz. With one warm-up frame (0.1 s) the first noise
    floor is the first frame's energy, which the DC blocker makes zero: the detector fires on
    the next frame and the window is the whole recording. The settings of for_rate find it."""
    rate = 10.0
    rng = np.random.default_rng(3)
    x = rng.normal(0, 1.0, (5, 6, 70)) + rng.integers(-50, 50, (5, 6, 1))
    x[1:4, 2:5, 30:40] += 20 * np.sin(np.pi * np.arange(1, 11) / 11)
    one_frame = WindowConfig(dc_cutoff_hz=1.0)
    np.testing.assert_array_equal(detect_windows(x, sample_rate_hz=rate, config=one_frame),
                                  [0, 70])
    cfg, _ = WindowConfig().for_rate(rate)
    t = detect_touches(x[None], sample_rate_hz=rate, config=cfg)
    assert t.found[0] and t.onset[0] == 30 and t.start[0] == 29
    assert 40 <= t.offset[0] <= 45 and t.stop[0] == t.offset[0] + 1  # the DC blocker's tail


@settings(max_examples=25, deadline=None)
@given(
    a=st.integers(500, 15000),
    dur=st.integers(300, 5000),
    amp=st.floats(60.0, 500.0),
    k=st.integers(-3, 3),
    seed=st.integers(0, 2**16),
)
def test_detector_invariants(a, dur, amp, k, seed):
    T = 21000
    x = recording(T, [(a, min(T, a + dur), amp)], seed).astype(np.float64)
    length = T - seed % 2000
    t = detect_touches(x[None], lengths=[length])
    assert 0 <= t.start[0] < t.stop[0] <= length
    assert t.start[0] <= t.onset[0] <= t.offset[0] <= t.stop[0]
    assert t.stop[0] - t.start[0] <= 21000
    # thresholds are relative to the noise floor: scaling by a power of two changes nothing
    t2 = detect_touches(x[None] * 2.0**k, lengths=[length])
    np.testing.assert_array_equal(t2.windows, t.windows)
    # int16 and float64 inputs give the same windows
    t3 = detect_touches(x[None].astype(np.int16), lengths=[length])
    np.testing.assert_array_equal(t3.windows, t.windows)


# --------------------------------------------------------------------------- streaming == batch


@pytest.mark.parametrize("select", ["energy", "first", "span"])
def test_streaming_equals_batch(select):
    rng = np.random.default_rng(11)
    cfg = WindowConfig(select=select)
    for seed in range(3):
        bursts = [(int(a), int(a + rng.integers(300, 4000)), 80.0 + 40 * j)
                  for j, a in enumerate(sorted(rng.integers(1000, 16000, 3)))]
        x = recording(21000, bursts, seed)
        det = TouchDetector((4, 4), RATE, cfg, D=50)
        stream = np.moveaxis(x, -1, 0)  # (T, 4, 4), sample-major
        found = []
        i = 0
        while i < stream.shape[0]:
            n = int(rng.integers(1, 3000))
            found += det.push(stream[i : i + n])
            i += n
        found += det.flush()
        assert det.samples_seen == 21000
        assert found
        b = detect_touches(x[None], config=cfg)
        energies = [w.energy for w in found]
        if select == "first":
            chosen = found[0]
        elif select == "energy":
            chosen = found[int(np.argmax(energies))]
        if select == "span":
            assert b.start[0] == found[0].start and b.stop[0] == found[-1].stop
        else:
            assert (b.start[0], b.stop[0], b.onset[0], b.offset[0]) == (
                chosen.start, chosen.stop, chosen.onset, chosen.offset)
            assert b.energy[0] == chosen.energy
            # the streamed window's tensor equals the batch tensor
            np.testing.assert_array_equal(chosen.tensor, preprocess(x, 50, config=cfg))


@pytest.mark.parametrize(
    "cfg",
    [
        WindowConfig(),
        WindowConfig(select="energy", combine="max", dc_cutoff_hz=0.0),
        WindowConfig(combine="trimmed", noise_quantile=0.25),
        WindowConfig(select="first", max_window_s=1.0, lookback_s=0.0, release_fraction=0.0),
    ],
)
def test_numpy_reference_finds_the_same_windows(cfg):
    rng = np.random.default_rng(21)
    for seed in range(4):
        bursts = [(int(a), int(a + rng.integers(300, 6000)), float(rng.uniform(40, 300)))
                  for a in sorted(rng.integers(200, 15000, 2))]
        x = recording(21000, bursts, seed)
        length = 21000 - 1000 * seed
        out, w = _ref.preprocess(x, 50, RATE, cfg, length=length)
        got, gw = preprocess(x, 50, lengths=length, config=cfg, return_windows=True)
        np.testing.assert_array_equal(w, gw)
        np.testing.assert_array_equal(out, got)


def test_streaming_one_sample_at_a_time_and_reset():
    x = recording(9000, [(3000, 6000, 150.0)], 12)
    det = TouchDetector(16, RATE)
    found = []
    for t in range(9000):
        found += det.push(x[:, :, t].reshape(16))
    found += det.flush()
    assert len(found) == 1 and found[0].tensor is None
    np.testing.assert_array_equal([found[0].start, found[0].stop], detect_windows(x))
    det.reset()
    assert det.samples_seen == 0
    again = det.push(np.moveaxis(x, -1, 0).reshape(9000, 16)) + det.flush()
    assert [(w.start, w.stop) for w in again] == [(w.start, w.stop) for w in found]


def test_streaming_rejects_bad_samples():
    det = TouchDetector((4, 4), RATE)
    with pytest.raises(ValueError, match="samples must be"):
        det.push(np.zeros((10, 3, 3)))
    bad = np.zeros((5, 16))
    bad[3, 7] = np.nan
    with pytest.raises(ValueError, match=r"samples\[3\].*taxel 7"):
        det.push(bad)
    assert det.samples_seen == 0
    with pytest.raises(ValueError, match="grid"):
        TouchDetector((0, 4))


# --------------------------------------------------------------------------- batch API


def kept(window: np.ndarray, stride: int) -> np.ndarray:
    """A window as the bounded buffer keeps it: sample t is sample (t // stride) * stride."""
    S = window.shape[-1]
    return window[..., (np.arange(S) // stride) * stride]


def test_preprocess_batch_and_single():
    xs = np.stack([recording(21000, [(3000 + 1000 * i, 9000 + 500 * i, 120.0)], i)
                   for i in range(4)])
    out, w = preprocess(xs, 100, return_windows=True)
    assert out.shape == (4, 4, 4, 100) and out.dtype == np.float64 and w.shape == (4, 2)
    np.testing.assert_array_equal(w, detect_windows(xs))
    stride = detect_touches(xs).stride
    assert np.all(stride == 8)  # windows of 6000-7500 samples kept in 1024
    for i in range(4):
        np.testing.assert_array_equal(out[i], preprocess(xs[i], 100))
        win = xs[i, :, :, w[i, 0]:w[i, 1]]
        np.testing.assert_array_equal(out[i], algorithm2_numpy(kept(win, stride[i]), 100))
    even = preprocess(xs, 20, subsample="even")
    win = xs[1, :, :, w[1, 0]:w[1, 1]]
    np.testing.assert_array_equal(even[1], even_numpy(kept(win, stride[1]), 20))
    none = preprocess(xs, 20, window="none", lengths=[21000, 20000, 15000, 100])
    np.testing.assert_array_equal(none[2], algorithm2_numpy(xs[2, :, :, :15000], 20))
    # threads do not change anything
    np.testing.assert_array_equal(preprocess(xs, 100, n_threads=1), out)
    # the public names resolve through the package; eskin.preprocess is callable even though
    # the submodule eskin.preprocess has been imported (and shadows the attribute)
    np.testing.assert_array_equal(eskin.preprocess(xs, 100), out)
    assert eskin.WindowConfig is WindowConfig and eskin.detect_windows is detect_windows


def test_preprocess_reads_h5py_datasets_in_chunks(tmp_path):
    n = 37  # more than one chunk
    rng = np.random.default_rng(8)
    xs = rng.normal(0, 20, (n, 2, 2, 3000))
    for i in range(n):
        a = 500 + 30 * i
        xs[i, :, :, a : a + 1000] += 200 * np.sin(np.arange(1000) / 3.0)
    xs = np.round(xs).astype(np.int16)
    lengths = rng.integers(2500, 3001, n)
    with h5py.File(tmp_path / "c.h5", "w") as f:
        f.create_dataset("s", data=xs, chunks=(1, 2, 2, 3000))
    with h5py.File(tmp_path / "c.h5", "r") as f:
        got = preprocess(f["s"], 20, lengths=lengths)
        wins = detect_windows(f["s"], lengths)
    np.testing.assert_array_equal(got, preprocess(xs, 20, lengths=lengths))
    np.testing.assert_array_equal(wins, detect_windows(xs, lengths))
    # an error in a later chunk names the recording's index in the whole dataset
    xf = xs.astype(float)
    xf[35, 1, 0, 17] = np.nan
    with h5py.File(tmp_path / "d.h5", "w") as f:
        f.create_dataset("s", data=xf)
    with h5py.File(tmp_path / "d.h5", "r") as f:
        with pytest.raises(ValueError, match=r"signals\[35\] has a non-finite value at taxel 2"):
            preprocess(f["s"], 20)


@pytest.mark.parametrize(
    "call,match",
    [
        (lambda x: preprocess(x, 0), "D = 0"),
        (lambda x: preprocess(x, 2.5), "D = 2.5"),
        (lambda x: preprocess(x, True), "D = True"),
        (lambda x: preprocess(x[0, 0], 10), "shape"),
        (lambda x: preprocess(x[None], 10), "shape"),
        (lambda x: preprocess(x, 10, lengths=[0, 100]), r"lengths\[0\] = 0"),
        (lambda x: preprocess(x, 10, lengths=[100, 5000]), r"lengths\[1\] = 5000"),
        (lambda x: preprocess(x, 10, lengths=[100]), "lengths must have shape"),
        (lambda x: preprocess(x, 10, lengths=[100.5, 3]), "integers"),
        (lambda x: preprocess(x, 10, window="hann"), "window"),
        (lambda x: preprocess(x, 10, subsample="random"), "subsample"),
        (lambda x: preprocess(x, 10, sample_rate_hz=0), "sample_rate_hz"),
        (lambda x: preprocess(x, 10, config=3), "config"),
        (lambda x: preprocess(x, 10, window=[[0, 10]]), "window"),
        (lambda x: preprocess(x, 10, window=[[0, 10], [50, 40]]), r"windows\[1\]"),
        (lambda x: preprocess(x.astype(complex), 10), "dtype"),
        (lambda x: detect_windows("abc"), "signals"),
    ],
)
def test_errors(call, match):
    x = np.zeros((2, 4, 4, 3000), dtype=np.int16)
    with pytest.raises(ValueError, match=match):
        call(x)


def test_nan_names_recording_taxel_and_sample():
    x = np.zeros((3, 4, 4, 1000))
    x[2, 1, 2, 500] = np.nan
    msg = r"signals\[2\] has a non-finite value at taxel 6, sample 500"
    with pytest.raises(ValueError, match=msg):
        preprocess(x, 10)
    with pytest.raises(ValueError, match=r"signals\[2\]"):
        preprocess(x, 10, window="none")
    # NaN beyond the valid length is padding and is ignored
    assert preprocess(x, 10, lengths=[1000, 1000, 400]).shape == (3, 4, 4, 10)


def test_eskin_preprocess_is_both_the_function_and_the_module():
    import eskin.signal.preprocess as module  # noqa: PLC0415

    assert callable(eskin.preprocess) and eskin.preprocess.WindowConfig is WindowConfig
    assert module.preprocess is preprocess
    x = recording(3000, [(1000, 2000, 150.0)], 9)
    np.testing.assert_array_equal(eskin.preprocess(x, 10), preprocess(x, 10))
    np.testing.assert_array_equal(module(x, 10, window="none"), preprocess(x, 10, window="none"))


# --------------------------------------------------------------------------- simulator truth


def test_windows_against_the_simulators_true_contact_interval(tmp_path, capsys):
    """Detected windows vs /recordings/contact_interval on a small simulated campaign.

    The true interval runs from the first to the last instant of contact; parts of a gesture
    that give no electrode signal (a slow press, a washer resting or rolling off the electrodes,
    the end of a release) are invisible to any detector, so the error has a floor set by the
    physics, highest for the washer. The bounds leave a margin over what the defaults give on
    240 simulated recordings (docs/preprocessing.md); the distribution is printed.
    """
    from eskin.data.campaign import load_campaign
    from eskin.data.simulator import simulate

    path = simulate(tmp_path / "c.h5", participants=4, seed=7)
    with load_campaign(path) as c:
        rate = c.sample_rate_hz
        t = detect_touches(c.signals, c.lengths, rate)
        truth = np.asarray(c.contact_interval, dtype=np.int64)
        modality = np.asarray(c.modality)
        names = list(c.modalities)
        # an independent numpy implementation of the same detector finds the same windows
        ref_windows = [
            _ref.preprocess(c.recording(i), 20, rate, length=int(c.lengths[i]))[1]
            for i in range(0, len(c), 3)
        ]
    np.testing.assert_array_equal(np.array(ref_windows), t.windows[::3])
    assert t.found.all()
    ms = 1000.0 / rate
    err = {
        "start-onset": (t.start - truth[:, 0]) * ms,
        "stop-offset": (t.stop - truth[:, 1]) * ms,
        "detected onset": (t.onset - truth[:, 0]) * ms,
        "detected offset": (t.offset - truth[:, 1]) * ms,
    }
    inter = np.clip(np.minimum(t.stop, truth[:, 1]) - np.maximum(t.start, truth[:, 0]), 0, None)
    iou = inter / (np.maximum(t.stop, truth[:, 1]) - np.minimum(t.start, truth[:, 0]))
    with capsys.disabled():
        print(f"\nwindow vs true contact interval, {len(truth)} SIMULATED recordings (ms):")
        for m, name in [(None, "all")] + list(enumerate(names)):
            sel = np.ones(len(truth), bool) if m is None else modality == m
            print(f"  {name} (n={sel.sum()}), IoU median {np.median(iou[sel]):.2f}")
            for key, e in err.items():
                a = np.abs(e[sel])
                p = np.percentile(a, [50, 90, 100])
                print(f"    {key:16s} |err| median {p[0]:6.0f}  p90 {p[1]:6.0f}  max {p[2]:6.0f}"
                      f"   signed median {np.median(e[sel]):6.0f}")
    start, stop = np.abs(err["start-onset"]), np.abs(err["stop-offset"])
    assert np.median(start) < 150 and np.median(stop) < 300
    assert np.median(iou) > 0.65
    # brush and finger make signal from first to last contact: tighter bounds
    bf = modality != names.index("washer")
    assert np.median(start[bf]) < 100 and np.percentile(start[bf], 90) < 500
    assert np.median(stop[bf]) < 300 and np.percentile(stop[bf], 90) < 600
    assert np.median(start[~bf]) < 1200 and np.median(stop[~bf]) < 1200
