"""Controller targets: the flash and RAM budget of a model (eskin.deploy.target) and
`eskin export --target`, which reports it and refuses a model that does not fit."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import eskin
from eskin.deploy.export import CompiledModel
from eskin.deploy.target import TARGETS, Target, device_budget

TESTS = Path(__file__).resolve().parents[2]
CORPUS = TESTS / "fuzz" / "corpus" / "model"


@pytest.fixture(scope="module")
def campaign(tmp_path_factory):
    """4 participants, run 2 (simulated data)."""
    path = tmp_path_factory.mktemp("campaign") / "sim.h5"
    eskin.simulate(path, participants=4, seed=5, runs=(2,))
    return eskin.load_campaign(path, in_memory=True)


def _model(campaign, D, max_window_s, window_samples=1024):
    """A 3-class tensor-RLS with fixed hyperparameters on the first 3 participants."""
    from eskin.learn.estimators import OneVsAllTouchClassifier, TensorRLS
    from eskin.learn.models import TouchModel

    cfg = eskin.WindowConfig(max_window_s=max_window_s, window_samples=window_samples)
    X = eskin.preprocess(
        np.asarray(campaign.signals),
        D,
        lengths=np.asarray(campaign.lengths),
        sample_rate_hz=campaign.sample_rate_hz,
        config=cfg,
    )
    y = np.asarray(campaign.modality).astype(np.int64)
    train = np.isin(campaign.participant, np.unique(campaign.participant)[:3])
    est = OneVsAllTouchClassifier(TensorRLS(lam=0.1, sigma=0.5, alpha="half"))
    est.fit(X[train], y[train])
    return TouchModel(
        classes=list(campaign.modalities),
        estimator=est,
        machine="rls",
        selection="fixed",
        D=D,
        window="energy",
        subsample="algorithm2",
        sample_rate_hz=campaign.sample_rate_hz,
        grid_shape=(4, 4),
        window_config=cfg,
    )


def test_budget_terms_follow_the_model(campaign):
    cm = CompiledModel.from_model(_model(campaign, 20, 0.5))
    b = device_budget(cm, "cortex-m4")
    assert b.target is TARGETS["cortex-m4"]
    assert b.flash == {"model": cm.file_bytes, "program": TARGETS["cortex-m4"].program_flash_bytes}
    # the detector keeps int16 samples of 16 taxels: the pre-onset ring (pad_before 150 +
    # (lookback 30 frames + 1) x 30 samples) and the bounded window buffer (window_samples 1024
    # of the 0.5 s = 1500 samples), or, unbounded, the longest window
    assert b.ram["detector samples"] == (150 + 31 * 30 + 1024) * 16 * 2
    unbounded = device_budget(CompiledModel.from_model(_model(campaign, 20, 0.5, 0)))
    assert unbounded.ram["detector samples"] == (150 + 31 * 30 + 1500) * 16 * 2
    assert b.fits and b.flash_total < (1 << 20) and b.ram_total < (128 << 10)
    assert b.advice == []
    lines = b.report()
    assert lines[1].startswith(f"flash {b.flash_total} of 1048576 bytes")


def test_a_model_too_large_gets_advice(campaign):
    # an unbounded detector keeps up to 7 s of raw samples: far more than 128 KB of RAM; the
    # default bounded window keeps 1024 samples per taxel of them, whatever max_window_s is
    big = device_budget(CompiledModel.from_model(_model(campaign, 20, 7.0, 0)))
    assert not big.fits and big.ram_total > (128 << 10)
    assert any("--window-samples" in a and "max_window_s 7 s" in a for a in big.advice)
    bounded = device_budget(CompiledModel.from_model(_model(campaign, 20, 7.0)))
    assert bounded.fits and bounded.ram["detector samples"] == (150 + 31 * 30 + 1024) * 16 * 2
    tiny = Target("tiny", "a 64 KB part", 64 << 10, 256 << 10, 40 << 10, 4 << 10)
    small_flash = device_budget(CompiledModel.from_model(_model(campaign, 50, 0.5)), tiny)
    assert not small_flash.fits and any("smaller D" in a for a in small_flash.advice)
    with pytest.raises(ValueError, match="unknown target 'cortex-m7'"):
        device_budget(CompiledModel.from_model(_model(campaign, 20, 0.5)), "cortex-m7")


def _eskin(*args):
    return subprocess.run(
        [sys.executable, "-m", "eskin", *map(str, args)],
        capture_output=True,
        text=True,
        check=False,
    )


def test_cli_export_target_reports_and_refuses(campaign, tmp_path):
    from eskin.learn.models import save_model

    fits = save_model(_model(campaign, 20, 0.5), tmp_path / "fits.joblib")
    res = _eskin(
        "export",
        fits,
        "-o",
        tmp_path / "fits.eskin",
        "--target",
        "cortex-m4",
        "--c-header",
        tmp_path / "fits.h",
    )
    assert res.returncode == 0, res.stderr
    assert "target cortex-m4" in res.stdout and "RAM " in res.stdout
    header = (tmp_path / "fits.h").read_text()
    assert "FITS_ALIGN static const unsigned char fits_data[" in header
    assert "alignas(8)" in header and "view_bytes" in header
    big = save_model(_model(campaign, 20, 7.0, 0), tmp_path / "big.joblib")
    res = _eskin("export", big, "-o", tmp_path / "big.eskin", "--target", "cortex-m4")
    assert res.returncode == 2
    assert "does not fit cortex-m4; nothing written" in res.stderr
    assert "max_window_s" in res.stdout and "Traceback" not in res.stderr
    assert not (tmp_path / "big.eskin").exists()


# the QEMU counts of eskin.deploy.target and the cost model's error on them (docs/mcu.md)


def test_the_instruction_model_reproduces_the_qemu_counts():
    from eskin.deploy.target import (
        INSTRUCTION_CALIBRATION,
        decision_instructions,
        instruction_counts,
        instruction_model_error,
    )

    counts = [c for c in instruction_counts() if c["terms"] is not None]  # the fitted ones
    err = instruction_model_error()
    assert err["points"] == len(INSTRUCTION_CALIBRATION) == len(counts)
    # fitted to several grids, each count predicted within the in-sample error
    grids = {tuple(c["grid"]) for c in counts}
    assert {(1, 4), (3, 5), (4, 4), (8, 8)} <= grids
    assert set(err["leave_one_out_by_grid"]) == {f"{r}x{c}" for r, c in grids}
    assert err["max_fit"] <= err["max_leave_one_out"]
    for grid, D, n_sv, alphas, amplitude, bounded, terms, count in INSTRUCTION_CALIBRATION:
        assert decision_instructions(grid, D, alphas, n_sv, amplitude, bounded, terms) == (
            pytest.approx(count, rel=err["max_fit"] + 1e-9))
    # the SVMs with the amplitude factor the searched default trains are in the calibration
    assert any(amp and bounded for *_, amp, bounded, _, _ in INSTRUCTION_CALIBRATION)
    # more support vectors, a larger alpha or D, the amplitude factor, more taxels: more work
    base = decision_instructions((4, 4), 50, (1, 1, 1), 36)
    assert decision_instructions((4, 4), 50, (1, 1, 1), 84) > base
    assert decision_instructions((4, 4), 50, (2, 2, 8), 36) > base
    assert decision_instructions((4, 4), 100, (1, 1, 1), 36) > base
    assert decision_instructions((4, 4), 50, (1, 1, 1), 36, True) > base
    assert decision_instructions((8, 8), 50, (1, 1, 1), 36) > base
    # by default the window of today's detector, bounded (WindowConfig's window_samples > 0)
    assert eskin.WindowConfig().window_samples > 0
    assert base == decision_instructions((4, 4), 50, (1, 1, 1), 36, False, True)
    assert base != decision_instructions((4, 4), 50, (1, 1, 1), 36, False, False)


def test_the_margin_bounds_every_recorded_decision():
    """estimate x (1 + margin) is at least every count of the data file the benchmark wrote
    (the largest decision of a run where it was recorded), both with the model fitted to every
    count and with the model fitted without the count; and the margin is the smallest that
    does so for the left-out estimates."""
    from eskin.deploy import target

    counts = [c for c in target.instruction_counts() if c["terms"] is not None]  # fitted
    assert len(counts) == len(target._left_out())
    margin = target.instruction_margin()
    assert margin == target.INSTRUCTION_MARGIN and 0 <= margin < 0.5
    ratios = []
    for c, (left_out, _) in zip(counts, target._left_out()):
        observed = c["instr_max"] or c["instr_median"]
        assert c["instr_max"] is None or c["instr_max"] >= c["instr_median"]
        assert left_out * (1 + margin) >= observed * (1 - 1e-12)
        full = target.decision_instructions(c["grid"], c["D"], c["alpha_store"], c["n_support"],
                                            c["amplitude"], c["bounded_window"], c["terms"])
        assert full * (1 + margin) >= observed
        ratios.append(observed / left_out)
    assert max(ratios) == pytest.approx(1 + margin)
    # the counts with a largest decision come from the device benchmark, on every grid
    recorded = [c for c in counts if c["instr_max"]]
    assert {tuple(c["grid"]) for c in recorded} >= {(1, 4), (3, 5), (4, 4), (8, 8)}
    assert all("bench_device_budget" in c["source"] for c in recorded)


def test_the_search_estimate_matches_the_compiled_model(campaign):
    """What the recipe search estimates for a candidate before fitting it is what
    device_budget reads from the compiled model (same support vectors)."""
    from eskin.deploy.target import estimate_model, parse_budget

    model = _model(campaign, 20, 0.5)
    cm = CompiledModel.from_model(model)
    budget = parse_budget(None, "cortex-m4")
    est = estimate_model(budget, (4, 4), 20, tuple(cm.alpha_store), cm.n_support, 3, False,
                         model.window_config, campaign.sample_rate_hz)
    real = device_budget(cm, budget.target)
    # a tensor-RLS keeps every pattern in every machine, as the estimate assumes: its RAM is
    # the model's to the byte, its flash the file's plus under 256 bytes (the estimate's fixed
    # 1800 bytes of header and sections), never less
    assert est["ram"] == real.ram_total
    assert 0 <= est["flash"] - real.flash_total < 256
    # each machine term is a u32 support-vector index and a float32 coefficient in the file
    # (docs/model-format.md): one machine more is 8 bytes per support vector more
    more = estimate_model(budget, (4, 4), 20, tuple(cm.alpha_store), cm.n_support, 4, False,
                          model.window_config, campaign.sample_rate_hz)
    assert more["flash"] - est["flash"] == cm.n_support * (4 + 4)
    with pytest.raises(ValueError, match="--budget ram=lots: not a number"):
        parse_budget("ram=lots")
    with pytest.raises(ValueError, match="expected flash=..,ram=..,instr=.."):
        parse_budget("speed=3")
    assert parse_budget("flash=512K,instr=2M").flash_bytes == 512 << 10
    assert parse_budget("flash=512K,instr=2M").instructions == 2e6


def test_a_support_budget_lets_a_larger_candidate_fit(campaign):
    """With --max-support, the search estimates a candidate's model at the bounded number of
    support vectors: a candidate too large with 800 fits with 40, and no bound changes
    nothing below it."""
    from eskin.deploy.target import candidate_budget, parse_budget
    from eskin.learn.recipes import Candidate, Recipe

    budget = parse_budget(None, "cortex-m4")
    wc = _model(campaign, 20, 0.5).window_config
    big = Candidate(Recipe("svm", 50, "algorithm2", "all"), 0.1, 1.0, "1", None)
    free = candidate_budget(budget, (4, 4), campaign.sample_rate_hz, wc, 3)
    bound = candidate_budget(budget, (4, 4), campaign.sample_rate_hz, wc, 3, max_support=40)
    assert not free.fits(big, 800) and bound.fits(big, 800)
    assert free.fits(big, 40) == bound.fits(big, 40) == bound.fits(big, 30)


def test_the_budget_gives_the_most_support_vectors_that_fit(campaign):
    """``largest(candidate, n)``: n when the model fits with n support vectors, else the most
    that fit (fits with it, not with one more), 0 when none does; absent with --max-support."""
    from eskin.deploy.target import candidate_budget, parse_budget
    from eskin.learn.recipes import Candidate, Recipe

    wc = _model(campaign, 20, 0.5).window_config
    rate = campaign.sample_rate_hz
    q50 = Candidate(Recipe("svm", 50, "algorithm2", "all"), 0.1, 1.0, "Q", 1.0)
    b = candidate_budget(parse_budget(None, "cortex-m4"), (4, 4), rate, wc, 3)
    most = b.largest(q50, 500)
    assert 20 < most < 500
    assert b.fits(q50, most) and not b.fits(q50, most + 1)
    # the estimate times (1 + INSTRUCTION_MARGIN) must fit: the cost model's error
    from eskin.deploy.target import INSTRUCTION_MARGIN, decision_instructions

    def instr(n):
        return decision_instructions((4, 4), 50, (4, 4, 16), n, True, True)

    assert 0 < INSTRUCTION_MARGIN < 0.5
    assert instr(most) * (1 + INSTRUCTION_MARGIN) <= 1.5e6 < instr(most + 1) * (
        1 + INSTRUCTION_MARGIN)
    assert b.largest(q50, most - 3) == most - 3
    tiny = candidate_budget(parse_budget("instr=100K", "cortex-m4"), (4, 4), rate, wc, 3)
    assert tiny.largest(q50, 500) == 0
    assert candidate_budget(parse_budget(None, "cortex-m4"), (4, 4), rate, wc, 3,
                            max_support=40).largest is None


@pytest.mark.parametrize("text,problem", [
    ("flash=1M,flash=2M", "--budget flash=1M,flash=2M: flash is given twice"),
    ("ram=64K,RAM=128K", "--budget ram=64K,RAM=128K: ram is given twice"),
    ("", "--budget '' is empty: give flash=..,ram=..,instr=.. (or leave --budget out for the "
         "target's own budget)"),
    (" , ", "--budget ' , ' is empty: "),
])
def test_a_repeated_key_or_an_empty_budget_is_refused(text, problem):
    """`--budget flash=1M,flash=2M` took the last, `--budget ""` meant the target's budget."""
    from eskin.deploy.target import parse_budget

    with pytest.raises(ValueError) as info:
        parse_budget(text)
    assert str(info.value).startswith(problem)
    assert parse_budget("flash=1M,").flash_bytes == 1 << 20  # a trailing comma is no entry


