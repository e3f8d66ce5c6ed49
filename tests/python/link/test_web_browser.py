"""`eskin listen --web` in a real browser: Debian's chromium (headless, driven by Selenium
through chromium-driver) against a real `eskin-fw-sim` stream on a pseudo-terminal and a real
`eskin listen` process.

Skipped when chromium or chromium-driver is missing, except in CI (the CI variable set), where
that is a failure: `make test` installs both. ESKIN_UPDATE_SCREENSHOT=1 also writes the
README's screenshot, docs/img/live-page.png.
"""

from __future__ import annotations

import io
import os
import re
import shutil
import subprocess
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from waiting import wait_until
from web_data import make_case, start_fw_sim, start_listen, stop

REPO = Path(__file__).resolve().parents[3]
SCREENSHOT = REPO / "docs" / "img" / "live-page.png"


def chromium_paths() -> tuple[str, str]:
    """(chromium, chromedriver), or skip (fail in CI) when either is missing."""
    browser = shutil.which("chromium") or shutil.which("chromium-browser")
    driver = shutil.which("chromedriver")
    if browser and driver:
        return browser, driver
    missing = "chromium" if not browser else "chromium-driver (chromedriver)"
    if os.environ.get("CI"):
        pytest.fail(f"{missing} is not installed (make test-deps installs it)")
    pytest.skip(f"{missing} is not installed (apt-get install chromium chromium-driver)")


def chromium_flags() -> list[str]:
    flags = ["--headless=new", "--disable-gpu", "--no-first-run", "--disable-extensions",
             "--disable-dev-shm-usage", "--window-size=1280,1300"]
    if os.geteuid() == 0:
        flags.append("--no-sandbox")  # chromium refuses to run as root with its sandbox
    return flags


@pytest.fixture(scope="module")
def browser():
    browser_path, driver_path = chromium_paths()
    from selenium import webdriver
    from selenium.webdriver.chrome.options import Options
    from selenium.webdriver.chrome.service import Service

    opts = Options()
    opts.binary_location = browser_path
    for f in chromium_flags():
        opts.add_argument(f)
    driver = webdriver.Chrome(service=Service(driver_path), options=opts)
    driver.set_page_load_timeout(30)
    yield driver
    driver.quit()


@pytest.fixture(scope="module")
def case(tmp_path_factory):
    return make_case(tmp_path_factory.mktemp("web"), recordings=15)


class Lines:
    """The lines a child writes to stdout, read by a thread (so the child never blocks on a
    full pipe), and a wait for one matching a pattern."""

    def __init__(self, proc: subprocess.Popen) -> None:
        self.lines: list[str] = []
        self._new = threading.Condition()
        self._thread = threading.Thread(target=self._read, args=(proc,), daemon=True)
        self._thread.start()

    def _read(self, proc: subprocess.Popen) -> None:
        assert proc.stdout is not None
        for line in proc.stdout:
            with self._new:
                self.lines.append(line.rstrip("\n"))
                self._new.notify_all()

    def wait_for(self, pattern: str, timeout: float = 60.0) -> str:
        deadline = time.monotonic() + timeout
        with self._new:
            while True:
                for line in self.lines:
                    if re.search(pattern, line):
                        return line
                left = deadline - time.monotonic()
                assert left > 0, f"no line matching {pattern!r} in {self.lines[-20:]}"
                self._new.wait(left)


def wait_for_page(condition, timeout: float = 30.0, what: str = "condition"):
    return wait_until(condition, timeout=timeout, what=what, interval=0.03)


def page_labels(driver) -> list[str]:
    return driver.execute_script(
        "return [...document.querySelectorAll('#decision-rows td.label')]"
        ".map(td => td.firstChild.textContent.trim())")


def status_text(driver) -> str:
    return driver.find_element("id", "status").text


def heat_png(driver) -> np.ndarray:
    import matplotlib.image

    png = driver.find_element("id", "heat").screenshot_as_png
    return matplotlib.image.imread(io.BytesIO(png), format="png")[..., :3]


