"""A campaign file's root attributes (eskin.data.campaign): each refused with the message that
names it and what is wrong, on both sides of every boundary, and the values at the boundaries
taken."""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
import pytest

from eskin.data import limits
from eskin.data.campaign import (
    FORMAT,
    FORMAT_VERSION,
    CampaignFormatError,
    load_campaign,
    write_campaign,
)

N, T = 3, 20


def _file(path: Path, **attrs) -> Path:
    """A valid campaign, then its root attributes set (None: deleted)."""
    write_campaign(path, np.zeros((N, 2, 2, T), np.int16), modality=[0, 1, 0],
                   participant=[1, 2, 3], direction=[0] * N, run=[1] * N,
                   modalities=["a", "b"], sample_rate_hz=1000.0, volts_per_count=1.0,
                   source="recorded")
    with h5py.File(path, "a") as f:
        for k, v in attrs.items():
            if v is None:
                del f.attrs[k]
            else:
                f.attrs[k] = v
    return path


def _refused(path: Path) -> tuple[str, str]:
    with pytest.raises(CampaignFormatError) as info:
        load_campaign(path)
    assert info.value.path == str(path)
    return info.value.field, info.value.problem


@pytest.mark.parametrize("value", ["abc", "eskin-campaigm", "eskin-campaign2", "zzz"])
def test_a_format_other_than_ours_is_refused_whichever_side_it_sorts(tmp_path, value):
    assert _refused(_file(tmp_path / "c.h5", format=value)) == (
        "attribute 'format'", f"is {value!r}, not {FORMAT!r}: not an eskin campaign")


@pytest.mark.parametrize("name", ["format_version", "sample_rate_hz", "volts_per_count",
                                  "modalities", "source"])
def test_each_required_attribute_missing_is_named(tmp_path, name):
    assert _refused(_file(tmp_path / "c.h5", **{name: None})) == (
        f"attribute {name!r}", "missing (required)")


@pytest.mark.parametrize("value, problem", [
    ("1", "must be an integer, got '1'"), (True, "must be an integer, got True"),
    (1.0, "must be an integer, got 1.0"),
    (FORMAT_VERSION - 1, f"version {FORMAT_VERSION - 1} is not supported (this eskin reads "
                         f"version {FORMAT_VERSION})"),
    (FORMAT_VERSION + 1, f"version {FORMAT_VERSION + 1} is not supported (this eskin reads "
                         f"version {FORMAT_VERSION})"),
    (1000, f"version 1000 is not supported (this eskin reads version {FORMAT_VERSION})"),
])
def test_a_format_version_not_ours_is_refused(tmp_path, value, problem):
    assert _refused(_file(tmp_path / "c.h5", format_version=value)) == (
        "attribute 'format_version'", problem)


@pytest.mark.parametrize("name", ["sample_rate_hz", "volts_per_count"])
@pytest.mark.parametrize("value", [True, "3", 0, 0.0, -1.0, np.inf, np.nan])
def test_a_scale_that_is_not_a_positive_finite_number_is_refused(tmp_path, name, value):
    assert _refused(_file(tmp_path / "c.h5", **{name: value})) == (
        f"attribute {name!r}", f"must be a positive finite number, got {value!r}")


def test_the_ends_of_the_sample_rates_are_taken_and_beyond_them_refused(tmp_path):
    lo, hi = limits.MIN_SAMPLE_RATE_HZ, limits.MAX_SAMPLE_RATE_HZ
    for rate in (lo, hi, 7):
        with load_campaign(_file(tmp_path / f"{rate}.h5", sample_rate_hz=rate)) as c:
            assert c.sample_rate_hz == rate and isinstance(c.sample_rate_hz, float)
    for rate in (lo * 0.999, hi * 1.001):
        field, problem = _refused(_file(tmp_path / f"{rate}.h5", sample_rate_hz=rate))
        assert field == "attribute 'sample_rate_hz'"
        assert problem == (f"{rate:g} Hz is outside the sample rates eskin reads, {lo:g} Hz to "
                           f"{hi:g} Hz (docs/dataset-format.md)")


@pytest.mark.parametrize("value, problem", [
    (np.array([], dtype=h5py.string_dtype()),
     "must be a non-empty list of non-empty names, got []"),
    (["a", ""], "must be a non-empty list of non-empty names, got ['a', '']"),
    (np.array([1, 2]), "must be a non-empty list of non-empty names, got [1, 2]"),
    (7, "must be a non-empty list of non-empty names, got 7"),
    (["a", "b", "a"], "has duplicate names ['a', 'b', 'a']"),
    ([f"m{i}" for i in range(256)], "more than 255 names"),
    ([f"m{i}" for i in range(300)], "more than 255 names"),
])
def test_modalities_other_than_distinct_names_are_refused(tmp_path, value, problem):
    assert _refused(_file(tmp_path / "c.h5", modalities=value)) == (
        "attribute 'modalities'", problem)


def test_one_modality_name_alone_and_255_names_are_taken(tmp_path):
    with h5py.File(_file(tmp_path / "one.h5"), "a") as f:
        f["recordings/modality"][...] = 0
        f.attrs["modalities"] = "brush"
    with load_campaign(tmp_path / "one.h5") as c:
        assert c.modalities == ["brush"]
    names = [f"m{i}" for i in range(255)]
    with load_campaign(_file(tmp_path / "many.h5", modalities=names)) as c:
        assert c.modalities == names


@pytest.mark.parametrize("value", ["guessed", "Recorded", ""])
def test_a_source_other_than_simulated_or_recorded_is_refused(tmp_path, value):
    assert _refused(_file(tmp_path / "c.h5", source=value)) == (
        "attribute 'source'", f"must be one of ('simulated', 'recorded'), got {value!r}")


def test_an_attribute_that_is_not_utf8_names_its_first_bad_byte(tmp_path):
    path = _file(tmp_path / "c.h5", notes=np.bytes_(b"ok \xe9t\xe9"))
    assert _refused(path) == ("attribute 'notes'", "not UTF-8 text (byte 0xe9 at position 3)")