def test_the_ram_parts_of_a_model_are_its_buffers_to_the_byte(campaign):
    """The detector's state and the input's workspace of a 4x4, D 20 float32 model, each term
    written out: the detector keeps two noise frames per noise frame counted, the lookback
    frames and two per taxel, 8-byte pairs; the workspace the scaled pattern (double), the
    bases, two float copies of the tensor, two q x q factors of the largest mode, a column of
    the longest basis and the 64 16-byte reflectors."""
    from eskin import _core

    model = _model(campaign, 20, 0.5)
    cm = CompiledModel.from_model(model)
    b = device_budget(cm, "cortex-m4")
    assert not cm.is_float64
    p = _core.window_config_resolve(
        np.array([cm.window_config[k] for k in _core.WINDOW_CONFIG_FIELDS]), cm.sample_rate_hz)
    assert p["lookback_frames"] == 30
    assert b.ram["detector state"] == 2 * (2 * p["noise_frames"] + 30 + 2 * 16) * 8
    a0, a1, a2 = cm.alpha_store  # N = 80, 80, 16 (4 x 4 x 20)
    bases = 80 * a0 + 80 * a1 + 16 * a2
    assert b.ram["input workspace"] == (
        320 * 8 + bases * 4 + 2 * 320 * 4 + 2 * 16 * 16 * 4 + 80 * 4 + 16 * 64)
    assert b.ram["statics and stack"] == TARGETS["cortex-m4"].program_ram_bytes


