"""The designer's web application: a Starlette app with a JSON API and one static page.

The server holds no design: every request carries the tab's whole design (it lives in
the page and its URL), so two tabs never share state. Background jobs are kept by an
unguessable id. Every request that fails answers with its message; none stops the
server.
"""

from __future__ import annotations

import contextlib
import json
import math
import time
import traceback
from pathlib import Path

from starlette.applications import Starlette
from starlette.concurrency import run_in_threadpool
from starlette.requests import Request
from starlette.responses import FileResponse, JSONResponse, Response
from starlette.routing import Route

from mtplan._validate import InvalidInput
from mtplan.explore import design as d
from mtplan.explore.jobs import Jobs

__all__ = ["create_app", "STATIC"]

STATIC = Path(__file__).resolve().parent / "static"


def _clean(x):
    """JSON-safe: non-finite floats become null, numpy scalars plain numbers."""
    if isinstance(x, dict):
        return {str(k): _clean(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_clean(v) for v in x]
    if hasattr(x, "item") and not isinstance(x, str | bytes):
        x = x.item()
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


def _answer(payload, status=200) -> JSONResponse:
    return JSONResponse(_clean(payload), status_code=status)


async def _body(request: Request) -> dict:
    try:
        data = json.loads((await request.body()) or b"{}")
    except ValueError:
        raise InvalidInput(["The request is not JSON."]) from None
    if not isinstance(data, dict):
        raise InvalidInput(["The request must be a JSON object."])
    return data


def _plotly_js() -> Path | None:
    try:
        import plotly
    except ImportError:  # pragma: no cover - part of the extra
        return None
    path = Path(plotly.__file__).resolve().parent / "package_data" / "plotly.min.js"
    return path if path.exists() else None


def create_app(initial: dict | None = None) -> Starlette:
    """The application; `initial` is the design a page without one in its URL starts from."""
    jobs = Jobs()
    start = d.normalise(initial) if initial else None

    def guarded(fn):
        async def endpoint(request: Request):
            try:
                return await fn(request)
            except InvalidInput as exc:
                return _answer({"error": " ".join(exc.problems), "problems": exc.problems}, 400)
            except KeyError as exc:
                return _answer({"error": f"unknown {exc.args[0]!r}"}, 404)
            except Exception as exc:  # shown on the page; the server answers the next one
                traceback.print_exc()
                return _answer({"error": f"{type(exc).__name__}: {exc}"}, 500)
        return endpoint

    async def page(request):
        return FileResponse(STATIC / "index.html", media_type="text/html")

    async def static(request):
        name = request.path_params["name"]
        if name == "plotly.min.js":
            path = _plotly_js()
        else:
            path = STATIC / name
            if path.resolve().parent != STATIC or not path.is_file():
                path = None
        if path is None:
            return Response("not found", status_code=404)
        kind = "text/css" if name.endswith(".css") else "application/javascript"
        return FileResponse(path, media_type=kind, headers={"Cache-Control": "max-age=3600"})

    async def procedures(request):
        return _answer({"procedures": d.procedures_info(), "initial": start})

    async def procedure(request):
        return _answer(d.procedure_info(request.path_params["name"]))

    latest: dict = {}  # page id -> its latest change (a sensitivity gives way to it)

    def seen(body) -> tuple:
        tab, change = str(body.get("tab", "")), int(body.get("change") or 0)
        if tab and change > latest.get(tab, -1):
            latest[tab] = change
            while len(latest) > 1000:
                latest.pop(next(iter(latest)))
        return tab, change

    evaluating = [0]  # numbers' requests in flight: a sensitivity gives them the CPU

    async def evaluate(request):
        body = await _body(request)
        seen(body)
        evaluating[0] += 1
        try:
            return _answer(await run_in_threadpool(d.evaluate, body.get("design", body)))
        finally:
            evaluating[0] -= 1

    async def sensitivity(request):
        body = await _body(request)
        tab, change = seen(body)

        def stop() -> bool:  # before each point: wait (up to 2 s) while numbers are computed
            for _ in range(400):
                if not evaluating[0]:
                    break
                time.sleep(0.005)
            return bool(tab) and latest.get(tab, -1) > change

        return _answer(await run_in_threadpool(
            d.sensitivity, body.get("design") or {}, body.get("field"), stop=stop))

    async def export(request):
        return _answer({"toml": await run_in_threadpool(d.study_toml, await _body(request))})

    async def load(request):
        body = await _body(request)
        return _answer({"design": await run_in_threadpool(
            d.design_from_study, str(body.get("toml", "")), body.get("procedure"))})

    async def job_start(request):
        body = await _body(request)
        design = d.normalise(body.get("design") or {})
        d.setup_of(design)  # a refused set-up is said at once, not by the child
        return _answer({"id": jobs.start(str(body.get("kind")), design)})

    async def job_status(request):
        return _answer(jobs.status(request.path_params["id"]))

    async def job_cancel(request):
        return _answer(jobs.cancel(request.path_params["id"]))

    routes = [
        Route("/", page),
        Route("/static/{name}", static),
        Route("/api/procedures", guarded(procedures)),
        Route("/api/procedure/{name}", guarded(procedure)),
        Route("/api/evaluate", guarded(evaluate), methods=["POST"]),
        Route("/api/sensitivity", guarded(sensitivity), methods=["POST"]),
        Route("/api/export", guarded(export), methods=["POST"]),
        Route("/api/load", guarded(load), methods=["POST"]),
        Route("/api/jobs", guarded(job_start), methods=["POST"]),
        Route("/api/jobs/{id}", guarded(job_status)),
        Route("/api/jobs/{id}/cancel", guarded(job_cancel), methods=["POST"]),
    ]
    @contextlib.asynccontextmanager
    async def lifespan(app):
        yield
        jobs.close()

    app = Starlette(routes=routes, lifespan=lifespan)
    app.state.jobs = jobs
    return app
