"""Each way out of ``with CampaignWriter(...)``, through a real process: the campaign or a
recoverable journal holds every recording whose append returned (docs/dataset-format.md,
"Each way out")."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from child_process import interruptible

from eskin.data.campaign import load_campaign
from eskin.data.journal import journal_path

PYTHON_DIR = Path(__file__).resolve().parents[3] / "python"

CHILD = textwrap.dedent("""
    import sys, numpy as np
    from eskin.data.campaign import CampaignWriter
    path, mode, n = sys.argv[1], sys.argv[2], int(sys.argv[3])
    with CampaignWriter(path, grid_shape=(2, 2), n_samples=32, sample_rate_hz=1000.0,
                        volts_per_count=1e-3, modalities=["brush", "finger"],
                        source="recorded") as w:
        i = 0
        while mode in ("sigint", "sigterm", "kill") or i < n:
            x = np.full((2, 2, 32), i % 1000, np.int16)
            label = "brsh" if mode == "typo" and i == n - 1 else "finger"
            w.append(x, modality=label, participant=i, direction=0, run=1)
            print(i, flush=True)
            i += 1
        if mode == "raise":
            raise RuntimeError("the experiment script failed after its appends")
""")


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(PYTHON_DIR), env.get("PYTHONPATH", "")])
    return env


def _run_child(tmp_path: Path, mode: str, n: int = 6) -> tuple[subprocess.CompletedProcess, int]:
    """Run the writer; for the signal modes, send the signal once n appends have returned.
    Returns the finished process and the appends known to have returned."""
    script = tmp_path / "child.py"
    script.write_text(CHILD)
    args = [sys.executable, str(script), str(tmp_path / "c.h5"), mode, str(n)]
    if mode not in ("sigint", "sigterm", "kill"):
        res = subprocess.run(args, capture_output=True, text=True, env=_env(), timeout=120)
        return res, len(res.stdout.split())
    proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=_env(), preexec_fn=interruptible)
    seen = 0
    while seen < n:
        assert proc.stdout.readline(), proc.stderr.read()
        seen += 1
    proc.send_signal({"sigint": signal.SIGINT, "sigterm": signal.SIGTERM,
                      "kill": signal.SIGKILL}[mode])
    proc.wait(timeout=120)
    # read through the same buffered file as readline (communicate would skip what it holds)
    out, err = proc.stdout.read(), proc.stderr.read()
    proc.stdout.close()
    proc.stderr.close()
    seen += len(out.split())
    return subprocess.CompletedProcess(args, proc.returncode, out, err), seen


def _recover(path: Path) -> int:
    res = subprocess.run([sys.executable, "-m", "eskin", "recover", str(path)],
                         capture_output=True, text=True, env=_env(), timeout=120)
    assert res.returncode == 0 and res.stderr == "", res.stderr
    m = re.match(r"recovered (\d+) complete recordings into ", res.stdout)
    assert m, res.stdout
    return int(m.group(1))


def _check(path: Path, n: int) -> None:
    with load_campaign(path, check_data=True) as c:
        assert len(c) == n
        assert list(c.participant) == list(range(n))
        for i in range(n):
            assert (c.recording(i) == i % 1000).all()


def test_normal_close_builds_the_campaign_and_deletes_the_journal(tmp_path):
    res, returned = _run_child(tmp_path, "close")
    assert res.returncode == 0, res.stderr
    assert returned == 6 and not journal_path(tmp_path / "c.h5").exists()
    _check(tmp_path / "c.h5", 6)


@pytest.mark.parametrize("mode", ["typo", "raise"])
def test_an_exception_keeps_every_returned_append_and_says_so(tmp_path, mode):
    path = tmp_path / "c.h5"
    res, returned = _run_child(tmp_path, mode)
    assert res.returncode == 1
    kept = returned  # the typo's append (recording 5) raised; the raise comes after 6 appends
    assert kept == (5 if mode == "typo" else 6)
    note = (f"{path}: the {kept} recordings whose append returned are kept in the journal "
            f"{journal_path(path)}; `eskin recover {path}` builds the campaign from them")
    assert note in res.stderr
    assert ("(recording 5, whose append failed, is not among them)" in res.stderr) == (
        mode == "typo")
    if mode == "typo":
        assert f"{path}: recording 5: unknown modality 'brsh'" in res.stderr
    assert not path.exists()
    assert _recover(path) == kept
    _check(path, kept)


def test_sigint_keeps_every_returned_append(tmp_path):
    path = tmp_path / "c.h5"
    res, returned = _run_child(tmp_path, "sigint")
    assert res.returncode == -signal.SIGINT and "KeyboardInterrupt" in res.stderr
    m = re.search(r"the (\d+) recordings whose append returned are kept", res.stderr)
    assert m, res.stderr
    kept = int(m.group(1))
    assert returned <= kept <= returned + 1  # the append in flight may have returned unseen
    assert _recover(path) == kept
    _check(path, kept)


@pytest.mark.parametrize("mode", ["sigterm", "kill"])
def test_death_by_signal_leaves_a_journal_with_every_returned_append(tmp_path, mode):
    path = tmp_path / "c.h5"
    res, returned = _run_child(tmp_path, mode)
    assert res.returncode == -(signal.SIGTERM if mode == "sigterm" else signal.SIGKILL)
    assert not path.exists() and journal_path(path).exists()
    kept = _recover(path)
    assert returned <= kept <= returned + 1
    _check(path, kept)


def test_discard_on_error_leaves_nothing(tmp_path):
    import numpy as np

    from eskin.data.campaign import CampaignWriter

    path = tmp_path / "c.h5"
    with pytest.raises(ValueError, match="unknown modality"):
        with CampaignWriter(path, n_samples=8, sample_rate_hz=1e3, volts_per_count=1.0,
                            modalities=["a"], source="recorded", on_error="discard") as w:
            w.append(np.zeros((4, 4, 8), np.int16), modality="a", participant=0, direction=0,
                     run=1)
            w.append(np.zeros((4, 4, 8), np.int16), modality="b", participant=0, direction=0,
                     run=1)
    assert sorted(p.name for p in tmp_path.iterdir()) == []


CLOSING_CHILD = textwrap.dedent("""
    import sys, numpy as np
    from eskin.data.campaign import CampaignWriter
    rng = np.random.default_rng(0)
    x = rng.integers(-3000, 3000, (8, 8, 20000)).astype(np.int16)
    with CampaignWriter(sys.argv[1], grid_shape=(8, 8), n_samples=20000, sample_rate_hz=1000.0,
                        volts_per_count=1e-3, modalities=["brush"], source="recorded",
                        compression_level=None, durable=False) as w:
        for i in range(40):
            w.append(x, modality=0, participant=i, direction=0, run=1)
        print("closing", flush=True)
