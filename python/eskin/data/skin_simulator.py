"""A simulated skin: every patch of a skin description (:mod:`eskin.data.skin`) on one
timeline, with gestures that cross patch borders (docs/skin.md, "The simulated skin").

Everything here is SIMULATED data. The skin's time is cut into episodes of ``episode_s``
seconds; one gesture happens in each, and every patch records every episode, so the patches'
streams stay aligned sample for sample. Two kinds of gesture alternate:

* a *slide*: a fingertip pressed on one patch slides, in body coordinates, from that patch's
  centre to the centre of a neighbouring patch (the skin's adjacency) and lifts there; the
  contact leaves the first patch and reaches the second in time order. The contact is a round
  Gaussian pressure spot (the fingertip and the PDMS spread of docs/simulator.md) integrated
  over each taxel's square electrode, centred on the taxel's body position;
* a *local* touch: one of the simulator's gestures (brush, finger, washer) on one patch, made by
  the single-patch simulator (:mod:`eskin.data.simulator`) with that patch's grid and pitch.

Each patch has its own sensor (gains, mains pickup, noise: the single-patch simulator's
electronics, seeded per patch); a patch nothing touches in an episode records its quiet noise.

:func:`simulate_skin` writes one replay file per patch (``PATCH.eskr``, the input of
``eskin-fw-sim``; an episode nobody touched on that patch is a segment labelled -1) and one
campaign (``skin.h5``) holding one recording per touched (episode, patch), with the campaign's
``patch`` field (docs/dataset-format.md) saying which patch it came from.
"""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy.special import erf

from eskin.data.simulator import (
    SimulatorConfig,
    _Chain,
    _participant_style,
    acquisition_config,
)
from eskin.data.skin import Skin

__all__ = ["SimulatedSkin", "SkinGesture", "simulate_skin"]

#: the fraction of its peak force a contact must put on a patch for the patch to count as touched
TOUCH_FRACTION = 0.05
PARTICIPANTS = 4


@dataclass(frozen=True)
class SkinGesture:
    """Gesture ``episode``: ``kind`` "slide" (across a border) or "local"; ``modality`` its
    class index; ``contacts``: patch id -> contact [onset, offset) in the episode's samples, in
    time order of onset."""

    episode: int
    kind: str
    modality: int
    direction: int
    contacts: dict[str, tuple[int, int]]


@dataclass(frozen=True)
class SimulatedSkin:
    """What :func:`simulate_skin` wrote: one replay per patch, the campaign, the gestures."""

    folder: Path
    replays: dict[str, Path]
    campaign: Path
    gestures: list[SkinGesture]
    episode_samples: int
    gap_samples: int


def skin_grid(skin: Skin) -> tuple[tuple[int, int], float]:
    """The one grid and sample rate of every patch (a campaign holds one grid)."""
    first = skin.patches[0]
    for i, p in enumerate(skin.patches):
        if p.grid != first.grid or p.sample_rate_hz != first.sample_rate_hz:
            raise ValueError(
                f"{skin.path or '<memory>'}: patch[{i}] ({p.id}): grid {p.grid[0]}x{p.grid[1]} "
                f"at {p.sample_rate_hz:g} Hz; a simulated skin needs every patch on the grid "
                f"and rate of patch[0] ({first.grid[0]}x{first.grid[1]} at "
                f"{first.sample_rate_hz:g} Hz)")
    return first.grid, first.sample_rate_hz


def _patch_config(cfg: SimulatorConfig, pitch_mm: float) -> SimulatorConfig:
    """The simulator's settings for a patch of taxels ``pitch_mm`` apart (electrodes 2/3 of the
    pitch, the sensed disc scaled alike, as the paper's 8 mm electrodes at 12 mm)."""
    scale = pitch_mm / cfg.pitch_mm
    return dataclasses.replace(cfg, pitch_mm=pitch_mm, electrode_mm=cfg.electrode_mm * scale,
                               disc_diameter_mm=cfg.disc_diameter_mm * scale)


def _pairs(skin: Skin) -> list[tuple[str, str]]:
    return [(a, b) for a in skin.ids for b in skin.adjacency[a]]


