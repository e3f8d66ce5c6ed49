"""Shared material of the live page's tests: a small real model, a replay file for it, and
`eskin-fw-sim` / `eskin listen --web` started as the user would start them."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

CLASSES = ("brush", "finger", "washer")


def synthetic_touch(kind: int, seed: int, n: int = 3000) -> np.ndarray:
    """A 1 s recording (4, 4, n): quiet noise and one touch whose place (rows 0-1, 1-3 or
    2-3), frequency and duration depend on ``kind`` (0, 1, 2)."""
    rng = np.random.default_rng(seed)
    x = rng.normal(0, 4, size=(4, 4, n))
    on = 900 + 37 * (seed % 5)
    dur = (450, 700, 300)[kind] + 20 * (seed % 3)
    t = np.arange(dur) / 3000.0
    env = np.sin(np.pi * np.arange(dur) / dur) ** 2
    freq = (25.0, 60.0, 120.0)[kind]
    amp = 600 + 40 * (seed % 4)
    rows = (slice(0, 2), slice(1, 4), slice(2, 4))[kind]
    x[rows, :, on:on + dur] += amp * env * np.sin(2 * np.pi * freq * t)
    return np.rint(x).astype(np.int16)


def make_case(folder: Path, recordings: int = 9, gap_s: float = 0.4) -> tuple[Path, Path]:
    """A compiled 3-class model (its support patterns: preprocessed synthetic touches) and a
    replay file of ``recordings`` other synthetic touches, classes in turn; returns their
    paths."""
    from eskin.data.replay import write_replay_arrays
    from eskin.deploy.export import MachineSpec, ModelSpec, model_to_bytes
    from eskin.signal.preprocess import preprocess

    folder.mkdir(parents=True, exist_ok=True)
    D = 20
    train = [synthetic_touch(k, 100 + i) for i in range(3) for k in range(3)]
    y = np.array([k for _ in range(3) for k in range(3)])
    X = preprocess(np.stack(train), D)
    X /= np.linalg.norm(X.reshape(len(X), -1), axis=1)[:, None, None, None]
    machines = [MachineSpec(k, -1, -0.01, (2, 2, 3), (1.0, 1.0, 1.0), X,
                            np.where(y == k, 1.0, -0.5)) for k in range(3)]
    spec = ModelSpec(list(CLASSES), "one_vs_all", machines, D, (4, 4))
    model = folder / "small.eskin"
    model.write_bytes(model_to_bytes(spec, "float32"))
    kinds = [i % 3 for i in range(recordings)]
    test = [synthetic_touch(k, i) for i, k in enumerate(kinds)]
    replay = folder / "test.eskr"
    write_replay_arrays(replay, test, labels=kinds, class_names=CLASSES, gap_s=gap_s, seed=5)
    return model, replay


def child_env() -> dict[str, str]:
    """The environment of an `eskin` child process: this package first on its path."""
    env = dict(os.environ)
    package = str(Path(__file__).resolve().parents[2] / "python")
    env["PYTHONPATH"] = os.pathsep.join([package, *filter(None, [env.get("PYTHONPATH")])])
    return env


def start_fw_sim(replay: Path, *args: object) -> tuple[subprocess.Popen, str]:
    """`eskin-fw-sim REPLAY ARGS --quiet` with a 1 MB transmit queue; returns it and its pty."""
    from eskin._paths import find_executable

    proc = subprocess.Popen([str(find_executable("eskin-fw-sim")), str(replay),
                             *map(str, args), "--tx-buffer", str(1 << 20), "--quiet"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    first = proc.stdout.readline().split() if proc.stdout else []
    assert first and first[0] == "PTY", (first, proc.stderr.read() if proc.stderr else "")
    return proc, first[1]


def start_listen(pty: str, *args: object) -> tuple[subprocess.Popen, str]:
    """`eskin listen PTY --web 127.0.0.1:0 ARGS --view plain`; returns it and the page's URL
    (read from its "live page: URL" line, within 30 s)."""
    proc = subprocess.Popen([sys.executable, "-m", "eskin", "listen", pty,
                             "--web", "127.0.0.1:0", "--view", "plain", *map(str, args)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=child_env())
    deadline = time.monotonic() + 30
    assert proc.stdout is not None
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        if not line:
            break
        m = re.match(r"live page: (http://\S+)", line)
        if m:
            return proc, m.group(1)
    proc.kill()
    raise AssertionError(f"no 'live page:' line from eskin listen: {proc.stderr.read()}")


def stop(proc: subprocess.Popen, timeout: float = 30.0) -> tuple[str, str]:
    """Wait for ``proc`` (killing it after ``timeout`` s); its remaining stdout and stderr."""
    try:
        return proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
        for pipe in (proc.stdout, proc.stderr):  # a grandchild may still hold them open
            if pipe is not None:
                pipe.close()
        return "", ""
