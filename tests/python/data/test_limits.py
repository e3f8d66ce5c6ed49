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


def _unwritten(path, n=24, shape=(64, 64, 100_000)):
    """A campaign of 11 KB declaring ``n`` recordings of ``shape`` (19.7 GB), gzip chunks
    never written: every size limit passes, and reading it took minutes."""
    p = _declared(path, (n, *shape))
    with h5py.File(p, "a") as f:
        del f["recordings/signals"]
        f["recordings"].create_dataset("signals", shape=(n, *shape), dtype=np.int16,
                                       chunks=(1, *shape[:2], 2000), compression="gzip",
                                       shuffle=True)
        f["recordings/length"][...] = shape[2]
    return p


def test_a_declaration_the_stored_bytes_cannot_hold_is_refused_at_once(tmp_path):
    import time

    p = _unwritten(tmp_path / "huge.h5")
    assert p.stat().st_size < 20_000
    start = time.perf_counter()
    with pytest.raises(CampaignFormatError) as info:
        load_campaign(p)
    assert time.perf_counter() - start < 1.0
    assert str(info.value) == (
        f"{p}: /recordings/signals: shape (24, 64, 64, 100000): declares 19,660,800,000 bytes "
        f"of samples but the file stores 0 bytes of them, which hold at most 0 (filters: "
        f"shuffle+gzip; a chunk never written holds none); the file is damaged or was not "
        f"written whole")


def test_one_written_recording_does_not_vouch_for_the_others(tmp_path):
    p = _unwritten(tmp_path / "one.h5", n=40, shape=(16, 16, 50_500))
    with h5py.File(p, "a") as f:
        f["recordings/signals"][0] = np.random.default_rng(0).integers(
            -500, 500, (16, 16, 50_500), dtype=np.int16)
    # recording 0's 26 chunks hold its samples: 25 whole ones of 2000 and the last's 500 (the
    # rest of that chunk is past the end of the recording)
    with pytest.raises(CampaignFormatError, match=r"declares 1,034,240,000 bytes of samples but "
                       r"the file stores [0-9,]+ bytes of them, which hold at most 25,856,000 "
                       r"\(filters: shuffle\+gzip;"):
        load_campaign(p)


def test_the_bound_of_each_compression():
    assert limits.filter_ratio([]) == 1 and limits.filter_ratio([2, 1]) == 1032
    assert limits.filter_ratio([32000]) == 88 and limits.filter_ratio([3, 1]) == 1032
    assert limits.filter_ratio([307]) == limits.FILTER_RATIO_UNKNOWN  # a plugin (bzip2)
    free = limits.UNSTORED_BYTES
    assert limits.stored_size_problem(10**9 + free, 10**9, 10**9, []) is None
    assert limits.stored_size_problem(10**9 + free + 1, 10**9, 10**9, []).startswith(
        "declares 1,067,108,865 bytes of samples but the file stores 1,000,000,000 bytes of "
        "them, which hold at most 1,000,000,000 (filters: none; a chunk never written holds "
        "none)")


def test_the_most_compressible_campaign_a_writer_makes_is_accepted(tmp_path):
    """All zeros, gzip at level 9 (about 1030 times smaller): under the bound, and over the
    64 MiB that need no stored bytes."""
    with CampaignWriter(tmp_path / "z.h5", grid_shape=(8, 8), n_samples=200_000,
                        sample_rate_hz=3000.0, volts_per_count=1e-3, modalities=["a", "b"],
                        source="recorded", compression_level=9, durable=False) as w:
        for i in range(4):
            w.append(np.zeros((8, 8, 200_000), np.int16), modality=i % 2, participant=1,
                     direction=0, run=1)
    with load_campaign(tmp_path / "z.h5", check_data=True) as c:
        assert c.signals.shape == (4, 8, 8, 200_000)
        assert np.prod(c.signals.shape) * 2 > limits.UNSTORED_BYTES


def test_the_chunk_count_without_hdf5_chunk_iteration_is_the_same(tmp_path):
    """HDF5 before 1.12.3 has no chunk_iter: the chunks are then visited one by one through
    get_num_chunks / get_chunk_info, and must add up to the same bytes."""
    from eskin.data.campaign import _stored_chunks

    p = _unwritten(tmp_path / "one.h5", n=6, shape=(4, 4, 5_100))
    with h5py.File(p, "a") as f:
        f["recordings/signals"][2] = np.random.default_rng(1).integers(
            -500, 500, (4, 4, 5_100), dtype=np.int16)
    with h5py.File(p, "r") as f:
        ds = f["recordings/signals"]
        assert hasattr(ds.id, "chunk_iter")  # this HDF5 has it: compare the two ways

        class WithoutChunkIter:  # the dataset as an older HDF5 presents it
            def __init__(self, dsid):
                self.get_num_chunks, self.get_chunk_info = dsid.get_num_chunks, dsid.get_chunk_info

        class Older:
            shape, chunks, dtype, id = ds.shape, ds.chunks, ds.dtype, WithoutChunkIter(ds.id)

        stored, backed = _stored_chunks(ds, 1032)
        assert backed == 4 * 4 * 5_100 * 2 and 0 < stored < backed  # three chunks, one partial
        assert _stored_chunks(Older(), 1032) == (stored, backed)
        assert _stored_chunks(Older(), 1) == _stored_chunks(ds, 1) == (stored, stored)
