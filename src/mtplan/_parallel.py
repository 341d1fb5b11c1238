"""Ordered parallel map over joblib's backends (loky, threading) and a Dask cluster.

Workers only decide who computes which task; results always come back in task
order, with a bounded number of tasks ahead, so memory stays bounded and a result
never depends on ``n_jobs`` or the backend. Dask tasks go to the cluster's futures
directly (see :func:`_dask_map`).
"""

from __future__ import annotations

import atexit
import contextlib
import functools
import os
import sys
from collections.abc import Callable, Iterable, Iterator

from mtplan._validate import InvalidInput, Problems

__all__ = ["BACKENDS", "check_parallel", "one_blas_thread", "ordered_map", "parallel_session",
           "stage_executor"]

BACKENDS = ("loky", "threading", "multiprocessing", "dask", "sequential")


@functools.lru_cache(maxsize=1)
def _blas_controller():
    import scipy.linalg  # noqa: F401 - loads scipy's own OpenBLAS before the look-up
    from threadpoolctl import ThreadpoolController

    return ThreadpoolController()


def one_blas_thread():
    """A context in which numpy's and scipy's BLAS run on one thread (threadpoolctl).

    For the many small products that fits, budgets, samplers and propagations are made
    of, a team of threads costs more than it gains (several times, on a busy machine).
    The libraries are found once (``threadpool_limits`` looks them up on every call:
    milliseconds), after scipy.linalg is imported: a limit covers only the libraries
    loaded when it is set, and scipy brings its own OpenBLAS, loaded on first use; left
    out, it ran a posterior's least squares on every core, where a thin SVD that takes
    5 ms on one thread took 80 ms of spinning CPU.
    """
    return _blas_controller().limit(limits=1, user_api="blas")


def check_parallel(problems: Problems, n_jobs, backend, scheduler=None) -> None:
    """Record problems with the ``n_jobs``, ``backend`` and ``scheduler`` parameters."""
    if problems.number("n_jobs", n_jobs, integer=True, low=-64, high=4096):
        problems.require(int(n_jobs) != 0, "n_jobs", n_jobs, "a non-zero int (-1 means all cores)")
    if backend is not None:
        problems.choice("backend", backend, BACKENDS)
    if scheduler is not None:
        if problems.require(
            isinstance(scheduler, str) and bool(scheduler.strip()),
            "scheduler",
            scheduler,
            "a Dask scheduler address such as 'tcp://host:8786'",
        ):
            problems.require(backend == "dask", "scheduler", scheduler,
                             "given only with backend='dask' (it is the Dask cluster to run on)")


#: how long a Dask scheduler may take to answer before it counts as unreachable [s]
CONNECT_TIMEOUT_S = 5.0


def _reach(address: str) -> None:
    """Refuse, within CONNECT_TIMEOUT_S, a scheduler address that is malformed or does not
    answer on its TCP port (before a Dask client is made, which would wait far longer)."""
    import socket

    from distributed.comm import parse_address, parse_host_port

    try:
        scheme, location = parse_address(address)
        host, port = parse_host_port(location) if scheme in ("tcp", "tls") else (None, None)
    except (ValueError, TypeError) as exc:
        raise InvalidInput([f"The 'scheduler' parameter must be a Dask scheduler address such "
                            f"as 'tcp://host:8786'. Got {address!r} instead ({exc})."]) from None
    if host is None:
        return
    try:
        socket.create_connection((host, port), timeout=CONNECT_TIMEOUT_S).close()
    except OSError as exc:
        reason = "no answer" if isinstance(exc, TimeoutError) else (exc.strerror or str(exc))
        raise InvalidInput([f"The Dask scheduler {address!r} cannot be reached ({reason} within "
                            f"{CONNECT_TIMEOUT_S:g} s)."]) from None


#: the pool :func:`stage_executor` hands out: (number of workers, executor)
_stage_pool: tuple | None = None


