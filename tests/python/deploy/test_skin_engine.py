"""The skin engine (eskin.deploy.skin_engine): many patches over shared models give, patch by
patch, exactly the decisions of one StreamClassifier per patch (values, labels, windows, sample
indices) whatever the block sizes, patch orders and model table; the per-patch memory bound of a
4x4 patch at 3 kHz with the default detector; skin events and positions; bad arguments refused
with a one-line message. Real compiled core, real simulated recordings."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

import eskin
from eskin import _core
from eskin.deploy.export import CompiledModel, MachineSpec, ModelSpec, model_to_bytes
from eskin.deploy.skin_engine import SkinEngine

D = 20


@pytest.fixture(scope="module")
def campaign(tmp_path_factory):
    """A small simulated campaign: 3 participants, run 2, 18 recordings (simulated data)."""
    path = tmp_path_factory.mktemp("campaign") / "sim.h5"
    eskin.simulate(path, participants=3, seed=5, runs=(2,))
    return eskin.load_campaign(path, in_memory=True)


def _spec(campaign, seed):
    """One-vs-all machines whose support vectors are the campaign's own patterns; the default
    detector (WindowConfig())."""
    rng = np.random.default_rng(seed)
    X = eskin.preprocess(
        np.asarray(campaign.signals),
        D,
        lengths=np.asarray(campaign.lengths),
        sample_rate_hz=campaign.sample_rate_hz,
    )
    alphas = eskin.resolve_alphas(X.shape[1:], "half")
    machines = [
        MachineSpec(
            k,
            -1,
            float(rng.normal(0, 0.1)),
            alphas,
            (1.5, 1.2, 2.0),
            X[np.sort(rng.choice(len(X), 6, replace=False))],
            rng.normal(0, 1, 6),
        )
        for k in range(3)
    ]
    return ModelSpec(
        class_names=list(campaign.modalities[:3]),
        rule="one_vs_all",
        machines=machines,
        D=D,
        grid_shape=X.shape[1:3],
        window="energy",
        subsample="algorithm2",
        sample_rate_hz=campaign.sample_rate_hz,
        window_config=eskin.WindowConfig(),
    )


@pytest.fixture(scope="module")
def models(campaign):
    return [
        CompiledModel(model_to_bytes(_spec(campaign, 0), "float32")),
        CompiledModel(model_to_bytes(_spec(campaign, 1), "float64")),
    ]


def _stream(campaign, rng, n_recordings):
    """A patch's stream: recordings of the campaign back to back, (T, 16) int16 codes."""
    sig, lengths = np.asarray(campaign.signals), np.asarray(campaign.lengths)
    parts = []
    for i in rng.choice(len(sig), n_recordings):
        rec = sig[i, :, :, : lengths[i]]
        parts.append(rec.reshape(-1, rec.shape[-1]).T)
    return np.ascontiguousarray(np.concatenate(parts), dtype=np.int16)


def _reference(model, stream):
    """(sample, label, dont_know, window, values) of a StreamClassifier fed the stream."""
    events = _core.StreamClassifier(model._model).feed(stream.astype(np.float64), flush=True)
    return [
        (e["sample"], e["label"], e["dont_know"], tuple(e["window"]), tuple(e["values"]))
        for e in events
        if "label" in e
    ]


def _per_patch(decisions, n_patches):
    out = [[] for _ in range(n_patches)]
    for d in decisions:
        out[d.patch].append((d.sample, d.label, d.dont_know, d.window, d.values))
    return out


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_each_patch_decides_as_its_own_stream_classifier(campaign, models, seed):
    rng = np.random.default_rng(seed)
    P = 3 + seed
    table = [int(v) for v in rng.integers(0, 2, P)]
    streams = [_stream(campaign, rng, 4) for _ in range(P)]
    T = min(len(s) for s in streams)
    streams = [s[:T] for s in streams]
    want = [_reference(models[table[p]], streams[p]) for p in range(P)]
    assert sum(map(len, want)) >= P

    engine = SkinEngine(models, patch_model=table)
    block = np.stack(streams, axis=1)  # (T, P, 16)
    got, t = [], 0
    while t < T:
        n = int(rng.integers(1, 4000))
        got += engine.push_interleaved(block[t : t + n])
        t += n
    got += engine.flush()
    assert _per_patch(got, P) == want
    assert [(d.sample, d.patch) for d in got] == sorted((d.sample, d.patch) for d in got)
    assert all(d.class_name == models[d.model].class_names[d.label] for d in got)

    engine.reset()
    got, at = [], [0] * P
    while min(at) < T:
        p = int(rng.integers(0, P))
        n = int(rng.integers(1, 6000))
        got += engine.push(p, streams[p][at[p] : at[p] + n])
        at[p] = min(T, at[p] + n)
    got += engine.flush()
    assert _per_patch(got, P) == want


