"""Real machines for the deployment tests: trained on a simulated campaign's patterns."""

from __future__ import annotations

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
