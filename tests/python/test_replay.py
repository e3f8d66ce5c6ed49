"""eskin.replay: the firmware simulator's input file."""

from __future__ import annotations

import numpy as np
import pytest

from eskin.replay import ReplayFormatError, read_replay_file, write_replay_arrays, write_replay_file


def test_arrays_round_trip_with_gaps(tmp_path):
    rng = np.random.default_rng(0)
    recs = [rng.integers(-500, 500, size=(4, 4, n)).astype(np.int16) for n in (100, 250)]
    rf = write_replay_arrays(
        tmp_path / "a.eskr", recs, labels=[1, 0], class_names=["a", "b"], gap_s=0.01,
        sample_rate_hz=3000.0, volts_per_count=1e-3, contact_intervals=[[10, 50], [0, 200]],
        noise_counts=2.0, baseline=np.zeros((4, 4)), seed=1,
    )
    assert rf.n_samples == 30 + 100 + 30 + 250 + 30
    assert rf.grid_shape == (4, 4)
    assert rf.class_names == ("a", "b")
    assert list(rf.segments["start"]) == [30, 160]
    assert list(rf.segments["label"]) == [1, 0]
    assert list(rf.segments["contact_onset"]) == [10, 0]
    for k, r in enumerate(recs):
        np.testing.assert_array_equal(rf.recording(k), r)
    gap = np.asarray(rf.samples[:30], dtype=float)
    assert abs(gap.mean()) < 1.5 and 0.5 < gap.std() < 4.0  # quiet noise around the baseline
    again = write_replay_arrays(tmp_path / "b.eskr", recs, gap_s=0.01, noise_counts=2.0, seed=1,
                                baseline=np.zeros((4, 4)))
    np.testing.assert_array_equal(again.samples, rf.samples)  # seeded


def test_from_a_simulated_campaign(tmp_path):
    from eskin.campaign import load_campaign
    from eskin.simulator import simulate

    path = simulate(tmp_path / "c.h5", participants=1, seed=3, runs=(2,))
    camp = load_campaign(path)
    rf = write_replay_file(camp, [0, 3], tmp_path / "c.eskr", gap_s=0.05)
    assert rf.class_names == tuple(camp.modalities)
    assert rf.sample_rate_hz == camp.sample_rate_hz
    assert rf.volts_per_count == pytest.approx(camp.volts_per_count)
    assert list(rf.segments["recording"]) == [0, 3]
    assert list(rf.segments["label"]) == [int(camp.modality[0]), int(camp.modality[3])]
    np.testing.assert_array_equal(rf.segments["contact_onset"],
                                  np.asarray(camp.contact_interval)[[0, 3], 0])
    np.testing.assert_array_equal(rf.recording(1), camp.recording(3))


def test_bad_files_are_named(tmp_path):
    p = tmp_path / "x.eskr"
    p.write_bytes(b"hello")
    with pytest.raises(ReplayFormatError, match="x.eskr.*magic"):
        read_replay_file(p)
    rng = np.random.default_rng(0)
    recs = [rng.integers(-5, 5, size=(2, 3, 40)).astype(np.int16)]
    write_replay_arrays(p, recs, gap_s=0.0)
    raw = bytearray(p.read_bytes())
    raw[60] ^= 1  # inside the segment table
    p.write_bytes(bytes(raw))
    with pytest.raises(ReplayFormatError, match="checksum"):
        read_replay_file(p)
    write_replay_arrays(p, recs, gap_s=0.0)
    p.write_bytes(p.read_bytes()[:-2])
    with pytest.raises(ReplayFormatError, match="size"):
        read_replay_file(p)


def test_argument_errors(tmp_path):
    ok = np.zeros((4, 4, 10), np.int16)
    with pytest.raises(ValueError, match="at least one"):
        write_replay_arrays(tmp_path / "e.eskr", [])
    with pytest.raises(ValueError, match="recording 1"):
        write_replay_arrays(tmp_path / "e.eskr", [ok, np.zeros((3, 4, 10), np.int16)])
    with pytest.raises(ValueError, match="integer"):
        write_replay_arrays(tmp_path / "e.eskr", [ok.astype(float)])
    with pytest.raises(ValueError, match="labels"):
        write_replay_arrays(tmp_path / "e.eskr", [ok], labels=[3], class_names=["a"])


def test_default_gaps_ramp_between_recording_levels_so_boundaries_are_not_touches(tmp_path):
    # Two quiet recordings sitting at different DC levels (an amplifier offset that differs
    # from one recording to the next): the gaps must join them without a step, which the
    # touch detector would report as a touch.
    from eskin.preprocess import TouchDetector

    rng = np.random.default_rng(5)
    fs = 3000.0
    recs = [
        (level + 8.0 * rng.standard_normal((4, 4, 3000))).astype(np.int16)
        for level in (-15.0, 15.0)
    ]
    rf = write_replay_arrays(tmp_path / "r.eskr", recs, gap_s=0.5, sample_rate_hz=fs,
                             noise_counts=8.0, seed=2)
    s = np.asarray(rf.samples, dtype=float)
    g = int(rf.segments["start"][1]) - 1500  # the gap between the two recordings
    assert abs(np.median(s[g : g + 5]) - (-15.0)) < 8  # starts where recording 0 ends
    assert abs(np.median(s[g + 1495 : g + 1500]) - 15.0) < 8  # ends where recording 1 starts
    assert abs(np.median(s[1495:1500]) - (-15.0)) < 8  # the leading gap sits at the first level
    det = TouchDetector((4, 4), fs)
    assert det.push(rf.samples) + det.flush() == []
    # with a fixed baseline the gaps stay flat
    flat = write_replay_arrays(tmp_path / "f.eskr", recs, gap_s=0.5, sample_rate_hz=fs,
                               noise_counts=8.0, baseline=np.zeros((4, 4)), seed=2)
    assert abs(np.median(np.asarray(flat.samples[g : g + 1500], dtype=float))) < 2

