"""Reports as a person would meet them: escaped text, atomic writes, a self-contained page
that a browser shows with every image, and a PDF whose pages are not blank."""

from __future__ import annotations

import html.parser
import re
import subprocess
import sys
from pathlib import Path

import pytest

from mtplan.reports.certificate import WATERMARK
from tests.reports.conftest import need

REPORT_TITLES = ["Overall result and actions", "Contents", "Results as found",
                 "Test conditions and instruments", "Deviations from the plan", "Glossary",
                 "Measured data", "Provenance"]
PLAN_TITLES = ["The agreement", "Annex: tests and decision rules (technical study)",
               "Methods and estimators", "Glossary",
               "What the simulation shows", "Plan: the cheapest set-up meeting the targets",
               "Provenance"]


# ------------------------------------------------------------------ escaping
def test_script_in_labels_is_text_in_html(small_report):
    for name in ("report", "plan"):
        page = (small_report / f"{name}.html").read_text(encoding="utf-8")
        assert "<script" not in page.lower() and "<img src=x" not in page, name
        assert "&lt;script&gt;alert(1)&lt;/script&gt;" in page, name
    page = (small_report / "plan.html").read_text(encoding="utf-8")  # the notes: in the plan
    assert "&lt;img src=x onerror=alert(2)&gt;" in page


def test_script_in_labels_is_text_in_pdf(small_report):
    text = _pdftotext(small_report / "report.pdf")
    assert "<script>alert(1)</script>" in text
    assert "<script>alert('title')</script>" in text


# ------------------------------------------------------------------ self-contained
class _Links(html.parser.HTMLParser):
    def __init__(self):
        super().__init__()
        self.refs = []

    def handle_starttag(self, tag, attrs):
        for key, value in attrs:
            if key in ("src", "href", "srcset", "data", "poster", "action"):
                self.refs.append((tag, key, value or ""))


def test_html_is_self_contained(small_report):
    page = (small_report / "report.html").read_text(encoding="utf-8")
    parser = _Links()
    parser.feed(page)
    assert parser.refs, "the page should at least link its sections and embed figures"
    for tag, key, value in parser.refs:
        assert value.startswith("#") or value.startswith("data:"), (tag, key, value[:60])
    assert "@import" not in page and "url(" not in page.replace("url(data:", "")


def test_results_csv_written(small_report):
    names = {p.name for p in (small_report / "results").glob("*.csv")}
    assert any(n.endswith("_uncertainty.csv") for n in names)
    assert any("sweep" in n for n in names)


def test_results_hold_one_covariance_per_test(small_report):
    """results/covariance_<procedure>_<k>.csv: the measured values' covariance (the test has
    readings), one row and one column per measurand, its diagonal the measured u^2 of
    verdicts.csv."""
    import numpy as np
    import pandas as pd

    cov = pd.read_csv(small_report / "results" / "covariance_circle_centre_1.csv")
    names = list(cov["measurand"])
    assert names == ["centre_x", "centre_y", "radius"] and list(cov["unit"]) == ["um"] * 3
    assert cov["source"].str.startswith("measured").all()
    matrix = cov[names].to_numpy()
    assert np.allclose(matrix, matrix.T, rtol=1e-12, atol=0)
    verdicts = pd.read_csv(small_report / "results" / "verdicts.csv").set_index("measurand")
    for i, name in enumerate(names):
        if name in verdicts.index:
            assert matrix[i, i] == pytest.approx(verdicts.loc[name, "measured_u"] ** 2, rel=1e-9)


# ------------------------------------------------------------------ atomic writes
def test_failed_pdf_leaves_nothing_behind(small_result, tmp_path, monkeypatch):
    from mtplan.reports import render, write_report

    out = tmp_path / "out"
    out.mkdir()
    (out / "keep.txt").write_text("before", encoding="utf-8")

    def boom(doc):
        raise RuntimeError("renderer died mid-way")

    monkeypatch.setattr(render, "render_pdf", boom)
    with pytest.raises(RuntimeError, match="mid-way"):
        write_report(small_result, out)
    assert sorted(p.name for p in out.rglob("*")) == ["keep.txt"]


def test_failed_write_keeps_old_report(small_result, tmp_path, monkeypatch):
    """A write that fails half-way leaves the previous file whole and no temporary files."""
    from mtplan.reports import render, write_report

    out = tmp_path / "out"
    write_report(small_result, out)
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}

    real = render.render_html

    def half(doc):
        real(doc)
        raise KeyboardInterrupt

    monkeypatch.setattr(render, "render_html", half)
    with pytest.raises(KeyboardInterrupt):
        write_report(small_result, out)
    after = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    assert after == before


# ------------------------------------------------------------------ the PDF, looked at
def _pdftotext(pdf: Path) -> str:
    need("pdftotext")
    return subprocess.run(["pdftotext", "-layout", str(pdf), "-"], check=True,
                          capture_output=True, text=True).stdout


def _pages_non_blank(pdf: Path, tmp_path: Path) -> int:
    need("pdftoppm")
    import numpy as np
    from matplotlib.image import imread

    tmp_path.mkdir(parents=True, exist_ok=True)
    subprocess.run(["pdftoppm", "-r", "30", "-png", str(pdf), str(tmp_path / "page")],
                   check=True, capture_output=True)
    pages = sorted(tmp_path.glob("page*.png"))
    assert pages
    for page in pages:
        img = imread(page)[..., :3]
        ink = float(np.mean(img.mean(axis=2) < 0.9))
        assert ink > 0.002, f"{page.name} looks blank ({ink:.4f} of pixels inked)"
    return len(pages)


