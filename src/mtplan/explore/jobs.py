"""Background work of the designer: Monte Carlo confirmation and the planner's search.

Each job runs in its own process (``spawn``), so the page and the server stay
responsive while it computes and a cancel ends it at once. The child reports
progress (trials done) and its result through a pipe; the server polls it.

A job is checked before any process is spawned (:func:`job_cost`): its kind, trials and
seed, its set-up, and its time, estimated from one small block of trials timed here, must
fit :data:`JOB_BUDGET_S`; at most ``max_running`` jobs run at once (:class:`Busy` beyond).
"""

from __future__ import annotations

import math
import multiprocessing
import secrets
import threading
import time

from mtplan._validate import InvalidInput

__all__ = ["Jobs", "Busy", "confirm", "histogram", "cheapest", "check_first_order", "job_cost",
           "JOB_BUDGET_S", "MAX_TRIALS", "planner_inputs"]

#: the longest a job may be estimated to take [s]; more trials are refused before it starts
JOB_BUDGET_S = 600.0
#: the most trials a job may ask for, whatever its speed
MAX_TRIALS = 10**7
#: trials of the planner's confirmations (it caps the trials it is given at this)
PLAN_TRIALS = 5000


class Busy(Exception):
    """Refused for now: as many jobs as allowed are running."""


def _duration(seconds: float) -> str:
    if seconds < 120:
        return f"{seconds:.0f} s"
    if seconds < 7200:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


