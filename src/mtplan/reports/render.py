"""Renderers of the document model: HTML (jinja2) and PDF (reportlab platypus).

The PDF embeds its fonts (the DejaVu TrueType family that matplotlib ships), has a
bookmark per section, never breaks a word inside a table header (columns are at
least as wide as their header's longest word) and right-aligns numeric columns.
"""

from __future__ import annotations

import base64
import functools
import io
from pathlib import Path
from xml.sax.saxutils import escape

from mtplan._io import atomic_write, output_problem
from mtplan._validate import InvalidInput
from mtplan.plans.agreement import FIT_NO_DECISION, LARGER_U_NO_DECISION, NO_INSTRUMENT
from mtplan.plans.conditions import NO_CONDITION
from mtplan.reports.model import Document, Figure, Section, Table
from mtplan.reports.wording import VERDICT_SHORT

__all__ = ["render_html", "render_pdf", "write_report", "column_widths", "VERDICT_CLASS"]

_DPI = 140  # the figures' dpi (figures._figure)
_FONT = "DejaVuSans"
_SIZE = 7.5  # table text [pt]
_PAD = 3.0   # table cell padding, each side [pt]
#: verdict -> the class (HTML) and colour (PDF) it is shown in
VERDICT_CLASS = {"pass": "ok", "fail": "bad", "conditional pass": "warn",
                 "conditional fail": "warn", "not determinable": "nd",
                 FIT_NO_DECISION: "warn", NO_INSTRUMENT: "nd", LARGER_U_NO_DECISION: "warn",
                 NO_CONDITION: "nd",
                 "not measured": "nd"}
VERDICT_CLASS.update({short: VERDICT_CLASS[full] for full, short in VERDICT_SHORT.items()})
_VERDICT_COLOUR = {"ok": "#1b5e20", "bad": "#b3261e", "warn": "#8a5a00", "nd": "#555555"}


def render_html(doc: Document) -> str:
    """The report as one self-contained HTML page (user text escaped)."""
    import jinja2

    env = jinja2.Environment(
        loader=jinja2.PackageLoader("mtplan.reports", "templates"),
        autoescape=jinja2.select_autoescape(default=True, default_for_string=True),
        undefined=jinja2.StrictUndefined,
    )
    env.filters["b64"] = lambda data: base64.b64encode(data).decode("ascii")
    env.globals["verdict_class"] = VERDICT_CLASS
    return env.get_template("report.html.j2").render(doc=doc)


# ----------------------------------------------------------------------- PDF: fonts, styles
def _register_fonts() -> str:
    """Register the DejaVu Sans family with reportlab once; returns its name."""
    from reportlab.lib.fonts import addMapping
    from reportlab.pdfbase import pdfmetrics
    from reportlab.pdfbase.ttfonts import TTFont

    if _FONT in pdfmetrics.getRegisteredFontNames():
        return _FONT
    import matplotlib

    folder = Path(matplotlib.get_data_path()) / "fonts" / "ttf"
    faces = {"": "DejaVuSans.ttf", "-Bold": "DejaVuSans-Bold.ttf",
             "-Oblique": "DejaVuSans-Oblique.ttf", "-BoldOblique": "DejaVuSans-BoldOblique.ttf"}
    for suffix, file in faces.items():
        pdfmetrics.registerFont(TTFont(_FONT + suffix, str(folder / file)))
    for bold, italic, suffix in ((0, 0, ""), (1, 0, "-Bold"), (0, 1, "-Oblique"),
                                 (1, 1, "-BoldOblique")):
        addMapping(_FONT, bold, italic, _FONT + suffix)
    return _FONT


