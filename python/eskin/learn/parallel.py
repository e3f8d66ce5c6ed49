"""Running searches and folds on a Dask cluster: ``--scheduler ADDRESS``.

Model selection and evaluation already run their independent pieces (selection blocks,
1-vs-all machines, outer folds, experiment tasks) through joblib. :func:`compute_backend`
makes joblib send them to a ``dask.distributed`` cluster: the address of a running scheduler
(``tcp://host:8786``), or ``local:N`` to start a LocalCluster of N single-threaded worker
processes for the duration of the work. Every random choice is seeded by the piece it belongs
to, never by where or when it runs, so the results are those of a serial run.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from typing import Any

from eskin.errors import SchedulerError


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
def compute_backend(
    scheduler: str | None, *, processes: bool = True, timeout_s: float = 30.0
) -> Iterator[Any]:
    """Context in which joblib work runs on ``scheduler`` (None: nothing changes).

    Yields the ``dask.distributed.Client`` (or None). ``processes=False`` makes a ``local:N``
    cluster use threads in this process (quick to start; for tests).
    """
    if scheduler is None:
        yield None
        return
    kind, value = parse_scheduler(scheduler)
    try:
        import joblib
        from dask.distributed import Client, LocalCluster
    except ImportError:
        raise SchedulerError(
            "--scheduler needs dask.distributed: pip install 'eskin[dask]'"
        ) from None
    with contextlib.ExitStack() as stack:
        if kind == "local":
            cluster = stack.enter_context(
                LocalCluster(
                    n_workers=value,
                    threads_per_worker=1,
                    processes=processes,
                    dashboard_address=":0",
                )
            )
            client = stack.enter_context(Client(cluster))
        else:
            try:
                client = stack.enter_context(Client(value, timeout=timeout_s))
            except (OSError, TimeoutError, ValueError) as exc:
                raise SchedulerError(
                    f"--scheduler {value}: cannot connect to a Dask scheduler ({exc})"
                ) from None
        stack.enter_context(joblib.parallel_backend("dask", wait_for_workers_timeout=timeout_s))
        yield client
