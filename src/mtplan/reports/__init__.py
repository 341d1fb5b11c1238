"""Reports: HTML and PDF documents of a computed study, with figures.

Reports read result objects; they never compute. :func:`write_report` writes the test
plan (``plan.pdf``, ``plan.html``, ``plan.json``) and the test report decided with it
(``report.pdf``, ``report.html``), each HTML self-contained (figures embedded, no external
scripts, styles or fonts), and ``results/*.csv``, each file atomically.
"""

from mtplan.reports.render import render_html, render_pdf, write_report

__all__ = ["render_html", "render_pdf", "write_report"]
