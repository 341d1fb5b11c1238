"""The document model: sections of paragraphs, lists, tables and figures.

:mod:`mtplan.reports.document` builds it from a computed study; the renderers
(:mod:`mtplan.reports.render`) draw it as HTML and PDF.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

__all__ = ["Document", "Section", "Table", "Figure"]

_NUMERIC = re.compile(r"^[\[(]?[-+±≤≥]? ?(\d|\.\d)[\d.,eE+\-− ]*[\])%]?( %)?$")
_EMPTY = {"-", "", "n/d"}
_NEGATIVE_ZERO = re.compile(r"^[-−]0(\.0+)?$")


@dataclass
class Table:
    """A table; ``grow``: the column (a long plain name) that gets the PDF's spare width
    first, so it wraps least; ``size``: the largest font size [pt] the PDF may use;
    ``whole``: the columns whose cells are never wrapped (a verdict on one line)."""

    caption: str
    header: list
    rows: list
    grow: int | None = None
    size: float | None = None
    keep: bool = False  # never split over two pages (a glossary: no page of a few rows)
    whole: tuple = ()

    def __post_init__(self):
        # a value that rounds to zero is printed without a sign ("-0.00" reads as negative)
        self.rows = [[c[1:] if isinstance(c, str) and _NEGATIVE_ZERO.match(c) else c
                      for c in row] for row in self.rows]

    @property
    def numeric(self) -> list:
        """Per column: every cell a number (or empty): the renderers right-align it."""
        out = []
        for j in range(len(self.header)):
            cells = [str(r[j]) for r in self.rows]
            out.append(any(c not in _EMPTY for c in cells)
                       and all(c in _EMPTY or _NUMERIC.match(c) for c in cells))
        return out


@dataclass
class Figure:
    caption: str
    png: bytes


@dataclass
class Section:
    title: str
    blocks: list = field(default_factory=list)
    level: int = 1
    anchor: str = ""
    appendix: bool = False


@dataclass
class Document:
    title: str
    subtitle: str
    meta: dict                 # header label -> value, in the cover's order
    provenance: dict
    sections: list
    csv: dict = field(default_factory=dict)  # name -> DataFrame for results/*.csv
    signoff: list = field(default_factory=list)    # (role, name)
    standards: list = field(default_factory=list)  # (test, standards applied)
    methods: list = field(default_factory=list)    # (test, source method, standards)
    identification: str = ""   # the document's unique identification, on every page
    watermark: str = ""        # drawn across every page (simulated readings)
    end_mark: str = ""         # the last line of the document
    statement: str = ""        # the cover's statement (results relate only to ...)
    flow: bool = False         # body sections after the first follow without a page break
    box: list = field(default_factory=list)  # lines boxed on page 1 (the overall result)
    box_title: str = "Overall result"          # the box's heading
    #: what the numbers can be reproduced from (the cover's closing line)
    inputs: str = "the study file, the readings files and the random seed"

    @property
    def body(self) -> list:
        return [s for s in self.sections if not s.appendix]

    @property
    def appendix(self) -> list:
        return [s for s in self.sections if s.appendix]
