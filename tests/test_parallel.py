"""The ordered map on a Dask cluster: task order, early stop and errors."""

from __future__ import annotations

import os
import subprocess
import sys
import time

import pytest

from mtplan._parallel import ordered_map


def _slow_square(x, pause):
    time.sleep(pause)
    if x < 0:
        raise ValueError(f"negative {x}")
    return x * x


@pytest.fixture(scope="module")
def client():
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


HEAP_SCRIPT = """
import resource
import numpy as np
from mtplan._parallel import _heap_as_in_a_plain_process

def faults():
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range(100):
        np.ones(1 << 17).sum()  # 1 MiB, allocated, touched and freed
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before

untuned = faults()
_heap_as_in_a_plain_process()
print(untuned, faults())
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's heap (Linux) only")
def test_a_worker_started_as_a_dask_nanny_does_stops_paying_page_faults_per_array():
    """Under a nanny's MALLOC_TRIM_THRESHOLD_ every 1 MiB array is a fresh mmap (256 page
    faults); with the worker's heap set up as in a plain process, it reuses freed memory."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_")}
    env["MALLOC_TRIM_THRESHOLD_"] = "65536"  # the nanny's, and no other setting
    out = subprocess.run([sys.executable, "-c", HEAP_SCRIPT], env=env, capture_output=True,
                         text=True, check=True).stdout
    untuned, tuned = map(int, out.split())
    assert untuned > 100 * 200  # about 256 per array
    assert tuned < untuned / 20


def test_keep_freed_memory_takes_its_settings_under_glibc():
    """The allocator settings `mtplan` takes (large arrays from the heap, freed memory kept)
    are accepted by glibc's mallopt; elsewhere the call says it did nothing."""
    import platform

    from mtplan._parallel import MALLOC_SETTINGS, keep_freed_memory

    taken = keep_freed_memory()
    if platform.libc_ver()[0] == "glibc":
        assert taken is True
    assert set(MALLOC_SETTINGS) == {"MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_",
                                    "MALLOC_TOP_PAD_"}


def test_compile_ahead_compiles_in_a_second_process_only_what_has_no_bytecode(tmp_path,
                                                                              monkeypatch):
    """The first run after an install: modules without bytecode are imported (so compiled)
    in a second process; once they have it, or where no bytecode is written, nothing."""
    from mtplan._parallel import compile_ahead

    pkg = tmp_path / "mtplan_probe_pkg"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("VALUE = 1\n")
    (pkg / "part.py").write_text("from mtplan_probe_pkg import VALUE\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.delenv("PYTHONDONTWRITEBYTECODE", raising=False)
    monkeypatch.setenv("PYTHONPATH", str(tmp_path))
    monkeypatch.setattr(sys, "dont_write_bytecode", True)
    assert compile_ahead(("mtplan_probe_pkg.part",)) is None  # no bytecode written here
    monkeypatch.setattr(sys, "dont_write_bytecode", False)
    helper = compile_ahead(("mtplan_probe_pkg.part", "no_such_module_here"))
    assert helper is not None and helper.wait(timeout=60) == 0
    cached = {p.name.split(".")[0] for p in (pkg / "__pycache__").iterdir()}
    assert cached == {"__init__", "part"}
    assert compile_ahead(("mtplan_probe_pkg.part",)) is None  # compiled already