def test_the_advice_names_the_rings_bytes_per_tenth_of_a_second(campaign):
    """An unbounded 7 s window: the advice gives the ring's bytes per 0.1 s, 16 taxels x 2
    bytes x the rate / 10."""
    big = device_budget(CompiledModel.from_model(_model(campaign, 20, 7.0, 0)))
    per = 16 * 2 * campaign.sample_rate_hz / 10
    assert per > 100
    assert any(f"{per:.0f} bytes per 0.1 s of ring" in a for a in big.advice), big.advice


def test_the_instruction_features_of_an_uneven_grid_term_by_term():
    """A 3x5 grid, D 20 (N = 100, 60, 15), alphas 1, 2, 2, 10 support vectors: the features
    of the cost model, each computed by hand (docs/mcu.md)."""
    from eskin.deploy.target import _instruction_features

    f = _instruction_features((3, 5), 20, (1, 2, 2), 10, amplitude=True, bounded_window=True,
                              terms=25)
    # 1, taxels, size, QR sum L q^2 (100*9 + 60*25 + 20*225), Jacobi q^3 (27 + 125 + 15^3:
    # mode 2's alpha 2 is below its N of 15), output columns alpha L q (1*100*3 + 2*60*5), the
    # support vectors, their overlaps' inner loops (100*5 + 60*10 + 15*10 per vector), the
    # amplitude factor, the kernel terms, the bounded window
    assert f.tolist() == [1, 15, 300, 6900, 3527, 900, 10, 12500, 10, 25, 300]
    g = _instruction_features((3, 5), 20, (1, 2, 2), 10)
    assert g.tolist() == [1, 15, 300, 6900, 3527, 900, 10, 12500, 0, 30, 300]
    assert _instruction_features((3, 5), 20, (1, 2, 2), 10, bounded_window=False)[-1] == 0