""")


def test_a_kill_during_close_leaves_a_building_file_that_the_next_write_removes(tmp_path):
    """SIGKILL while close() builds the campaign (no cleanup can run) left
    `.c.h5.<pid>.building` behind for good; the next write to c.h5 (here `eskin recover`)
    removes it, since its process is gone, and keeps one whose process is alive."""
    script = tmp_path / "child.py"
    script.write_text(CLOSING_CHILD)
    target = tmp_path / "c.h5"
    proc = subprocess.Popen([sys.executable, str(script), str(target)], stdout=subprocess.PIPE,
                            text=True, env=_env())
    building = tmp_path / f".c.h5.{proc.pid}.building"
    assert proc.stdout.readline() == "closing\n"
    while not building.exists() and proc.poll() is None:
        pass
    proc.kill()
    proc.communicate(timeout=60)
    if not building.exists():
        pytest.skip("the close finished before the kill (a very fast disk)")
    assert not target.exists() and journal_path(target).exists()
    # a process that is alive for the whole test (it is killed at the end), not a wait
    alive = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        living = tmp_path / f".c.h5.{alive.pid}.building"
        living.write_bytes(b"another process's file in progress")
        r = subprocess.run([sys.executable, "-m", "eskin", "recover", str(target)],
                           capture_output=True, text=True, env=_env(), timeout=120)
        assert r.returncode == 0, r.stderr
        assert not building.exists() and living.exists()
        assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
            ["c.h5", "child.py", living.name])
    finally:
        alive.kill()
        alive.wait()
    with load_campaign(target) as c:
        assert len(c) == 40
