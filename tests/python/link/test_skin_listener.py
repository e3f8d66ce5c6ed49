"""The whole skin end to end: a simulated skin of three patches, one eskin-fw-sim per patch on
its own real pseudo-terminal (eskin.link.simulated_controllers), one SkinListener reading all
of them (a thread per link), classifying every patch through the SkinClassifier and recording
every patch into one campaign (the patch field); and `eskin listen --skin` on the same."""

from __future__ import annotations

import numpy as np
import pytest
from skin_data import strip_skin

from eskin.data.campaign import load_campaign
from eskin.data.replay import read_replay_file
from eskin.data.skin import load_skin
from eskin.data.skin_simulator import simulate_skin
from eskin.link.events import Decision
from eskin.link.simulated_controllers import SimulatedControllers, link_path
from eskin.link.skin_listener import SkinListener, agreement

STRIP = strip_skin('model = "model.eskin"')


@pytest.fixture(scope="module")
def skin_files(tmp_path_factory, data_dir):
    d = tmp_path_factory.mktemp("skin")
    (d / "model.eskin").write_bytes((data_dir / "model_small_float32.eskin").read_bytes())
    (d / "skin.toml").write_text(STRIP)
    skin = load_skin(d / "skin.toml")
    sim = simulate_skin(skin, d / "sim", gestures=3, episode_s=1.0, seed=1)
    return skin, sim


def test_three_patches_three_links_one_host_one_campaign(skin_files, tmp_path):
    skin, sim = skin_files
    ports = {pid: str(link_path(sim.folder, pid)) for pid in skin.ids}
    with SimulatedControllers(skin, sim.folder, speed=0) as fleet:
        with SkinListener(skin, ports, replays=sim.replays, record=tmp_path / "live.h5",
                          record_source="simulated") as listener:
            listener.open(timeout_s=10)
            report = listener.run(until_eof=True, duration=120)
        fleet.wait()
    sent = {c.patch_id: c.stats for c in fleet.controllers}
    assert [p.patch_id for p in report.patches] == ["p0", "p1", "p2"]
    for p in report.patches:
        rf = read_replay_file(sim.replays[p.patch_id])
        st = p.stats
        assert not p.error
        assert st.samples == rf.n_samples == sent[p.patch_id]["samples_sent"]
        assert st.lost_samples == 0 and st.crc_errors == 0 and st.rejected == 0
        assert p.lost == 0 and st.controller_samples_sent == st.samples
        ctrl = [d for d in p.decisions if d.source == "controller"]
        host = [d for d in p.decisions if d.source == "host"]
        assert len(ctrl) == len(host) == sent[p.patch_id]["decisions_sent"]
        assert p.agree == (len(ctrl), len(ctrl))
    total_decisions = sum(s["decisions_sent"] for s in sent.values())
    assert total_decisions > 0  # the controllers classified with their patch's model
    assert report.agree == (total_decisions, total_decisions)
    assert report.summary().startswith("patches=3 ") and " lost=0 crc_errors=0 " in \
        report.summary()
    # every segment of every patch, in one campaign, each with its patch; none lost
    camp = load_campaign(tmp_path / "live.h5")
    assert camp.patches == skin.ids and len(camp) == report.recordings == 3 * 3
    for pid in skin.ids:
        mine = camp.select(patch=pid)
        rf = read_replay_file(sim.replays[pid])
        assert len(mine) == len(rf.segments)
        for k in range(len(mine)):
            assert np.array_equal(mine.recording(k), rf.recording(k))


def test_a_link_that_ended_early_counts_what_its_controller_sent_beyond():
    from eskin.link.events import LinkStats
    from eskin.link.skin_listener import PatchReport, SkinReport

    short = PatchReport("a", "/dev/pts/1", LinkStats(samples=900, controller_samples_sent=1000))
    whole = PatchReport("b", "/dev/pts/2", LinkStats(samples=1000, controller_samples_sent=990,
                                                     lost_samples=3))
    assert (short.lost, whole.lost) == (100, 3)
    assert " lost=103 " in SkinReport([short, whole]).summary()


def test_agreement_needs_the_same_window_label_and_dont_know():
    def d(source, onset, label, dk=False):
        return Decision(source, onset, onset + 10, label, 0, (), dk)

    assert agreement([d("controller", 0, "a"), d("host", 0, "a")]) == (1, 1)
    assert agreement([d("controller", 0, "a"), d("host", 0, "b")]) == (0, 1)
    assert agreement([d("controller", 0, "a"), d("host", 0, "a", True)]) == (0, 1)
    assert agreement([d("controller", 0, "a"), d("host", 5, "a")]) == (0, 1)
    assert agreement([d("controller", 0, "a")]) == (0, 1)
    assert agreement([d("host", 0, "a"), d("host", 20, "a")]) == (0, 2)


def test_listen_skin_command_prints_each_patch_and_the_skin(skin_files, tmp_path):
    from typer.testing import CliRunner

    from eskin.cli import app

    skin, sim = skin_files
    with SimulatedControllers(skin, sim.folder, speed=0):
        result = CliRunner().invoke(app, [
            "listen", "--skin", str(skin.path), "--sim", str(sim.folder), "--until-eof",
            "--duration", "120", "--wait-ports", "10", "--record", str(tmp_path / "l.h5")])
    assert result.exit_code == 0, result.output
    lines = result.output.splitlines()
    assert [line.split()[1] for line in lines if line.startswith("patch ") and " frames=" in line
            ] == ["p0", "p1", "p2"]
    last = lines[-1]
    assert last.startswith("skin: patches=3 ") and " lost=0 crc_errors=0 " in last
    n = int(last.split(" decisions=")[1].split()[0])
    assert last.endswith(f"agree={n}/{n}") and n > 0
    assert load_campaign(tmp_path / "l.h5").patches == ["p0", "p1", "p2"]


def test_listen_skin_refuses_a_port_and_a_simulated_patch_without_sim(skin_files):
    from typer.testing import CliRunner

    from eskin.cli import app

    skin, _ = skin_files
    r = CliRunner().invoke(app, ["listen", "/dev/null", "--skin", str(skin.path)])
    assert r.exit_code == 2 and "not with PORT '/dev/null'" in r.output
    r = CliRunner().invoke(app, ["listen", "--skin", str(skin.path)])
    assert r.exit_code == 2 and "patch 'p0' has link = \"simulated\": give --sim" in r.output
    r = CliRunner().invoke(app, ["listen"])
    assert r.exit_code == 2 and "give a PORT, or --skin" in r.output
