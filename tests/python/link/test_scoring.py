"""eskin.link.scoring: live decisions against the true classes of a replay file."""

from __future__ import annotations

import numpy as np
import pytest

from eskin.data.replay import write_replay_arrays
from eskin.link.listener import Decision
from eskin.link.scoring import score_decisions, segment_of


def _replay(tmp_path):
    recs = [np.zeros((4, 4, 1000), np.int16) for _ in range(4)]
    # gaps of 100 samples: segments at [100, 1100), [1200, 2200), [2300, 3300), [3400, 4400)
    return write_replay_arrays(
        tmp_path / "r.eskr",
        recs,
        labels=[0, 1, 2, -1],
        class_names=["brush", "finger", "washer"],
        gap_s=0.1,
        sample_rate_hz=1000.0,
        noise_counts=1.0,
        seed=0,
    )


def _d(source, onset, label, dont_know=False, index=99):
    return Decision(source, onset, onset + 300, label, index, (0.1, -0.2, 0.3), dont_know)


def test_scores_by_class_name_per_source(tmp_path):
    rf = _replay(tmp_path)
    assert list(rf.segments["start"]) == [100, 1200, 2300, 3400]
    decisions = [
        _d("host", 200, "brush"),
        _d("controller", 200, "brush", index=0),
        _d("controller", 1300, "washer", dont_know=True),  # wrong, flagged
        _d("controller", 2400, "washer"),
        _d("controller", 3500, "finger"),  # a segment of unknown class: not scored
        _d("controller", 50, "finger"),  # in the first gap: not a recording's decision
    ]
    controller, host = score_decisions(decisions, rf)
    assert controller.source == "controller" and host.source == "host"
    # the label index a model gives (99 here) is not used: classes are matched by name
    assert (
        controller.recordings,
        controller.correct,
        controller.dont_know,
        controller.no_decision,
    ) == (3, 2, 1, 0)
    assert controller.confusion.tolist() == [[1, 0, 0, 0], [0, 0, 1, 0], [0, 0, 1, 0]]
    assert controller.accuracy == 2 / 3
    assert (host.correct, host.no_decision) == (1, 2)
    assert host.confusion.tolist() == [[1, 0, 0, 0], [0, 0, 0, 1], [0, 0, 0, 1]]
    d = host.as_dict()
    assert d["type"] == "accuracy" and d["confusion_columns"] == [
        "brush",
        "finger",
        "washer",
        "none",
    ]
    assert score_decisions([], rf) == []


def test_segment_of_a_window(tmp_path):
    rf = _replay(tmp_path)
    assert segment_of(rf, 1050, 1400) == 1  # 200 samples in segment 1, 50 in segment 0
    assert segment_of(rf, 1100, 1200) == -1  # the gap
    assert segment_of(rf, 0, 150, stream_offset=100) == -1
    assert segment_of(rf, 250, 300, stream_offset=100) == 0


@pytest.mark.parametrize("live", [True, False])
def test_scores_are_printed_as_accuracy_and_confusion_matrix(tmp_path, capsys, live):
    from eskin.cli.link import _print_scores

    rf = _replay(tmp_path)
    (score,) = score_decisions(
        [_d("controller", 200, "brush"), _d("controller", 1300, "brush")], rf
    )
    _print_scores([score], live)
    out = capsys.readouterr().out
    assert "accuracy against the replay's true classes (one decision per recording):" in out
    assert "controller: 1/3 recordings right (33.3 %), 0 don't know, 1 without a decision" in out
    rows = [ln for ln in out.splitlines() if "finger" in ln and "true" not in ln]
    assert rows and rows[0].replace("│", " ").split() == ["finger", "1", "0", "0", "0"]
