"""eskin.data.skin_simulator: a simulated skin's per-patch replays and its campaign with the
patch field, gestures crossing patch borders in time order."""

from __future__ import annotations

import json

import numpy as np
import pytest
from skin_data import strip_skin

from eskin.data.campaign import CampaignFormatError, load_campaign
from eskin.data.replay import read_replay_file
from eskin.data.skin import load_skin
from eskin.data.skin_simulator import simulate_skin

STRIP = strip_skin()


@pytest.fixture(scope="module")
def simulated(tmp_path_factory):
    d = tmp_path_factory.mktemp("skin")
    (d / "skin.toml").write_text(STRIP)
    skin = load_skin(d / "skin.toml")
    return skin, simulate_skin(skin, d / "out", gestures=3, episode_s=1.0, seed=3)


def test_every_patch_streams_the_same_timeline(simulated):
    _, sim = simulated
    replays = {pid: read_replay_file(p) for pid, p in sim.replays.items()}
    assert sorted(replays) == ["p0", "p1", "p2"]
    n = 3 * (sim.episode_samples + sim.gap_samples) + sim.gap_samples
    for rf in replays.values():
        assert rf.n_samples == n and len(rf.segments) == 3 and rf.grid_shape == (4, 4)
        assert list(rf.segments["start"]) == [sim.gap_samples + k * (3000 + sim.gap_samples)
                                              for k in range(3)]
    # a segment is labelled on the patches its gesture touched, -1 on the others
    for g in sim.gestures:
        for pid, rf in replays.items():
            label = int(rf.segments["label"][g.episode])
            assert label == (g.modality if pid in g.contacts else -1)


def test_a_slide_crosses_from_one_patch_to_its_neighbour_in_time_order(simulated):
    skin, sim = simulated
    slide = sim.gestures[0]
    assert slide.kind == "slide" and len(slide.contacts) == 2
    (a, (on_a, off_a)), (b, (on_b, off_b)) = slide.contacts.items()
    assert b in skin.neighbours(a)
    assert on_a < on_b < off_a < off_b  # it leaves a after reaching b (the contact spans both)
    assert sim.gestures[1].kind == "local" and len(sim.gestures[1].contacts) == 1


def test_the_campaign_holds_one_recording_per_touched_patch_with_its_patch(simulated):
    skin, sim = simulated
    camp = load_campaign(sim.campaign)
    expected = [(g.episode, pid) for g in sim.gestures for pid in g.contacts]
    assert camp.patches == ["p0", "p1", "p2"]
    assert [(int(e), camp.patches[int(p)]) for e, p in
            zip(camp.extras["episode"], camp.patch)] == expected
    replays = {pid: read_replay_file(p) for pid, p in sim.replays.items()}
    for k, (episode, pid) in enumerate(expected):
        start = int(camp.extras["stream_start"][k])
        rf = replays[pid]
        assert np.array_equal(camp.recording(k), rf.recording(episode))
        assert start == int(rf.segments["start"][episode])
    only = camp.select(patch=expected[0][1])
    assert len(only) == sum(pid == expected[0][1] for _, pid in expected)
    assert json.loads(camp.attrs["patches"]) == skin.ids


def test_a_patch_field_without_its_ids_is_refused(simulated, tmp_path):
    import h5py

    _, sim = simulated
    bad = tmp_path / "bad.h5"
    bad.write_bytes(sim.campaign.read_bytes())
    with h5py.File(bad, "a") as f:
        del f.attrs["patches"]
    with pytest.raises(CampaignFormatError, match="attribute 'patches': missing"):
        load_campaign(bad)
    with h5py.File(bad, "a") as f:
        f.attrs["patches"] = json.dumps(["p0"])
    with pytest.raises(CampaignFormatError, match="past the 1 ids"):
        load_campaign(bad)


def test_mixed_grids_are_refused_by_name(tmp_path):
    (tmp_path / "s.toml").write_text(STRIP.replace('id = "p2"', 'id = "p2"\ngrid = [3, 3]'))
    with pytest.raises(ValueError, match=r"patch\[2\] \(p2\): grid 3x3"):
        simulate_skin(load_skin(tmp_path / "s.toml"), tmp_path / "o", gestures=1)
