"""The campaign file format: round trips, hand-written files, and every bad-file case."""

from __future__ import annotations

import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest

import eskin
from eskin.data.campaign import (
    FORMAT,
    Campaign,
    CampaignFormatError,
    CampaignWriter,
    load_campaign,
    save_campaign,
    write_campaign,
)

MODS = ["brush", "finger", "washer"]


def _arrays(n=6, grid=(4, 4), t=500, seed=0):
    rng = np.random.default_rng(seed)
    sig = rng.integers(-3000, 3000, (n, *grid, t)).astype(np.int16)
    lengths = rng.integers(t // 2, t + 1, n).astype(np.int32)
    sig *= (np.arange(t)[None, None, None, :] < lengths[:, None, None, None]).astype(np.int16)
    labels = dict(
        modality=np.arange(n) % 3,
        participant=np.repeat(np.arange(1, n // 2 + 2), 2)[:n],
        direction=np.arange(n) % 2,
        run=np.ones(n, int) + (np.arange(n) >= n // 2),
    )
    return sig, lengths, labels


def _write(path, **kw):
    sig, lengths, labels = _arrays()
    args = dict(modalities=MODS, sample_rate_hz=3000.0, volts_per_count=5 / 32768,
                source="simulated", lengths=lengths,
                contact_interval=np.stack([lengths // 4, lengths // 2], 1))
    args.update(labels)
    args.update(kw)
    write_campaign(path, sig, **args)
    return sig, lengths, labels


def test_round_trip_keeps_every_field(tmp_path):
    p = tmp_path / "c.h5"
    sig, lengths, labels = _write(p, attrs={"note": "hello", "params": {"a": 1}})
    with load_campaign(p) as c:
        assert len(c) == 6 and c.grid_shape == (4, 4) and c.n_samples == 500
        assert c.signals.shape == sig.shape and c.signals.dtype == np.int16
        np.testing.assert_array_equal(np.asarray(c.signals), sig)
        np.testing.assert_array_equal(c.lengths, lengths)
        for k, v in labels.items():
            np.testing.assert_array_equal(getattr(c, k), v)
            assert getattr(c, k).dtype == {"modality": np.uint8, "participant": np.int32,
                                           "direction": np.uint8, "run": np.uint8}[k]
        assert c.modalities == MODS and c.source == "simulated"
        assert c.sample_rate_hz == 3000.0 and c.volts_per_count == 5 / 32768
        assert c.attrs["note"] == "hello" and c.attrs["params"] == '{"a": 1}'
        np.testing.assert_array_equal(c.contact_interval[:, 1], lengths // 2)
        rec = c.recording(2)
        assert rec.shape == (4, 4, lengths[2]) and rec.dtype == np.int16
        np.testing.assert_array_equal(rec, sig[2, ..., : lengths[2]])
        np.testing.assert_allclose(c.signals_float(2), rec * (5 / 32768))
    with h5py.File(p) as f:
        ds = f["recordings/signals"]
        assert ds.chunks == (1, 4, 4, 500) and ds.compression == "gzip"
        assert f.attrs["format"] == FORMAT and int(f.attrs["format_version"]) == 1


def test_subset_select_and_save(tmp_path):
    p = tmp_path / "c.h5"
    sig, lengths, labels = _write(p)
    with load_campaign(p) as c:
        sub = c.subset([4, 1, 1])
        assert len(sub) == 3
        np.testing.assert_array_equal(np.asarray(sub.signals), sig[[4, 1, 1]])
        np.testing.assert_array_equal(sub.lengths, lengths[[4, 1, 1]])
        fingers = c.select(modality="finger", run=[1, 2])
        assert list(fingers.modality) == [1, 1]
        mask = c.subset(c.run == 2)
        assert set(mask.run.tolist()) == {2}
        np.testing.assert_array_equal(mask.subset([0]).signals[0], sig[c.run == 2][0])
        save_campaign(sub, tmp_path / "sub.h5")
        mem = c.load()
        assert isinstance(mem.signals, np.ndarray)
    with load_campaign(tmp_path / "sub.h5", in_memory=True) as s2:
        np.testing.assert_array_equal(s2.signals, sig[[4, 1, 1]])
        assert s2.contact_interval.shape == (3, 2)


def test_streaming_writer_pads_and_checks(tmp_path):
    p = tmp_path / "w.h5"
    with CampaignWriter(p, grid_shape=(2, 3), n_samples=100, sample_rate_hz=1000.0,
                        volts_per_count=1e-3, modalities=["a", "b"], source="recorded") as w:
        w.append(np.ones((2, 3, 60), np.int16), modality="b", participant=5, direction=255,
                 run=1)
        w.append(np.full((2, 3, 100), -7, np.int32), modality=0, participant=6, direction=0,
                 run=2, length=80)
        with pytest.raises(ValueError, match="shape"):
            w.append(np.ones((3, 2, 10), np.int16), modality=0, participant=1, direction=0,
                     run=1)
        with pytest.raises(ValueError, match="unknown modality"):
            w.append(np.ones((2, 3, 10), np.int16), modality="c", participant=1, direction=0,
                     run=1)
        with pytest.raises(ValueError, match="int16 ADC counts"):
            w.append(np.ones((2, 3, 10)), modality=0, participant=1, direction=0, run=1)
        assert not p.exists()  # the file appears only when complete
    c = load_campaign(p, in_memory=True)
    assert c.lengths.tolist() == [60, 80]
    assert c.recording(0).shape == (2, 3, 60) and c.recording(1).shape == (2, 3, 80)
    assert np.all(np.asarray(c.signals)[0, ..., 60:] == 0)
    assert np.all(np.asarray(c.signals)[1, ..., 80:] == 0)
    assert c.direction.tolist() == [255, 0] and c.modality.tolist() == [1, 0]


def test_never_overwrites_unless_asked(tmp_path):
    p = tmp_path / "c.h5"
    sig, _, _ = _write(p)
    before = p.read_bytes()
    with pytest.raises(FileExistsError, match="refusing to overwrite"):
        _write(p)
    assert p.read_bytes() == before
    _write(p, overwrite=True)
    assert load_campaign(p, in_memory=True).signals.shape == sig.shape


def test_failed_write_leaves_existing_file_intact(tmp_path):
    p = tmp_path / "c.h5"
    _write(p)
    before = p.read_bytes()
    with pytest.raises(RuntimeError):
        with CampaignWriter(p, n_samples=10, sample_rate_hz=1.0, volts_per_count=1.0,
                            modalities=["x"], source="recorded", overwrite=True) as w:
            w.append(np.zeros((4, 4, 10), np.int16), modality=0, participant=0, direction=0,
                     run=0)
            raise RuntimeError("power cut")
    assert p.read_bytes() == before
    # the appended recording waits in the journal (docs/dataset-format.md, "Each way out")
    assert sorted(q.name for q in tmp_path.iterdir()) == [".c.h5.partial", "c.h5"]


def test_hand_written_odd_grid_loads(tmp_path):
    """A file made with h5py alone, following docs/dataset-format.md: 3x5 taxels at 1000 Hz."""
    p = tmp_path / "hand.h5"
    rng = np.random.default_rng(3)
    sig = rng.integers(-100, 100, (4, 3, 5, 250)).astype(np.int16)
    with h5py.File(p, "w") as f:
        f.attrs["format"] = "eskin-campaign"
        f.attrs["format_version"] = 1
        f.attrs["sample_rate_hz"] = 1000.0
        f.attrs["volts_per_count"] = 0.5e-3
        f.attrs["modalities"] = ["tap", "slide"]
        f.attrs["source"] = "recorded"
        g = f.create_group("recordings")
        g.create_dataset("signals", data=sig, chunks=(1, 3, 5, 250), compression="gzip")
        g["length"] = np.array([250, 200, 10, 0], np.int32)
        g["modality"] = np.array([0, 1, 1, 0], np.uint8)
        g["participant"] = np.array([1, 1, 2, 2], np.int32)
        g["direction"] = np.array([0, 1, 255, 0], np.uint8)
        g["run"] = np.array([1, 1, 1, 2], np.uint8)
    with load_campaign(p) as c:
        assert c.grid_shape == (3, 5) and c.sample_rate_hz == 1000.0
        assert c.modalities == ["tap", "slide"] and c.contact_interval is None
        assert c.recording(1).shape == (3, 5, 200) and c.recording(3).shape == (3, 5, 0)
        np.testing.assert_array_equal(c.recording(0), sig[0])
    # fixed-length byte strings (as MATLAB or h5py users may write them) load too
    with h5py.File(p, "a") as f:
        f.attrs["modalities"] = np.array([b"tap", b"slide"])
        f.attrs["source"] = np.bytes_("recorded")
    assert load_campaign(p, in_memory=True).modalities == ["tap", "slide"]


def test_in_memory_campaign_validates():
    sig, lengths, labels = _arrays()
    c = Campaign(sig, lengths, modalities=MODS, sample_rate_hz=3000, volts_per_count=1.0,
                 source="recorded", **labels)
    assert len(c) == 6 and c.path is None
    with pytest.raises(CampaignFormatError, match="<memory>: /recordings/modality"):
        Campaign(sig, lengths, modalities=["a"], sample_rate_hz=3000, volts_per_count=1.0,
                 source="recorded", **labels)


# ---------------------------------------------------------------- bad files


def _good(tmp_path) -> Path:
    p = tmp_path / "good.h5"
    _write(p)
    return p


def _edit(tmp_path, fn) -> Path:
    p = _good(tmp_path)
    with h5py.File(p, "a") as f:
        fn(f)
    return p


def _replace(name, data):
    def fn(f):
        del f[f"recordings/{name}"]
        f[f"recordings/{name}"] = data

    return fn


BAD_CASES = {
    "missing signals": (lambda f: f.__delitem__("recordings/signals"),
                        "/recordings/signals", "missing"),
    "missing length": (lambda f: f.__delitem__("recordings/length"),
                       "/recordings/length", "missing"),
    "missing run": (lambda f: f.__delitem__("recordings/run"), "/recordings/run", "missing"),
    "missing group": (lambda f: f.__delitem__("recordings"), "/recordings", "missing"),
    "missing rate": (lambda f: f.attrs.__delitem__("sample_rate_hz"),
                     "attribute 'sample_rate_hz'", "missing"),
    "missing modalities": (lambda f: f.attrs.__delitem__("modalities"),
                           "attribute 'modalities'", "missing"),
    "bad version": (lambda f: f.attrs.__setitem__("format_version", 7),
                    "attribute 'format_version'", "not supported"),
    "bad source": (lambda f: f.attrs.__setitem__("source", "guessed"),
                   "attribute 'source'", "must be one of"),
    "negative rate": (lambda f: f.attrs.__setitem__("sample_rate_hz", -3.0),
                      "attribute 'sample_rate_hz'", "positive"),
    "rate 1e300": (lambda f: f.attrs.__setitem__("sample_rate_hz", 1e300),
                   "attribute 'sample_rate_hz'",
                   "1e+300 Hz is outside the sample rates eskin reads, 0.1 Hz to 1e+06 Hz"),
    "rate 1e-300": (lambda f: f.attrs.__setitem__("sample_rate_hz", 1e-300),
                    "attribute 'sample_rate_hz'", "1e-300 Hz is outside the sample rates"),
    "float signals": (_replace("signals", np.zeros((6, 4, 4, 500), np.float32)),
                      "/recordings/signals", "wrong dtype float32"),
    "3-axis signals": (_replace("signals", np.zeros((6, 16, 500), np.int16)),
                       "/recordings/signals", "wrong shape"),
    "int64 length": (_replace("length", np.full(6, 10, np.int64)),
                     "/recordings/length", "wrong dtype int64"),
    "int32 modality": (_replace("modality", np.zeros(6, np.int32)),
                       "/recordings/modality", "wrong dtype"),
    "short participant": (_replace("participant", np.zeros(5, np.int32)),
                          "/recordings/participant", "wrong shape"),
    "length > T": (_replace("length", np.full(6, 501, np.int32)),
                   "/recordings/length", "outside"),
    "modality out of range": (_replace("modality", np.full(6, 3, np.uint8)),
                              "/recordings/modality", "out of range"),
    "bad direction": (_replace("direction", np.full(6, 2, np.uint8)),
                      "/recordings/direction", "direction 2"),
    "bad interval": (_replace("contact_interval", np.tile(np.array([[5, 2]], np.int32), (6, 1))),
                     "/recordings/contact_interval", "onset <= offset"),
    "foreign format": (lambda f: f.attrs.__setitem__("format", "matlab-thing"),
                       "attribute 'format'", "not an eskin campaign"),
}


@pytest.mark.parametrize("case", sorted(BAD_CASES))
def test_bad_file_gives_clear_error(tmp_path, case):
    fn, field, problem = BAD_CASES[case]
    p = _edit(tmp_path, fn)
    with pytest.raises(CampaignFormatError) as info:
        load_campaign(p)
    err = info.value
    assert isinstance(err, ValueError)
    assert str(p) in str(err) and field in str(err) and problem in str(err), str(err)
    assert err.field == field


@pytest.mark.parametrize("rate", [1e300, 1e-300, 0.05, 2e6])
def test_the_writer_refuses_a_rate_the_loader_would_refuse(tmp_path, rate):
    with pytest.raises(CampaignFormatError, match=r"attribute 'sample_rate_hz': .* Hz is outside "
                       r"the sample rates eskin reads, 0.1 Hz to 1e\+06 Hz"):
        CampaignWriter(tmp_path / "w.h5", n_samples=10, sample_rate_hz=rate,
                       volts_per_count=1.0, modalities=["x"], source="recorded")
    assert list(tmp_path.iterdir()) == []


def test_a_symbolic_link_loop_is_an_os_error_naming_it(tmp_path):
    import errno

    p = tmp_path / "loop.h5"
    p.symlink_to("loop.h5")
    with pytest.raises(OSError) as info:
        load_campaign(p)
    assert info.value.errno == errno.ELOOP and info.value.filename == str(p)


def test_foreign_hdf5(tmp_path):
    p = tmp_path / "other.h5"
    with h5py.File(p, "w") as f:
        f["data"] = np.arange(10)
    with pytest.raises(CampaignFormatError, match="not an eskin campaign"):
        load_campaign(p)


def test_not_hdf5(tmp_path):
    p = tmp_path / "notes.h5"
    p.write_text("participant,modality\n1,brush\n")
    with pytest.raises(CampaignFormatError, match=r"notes\.h5: not an HDF5 file \(no HDF5 signature\), so not an eskin campaign"):
        load_campaign(p)
    empty = tmp_path / "empty.h5"
    empty.write_bytes(b"")
    with pytest.raises(CampaignFormatError, match="not an HDF5 file"):
        load_campaign(empty)


@pytest.mark.parametrize("keep", [0.3, 0.7, 0.97])
def test_truncated_hdf5(tmp_path, keep):
    good = _good(tmp_path)
    p = tmp_path / "cut.h5"
    data = good.read_bytes()
    p.write_bytes(data[: int(len(data) * keep)])
    with pytest.raises(CampaignFormatError, match=r"cut\.h5: (truncated|not an HDF5)"):
        load_campaign(p, check_data=True)


def test_corrupted_chunk_is_reported_not_crashed(tmp_path):
    good = _good(tmp_path)
    with h5py.File(good) as f:
        offset = f["recordings/signals"].id.get_chunk_info(2).byte_offset
    p = tmp_path / "bad_chunk.h5"
    shutil.copy(good, p)
    with open(p, "r+b") as fh:
        fh.seek(offset + 10)
        fh.write(b"\xff" * 64)
    c = load_campaign(p)  # labels are fine; the damage shows when reading data
    with pytest.raises(CampaignFormatError, match="/recordings/signals"):
        c.recording(2)
    c.close()
    with pytest.raises(CampaignFormatError, match="/recordings/signals"):
        load_campaign(p, check_data=True)


def test_missing_file_and_directory(tmp_path):
    with pytest.raises(FileNotFoundError, match="no such campaign file"):
        load_campaign(tmp_path / "nope.h5")
    with pytest.raises(CampaignFormatError, match="directory"):
        load_campaign(tmp_path)


def test_public_names():
    assert eskin.load_campaign is load_campaign
    assert issubclass(eskin.CampaignFormatError, ValueError)


def test_extras_round_trip_and_follow_subsets(tmp_path):
    sig, lengths, labels = _arrays()
    extras = {"speed": np.linspace(1, 2, 6).astype(np.float32),
              "pair": np.arange(12, dtype=np.int8).reshape(6, 2)}
    p = tmp_path / "x.h5"
    write_campaign(p, sig, lengths=lengths, modalities=MODS, sample_rate_hz=100.0,
                   volts_per_count=1.0, source="recorded", extras=extras, **labels)
    with load_campaign(p) as c:
        np.testing.assert_array_equal(c.extras["speed"], extras["speed"])
        assert c.extras["pair"].dtype == np.int8
        sub = c.subset([5, 0])
        np.testing.assert_array_equal(sub.extras["pair"], extras["pair"][[5, 0]])
        save_campaign(sub, tmp_path / "y.h5")
    with load_campaign(tmp_path / "y.h5") as d:
        np.testing.assert_array_equal(d.extras["speed"], extras["speed"][[5, 0]])
    with h5py.File(p, "a") as f:
        del f["recordings/extra/speed"]
        f["recordings/extra/speed"] = np.zeros(4)
    with pytest.raises(CampaignFormatError, match="/recordings/extra/speed: wrong shape"):
        load_campaign(p)


def test_encoded_and_uncompressed_recordings(tmp_path):
    from eskin.data.campaign import encode_recording

    rec = np.arange(2 * 3 * 40, dtype=np.int16).reshape(2, 3, 40) - 100
    enc = encode_recording(rec, grid_shape=(2, 3), n_samples=50, length=30)
    for level in (None, 1):
        p = tmp_path / f"e{level}.h5"
        with CampaignWriter(p, grid_shape=(2, 3), n_samples=50, sample_rate_hz=10.0,
                            volts_per_count=1.0, modalities=["a"], source="recorded",
                            compression_level=level) as w:
            if level == 1:
                w.append(enc, modality=0, participant=1, direction=0, run=1)
            else:
                with pytest.raises(ValueError, match="encoded for grid"):
                    w.append(enc, modality=0, participant=1, direction=0, run=1)
                w.append(rec, modality=0, participant=1, direction=0, run=1, length=30)
        with h5py.File(p) as f:
            assert f["recordings/signals"].compression == (None if level is None else "gzip")
        with load_campaign(p) as c:
            np.testing.assert_array_equal(c.recording(0), rec[..., :30])
            assert np.all(np.asarray(c.signals)[0, ..., 30:] == 0)


# ---------------------------------------------------------------- the checks beside the job


def test_compression_levels_are_0_to_9(tmp_path):
    for level in (0, 9):
        with CampaignWriter(tmp_path / f"c{level}.h5", grid_shape=(1, 2), n_samples=4,
                            sample_rate_hz=10.0, volts_per_count=1.0, modalities=["a"],
                            source="recorded", compression_level=level) as w:
            w.append(np.ones((1, 2, 4), np.int16), modality=0, participant=1, direction=0, run=1)
        assert len(load_campaign(tmp_path / f"c{level}.h5", in_memory=True)) == 1
    for level in (-1, 10):
        with pytest.raises(ValueError, match=f"compression_level must be None or 0..9, got {level}"):
            CampaignWriter(tmp_path / "bad.h5", grid_shape=(1, 2), n_samples=4,
                           sample_rate_hz=10.0, volts_per_count=1.0, modalities=["a"],
                           source="recorded", compression_level=level)


def test_subset_indices_are_checked_at_both_ends(tmp_path):
    p = tmp_path / "c.h5"
    sig, _, _ = _write(p)
    with load_campaign(p) as c:
        np.testing.assert_array_equal(np.asarray(c.subset([-1, -6]).signals), sig[[5, 0]])
        for bad in ([6], [-7], [0, 6]):
            with pytest.raises(IndexError, match="out of range for 6 recordings"):
                c.subset(bad)
        assert len(c.subset([])) == 0


def test_a_single_label_of_the_wrong_kind_is_refused():
    sig, lengths, labels = _arrays(n=1)
    with pytest.raises(CampaignFormatError, match="must be integers"):
        Campaign(sig, lengths, modalities=MODS, sample_rate_hz=3000, volts_per_count=1.0,
                 source="recorded", **{**labels, "run": np.array([1.0])})


def test_an_extra_field_over_its_size_limit_is_refused_before_it_is_read(tmp_path, monkeypatch):
    import eskin.data.campaign as cm

    sig, lengths, labels = _arrays()
    p = tmp_path / "x.h5"
    write_campaign(p, sig, lengths=lengths, modalities=MODS, sample_rate_hz=100.0,
                   volts_per_count=1.0, source="recorded",
                   extras={"wide": np.zeros((6, 64), np.float64)}, **labels)
    assert load_campaign(p).extras["wide"].shape == (6, 64)
    monkeypatch.setattr(cm, "_MAX_EXTRA_BYTES", 6 * 64 * 8 - 1)  # one byte short of the field
    with pytest.raises(CampaignFormatError, match="/recordings/extra/wide: wrong shape"):
        load_campaign(p)


def test_a_label_stored_with_another_integer_type_is_refused(tmp_path):
    p = _good(tmp_path)
    with h5py.File(p, "a") as f:
        run = f["recordings/run"][()]
        del f["recordings/run"]
        f["recordings/run"] = run.astype(np.int8)  # expected uint8
    with pytest.raises(CampaignFormatError, match="/recordings/run: wrong dtype int8"):
        load_campaign(p)


def test_repeated_reads_of_one_recording(tmp_path):
    p = tmp_path / "c.h5"
    sig, _, _ = _write(p)
    with load_campaign(p) as c:
        np.testing.assert_array_equal(np.asarray(c.subset([3, 3]).signals), sig[[3, 3]])
        np.testing.assert_array_equal(np.asarray(c.subset([5]).signals), sig[[5]])


def _writer(path, **kw):
    return CampaignWriter(path, grid_shape=(1, 2), n_samples=10, sample_rate_hz=10.0,
                          volts_per_count=1.0, modalities=["a"], source="recorded", **kw)


def test_the_writer_checks_values_lengths_and_contact_intervals(tmp_path):
    labels = dict(modality=0, participant=1, direction=0, run=1)
    with _writer(tmp_path / "c.h5", contact_interval=True) as w:
        for bad in (32768, -32769):
            x = np.zeros((1, 2, 4), np.int32)
            x[0, 1, 2] = bad
            with pytest.raises(ValueError, match="values outside the int16 range"):
                w.append(x, contact_interval=(0, 1), **labels)
        with pytest.raises(ValueError, match=r"length 5 outside \[0, 4\]"):
            w.append(np.zeros((1, 2, 4), np.int16), length=5, contact_interval=(0, 1), **labels)
        for on, off in ((-1, 2), (3, 2), (0, 5)):
            with pytest.raises(ValueError, match=rf"contact interval \[{on}, {off}\) not within \[0, 4\]"):
                w.append(np.zeros((1, 2, 4), np.int16), contact_interval=(on, off), **labels)
        w.append(np.zeros((1, 2, 4), np.int16), contact_interval=(0, 4), **labels)
        w.append(np.full((1, 2, 4), 32767, np.int32), contact_interval=(2, 2), **labels)
    c = load_campaign(tmp_path / "c.h5", in_memory=True)
    assert c.contact_interval.tolist() == [[0, 4], [2, 2]]
    assert int(np.asarray(c.signals).max()) == 32767


def test_recovery_skips_a_chunk_of_the_wrong_size_and_says_both_sizes(tmp_path):
    """In process (the command's tests are in test_recover_checks.py): a journal record whose
    chunk inflates to 10 bytes, not a 2x2x100 recording's 800, is skipped and named."""
    import zlib

    from eskin.data.campaign import CampaignWriter, recover_campaign

    path = tmp_path / "c.h5"
    w = CampaignWriter(path, grid_shape=(2, 2), n_samples=100, sample_rate_hz=1000.0,
                       volts_per_count=1e-3, modalities=["a"], source="recorded")
    w.append(np.full((2, 2, 100), 3, np.int16), modality=0, participant=0, direction=0, run=1)
    meta = {"length": 100, "modality": 0, "participant": 1, "direction": 0, "run": 1}
    w._journal.append(meta, {}, zlib.compress(b"\0" * 10))
    w._journal.release()
    rec = recover_campaign(path)
    assert rec.recordings == 1
    assert rec.skipped == ("record 1: /recordings/signals: the chunk holds 10 bytes, not the 800 "
                           "of a 2x2x100 int16 recording",)
    with load_campaign(path, check_data=True) as c:
        assert len(c) == 1 and (c.recording(0) == 3).all()


def _one_recording_writer(path, **kw) -> "eskin.data.campaign.CampaignWriter":
    from eskin.data.campaign import CampaignWriter

    return CampaignWriter(path, grid_shape=(1, 2), n_samples=100, sample_rate_hz=100.0,
                          volts_per_count=1e-3, modalities=["a", "b"], source="recorded", **kw)


def test_a_mapping_attribute_is_stored_as_json_with_sorted_keys(tmp_path):
    path = tmp_path / "c.h5"
    with _one_recording_writer(path, attrs={"calibration": {"b": 1, "a": [2, 3]}}) as w:
        w.append(np.zeros((1, 2, 10), np.int16), modality=0, participant=0, direction=0, run=1)
    with h5py.File(path, "r") as f:
        raw = f.attrs["calibration"]
    assert (raw.decode() if isinstance(raw, bytes) else raw) == '{"a": [2, 3], "b": 1}'


def test_contact_intervals_inside_the_recording_are_kept_at_either_end(tmp_path):
    path = tmp_path / "c.h5"
    with _one_recording_writer(path, contact_interval=True) as w:
        for ci in [(0, 100), (3, 50), (7, 7), (40, 100)]:
            w.append(np.zeros((1, 2, 100), np.int16), modality=1, participant=5, direction=1,
                     run=255, contact_interval=ci)
        for ci in [(50, 3), (-1, 10), (3, 101)]:
            with pytest.raises(ValueError, match=r"contact interval \[.*not within"):
                w.append(np.zeros((1, 2, 100), np.int16), modality=1, participant=5,
                         direction=1, run=1, contact_interval=ci)
    with load_campaign(path) as c:
        assert np.asarray(c.contact_interval).tolist() == [[0, 100], [3, 50], [7, 7], [40, 100]]
        assert list(c.run) == [255] * 4


def test_run_numbers_are_0_to_255_in_the_writer(tmp_path):
    with _one_recording_writer(tmp_path / "c.h5") as w:
        for run in (0, 255):
            w.append(np.zeros((1, 2, 5), np.int16), modality=0, participant=0, direction=0,
                     run=run)
        for run in (-1, 256):
            with pytest.raises(ValueError, match=rf"run {run} outside \[0, 255\]"):
                w.append(np.zeros((1, 2, 5), np.int16), modality=0, participant=0,
                         direction=0, run=run)


def test_several_bad_lengths_are_counted_in_the_message(tmp_path):
    path = tmp_path / "c.h5"
    with _one_recording_writer(path) as w:
        for _ in range(3):
            w.append(np.zeros((1, 2, 10), np.int16), modality=0, participant=0, direction=0, run=1)
    with h5py.File(path, "r+") as f:
        f["recordings/length"][1] = 500
    with pytest.raises(CampaignFormatError, match=r"recording 1 has length 500, outside \[0, T=100\]$"):
        load_campaign(path)
    with h5py.File(path, "r+") as f:
        f["recordings/length"][2] = 400
    with pytest.raises(CampaignFormatError, match=r"length 500, outside \[0, T=100\] \(2 bad entries\)"):
        load_campaign(path)


def test_extras_need_one_entry_per_recording_in_memory_and_on_disk(tmp_path):
    sig = [np.zeros((1, 2, 5), np.int16)] * 3
    common = dict(modality=[0, 1, 0], participant=[0, 0, 1], direction=[0] * 3, run=[1] * 3,
                  modalities=["a", "b"], sample_rate_hz=100.0, volts_per_count=1e-3,
                  source="recorded")
    path = write_campaign(tmp_path / "ok.h5", sig, **common,
                          extras={"force": np.arange(6.0).reshape(3, 2), "id": np.arange(3)})
    with load_campaign(path) as c:
        assert np.asarray(c.extras["force"]).tolist() == [[0, 1], [2, 3], [4, 5]]
    for bad in (np.arange(2), np.arange(4), np.float64(1.0)):
        with pytest.raises(ValueError, match=r"extras\['id'\] must have one entry per recording \(3\)"):
            write_campaign(tmp_path / "bad.h5", sig, **common, extras={"id": bad})
    with h5py.File(path, "r+") as f:  # on disk: one entry short
        del f["recordings/extra/id"]
        f["recordings/extra/id"] = np.arange(2)
    with pytest.raises(CampaignFormatError, match="/recordings/extra/id"):
        load_campaign(path)


def test_a_recording_index_past_either_end_is_refused_naming_it(tmp_path):
    path = tmp_path / "c.h5"
    with _one_recording_writer(path) as w:
        for k in range(3):
            w.append(np.full((1, 2, 5), k, np.int16), modality=0, participant=0, direction=0, run=1)
    with load_campaign(path) as c:
        assert c.recording(-3)[0, 0, 0] == 0 and c.recording(2)[0, 0, 0] == 2
        for i in (3, 7, -4):
            with pytest.raises(IndexError, match=f"recording index {i} out of range for 3 recordings"):
                c.recording(i)


def test_an_empty_campaign_summarises_to_zero_lengths(tmp_path):
    path = tmp_path / "c.h5"
    _one_recording_writer(path).close()
    with load_campaign(path) as c:
        s = c.summary()
    assert s["recordings"] == 0 and s["length_min"] == 0 and s["length_median"] == 0.0


def test_recovery_never_replaces_an_existing_output_unless_told(tmp_path):
    from eskin.data.campaign import recover_campaign

    path = tmp_path / "c.h5"
    w = _one_recording_writer(path)
    w.append(np.full((1, 2, 5), 4, np.int16), modality=0, participant=0, direction=0, run=1)
    w._journal.release()
    out = tmp_path / "out.h5"
    out.write_bytes(b"keep me")
    with pytest.raises(FileExistsError):
        recover_campaign(path, out)
    assert out.read_bytes() == b"keep me"
    assert recover_campaign(path, out, overwrite=True).recordings == 1
    with load_campaign(out) as c:
        assert (c.recording(0) == 4).all()


def test_practice_runs_are_run_1_and_second_runs_run_2():
    """docs/dataset-format.md's numbering of /recordings/run."""
    from eskin.data.campaign import RUN_PRACTICE, RUN_SECOND

    assert (RUN_PRACTICE, RUN_SECOND) == (1, 2)


def test_participants_span_the_whole_int32_range_in_the_writer(tmp_path):
    path = tmp_path / "c.h5"
    lo, hi = -(2**31), 2**31 - 1
    with _one_recording_writer(path) as w:
        for p in (lo, hi):
            w.append(np.zeros((1, 2, 5), np.int16), modality=0, participant=p, direction=0, run=1)
        for p in (lo - 1, hi + 1):
            with pytest.raises(ValueError, match=f"participant {p} outside the int32 range"):
                w.append(np.zeros((1, 2, 5), np.int16), modality=0, participant=p, direction=0,
                         run=1)
    with load_campaign(path) as c:
        assert list(c.participant) == [lo, hi]


def test_a_writer_needs_at_least_one_sample_per_recording(tmp_path):
    for n in (0, -5):
        with pytest.raises(ValueError, match=f"n_samples must be >= 1, got {n}"):
            CampaignWriter(tmp_path / "c.h5", grid_shape=(1, 1), n_samples=n, sample_rate_hz=1.0,
                           volts_per_count=1.0, modalities=["a"], source="recorded")
    assert not (tmp_path / "c.h5").exists()


def test_directions_are_numbered_as_the_format_says():
    """docs/dataset-format.md: 0 horizontal, 1 vertical, 255 unknown."""
    from eskin.data.campaign import (
        DIRECTION_HORIZONTAL,
        DIRECTION_NAMES,
        DIRECTION_UNKNOWN,
        DIRECTION_VERTICAL,
    )

    assert (DIRECTION_HORIZONTAL, DIRECTION_VERTICAL, DIRECTION_UNKNOWN) == (0, 1, 255)
    assert DIRECTION_NAMES[1] == "vertical" and DIRECTION_NAMES[0] == "horizontal"


def test_a_writer_that_fails_after_appends_keeps_them_and_one_that_failed_at_once_keeps_nothing(
    tmp_path,
):
    kept, empty = tmp_path / "kept.h5", tmp_path / "empty.h5"
    with pytest.raises(RuntimeError):
        with _one_recording_writer(kept) as w:
            w.append(np.full((1, 2, 5), 9, np.int16), modality=0, participant=0, direction=0, run=1)
            raise RuntimeError("the rig fell over")
    from eskin.data.campaign import recover_campaign
    from eskin.data.journal import journal_path

    assert journal_path(kept).exists() and not kept.exists()  # kept for `eskin recover`
    assert recover_campaign(kept).recordings == 1
    with load_campaign(kept) as c:
        assert len(c) == 1 and (c.recording(0) == 9).all()
    with pytest.raises(RuntimeError):
        with _one_recording_writer(empty):
            raise RuntimeError("before any recording")
    assert not empty.exists() and not journal_path(empty).exists()


def test_a_modality_id_past_the_named_modalities_is_refused(tmp_path):
    with _one_recording_writer(tmp_path / "c.h5") as w:  # modalities a, b
        w.append(np.zeros((1, 2, 5), np.int16), modality=1, participant=0, direction=0, run=1)
        for m in (2, 3, 200, -1):
            with pytest.raises(ValueError, match=f"modality id {m} out of range"):
                w.append(np.zeros((1, 2, 5), np.int16), modality=m, participant=0, direction=0,
                         run=1)


def test_select_takes_its_labels_by_name_only(tmp_path):
    path = tmp_path / "c.h5"
    with _one_recording_writer(path) as w:
        w.append(np.zeros((1, 2, 5), np.int16), modality=1, participant=3, direction=0, run=1)
    with load_campaign(path) as c:
        assert len(c.select(modality="b")) == 1 and len(c.select(participant=2)) == 0
        with pytest.raises(TypeError):
            c.select("b")  # a positional label would be ambiguous: refused
