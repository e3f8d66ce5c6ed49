"""Crash-safe recording: kill -9 during appends, recovery, exclusive creation, one writer."""

from __future__ import annotations

import multiprocessing
import os
import re
import signal
import time
import warnings

import numpy as np
import pytest

from eskin.data.campaign import CampaignWriter, load_campaign, recover_campaign
from eskin.data.journal import journal_path

GRID, T = (2, 3), 64
MODALITIES = ["brush", "finger", "washer"]


def _recording(i: int) -> np.ndarray:
    """Recording i, reproducible from i alone (the parent checks what the child wrote)."""
    rng = np.random.default_rng(1000 + i)
    return rng.integers(-2000, 2000, size=(*GRID, 8 + i % 50), dtype=np.int16)


def _labels(i: int) -> dict:
    n = 8 + i % 50
    return {
        "modality": i % 3,
        "participant": i // 6,
        "direction": i % 2,
        "run": 1 + i % 2,
        "contact_interval": (i % 5, n - 1),
        "extra": {"force_n": 0.5 * i, "tag": i % 7},
    }


def _open(path, **kw) -> CampaignWriter:
    return CampaignWriter(
        path,
        grid_shape=GRID,
        n_samples=T,
        sample_rate_hz=3000.0,
        volts_per_count=1e-3,
        modalities=MODALITIES,
        source="recorded",
        contact_interval=True,
        attrs={"operator": "lab", "gain": [1.5, 2.0]},
        extra_fields={"force_n": np.float32, "tag": np.uint8},
        **kw,
    )


def _append(w: CampaignWriter, i: int) -> int:
    return w.append(_recording(i), **_labels(i))


def _check_recordings(path, n: int) -> None:
    c = load_campaign(path, in_memory=True)
    assert len(c) == n
    assert c.attrs["operator"] == "lab" and c.attrs["gain"] == [1.5, 2.0]
    for i in range(n):
        lab = _labels(i)
        np.testing.assert_array_equal(c.recording(i), _recording(i))
        assert (c.modality[i], c.participant[i], c.direction[i], c.run[i]) == (
            lab["modality"],
            lab["participant"],
            lab["direction"],
            lab["run"],
        )
        assert tuple(c.contact_interval[i]) == lab["contact_interval"]
        assert c.extras["force_n"][i] == np.float32(lab["extra"]["force_n"])
        assert c.extras["tag"][i] == lab["extra"]["tag"]


def _writer_child(path, conn) -> None:
    """Append forever, reporting each index once its append has returned."""
    w = _open(path)
    conn.send("open")
    i = 0
    while True:
        _append(w, i)
        conn.send(i)
        i += 1


def _fork(target, *args):
    """Start ``target`` in a forked child (fast: nothing to import again). The child only
    writes a journal, so Python's warning about forking a process with threads does not
    apply to it."""
    proc = multiprocessing.get_context("fork").Process(target=target, args=args)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        proc.start()
    return proc


def test_kill_9_mid_append_loses_at_most_the_recording_in_flight(tmp_path):
    ctx = multiprocessing.get_context("fork")
    rng = np.random.default_rng(20260)
    for trial in range(24):
        path = tmp_path / f"c{trial}.h5"
        parent, child = ctx.Pipe(duplex=False)
        proc = _fork(_writer_child, path, child)
        child.close()
        assert parent.recv() == "open"
        # not synchronisation: the kill lands at a random point of the writes (the behaviour
        # under test), drawn from the seeded generator
        time.sleep(float(rng.uniform(0.0, 0.06)))
        os.kill(proc.pid, signal.SIGKILL)
        proc.join()
        assert proc.exitcode == -signal.SIGKILL
        returned = []
        while parent.poll():
            try:
                returned.append(parent.recv())
            except EOFError:
                break
        parent.close()
        assert returned == list(range(len(returned)))
        assert not path.exists() and journal_path(path).exists()
        report = recover_campaign(path)
        # every append that returned is there; the one in flight may be complete or not
        assert len(returned) <= report.recordings <= len(returned) + 1, (trial, report)
        assert report.message().startswith(f"recovered {report.recordings} complete recordings")
        _check_recordings(path, report.recordings)
        assert sorted(q.name for q in tmp_path.iterdir() if q.name.startswith(f".c{trial}.")) == []