@pytest.mark.parametrize("dims,alphas,jacobi,columns", [
    # N = 8, 8, 4: mode 2 is square (4 x 4): its Jacobi and its output columns both counted
    ((2, 2, 4), (1, 1, 4), 8 + 8 + 64, 1 * 8 * 2 + 1 * 8 * 2 + 4 * 4 * 4),
    # N = 80, 20, 4: mode 2 (20 rows > N = 4) with alpha 4 = N proves full rank, no Jacobi
    ((1, 4, 20), (1, 1, 4), 1 + 64, 1 * 80 * 1 + 1 * 20 * 4),
    ((1, 4, 20), (1, 1, 3), 1 + 64 + 64, 1 * 80 * 1 + 1 * 20 * 4),
])
def test_the_bases_terms_count_each_mode_by_its_shape(dims, alphas, jacobi, columns):
    from eskin.deploy.target import _basis_terms

    assert _basis_terms(dims, alphas) == (jacobi, columns)


def test_the_leave_one_out_error_is_the_largest_relative_error_of_the_left_out_estimates():
    from eskin.deploy import target

    err = target.instruction_model_error()
    counts = [c for c in target.instruction_counts() if c["terms"] is not None]
    loo = [abs(est - c["instr_median"]) / c["instr_median"]
           for c, (est, _) in zip(counts, target._left_out())]
    assert err["max_leave_one_out"] == max(loo) == max(err["leave_one_out_by_grid"].values())
    assert 0 < err["max_leave_one_out"] < 0.5
    # a grid whose counts the other grids can predict has its leave-grid-out error
    fitted = {g: v for g, v in err["leave_grid_out"].items() if v is not None}
    assert fitted and all(0 <= v < 1 for v in fitted.values())


@pytest.mark.parametrize("text,value", [
    ("instr=1500", 1500.0), ("instr=1.5K", 1500.0), ("instr=2M", 2e6), ("instr=0.002G", 2e6),
    ("instr=3k", 3000.0),
])
def test_instructions_are_in_decimal_units(text, value):
    from eskin.deploy.target import parse_budget

    assert parse_budget(text).instructions == value


def test_a_budget_of_exactly_the_estimate_fits_and_one_less_does_not(campaign):
    """The candidate check and the compiled model's check at their boundaries: a budget of
    exactly the estimated flash, RAM or instruction bound fits, one byte (one instruction)
    less in any of them does not."""
    from eskin.deploy.target import (
        INSTRUCTION_MARGIN,
        _stored_alphas,
        candidate_budget,
        estimate_model,
        model_fits,
        parse_budget,
    )
    from eskin.learn.recipes import Candidate, Recipe

    model = _model(campaign, 20, 0.5)
    wc, rate = model.window_config, campaign.sample_rate_hz
    c = Candidate(Recipe("svm", 20, "algorithm2", "all"), 0.1, 1.0, "1", None)
    est = estimate_model(parse_budget(None), (4, 4), 20, _stored_alphas((4, 4), 20, "1"), 30, 3,
                         False, wc, rate)
    flash, ram = int(est["flash"]), int(est["ram"])
    instr = est["instructions"] * (1 + INSTRUCTION_MARGIN)

    def fits(f, r, i):
        return candidate_budget(parse_budget(f"flash={f},ram={r},instr={i!r}"), (4, 4), rate,
                                wc, 3).fits(c, 30)

    assert fits(flash, ram, instr)
    assert not fits(flash - 1, ram, instr)
    assert not fits(flash, ram - 1, instr)
    assert not fits(flash, ram, instr - 1)
    from eskin.deploy.export import model_to_bytes, spec_from_model

    data = model_to_bytes(spec_from_model(model), "float32")
    ok, fig = model_fits(data, parse_budget("flash=1G,ram=1G,instr=1G"))
    assert ok
    exact = {"flash": int(fig["flash"]), "ram": int(fig["ram"]), "instr": fig["instructions"]}
    for key, less in (("flash", 1), ("ram", 1), ("instr", 1.0)):
        given = dict(exact)
        assert model_fits(data, parse_budget(",".join(f"{k}={v!r}" for k, v in given.items())))[0]
        given[key] -= less
        assert not model_fits(
            data, parse_budget(",".join(f"{k}={v!r}" for k, v in given.items())))[0], key


def test_sizes_are_in_binary_units():
    from eskin.deploy.target import parse_budget

    b = parse_budget("flash=1G,ram=3M")
    assert (b.flash_bytes, b.ram_bytes) == (1 << 30, 3 << 20)
    assert parse_budget("flash=1000,ram=2K").ram_bytes == 2048
    assert parse_budget("flash=1000,ram=2KB").flash_bytes == 1000


def test_the_estimate_counts_the_amplitude_factor_and_the_unbounded_window(campaign):
    """The amplitude factor stores one double per support vector in the file; a window
    configuration without the bounded window (window_samples 0) is estimated as such."""
    from eskin.deploy.target import _stored_alphas, decision_instructions, estimate_model
    from eskin.deploy.target import parse_budget

    rate = campaign.sample_rate_hz
    alphas = _stored_alphas((4, 4), 20, "1")

    def est(amplitude, wc):
        return estimate_model(parse_budget(None), (4, 4), 20, alphas, 30, 3, amplitude, wc, rate)

    bounded, unbounded = eskin.WindowConfig(max_window_s=0.5), eskin.WindowConfig(
        max_window_s=0.5, window_samples=0)
    assert est(True, bounded)["flash"] - est(False, bounded)["flash"] == 30 * 8
    for wc, is_bounded in ((bounded, True), (unbounded, False)):
        assert est(True, wc)["instructions"] == decision_instructions(
            (4, 4), 20, alphas, 30, True, is_bounded, 90)
    assert est(True, bounded)["instructions"] != est(True, unbounded)["instructions"]


