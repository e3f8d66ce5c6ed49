"""eskin.link.simulated_controllers: one real eskin-fw-sim per simulated patch, each on its
own pseudo-terminal; stop() ends every one of them."""

from __future__ import annotations

import os

import pytest

from eskin.data.replay import write_replay_arrays
from eskin.data.skin import parse_skin
from eskin.link.serial_port import SerialPort
from eskin.link.simulated_controllers import SimulatedControllers, link_path, replay_path
from web_data import synthetic_touch


def skin(tmp_path, links=("simulated", "simulated", "/dev/ttyACM7")):
    rows = [{"id": f"p{i}", "link": link} for i, link in enumerate(links)]
    return parse_skin({"defaults": {"grid": [4, 4], "sample_rate_hz": 3000},
                       "patch": rows}, path=tmp_path / "s.toml")


def test_one_controller_per_simulated_patch_all_stopped(tmp_path):
    s = skin(tmp_path)
    for pid in ("p0", "p1"):
        write_replay_arrays(replay_path(tmp_path, pid), [synthetic_touch(0, 1)], gap_s=0.1)
    fleet = SimulatedControllers(s, tmp_path, speed=1, loop=True).start()
    try:
        assert [c.patch_id for c in fleet.controllers] == ["p0", "p1"]  # not the real port
        assert fleet.running() == 2
        for c in fleet.controllers:
            assert os.path.realpath(link_path(tmp_path, c.patch_id)) == c.pty
            with SerialPort(str(c.link)) as port:  # a real pseudo-terminal
                assert port.is_open
    finally:
        fleet.stop()
    assert fleet.running() == 0
    assert all(c.process.returncode is not None for c in fleet.controllers)


def test_a_missing_replay_or_no_simulated_patch_is_refused(tmp_path):
    with pytest.raises(FileNotFoundError, match="p0.eskr: no replay for patch 'p0'"):
        SimulatedControllers(skin(tmp_path), tmp_path)
    with pytest.raises(ValueError, match="no patch has link = \"simulated\""):
        SimulatedControllers(skin(tmp_path, links=("/dev/ttyACM0",)), tmp_path)
