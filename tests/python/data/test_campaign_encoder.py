"""A recording encoded outside the writer (eskin.data.campaign.encode_recording: the
simulator's worker processes compress recordings in parallel): what it takes, what it refuses,
and the writer taking it only for the grid, length and compression it was made for."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from eskin.data.campaign import CampaignWriter, encode_recording, load_campaign

T = 40


def _writer(path, grid=(4, 4), n_samples=T, level=1) -> CampaignWriter:
    return CampaignWriter(path, grid_shape=grid, n_samples=n_samples, sample_rate_hz=1000.0,
                          volts_per_count=1e-3, modalities=["a"], source="recorded",
                          compression_level=level)


def test_the_encoder_takes_whole_recordings_and_refuses_values_outside_int16():
    x = np.arange(4 * 4 * 10, dtype=np.int16).reshape(4, 4, 10)
    whole = encode_recording(x, grid_shape=(4, 4), n_samples=T, length=10)
    assert whole == encode_recording(x, grid_shape=(4, 4), n_samples=T)
    assert encode_recording(x.astype(np.uint8), grid_shape=(4, 4), n_samples=T).chunk == \
        whole.chunk
    for wide in (x.astype(np.uint16) + 40000, x.astype(np.int32) - 40000):
        with pytest.raises(ValueError) as info:
            encode_recording(wide, grid_shape=(4, 4), n_samples=T)
        assert str(info.value) == "recording: values outside the int16 range"


def test_an_encoded_recording_cannot_be_changed_after_encoding():
    enc = encode_recording(np.ones((4, 4, 10), np.int16), grid_shape=(4, 4), n_samples=T)
    with pytest.raises(dataclasses.FrozenInstanceError):
        enc.length = 5  # its chunk holds 10 samples: the two must never disagree


def test_a_recording_of_length_zero_is_encoded_and_stored_empty(tmp_path):
    x = np.full((4, 4, 10), 7, np.int16)
    enc = encode_recording(x, grid_shape=(4, 4), n_samples=T, length=0)
    assert enc.length == 0
    with _writer(tmp_path / "z.h5") as w:
        w.append(enc, modality=0, participant=1, direction=0, run=1)
    with load_campaign(tmp_path / "z.h5") as c:
        assert c.recording(0).shape == (4, 4, 0)
        assert not np.asarray(c.signals).any()  # the padding only: the 7s were not kept
    for bad in (-1, 11):
        with pytest.raises(ValueError, match=f"length {bad} outside \\[0, 10\\]"):
            encode_recording(x, grid_shape=(4, 4), n_samples=T, length=bad)


@pytest.mark.parametrize("grid, n_samples, level", [
    ((2, 8), T, 1), ((8, 2), T, 1), ((4, 4), T + 1, 1), ((4, 4), T - 1, 1), ((4, 4), T, 0),
    ((4, 4), T, 2), ((4, 4), T, None)])
def test_the_writer_refuses_a_recording_encoded_for_another_grid_length_or_level(
        tmp_path, grid, n_samples, level):
    x = np.ones((*grid, 10), np.int16)
    enc = encode_recording(x, grid_shape=grid, n_samples=n_samples, compression_level=level)
    with _writer(tmp_path / "w.h5") as w:
        with pytest.raises(ValueError, match="encoded for grid"):
            w.append(enc, modality=0, participant=1, direction=0, run=1)
        # the same recording encoded for this writer is taken
        same = encode_recording(np.ones((4, 4, 10), np.int16), grid_shape=(4, 4), n_samples=T)
        assert w.append(same, modality=0, participant=1, direction=0, run=1) == 0


@pytest.mark.parametrize("shape", [(4, 4), (1, 4, 4, 10), (3, 4, 10), (5, 4, 10), (4, 3, 10),
                                   (4, 5, 10)])
def test_signals_not_of_the_grid_are_refused_by_the_encoder(shape):
    with pytest.raises(ValueError) as info:
        encode_recording(np.zeros(shape, np.int16), grid_shape=(4, 4), n_samples=T)
    assert str(info.value) == (f"recording: signals must have shape (4, 4, length), got "
                               f"{shape}")


def test_wider_integers_at_the_ends_of_int16_are_taken_as_int16():
    x = np.zeros((4, 4, 10), np.int32)
    x[0, 0, 0], x[3, 3, 9] = -32768, 32767
    for wide in (x, x.astype(np.int64)):
        enc = encode_recording(wide, grid_shape=(4, 4), n_samples=T)
        assert enc == encode_recording(x.astype(np.int16), grid_shape=(4, 4), n_samples=T)
    for v in (-32769, 32768):
        x[1, 1, 1] = v
        with pytest.raises(ValueError, match="values outside the int16 range"):
            encode_recording(x, grid_shape=(4, 4), n_samples=T)


def test_a_long_recording_encoded_for_its_writer_is_taken(tmp_path):
    """T = 1000: counts past the integers Python keeps as single objects."""
    x = np.ones((4, 4, 1000), np.int16)
    with _writer(tmp_path / "w.h5", n_samples=1000) as w:
        enc = encode_recording(x, grid_shape=(4, 4), n_samples=1000)
        assert w.append(enc, modality=0, participant=1, direction=0, run=1) == 0
    with load_campaign(tmp_path / "w.h5") as c:
        np.testing.assert_array_equal(c.recording(0), x)