def _smooth(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * x * (10 - 15 * x + 6 * x * x)


class _SkinChains:
    """Each patch's simulator chain (its sensor and geometry), built once."""

    def __init__(self, skin: Skin, cfg: SimulatorConfig, seed: int) -> None:
        self.skin = skin
        self.cfg = cfg
        self.chains = {p.id: _Chain(_patch_config(cfg, p.pitch_mm), seed * 4096 + i)
                       for i, p in enumerate(skin.patches)}

    def quiet(self, pid: str, rng: np.random.Generator) -> np.ndarray:
        sensor = self.chains[pid].sensor
        n_tax = self.skin.patch(pid).n_taxels
        counts, _ = sensor.noise_and_adc(np.zeros((n_tax, self.cfg.n_samples)), rng)
        return counts

    def local(self, pid: str, modality: int, direction: int, rng: np.random.Generator,
              style: Any) -> tuple[np.ndarray, tuple[int, int]]:
        counts, truth = self.chains[pid].record(rng, style, modality, direction, 2)
        return counts, truth.contact_interval

    def slide(self, a: str, b: str, rng: np.random.Generator, style: Any
              ) -> tuple[dict[str, np.ndarray], dict[str, tuple[int, int]], int]:
        """A fingertip sliding from patch ``a``'s centre to patch ``b``'s: every patch's counts,
        the contact interval of each patch it touched, and its direction (0 horizontal)."""
        cfg = self.cfg
        chain = self.chains[a]
        t = chain.t_fine
        start, stop = self.skin.patch(a).centre_mm, self.skin.patch(b).centre_mm
        path = self._timing(float(np.linalg.norm(stop - start)), rng)
        along = _smooth((t - path["t_move0"]) / path["t_move"])
        pos = start[None, :] + along[:, None] * (stop - start)[None, :]
        force = path["force"] * _smooth((t - path["onset"]) / path["t_press"]) * (
            1.0 - _smooth((t - path["t_lift"]) / path["t_release"]))
        force *= 1.0 + 0.05 * np.sin(2 * np.pi * style.tremor_hz * t)
        sigma = math.hypot(cfg.finger_semi_axis_mm / 2, chain.spread)
        counts, contacts = {}, {}
        for p in self.skin.patches:
            taxel_force, share = _spot_on_taxels(p.taxels_mm, p.pitch_mm * 2 / 3, pos, sigma,
                                                 force)
            sensor = self.chains[p.id].sensor
            counts[p.id], _ = sensor.noise_and_adc(sensor.front_end(taxel_force, rng), rng)
            on = np.flatnonzero(share[:: cfg.oversample] >= TOUCH_FRACTION * path["force"])
            if on.size:
                contacts[p.id] = (int(on[0]), int(on[-1]) + 1)
        d = stop - start
        return counts, contacts, 0 if abs(d[0]) >= abs(d[1]) else 1

    def _timing(self, distance: float, rng: np.random.Generator) -> dict[str, float]:
        cfg = self.cfg
        onset = float(rng.uniform(0.15, 0.3))
        t_press, t_release = float(rng.uniform(0.06, 0.12)), float(rng.uniform(0.05, 0.1))
        speed = cfg.finger_speed_mm_s * math.exp(rng.normal(0.0, 0.2))
        budget = cfg.duration_s - 0.2 - onset - t_press - t_release
        t_move = min(max(distance / speed, 0.2), budget)
        return {"onset": onset, "t_press": t_press, "t_release": t_release,
                "t_move0": onset + 0.8 * t_press, "t_move": t_move,
                "t_lift": onset + 0.8 * t_press + t_move,
                "force": cfg.finger_force_n * math.exp(rng.normal(0.0, 0.2))}


def _spot_on_taxels(taxels: np.ndarray, electrode: float, pos: np.ndarray, sigma: float,
                    force: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The force of a round Gaussian spot at ``pos`` (n, 2) on square electrodes of side
    ``electrode`` centred on ``taxels`` (m, 2): (m, n) newtons, and the summed force (n,)."""
    half, s = electrode / 2, math.sqrt(2.0) * sigma

    def cover(axis: int) -> np.ndarray:
        c = pos[:, axis][None, :]
        x = taxels[:, axis][:, None]
        return 0.5 * (erf((x + half - c) / s) - erf((x - half - c) / s))

    out = cover(0) * cover(1) * force[None, :]
    return out, out.sum(axis=0)


def _plan(skin: Skin, gestures: int, modalities: tuple[str, ...], rng: np.random.Generator
          ) -> list[tuple[str, tuple[str, ...], int, int]]:
    """(kind, patches, modality, direction) of each episode: slides across a random adjacent
    pair and local touches on a random patch, alternating (slides first)."""
    pairs = _pairs(skin)
    plan = []
    for k in range(gestures):
        if pairs and k % 2 == 0:
            a, b = pairs[int(rng.integers(len(pairs)))]
            plan.append(("slide", (a, b), modalities.index("finger"), -1))
        else:
            pid = skin.ids[int(rng.integers(len(skin)))]
            plan.append(("local", (pid,), int(rng.integers(len(modalities))),
                         int(rng.integers(2))))
    return plan


def _episodes(skin: Skin, chains: _SkinChains, plan: list[Any], seed: int
              ) -> tuple[dict[str, list[np.ndarray]], list[SkinGesture]]:
    """Every patch's recording of every episode, and the gestures."""
    cfg = chains.cfg
    per_patch: dict[str, list[np.ndarray]] = {pid: [] for pid in skin.ids}
    done = []
    for k, (kind, patches, modality, direction) in enumerate(plan):
        rng = np.random.default_rng([seed, k, 0x5C1])
        style = _participant_style(cfg, np.random.default_rng([seed, k % PARTICIPANTS, 0x57]))
        if kind == "slide":
            counts, contacts, direction = chains.slide(patches[0], patches[1], rng, style)
        else:
            rec, ci = chains.local(patches[0], modality, direction, rng, style)
            counts = {pid: chains.quiet(pid, rng) for pid in skin.ids}
            counts[patches[0]], contacts = rec, {patches[0]: ci}
        for pid in skin.ids:
            per_patch[pid].append(counts[pid].reshape(*skin.patch(pid).grid, -1))
        order = dict(sorted(contacts.items(), key=lambda kv: kv[1]))
        done.append(SkinGesture(k, kind, modality, direction, order))
    return per_patch, done


def simulate_skin(skin: Skin, out: str | Path, *, gestures: int = 8, seed: int = 0,
                  episode_s: float = 2.0, gap_s: float = 0.3,
                  overwrite: bool = False) -> SimulatedSkin:
    """Simulate ``gestures`` episodes on every patch of ``skin`` into the folder ``out``: one
    replay file per patch (``PATCH_ID.eskr``) and the campaign ``skin.h5`` (one recording per
    touched patch of each episode, with its ``patch``, ``episode`` and ``stream_start``).
    Same arguments -> the same files."""
    from eskin.data.campaign import CampaignWriter
    from eskin.data.replay import write_replay_arrays

    if not 1 <= int(gestures) <= 10_000:
        raise ValueError(f"gestures must be in 1..10000, got {gestures}")
    grid, rate = skin_grid(skin)
    cfg = acquisition_config(grid=grid, rate_hz=rate, duration_s=episode_s)
    folder = Path(out)
    campaign = folder / "skin.h5"
    replays = {pid: folder / f"{pid}.eskr" for pid in skin.ids}
    _refuse(folder, [campaign, *replays.values()], overwrite)
    chains = _SkinChains(skin, cfg, int(seed))
    plan = _plan(skin, int(gestures), cfg.modalities, np.random.default_rng([seed, 0x9A7]))
    per_patch, done = _episodes(skin, chains, plan, int(seed))
    gap = int(round(gap_s * rate))
    n = cfg.n_samples
    folder.mkdir(parents=True, exist_ok=True)
    for pid, recs in per_patch.items():
        labels = [g.modality if pid in g.contacts else -1 for g in done]
        ci = np.array([g.contacts.get(pid, (-1, -1)) for g in done])
        write_replay_arrays(replays[pid], recs, labels=labels, class_names=cfg.modalities,
                            sample_rate_hz=rate, volts_per_count=cfg.volts_per_count,
                            contact_intervals=ci, recording_indices=[g.episode for g in done],
                            gap_s=gap_s, seed=int(seed))
    attrs = {"description": "SIMULATED skin (eskin simulate --skin); not recorded data",
             "skin_name": skin.name, "skin_file": str(skin.path or ""),
             "patches": json.dumps(skin.ids), "simulator_config": cfg.to_json(),
             "simulator_seed": int(seed),
             "gestures": json.dumps([{"episode": g.episode, "kind": g.kind,
                                      "patches": list(g.contacts)} for g in done])}
    with CampaignWriter(campaign, grid_shape=grid, n_samples=n, sample_rate_hz=rate,
                        volts_per_count=cfg.volts_per_count, modalities=list(cfg.modalities),
                        source="simulated", attrs=attrs, contact_interval=True,
                        overwrite=overwrite, durable=False, on_error="discard",
                        extra_fields={"patch": np.uint16, "episode": np.int32,
                                      "stream_start": np.int64}) as w:
        for g in done:
            for pid, ci in g.contacts.items():
                w.append(per_patch[pid][g.episode], modality=g.modality,
                         participant=1 + g.episode % PARTICIPANTS,
                         direction=g.direction if g.direction in (0, 1) else 255, run=2,
                         contact_interval=ci,
                         extra={"patch": skin.ids.index(pid), "episode": g.episode,
                                "stream_start": gap + g.episode * (n + gap)})
    return SimulatedSkin(folder, replays, campaign, done, n, gap)


def _refuse(folder: Path, files: list[Path], overwrite: bool) -> None:
    from eskin._files import refuse_overwrite_all

    if folder.exists() and not folder.is_dir():
        raise FileExistsError(f"{folder}: is a file; --output names the skin's folder")
    refuse_overwrite_all(files, overwrite)
