"""Renderers of the document model: HTML (jinja2) and PDF (reportlab platypus)."""

from __future__ import annotations

import base64
import io
from pathlib import Path

from mtplan._io import atomic_write, output_problem
from mtplan._validate import InvalidInput
from mtplan.reports.document import Document, Figure, Section, Table, build_document

__all__ = ["render_html", "render_pdf", "write_report"]

_NUMERIC = __import__("re").compile(r"^[\[(]?[-+]?(\d|\.\d)[\d.,eE+\- ]*[\])%]?( %)?$")
_DPI = 140  # the figures' dpi (figures._figure)


def render_html(doc: Document) -> str:
    """The report as one self-contained HTML page (user text escaped)."""
    import jinja2

    env = jinja2.Environment(
        loader=jinja2.PackageLoader("mtplan.reports", "templates"),
        autoescape=jinja2.select_autoescape(default=True, default_for_string=True),
        undefined=jinja2.StrictUndefined,
    )
    env.filters["b64"] = lambda data: base64.b64encode(data).decode("ascii")
    return env.get_template("report.html.j2").render(doc=doc)


def render_pdf(doc: Document) -> bytes:
    """The report as a PDF: title page, contents, sections, tables, captioned figures."""
    from reportlab.lib import colors
    from reportlab.lib.pagesizes import A4
    from reportlab.lib.styles import ParagraphStyle, getSampleStyleSheet
    from reportlab.lib.units import cm
    from reportlab.platypus import (
        Image,
        ListFlowable,
        ListItem,
        KeepTogether,
        PageBreak,
        Paragraph,
        SimpleDocTemplate,
        Spacer,
    )
    from reportlab.platypus import Table as RLTable
    from reportlab.platypus import TableStyle
    from reportlab.platypus.tableofcontents import TableOfContents
    from xml.sax.saxutils import escape

    styles = getSampleStyleSheet()
    h1 = ParagraphStyle("H1", parent=styles["Heading1"], textColor=colors.HexColor("#1f5fa8"))
    h2 = ParagraphStyle("H2", parent=styles["Heading2"], textColor=colors.HexColor("#333333"))
    body = styles["BodyText"]
    small = ParagraphStyle("Small", parent=body, fontSize=7.5, leading=9)
    caption = ParagraphStyle("Caption", parent=body, fontSize=8, leading=10,
                             textColor=colors.HexColor("#444444"), fontName="Helvetica-Oblique")

    class _Doc(SimpleDocTemplate):
        def afterFlowable(self, flowable):
            if isinstance(flowable, Paragraph) and flowable.style.name in ("H1", "H2"):
                level = 0 if flowable.style.name == "H1" else 1
                text = flowable.getPlainText()
                key = f"h{id(flowable)}"
                self.canv.bookmarkPage(key)
                self.notify("TOCEntry", (level, escape(text), self.page, key))

    def page_footer(canvas, _doc):
        canvas.saveState()
        canvas.setFont("Helvetica", 7)
        canvas.setFillColor(colors.HexColor("#666666"))
        canvas.drawString(2 * cm, 1.2 * cm, f"{doc.title} - mtplan "
                          f"{doc.provenance['versions'].get('mtplan', '')} - study "
                          f"{doc.provenance['study_sha256']}")
        canvas.drawRightString(A4[0] - 2 * cm, 1.2 * cm, f"page {_doc.page}")
        canvas.restoreState()

    width = A4[0] - 4 * cm
    story = [Spacer(1, 6 * cm),
             Paragraph(escape(doc.title), ParagraphStyle("T", parent=styles["Title"], fontSize=24,
                                                         leading=30)),
             Spacer(1, 0.5 * cm)]
    if doc.subtitle:
        story.append(Paragraph(escape(doc.subtitle), styles["Heading3"]))
    for k, v in doc.meta.items():
        if k != "subtitle":
            story.append(Paragraph(f"{escape(k)}: {escape(v)}", body))
    story += [Spacer(1, 1 * cm), Paragraph(f"{escape(doc.provenance['date'])}", body),
              Paragraph("Uncertainty evaluated after JCGM 101 (GUM Supplement 1) with mtplan.",
                        body), PageBreak()]
    toc = TableOfContents()
    toc.levelStyles = [ParagraphStyle("TOC1", fontSize=10, leading=14, leftIndent=10),
                       ParagraphStyle("TOC2", fontSize=9, leading=12, leftIndent=24)]
    story += [Paragraph("Contents", styles["Heading1"]), toc, PageBreak()]

    num_style = ParagraphStyle("Num", parent=small, alignment=2)  # right-aligned

    def is_num(c) -> bool:
        return isinstance(c, str) and bool(_NUMERIC.match(c))

    def table_flowable(t: Table):
        ncol = len(t.header)
        numeric = [bool(t.rows) and all(is_num(r[j]) or r[j] in ("-", "") for r in t.rows)
                   for j in range(ncol)]
        # column widths from the longest entry (capped), scaled to the frame
        longest = [max([len(str(t.header[j]))] + [len(str(r[j])) for r in t.rows])
                   for j in range(ncol)]
        weights = [min(max(n, 4), 60) for n in longest]
        total = sum(weights)
        widths = [width * w / total for w in weights]
        data = [[Paragraph(f"<b>{escape(str(h))}</b>", num_style if numeric[j] else small)
                 for j, h in enumerate(t.header)]]
        data += [[Paragraph(escape(str(c)), num_style if numeric[j] else small)
                  for j, c in enumerate(row)] for row in t.rows]
        tbl = RLTable(data, repeatRows=1, colWidths=widths, hAlign="LEFT")
        tbl.setStyle(TableStyle([
            ("GRID", (0, 0), (-1, -1), 0.3, colors.HexColor("#cfd6e3")),
            ("BACKGROUND", (0, 0), (-1, 0), colors.HexColor("#eef2f8")),
            ("ROWBACKGROUNDS", (0, 1), (-1, -1), [colors.white, colors.HexColor("#f8f9fc")]),
            ("VALIGN", (0, 0), (-1, -1), "TOP"),
            ("LEFTPADDING", (0, 0), (-1, -1), 3), ("RIGHTPADDING", (0, 0), (-1, -1), 3),
            ("TOPPADDING", (0, 0), (-1, -1), 1.5), ("BOTTOMPADDING", (0, 0), (-1, -1), 1.5),
        ]))
        return [Paragraph(escape(t.caption), caption), Spacer(1, 2), tbl, Spacer(1, 8)]

    def figure_flowable(f: Figure):
        from reportlab.lib.utils import ImageReader

        reader = ImageReader(io.BytesIO(f.png))
        w, h = reader.getSize()
        natural = 72.0 / _DPI  # points per pixel at the figure's own size
        scale = min(natural * 1.1, width / w, 17 * cm / h)
        img = Image(io.BytesIO(f.png), width=w * scale, height=h * scale)
        return [KeepTogether([img, Paragraph(escape(f.caption), caption), Spacer(1, 10)])]

    def blocks(items):
        out = []
        for b in items:
            if isinstance(b, str):
                out.append(Paragraph(escape(b), body))
            elif isinstance(b, list):
                out.append(ListFlowable([ListItem(Paragraph(escape(str(x)), body), leftIndent=12)
                                         for x in b], bulletType="bullet", start="\u2022",
                                        leftIndent=12))
            elif isinstance(b, Table):
                out += table_flowable(b)
            elif isinstance(b, Figure):
                out += figure_flowable(b)
            elif isinstance(b, Section):
                out.append(Paragraph(escape(b.title), h2))
                out += blocks(b.blocks)
        return out

    for i, sec in enumerate(doc.sections):
        if i:
            story.append(PageBreak())
        story.append(Paragraph(escape(sec.title), h1))
        story += blocks(sec.blocks)

    buf = io.BytesIO()
    pdf = _Doc(buf, pagesize=A4, leftMargin=2 * cm, rightMargin=2 * cm, topMargin=2 * cm,
               bottomMargin=2 * cm, title=doc.title, author="mtplan")
    pdf.multiBuild(story, onLaterPages=page_footer)
    return buf.getvalue()


def write_report(result, out_dir) -> dict:
    """Write ``index.html``, ``report.pdf`` and ``results/*.csv`` for a computed study.

    Every file is written to a temporary name and renamed into place, so an
    interrupted report leaves no half-written file. Returns the paths written.
    """
    out = Path(out_dir)
    for path in (out, out / "results"):
        problem = output_problem(path, folder=True)
        if problem:
            raise InvalidInput([f"The report folder cannot be written: {problem}."])
    doc = build_document(result)
    html = render_html(doc)
    pdf = render_pdf(doc)
    written = {}
    for name, frame in doc.csv.items():
        path = out / "results" / f"{name}.csv"
        with atomic_write(path, "w", encoding="utf-8", newline="") as fh:
            frame.to_csv(fh, index=False)
        written[name] = path
    with atomic_write(out / "report.pdf", "wb") as fh:
        fh.write(pdf)
    with atomic_write(out / "index.html", "w", encoding="utf-8") as fh:
        fh.write(html)
    written["pdf"] = out / "report.pdf"
    written["html"] = out / "index.html"
    return written
