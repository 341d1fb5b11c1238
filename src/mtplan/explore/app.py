"""The designer's web application: a Starlette app with a JSON API and one static page.

The server holds no design: every request carries the tab's whole design (it lives in
the page and its URL), so two tabs never share state. Background jobs are kept by an
unguessable id. Every request that fails answers with one line naming what it refused;
none stops the server and no traceback reaches the client.

It defends itself as Jupyter Server does (:class:`Guard`): the Host must be a loopback
name with the server's port (DNS rebinding), a state-changing request must come from the
page's own origin and be ``application/json`` (a cross-site form or ``text/plain`` POST
needs no CORS preflight), every request but the static files carries the per-launch
token (in the link the command prints, then a cookie), bodies are limited while they
stream in, and the requests in flight and the running jobs are capped.
"""

from __future__ import annotations

import contextlib
import functools
import hmac
import json
import logging
import math
import secrets
import threading
import time
from pathlib import Path
from urllib.parse import parse_qsl, urlencode, urlsplit

from starlette.applications import Starlette
from starlette.concurrency import run_in_threadpool as _in_thread
from starlette.requests import Request
from starlette.datastructures import Headers
from starlette.responses import FileResponse, JSONResponse, PlainTextResponse, Response
from starlette.middleware import Middleware
from starlette.routing import Route

from mtplan._validate import InvalidInput
from mtplan.explore import design as d
from mtplan.explore.jobs import Busy, Jobs, job_cost
from mtplan.explore.login import (LOGIN, login_endpoint, login_location, login_page,
                                  token_cookie, wants_page)
from mtplan.explore.positions import measuring_positions

__all__ = ["create_app", "STATIC", "Guard", "LOOPBACK", "MAX_BODY", "MAX_IN_FLIGHT"]

STATIC = Path(__file__).resolve().parent / "static"
#: the host names a request to the designer may carry (with the server's port)
LOOPBACK = ("127.0.0.1", "localhost", "[::1]")
#: largest request body [bytes]: a design, a study file or a prior CSV's values
MAX_BODY = 2_000_000
#: API requests computed at once; more are refused at once (503) rather than queued
MAX_IN_FLIGHT = 8
#: sensitivity curves computed at once (each holds a thread for up to 9 predictions)
MAX_CURVES = 2
log = logging.getLogger("mtplan.explore")


class TooLarge(Exception):
    """A request body over :data:`MAX_BODY`."""


def _plain(status: int, text: str, headers: dict | None = None) -> PlainTextResponse:
    return PlainTextResponse(text + "\n", status_code=status, headers=headers)


def _host_ok(host: str, port: int | None) -> bool:
    """A loopback name with this server's port (``127.0.0.1:8050``, ``localhost:8050``)."""
    name, _, p = host.rpartition(":") if not host.endswith("]") else (host, "", "")
    return name.lower() in LOOPBACK and port is not None and p == str(port)


def _origin_ok(origin: str, port: int | None) -> bool:
    parts = urlsplit(origin)
    return parts.scheme == "http" and _host_ok(parts.netloc, port)