def energy_max(driver) -> float:
    return driver.execute_script("return st.energy ? Math.max(...st.energy) : -1")


def heat_at(driver, test, timeout: float = 30.0) -> np.ndarray:
    """A screenshot of the heat map taken while ``test(max energy)`` holds before and after
    it (the canvas is drawn from the energy the page holds)."""
    def shot():
        if not test(energy_max(driver)):
            return None
        img = heat_png(driver)
        return (img,) if test(energy_max(driver)) else None

    return wait_for_page(shot, timeout, "a heat map in the wanted state")[0]


@pytest.mark.slow
def test_the_page_follows_the_stream_reloads_and_says_stopped(browser, case):
    model, replay = case
    sim, pty = start_fw_sim(replay, "--model", model, "--speed", 1, "--wait-start")
    listen, url = start_listen(pty, "--model", model, "--replay", replay, "--until-eof",
                               "--web-grace", 30)
    out = Lines(listen)
    try:
        browser.get(url)
        wait_for_page(lambda: status_text(browser) == "live", 30, "the page to say live")
        # the decisions appear as they arrive: first one, then more, with the stream running
        first = wait_for_page(lambda: page_labels(browser), 30, "a first decision")
        wait_for_page(lambda: len(page_labels(browser)) > len(first), 30, "a later decision")
        assert set(page_labels(browser)) <= {"brush", "finger", "washer"}
        # the heat map: quiet between touches, hot during one, and the pixels differ
        quiet = heat_at(browser, lambda e: 0 <= e < 40)
        hot = heat_at(browser, lambda e: e > 150)
        changed = np.abs(hot - quiet).max(axis=2) > 0.2
        assert changed.mean() > 0.05, changed.mean()
        if os.environ.get("ESKIN_UPDATE_SCREENSHOT"):
            SCREENSHOT.parent.mkdir(parents=True, exist_ok=True)
            browser.save_screenshot(str(SCREENSHOT))
        # reloading reconnects: the decisions so far are back (rendered, then live)
        before = page_labels(browser)
        browser.refresh()
        wait_for_page(lambda: status_text(browser) == "live", 30, "live again after a reload")
        assert page_labels(browser)[-len(before):] == before
        n = len(page_labels(browser))
        wait_for_page(lambda: len(page_labels(browser)) > n, 30, "a decision after the reload")
        # the listener ends with the replay: the page says so, with the final scores
        out.wait_for(r"^host: \d+/15 recordings right", 120)
        wait_for_page(lambda: status_text(browser).startswith("stopped"), 30, "stopped")
        summary = browser.find_element("id", "summary").text
        assert "controller: " in summary and "recordings right" in summary
        decisions = [line for line in out.lines if line.startswith("decision ")]
        shown = page_labels(browser)[::-1]  # the page lists the newest first
        assert shown == [re.search(r"label=(\w+)", line).group(1) for line in decisions]
    finally:
        listen.terminate()
        stop(listen)
        stop(sim)


def test_the_first_html_holds_the_decisions_so_far(case):
    browser_path, _ = chromium_paths()
    model, replay = case
    sim, pty = start_fw_sim(replay, "--model", model, "--speed", 0, "--wait-start")
    listen, url = start_listen(pty, "--model", model, "--replay", replay, "--until-eof",
                               "--web-grace", 60)
    out = Lines(listen)
    try:
        out.wait_for(r"^host: \d+/15 recordings right", 120)  # the stream is over
        decisions = [re.search(r"label=(\w+)", line).group(1)
                     for line in out.lines if line.startswith("decision ")]
        assert len(decisions) >= 30
        dom = subprocess.run([browser_path, *chromium_flags(), "--dump-dom",
                              "--virtual-time-budget=5000", url],
                             capture_output=True, text=True, timeout=60).stdout
        rows = re.findall(r'<td class="label">(\w+)', dom)
        assert rows[::-1] == decisions
        assert "stopped: the listener has ended" in dom
    finally:
        listen.terminate()
        stop(listen)
        stop(sim)