def _styles() -> dict:
    from reportlab.lib import colors
    from reportlab.lib.styles import ParagraphStyle

    f = _register_fonts()
    blue, grey = colors.HexColor("#1f5fa8"), colors.HexColor("#444444")
    body = ParagraphStyle("Body", fontName=f, fontSize=9.5, leading=12.5, spaceAfter=5)
    small = ParagraphStyle("Small", parent=body, fontSize=_SIZE, leading=9.2, spaceAfter=0)
    return {
        "title": ParagraphStyle("Title", fontName=f + "-Bold", fontSize=22, leading=28,
                                textColor=blue, spaceAfter=8),
        "subtitle": ParagraphStyle("Subtitle", parent=body, fontSize=11.5, leading=15,
                                   textColor=grey, spaceAfter=14),
        "h1": ParagraphStyle("H1", fontName=f + "-Bold", fontSize=15, leading=19,
                             textColor=blue, spaceBefore=2, spaceAfter=8, keepWithNext=1),
        "h2": ParagraphStyle("H2", fontName=f + "-Bold", fontSize=11.5, leading=15,
                             textColor=colors.HexColor("#333333"), spaceBefore=8,
                             spaceAfter=4, keepWithNext=1),
        "toc_head": ParagraphStyle("TOCHead", fontName=f + "-Bold", fontSize=15, leading=19,
                                   textColor=blue, spaceAfter=8),
        "body": body,
        "item": ParagraphStyle("Item", parent=body, fontSize=8.8, leading=11.2, spaceAfter=2),
        "small": small,
        "head": ParagraphStyle("Head", parent=small, fontName=f + "-Bold", splitLongWords=0),
        "num": ParagraphStyle("Num", parent=small, alignment=2),
        "head_num": ParagraphStyle("HeadNum", parent=small, fontName=f + "-Bold",
                                   splitLongWords=0, alignment=2),
        "caption": ParagraphStyle("Caption", parent=body, fontName=f + "-Oblique",
                                  fontSize=8, leading=10, textColor=grey, spaceAfter=2),
        "end": ParagraphStyle("End", parent=body, alignment=1, spaceBefore=18),
        "toc": [ParagraphStyle("TOC1", fontName=f, fontSize=10, leading=14, leftIndent=10),
                ParagraphStyle("TOC2", fontName=f, fontSize=8.5, leading=11, leftIndent=26)],
    }


# ----------------------------------------------------------------------- PDF: tables
def column_widths(t: Table, width: float, size: float = _SIZE) -> list:
    """Column widths [pt] for a table ``width`` wide at font ``size`` [pt]: never narrower
    than the header's longest word (so no header word is broken) nor than the longest word
    of the cells (up to 80 pt, or 70 % of the width in a two-column table: paths and
    digests stay whole there), nor, for numeric columns, than their widest number; the
    table's ``grow`` column (a long name) then gets the spare width it can use first; the
    rest of the width shared by how much text each column holds. The widths may add up to
    more than ``width`` when the words do not fit (see :func:`_table_size`)."""
    least, want = _column_needs(t, size, 0.7 * width if len(t.header) <= 2 else 80.0)
    spare = width - sum(least)
    if spare <= 0:
        return least
    if t.grow is not None and want[t.grow] > least[t.grow]:  # this column first
        g = t.grow
        more = min(spare, want[g] - least[g])
        least = [w + more if j == g else w for j, w in enumerate(least)]
        spare -= more
        if spare <= 0:
            return least
    extra = [w - lo for w, lo in zip(want, least, strict=True)]
    if sum(extra) <= spare:  # everything fits on one line: share the rest by text
        return [w + (width - sum(want)) * w / sum(want) for w in want]
    return [lo + spare * e / sum(extra) for lo, e in zip(least, extra, strict=True)]


def _column_needs(t: Table, size: float, cap: float) -> tuple[list, list]:
    """(least, wanted) width of each column [pt]."""
    from reportlab.pdfbase.pdfmetrics import stringWidth

    f = _register_fonts()
    pad = 2 * _PAD + 1
    least, want = [], []
    for j, (head, numeric) in enumerate(zip(t.header, t.numeric, strict=True)):
        words = str(head).split() or [""]
        w_head = max(stringWidth(w, f + "-Bold", size) for w in words)
        if len(str(head)) <= 10:  # short headers stay on one line
            w_head = stringWidth(str(head), f + "-Bold", size)
        cells = [str(r[j]) for r in t.rows]
        w_cells = [stringWidth(c, f, size) for c in cells] or [0.0]
        w_word = max([min(stringWidth(w, f + "-Bold", size), cap)
                      for c in cells for w in c.split()] or [0.0])
        low = max(w_head, w_word) + pad
        if numeric:
            low = max(low, max(w_cells) + pad)
        if j in t.whole:  # bold where it is a verdict
            low = max([low] + [stringWidth(c, f + "-Bold", size) + pad for c in cells])
        least.append(low)
        want.append(max(low, min(max(w_cells), 330.0) + pad))
    return least, want


