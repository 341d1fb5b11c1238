"""Screenshots of the designer's state and print views, for the documentation.

    python docs/explore/screenshots_state.py   # docs/explore/{login,scenarios}[_390].png,
                                               # docs/explore/positions_<procedure>.png,
                                               # docs/explore/specific[_390].png,
                                               # docs/explore/{rotary_axis,tracker_frame}_print.png

- the login page a saved design link meets after a restart of the server (1440 and 390 px);
- named scenarios side by side (the page's scenarios section, 1440 and 390 px);
- the measuring positions of each procedure (1440 px; rotary_axis at 390 px too);
- the specific risk of a measured value under the tolerance table (1440 and 390 px);
- the print: the page printed to PDF by Chromium, as the browser's Print does, one A4 page
  rendered by poppler's ``pdftoppm``.

Each picture is stored with a palette of 64 colours (they are flat drawings of text), to
keep the repository small.
"""

from __future__ import annotations

import base64
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from PIL import Image
from playwright.sync_api import sync_playwright

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from screenshots import CHROMIUM, DESIGNS, _start  # noqa: E402

PRINTED = {
    "rotary_axis": {"procedure": "rotary_axis", **DESIGNS["rotary_axis"],
                    "off": ["probe_noise"]},
    "tracker_frame": {"procedure": "tracker_frame", **DESIGNS["tracker_frame"]},
}


