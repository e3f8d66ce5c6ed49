"""`eskin recover` checks every journal record as the campaign loader does: valid records are
salvaged, invalid ones reported by index and field, and the journal is deleted only once the
campaign built from it loads and reads back."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np

from eskin.data.campaign import CampaignWriter, load_campaign
from eskin.data.journal import LockedJournal, journal_path

PYTHON_DIR = Path(__file__).resolve().parents[3] / "python"
T = 100


def eskin(*args: str) -> subprocess.CompletedProcess:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(PYTHON_DIR), env.get("PYTHONPATH", "")])
    return subprocess.run([sys.executable, "-m", "eskin", *map(str, args)], capture_output=True,
                          text=True, env=env, timeout=120)


def _journal(path: Path, bad: list[dict], n: int = 3) -> None:
    """A journal of n recordings (participant = index); the records after them carry the labels
    of ``bad``, CRC-valid (as a buggy writer or a hand-edited journal would leave them), and a
    last valid recording follows."""
    from eskin.data.campaign import encode_recording

    w = CampaignWriter(path, grid_shape=(2, 2), n_samples=T, sample_rate_hz=1000.0,
                       volts_per_count=1e-3, modalities=["brush", "finger"], source="recorded")
    for i in range(n):
        w.append(np.full((2, 2, T), i, np.int16), modality=1, participant=i, direction=0, run=1)
    chunk = encode_recording(np.zeros((2, 2, T), np.int16), grid_shape=(2, 2), n_samples=T).chunk
    for labels in bad:
        meta = {"length": T, "modality": 1, "participant": 0, "direction": 0, "run": 1, **labels}
        w._journal.append(meta, {}, chunk)
    w.append(np.full((2, 2, T), 7, np.int16), modality=0, participant=99, direction=1, run=2)
    w._journal.release()


BAD = [  # the labels of one record, the field named, the problem
    ({"run": 999}, "/recordings/run", "values out of the uint8 range [0, 255]: min 999"),
    ({"participant": 2**40}, "/recordings/participant",
     f"values out of the int32 range [-2147483648, 2147483647]: min {2**40}"),
    ({"length": 5000}, "/recordings/length", "recording 5 has length 5000, outside [0, T=100]"),
    ({"modality": 7}, "/recordings/modality",
     "recording 6 has modality id 7, out of range: the modalities attribute names 2 classes"),
    ({"direction": 3}, "/recordings/direction", "recording 7 has direction 3"),
    ({"run": "2"}, "labels", "incomplete"),
    ({"participant": 2**70}, "/recordings/participant", "must be integers, got dtype object"),
]


def test_invalid_records_are_skipped_and_named_by_index_and_field(tmp_path):
    path = tmp_path / "c.h5"
    _journal(path, [labels for labels, _, _ in BAD])
    r = eskin("recover", path)
    # the valid records are salvaged, but the journal held invalid ones: exit 2, one line
    assert r.returncode == 2 and r.stdout == "", r.stdout
    lines = r.stderr.splitlines()
    assert len(lines) == 1
    rejected = tmp_path / ".c.h5.rejected"
    assert lines[0].startswith(f"error: recovered 4 complete recordings into {path}; skipped 7 "
                               f"invalid records (record 3: /recordings/run: "), lines[0]
    for k, (_, field, problem) in enumerate(BAD):
        assert f"record {3 + k}: {field}: " in lines[0] and problem in lines[0], (k, lines[0])
    assert lines[0].endswith(f"; the journal is kept as {rejected}")
    with load_campaign(path, check_data=True) as c:
        assert list(c.participant) == [0, 1, 2, 99]
        assert (c.recording(3) == 7).all() and c.run[3] == 2 and c.modality[3] == 0
    assert not journal_path(path).exists() and rejected.exists()
    r = eskin("info", path, "--check")
    assert r.returncode == 0 and ("check: read the data of all 4 recordings; every chunk "
                                  "matched its checksum") in r.stdout, r.stderr


def test_contents_are_known_before_the_records_are_read(tmp_path):
    path = tmp_path / "c.h5"
    _journal(path, [{"run": "x"}], n=2)
    data = journal_path(path).read_bytes()
    journal_path(path).write_bytes(data[:-7])  # the last append was in flight
    with LockedJournal(journal_path(path)) as reader:
        contents = reader.read()
        assert contents.dropped_bytes > 0 and "recording 3 incomplete" in contents.dropped_reason
        assert len(contents.offsets) == 2 and contents.skipped[0].startswith("record 2: labels")
        assert [rec.meta["participant"] for rec in contents.records()] == [0, 1]


def test_a_chunk_that_does_not_inflate_is_skipped(tmp_path):
    path = tmp_path / "c.h5"
    w = CampaignWriter(path, grid_shape=(2, 2), n_samples=T, sample_rate_hz=1000.0,
                       volts_per_count=1e-3, modalities=["a"], source="recorded")
    w.append(np.zeros((2, 2, T), np.int16), modality=0, participant=0, direction=0, run=1)
    meta = {"length": T, "modality": 0, "participant": 1, "direction": 0, "run": 1}
    w._journal.append(meta, {}, b"not deflate data")
    w._journal.append(meta, {}, __import__("zlib").compress(b"\0" * 10))
    w._journal.release()
    r = eskin("recover", path)
    assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
    assert "skipped 2 invalid records (record 1: /recordings/signals: the compressed chunk " \
        "does not inflate" in r.stderr
    assert "record 2: /recordings/signals: the chunk holds 10 bytes, not the 800 of a 2x2x100 " \
        "int16 recording" in r.stderr
    assert len(load_campaign(path)) == 1