def job_cost(kind: str, design: dict, *, budget_s: float = JOB_BUDGET_S) -> dict:
    """Check a job and estimate its time before it starts.

    Returns
    -------
    dict with ``design`` (normalised, trials and seed as integers), ``seconds`` (the
    estimate), ``per_trial_s``, ``max_trials`` (what fits the budget), ``fits`` and, when
    it does not, ``refusal`` (one line naming trials). Raises InvalidInput for a bad kind,
    trials, seed or set-up.
    """
    from mtplan.explore.prediction import trial_seconds
    from mtplan.explore.size import JOB_SIZE, size_problem
    from mtplan.explore.state import normalise, setup_of, whole
    from mtplan.explore.studies import plan_vary

    if kind not in _KINDS:
        raise InvalidInput([f"The 'kind' of a job must be one of {', '.join(_KINDS)}. "
                            f"Got {kind[:40]!r} instead."])
    if not isinstance(design, dict):
        raise InvalidInput(["The 'design' of a job must be a JSON object."])
    design = normalise(design)
    trials = whole(design["trials"], "trials", low=2, high=MAX_TRIALS)
    seed = whole(design["seed"], "seed", low=0, high=2**63 - 1)
    design = {**design, "trials": trials, "seed": seed}
    proc, setup = setup_of(design)
    est, _ = proc.estimator(design["estimator"])
    _, problem = size_problem(proc, setup.as_dict(), limit=JOB_SIZE, what="a job's trial")
    if problem:  # before a trial is timed: one trial of it would hold gigabytes
        raise InvalidInput([problem])
    per = trial_seconds(proc, setup, est)
    runs, n = trials, trials
    if kind == "check":
        from mtplan.explore.trust import SPOT_TRIALS

        runs = n = SPOT_TRIALS
    if kind == "cheapest":
        planner_inputs(proc, design)  # before any process: the targets and the ranges
        vary = plan_vary(proc, design)
        n = min(trials, PLAN_TRIALS)
        runs = n * (1 + math.prod(len(v) for v in vary.values()) // 8) if vary else n
    seconds = 1.0 + per * runs
    max_trials = int(max(budget_s - 1.0, 0) / max(per * runs / n, 1e-9))
    out = {"design": design, "seconds": seconds, "per_trial_s": per, "fits": seconds <= budget_s,
           "max_trials": min(max_trials, MAX_TRIALS), "text": f"about {_duration(seconds)}"}
    if not out["fits"]:
        out["refusal"] = (f"trials: {trials} would take about {_duration(seconds)} here "
                          f"({per * 1e3:.3g} ms a trial); a job may take "
                          f"{_duration(budget_s)}, so at most {out['max_trials']} trials.")
    return out


def planner_inputs(proc, design: dict) -> tuple:
    """(ranges, targets) of the planner's search, or InvalidInput naming each target that
    is not a positive number or names no measurand, and the ranges' problems. A target
    ``residual:M`` bounds the error left after compensating M (the planner's
    ``residual:`` targets, as in a study's plan)."""
    from mtplan.explore.state import setup_of
    from mtplan.explore.studies import plan_vary
    from mtplan.plans.planner import RESIDUAL

    _, setup = setup_of(design)
    names = [m.name for m in proc.measurands(setup)]
    problems, targets = [], {}
    for name, v in design["targets"].items():
        try:
            x = float(v)
        except (TypeError, ValueError):
            x = math.nan
        if name.removeprefix(RESIDUAL) not in names:
            problems.append(f"The target {name!r} names no measurand of this set-up "
                            f"({', '.join(names[:8])}{', ...' if len(names) > 8 else ''}).")
        elif not (math.isfinite(x) and x > 0):
            problems.append(f"The target of {name} must be a number > 0 (U, k = 2). Got "
                            f"{str(v)[:40]!r} instead.")
        else:
            targets[name] = x
    if problems:
        raise InvalidInput(problems)
    vary = plan_vary(proc, design)
    if not vary:
        raise InvalidInput(["Mark at least one set-up field's range (values to try) to search."])
    if not targets:
        raise InvalidInput(["Enter at least one target U (k = 2) to search for."])
    return vary, targets


def histogram(values, bins: int = 60) -> dict | None:
    """Counts of the Monte Carlo values over `bins` equal bins [display unit] (None when
    the values were not kept or are all equal)."""
    import numpy as np

    if values is None:
        return None
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    if v.size < 2 or np.ptp(v) == 0:
        return None
    counts, edges = np.histogram(v, bins=bins)
    return {"counts": counts.tolist(), "edges": edges.tolist()}


def confirm(design: dict, progress=None) -> dict:
    """Monte Carlo of a design's set-up: what ``mtplan simulate`` gives for the same set-up,
    seed and trials, beside the page's linearised prediction."""
    from mtplan.evaluation.simulation import simulate_uncertainty
    from mtplan.explore.prediction import predict
    from mtplan.explore.state import K, normalise, setup_of

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
        m["histogram"] = histogram(r.mc.samples(m["name"]))
    doc["findings"] = r.findings()
    return doc


def cheapest(design: dict, progress=None) -> dict:
    """The planner over the design's ranges with its U targets: the cheapest set-up."""
    from mtplan.explore.state import K, normalise, setup_of
    from mtplan.plans.planner import plan

    design = normalise(design)
    proc, setup = setup_of(design)
    vary, targets = planner_inputs(proc, design)
    r = plan(proc, setup, vary, targets, k=K, estimator=design["estimator"],
             seed=int(design["seed"]), trials=min(int(design["trials"]), 5000))
    return {"best": r.best, "confirmation": r.confirmation, "k": K, "targets": targets,
            "tried": int(len(r.table))}


def check_first_order(design: dict, progress=None) -> dict:
    """The spot check of a design's first-order numbers where it is too costly for a live
    answer: the same trials and seed (:func:`mtplan.explore.trust.spot_check`) with a
    job's time and memory. The server keeps what it finds (:func:`Jobs.status`), so the
    page's next numbers are checked ones."""
    from mtplan.explore.state import normalise, setup_key, setup_of
    from mtplan.explore.trust import spot_check

    design = normalise(design)
    proc, setup = setup_of(design)
    est, _ = proc.estimator(design["estimator"])
    spot = spot_check(proc, setup, est, budget_s=JOB_BUDGET_S)
    return {"key": [proc.name, setup_key(setup), est], "spot": spot}


_KINDS = {"confirm": confirm, "cheapest": cheapest, "check": check_first_order}


def _child(kind: str, design: dict, conn) -> None:  # pragma: no cover - in a child process
    def progress(done, total):
        conn.send(("progress", done, total))

    try:
        conn.send(("done", _KINDS[kind](design, progress)))
    except InvalidInput as exc:
        conn.send(("error", " ".join(exc.problems)))
    except MemoryError:
        conn.send(("error", "the computation ran out of memory; use fewer trials or a "
                            "smaller set-up"))
    except Exception as exc:  # one line on the page; the server goes on
        import traceback

        traceback.print_exc()  # the server's log
        conn.send(("error", f"the computation failed ({type(exc).__name__}); the server's "
                            "log has the details"))
    finally:
        conn.close()


class Jobs:
    """The running and finished jobs of a server, by unguessable id (a tab sees its own)."""

    def __init__(self, keep: int = 64, max_running: int = 2):
        self._jobs: dict[str, dict] = {}
        self._lock = threading.Lock()
        self._ctx = multiprocessing.get_context("spawn")
        self._keep = keep
        self.max_running = max_running

    def running(self) -> int:
        """Jobs still running (finished ones are collected first)."""
        with self._lock:
            for job in self._jobs.values():
                self._drain(job)
            return sum(j["state"] == "running" for j in self._jobs.values())

    def check_room(self, kind: str) -> None:
        """InvalidInput for an unknown kind, Busy when no more jobs may run now."""
        if kind not in _KINDS:
            raise InvalidInput([f"The 'kind' of a job must be one of {', '.join(_KINDS)}. "
                                f"Got {kind[:40]!r} instead."])
        if self.running() >= self.max_running:
            raise Busy(f"{self.max_running} jobs are running, the most at once; cancel one or "
                       "wait for it to finish.")

    def start(self, kind: str, design: dict) -> str:
        """Spawn a checked job (:func:`job_cost`); Busy when the cap is reached."""
        with self._lock:  # the count and the new entry together: no two starts slip past
            for job in self._jobs.values():
                self._drain(job)
            if sum(j["state"] == "running" for j in self._jobs.values()) >= self.max_running:
                raise Busy(f"{self.max_running} jobs are running, the most at once; cancel "
                           "one or wait for it to finish.")
            if kind not in _KINDS:
                raise InvalidInput([f"No job {kind!r}; the jobs are {', '.join(_KINDS)}."])
            parent, child = self._ctx.Pipe(duplex=False)
            proc = self._ctx.Process(target=_child, args=(kind, design, child), daemon=True)
            proc.start()
            child.close()
            job_id = secrets.token_urlsafe(12)
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
                    if job["kind"] == "check":  # the live numbers are checked from now on
                        from mtplan.explore.trust import remember

                        remember(tuple(msg[1]["key"]), msg[1]["spot"])
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
