"""Real machines for the deployment tests: trained on a simulated campaign's patterns."""

from __future__ import annotations

import struct

import numpy as np

import eskin


def campaign_patterns(campaign, D, subsample="algorithm2", window="energy"):
    """Every recording of ``campaign`` preprocessed to (n, rows, cols, D)."""
    return eskin.preprocess(
        np.asarray(campaign.signals), D, lengths=np.asarray(campaign.lengths),
        sample_rate_hz=campaign.sample_rate_hz, window=window, subsample=subsample,
    )


def fit_machine(campaign, D, machine, n_classes, **params):
    """A TensorSVC (C = 10) or TensorRLS (lam = 0.1), sigma 0.5 and ``params`` (alpha,
    amplitude), alone on the first two classes or one-vs-all on all three, trained on the
    first 3 participants; returns (estimator, every recording's pattern)."""
    from eskin.learn.estimators import OneVsAllTouchClassifier, TensorRLS, TensorSVC

    X = campaign_patterns(campaign, D)
    y = np.asarray(campaign.modality).astype(np.int64)
    part = np.asarray(campaign.participant)
    train = np.isin(part, np.unique(part)[:3])
    if n_classes == 2:
        train &= y < 2
    base = (TensorSVC(C=10.0, sigma=0.5, **params) if machine == "svm"
            else TensorRLS(lam=0.1, sigma=0.5, **params))
    est = base if n_classes == 2 else OneVsAllTouchClassifier(base)
    return est.fit(X[train], y[train]), X


def model_sections(data: bytes) -> list[tuple[bytes, bytes]]:
    """The sections of a ``.eskin`` file, in order: [(tag, payload)] (docs/model-format.md: a
    32-byte header, then tag, length and payload padded to 8 bytes; a CRC-32 ends the file)."""
    pos, out = 32, []
    while pos < len(data) - 4:
        tag, n = struct.unpack_from("<4sI", data, pos)
        out.append((tag, bytes(data[pos + 8 : pos + 8 + n])))
        pos += 8 + (n + 7) // 8 * 8
    return out