def stage_executor(jobs: int):
    """A reusable pool of ``jobs`` worker processes for whole stages submitted one by one
    (the staged study, then the documents drawn from it): the same pool, already started,
    for every caller that asks for the same number of workers.

    On Linux, in a process with no other thread, the workers are forked from this process
    when the first task is submitted, all at once, so they start with every module this
    process has imported by then (each worker would otherwise import numpy, scipy, pandas
    and the models again; a module only the tasks need is imported by each worker, at once:
    importing it here first would keep the other core idle meanwhile, and on a fresh
    installation also while it is compiled to bytecode). Elsewhere, or beside other
    threads (whose locks a forked child could find held): joblib's loky workers, started
    afresh. Arguments and results travel pickled; the workers take no part in the
    results' values.
    """
    import threading

    global _stage_pool
    if _stage_pool is not None and _stage_pool[0] == jobs:
        return _stage_pool[1]
    if _stage_pool is not None:
        _stage_pool[1].shutdown(wait=True)
        _stage_pool = None
    if not sys.platform.startswith("linux") or threading.active_count() > 1:
        from joblib.executor import get_memmapping_executor

        return get_memmapping_executor(jobs, max_nbytes=None)  # loky reuses its own pool
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    executor = ProcessPoolExecutor(jobs, mp_context=multiprocessing.get_context("fork"))
    _stage_pool = (jobs, executor)
    return executor


def _close_stage_pool() -> None:
    """The stage pool shut down at exit, while the modules it needs are still there (left
    to the garbage collector at the interpreter's end, its manager's callback found them
    gone and printed an ignored exception)."""
    global _stage_pool
    if _stage_pool is not None:
        _stage_pool[1].shutdown(wait=True)
        _stage_pool = None


atexit.register(_close_stage_pool)


def effective_jobs(n_jobs: int) -> int:
    """Number of workers ``n_jobs`` asks for (joblib's convention for negative values)."""
    if n_jobs < 0:
        return max((os.cpu_count() or 1) + 1 + n_jobs, 1)
    return n_jobs


