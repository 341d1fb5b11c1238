"""The designer's login page: a saved design link opens after the server restarts.

A design lives in its link (``/?d=...``), never on the server, but each launch of
``mtplan explore`` has a new token, so a saved link reaches a server whose cookie the
browser does not hold. As Jupyter Server does, a browser asking for the page without a
valid token is sent to a small page that asks for the token and keeps where it was going
(``/login?next=...``); once the token is right, the cookie is set and the page opens the
design.

The login page tells nothing about the server (no procedure, no design, no token): it is
one static page whose script reads ``next`` from its own address. ``next`` is only ever
a path of this server's page (:func:`safe_next`), so the page cannot be used to send a
browser elsewhere. The token is sent as JSON from the page's own origin, through the same
checks as every state-changing request (Host, Origin, content type, body size).
"""

from __future__ import annotations

import hmac
from pathlib import Path
from urllib.parse import parse_qsl, quote, urlencode, urlsplit

__all__ = ["LOGIN", "SECURITY_HEADERS", "login_endpoint", "login_location", "login_page",
           "safe_next", "token_cookie", "token_matches", "wants_page"]

#: the login page's path (it and the static files are all that answer without a token)
LOGIN = "/login"
#: the login page itself, a static file beside the designer's page
PAGE = Path(__file__).resolve().parent / "static" / "login.html"
#: what every page of the designer's own forbids: framing by another site, referrers
SECURITY_HEADERS = {"Cache-Control": "no-store", "X-Frame-Options": "DENY",
                    "Content-Security-Policy": "frame-ancestors 'none'",
                    "Referrer-Policy": "no-referrer", "X-Content-Type-Options": "nosniff"}


def safe_next(value: str | None) -> str:
    """Where a login may go: the designer's page with the query it had (without a token);
    anything else (another host, a scheme, another path, ``//evil``) is the page itself.

    >>> safe_next("/?d=abc&token=old")
    '/?d=abc'
    >>> safe_next("//evil.example/?d=1"), safe_next("https://evil.example/")
    ('/', '/')
    """
    parts = urlsplit(str(value or "")[:100_000])
    if parts.scheme or parts.netloc or parts.path != "/":
        return "/"
    query = urlencode([(k, v) for k, v in parse_qsl(parts.query, keep_blank_values=True)
                       if k != "token"])
    return "/" + (f"?{query}" if query else "")


def wants_page(method: str, path: str, accept: str) -> bool:
    """A browser asking for the designer's page (not a script calling the API): it is
    sent to the login page rather than answered with a plain 403."""
    return method in ("GET", "HEAD") and path == "/" and "text/html" in accept.lower()


def login_location(query_string: str) -> str:
    """The login page's address that keeps the page's query as ``next``."""
    return f"{LOGIN}?next={quote(safe_next('/?' + query_string), safe='')}"


def token_cookie(name: str, token: str) -> str:
    """The ``Set-Cookie`` value of the launch's token: never readable by a script, never
    sent by another site."""
    return f"{name}={token}; Path=/; HttpOnly; SameSite=Strict"


def token_matches(given, token: str) -> bool:
    """The given token is the launch's (in constant time; anything not a string is not)."""
    return isinstance(given, str) and bool(given) and hmac.compare_digest(
        given.encode(), token.encode())


#: largest login request [bytes]: a token and the address of a design
MAX_LOGIN_BODY = 200_000


async def login_page(request):
    """GET /login: the static page that asks for the token (it reads ``next`` itself)."""
    from starlette.responses import FileResponse

    return FileResponse(PAGE, media_type="text/html", headers=SECURITY_HEADERS)


def login_endpoint(token: str, cookie_name):
    """POST /login ``{"token": ..., "next": ...}``: with this launch's token, the cookie
    and ``{"next": the page to open}``; else 403 with one line. `cookie_name` maps the
    server's port to the cookie's name."""
    import json

    from starlette.responses import JSONResponse

    async def login(request):
        chunks, size = [], 0
        async for chunk in request.stream():
            size += len(chunk)
            if size > MAX_LOGIN_BODY:
                return JSONResponse({"error": "The login request is over its limit of "
                                              f"{MAX_LOGIN_BODY} bytes."}, 413)
            chunks.append(chunk)
        try:
            body = json.loads(b"".join(chunks) or b"{}")
        except ValueError:
            body = None
        if not isinstance(body, dict):
            return JSONResponse({"error": "The login request must be a JSON object with "
                                          "'token'."}, 400)
        if not token_matches(body.get("token"), token):
            return JSONResponse({"error": "That token is not this launch's: copy it from "
                                          "the link `mtplan explore` printed when it started "
                                          "(after ?token=)."}, 403, headers=SECURITY_HEADERS)
        port = (request.scope.get("server") or (None, None))[1]
        return JSONResponse({"next": safe_next(body.get("next"))}, headers={
            **SECURITY_HEADERS, "Set-Cookie": token_cookie(cookie_name(port), token)})

    return login