class Guard:
    """ASGI middleware: the checks of a local server (Jupyter Server's, in order).

    1. Host: a loopback name and this server's port, else 403 (a DNS-rebound name).
    2. Origin, on every request that is not GET or HEAD: absent (not a browser) or this
       server's own origin, else 403; the body must be ``application/json``, else 415.
    3. Token: the per-launch secret, as the ``token`` query of the page's link (answered
       with a cookie and a redirect to the link without it), the cookie, or the header
       ``X-Mtplan-Token``; else 403, or, for a browser asking for the page, a redirect
       to the login page that keeps the link (:mod:`mtplan.explore.login`). The static
       files and the login page need none.
    4. ``Content-Length`` over the body limit: 413 (a body without one is counted as it
       streams in, :func:`_body`).
    5. More than `max_in_flight` API requests at once: 503 at once, not a queue.
    """

    def __init__(self, app, *, token: str, max_body: int = MAX_BODY,
                 max_in_flight: int = MAX_IN_FLIGHT):
        self.app, self.token, self.max_body = app, token, max_body
        self.max_in_flight, self.in_flight = max_in_flight, 0

    def _token_ok(self, value: str | None) -> bool:
        return bool(value) and hmac.compare_digest(value.encode(), self.token.encode())

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        answer = self._check(scope)
        if answer is not None:
            return await answer(scope, receive, send)
        if not scope["path"].startswith("/api/"):
            return await self.app(scope, receive, send)
        if self.in_flight >= self.max_in_flight:
            return await _plain(503, f"The designer is busy: {self.in_flight} requests are "
                                     "being computed. Try again in a moment.")(
                scope, receive, send)
        self.in_flight += 1
        try:
            await self.app(scope, receive, send)
        finally:
            self.in_flight -= 1

    def _check(self, scope):
        headers = Headers(scope=scope)
        port = (scope.get("server") or (None, None))[1]
        host = headers.get("host", "")
        if not _host_ok(host, port):
            return _plain(403, f"Host {host[:80]!r} refused: the designer answers only "
                               f"127.0.0.1:{port} or localhost:{port}.")
        state_changing = scope["method"] not in ("GET", "HEAD")
        if state_changing:
            origin = headers.get("origin")
            if origin is not None and not _origin_ok(origin, port):
                return _plain(403, f"Origin {origin[:80]!r} refused: requests that change "
                                   "state come only from the designer's own page.")
            kind = headers.get("content-type", "").split(";")[0].strip().lower()
            if kind != "application/json":
                return _plain(415, f"Content-Type {kind or 'none'!r} refused: the designer "
                                   "accepts application/json only.")
        path = scope["path"]
        if not path.startswith("/static/") and path != LOGIN:
            raw = scope.get("query_string", b"").decode("latin-1")
            query = dict(parse_qsl(raw))
            cookie = _cookies(headers).get(self.cookie_name(port))
            if path == "/" and self._token_ok(query.get("token")):
                rest = urlencode({k: v for k, v in query.items() if k != "token"})
                return Response(status_code=303, headers={
                    "Location": "/" + (f"?{rest}" if rest else ""),
                    "Set-Cookie": token_cookie(self.cookie_name(port), self.token)})
            if not (self._token_ok(cookie) or self._token_ok(headers.get("x-mtplan-token"))):
                if wants_page(scope["method"], path, headers.get("accept", "")):
                    # a saved design link after a restart: ask for the token, keep the link
                    return Response(status_code=303, headers={"Location": login_location(raw)})
                return _plain(403, "Token missing or wrong: open the link that `mtplan "
                                   "explore` printed (it holds this launch's token).")
        length = headers.get("content-length")
        if length is not None:
            if not length.isdigit():
                return _plain(400, f"Content-Length {length[:20]!r} is not a number of bytes.")
            if int(length) > self.max_body:
                return _plain(413, f"The request body ({int(length)} bytes) is over the "
                                   f"limit of {self.max_body} bytes.")
        return None

    @staticmethod
    def cookie_name(port) -> str:
        return f"mtplan_token_{port}"  # cookies are per host, not per port


def _cookies(headers: Headers) -> dict:
    out = {}
    for part in headers.get("cookie", "").split(";"):
        k, _, v = part.strip().partition("=")
        if k:
            out[k] = v
    return out


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


async def _body(request: Request, limit: int = MAX_BODY) -> dict:
    """The request's JSON object, read as it streams in and refused past `limit` bytes."""
    chunks, size = [], 0
    async for chunk in request.stream():
        size += len(chunk)
        if size > limit:
            raise TooLarge(f"The request body is over the limit of {limit} bytes.")
        chunks.append(chunk)
    try:
        data = json.loads(b"".join(chunks) or b"{}")
    except ValueError:
        raise InvalidInput(["The request is not JSON."]) from None
    if not isinstance(data, dict):
        raise InvalidInput(["The request must be a JSON object."])
    return data


def _release_memory() -> None:
    """Hand the memory a computation freed back to the system. The C library keeps what a
    thread frees in that thread's arena for its next use: the server computes in a pool of
    threads, and one geometry21 set-up of 100 line repeats left 160 MB resident after its
    arrays were freed, more with each thread that computed one (glibc's ``malloc_trim``;
    nothing elsewhere)."""
    trim = _malloc_trim()
    if trim is not None:
        trim(0)