def _journal_bytes(tmp_path, n: int) -> tuple[bytes, list[int]]:
    """A journal of n recordings and the size it had after each append."""
    path = tmp_path / "j.h5"
    w = _open(path)
    sizes = [journal_path(path).stat().st_size]
    for i in range(n):
        _append(w, i)
        sizes.append(journal_path(path).stat().st_size)
    data = journal_path(path).read_bytes()
    w.abort()
    return data, sizes


def test_every_cut_of_the_journal_recovers_exactly_the_complete_records(tmp_path):
    data, sizes = _journal_bytes(tmp_path, 4)
    rng = np.random.default_rng(7)
    cuts = sorted({*sizes, *(s - 1 for s in sizes[1:]), *rng.integers(sizes[0], len(data), 12)})
    for k, cut in enumerate(cuts):
        path = tmp_path / f"cut{k}.h5"
        journal_path(path).write_bytes(data[:cut])
        report = recover_campaign(path)
        complete = sum(1 for s in sizes[1:] if s <= cut)
        assert report.recordings == complete
        assert report.dropped_bytes == cut - sizes[complete]
        _check_recordings(path, complete)


def test_a_damaged_record_stops_recovery_there(tmp_path):
    data, sizes = _journal_bytes(tmp_path, 3)
    bad = bytearray(data)
    bad[sizes[2] - 10] ^= 0x40  # inside the chunk of recording 1
    path = tmp_path / "bad.h5"
    journal_path(path).write_bytes(bytes(bad))
    report = recover_campaign(path)
    assert report.recordings == 1
    assert "recording 1 fails its CRC-32" in report.message()
    _check_recordings(path, 1)


def test_a_record_with_incomplete_labels_is_skipped(tmp_path):
    path = tmp_path / "c.h5"
    w = _open(path)
    _append(w, 0)
    # a CRC-valid record whose labels lack the run (a writer of another version, a bug)
    w._journal.append(
        {"length": 8, "modality": 0, "participant": 0, "direction": 0},
        {"force_n": (1.0, np.float32), "tag": (1, np.uint8)},
        b"x",
    )
    _append(w, 1)  # record 2 of the journal, recording 1 of the campaign
    w._journal.release()
    report = recover_campaign(path)
    assert report.recordings == 2
    assert "skipped 1 invalid records (record 1: labels: " in report.message()
    assert "incomplete" in report.message()
    _check_recordings(path, 2)


@pytest.mark.parametrize(
    "settings, problem",
    [
        ({"grid_shape": [2, 3]}, "'n_samples' missing or malformed"),
        ({"grid_shape": [2, 3], "n_samples": "64"}, "'n_samples' missing or malformed ('64')"),
        ([1, 2], "settings are not a JSON object"),
    ],
)
def test_a_malformed_header_is_a_clear_error(tmp_path, settings, problem):
    import json
    import struct
    import zlib

    text = json.dumps(settings).encode()
    path = tmp_path / "h.h5"
    journal_path(path).write_bytes(
        b"ESKJRNL1" + struct.pack("<I", len(text)) + text + struct.pack("<I", zlib.crc32(text))
    )
    with pytest.raises(ValueError, match=re.escape(f"header: {problem}")):
        recover_campaign(path)


def test_a_torn_header_is_a_clear_error(tmp_path):
    data, sizes = _journal_bytes(tmp_path, 1)
    path = tmp_path / "torn.h5"
    journal_path(path).write_bytes(data[: sizes[0] - 3])
    with pytest.raises(ValueError, match="header: torn or damaged"):
        recover_campaign(path)
    assert not path.exists()


def test_second_writer_on_the_same_path_fails_at_open(tmp_path):
    path = tmp_path / "c.h5"
    first = _open(path)
    _append(first, 0)
    with pytest.raises(FileExistsError, match="another writer is recording to this file"):
        _open(path)
    with pytest.raises(FileExistsError, match="another writer is recording to this file"):
        _open(path, overwrite=True)
    with pytest.raises(FileExistsError, match="another writer"):
        recover_campaign(path)  # never reads a journal that is still being written
    _append(first, 1)
    first.close()
    _check_recordings(path, 2)
    assert not journal_path(path).exists()


