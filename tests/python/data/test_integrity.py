"""`eskin info --check` says what it verified: the recordings' data against the checksums the
file carries, and that labels, extra fields and attributes carry none (a flipped label bit that
stays in range passes, and the check must not claim otherwise)."""

from __future__ import annotations

import h5py
import numpy as np
import pytest
from typer.testing import CliRunner

from eskin.cli import app
from eskin.data.campaign import CampaignWriter, load_campaign
from eskin.data.integrity import check_report


def _campaign(path, level=1):
    rng = np.random.default_rng(3)
    with CampaignWriter(path, grid_shape=(2, 2), n_samples=300, sample_rate_hz=1000.0,
                        volts_per_count=1e-3, modalities=["a", "b"], source="recorded",
                        compression_level=level, extra_fields={"force_n": np.float64},
                        durable=False) as w:
        for i in range(4):
            w.append(rng.integers(-900, 900, (2, 2, 300)).astype(np.int16), modality=i % 2,
                     participant=1 + i // 2, direction=0, run=1, extra={"force_n": 0.5})
    return path


def _flip(path, offset, bit=1):
    with open(path, "r+b") as fh:
        fh.seek(offset)
        b = fh.read(1)[0]
        fh.seek(offset)
        fh.write(bytes([b ^ bit]))


def test_a_flipped_label_passes_the_check_which_says_it_cannot_see_it(tmp_path):
    p = _campaign(tmp_path / "c.h5")
    with h5py.File(p, "r") as f:
        offset = f["recordings/modality"].id.get_offset()
    _flip(p, offset)
    r = CliRunner().invoke(app, ["info", "--check", str(p)])
    assert r.exit_code == 0, r.output
    assert "intact" not in r.output
    assert r.output.splitlines()[-3:] == [
        "check: read the data of all 4 recordings; every chunk matched its checksum (gzip's "
        "Adler-32)",
        "check: the labels (direction, length, modality, participant, run) are within their "
        "ranges",
        "check: the labels, the extra fields and the attributes carry no checksum: a changed "
        "value that stays in range (a modality id 0 read as 1) cannot be detected"]
    with load_campaign(p) as c:
        assert list(c.modality) == [1, 1, 0, 1]  # the damage the check cannot see


def test_a_flipped_sample_in_a_gzip_chunk_is_found(tmp_path):
    p = _campaign(tmp_path / "c.h5")
    with h5py.File(p, "r") as f:
        info = f["recordings/signals"].id.get_chunk_info(2)
    _flip(p, info.byte_offset + info.size // 2, 0x10)
    r = CliRunner().invoke(app, ["info", "--check", str(p)])
    assert r.exit_code == 2
    assert r.output.startswith(f"error: {p}: /recordings/signals: cannot read recording data")


def test_uncompressed_data_is_said_to_carry_no_checksum(tmp_path):
    p = _campaign(tmp_path / "c.h5", level=None)
    load_campaign(p, check_data=True).close()
    assert check_report(p)[0] == (
        "check: read the data of all 4 recordings; it is stored uncompressed, with no "
        "checksum: an unreadable chunk would have been found, a changed sample cannot be")


@pytest.mark.parametrize("summed", [["modality"], ["direction", "length", "modality",
                                                   "participant", "run", "extra/force_n"]])
def test_labels_written_with_fletcher32_are_named_as_checked(tmp_path, summed):
    p = _campaign(tmp_path / "c.h5")
    with h5py.File(p, "a") as f:
        for name in summed:
            data = f["recordings"][name][()]
            del f["recordings"][name]
            f["recordings"].create_dataset(name, data=data, fletcher32=True, chunks=data.shape)
    load_campaign(p, check_data=True).close()
    lines = check_report(p)
    assert f"check: {', '.join(summed)} matched their checksums (HDF5's Fletcher-32)" in lines
    assert lines[-1].startswith("check: the attributes carry no checksum" if len(summed) == 6
                                else "check: direction, length, participant, run, the extra "
                                     "fields and the attributes carry no checksum")
