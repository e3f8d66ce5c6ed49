"""Declared sizes over the documented limits are refused before anything large is read."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from eskin.data import limits
from eskin.data.campaign import CampaignFormatError, CampaignWriter, load_campaign


def _declared(path, shape, *, label_n=None):
    """A campaign file whose signals declare ``shape`` (no data written: HDF5 allocates lazily)
    and whose label datasets have ``label_n`` entries (default: shape[0])."""
    n = shape[0] if label_n is None else label_n
    with h5py.File(path, "w") as f:
        f.attrs.update({"format": "eskin-campaign", "format_version": 1, "source": "recorded",
                        "sample_rate_hz": 3000.0, "volts_per_count": 1e-3})
        f.attrs["modalities"] = ["a", "b"]
        g = f.create_group("recordings")
        g.create_dataset("signals", shape=shape, dtype=np.int16,
                         chunks=(1, min(shape[1], 64), min(shape[2], 64), min(shape[3], 1000)))
        for name, dt in (("length", np.int32), ("modality", np.uint8), ("participant", np.int32),
                         ("direction", np.uint8), ("run", np.uint8)):
            g.create_dataset(name, shape=(n,), dtype=dt, chunks=(min(n, 1 << 16),))
    return path


HUGE = {
    "T = 2e9": ((3, 4, 4, 2_000_000_000),
                "samples per recording T 2,000,000,000 is over the limit of 16,777,216"),
    "n = 1e6": ((1_000_000, 4, 4, 21_000), "recordings n 1,000,000 is over the limit of 100,000"),
    "4096 x 4096 grid": ((2, 4096, 4096, 100), "grid rows 4,096 is over the limit of 256"),
    "64 x 128 grid": ((2, 64, 128, 100), "taxels (64 x 128) 8,192 is over the limit of 4,096"),
    "1 GiB recording": ((2, 64, 64, 1 << 18), "bytes per recording 2,147,483,648 is over"),
}


@pytest.mark.parametrize("case", sorted(HUGE))
def test_huge_declared_dimensions_are_refused_by_name(tmp_path, case):
    shape, problem = HUGE[case]
    p = _declared(tmp_path / "big.h5", shape)
    with pytest.raises(CampaignFormatError) as info:
        load_campaign(p)
    assert str(info.value).startswith(f"{p}: /recordings/signals: shape {shape}: {problem}")


def test_huge_label_dataset_is_refused_before_it_is_read(tmp_path):
    # 2e9 int32 would be an 8 GB read; the shape alone says it is wrong
    p = _declared(tmp_path / "labels.h5", (3, 4, 4, 100), label_n=2_000_000_000)
    with pytest.raises(CampaignFormatError, match=r"/recordings/length: wrong shape "
                       r"\(2000000000,\) \(expected \(3,\)"):
        load_campaign(p)


def test_in_memory_load_checks_the_memory_available(tmp_path, monkeypatch):
    p = _declared(tmp_path / "mem.h5", (3, 4, 4, 100))
    with h5py.File(p, "a") as f:
        f["recordings/signals"][...] = 1
    monkeypatch.setattr(limits, "available_memory", lambda: 1000)  # not even one recording
    with pytest.raises(CampaignFormatError, match=r"one recording would take 2.98e-06 GiB, "
                       r"more than the 9.31e-07 GiB of memory available"):
        load_campaign(p)
    monkeypatch.setattr(limits, "available_memory", lambda: 5000)  # one, not all three
    assert len(load_campaign(p)) == 3
    with pytest.raises(CampaignFormatError, match=r"in_memory=True: reading every recording "
                       r"would take 8.94e-06 GiB, more than the 4.66e-06 GiB of memory"):
        load_campaign(p, in_memory=True)
    monkeypatch.setattr(limits, "available_memory", lambda: 10_000)
    assert load_campaign(p, in_memory=True).signals.shape == (3, 4, 4, 100)


def test_available_memory_is_a_plausible_number():
    avail = limits.available_memory()
    assert avail is None or 0 < avail < 1 << 50


def test_writer_refuses_huge_recordings_before_allocating(tmp_path):
    with pytest.raises(CampaignFormatError, match="samples per recording T 10,000,000,000"):
        CampaignWriter(tmp_path / "w.h5", n_samples=10**10, sample_rate_hz=1.0,
                       volts_per_count=1.0, modalities=["x"], source="recorded")
    assert list(tmp_path.iterdir()) == []


def test_cli_info_on_a_huge_declaration_is_one_line(tmp_path):
    from typer.testing import CliRunner

    from eskin.cli import app

    p = _declared(tmp_path / "big.h5", (3, 4, 4, 2_000_000_000))
    r = CliRunner().invoke(app, ["info", str(p)])
    assert r.exit_code == 2
    assert r.output == (f"error: {p}: /recordings/signals: shape (3, 4, 4, 2000000000): samples "
                        f"per recording T 2,000,000,000 is over the limit of 16,777,216 "
                        f"(docs/dataset-format.md)\n")


def test_preprocess_huge_D_is_a_value_error_not_a_memory_error(monkeypatch):
    from eskin import preprocess

    x = np.zeros((2, 4, 4, 3000), np.int16)
    with pytest.raises(ValueError, match=r"^D = 1000000000000: over the limit of 100,000 "):
        preprocess(x, D=10**12)
    monkeypatch.setattr(limits, "available_memory", lambda: 10_000)
    with pytest.raises(ValueError, match=r"^D = 100: the output \(2, 4, 4, D=100\) float64 would "
                       r"take 2.38e-05 GiB, more than the 9.31e-06 GiB of memory available"):
        preprocess(x, D=100)
    monkeypatch.setattr(limits, "available_memory", lambda: 30_000)
    assert preprocess(x, D=100, window="none").shape == (2, 4, 4, 100)