def test_detector_settings_that_leave_room_are_kept_as_they_are(campaign):
    """window_for_budget: settings whose buffers and the smallest model fit the RAM (with room
    to spare, or exactly) come back unchanged, with no note; a budget a byte smaller lowers
    the bounded window and says so."""
    from eskin.deploy.target import _ram_terms, _stored_alphas, parse_budget, window_for_budget

    rate = campaign.sample_rate_hz
    cfg = eskin.WindowConfig(max_window_s=0.5)
    assert window_for_budget(parse_budget(None), (4, 4), rate, cfg) == (cfg, None)
    need = sum(_ram_terms(4, 4, 20, _stored_alphas((4, 4), 20, "1"), 100, 300, 1, True, 4, cfg,
                          rate, parse_budget(None).target).values())
    assert window_for_budget(parse_budget(f"ram={need}"), (4, 4), rate, cfg) == (cfg, None)
    lowered, note = window_for_budget(parse_budget(f"ram={need - 1}"), (4, 4), rate, cfg)
    assert lowered.window_samples == 512 and "window_samples 1024" in note and "-> 512" in note
    # a whole window kept (no bounded window): the longest max_window_s that fits, in 0.01 s
    # steps
    from dataclasses import replace

    whole = eskin.WindowConfig(max_window_s=0.5, window_samples=0)
    need = sum(_ram_terms(4, 4, 20, _stored_alphas((4, 4), 20, "1"), 100, 300, 1, True, 4,
                          replace(whole, max_window_s=0.37), rate,
                          parse_budget(None).target).values())
    lowered, note = window_for_budget(parse_budget(f"ram={need}"), (4, 4), rate, whole)
    assert lowered.max_window_s == 0.37 and "max_window_s 0.5 s -> 0.37 s" in note


def test_the_cortex_m4_budget_is_the_memory_the_device_program_links_into():
    """The target's flash and RAM are the regions mcu/CMakeLists.txt gives the linker script."""
    text = (TESTS.parent / "mcu" / "CMakeLists.txt").read_text()
    kb = dict(re.findall(r"set\(ESKIN_MCU_(FLASH|RAM)_KB (\d+) ", text))
    assert kb == {"FLASH": "1024", "RAM": "128"}  # docs/mcu.md: 1 MB of flash, 128 KB of RAM
    t = TARGETS["cortex-m4"]
    assert (t.flash_bytes, t.ram_bytes) == (int(kb["FLASH"]) * 1024, int(kb["RAM"]) * 1024)


def test_the_model_tables_are_the_device_classifiers_allocations_to_the_byte():
    """The model tables are the bytes the device classifier allocates for the model's tables."""
    cm = CompiledModel((TESTS / "data" / "model_projection_float64.eskin").read_bytes())
    assert cm.n_support == 6 and len({tuple(m["alphas"]) for m in cm.machines}) == 2
    assert [len(m["coef"]) for m in cm.machines] == [4, 4] and cm.sv_log_energy.size == 0
    b = device_budget(cm, "cortex-m4")
    # a float distance per (group, support vector, mode), an int rank per (support vector,
    # mode), a uint32 index and a double coefficient per term, the allocator's 4 KB (docs/mcu.md)
    assert b.ram["model tables"] == 2 * 6 * 3 * 4 + 6 * 3 * 4 + 8 * (4 + 8) + 4096


def test_the_amplitude_factor_keeps_a_log_energy_and_a_gap_per_support_vector():
    """The amplitude factor adds a double log energy and a float gap per support vector."""
    plain = CompiledModel((CORPUS / "tiny_float64.eskin").read_bytes())
    amp = CompiledModel((CORPUS / "tiny_amplitude_float64.eskin").read_bytes())
    for cm in (plain, amp):
        assert cm.n_support == 3 and [len(m["coef"]) for m in cm.machines] == [3]
    assert plain.sv_log_energy.size == 0 and amp.sv_log_energy.size == 3
    tables = 3 * 3 * 4 + 3 * 3 * 4 + 3 * (4 + 8) + 4096
    assert device_budget(plain).ram["model tables"] == tables
    assert device_budget(amp).ram["model tables"] == tables + 3 * (8 + 4)


def test_a_compiled_models_instruction_bound_is_its_estimate_times_one_plus_the_margin():
    """model_fits's instruction bound is the compiled model's estimate times (1 + margin)."""
    from eskin.deploy.target import (
        INSTRUCTION_MARGIN,
        decision_instructions,
        model_fits,
        parse_budget,
    )

    data = (TESTS / "data" / "model_projection_float64.eskin").read_bytes()
    cm = CompiledModel(data)
    assert cm.window_config["window_samples"] == 0 and 0 < INSTRUCTION_MARGIN < 0.5
    estimate = decision_instructions(cm.grid_shape, cm.D, tuple(cm.alpha_store), 6, False,
                                     False, 8)
    ok, fig = model_fits(data, parse_budget("flash=1G,ram=1G,instr=1G"))
    assert ok and fig["estimate"] == estimate
    assert fig["instructions"] == pytest.approx(estimate * (1 + INSTRUCTION_MARGIN), rel=1e-12)
    # the margin is below 0.5: a budget of 1.5 times the estimate fits
    assert model_fits(data, parse_budget(f"flash=1G,ram=1G,instr={1.5 * estimate!r}"))[0]


def test_a_counts_leave_grid_out_estimate_is_fitted_on_the_other_grids_only():
    from eskin.deploy import target

    for c, (_, grid_est) in zip(target._COUNTS, target._left_out()):
        others = [d for d in target._COUNTS if tuple(d["grid"]) != tuple(c["grid"])]
        assert grid_est == pytest.approx(float(target._features_of(c) @ target._fit(others)),
                                         rel=1e-12, abs=0)