def test_a_default_4x4_patch_at_3khz_fits_64_kib(models):
    engine = SkinEngine(models[0], n_patches=1000)
    assert models[0].grid_shape == (4, 4) and models[0].sample_rate_hz == 3000.0
    default = eskin.WindowConfig()
    for field in ("window_samples", "lookback_s", "pad_before_s", "hold_s", "frame_s"):
        assert models[0].window_config[field] == getattr(default, field)
    assert 16384 < engine.bytes_per_patch <= 65536


def _held_patches(campaign, seed: int, P: int = 4):
    """A model with a 1 s hold (what `eskin train` chooses for the built-in simulator's
    press-and-hold), P patch streams interleaved (T, P, 16) and each patch's decisions by a
    StreamClassifier of its own."""
    spec = replace(_spec(campaign, 0), window_config=eskin.WindowConfig(hold_s=1.0))
    held = CompiledModel(model_to_bytes(spec, "float32"))
    rng = np.random.default_rng(seed)
    streams = [_stream(campaign, rng, 6) for _ in range(P)]
    T = min(len(s) for s in streams)
    block = np.ascontiguousarray(np.stack([s[:T] for s in streams], axis=1))
    return held, block, [_reference(held, s[:T]) for s in streams]


def test_shared_window_buffers_keep_the_decisions_they_have_room_for(campaign, models):
    # the 1 s hold: the whole pre-onset ring stays per patch, the window buffers are shared
    P = 4
    held, block, want = _held_patches(campaign, 3, P)

    def run(buffers):
        engine = SkinEngine(held, n_patches=P, window_buffers=buffers)
        got = engine.push_interleaved(block) + engine.flush()
        return engine, _per_patch(got, P)

    own, got_own = run(0)
    assert got_own == want and own.unbuffered == 0 and own.window_buffers_peak == 0
    every, got_every = run(P)
    assert got_every == want and every.unbuffered == 0
    assert 2 <= every.window_buffers_peak <= P
    one, got_one = run(1)
    assert one.unbuffered > 0 and one.window_buffers_peak == 1
    assert sum(map(len, got_one)) + one.unbuffered == sum(map(len, want))
    assert all(set(g) <= set(w) for g, w in zip(got_one, want))
    assert one.bytes_per_patch < own.bytes_per_patch