@functools.lru_cache(maxsize=1)
def _malloc_trim():
    import ctypes
    import ctypes.util

    try:
        return ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6").malloc_trim
    except (OSError, AttributeError):  # not glibc
        return None


async def run_in_threadpool(fn, *args):
    """``fn(*args)`` in the server's pool of threads, its freed memory handed back after."""
    def run():
        try:
            return fn(*args)
        finally:
            _release_memory()
    return await _in_thread(run)


def _plotly_js() -> Path | None:
    try:
        import plotly
    except ImportError:  # pragma: no cover - part of the extra
        return None
    path = Path(plotly.__file__).resolve().parent / "package_data" / "plotly.min.js"
    return path if path.exists() else None


def _guarded(fn):
    """An endpoint whose every failure is one line: 413, 429, 400, 404, or 500 with the
    details in the server's log (never a traceback to the client)."""
    async def endpoint(request: Request):
        try:
            return await fn(request)
        except TooLarge as exc:
            return _answer({"error": str(exc)}, 413)
        except Busy as exc:
            return _answer({"error": str(exc)}, 429)
        except InvalidInput as exc:
            return _answer({"error": " ".join(exc.problems), "problems": exc.problems}, 400)
        except KeyError as exc:
            return _answer({"error": f"unknown {exc.args[0]!r}"}, 404)
        except Exception as exc:  # one line on the page; the details in the server's log
            log.exception("%s failed", request.url.path)
            return _answer({"error": f"{request.url.path} failed ({type(exc).__name__}); "
                                     "the server's log has the details."}, 500)
    return endpoint


async def _page(request):
    return FileResponse(STATIC / "index.html", media_type="text/html")


async def _static(request):
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


class _Live:
    """The live requests of the pages: the numbers first; a sensitivity curve and a spot
    check give way to them (they wait while numbers are computed, and give up for a change
    that a newer one from the same page has overtaken), and at most MAX_CURVES of each run."""

    def __init__(self):
        self.latest: dict = {}  # page id -> its latest change
        self.evaluating = 0  # numbers' requests in flight
        self.running = {"sensitivity": 0, "check": 0}

    def seen(self, body) -> tuple:
        tab, change = str(body.get("tab", ""))[:64], d.whole(body.get("change") or 0, "change")
        if tab and change > self.latest.get(tab, -1):
            self.latest[tab] = change
            while len(self.latest) > 1000:
                self.latest.pop(next(iter(self.latest)))
        return tab, change

    def overtaken(self, tab: str, change: int) -> bool:
        """After the numbers in flight (up to 2 s): has a newer change come from the page?"""
        for _ in range(400):
            if not self.evaluating:
                break
            time.sleep(0.005)
        return bool(tab) and self.latest.get(tab, -1) > change

    async def evaluate(self, request):
        body = await _body(request)
        self.seen(body)
        self.evaluating += 1
        try:
            return _answer(await run_in_threadpool(d.evaluate, body.get("design", body)))
        finally:
            self.evaluating -= 1

    async def _behind(self, what: str, request, compute):
        body = await _body(request)
        tab, change = self.seen(body)
        if self.running[what] >= MAX_CURVES:
            raise Busy(f"{self.running[what]} other {what} requests are being computed; this "
                       "one is skipped (the numbers are not).")
        self.running[what] += 1
        try:
            return _answer(await run_in_threadpool(compute, body, tab, change))
        finally:
            self.running[what] -= 1

    async def sensitivity(self, request):
        return await self._behind("sensitivity", request, lambda body, tab, change: (
            d.sensitivity(body.get("design") or {}, body.get("field"),
                          stop=lambda: self.overtaken(tab, change))))

    async def check(self, request):
        return await self._behind("check", request, lambda body, tab, change: (
            {"superseded": True} if self.overtaken(tab, change)
            else d.checked(body.get("design") or {})))