def _small(path: Path) -> None:
    """The picture with a 64-colour palette (text and flat plots lose nothing visible)."""
    img = Image.open(path).convert("RGB")
    img.quantize(colors=64, method=Image.Quantize.MEDIANCUT).save(path, optimize=True)
    print("wrote", path, path.stat().st_size // 1024, "KiB")


def _d(design: dict) -> str:
    return base64.urlsafe_b64encode(json.dumps(design).encode()).decode().rstrip("=")


def _link(link: str, design: dict) -> str:
    return f"{link}&d={_d(design)}"


def _settled(page) -> None:
    page.wait_for_function("window.mtplan && window.mtplan.changes > 0 && "
                           "window.mtplan.rendered === window.mtplan.changes && "
                           "window.mtplan.drawn === window.mtplan.rendered && "
                           "!window.mtplan.inflight")
    page.wait_for_function("document.body.dataset.checked || !document."
                           "querySelector('tr.unchecked')")


def main() -> int:
    server, link = _start()
    base = link.split("?", 1)[0]
    try:
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
            for suffix, width in (("", 1440), ("_390", 390)):
                # the login page, as a saved link meets it (a browser without the cookie)
                ctx = browser.new_context(viewport={"width": width, "height": 560})
                page = ctx.new_page()
                page.goto(f"{base}?d={_d({'procedure': 'rotary_axis'})}")
                page.wait_for_selector("body[data-ready='1']")
                page.fill("#token", "not-the-token")
                page.click("#login")
                page.wait_for_function("document.getElementById('login-error').textContent")
                out = HERE / f"login{suffix}.png"
                page.screenshot(path=str(out))
                _small(out)
                ctx.close()
                # two named scenarios side by side
                ctx = browser.new_context(viewport={"width": width, "height": 900})
                page = ctx.new_page()
                page.set_default_timeout(300_000)
                page.goto(_link(link, {"procedure": "rotary_axis", **DESIGNS["rotary_axis"]}))
                _settled(page)
                for name, positions in (("eight positions", "8"), ("twelve positions", "12")):
                    if positions != "8":
                        page.fill("#f-positions", positions)
                        page.dispatch_event("#f-positions", "change")
                        _settled(page)
                    page.click("#keep")
                    box = page.locator("#scenarios .scenario-name").last
                    box.fill(name)
                    box.dispatch_event("change")
                # naming the last one scrolled its table sideways: show it from its start
                page.evaluate("document.querySelectorAll('#scenarios, #scenarios ~ *, "
                              ".table-wrap').forEach((e) => { e.scrollLeft = 0; })")
                time.sleep(0.5)
                out = HERE / f"scenarios{suffix}.png"
                head = page.locator("h2", has_text="Scenarios side by side")
                head.scroll_into_view_if_needed()
                top = head.bounding_box()["y"] + page.evaluate("window.scrollY")
                bottom = page.locator("#scenarios").bounding_box()["y"] + page.evaluate(
                    "window.scrollY") + page.locator("#scenarios").bounding_box()["height"]
                left = 0 if width < 800 else page.locator("#results").bounding_box()["x"]
                page.screenshot(path=str(out), full_page=True, clip={
                    "x": left, "y": top - 8, "width": width - left, "height": bottom - top + 16})
                _small(out)
                ctx.close()
            # the measuring positions of each procedure (and one at a phone's width)
            # (of each procedure's own design: the others show a state of its numbers)
            for name, width in [(n, 1440) for n in DESIGNS if "procedure" not in DESIGNS[n]] \
                    + [("rotary_axis", 390)]:
                ctx = browser.new_context(viewport={"width": width, "height": 900})
                page = ctx.new_page()
                page.set_default_timeout(300_000)
                page.goto(_link(link, {"procedure": name, **DESIGNS[name]}))
                _settled(page)
                page.wait_for_function("document.getElementById('positions-plot').dataset.points")
                time.sleep(0.5)
                section = page.locator("#positions-plot")
                section.scroll_into_view_if_needed()
                box = section.bounding_box()
                y = box["y"] + page.evaluate("window.scrollY")
                out = HERE / f"positions_{name}{'_390' if width < 800 else ''}.png"
                page.screenshot(path=str(out), full_page=True, clip={
                    "x": box["x"], "y": y - 30, "width": box["width"], "height": box["height"] + 60})
                _small(out)
                ctx.close()
            # the specific risk of a measured value, under the tolerance table
            for suffix, width in (("", 1440), ("_390", 390)):
                ctx = browser.new_context(viewport={"width": width, "height": 900})
                page = ctx.new_page()
                page.set_default_timeout(300_000)
                design = {"procedure": "rotary_axis", **DESIGNS["rotary_axis"]}
                design["tolerances"] = {k: {**v, "measured": "95"}
                                        for k, v in design["tolerances"].items()}
                page.goto(_link(link, design))
                _settled(page)
                page.wait_for_function("/outside its tolerance/.test(document."
                                       "getElementById('specific-out').textContent)")
                time.sleep(0.5)
                top = page.locator("#acceptance").bounding_box()
                low = page.locator("#specific").bounding_box()
                scroll = page.evaluate("window.scrollY")
                out = HERE / f"specific{suffix}.png"
                page.screenshot(path=str(out), full_page=True, clip={
                    "x": low["x"], "y": top["y"] + scroll - 30,
                    "width": min(width - low["x"], max(top["width"], low["width"])),
                    "height": low["y"] + low["height"] - top["y"] + 40})
                _small(out)
                ctx.close()
            # the print: one A4 page, as Chromium prints it
            for name, design in PRINTED.items():
                ctx = browser.new_context(viewport={"width": 1440, "height": 1000})
                page = ctx.new_page()
                page.set_default_timeout(300_000)
                page.goto(_link(link, design))
                _settled(page)
                with tempfile.TemporaryDirectory() as tmp:
                    pdf = Path(tmp) / "report.pdf"
                    page.pdf(path=str(pdf), format="A4")
                    subprocess.run(["pdftoppm", "-r", "80", "-png", "-singlefile", str(pdf),
                                    str(Path(tmp) / "page")], check=True)
                    out = HERE / f"{name}_print.png"
                    out.write_bytes((Path(tmp) / "page.png").read_bytes())
                _small(out)
                ctx.close()
            browser.close()
    finally:
        server.terminate()
        try:
            server.wait(timeout=10)
        except subprocess.TimeoutExpired:  # busy computing: stop it
            server.kill()
            server.wait()
    return 0


if __name__ == "__main__":
    sys.exit(main())