def test_chunked_window_store_keeps_the_decisions_it_has_room_for(campaign, models):
    # the 1 s hold again; the windows' kept samples (window_samples = 1024, halving as they
    # grow) in chunks of a shared pool, taken as a window grows, given back as it halves and ends
    P = 4
    held, block, want = _held_patches(campaign, 4, P)

    def run(buffers, chunk):
        engine = SkinEngine(held, n_patches=P, window_buffers=buffers, window_chunk_samples=chunk)
        got = engine.push_interleaved(block) + engine.flush()
        return engine, _per_patch(got, P)

    whole, got_whole = run(P, 0)
    assert got_whole == want and whole.window_pool_samples == 1024
    for chunk in (64, 100):
        every, got_every = run(P, chunk)
        assert got_every == want and every.unbuffered == 0 and every.dropped == 0
        per_window = -(-1024 // chunk)
        assert every.window_pool_size == P * per_window and every.window_pool_samples == chunk
        assert 0 < every.window_buffers_peak <= whole.window_buffers_peak * per_window
        every.reset()
        assert every.window_pool_in_use == 0

        one, got_one = run(1, chunk)  # one window's worth of chunks for four patches
        assert one.unbuffered > 0 and one.window_buffers_peak == one.window_pool_size
        assert sum(map(len, got_one)) + one.unbuffered == sum(map(len, want))
        assert all(set(g) <= set(w) for g, w in zip(got_one, want))
        one.reset()
        assert one.window_pool_in_use == 0 and one.unbuffered == 0
        again = one.push_interleaved(block) + one.flush()
        assert _per_patch(again, P) == got_one  # reset gave every chunk back


def test_adjacent_simultaneous_touches_are_one_event_with_positions(campaign, models):
    rng = np.random.default_rng(7)
    s = _stream(campaign, rng, 2)
    grid = np.stack(
        np.meshgrid(np.arange(4.0), np.arange(4.0), indexing="ij"), axis=-1
    )  # (4, 4, 2)
    engine = SkinEngine(
        models[0],
        n_patches=3,
        adjacency=[(0, 1)],
        positions=[grid * 0.01 + [p, 0.0] for p in range(3)],
    )
    got = engine.push_interleaved(np.stack([s, s, s], axis=1)) + engine.flush()
    assert len(got) >= 3 and len(got) % 3 == 0
    for k in range(0, len(got), 3):
        a, b, c = sorted(got[k : k + 3], key=lambda d: d.patch)
        assert a.window == b.window == c.window
        assert a.event == b.event != c.event
        assert len(a.position) == 2
        assert b.position[0] == pytest.approx(a.position[0] + 1.0)
        assert 0.0 <= a.position[0] <= 0.03 and 0.0 <= a.position[1] <= 0.03


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"n_patches": None}, "n_patches: give the number of patches, or patch_model"),
        ({"patch_model": [0, 2]}, r"patch_model\[1\] = 2: must be a model index in \[0, 2\)"),
        ({"n_patches": 0}, "SkinConfig.n_patches = 0: must be in"),
        (
            {"n_patches": 2, "adjacency": [(0, 2)]},
            r"SkinConfig.adjacency\[0\] = \(0, 2\): must be two different patches in \[0, 2\)",
        ),
        (
            {"n_patches": 2, "positions": [np.zeros((16, 2))]},
            "positions: 1 patches, the skin has 2",
        ),
        (
            {"n_patches": 1, "positions": [np.zeros((15, 3))]},
            r"positions\[0\]: shape \(15, 3\), expected \(16, 2\) or \(16, 3\)",
        ),
        ({"n_patches": 1, "chunk_samples": -5}, "SkinConfig.chunk_samples = -5"),
        ({"n_patches": 2, "window_buffers": 3}, r"SkinConfig.window_buffers = 3: must be in \[0, 2\]"),
        (
            {"n_patches": 2, "window_buffers": 1, "window_chunk_samples": -1},
            r"SkinConfig.window_chunk_samples = -1: must be in \[0, 1024\] \(0: whole window",
        ),
        (
            {"n_patches": 2, "window_buffers": 1, "window_chunk_samples": 1025},
            r"SkinConfig.window_chunk_samples = 1025: must be in \[0, 1024\]",
        ),
        (
            {"n_patches": 2, "window_chunk_samples": 64},
            r"SkinConfig.window_chunk_samples = 64: needs shared window buffers \(window_buffers",
        ),
    ],
)
def test_bad_construction_is_a_one_line_value_error(models, kwargs, message):
    with pytest.raises(ValueError, match=message):
        SkinEngine(models, **kwargs)


def test_bad_samples_are_refused(models):
    engine = SkinEngine(models[0], n_patches=2)
    with pytest.raises(
        ValueError, match="samples of patch 0: dtype float64, expected int16 ADC codes"
    ):
        engine.push(0, np.zeros((10, 16)))
    with pytest.raises(ValueError, match="outside the int16 codes"):
        engine.push(0, np.full((10, 16), 40000))
    with pytest.raises(ValueError, match=r"samples of patch 1: expected shape \(n, 16\)"):
        engine.push(1, np.zeros((10, 15), np.int16))
    with pytest.raises(ValueError, match=r"patch = 2: must be in \[0, 2\)"):
        engine.push(2, np.zeros((10, 16), np.int16))
    with pytest.raises(ValueError, match=r"block: expected shape \(n, 32\)"):
        engine.push_interleaved(np.zeros((10, 16), np.int16))
    with pytest.raises(
        ValueError, match="models\\[0\\]: a CompiledModel or a .eskin path, got int"
    ):
        SkinEngine([3], n_patches=1)
    assert engine.push(0, np.zeros((10, 4, 4), np.int8)) == []
    assert engine.samples_seen(0) == 10 and engine.samples_seen(1) == 0