def _table_size(t: Table, width: float) -> float:
    """The table's font size [pt]: 7.5, or smaller (down to 5.5) until its words fit."""
    cap = 0.7 * width if len(t.header) <= 2 else 80.0
    for size in (_SIZE, 7.0, 6.5, 6.0, 5.5):
        if t.size is not None and size > t.size:
            continue
        if sum(_column_needs(t, size, cap)[0]) <= width:
            return size
    return 5.5


def _cell(text, style):
    from reportlab.platypus import Paragraph

    cls = VERDICT_CLASS.get(str(text))
    shown = escape(str(text))
    if cls:
        shown = f'<font color="{_VERDICT_COLOUR[cls]}"><b>{shown}</b></font>'
    return Paragraph(shown, style)


def _table_flowables(t: Table, width: float, st: dict, row_height: float | None = None) -> list:
    from reportlab.lib import colors
    from reportlab.lib.styles import ParagraphStyle
    from reportlab.platypus import KeepTogether, Paragraph, Spacer
    from reportlab.platypus import Table as RLTable
    from reportlab.platypus import TableStyle

    numeric = t.numeric
    size = _table_size(t, width)
    sized = {k: ParagraphStyle(f"{st[k].name}{size}", parent=st[k], fontSize=size,
                               leading=size * 1.23) for k in ("head", "head_num", "num", "small")}
    data = [[Paragraph(f"{escape(str(h))}", sized["head_num"] if numeric[j] else sized["head"])
             for j, h in enumerate(t.header)]]
    data += [[_cell(c, sized["num"] if numeric[j] else sized["small"]) for j, c in enumerate(row)]
             for row in t.rows]
    heights = None if row_height is None else [None] + [row_height] * len(t.rows)
    tbl = RLTable(data, repeatRows=1, colWidths=column_widths(t, width, size), hAlign="LEFT",
                  rowHeights=heights)
    tbl.setStyle(TableStyle([
        ("FONT", (0, 0), (-1, -1), _FONT, size),
        ("GRID", (0, 0), (-1, -1), 0.3, colors.HexColor("#cfd6e3")),
        ("BACKGROUND", (0, 0), (-1, 0), colors.HexColor("#eef2f8")),
        ("ROWBACKGROUNDS", (0, 1), (-1, -1), [colors.white, colors.HexColor("#f8f9fc")]),
        ("VALIGN", (0, 0), (-1, -1), "TOP"),
        ("LEFTPADDING", (0, 0), (-1, -1), _PAD), ("RIGHTPADDING", (0, 0), (-1, -1), _PAD),
        ("TOPPADDING", (0, 0), (-1, -1), 1.5), ("BOTTOMPADDING", (0, 0), (-1, -1), 1.5),
    ]))
    head = [Paragraph(escape(t.caption), st["caption"]), tbl]
    if len(t.rows) <= 8 or t.keep:  # not split from its caption or over two pages
        return [KeepTogether(head), Spacer(1, 8)]
    return head + [Spacer(1, 8)]


def _figure_flowables(f: Figure, width: float, st: dict) -> list:
    from reportlab.lib.units import cm
    from reportlab.lib.utils import ImageReader
    from reportlab.platypus import KeepTogether, Paragraph, Spacer

    w, h = ImageReader(io.BytesIO(f.png)).getSize()
    natural = 72.0 / _DPI  # points per pixel at the figure's own size
    scale = min(natural * 1.05, width / w, 16.5 * cm / h)
    img = _laid_out_first()(io.BytesIO(f.png), width=w * scale, height=h * scale)
    return [KeepTogether([img, Paragraph(escape(f.caption), st["caption"]), Spacer(1, 8)])]