#: Dask's configuration for the local cluster :func:`parallel_session` starts: its nannies
#: start the workers without ``MALLOC_TRIM_THRESHOLD_`` (None unsets a variable of
#: ``distributed.nanny.pre-spawn-environ``), so that a worker's C heap behaves as in a plain
#: process. Dask's default, 65536, switches off glibc's dynamic thresholds: every array above
#: 128 KiB is then a fresh ``mmap`` paid in page faults and handed back when freed, and a
#: sweep's Monte Carlo blocks took half as long again in the kernel. A cluster started
#: elsewhere takes the same setting from its own Dask configuration (docs/performance.md).
NANNY_ENVIRON = {"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None}


@contextlib.contextmanager
def parallel_session(n_jobs: int = 1, backend: str | None = None, scheduler: str | None = None):
    """Context in which :func:`ordered_map` runs with `backend`.

    For ``backend="dask"``, connect to `scheduler` when given, reuse a Dask client
    that already exists, or start a local cluster of ``n_jobs`` single-threaded
    worker processes for the duration of the context.
    """
    if backend != "dask":
        yield {"n_jobs": n_jobs, "backend": backend}
        return
    try:
        import dask
        import distributed
    except ImportError as exc:  # pragma: no cover - depends on the installation
        raise ImportError(
            "backend='dask' needs the dask extra: pip install 'mtplan[dask]'"
        ) from exc
    owned = []
    if scheduler:
        _reach(scheduler)
        try:
            client = distributed.Client(scheduler, timeout=CONNECT_TIMEOUT_S)
        except Exception as exc:  # noqa: BLE001 - whatever answers there is no scheduler
            raise InvalidInput([f"The Dask scheduler {scheduler!r} cannot be used (what answers "
                                f"there is not a Dask scheduler: {type(exc).__name__})."]) \
                from None
        owned.append(client)
    else:
        try:
            client = distributed.get_client()
        except ValueError:
            with dask.config.set(NANNY_ENVIRON):
                cluster = distributed.LocalCluster(
                    n_workers=max(effective_jobs(n_jobs), 1),
                    threads_per_worker=1,
                    processes=True,
                    dashboard_address=None,
                )
            client = distributed.Client(cluster)
            owned += [client, cluster]
    try:
        yield {"n_jobs": -1, "backend": "dask", "client": client}
    finally:
        for thing in owned:
            thing.close()


def ordered_map(
    fn: Callable,
    tasks: Iterable[tuple],
    *,
    n_jobs: int = 1,
    backend: str | None = None,
    chunk: int | None = None,
) -> Iterator:
    """Yield ``fn(*task)`` for each task, in task order.

    Runs in this process when ``n_jobs == 1`` or ``backend == "sequential"``. Otherwise
    through joblib: with `chunk`, in chunks of that many tasks (a caller that may stop
    early, such as the adaptive Monte Carlo, wastes at most a chunk); without, as one
    stream whose results come back in order while the workers stay busy (no barrier
    between chunks; at most ``2 n_jobs`` tasks are dispatched ahead, so memory stays
    bounded). The workers are loky's reusable pool: a later call finds them started.
    For the dask backend, call it inside :func:`parallel_session`: the tasks go to the
    session's client as workers free up (:func:`_dask_map`).
    """
    jobs = effective_jobs(n_jobs)
    if backend == "sequential" or (jobs == 1 and backend != "dask"):
        for task in tasks:
            yield fn(*task)
        return
    if backend == "dask":
        yield from _dask_map(fn, tasks, chunk)
        return
    import joblib

    kwargs = {"n_jobs": jobs, "backend": backend or "loky"}
    if chunk is None:
        parallel = joblib.Parallel(return_as="generator", pre_dispatch="2*n_jobs", **kwargs)
        yield from parallel(joblib.delayed(fn)(*t) for t in tasks)
        return
    tasks = iter(tasks)
    with joblib.Parallel(**kwargs) as parallel:
        while True:
            batch = [t for _, t in zip(range(chunk), tasks, strict=False)]
            if not batch:
                return
            yield from parallel(joblib.delayed(fn)(*t) for t in batch)


def _dask_map(fn, tasks: Iterable[tuple], chunk: int | None) -> Iterator:
    """``fn(*task)`` for each task on the session's Dask client, yielded in task order.

    Tasks go straight to the client's futures (no joblib layer between): each one is
    submitted as a worker frees up, so no worker waits at a barrier between batches while
    another finishes a long task, and the scheduler holds at most ``width`` of them (the
    workers' threads, twice, or `chunk` when the caller asked for one). Results that finish
    ahead of an earlier task wait here, at most ``4 width`` of them, so memory stays
    bounded. A caller that stops early (the adaptive Monte Carlo) cancels what is left.
    """
    from distributed import as_completed, get_client

    client = get_client()
    threads = sum(client.nthreads().values()) or 1
    width = max(chunk or 0, 2 * threads)
    tasks = iter(tasks)
    index, done = {}, {}  # future key -> task number; task number -> result
    running = as_completed(loop=client.loop)
    submitted = wanted = 0
    exhausted = False
    try:
        while True:
            while not exhausted and running.count() < width and len(done) + running.count() \
                    < 4 * width:
                task = next(tasks, None)
                if task is None:
                    exhausted = True
                    break
                future = client.submit(fn, *task, pure=False)
                index[future.key] = submitted
                running.add(future)
                submitted += 1
            if wanted in done:
                yield done.pop(wanted)
                wanted += 1
            elif wanted == submitted:
                return
            else:
                future = next(running)
                done[index.pop(future.key)] = future.result()  # a task's error raises here
    finally:
        if running.futures:
            client.cancel(list(running.futures))