def test_pdf_pages_non_blank_and_titles(small_report, tmp_path):
    for name, titles in (("report", REPORT_TITLES), ("plan", PLAN_TITLES)):
        n = _pages_non_blank(small_report / f"{name}.pdf", tmp_path / name)
        assert n >= 4
        text = _pdftotext(small_report / f"{name}.pdf")
        for title in titles:
            assert title in text, (name, title)
        assert "1. Bore" in text


# ------------------------------------------------------------------ the HTML, in a browser
def _chromium() -> str:
    return need("chromium", "chromium-browser")


def _chrome(args, tmp_path, timeout=120):
    exe = _chromium()
    profile = tmp_path / "profile"
    cmd = [exe, "--headless", "--disable-gpu", "--disable-background-networking",
           "--disable-component-update", "--disable-sync", "--no-first-run",
           "--disable-dev-shm-usage", f"--user-data-dir={profile}", *args]
    if sys.platform.startswith("linux") and hasattr(__import__("os"), "geteuid") \
            and __import__("os").geteuid() == 0:
        cmd.insert(2, "--no-sandbox")
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)


_PROBE = """<script>
window.__errors = [];
window.addEventListener('error', function (e) { window.__errors.push(String(e.message || e.type)); }, true);
(function () {
  var orig = console.error;
  console.error = function () { window.__errors.push([].join.call(arguments, ' ')); orig.apply(console, arguments); };
})();
window.addEventListener('load', function () {
  var imgs = Array.prototype.slice.call(document.images);
  var ok = imgs.filter(function (i) { return i.complete && i.naturalWidth > 0; }).length;
  var out = document.createElement('pre');
  out.id = 'mtplan-probe';
  out.textContent = 'PROBE images=' + imgs.length + ' loaded=' + ok + ' errors=' + window.__errors.length + ' ' + window.__errors.join(' | ') + ' END';
  document.body.appendChild(out);
});
</script>"""


def check_in_browser(report: Path, tmp_path: Path) -> None:
    """Open index.html in headless Chromium: every image loads, no errors, not blank."""
    page = (report / "report.html").read_text(encoding="utf-8")
    probe = tmp_path / "probe.html"  # a copy with the probe: the report itself stays script-free
    probe.write_text(page.replace("<head>", "<head>" + _PROBE, 1), encoding="utf-8")
    dom = _chrome(["--virtual-time-budget=10000", "--dump-dom", probe.as_uri()], tmp_path)
    m = re.search(r"PROBE images=(\d+) loaded=(\d+) errors=(\d+)(.*?)END", dom.stdout, re.S)
    assert m, f"the page did not finish loading: {dom.stderr[-2000:]}"
    images, loaded, errors = int(m[1]), int(m[2]), int(m[3])
    assert images > 0 and loaded == images, f"{loaded} of {images} images loaded"
    assert errors == 0, m[4]
    shot = tmp_path / "screenshot.png"
    _chrome(["--window-size=1280,2000", "--hide-scrollbars", f"--screenshot={shot}",
             (report / "report.html").as_uri()], tmp_path)
    assert shot.exists(), "no screenshot"
    import numpy as np
    from matplotlib.image import imread

    img = imread(shot)[..., :3]
    gray = img.mean(axis=2)
    assert float(np.mean(gray < 0.9)) > 0.01, "the screenshot is blank"
    assert float(gray.std()) > 0.05, "the screenshot has no contrast"


def test_html_in_browser(small_report, tmp_path):
    check_in_browser(small_report, tmp_path)


# ------------------------------------------------------------------ the demo, end to end
def test_demo_end_to_end(demo_report, tmp_path):
    """`mtplan demo` on the shipped study: the whole chain, and the documents a customer
    receives: the overall result after the cover, a verdict for every toleranced measurand,
    a report body of at most 12 pages, embedded fonts, bookmarks, whole header words."""
    import pandas as pd

    from tests.reports.test_document import (
        assert_fonts_embedded,
        assert_has_outline,
        pdf_pages,
    )

    report, out = demo_report
    for name in ("plan.pdf", "plan.html", "plan.json", "report.pdf", "report.html"):
        assert str(report / name) in out, name
    pdf = report / "report.pdf"
    text = _pdftotext(pdf)
    for title in ["C axis location", "21 geometric errors", "Bore centre", "line-laser",
                  "laser tracker", "Provenance", "Measured data", "Results as found"]:
        assert title in text, title
    pages = pdf_pages(pdf)
    first = " ".join(pages[:2]).replace(WATERMARK, "").split("Contents")[0]
    assert "Overall result and actions" in first, first[:200]
    verdicts = pd.read_csv(report / "results" / "verdicts.csv")
    summary = pd.read_csv(report / "results" / "summary.csv")
    procedures = ["rotary_axis", "geometry21", "circle_centre", "line_laser", "tracker_frame"]
    assert set(verdicts["procedure"]) == set(procedures)  # >= 1 toleranced measurand each
    assert set(summary["procedure"]) == set(procedures)
    decided = {"pass", "conditional pass", "conditional fail", "fail", "not determinable"}
    assert set(verdicts["verdict"]) <= decided
    for name in verdicts["measurand"]:  # every toleranced measurand in the results
        assert f"({name})" in " ".join(text.split()), name
    appendix = next(i for i, p in enumerate(pages) if re.search(r"^\s*A1\. ", p, re.M))
    assert appendix <= 12, f"the report's body has {appendix} pages"
    assert_fonts_embedded(pdf)
    assert_has_outline(pdf, ["Overall result and actions", "Results as found", "Provenance"])
    _pages_non_blank(pdf, tmp_path / "report")
    _pages_non_blank(report / "plan.pdf", tmp_path / "plan")
    check_in_browser(report, tmp_path)
