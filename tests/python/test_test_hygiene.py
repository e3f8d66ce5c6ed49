"""The tests wait for events, not for time: no test sleeps to let something happen (a process
start, bytes arrive, a peer read what it was sent) but waits for it with a deadline
(tests/python/waiting.py). The few sleeps left are the behaviour under test, each listed here
with its reason; a new one fails this test until it is replaced by a wait or justified here.
And a test that needs a tool `make test` installs (QEMU) does not pass CI by skipping."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
TESTS = REPO / "tests"

SLEEP = re.compile(r"\b(sleep|usleep|nanosleep|sleep_for|sleep_until)\s*\(")

#: (file, the line, stripped) -> why it is not a wait for an event
ALLOWED = {
    ("tests/python/waiting.py", "time.sleep(interval)  # the poll interval of this wait"):
        "the poll interval of the one waiting helper",
    ("tests/cpp/test_serial_port.cpp", "nanosleep(&ts, nullptr);"):
        "the poll interval of `eventually`, which waits for the port's reading thread",
    ("tests/python/data/test_campaign_recovery.py",
     "time.sleep(float(rng.uniform(0.0, 0.06)))"):
        "the SIGKILL lands at a seeded random point of the writes: the behaviour under test",
    ("tests/python/data/test_writer_exits.py",
     'alive = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])'):
        "a living process whose pid the test needs (killed at the end), not a wait",
}


def sleeps() -> set[tuple[str, str]]:
    found = set()
    for path in sorted(TESTS.rglob("*")):
        if (path.suffix not in (".py", ".cpp", ".hpp", ".sh") or "corpus" in path.parts
                or path == Path(__file__).resolve()):  # this file names the sleeps it finds
            continue
        for line in path.read_text(errors="replace").splitlines():
            code = line.split("//")[0] if path.suffix in (".cpp", ".hpp") else line
            if SLEEP.search(code) and not code.lstrip().startswith("#"):
                found.add((str(path.relative_to(REPO)), line.strip()))
    return found


def test_no_test_sleeps_but_the_listed_ones():
    unlisted = sorted(sleeps() - set(ALLOWED))
    assert not unlisted, ("a sleep in a test: wait for the event instead (tests/python/"
                          f"waiting.py: wait_until), or list it in ALLOWED with why: {unlisted}")


def test_every_listed_sleep_is_still_there():
    assert not sorted(set(ALLOWED) - sleeps())


def test_the_pattern_finds_the_sleeps_it_is_for():
    for line in ("time.sleep(0.2)", "sleep(1)", "std::this_thread::sleep_for(10ms);",
                 "usleep(1000);", "await asyncio.sleep (0.1)"):
        assert SLEEP.search(line), line
    for line in ("the simulator sleeps in poll", "a sleeper gives up the CPU"):
        assert not SLEEP.search(line), line


def _mcu_link_tests_without_qemu(ci: str | None) -> subprocess.CompletedProcess:
    """tests/python/test_mcu_link.py run where qemu-system-arm cannot be found (a PATH of the
    venv's tools only)."""
    env = {k: v for k, v in os.environ.items() if k != "CI"}
    env["PATH"] = str(Path(sys.executable).parent)
    env["PYTHONPATH"] = str(REPO / "python")
    if ci is not None:
        env["CI"] = ci
    return subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                           "-p", "no:randomly", "-x", "tests/python/test_mcu_link.py"],
                          cwd=REPO, env=env, capture_output=True, text=True, timeout=300)


def test_without_qemu_the_firmware_tests_skip_but_fail_under_ci():
    here = _mcu_link_tests_without_qemu(None)
    assert here.returncode == 0 and " skipped" in here.stdout and " passed" not in here.stdout, \
        here.stdout[-2000:]
    r = _mcu_link_tests_without_qemu("true")
    assert r.returncode == 1 and re.search(r"\b1 (failed|error)\b", r.stdout) \
        and " skipped" not in r.stdout, r.stdout[-2000:]
    assert "qemu-system-arm is not installed (make mcu-deps); CI must run this test" in r.stdout
