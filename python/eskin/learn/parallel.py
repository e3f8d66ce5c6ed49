"""Running searches and folds in parallel: ``--scheduler local:N`` or ``--scheduler ADDRESS``.

Model selection and evaluation run their independent pieces (selection blocks, 1-vs-all
machines, outer folds, recipes, experiment tasks) through :func:`run_calls`.
:func:`compute_backend` decides where they go: ``local:N`` to a pool of N single-threaded
worker processes on this machine (joblib's loky pool, started for the duration of the work),
any other text to the ``dask.distributed`` cluster of the scheduler at that address
(``tcp://host:8786``). Every random choice is seeded by the piece it belongs to, never by where
or when it runs, so the results are those of a serial run.

Why not a Dask LocalCluster for ``local:N``: its scheduler, nannies and workers (four more
processes importing ``distributed`` for two workers, polling memory, sending heartbeats) cost
CPU and memory of their own: on two cores, evaluating a 30-participant campaign, 1.10-1.18x the
serial CPU and 1.8 GB at peak, against 0.98-1.07x and 0.7 GB for the pool (BENCHMARKS.md,
"Folds on a local pool"). The loky pool's workers wait on a pipe between tasks.

On a Dask cluster the data reach the workers from the client, never by a path: :func:`share`
scatters the arrays a run's tasks read to every worker once (``client.scatter(...,
broadcast=True)``) and :func:`run_calls` submits the tasks with those futures as arguments,
which each worker resolves from its own copy. A cluster needs no filesystem shared with the
client. On the local pool :func:`share` keeps the values, and joblib hands an array larger than
1 MB to the workers as a memory map of one file written once per call of :func:`run_calls`.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterable, Iterator, Mapping
from typing import Any

from eskin.errors import SchedulerError

#: the thread limits of a ``local:N`` pool's worker processes: the core's kernels one thread
#: each, as BLAS and OpenMP (joblib sets those), not one per core in every worker
WORKER_THREADS = ("ESKIN_NUM_THREADS",)


def parse_scheduler(address: str) -> tuple[str, Any]:
    """("local", n_workers) for ``local:N``, ("address", text) otherwise."""
    text = str(address).strip()
    if text.startswith("local"):
        _, _, count = text.partition(":")
        try:
            n = int(count) if count else 2
        except ValueError:
            raise SchedulerError(
                f"--scheduler {address!r}: expected local:N with N a whole number of workers"
            ) from None
        if n < 1:
            raise SchedulerError(f"--scheduler {address!r}: N must be at least 1")
        return "local", n
    if not text:
        raise SchedulerError("--scheduler: empty address")
    return "address", text


@contextlib.contextmanager
def compute_backend(scheduler: str | None, *, timeout_s: float = 30.0) -> Iterator[Any]:
    """Context in which joblib work (and :func:`run_calls`) runs on ``scheduler`` (None:
    nothing changes).

    ``local:N``: a pool of N single-threaded worker processes, shut down on leaving; yields
    None. Any other address: the Dask cluster of that scheduler; yields its
    ``dask.distributed.Client``.
    """
    if scheduler is None:
        yield None
        return
    kind, value = parse_scheduler(scheduler)
    if kind == "local":
        with local_pool(value):
            yield None
        return
    try:
        import joblib
        from dask.distributed import Client
    except ImportError:
        raise SchedulerError(
            "--scheduler needs dask.distributed: pip install 'eskin[dask]'"
        ) from None
    with contextlib.ExitStack() as stack:
        try:
            client = stack.enter_context(Client(value, timeout=timeout_s))
        except (OSError, TimeoutError, ValueError) as exc:
            raise SchedulerError(
                f"--scheduler {value}: cannot connect to a Dask scheduler ({exc})"
            ) from None
        stack.enter_context(joblib.parallel_backend("dask", wait_for_workers_timeout=timeout_s))
        yield client


@contextlib.contextmanager
def local_pool(n_workers: int) -> Iterator[None]:
    """Context in which joblib work runs on ``n_workers`` worker processes of this machine,
    one thread each (``n_jobs=-1`` and any larger count mean all of them); the processes are
    started at the first call and stopped on leaving."""
    import joblib

    backend = _local_backend(n_workers)
    try:
        with joblib.parallel_config(backend=backend, n_jobs=n_workers):
            yield
    finally:
        backend.shutdown()


def _local_backend(n_workers: int) -> Any:
    """A joblib loky backend of at most ``n_workers`` processes that also limits the core's
    threads in them (:data:`WORKER_THREADS`) and keeps its pool to shut it down."""
    from joblib.parallel import LokyBackend

    class LocalPool(LokyBackend):
        MAX_NUM_THREADS_VARS = (*LokyBackend.MAX_NUM_THREADS_VARS, *WORKER_THREADS)

        def __init__(self, **kwargs: Any) -> None:
            super().__init__(**kwargs)
            self.pools: list[Any] = []

        def effective_n_jobs(self, n_jobs: int | None) -> int:
            if n_jobs is not None and n_jobs < 0:
                n_jobs = n_workers
            return min(super().effective_n_jobs(n_jobs), n_workers)

        def configure(self, *args: Any, **kwargs: Any) -> int:
            n = super().configure(*args, **kwargs)
            if self._workers is not None and self._workers not in self.pools:
                self.pools.append(self._workers)
            return n

        def shutdown(self) -> None:
            for pool in self.pools:
                pool.shutdown(wait=True)

    return LocalPool(inner_max_num_threads=1)


def dask_client() -> Any | None:
    """The ``dask.distributed`` Client that joblib's active backend sends work to (inside
    :func:`compute_backend` or ``joblib.parallel_backend("dask")``), or None (any other backend,
    and inside a task running on a worker)."""
    from joblib.parallel import get_active_backend

    backend, _ = get_active_backend()
    if type(backend).__name__ != "DaskDistributedBackend":
        return None
    return getattr(backend, "client", None)


def share(data: Mapping[str, Any]) -> dict[str, Any]:
    """The values of ``data`` (numpy arrays, small containers of them) as the tasks of
    :func:`run_calls` take them: on a Dask cluster, futures of copies scattered once to every
    worker (``broadcast=True``); otherwise the values themselves."""
    client = dask_client()
    if client is None:
        return dict(data)
    names = list(data)
    # a list, not the dict: scattering a dict would name the futures by its keys, and the
    # next share() of the same names would replace this data on the cluster
    futures = client.scatter([data[k] for k in names], broadcast=True, hash=False)
    return dict(zip(names, futures))


#: an argument larger than this goes to the cluster on its own (client.scatter), not inside
#: the task graph (distributed warns about large graphs and sends them through the scheduler)
_SCATTER_BYTES = 100_000


def _by_reference(client: Any, value: Any) -> Any:
    """``value``, or a future of a copy on the cluster when it is large (futures unchanged)."""
    from dask.distributed import Future
    from dask.sizeof import sizeof

    if isinstance(value, Future) or sizeof(value) <= _SCATTER_BYTES:
        return value
    # in a list: scattering a list itself would give one future per item
    return client.scatter([value], hash=False)[0]


def run_calls(
    func: Callable[..., Any],
    calls: Iterable[tuple[tuple[Any, ...], Mapping[str, Any]]],
    *,
    n_jobs: int | None = 1,
    unordered: bool = False,
) -> Iterator[Any]:
    """``func(*args, **kwargs)`` for every ``(args, kwargs)`` of ``calls``, results in the
    order of ``calls`` (``unordered``: as they finish).

    On a Dask cluster (:func:`dask_client`) every call is a task of its own; arguments made by
    :func:`share` are futures that each worker resolves from its copy, and any other argument
    larger than 100 kB is scattered to the cluster on its own. joblib's Dask backend is never
    used for the calls themselves: its cache of scattered arguments is keyed by ``id()`` and
    raised ``KeyError`` from a weakref callback when ids were reused (joblib 1.6). Otherwise
    joblib runs them with ``n_jobs`` (1: here, one after the other; -1 inside
    :func:`local_pool`: on all its workers)."""
    calls = list(calls)
    client = dask_client()
    if client is None:
        if n_jobs == 1:
            yield from (func(*a, **k) for a, k in calls)
            return
        from joblib import Parallel, delayed

        mode = "generator_unordered" if unordered else "generator"
        yield from Parallel(n_jobs=n_jobs, return_as=mode)(delayed(func)(*a, **k) for a, k in calls)
        return
    from dask.distributed import as_completed

    futures = [
        client.submit(
            func,
            *(_by_reference(client, v) for v in a),
            pure=False,
            **{name: _by_reference(client, v) for name, v in k.items()},
        )
        for a, k in calls
    ]
    try:
        for f in as_completed(futures) if unordered else futures:
            yield f.result()
    finally:
        client.cancel(futures)