@functools.lru_cache(maxsize=1)
def _laid_out_first():
    """reportlab's Image, not drawn on the first of a document's passes: that pass only
    lays the pages out (the contents' page numbers come from it) and its canvas is thrown
    away, so decoding and compressing each figure there was a quarter of a PDF's time."""
    from reportlab.platypus import Image

    class LaidOutFirst(Image):
        def draw(self):
            if getattr(getattr(self.canv, "_doctemplate", None), "passes", 2) > 1:
                super().draw()

    return LaidOutFirst


def _block_flowables(items, width: float, st: dict) -> list:
    from reportlab.platypus import KeepTogether, ListFlowable, ListItem, Paragraph

    out = []
    for b in items:
        if isinstance(b, str):
            out.append(Paragraph(escape(b), st["body"]))
        elif isinstance(b, list):
            out.append(ListFlowable([ListItem(Paragraph(escape(str(x)), st["item"]),
                                              leftIndent=12) for x in b],
                                    bulletType="bullet", start="\u2022", leftIndent=12,
                                    bulletFontName=_FONT))
        elif isinstance(b, Table):
            out += _table_flowables(b, width, st)
        elif isinstance(b, Figure):
            out += _figure_flowables(b, width, st)
        elif isinstance(b, Section):  # the heading stays with what follows it
            inner = _block_flowables(b.blocks, width, st)
            out.append(KeepTogether([Paragraph(escape(b.title), st["h2"])] + inner[:2]))
            out += inner[2:]
    return out


# ----------------------------------------------------------------------- PDF: pages
def _cover_flowables(doc: Document, width: float, st: dict) -> list:
    """Title, the header table, the methods and standards per test, the statement and the
    sign-off block."""
    from reportlab.lib.units import cm
    from reportlab.platypus import Paragraph, Spacer

    out = [Spacer(1, 0.6 * cm), Paragraph(escape(doc.title), st["title"])]
    if doc.subtitle:
        out.append(Paragraph(escape(doc.subtitle), st["subtitle"]))
    if doc.box:
        out.append(_box_flowable(doc.box, width, st, doc.box_title))
    rows = [[k, v] for k, v in doc.meta.items()]
    out += _table_flowables(Table(doc.title.split(" (")[0], ["item", "value"], rows), width, st)
    methods = []
    if doc.methods:
        methods += _table_flowables(Table("Methods: the source method of each test and the "
                                          "standards applied", ["test", "method", "standards"],
                                          [list(r) for r in doc.methods]), width, st)
    if doc.standards:
        methods += _table_flowables(Table("Standards applied", ["test", "standards"],
                                          [list(r) for r in doc.standards]), width, st)
    if not doc.box:  # a boxed result takes the room: the sign-off stays on page 1
        out += methods
    if doc.statement:
        out.append(Paragraph(escape(doc.statement), st["body"]))
    sign = [[role, name or "", "", ""] for role, name in doc.signoff]
    out += _table_flowables(Table("Sign-off", ["", "name", "date", "signature"], sign),
                            width, st, row_height=0.9 * cm)
    if doc.box:
        out += methods
    out.append(Paragraph(
        f"Uncertainty evaluated after JCGM 101 (GUM Supplement 1) with mtplan "
        f"{escape(doc.provenance['versions'].get('mtplan', ''))}; every number can be "
        f"reproduced from {escape(doc.inputs)} named in the provenance (a record of the "
        "calculation, not metrological traceability, which the instruments' certificates "
        "carry).",
        st["caption"]))
    return out


def _box_flowable(lines, width: float, st: dict, title: str = "Overall result"):
    """The lines of the overall result (or the plan's warnings) in a framed box (page 1)."""
    from reportlab.platypus import Paragraph
    from reportlab.platypus import Table as RLTable

    cells = [[Paragraph(f"<b>{escape(title)}</b>", st["body"])]]
    cells += [[Paragraph(f"<b>{escape(line)}</b>", st["body"])] for line in lines]
    box = RLTable(cells, colWidths=[width])
    box.setStyle([("FONT", (0, 0), (-1, -1), _FONT, 9),
                  ("BOX", (0, 0), (-1, -1), 1.4, "#222222"),
                  ("BACKGROUND", (0, 0), (-1, -1), "#f3f3f3"),
                  ("TOPPADDING", (0, 0), (-1, -1), 2), ("BOTTOMPADDING", (0, 0), (-1, -1), 2)])
    box.spaceAfter = 8
    return box


