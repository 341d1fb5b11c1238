"""The ordered map on a Dask cluster: task order, early stop and errors."""

from __future__ import annotations

import os
import time

import pytest

from mtplan._parallel import ordered_map


def _slow_square(x, pause):
    time.sleep(pause)
    if x < 0:
        raise ValueError(f"negative {x}")
    return x * x


@pytest.fixture
def client():  # one per test: none is left current for the local-cluster test
    import distributed  # the test extras hold it: missing is a failure, not a skip

    with distributed.Client(processes=False, n_workers=2, threads_per_worker=1,
                            dashboard_address=None) as c:
        yield c


def test_results_come_back_in_task_order_whatever_finishes_first(client):
    # the first tasks are the slowest: they finish last, yet are yielded first
    tasks = [(i, 0.2 if i < 2 else 0.0) for i in range(12)]
    assert list(ordered_map(_slow_square, tasks, backend="dask")) == [i * i for i in range(12)]


def test_a_caller_that_stops_early_leaves_nothing_running(client):
    def endless():
        i = 0
        while True:
            yield (i, 0.01)
            i += 1

    got = []
    for value in ordered_map(_slow_square, endless(), backend="dask", chunk=2):
        got.append(value)
        if len(got) == 5:
            break
    assert got == [0, 1, 4, 9, 16]
    deadline = time.monotonic() + 10
    while client.processing() and any(client.processing().values()) \
            and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not any(client.processing().values())


def test_a_task_error_reaches_the_caller(client):
    with pytest.raises(ValueError, match="negative -1"):
        list(ordered_map(_slow_square, [(1, 0.0), (-1, 0.0), (2, 0.0)], backend="dask"))


def test_the_local_cluster_starts_its_workers_with_the_heap_of_a_plain_process():
    """The nannies of the cluster parallel_session starts leave MALLOC_TRIM_THRESHOLD_ unset
    (Dask's default sets it, which costs a Monte Carlo block page faults per array); the rest
    of Dask's worker environment stays as Dask sets it."""
    from mtplan._parallel import parallel_session

    with parallel_session(n_jobs=1, backend="dask") as session:
        env = session["client"].run(lambda: dict(os.environ))
    (worker_env,) = env.values()
    assert "MALLOC_TRIM_THRESHOLD_" not in worker_env
    assert worker_env.get("OMP_NUM_THREADS") == "1"
