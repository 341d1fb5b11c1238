"""Reports: HTML and PDF documents of a computed study, with figures.

Reports read result objects; they never compute. :func:`write_report` writes
``index.html`` (self-contained: figures embedded, no external scripts, styles or
fonts), ``report.pdf`` (the same content as a document with title page, contents,
tables and captioned figures) and ``results/*.csv``, each file atomically.
"""

from mtplan.reports.render import render_html, render_pdf, write_report

__all__ = ["render_html", "render_pdf", "write_report"]
