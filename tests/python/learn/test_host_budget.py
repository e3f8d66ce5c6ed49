"""The host budget (eskin.learn.host_budget): the estimated decision cost of a model on the
host, and the recipe search's budget that bounds it by default."""

from __future__ import annotations

import pytest

from eskin.errors import TrainingError
from eskin.learn.host_budget import (
    HOST_DECISION_US,
    HOST_INPUT_FACTOR,
    HOST_NS_PER_BASIS_ENTRY,
    HOST_NS_PER_ENTRY,
    HOST_NS_PER_SV,
    HOST_US_INPUT,
    basis_entries,
    default_cap_us,
    host_budget,
    host_decision_us,
    input_us,
    support_us,
)
from eskin.learn.recipes import Candidate, Recipe


def test_basis_entries_counts_N_alpha_per_mode_and_nothing_for_a_full_rank_mode():
    # 4x4xD=100: N = (400, 400, 16); alpha Q = (4, 4, 16): the third mode spans all of R^16
    assert basis_entries((4, 4), 100, (4, 4, 16)) == 400 * 4 * 2
    assert basis_entries((4, 4), 100, (2, 2, 8)) == 400 * 2 * 2 + 16 * 8
    assert basis_entries((4, 4), 100, (1, 1, 1)) == 400 + 400 + 16
    assert basis_entries((1, 4), 20, (1, 4, 4)) == 80 * 1 + 20 * 4 + 0  # N = (80, 20, 4)


def test_host_decision_us_is_the_bases_plus_the_support_vectors_entries():
    base = HOST_US_INPUT + 4 * 4 * 100 * HOST_NS_PER_ENTRY / 1e3
    assert host_decision_us((4, 4), 100, (2, 2, 8), 0) == pytest.approx(base)
    per_sv = ((400 * 2 * 2 + 16 * 8) * HOST_NS_PER_BASIS_ENTRY + HOST_NS_PER_SV) / 1e3
    assert host_decision_us((4, 4), 100, (2, 2, 8), 50) == pytest.approx(base + 50 * per_sv)


def test_the_estimate_follows_the_measured_end_of_touch_cost():
    """The fitted figures against the end-of-touch decision times they were fitted to (4x4):
    the input's bases 38-48 us at D = 20-100; D = 50 alpha Q about 0.74 us per support vector,
    D = 100 alpha Q about 1.4; the default cap admits 216 support vectors at D = 20 alpha Q
    (the searched model of the built-in 70-participant campaign keeps 216 of its 336), 107 at
    D = 50 alpha Q and 58 at D = 100 alpha Q; a cap of 180 would admit every one of 336 at
    D = 20 and 241 at D = 50."""
    assert host_decision_us((4, 4), 20, (4, 4, 16), 0) == pytest.approx(38, abs=1)
    assert host_decision_us((4, 4), 100, (4, 4, 16), 0) == pytest.approx(48, abs=1)
    assert support_us((4, 4), 50, (4, 4, 16), 1) == pytest.approx(0.74, abs=0.03)
    assert support_us((4, 4), 100, (4, 4, 16), 1) == pytest.approx(1.37, abs=0.03)
    assert support_us((4, 4), 20, (4, 4, 16), 216) <= HOST_DECISION_US
    assert support_us((4, 4), 20, (4, 4, 16), 217) > HOST_DECISION_US
    assert int(HOST_DECISION_US // support_us((4, 4), 50, (4, 4, 16), 1)) == 107
    assert int(HOST_DECISION_US // support_us((4, 4), 100, (4, 4, 16), 1)) == 58
    assert support_us((4, 4), 20, (4, 4, 16), 336) <= 180 < support_us((4, 4), 50, (4, 4, 16), 243)


def _candidate(D: int, alpha: str) -> Candidate:
    return Candidate(Recipe("svm", D, "algorithm2", "all"), 0.1, 1.0, alpha, None)


def test_the_budget_keeps_what_fits_and_bounds_the_rest_to_the_most_that_fit():
    budget = host_budget((4, 4), 100.0)
    assert budget.trades_D  # as a controller's: the order of preference leaves D out
    c = _candidate(100, "Q")
    most = budget.largest(c, 10_000)
    assert 0 < most < 10_000
    assert budget.fits(c, most) and not budget.fits(c, most + 1)
    assert support_us((4, 4), 100, (4, 4, 16), most) <= 100.0 < support_us(
        (4, 4), 100, (4, 4, 16), most + 1)
    assert budget.largest(c, most - 3) == most - 3  # fits as it is
    # alpha 1 costs far less per support vector than alpha Q: many more fit
    assert budget.largest(_candidate(100, "1"), 10_000) > 2 * most


def test_the_default_cap_is_80_us_or_twice_the_inputs_bases_where_those_take_more():
    """On a 4x4 grid the input's bases take 38-48 us: the default cap is 80 us at D = 20 and a
    little more at D = 50 and 100; on a 19 x 27 grid at D = 18 they take about 109 us, and a
    cap of 80 would leave a model of 336 patterns at alpha 1 under half its support vectors
    (none fits then), where twice the input's share keeps them all."""
    assert input_us((4, 4), 20) == pytest.approx(HOST_US_INPUT + 320 * HOST_NS_PER_ENTRY / 1e3)
    assert HOST_INPUT_FACTOR * input_us((4, 4), 20) < HOST_DECISION_US
    assert default_cap_us((4, 4), 20) == HOST_DECISION_US == 80.0
    assert default_cap_us((4, 4), 50) == pytest.approx(2 * (35 + 800 * 8e-3))
    assert default_cap_us((19, 27), 18) == pytest.approx(2 * (35 + 9234 * 8e-3))
    auto, strict = host_budget((19, 27), "auto"), host_budget((19, 27), 80.0)
    c = _candidate(18, "1")
    per_sv = support_us((19, 27), 18, (1, 1, 1), 1)
    assert auto.fits(c, 336) and auto.largest(c, 10_000) == int(default_cap_us((19, 27), 18) // per_sv)
    assert not strict.fits(c, 336) and strict.largest(c, 336) == int(80.0 // per_sv) < 336 // 2
    # on the 4x4 grid at D = 20 the two are the same budget
    four = _candidate(20, "Q")
    assert host_budget((4, 4), "auto").largest(four, 10_000) == host_budget((4, 4), 80.0).largest(
        four, 10_000) == 216
    assert "or 2 times the input's bases" in host_budget((4, 4)).description
    assert host_budget((4, 4), 80.0).description.startswith(
        "host: support vectors' share of a decision at most 80 us (estimated)")


@pytest.mark.parametrize("bad", [0, -1.0, float("nan"), float("inf"), "fast", ""])
def test_a_budget_that_is_not_a_positive_number_is_refused(bad):
    with pytest.raises(TrainingError, match="host decision budget"):
        host_budget((4, 4), bad)