def test_the_stored_alphas_of_an_uneven_grid_are_its_own_rows_first():
    """alpha Q on 3 x 5 taxels at D = 20: each mode's rank, rows 3, columns 5, time 15."""
    from eskin.deploy.target import _stored_alphas

    assert _stored_alphas((3, 5), 20, "Q") == (3, 5, 15)
    assert _stored_alphas((5, 3), 20, "Q") == (5, 3, 15)
    assert _stored_alphas((3, 5), 20, "Q/2") == (1, 2, 7)


def test_a_model_filling_the_flash_exactly_fits_and_one_byte_less_does_not():
    from dataclasses import replace

    cm = CompiledModel((TESTS / "data" / "model_projection_float64.eskin").read_bytes())
    roomy = replace(TARGETS["cortex-m4"], ram_bytes=1 << 30)
    exact = replace(roomy, flash_bytes=device_budget(cm, roomy).flash_total)
    assert device_budget(cm, exact).advice == [] and device_budget(cm, exact).fits
    short = replace(exact, flash_bytes=exact.flash_bytes - 1)
    assert device_budget(cm, short).advice[0].startswith("the bases take ")
    assert not device_budget(cm, short).fits
    roomy = replace(TARGETS["cortex-m4"], flash_bytes=1 << 30)
    exact = replace(roomy, ram_bytes=device_budget(cm, roomy).ram_total)
    assert device_budget(cm, exact).fits
    assert not device_budget(cm, replace(exact, ram_bytes=exact.ram_bytes - 1)).fits


def test_targets_and_budgets_are_frozen_and_the_program_ram_is_its_statics_and_stack():
    import dataclasses

    from eskin.deploy.target import program_image

    t = TARGETS["cortex-m4"]
    image = program_image("cortex-m4")
    assert t.program_ram_bytes == image["program_statics_bytes"] + image["stack_bytes"]
    assert t.program_flash_bytes == image["program_flash_bytes"]
    with pytest.raises(dataclasses.FrozenInstanceError):
        t.ram_bytes = 1
    budget = device_budget(CompiledModel((TESTS / "data" / "model_projection_float64.eskin")
                                         .read_bytes()), t)
    with pytest.raises(dataclasses.FrozenInstanceError):
        budget.advice = []


def test_a_budget_describes_itself_in_bytes_and_millions_of_instructions():
    import dataclasses
    from dataclasses import replace

    from eskin.deploy.target import Budget

    b = Budget(TARGETS["cortex-m4"], 524288, 65536, 2.5e6)
    assert b.describe() == (f"{TARGETS['cortex-m4'].name}: flash 524288 B, RAM 65536 B, 2.5 M "
                            f"instructions per decision")
    # six significant digits of millions, rounded at the sixth
    for instructions, shown in ((1234565.6, "1.23457"), (1234564.4, "1.23456")):
        assert replace(b, instructions=instructions).describe().endswith(
            f" {shown} M instructions per decision")
    with pytest.raises(dataclasses.FrozenInstanceError):
        b.instructions = 1.0


def test_the_default_budget_is_the_documented_one_and_a_half_million_instructions():
    from eskin.deploy.target import parse_budget

    assert parse_budget(None).instructions == 1.5e6
    assert "<= 1.5 M instructions per decision" in (TESTS.parent / "docs" / "mcu.md").read_text()


def _svbs_bases_bytes(data: bytes) -> int:
    """The bytes of the support vectors' bases in a .eskin file (docs/model-format.md: SVBS is
    its order, count, grid and D, alpha_store, the ranks padded to 8 bytes, then the bases)."""
    import struct

    from deploy_data import model_sections

    svbs = dict(model_sections(data))[b"SVBS"]
    n_sv = struct.unpack_from("<I", svbs, 4)[0]
    return len(svbs) - 32 - (12 * n_sv + 7) // 8 * 8


@pytest.mark.parametrize("name, dtype_advice", [
    ("model_uneven_float64.eskin", "float32 instead of float64"),
    ("model_projection_float32.eskin", "float16 bases would halve them (not in the model format)")])
def test_the_flash_advice_gives_the_bases_bytes_the_file_holds(name, dtype_advice):
    data = (TESTS / "data" / name).read_bytes()
    cm = CompiledModel(data)
    real = 8 if cm.is_float64 else 4
    rows, cols = cm.grid_shape
    no_flash = Target("no flash", "none", 1, 1 << 30, 0, 0)
    advice = device_budget(cm, no_flash).advice
    assert advice == [
        f"the bases take {_svbs_bases_bytes(data)} bytes (n_sv x sum_z N_z alpha_z x {real}): a "
        f"smaller D shrinks the (rows) and (cols) modes, N = {cols * cm.D} and {rows * cm.D}",
        f"a smaller alpha (alpha_store {tuple(cm.alpha_store)})",
        "fewer support vectors (a tensor-SVM keeps only its support vectors, tensor-RLS every "
        f"training pattern: {cm.n_support} here)",
        dtype_advice]


def test_a_model_filling_the_ram_exactly_gets_no_advice():
    from dataclasses import replace

    cm = CompiledModel((TESTS / "data" / "model_uneven_float64.eskin").read_bytes())
    roomy = replace(TARGETS["cortex-m4"], ram_bytes=1 << 30)
    exact = replace(roomy, ram_bytes=device_budget(cm, roomy).ram_total)
    assert device_budget(cm, exact).advice == []
    advice = device_budget(cm, replace(exact, ram_bytes=exact.ram_bytes - 1)).advice
    assert len(advice) == 1 and advice[0].startswith("the detector keeps lookback_s")
    assert "bound the window with --window-samples (max_window_s" in advice[0]  # a version 1 file