def _doc_template(buf, doc: Document):
    from reportlab.lib.pagesizes import A4
    from reportlab.lib.units import cm
    from reportlab.platypus import Paragraph, SimpleDocTemplate

    class _Doc(SimpleDocTemplate):
        passes = 0  # the passes begun (:func:`_laid_out_first` draws from the second on)

        def build(self, *args, **kwargs):
            self.passes += 1
            super().build(*args, **kwargs)

        def afterFlowable(self, flowable):
            if not isinstance(flowable, Paragraph):
                return
            name = flowable.style.name
            if name not in ("H1", "H2", "TOCHead", "Title"):
                return
            level = 1 if name == "H2" else 0
            text = flowable.getPlainText()
            key = f"h{id(flowable)}"
            self.canv.bookmarkPage(key)
            self.canv.addOutlineEntry(text, key, level=level, closed=level > 0)
            if name in ("H1", "H2"):
                self.notify("TOCEntry", (level, escape(text), self.page, key))

    return _Doc(buf, pagesize=A4, leftMargin=2 * cm, rightMargin=2 * cm, topMargin=1.8 * cm,
                bottomMargin=2 * cm, title=doc.title, author="mtplan",
                subject=doc.subtitle, creator="mtplan", initialFontName=_FONT,
                pageCompression=1)


def _canvas_maker(doc: Document):
    """A canvas that knows the page count: every page gets the document's identification,
    "page x of N" and, for simulated readings, the watermark."""
    from reportlab.lib import colors
    from reportlab.lib.pagesizes import A4
    from reportlab.lib.units import cm
    from reportlab.pdfgen.canvas import Canvas

    ident = doc.identification or " - ".join(
        x for x in (doc.meta.get("document number", ""), doc.title) if x)

    class _Numbered(Canvas):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            self._pages = []

        def showPage(self):  # noqa: N802 - reportlab's name
            self._pages.append(dict(self.__dict__))
            self._startPage()

        def save(self):
            total = len(self._pages)
            for state in self._pages:
                self.__dict__.update(state)
                self._decorate(total)
                super().showPage()
            super().save()

        def _decorate(self, total):
            self.saveState()
            self.setFont(_FONT, 7)
            self.setFillColor(colors.HexColor("#555555"))
            self.drawString(2 * cm, 1.2 * cm, ident[:100])
            self.drawRightString(A4[0] - 2 * cm, 1.2 * cm,
                                 f"page {self._pageNumber} of {total}")
            if doc.watermark:  # a band across the top of every page (text, so it is read)
                self.setFillColor(colors.Color(0.70, 0.15, 0.12, alpha=0.10))
                self.rect(0, A4[1] - 1.35 * cm, A4[0], 0.75 * cm, stroke=0, fill=1)
                self.setFillColor(colors.HexColor("#b3261e"))
                self.setFont(_FONT + "-Bold", 11)
                self.drawCentredString(A4[0] / 2, A4[1] - 1.1 * cm, doc.watermark)
            self.restoreState()

    return _Numbered


