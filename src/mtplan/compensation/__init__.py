"""Compensation: the corrections a controller takes, written from measured results with their
uncertainty, and the residual predicted after them.

- :mod:`mtplan.compensation.model`: :class:`Correction` and :func:`correction`, a procedure's
  correction model (:class:`mtplan.models.correction.CorrectionModel`) applied to a result;
- :mod:`mtplan.compensation.formats`: the writers' interface and the predicted residual after
  compensation; :mod:`mtplan.compensation.registry`: the formats by name (entry point group
  ``mtplan.compensation_formats``);
- one module per built-in format: :mod:`~mtplan.compensation.neutral`,
  :mod:`~mtplan.compensation.isg`, :mod:`~mtplan.compensation.fanuc`.
"""

from __future__ import annotations

from mtplan._validate import InvalidInput
from mtplan.compensation.formats import CompensationFormat, FormatOption, Residual, residual
from mtplan.compensation.model import Correction, correction, read_result
from mtplan.compensation.registry import available_formats, get_format
from mtplan.compensation.unseen import unseen_covariance

__all__ = ["Correction", "correction", "read_result", "CompensationFormat", "FormatOption",
           "Residual", "available_formats", "get_format", "residual", "compensate"]


def compensate(result, format: str = "neutral", options=None):
    """The files of `result`'s correction: the neutral table and, for another `format`,
    that format's files too.

    Parameters
    ----------
    result : path or dict
        An ``mtplan estimate --json`` document, or its file.
    format : str
        A name of :func:`available_formats`.
    options : mapping of str to str, optional
        The format's options as texts (``{"offset": "2"}``).

    Returns
    -------
    (files, correction, residual)
        ``{file name: text}`` (nothing written yet), the :class:`Correction` and the
        :class:`Residual` after compensation with the format's rounding.
    """
    from mtplan import models

    doc = read_result(result) if not isinstance(result, dict) else result
    fmt = get_format(format)
    opts = fmt.parse_options(dict(options or {}))
    proc = models.get(doc["procedure"])
    corr = correction(proc.correction, doc, procedure=proc.name,
                      unseen=unseen_covariance(proc, doc))
    files = get_format("neutral").write_files(corr, {})
    if not fmt.holds(corr):
        able = [f.name for f in available_formats().values() if f.holds(corr)]
        raise InvalidInput([f"format {fmt.name!r} holds {', '.join(fmt.kinds)} corrections; "
                            f"{corr.procedure}'s result is a {corr.kind} correction (formats "
                            f"that hold it: {', '.join(able)})"])
    if fmt.name != "neutral":
        files.update(fmt.write_files(corr, opts))
    return files, corr, residual(corr, fmt.resolution(corr, opts))