@pytest.mark.parametrize("n, alpha, tiles", [
    (16, 1, [1]), (16, 3, [3]), (16, 4, [4]), (16, 5, [4, 1]), (16, 8, [4, 4]), (16, 11, [4, 4, 3]),
    (16, 15, [4, 4, 4, 3]), (16, 16, []), (16, 17, []), (80, 16, [4, 4, 4, 4])])
def test_the_overlap_counts_the_devices_4x4_tiles_and_nothing_at_full_rank(n, alpha, tiles):
    """cpp/src/model_overlap.cpp: blocks of 4 basis columns, then the 1-3 left, on each side;
    a tile of kb x lb dot products costs kb + lb loads, kb * lb multiply-adds and 2 per entry."""
    from eskin.deploy.target import overlap_instructions

    want = sum(n * (kb + lb + kb * lb + 2) for kb in tiles for lb in tiles)
    assert overlap_instructions(n, alpha) == want
    if alpha == 4:
        assert want == 16 * 26  # 26 instructions per entry for 16 multiply-adds


def test_the_cost_model_is_the_least_squares_fit_of_the_relative_error():
    """The coefficients minimise the sum of squared relative errors over the counts: as small
    a sum as SciPy's least squares on the rows divided by their counts, and smaller than a fit
    of the absolute errors."""
    import scipy.linalg

    from eskin.deploy import target

    counts = [c for c in target.instruction_counts() if c["terms"] is not None]
    A = np.array([target._features_of(c) for c in counts])
    y = np.array([float(c["instr_median"]) for c in counts])

    def relative(coef):
        return float(np.sum(((y - A @ coef) / y) ** 2))

    best = scipy.linalg.lstsq(A / y[:, None], np.ones(len(y)))[0]
    absolute = scipy.linalg.lstsq(A, y)[0]
    assert relative(target._COEF) == pytest.approx(relative(best), rel=1e-9)
    assert relative(target._COEF) < relative(absolute)


def test_the_default_window_is_bounded_and_a_mapping_without_the_field_is_not():
    from eskin.deploy.target import _bounded

    assert _bounded(None) is True and eskin.WindowConfig().window_samples > 0
    assert _bounded(eskin.WindowConfig(window_samples=0)) is False
    assert _bounded({}) is False  # the fields of a file before version 3
    assert _bounded({"window_samples": 64.0}) is True
    assert _bounded({"window_samples": 0.0}) is False


