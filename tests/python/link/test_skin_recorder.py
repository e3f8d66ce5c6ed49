"""eskin.link.skin_recorder: the patches' recorders append to one campaign, each recording
with its patch; a patch recording on other settings is refused by name."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from eskin.data.campaign import load_campaign
from eskin.link.skin_recorder import SkinRecorder


def settings(grid=(2, 2), rate=1000.0):
    return {"grid_shape": grid, "n_samples": 50, "sample_rate_hz": rate,
            "volts_per_count": 1e-3, "modalities": ["finger", "unknown"], "source": "recorded",
            "attrs": {"port": "/dev/pts/9", "labels": "test"}, "contact_interval": False,
            "overwrite": False, "extra_fields": {"stream_start": np.int64}}


def test_every_patch_in_one_campaign_with_its_patch(tmp_path):
    rec = SkinRecorder(tmp_path / "skin.h5", ["a", "b", "c"], overwrite=False,
                       attrs={"skin_name": "t"})
    writers = {pid: rec.writer_for(pid, settings()) for pid in ("c", "a")}
    rng = np.random.default_rng(0)
    expected = []

    def record(pid, k):
        x = rng.integers(-100, 100, (2, 2, 40)).astype(np.int16)
        writers[pid].append(x, modality=0, participant=-1, direction=255, run=0,
                            extra={"stream_start": k})
        return x

    threads = [threading.Thread(target=lambda p=pid: expected.extend(
        (p, record(p, k)) for k in range(5))) for pid in writers]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    writers["a"].close()  # a patch's close leaves the file to the skin's recorder
    rec.close()
    camp = load_campaign(tmp_path / "skin.h5")
    assert camp.patches == ["a", "b", "c"] and rec.recordings == len(camp) == 10
    assert camp.attrs["skin_name"] == "t" and "port" not in camp.attrs
    got = {(camp.patches[int(p)], int(s)) for p, s in zip(camp.patch,
                                                         camp.extras["stream_start"])}
    assert got == {(pid, k) for pid in ("a", "c") for k in range(5)}
    by_patch = {pid: [x for p, x in expected if p == pid] for pid in ("a", "c")}
    for pid, xs in by_patch.items():
        mine = camp.select(patch=pid)
        order = np.argsort(mine.extras["stream_start"])
        for k, x in zip(order, xs):
            assert np.array_equal(mine.recording(int(k)), x)


@pytest.mark.parametrize("change, key", [({"grid": (3, 2)}, "grid_shape"),
                                         ({"rate": 2000.0}, "sample_rate_hz")])
def test_a_patch_on_other_settings_is_refused_by_name(tmp_path, change, key):
    rec = SkinRecorder(tmp_path / "skin.h5", ["a", "b"], overwrite=False, attrs={})
    rec.writer_for("a", settings())
    with pytest.raises(ValueError, match=f"patch 'b' records {key}=.*patch 'a'"):
        rec.writer_for("b", settings(**change))
    rec.close()
    assert len(load_campaign(tmp_path / "skin.h5")) == 0  # nothing was appended
