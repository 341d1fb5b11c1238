"""Background work of the designer: Monte Carlo confirmation and the planner's search.

Each job runs in its own process (``spawn``), so the page and the server stay
responsive while it computes and a cancel ends it at once. The child reports
progress (trials done) and its result through a pipe; the server polls it.
"""

from __future__ import annotations

import multiprocessing
import secrets
import threading
import time

from mtplan._validate import InvalidInput

__all__ = ["Jobs", "confirm", "cheapest"]


def confirm(design: dict, progress=None) -> dict:
    """Monte Carlo of a design's set-up: what ``mtplan simulate`` gives for the same set-up,
    seed and trials, beside the page's linearised prediction."""
    from mtplan.evaluation.simulation import simulate_uncertainty
    from mtplan.explore.design import K, normalise, predict, setup_of

    design = normalise(design)
    proc, setup = setup_of(design)
    est, _ = proc.estimator(design["estimator"])
    r = simulate_uncertainty(proc, setup, estimator=est, trials=int(design["trials"]),
                             rng=int(design["seed"]), progress=progress or False)
    doc = r.to_dict()
    pred = predict(proc, setup, est)["u"]
    for m in doc["measurands"]:
        m["U"] = None if m["u"] is None else K * m["u"]
        m["predicted_u"] = pred.get(m["name"])
    doc["findings"] = r.findings()
    return doc


def cheapest(design: dict, progress=None) -> dict:
    """The planner over the design's ranges with its U targets: the cheapest set-up."""
    from mtplan.explore.design import K, normalise, plan_vary, setup_of
    from mtplan.plans.planner import plan

    design = normalise(design)
    proc, setup = setup_of(design)
    vary = plan_vary(proc, design)
    targets = {k: float(v) for k, v in design["targets"].items()}
    if not vary:
        raise InvalidInput(["Mark at least one set-up field's range (values to try) to search."])
    if not targets:
        raise InvalidInput(["Enter at least one target U (k = 2) to search for."])
    r = plan(proc, setup, vary, targets, k=K, estimator=design["estimator"],
             seed=int(design["seed"]), trials=min(int(design["trials"]), 5000))
    return {"best": r.best, "confirmation": r.confirmation, "k": K, "targets": targets,
            "tried": int(len(r.table))}


_KINDS = {"confirm": confirm, "cheapest": cheapest}


def _child(kind: str, design: dict, conn) -> None:  # pragma: no cover - in a child process
    def progress(done, total):
        conn.send(("progress", done, total))

    try:
        conn.send(("done", _KINDS[kind](design, progress)))
    except InvalidInput as exc:
        conn.send(("error", " ".join(exc.problems)))
    except Exception as exc:  # the page shows it; the server goes on
        conn.send(("error", f"{type(exc).__name__}: {exc}"))
    finally:
        conn.close()


class Jobs:
    """The running and finished jobs of a server, by unguessable id (a tab sees its own)."""

    def __init__(self, keep: int = 64):
        self._jobs: dict[str, dict] = {}
        self._lock = threading.Lock()
        self._ctx = multiprocessing.get_context("spawn")
        self._keep = keep

    def start(self, kind: str, design: dict) -> str:
        if kind not in _KINDS:
            raise InvalidInput([f"No job {kind!r}; the jobs are {', '.join(_KINDS)}."])
        parent, child = self._ctx.Pipe(duplex=False)
        proc = self._ctx.Process(target=_child, args=(kind, design, child), daemon=True)
        proc.start()
        child.close()
        job_id = secrets.token_urlsafe(12)
        with self._lock:
            self._jobs[job_id] = {"kind": kind, "process": proc, "conn": parent,
                                  "state": "running", "done": 0, "total": None,
                                  "start": time.monotonic(), "result": None, "error": None}
            self._forget_old()
        return job_id

    def _forget_old(self) -> None:
        finished = [k for k, j in self._jobs.items() if j["state"] != "running"]
        for k in finished[: max(0, len(self._jobs) - self._keep)]:
            del self._jobs[k]

    def status(self, job_id: str) -> dict:
        with self._lock:
            job = self._jobs.get(job_id)
            if job is None:
                raise KeyError(job_id)
            self._drain(job)
            return {"kind": job["kind"], "state": job["state"], "done": job["done"],
                    "total": job["total"], "elapsed_s": time.monotonic() - job["start"],
                    "result": job["result"], "error": job["error"]}

    @staticmethod
    def _drain(job) -> None:
        if job["state"] != "running":
            return
        conn = job["conn"]
        try:
            while conn.poll():
                msg = conn.recv()
                if msg[0] == "progress":
                    job["done"], job["total"] = msg[1], msg[2]
                elif msg[0] == "done":
                    job["state"], job["result"] = "done", msg[1]
                else:
                    job["state"], job["error"] = "error", msg[1]
        except (EOFError, OSError):
            pass
        if job["state"] == "running" and not job["process"].is_alive() and not conn.poll():
            job["state"] = "error"
            job["error"] = f"the computation stopped (exit code {job['process'].exitcode})"
        if job["state"] != "running":
            conn.close()
            job["process"].join(timeout=1)

    def cancel(self, job_id: str) -> dict:
        with self._lock:
            job = self._jobs.get(job_id)
            if job is None:
                raise KeyError(job_id)
            self._drain(job)
            if job["state"] == "running":
                job["process"].terminate()
                job["process"].join(timeout=5)
                job["conn"].close()
                job["state"] = "cancelled"
        return self.status(job_id)

    def close(self) -> None:
        with self._lock:
            for job in self._jobs.values():
                if job["state"] == "running":
                    job["process"].terminate()
                    job["state"] = "cancelled"