def render_pdf(doc: Document) -> bytes:
    """The report as a PDF: cover, summary, contents, body, appendix."""
    from reportlab import rl_config
    from reportlab.lib.pagesizes import A4
    from reportlab.lib.units import cm
    from reportlab.platypus import CondPageBreak, PageBreak, Paragraph, Spacer, TableStyle
    from reportlab.platypus.tableofcontents import TableOfContents

    st = _styles()
    width = A4[0] - 4 * cm - 12  # the frame pads 6 pt on each side
    # a report flows on after its cover's methods (no half-empty page 2)
    story = _cover_flowables(doc, width, st) + [Spacer(1, 14) if doc.flow else PageBreak()]
    toc = TableOfContents()
    toc.levelStyles = st["toc"]
    toc.tableStyle = TableStyle([("FONT", (0, 0), (-1, -1), _FONT, 9),
                                 ("VALIGN", (0, 0), (-1, -1), "TOP"),
                                 ("RIGHTPADDING", (0, 0), (-1, -1), 0),
                                 ("LEFTPADDING", (0, 0), (-1, -1), 0)])
    body, appendix = doc.body, doc.appendix

    def headed(sec) -> list:  # a heading never ends a page: it is kept with what follows
        from reportlab.platypus import KeepTogether

        blocks = _block_flowables(sec.blocks, width, st)
        return [KeepTogether([Paragraph(escape(sec.title), st["h1"])] + blocks[:1])] + \
            blocks[1:]

    # a section starts a new page unless the page it ends on is less than a third full:
    # no page under a third full but the last of a section
    new_page = CondPageBreak((A4[1] - 3.8 * cm - 12) * 2 / 3)
    for i, sec in enumerate(body):
        story += headed(sec)
        if i == 0 and doc.flow:  # the summary first, then the contents, flowing on
            # the contents whole on one page (a report's take about 13 cm)
            story += [Spacer(1, 14), CondPageBreak(15 * cm),
                      Paragraph("Contents", st["toc_head"]), toc, Spacer(1, 14)]
        elif i == 0:
            story += [new_page, Paragraph("Contents", st["toc_head"]), toc, PageBreak()]
        elif not doc.flow or i == len(body) - 1:
            story.append(new_page)
        else:
            pass  # the next heading's own space before it (a spacer at a page's foot made a blank page)
    for i, sec in enumerate(appendix):
        story += headed(sec)
        if i < len(appendix) - 1:
            story.append(new_page)
    if doc.end_mark:
        story.append(Paragraph(f"<b>\u2014 {escape(doc.end_mark)} \u2014</b>", st["end"]))
    buf = io.BytesIO()
    pdf = _doc_template(buf, doc)
    # binary Flate streams, not ASCII85 text ones: reportlab's pure-Python ASCII85 encoder
    # took half the rendering time of a PDF with figures (each is encoded on every pass)
    a85, rl_config.useA85 = rl_config.useA85, 0
    try:
        if pdf.multiBuild(story, canvasmaker=_canvas_maker(doc)) == 1:
            # laid out in one pass (no contents to number): again, with the figures
            buf.seek(0)
            buf.truncate()
            pdf = _doc_template(buf, doc)
            pdf.passes = 1
            pdf.multiBuild(story, canvasmaker=_canvas_maker(doc))
    finally:
        rl_config.useA85 = a85
    return buf.getvalue()


def _write_doc(doc: Document, out: Path, name: str) -> dict:
    html = render_html(doc)
    pdf = render_pdf(doc)
    written = {}
    for csv_name, frame in doc.csv.items():
        path = out / "results" / f"{csv_name}.csv"
        with atomic_write(path, "w", encoding="utf-8", newline="") as fh:
            frame.to_csv(fh, index=False)
        written[csv_name] = path
    with atomic_write(out / f"{name}.pdf", "wb") as fh:
        fh.write(pdf)
    with atomic_write(out / f"{name}.html", "w", encoding="utf-8") as fh:
        fh.write(html)
    written[f"{name}_pdf"] = out / f"{name}.pdf"
    written[f"{name}_html"] = out / f"{name}.html"
    return written


