"""A campaign holds its data itself: external storage (e.g. signals read from /dev/urandom),
external links and virtual datasets are refused by the loader, naming the dataset, unless
load_campaign(..., allow_external=True)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from eskin.data.campaign import CampaignFormatError, load_campaign, write_campaign

REPO = Path(__file__).resolve().parents[3]
N, T = 3, 50


def _campaign(path: Path) -> Path:
    sig = np.arange(N * 4 * 4 * T, dtype=np.int16).reshape(N, 4, 4, T)
    return write_campaign(path, sig, modality=[0, 1, 0], participant=[1, 2, 3],
                          direction=[0, 0, 1], run=[1, 1, 2], modalities=["a", "b"],
                          sample_rate_hz=1000.0, volts_per_count=1e-3, source="recorded")


def _replace_signals(path: Path, make) -> None:
    with h5py.File(path, "a") as f:
        del f["recordings/signals"]
        make(f["recordings"])


def test_signals_stored_in_dev_urandom_are_refused_by_info_check(tmp_path):
    path = _campaign(tmp_path / "c.h5")
    _replace_signals(path, lambda g: g.create_dataset(
        "signals", shape=(N, 4, 4, T), dtype=np.int16,
        external=[("/dev/urandom", 0, N * 4 * 4 * T * 2)]))
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO / "python") + os.pathsep + env.get("PYTHONPATH", "")
    r = subprocess.run([sys.executable, "-m", "eskin", "info", "--check", str(path)],
                       capture_output=True, text=True, env=env, timeout=120)
    assert r.returncode == 2 and r.stdout == ""
    assert r.stderr == (f"error: {path}: /recordings/signals: external storage: its data is in "
                        f"/dev/urandom, not in this file (load_campaign(..., "
                        f"allow_external=True) reads it)\n")
    with load_campaign(path, allow_external=True) as c:  # the documented way to read it
        assert c.signals.shape == (N, 4, 4, T)


def test_an_external_link_is_refused(tmp_path):
    other = _campaign(tmp_path / "other.h5")
    path = _campaign(tmp_path / "c.h5")
    _replace_signals(path, lambda g: g.__setitem__(
        "signals", h5py.ExternalLink(str(other), "/recordings/signals")))
    with pytest.raises(CampaignFormatError, match=r"/recordings/signals: an external link to "
                                                  r".*other\.h5:/recordings/signals"):
        load_campaign(path)
    with load_campaign(path, allow_external=True, check_data=True) as c:
        np.testing.assert_array_equal(c.recording(2), load_campaign(other).recording(2))
    with h5py.File(path, "a") as f:  # anywhere in the file, not only where data is read
        del f["recordings/signals"]
        f["recordings/signals"] = load_campaign(other, in_memory=True).signals
        f["notes"] = h5py.ExternalLink("/etc/passwd", "/x")
    with pytest.raises(CampaignFormatError, match=r": /notes: an external link to /etc/passwd"):
        load_campaign(path)


def test_a_virtual_dataset_is_refused(tmp_path):
    other = _campaign(tmp_path / "other.h5")
    path = _campaign(tmp_path / "c.h5")

    def virtual(g):
        layout = h5py.VirtualLayout(shape=(N, 4, 4, T), dtype=np.int16)
        layout[:] = h5py.VirtualSource(str(other), "/recordings/signals", shape=(N, 4, 4, T))
        g.create_virtual_dataset("signals", layout)

    _replace_signals(path, virtual)
    with pytest.raises(CampaignFormatError, match=r"/recordings/signals: a virtual dataset"):
        load_campaign(path)
    with load_campaign(path, allow_external=True) as c:
        assert c.signals.shape == (N, 4, 4, T)


def test_external_storage_names_its_first_three_files(tmp_path):
    path = _campaign(tmp_path / "c.h5")
    parts = [tmp_path / f"part{i}.bin" for i in range(4)]
    size = N * 4 * 4 * T * 2 // 4
    for p in parts:
        p.write_bytes(bytes(size))
    _replace_signals(path, lambda g: g.create_dataset(
        "signals", shape=(N, 4, 4, T), dtype=np.int16,
        external=[(str(p), 0, size) for p in parts]))
    with pytest.raises(CampaignFormatError) as info:
        load_campaign(path)
    assert info.value.problem == (f"external storage: its data is in {parts[0]}, {parts[1]}, "
                                  f"{parts[2]}, not in this file (load_campaign(..., "
                                  f"allow_external=True) reads it)")


def test_a_soft_link_is_followed_where_it_points_and_the_names_after_it_checked(tmp_path):
    path = _campaign(tmp_path / "c.h5")
    with h5py.File(path, "a") as f:
        f["a_alias"] = h5py.SoftLink("/recordings/run")  # sorts before the next name
        f["b_notes"] = h5py.ExternalLink("/etc/passwd", "/x")
    with pytest.raises(CampaignFormatError) as info:
        load_campaign(path)
    assert info.value.field == "/b_notes"
    with h5py.File(path, "a") as f:
        del f["b_notes"]
    with load_campaign(path) as c:  # a soft link inside the file is harmless
        assert len(c) == N


def _nested_link(path: Path, depth: int) -> str:
    """An external link inside ``depth`` nested groups; its path in the file."""
    where = "".join(f"/g{i}" for i in range(depth)) + "/link"
    with h5py.File(path, "a") as f:
        f[where] = h5py.ExternalLink("/etc/passwd", "/x")
    return where


def test_links_are_looked_for_eight_groups_deep_and_a_cycle_of_groups_ends(tmp_path):
    for depth in (1, 7, 8):
        path = _campaign(tmp_path / f"d{depth}.h5")
        where = _nested_link(path, depth)
        with pytest.raises(CampaignFormatError) as info:
            load_campaign(path)
        assert info.value.field == where
    # deeper than the walk goes: nothing the loader reads is there
    path = _campaign(tmp_path / "d9.h5")
    _nested_link(path, 9)
    with load_campaign(path) as c:
        assert len(c) == N
    # a group holding a hard link to its parent: the walk stops at its depth, and the loader
    # still finds a link after the cycle
    path = _campaign(tmp_path / "cycle.h5")
    with h5py.File(path, "a") as f:
        f.create_group("loop")
        f["loop/back"] = f["loop"]
        f["z_notes"] = h5py.ExternalLink("/etc/passwd", "/x")
    with pytest.raises(CampaignFormatError) as info:
        load_campaign(path)
    assert info.value.field == "/z_notes"


@pytest.mark.parametrize("dtype", ["int8", "uint16", "int32", "float32"])
def test_stored_signals_other_than_int16_are_refused(tmp_path, dtype):
    path = _campaign(tmp_path / "c.h5")
    _replace_signals(path, lambda g: g.create_dataset("signals", data=np.zeros((N, 4, 4, T),
                                                                                dtype)))
    with pytest.raises(CampaignFormatError) as info:
        load_campaign(path)
    assert (info.value.field, info.value.problem) == (
        "/recordings/signals", f"wrong dtype {dtype} (expected int16)")


@pytest.mark.parametrize("shape", [(N, 4, 4), (N, 1, 4, 4, T)])
def test_stored_signals_without_four_axes_are_refused(tmp_path, shape):
    path = _campaign(tmp_path / "c.h5")
    _replace_signals(path, lambda g: g.create_dataset("signals", data=np.zeros(shape, np.int16)))
    with pytest.raises(CampaignFormatError) as info:
        load_campaign(path)
    assert (info.value.field, info.value.problem) == (
        "/recordings/signals", f"wrong shape {shape}: expected 4 axes (n, rows, cols, T)")


def test_external_storage_allowed_is_not_measured_against_the_file(tmp_path):
    """76.8 MB of samples kept in a (sparse) file beside the campaign: the campaign file
    stores none of them, and with allow_external=True that is what was asked for."""
    shape = (N, 16, 16, 50_000)
    size = int(np.prod(shape)) * 2
    data = tmp_path / "samples.bin"
    with open(data, "wb") as fh:
        fh.truncate(size)
    path = write_campaign(tmp_path / "c.h5", np.zeros((N, 16, 16, 10), np.int16),
                          modality=[0, 1, 0], participant=[1, 2, 3], direction=[0, 0, 1],
                          run=[1, 1, 2], modalities=["a", "b"], sample_rate_hz=1000.0,
                          volts_per_count=1e-3, source="recorded")
    _replace_signals(path, lambda g: g.create_dataset("signals", shape=shape, dtype=np.int16,
                                                      external=[(str(data), 0, size)]))
    with load_campaign(path, allow_external=True) as c:
        assert c.signals.shape == shape
        assert not c.recording(1).any()


def test_a_campaign_of_three_hundred_recordings_keeps_its_extra_fields_and_patches(tmp_path):
    """Counts past the integers Python keeps as single objects."""
    n = 300
    ids = [f"p{i}" for i in range(300)]
    path = write_campaign(tmp_path / "c.h5", np.zeros((n, 1, 1, 2), np.int16),
                          modality=[0] * n, participant=list(range(n)), direction=[0] * n,
                          run=[1] * n, modalities=["a"], sample_rate_hz=1000.0,
                          volts_per_count=1e-3, source="recorded",
                          attrs={"patches": "[" + ", ".join(f'"{p}"' for p in ids) + "]"},
                          extras={"patch": np.arange(n, dtype=np.uint16),
                                  "force": np.ones(n, np.float32)})
    with load_campaign(path) as c:
        assert len(c.patches) == 300 and c.patch.tolist() == list(range(n))
        assert c.select(patch="p299").participant.tolist() == [299]
