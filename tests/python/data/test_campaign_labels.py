"""A campaign's per-recording labels (eskin.data.campaign): each field's shape, type and range
checked for an in-memory campaign, and the cross-field checks naming the first bad recording
and counting the others, whether the campaign is built in memory or loaded from a file."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from eskin.data.campaign import Campaign, CampaignFormatError, load_campaign, write_campaign

N, T = 5, 30
FIELDS = ("modality", "participant", "direction", "run")


def _labels(**override) -> dict:
    labels = {"lengths": np.full(N, T), "modality": [0, 1, 0, 1, 0], "participant": [1, 2, 3, 4, 5],
              "direction": [0, 1, 255, 0, 1], "run": [1, 1, 2, 2, 3]}
    labels.update(override)
    return labels


def _campaign(n: int = N, **override) -> Campaign:
    sig = np.zeros((n, 2, 2, T), np.int16)
    return Campaign(sig, modalities=["a", "b"], sample_rate_hz=1000.0, volts_per_count=1.0,
                    source="recorded", **_labels(**override))


def _refusal(**override) -> tuple[str, str]:
    with pytest.raises(CampaignFormatError) as info:
        _campaign(**override)
    return info.value.field, info.value.problem


def test_valid_labels_are_taken_in_their_stored_types():
    c = _campaign(modality=np.array([0, 1, 0, 1, 0], np.int64), run=[1, 1, 2, 2, 255])
    assert c.modality.dtype == np.uint8 and c.participant.dtype == np.int32
    assert c.run.tolist() == [1, 1, 2, 2, 255] and c.lengths.dtype == np.int32


@pytest.mark.parametrize("name", ["lengths", *FIELDS])
@pytest.mark.parametrize("n_given", [N - 1, N + 1])
def test_a_label_field_of_another_length_is_refused(name, n_given):
    value = np.asarray(_labels()[name])
    value = np.resize(value, n_given)
    field = "length" if name == "lengths" else name
    assert _refusal(**{name: value}) == (
        f"/recordings/{field}", f"wrong shape ({n_given},) (expected ({N},): one entry per "
        f"recording, {N} recordings in /recordings/signals)")


@pytest.mark.parametrize("shape", [(N, 3), (N, 1), (N - 1, 2), (N + 1, 2)])
def test_a_contact_interval_of_another_shape_is_refused(shape):
    assert _refusal(contact_interval=np.zeros(shape, int)) == (
        "/recordings/contact_interval", f"wrong shape {shape} (expected ({N}, 2): one entry per "
        f"recording, {N} recordings in /recordings/signals)")


@pytest.mark.parametrize("name", FIELDS)
def test_a_label_field_of_floats_is_refused_unless_there_are_no_recordings(name):
    assert _refusal(**{name: np.asarray(_labels()[name], float)}) == (
        f"/recordings/{name}", "must be integers, got dtype float64")
    # no recordings: an empty list is float64 to numpy, and there is nothing wrong in it
    empty = _campaign(0, lengths=[], modality=[], participant=[], direction=[], run=[])
    assert len(empty) == 0 and empty.modality.dtype == np.uint8


@pytest.mark.parametrize("name, low, high", [("modality", 0, 255), ("direction", 0, 255),
                                             ("run", 0, 255),
                                             ("participant", -(2**31), 2**31 - 1)])
def test_a_label_outside_its_stored_type_is_refused_and_its_ends_are_taken(name, low, high):
    for bad in (low - 1, high + 1):
        value = np.asarray(_labels()[name], np.int64)
        value[3] = bad
        field, problem = _refusal(**{name: value})
        assert field == f"/recordings/{name}"
        dtype = {"participant": "int32"}.get(name, "uint8")
        assert problem == (f"values out of the {dtype} range [{low}, {high}]: "
                           f"min {min(value)}, max {max(value)}")
    if name == "participant":
        c = _campaign(participant=[low, high, 0, 1, 2])
        assert c.participant.tolist() == [low, high, 0, 1, 2]


@pytest.mark.parametrize("field, override, problem", [
    ("length", {"lengths": [T, T, -1, T, T + 1]},
     f"recording 2 has length -1, outside [0, T={T}] (2 bad entries)"),
    ("length", {"lengths": [T, T, T, T + 1, T]},
     f"recording 3 has length {T + 1}, outside [0, T={T}]"),
    ("modality", {"modality": [0, 1, 3, 1, 2]},
     "recording 2 has modality id 3, out of range: the modalities attribute names 2 classes "
     "(2 bad entries)"),
    ("modality", {"modality": [0, 1, 0, 2, 0]},
     "recording 3 has modality id 2, out of range: the modalities attribute names 2 classes"),
    ("direction", {"direction": [0, 1, 2, 254, 0]},
     "recording 2 has direction 2 (allowed: 0 horizontal, 1 vertical, 255 unknown)"),
    ("contact_interval", {"contact_interval": [[0, 5], [0, 5], [-1, 5], [0, 5], [6, 5]]},
     "recording 2 has interval [-1, 5), not within [0, length=30] with onset <= offset"),
    ("contact_interval", {"contact_interval": [[0, 5], [0, 5], [0, 5], [7, 6], [0, 5]]},
     "recording 3 has interval [7, 6), not within [0, length=30] with onset <= offset"),
    ("contact_interval", {"contact_interval": [[0, 5], [0, T], [0, 5], [0, T + 1], [0, 5]]},
     f"recording 3 has interval [0, {T + 1}), not within [0, length={T}] with onset <= offset"),
])
def test_the_first_bad_recording_is_named_and_the_others_counted(field, override, problem):
    assert _refusal(**override) == (f"/recordings/{field}", problem)


def test_the_ends_of_each_range_are_taken():
    c = _campaign(lengths=[0, T, 1, T - 1, T], modality=[0, 1, 1, 0, 1],
                  direction=[0, 1, 255, 0, 1],
                  contact_interval=[[0, 0], [0, T], [1, 1], [0, T - 1], [T, T]])
    assert c.lengths.tolist() == [0, T, 1, T - 1, T]
    assert c.contact_interval.tolist()[4] == [T, T]


def test_a_loaded_campaign_names_its_bad_recording_in_the_file(tmp_path):
    path = write_campaign(tmp_path / "c.h5", np.zeros((N, 2, 2, T), np.int16),
                          modality=[0, 1, 0, 1, 0], participant=[1, 2, 3, 4, 5],
                          direction=[0] * N, run=[1] * N, modalities=["a", "b"],
                          sample_rate_hz=1000.0, volts_per_count=1.0, source="recorded")
    with h5py.File(path, "a") as f:
        f["recordings/modality"][3] = 7
        f["recordings/modality"][4] = 9
    with pytest.raises(CampaignFormatError) as info:
        load_campaign(path)
    assert str(info.value) == (
        f"{path}: /recordings/modality: recording 3 has modality id 7, out of range: the "
        "modalities attribute names 2 classes (2 bad entries)")


def _stored(path, name, data):
    with h5py.File(path, "a") as f:
        del f[f"recordings/{name}"]
        if data is None:
            f.create_group(f"recordings/{name}")
        else:
            f[f"recordings/{name}"] = data


def _written(path):
    return write_campaign(path, np.zeros((N, 2, 2, T), np.int16), lengths=[T] * N,
                          modality=[0, 1, 0, 1, 0], participant=[1, 2, 3, 4, 5],
                          direction=[0] * N, run=[1] * N, contact_interval=[[0, 1]] * N,
                          modalities=["a", "b"], sample_rate_hz=1000.0, volts_per_count=1.0,
                          source="recorded")


STORED = {"length": ("int32", ()), "modality": ("uint8", ()), "participant": ("int32", ()),
          "direction": ("uint8", ()), "run": ("uint8", ()), "contact_interval": ("int32", (2,))}
OTHER = {"int32": ["int16", "int64", "uint32"], "uint8": ["int8", "uint16", "bool"]}


@pytest.mark.parametrize("name", sorted(STORED))
def test_a_stored_label_of_another_type_shape_or_kind_is_refused(tmp_path, name):
    dtype, tail = STORED[name]
    cases = [(np.ones((N, *tail), other), f"wrong dtype {np.dtype(other)} (expected {dtype})")
             for other in OTHER[dtype]]
    for n in (N - 1, N + 1):
        cases.append((np.ones((n, *tail), dtype),
                      f"wrong shape {(n, *tail)} (expected {(N, *tail)}: one entry per "
                      f"recording, {N} recordings in /recordings/signals)"))
    cases.append((None, "must be a dataset"))
    for i, (data, problem) in enumerate(cases):
        path = _written(tmp_path / f"{i}.h5")
        _stored(path, name, data)
        with pytest.raises(CampaignFormatError) as info:
            load_campaign(path)
        assert (info.value.field, info.value.problem) == (f"/recordings/{name}", problem)


def test_a_group_among_the_extra_fields_is_passed_over(tmp_path):
    path = _written(tmp_path / "c.h5")
    with h5py.File(path, "a") as f:
        f.create_group("recordings/extra/a_group")
        f["recordings/extra/b_force"] = np.arange(N, dtype=np.float32)
    with load_campaign(path) as c:
        assert sorted(c.extras) == ["b_force"]
        np.testing.assert_array_equal(c.extras["b_force"], np.arange(N))
