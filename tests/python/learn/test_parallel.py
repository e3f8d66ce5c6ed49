"""eskin.learn.parallel on a real local Dask cluster of two worker processes (the data reach the
workers from the client: the campaign file is gone before any task runs) and on the local pool
of ``--scheduler local:2``: the results are those of the serial run."""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("distributed")

#: the longest a cluster run in this file may take before the test fails (it must not hang)
DEADLINE_S = 240


@contextlib.contextmanager
def _deadline(seconds: int = DEADLINE_S):
    """Fail (TimeoutError in the waiting main thread) instead of hanging."""

    def _expired(*_):
        raise TimeoutError(f"the Dask cluster gave no result within {seconds} s")

    old = signal.signal(signal.SIGALRM, _expired)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


@pytest.fixture(scope="module")
def client():
    """A LocalCluster of two single-threaded worker processes and a client of it."""
    import dask
    from dask.distributed import Client, LocalCluster

    with _deadline(), dask.config.set({"distributed.comm.timeouts.connect": "60s"}):
        cluster = LocalCluster(
            n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0"
        )
        c = Client(cluster, timeout="60s")
    try:
        yield c
    finally:
        with _deadline(60):
            c.close()
            cluster.close()


@pytest.fixture()
def campaign_without_file(tmp_path):
    """The small simulated campaign read into memory by the client, its file removed."""
    from learn_data import small_simulated

    from eskin.data.campaign import load_campaign

    path = tmp_path / "gone.h5"
    shutil.copy(small_simulated(tmp_path), path)
    camp = load_campaign(path, in_memory=True)
    path.unlink()
    assert not Path(camp.path).exists()
    return camp


def _task_names(stream) -> set[str]:
    from dask.utils import key_split

    return {key_split(t["key"]) for t in stream.data}


def _workers(stream) -> set[str]:
    return {t["worker"] for t in stream.data}


@pytest.mark.filterwarnings("ignore::UserWarning:distributed")
def test_evaluate_on_two_worker_processes_matches_the_serial_run_without_the_file(
    client, campaign_without_file
):
    import joblib
    from dask.distributed import get_task_stream

    from eskin.learn.evaluation import evaluate_recipe

    kw = {"recipe": {"quick": True, "D": 8}, "n_folds": 3, "classes": ["brush", "washer"],
          "seed": 1}
    serial = evaluate_recipe(campaign_without_file, n_jobs=1, **kw)
    with _deadline(), joblib.parallel_backend("dask"), get_task_stream(client) as ts:
        on_cluster = evaluate_recipe(campaign_without_file, n_jobs=-1, **kw)
    assert "run_fold" in _task_names(ts)  # the folds ran on the workers
    for r in (serial, on_cluster):
        r.pop("seconds")
        for f in r["folds"]:
            f.pop("seconds")
    assert on_cluster == serial
    assert len(serial["folds"]) == 3 and serial["trained_with"]["D"] == 8


@pytest.mark.filterwarnings("ignore::UserWarning:distributed")
def test_the_recipe_search_on_two_worker_processes_matches_the_serial_run(
    client, campaign_without_file
):
    import joblib
    from dask.distributed import get_task_stream

    from eskin.learn.training import train_model

    kw = {"classes": ["brush", "finger", "washer"], "quick": True, "D": 8, "seed": 2}
    serial = train_model(campaign_without_file, n_jobs=1, **kw)
    with _deadline(), joblib.parallel_backend("dask"), get_task_stream(client) as ts:
        on_cluster = train_model(campaign_without_file, n_jobs=-1, **kw)
    # the recipes and their inner folds: one task per (D, subsampling, alpha) and split
    assert "score_task" in _task_names(ts) and len(_workers(ts)) == 2
    a, b = serial.training["recipe_search"], on_cluster.training["recipe_search"]
    a.pop("seconds", None), b.pop("seconds", None)
    assert a == b and a["evaluations"] > 0
    assert serial.selected == on_cluster.selected
    X = serial.preprocess(campaign_without_file)
    np.testing.assert_array_equal(serial.predict_indices(X)[0], on_cluster.predict_indices(X)[0])
    np.testing.assert_array_equal(serial.decision_function(X), on_cluster.decision_function(X))


def test_without_a_cluster_the_data_stay_here_and_calls_keep_their_order():
    from eskin.learn.parallel import dask_client, run_calls, share

    assert dask_client() is None
    arrays = {"x": np.arange(5)}
    assert share(arrays)["x"] is arrays["x"]
    calls = [(("11",), {"base": b}) for b in (2, 3, 10, 16)]
    for n_jobs in (1, 2):
        assert list(run_calls(int, calls, n_jobs=n_jobs)) == [3, 4, 11, 17]


def _sum_of(a, *, scale=1.0):
    return float(a.sum()) * scale


def test_large_arguments_reach_the_workers_outside_the_task_graph(client):
    """An argument of 16 MB is scattered on its own: distributed warns about any graph over
    10 MB (an error in this suite), and the joblib backend's id()-keyed cache is not used."""
    import joblib

    from eskin.learn.parallel import run_calls

    big = np.arange(2_000_000, dtype=np.float64)  # 16 MB
    calls = [((big,), {"scale": s}) for s in (1.0, 2.0, 3.0)]
    serial = list(run_calls(_sum_of, calls, n_jobs=1))
    with _deadline(), joblib.parallel_backend("dask"):
        on_cluster = list(run_calls(_sum_of, calls, n_jobs=-1))
        unordered = sorted(run_calls(_sum_of, calls, n_jobs=-1, unordered=True))
    assert serial == on_cluster == unordered == [float(big.sum()) * s for s in (1, 2, 3)]


def _pid_and_threads(_):
    return os.getpid(), os.environ.get("ESKIN_NUM_THREADS")


def test_a_local_pool_runs_calls_on_single_threaded_workers_and_stops_them():
    import joblib.parallel
    import psutil

    from eskin.learn.parallel import compute_backend, run_calls

    with _deadline(), compute_backend("local:2") as client:
        assert client is None
        backend, _ = joblib.parallel.get_active_backend()
        assert [backend.effective_n_jobs(n) for n in (-1, 1, 2, 8)] == [2, 1, 2, 2]
        ran = list(run_calls(_pid_and_threads, [((i,), {}) for i in range(8)], n_jobs=-1))
    pids = {pid for pid, _ in ran}
    assert os.getpid() not in pids and len(pids) <= 2
    assert {threads for _, threads in ran} == {"1"}
    assert not any(psutil.pid_exists(p) for p in pids)  # stopped on leaving


def test_evaluate_on_a_local_pool_matches_the_serial_run(tmp_path):
    from learn_data import small_simulated

    from eskin.learn.evaluation import evaluate_recipe
    from eskin.learn.parallel import compute_backend

    path = str(small_simulated(tmp_path))
    kw = {"recipe": {"quick": True, "D": 8}, "n_folds": 3, "classes": ["brush", "washer"],
          "seed": 1}
    serial = evaluate_recipe(path, n_jobs=1, **kw)
    with _deadline(), compute_backend("local:2"):
        pooled = evaluate_recipe(path, n_jobs=-1, **kw)
    for r in (serial, pooled):
        r.pop("seconds")
        for f in r["folds"]:
            f.pop("seconds")
    assert pooled == serial
    assert [f["fold"] for f in serial["folds"]] == [0, 1, 2]
