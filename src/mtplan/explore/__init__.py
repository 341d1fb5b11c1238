"""The live set-up designer: choose a measurement set-up in the browser.

``mtplan explore [PROC]`` serves a page on the loopback address where every set-up field
of a procedure is a control and the predicted uncertainty, duration, identifiability and
acceptance figures follow each change. Optional: ``pip install 'mtplan[explore]'``
(Starlette and Uvicorn for the server, Plotly's JavaScript for the plots).

- the services, as pure functions: :mod:`~mtplan.explore.state` (a design and its set-up),
  :mod:`~mtplan.explore.info` (controls and help), :mod:`~mtplan.explore.prediction`
  (first order, identifiability, cost guard), :mod:`~mtplan.explore.trust` (the spot
  check), :mod:`~mtplan.explore.tolerances`, :mod:`~mtplan.explore.results` (what the page
  shows), :mod:`~mtplan.explore.sensitivity`, :mod:`~mtplan.explore.studies`; gathered in
  :mod:`mtplan.explore.design`;
- :mod:`mtplan.explore.jobs`: Monte Carlo confirmation and the planner in the background;
- :mod:`mtplan.explore.app`: the web application (imports the extra's packages).
"""

from __future__ import annotations

__all__ = ["EXTRA_MODULES", "missing_extra", "serve"]

#: the packages the ``explore`` extra installs, by import name
EXTRA_MODULES = ("starlette", "uvicorn", "plotly")

HOST = "127.0.0.1"


def missing_extra() -> list[str]:
    """The extra's packages that are not installed."""
    import importlib.util

    return [m for m in EXTRA_MODULES if importlib.util.find_spec(m) is None]


def serve(initial: dict | None = None, *, port: int = 8050, open_browser: bool = True,
          log_level: str = "warning") -> None:
    """Serve the designer on ``127.0.0.1:port`` until interrupted (loopback only).

    The link printed (and opened) holds this launch's secret token, as Jupyter's does;
    the page keeps it as a cookie, and nothing but the static files answers without it.
    """
    import secrets
    import threading
    import webbrowser

    import uvicorn

    from mtplan.explore.app import create_app

    from mtplan._parallel import one_blas_thread

    # the live numbers are small products computed side by side in the server's threads:
    # a team of BLAS threads per product only waits on itself (a 3384 x 60 QR of
    # geometry21 took 0.3-1.2 s on a busy 2-core machine, 10-20 ms on one thread). Held
    # for the server's life (the jobs' processes start afresh)
    blas = one_blas_thread()
    token = secrets.token_urlsafe(24)
    app = create_app(initial, token=token, learn=True)
    config = uvicorn.Config(app, host=HOST, port=port, log_level=log_level, lifespan="on",
                            timeout_graceful_shutdown=2, limit_concurrency=64,
                            server_header=False)
    server = uvicorn.Server(config)
    url = f"http://{HOST}:{port}/?token={token}"
    if open_browser:
        threading.Timer(1.0, webbrowser.open, args=(url,)).start()
    print(f"mtplan explore: serving on {url} (Ctrl+C to stop)", flush=True)
    try:
        server.run()
    finally:
        blas.restore_original_limits()
