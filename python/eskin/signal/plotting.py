"""Pictures of campaign recordings (matplotlib, Agg backend: no display needed)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

#: at most this many taxel labels on the traces' axis: more overlap at the figure's size
MAX_TAXEL_LABELS = 16


def labelled_taxels(rows: int, cols: int) -> list[int]:
    """The taxels (row-major indices) whose traces get a label: all of a grid of up to
    :data:`MAX_TAXEL_LABELS` taxels; else every k-th, starting at each row's first taxel when
    the rows fit (an 8x8 grid: columns 0 and 4 of every row)."""
    n = rows * cols
    if n <= MAX_TAXEL_LABELS:
        return list(range(n))
    if rows <= MAX_TAXEL_LABELS:
        per_row = max(1, MAX_TAXEL_LABELS // rows)
        stride = -(-cols // per_row)
        return [r * cols + c for r in range(rows) for c in range(0, cols, stride)]
    stride = -(-n // MAX_TAXEL_LABELS)
    return list(range(0, n, stride))

def _detect_window(rec: np.ndarray, length: int, rate: float) -> tuple[tuple[int, int], str]:
    """The touch window of one recording, from eskin.preprocess.detect_windows."""
    from eskin.signal.preprocess import detect_windows

    win = detect_windows(rec[None].astype(np.int16), lengths=np.array([length]),
                         sample_rate_hz=rate)
    return (int(win[0, 0]), int(win[0, 1])), "detected window (eskin.preprocess)"


def plot_recording(campaign: Any, index: int, path: str | os.PathLike[str], *,
                   n_maps: int = 8) -> Path:
    """Draw recording ``index``: every taxel's trace (volts, offset per taxel), the detected
    touch window (shaded), the true contact interval when the file has one (dashed), and a
    strip of heat maps of the taxels' short-time energy across the window."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(campaign)
    if not -n <= index < n:
        raise IndexError(f"recording index {index} out of range: the campaign has {n} recordings")
    index %= n
    rec = campaign.recording(index)
    rows, cols, length = rec.shape
    rate = campaign.sample_rate_hz
    volts = rec.astype(np.float64) * campaign.volts_per_count
    t = np.arange(length) / rate
    (w0, w1), wlabel = _detect_window(np.asarray(campaign.signals[index]), length, rate)
    if w1 <= w0:  # nothing detected: show the energy of the whole recording
        e0, e1 = 0, max(length, 1)
    else:
        e0, e1 = w0, w1

    fig = plt.figure(figsize=(10, 7.2), dpi=80)
    gs = fig.add_gridspec(2, n_maps, height_ratios=[3.2, 1.0], hspace=0.35, wspace=0.08)
    ax = fig.add_subplot(gs[0, :])
    flat = volts.reshape(rows * cols, length)
    spread = np.percentile(np.abs(flat), 99.5) if flat.size else 1.0
    step = 2.2 * max(spread, 1e-6)
    cmap = plt.get_cmap("tab10")
    for k in range(rows * cols):
        ax.plot(t, flat[k] - k * step, lw=0.5, color=cmap((k // cols) % 10))
    shown = labelled_taxels(rows, cols)
    ax.set_yticks([-k * step for k in shown])
    ax.set_yticklabels([f"{k // cols},{k % cols}" for k in shown], fontsize=7)
    ax.set_ylabel("taxel (row,col); traces offset")
    ax.set_xlabel("time (s)")
    ax.set_xlim(0, max(length, 1) / rate)
    if w1 > w0:
        ax.axvspan(w0 / rate, w1 / rate, color="gold", alpha=0.25, label=wlabel)
    ci = campaign.contact_interval
    if ci is not None:
        a, b = ci[index]
        ax.axvline(a / rate, color="k", ls="--", lw=0.8, label="true contact interval")
        ax.axvline(b / rate, color="k", ls="--", lw=0.8)
    mod = campaign.modalities[int(campaign.modality[index])]
    from eskin.data.campaign import DIRECTION_NAMES

    direction = DIRECTION_NAMES.get(int(campaign.direction[index]), "?")
    src = "SIMULATED" if campaign.source == "simulated" else campaign.source
    ax.set_title(f"recording {index}: {mod}, participant {int(campaign.participant[index])}, "
                 f"{direction}, run {int(campaign.run[index])}  [{src} data, "
                 f"{rows}x{cols} taxels, {rate:g} Hz, scale {step:.3g} V/taxel]", fontsize=9)
    ax.legend(loc="upper right", fontsize=7)

    # energy heat maps over the window
    edges = np.linspace(e0, e1, n_maps + 1).astype(int)
    centred = volts - np.median(volts[..., : max(e0, 1)] if e0 > 0 else volts, axis=-1,
                                keepdims=True)
    energies = np.stack([
        np.mean(centred[..., a:max(b, a + 1)] ** 2, axis=-1) for a, b in zip(edges[:-1], edges[1:])
    ])
    vmax = float(energies.max()) if energies.size and energies.max() > 0 else 1.0
    for k in range(n_maps):
        axm = fig.add_subplot(gs[1, k])
        im = axm.imshow(energies[k], vmin=0.0, vmax=vmax, cmap="magma",
                        interpolation="nearest")
        axm.set_xticks([])
        axm.set_yticks([])
        axm.set_title(f"{edges[k] / rate:.2f} s", fontsize=7)
    cax = fig.add_axes((0.92, 0.1, 0.012, 0.17))
    fig.colorbar(im, cax=cax).ax.tick_params(labelsize=6)
    fig.text(0.5, 0.29, "short-time energy (V$^2$) of each taxel across the window",
             ha="center", fontsize=8)
    out = Path(path)
    fig.savefig(out)
    plt.close(fig)
    return out