def test_second_writer_in_another_process_fails_cleanly(tmp_path):
    path = tmp_path / "c.h5"
    first = _open(path)
    ctx = multiprocessing.get_context("fork")
    parent, child = ctx.Pipe(duplex=False)

    def second(conn):
        try:
            _open(path)
            conn.send("opened")
        except FileExistsError as exc:
            conn.send(str(exc))

    proc = _fork(second, child)
    msg = parent.recv()
    proc.join()
    assert "another writer is recording to this file" in msg and proc.exitcode == 0
    first.close()
    _check_recordings(path, 0)


def test_stale_journal_blocks_a_new_writer_until_recovered(tmp_path):
    path = tmp_path / "c.h5"
    data, _ = _journal_bytes(tmp_path, 2)
    journal_path(path).write_bytes(data)
    with pytest.raises(FileExistsError, match=r"eskin recover .*c\.h5"):
        _open(path)
    assert recover_campaign(path).recordings == 2
    w = _open(path.with_name("d.h5"))
    w.close()


def test_file_appearing_while_recording_is_never_replaced(tmp_path):
    path = tmp_path / "c.h5"
    w = _open(path)
    for i in range(3):
        _append(w, i)
    path.write_bytes(b"another program's data")
    with pytest.raises(FileExistsError, match="appeared while recording"):
        w.close()
    assert path.read_bytes() == b"another program's data"
    assert journal_path(path).exists()  # nothing recorded is lost
    with pytest.raises(FileExistsError, match="refusing to overwrite"):
        recover_campaign(path)
    report = recover_campaign(path, tmp_path / "saved.h5")
    assert report.recordings == 3 and report.output == tmp_path / "saved.h5"
    _check_recordings(tmp_path / "saved.h5", 3)
    assert not journal_path(path).exists()
    assert sorted(q.name for q in tmp_path.iterdir()) == ["c.h5", "saved.h5"]


def test_overwrite_replaces_a_file_that_appeared(tmp_path):
    path = tmp_path / "c.h5"
    w = _open(path, overwrite=True)
    _append(w, 0)
    path.write_bytes(b"old")
    w.close()
    _check_recordings(path, 1)


def test_recovery_never_writes_onto_its_journal(tmp_path):
    path = tmp_path / "c.h5"
    data, _ = _journal_bytes(tmp_path, 2)
    journal_path(path).write_bytes(data)
    for force in (False, True):
        with pytest.raises(ValueError, match="is the journal being recovered"):
            recover_campaign(path, journal_path(path), overwrite=force)
    assert journal_path(path).read_bytes() == data
    assert recover_campaign(path).recordings == 2


def test_nothing_to_recover(tmp_path):
    with pytest.raises(FileNotFoundError, match="nothing to recover"):
        recover_campaign(tmp_path / "none.h5")


def test_cli_recover_says_what_it_salvaged(tmp_path):
    from typer.testing import CliRunner

    from eskin.cli import app

    path = tmp_path / "c.h5"
    data, sizes = _journal_bytes(tmp_path, 3)
    journal_path(path).write_bytes(data[: sizes[3] - 5])  # the third append was in flight
    with pytest.raises(FileNotFoundError, match=r"eskin recover .*c\.h5"):
        load_campaign(path)
    r = CliRunner().invoke(app, ["recover", str(path)])
    assert r.exit_code == 0, r.output
    assert r.output.startswith(
        f"recovered 2 complete recordings into {path}; dropped the last "
        f"{sizes[3] - 5 - sizes[2]} bytes of the journal (recording 2 "
        f"incomplete (the append in flight))"
    )
    _check_recordings(path, 2)
    r = CliRunner().invoke(app, ["recover", str(path)])
    assert r.exit_code == 2 and "nothing to recover" in r.output
    assert r.output.count("\n") == 1
    # the one overwrite rule: an existing output only with --force, never the journal itself
    journal_path(path).write_bytes(data)
    for args, message in (
        ([], f"error: {path}: file exists"),
        (
            ["-o", str(journal_path(path)), "--force"],
            f"error: {journal_path(path)}: this is also an input of the command",
        ),
    ):
        r = CliRunner().invoke(app, ["recover", str(path), *args])
        assert r.exit_code == 2 and r.output.startswith(message), r.output
        assert r.output.count("\n") == 1
    assert journal_path(path).read_bytes() == data
    r = CliRunner().invoke(app, ["recover", str(path), "--force"])
    assert r.exit_code == 0 and r.output.startswith(f"recovered 3 complete recordings into {path}")