def write_report(result, out_dir, plan=None, *, plan_only: bool = False,
                 n_jobs: int = 1) -> dict:
    """Write the test plan and the test report of a computed study.

    Without ``plan`` the plan is issued from ``result`` (``plan.json``, ``plan.pdf``,
    ``plan.html``, the planning study's ``results/*.csv``) and, unless ``plan_only``, the
    report decided with it (``report.pdf``, ``report.html``, ``results/verdicts.csv``,
    ``results/measured.csv``), saying that both came from the same run. With ``plan`` (a
    dict from :func:`mtplan.plans.agreement.read_plan`, already checked against the study)
    only the report is written. Every file is written to a temporary name and renamed into
    place, so an interrupted report leaves no half-written file. With ``n_jobs`` > 1 the
    plan's figures and the report are drawn on that many processes at once (the same
    documents as one after the other; see :func:`_write_both`). Returns the paths written
    (``pdf``/``html``: the last document written).
    """
    import json

    from mtplan.plans import agreement
    from mtplan.reports.certificate import build_plan, build_report

    out = Path(out_dir)
    for path in (out, out / "results"):
        problem = output_problem(path, folder=True)
        if problem:
            raise InvalidInput([f"The report folder cannot be written: {problem}."])
    written, deviations = {}, []
    if not plan_only:  # a late plan is refused before anything is written
        dated = plan if plan is not None else agreement.issue_plan(result)
        if plan is not None or result.study.header.get("plan_date"):
            deviations += agreement.check_dates(result.study, dated)
    if plan is None and not plan_only and n_jobs != 1:
        return _write_both(result, out, agreement.issue_plan(result), n_jobs, deviations)
    if plan is None:
        plan = agreement.issue_plan(result)
        plan_doc = build_plan(result, plan)
        written.update(_write_doc(plan_doc, out, "plan"))
        with atomic_write(out / "plan.json", "w", encoding="utf-8") as fh:
            json.dump(plan, fh, indent=1)
        written["plan_json"] = out / "plan.json"
        written["pdf"], written["html"] = written["plan_pdf"], written["plan_html"]
        if plan_only:
            return written
        deviations.insert(0, _same_run(plan))
    deviations += agreement.apply_plan(result, plan)
    written.update(_write_doc(build_report(result, plan, deviations), out, "report"))
    written["pdf"], written["html"] = written["report_pdf"], written["report_html"]
    return written


def _same_run(plan) -> str:
    return (f"The test plan {plan['document']} was issued in the same run as this report, not "
            "agreed before the test.")


def _document(result, plan, out: Path, kind: str, dated=()) -> dict:
    """Build, render and write the plan (``kind`` "plan") or the report decided with it
    (``dated``: the deviations of the plan's date, :func:`~mtplan.plans.agreement.
    check_dates`)."""
    from mtplan.plans import agreement
    from mtplan.reports.certificate import build_plan, build_report

    if kind == "plan":
        return _write_doc(build_plan(result, plan), out, "plan")
    deviations = [_same_run(plan), *dated] + agreement.apply_plan(result, plan)
    return _write_doc(build_report(result, plan, deviations), out, "report")


def _write_both(result, out: Path, plan: dict, n_jobs: int, dated=()) -> dict:
    """The plan and the report of one run, drawn on ``n_jobs`` worker processes: the whole
    report is a task (its process decides its own copy of ``result`` with the plan, as the
    serial path does after the plan was written), each test's part of the plan (its
    figures: most of the work) another, unless the study drew them already as each test
    was complete (``result.then``: :data:`mtplan.reports.certificate.PLAN_PARTS` given to
    :func:`mtplan.plans.study.run_study`); the plan is put together and rendered here as
    the report is still being drawn; ``result`` is then decided here too. The same files as
    the serial path: every figure and table is drawn from the same data."""
    import json
    from concurrent.futures import wait

    from mtplan._parallel import effective_jobs, stage_executor
    from mtplan.plans import agreement
    from mtplan.reports.certificate import build_plan, plan_parts

    with atomic_write(out / "plan.json", "w", encoding="utf-8") as fh:
        json.dump(plan, fh, indent=1)
    # the pool the study ran on, when it ran here: its workers are started already
    executor = stage_executor(max(effective_jobs(n_jobs), 2))
    report = executor.submit(_document, result, plan, out, "report",  # the longest task
                             list(dated))
    if result.then is not None:  # drawn on the study's workers as each test was complete
        parts = result.then
    else:
        futures = [executor.submit(plan_parts, k, o)
                   for k, o in enumerate(result.outcomes, start=1)]
        wait(futures)
        parts = [f.result() for f in futures]
    plan_files = _write_doc(build_plan(result, plan, parts), out, "plan")
    report_files = report.result()
    agreement.apply_plan(result, plan)
    written = {**plan_files, **report_files, "plan_json": out / "plan.json"}
    written["pdf"], written["html"] = written["report_pdf"], written["report_html"]
    return written
