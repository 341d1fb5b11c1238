"""A log of the ambient temperature during the test (``[conditions] temperature_log``), read
into what the plan's conditions are compared with (:mod:`mtplan.plans.conditions`)."""

from __future__ import annotations

from pathlib import Path

__all__ = ["read_temperature_log"]


def read_temperature_log(path) -> dict:
    """The ambient temperatures a log records, as ``[conditions]`` states them: the lowest
    (``temperature_min_c``), the highest (``temperature_max_c``), the largest change within
    any hour (``temperature_change_c_per_h``: the highest minus the lowest reading of any
    60 min window) and what the log is (``temperature_log``: its name, count and span;
    ``temperature_log_span``: its first and last time [min after midnight], which each
    test's time is held to).

    The log is a CSV file with a header row and the columns ``time`` (the time of day on the
    test date, "08:30" or "08:30:15", in order) and ``temperature_c`` [°C].

    Raises
    ------
    InvalidInput
        The file, the row and what is wrong, every problem at once.
    """
    import csv
    import datetime

    import numpy as np

    from mtplan._validate import InvalidInput

    where = f"The temperature log {Path(path).name!r}"
    try:
        with open(path, newline="", encoding="utf-8") as fh:
            rows = list(csv.DictReader(fh))
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise InvalidInput([f"{where} cannot be read: {exc}."]) from None
    problems, minutes, temps = [], [], []
    for i, row in enumerate(rows, start=2):
        try:
            t = datetime.time.fromisoformat(str(row.get("time", "")).strip())
            value = float(row.get("temperature_c", ""))
            if not -30 <= value <= 60:
                raise ValueError
        except (TypeError, ValueError):
            problems.append(f"{where} row {i}: needs 'time' (08:30 or 08:30:15) and "
                            "'temperature_c' (a number from -30 to 60 [°C]). Got "
                            f"{row.get('time')!r}, {row.get('temperature_c')!r} instead.")
            continue
        minutes.append(t.hour * 60 + t.minute + t.second / 60)
        temps.append(value)
    if not problems and len(temps) < 2:
        problems.append(f"{where} needs at least two readings (columns time, temperature_c).")
    if not problems and any(b <= a for a, b in zip(minutes, minutes[1:])):
        problems.append(f"{where}: the times must increase from row to row.")
    if problems:
        raise InvalidInput(problems)
    t, x = np.asarray(minutes), np.asarray(temps)
    window = (t[None, :] >= t[:, None]) & (t[None, :] <= t[:, None] + 60.0)
    change = np.max(np.where(window, x, -np.inf), axis=1) - np.min(np.where(window, x, np.inf),
                                                                   axis=1)
    span = [f"{int(m) // 60:02d}:{int(m) % 60:02d}" for m in (t[0], t[-1])]
    return {"temperature_min_c": float(x.min()), "temperature_max_c": float(x.max()),
            "temperature_change_c_per_h": float(change.max()),
            "temperature_log": f"log {Path(path).name}, {len(x)} readings from {span[0]} to "
                               f"{span[1]}",
            "temperature_log_span": [float(t[0]), float(t[-1])]}