def create_app(initial: dict | None = None, *, token: str | None = None,
               max_jobs: int = 2, max_in_flight: int = MAX_IN_FLIGHT,
               learn: bool = False) -> Starlette:
    """The application; `initial` is the design a page without one in its URL starts from,
    `token` the launch's secret (a fresh one when None: ``app.state.token``). With `learn`,
    what the cost guard asks of each procedure is learnt at start, in a background thread
    (:func:`mtplan.explore.prediction.learn_costs`; the initial procedure first), and
    ``/api/procedures`` says ``costs_learnt`` once it is."""
    jobs = Jobs(max_running=max_jobs)
    start = d.normalise(initial) if initial else None
    token = token or secrets.token_urlsafe(24)
    live = _Live()

    async def procedures(request):
        return _answer({"procedures": d.procedures_info(), "initial": start,
                        "costs_learnt": app.state.costs_learnt is not None})

    async def glossary(request):
        return _answer({"terms": d.glossary()})

    async def procedure(request):
        return _answer(d.procedure_info(request.path_params["name"]))

    async def positions(request):
        design = (await _body(request)).get("design")
        if not isinstance(design, dict):
            raise InvalidInput(["The 'design' of a positions request must be a JSON object."])
        return _answer(await run_in_threadpool(measuring_positions, design))

    async def export(request):
        return _answer({"toml": await run_in_threadpool(d.study_toml, await _body(request))})

    async def load(request):
        body = await _body(request)
        return _answer({"design": await run_in_threadpool(
            d.design_from_study, body.get("toml", ""), body.get("procedure"))})

    async def job_estimate(request):
        body = await _body(request)
        return _answer(await run_in_threadpool(
            job_cost, str(body.get("kind", "confirm")), body.get("design") or {}))

    async def job_start(request):
        body = await _body(request)
        kind = str(body.get("kind"))
        jobs.check_room(kind)  # before any work: a refusal costs nothing
        cost = await run_in_threadpool(job_cost, kind, body.get("design") or {})
        if not cost["fits"]:
            raise InvalidInput([cost["refusal"]])
        return _answer({"id": jobs.start(kind, cost["design"]), "estimate": cost})

    async def job_status(request):
        return _answer(jobs.status(request.path_params["id"]))

    async def job_cancel(request):
        return _answer(jobs.cancel(request.path_params["id"]))

    routes = [
        Route("/", _page),
        Route("/static/{name}", _static),
        Route(LOGIN, login_page),
        Route(LOGIN, login_endpoint(token, Guard.cookie_name), methods=["POST"]),
        Route("/api/procedures", _guarded(procedures)),
        Route("/api/procedure/{name}", _guarded(procedure)),
        Route("/api/glossary", _guarded(glossary)),
        Route("/api/evaluate", _guarded(live.evaluate), methods=["POST"]),
        Route("/api/sensitivity", _guarded(live.sensitivity), methods=["POST"]),
        Route("/api/check", _guarded(live.check), methods=["POST"]),
        Route("/api/positions", _guarded(positions), methods=["POST"]),
        Route("/api/export", _guarded(export), methods=["POST"]),
        Route("/api/load", _guarded(load), methods=["POST"]),
        Route("/api/jobs", _guarded(job_start), methods=["POST"]),
        Route("/api/jobs/estimate", _guarded(job_estimate), methods=["POST"]),
        Route("/api/jobs/{id}", _guarded(job_status)),
        Route("/api/jobs/{id}/cancel", _guarded(job_cancel), methods=["POST"]),
    ]

    def learn_costs():
        from mtplan.explore.prediction import learn_costs
        from mtplan.models import registry

        first = [start["procedure"]] if start else []
        try:
            app.state.costs_learnt = learn_costs(first + [n for n in registry() if n not in first])
        except Exception:  # a request learns what it needs itself; the log says why
            log.exception("learning the cost guard's models failed")
            app.state.costs_learnt = math.nan

    @contextlib.asynccontextmanager
    async def lifespan(app):
        if learn:
            threading.Thread(target=learn_costs, name="mtplan-learn-costs", daemon=True).start()
        yield
        jobs.close()

    app = Starlette(routes=routes, lifespan=lifespan, middleware=[
        Middleware(Guard, token=token, max_in_flight=max_in_flight)])
    app.state.jobs = jobs
    app.state.token = token
    app.state.costs_learnt = None  # seconds the learning took, once it is done
    return app