def test_each_left_out_estimate_is_the_fit_without_that_count():
    """The leave-one-out estimates and the margin, recomputed with SciPy's least squares of the
    relative error on the other counts."""
    import scipy.linalg

    from eskin.deploy import target

    counts = [c for c in target.instruction_counts() if c["terms"] is not None]
    left_out = target._left_out()
    ratios = []
    for i in (0, 1, len(counts) // 2, len(counts) - 1):
        rest = counts[:i] + counts[i + 1:]
        A = np.array([target._features_of(c) for c in rest])
        y = np.array([float(c["instr_median"]) for c in rest])
        coef = scipy.linalg.lstsq(A / y[:, None], np.ones(len(y)))[0]
        assert left_out[i][0] == pytest.approx(float(target._features_of(counts[i]) @ coef),
                                               rel=1e-6)
    for c, (est, _) in zip(counts, left_out):
        ratios.append(float(c["instr_max"] or c["instr_median"]) / est - 1.0)
    assert target.instruction_margin() == max(ratios) and 0 < max(ratios) < 1
    assert all(v is not None for v in target.instruction_model_error()["leave_grid_out"].values())


@pytest.mark.parametrize("text, value", [
    ("flash=0", None), ("ram=-1K", None), ("instr=inf", None), ("instr=nanM", None),
    ("instr=0.5M", 500000.0), ("flash=0.5K", 512.0), ("ram=1", 1.0)])
def test_a_budgets_sizes_are_positive_and_finite(text, value):
    from eskin.deploy.target import parse_budget

    key = text.split("=")[0]
    if value is None:
        with pytest.raises(ValueError) as info:
            parse_budget(text)
        assert str(info.value) == f"--budget {text}: must be positive"
        return
    b = parse_budget(text)
    got = {"flash": b.flash_bytes, "ram": b.ram_bytes, "instr": b.instructions}[key]
    assert got == int(value) if key != "instr" else got == value


def test_a_budget_is_named_after_its_target_and_the_text_it_was_given():
    from eskin.deploy.target import parse_budget

    assert parse_budget(None).target.name == "cortex-m4"
    assert parse_budget(None, "cortex-m4").target == TARGETS["cortex-m4"]
    b = parse_budget("ram=64K")
    assert b.target.name == "cortex-m4 (budget ram=64K)" and b.target.ram_bytes == 64 << 10
    assert b.target.program_ram_bytes == TARGETS["cortex-m4"].program_ram_bytes


def test_a_detector_without_lookback_keeps_one_frame_of_it():
    """The device allocates max(1, lookback_frames) frames (cpp/src/preprocess.cpp)."""
    from eskin import _core
    from eskin.deploy.target import _ram_terms

    cfg = eskin.WindowConfig(lookback_s=0.0)
    p = _core.window_config_resolve(np.asarray(cfg.to_array(), dtype=float), 3000.0)
    assert p["lookback_frames"] == 0
    ram = _ram_terms(4, 4, 20, (1, 1, 1), 10, 30, 1, False, 4, cfg, 3000.0, TARGETS["cortex-m4"])
    assert ram["detector state"] == 2 * (2 * p["noise_frames"] + 1 + 2 * 16) * 8


def test_the_window_for_a_budget_takes_no_settings_or_their_fields_as_the_settings():
    from eskin.deploy.target import parse_budget, window_for_budget

    budget = parse_budget("ram=80K")
    want = window_for_budget(budget, (4, 4), 3000.0, eskin.WindowConfig())
    assert want[1] is not None  # lowered: the default does not fit 80 KB
    assert window_for_budget(budget, (4, 4), 3000.0, None) == want
    assert window_for_budget(budget, (4, 4), 3000.0, eskin.WindowConfig().to_dict()) == want


@pytest.mark.parametrize("start, steps", [(1024, (512, 256, 128)), (1000, (500, 250, 128)),
                                         (260, (130, 128)), (130, (128,)),
                                         (518, (258, 128)), (258, (128,))])  # halves 259, 129
def test_the_bounded_window_is_halved_to_even_counts_down_to_128_and_no_further(start, steps):
    """Halving window_samples keeps it even (the detector refuses an odd count) and stops at
    128 per taxel: each step's RAM gets that step, a budget only a smaller window would fit is
    refused."""
    from dataclasses import replace

    from eskin.deploy.target import _ram_terms, _stored_alphas, parse_budget, window_for_budget

    cfg = eskin.WindowConfig(window_samples=start)

    def need(ws):
        return sum(_ram_terms(4, 4, 20, _stored_alphas((4, 4), 20, "1"), 100, 300, 1, True, 4,
                              replace(cfg, window_samples=ws), 3000.0,
                              parse_budget(None).target).values())

    for ws in steps:
        lowered, note = window_for_budget(parse_budget(f"ram={need(ws)}"), (4, 4), 3000.0, cfg)
        assert lowered.window_samples == ws and f"window_samples {start} -> {ws} to fit" in note
    with pytest.raises(ValueError, match=r"the detector's buffers alone exceed the RAM budget"):
        window_for_budget(parse_budget(f"ram={need(126)}"), (4, 4), 3000.0, cfg)


def test_a_whole_window_is_lowered_no_further_than_its_pad_lookback_and_two_frames():
    """max_window_s is lowered in 0.01 s steps down to pad_before_s + lookback_s + 2 frame_s
    (0.1 + 0.2 + 0.02 here, the least the detector takes): a budget that fits there gets it,
    one that needs less is refused."""
    from dataclasses import replace

    from eskin.deploy.target import _ram_terms, _stored_alphas, parse_budget, window_for_budget

    whole = eskin.WindowConfig(max_window_s=0.6, window_samples=0, pad_before_s=0.1,
                               lookback_s=0.2, frame_s=0.01)

    def need(s):
        return sum(_ram_terms(4, 4, 20, _stored_alphas((4, 4), 20, "1"), 100, 300, 1, True, 4,
                              replace(whole, max_window_s=s), 3000.0,
                              parse_budget(None).target).values())

    for s in (0.45, 0.32):  # a budget of exactly a step's RAM stops there
        lowered, note = window_for_budget(parse_budget(f"ram={need(s)}"), (4, 4), 3000.0, whole)
        assert lowered.max_window_s == s and f"max_window_s 0.6 s -> {s:g} s" in note
    with pytest.raises(ValueError, match=r"the detector's buffers alone exceed the RAM budget"):
        window_for_budget(parse_budget(f"ram={need(0.32) - 1}"), (4, 4), 3000.0, whole)


def test_a_two_class_problem_is_one_machine_and_k_classes_k_machines(campaign):
    """The kernel terms a candidate is estimated with: one machine for two classes (the binary
    rule), one per class otherwise, each holding every support vector at most."""
    from eskin.deploy.target import INSTRUCTION_MARGIN, candidate_budget, decision_instructions
    from eskin.deploy.target import parse_budget
    from eskin.learn.recipes import Candidate, Recipe

    wc = _model(campaign, 20, 0.5).window_config
    q50 = Candidate(Recipe("svm", 50, "algorithm2", "all"), 0.1, 1.0, "Q", 1.0)
    budget = parse_budget("flash=64M,ram=64M", "cortex-m4")  # only the instructions bind
    for n_classes, machines in ((2, 1), (3, 3), (4, 4), (6, 6)):
        most = candidate_budget(budget, (4, 4), campaign.sample_rate_hz, wc, n_classes
                                ).largest(q50, 2000)

        def bound(n):
            return decision_instructions((4, 4), 50, (4, 4, 16), n, True, True,
                                         n * machines) * (1 + INSTRUCTION_MARGIN)

        assert bound(most) <= 1.5e6 < bound(most + 1), (n_classes, most)


def test_a_whole_windows_steps_are_taken_to_the_microsecond(campaign):
    """window_for_budget lowers a whole window's max_window_s in 0.01 s steps, each step and
    the floor (pad_before_s + lookback_s + two frames) to the microsecond: from 4 us less than
    a step above the floor no step is taken (it would cross the floor by 4 us, and the budget
    that needs it is refused); from 0.4 us less, the step lands on the floor (binary noise
    below the microsecond is not a crossing) and fits."""
    from dataclasses import replace

    from eskin.deploy.target import _ram_terms, _stored_alphas, parse_budget, window_for_budget

    rate = campaign.sample_rate_hz
    whole = eskin.WindowConfig(window_samples=0)
    floor = round(whole.pad_before_s + whole.lookback_s + 2 * whole.frame_s, 6)

    def need(max_window_s: float) -> int:
        return sum(_ram_terms(4, 4, 20, _stored_alphas((4, 4), 20, "1"), 100, 300, 1, True, 4,
                              replace(whole, max_window_s=max_window_s), rate,
                              parse_budget(None).target).values())

    over = replace(whole, max_window_s=round(floor + 0.01 - 4e-6, 6))
    with pytest.raises(ValueError, match="the detector's buffers alone exceed the RAM budget"):
        window_for_budget(parse_budget(f"ram={need(round(floor - 4e-6, 6))}"), (4, 4), rate, over)
    near = replace(whole, max_window_s=floor + 0.01 - 4e-7)
    lowered, note = window_for_budget(parse_budget(f"ram={need(floor)}"), (4, 4), rate, near)
    assert lowered.max_window_s == floor and note is not None
