"""Figures for the reports (matplotlib, object API only: no pyplot global state).

Every function takes result objects or tables and returns PNG bytes; nothing here
computes an uncertainty. Values are in the measurands' display units.
"""

from __future__ import annotations

import io
import math

import numpy as np

from mtplan.reports.labels import unit
from mtplan.reports.wording import verdict_short

__all__ = ["bands_figure", "sweep_figure", "lever_figure", "acceptance_figure", "pareto_figure",
           "budget_figure", "histogram_figure", "estimator_figure", "corner_figure",
           "trace_figure", "path_figure", "along_figure"]

_COLORS = ["#1f5fa8", "#d9622b", "#3a923a", "#b0306d", "#7a5cc2", "#8c6d31", "#2a9fa8"]


def qualitative_colors(n: int) -> list:
    """``n`` colours that tell every series apart: matplotlib's qualitative palettes
    (tab10, then tab20, then tab20 with tab20b and tab20c: up to 60 distinct colours)."""
    from matplotlib import colormaps
    from matplotlib.colors import to_hex

    if n <= 10:
        names = ["tab10"]
    elif n <= 20:
        names = ["tab20"]
    else:
        names = ["tab20", "tab20b", "tab20c"]
    colours = [to_hex(c) for name in names for c in colormaps[name].colors]
    if n > len(colours):
        raise ValueError(f"{n} series need more than {len(colours)} distinct colours")
    return colours[:n]


def _figure(w=6.4, h=3.6, *, layout="constrained", dpi=140):
    from matplotlib.figure import Figure

    return Figure(figsize=(w, h), dpi=dpi, layout=layout)


def _panels(rows, cols, w, h, *, legend_rows=1, label_lines=1, dpi=140):
    """A grid of panels with fixed margins [in]: much faster than a constrained layout
    for the many-panel sweeps, with room for a legend of ``legend_rows`` below and x
    labels of ``label_lines`` lines."""
    more = 0.14 * (label_lines - 1)  # each further line of the x label [in]
    h = h + more * rows
    fig = _figure(w, h, layout=None, dpi=dpi)
    left, right, top, bottom = 0.62, 0.12, 0.3, 0.55 + 0.2 * legend_rows + more  # [in]
    gap_x, gap_y = 0.7, 0.75 + more  # between panels [in]: y labels; x label, next title
    ax_w = (w - left - right - (cols - 1) * gap_x) / cols
    ax_h = (h - top - bottom - (rows - 1) * gap_y) / rows
    fig.subplots_adjust(left=left / w, right=1 - right / w, bottom=bottom / h, top=1 - top / h,
                        wspace=gap_x / ax_w, hspace=gap_y / ax_h)
    return fig, fig.subplots(rows, cols, squeeze=False)


def _max_n(n):
    from matplotlib.ticker import MaxNLocator

    return MaxNLocator(n)


def _png(fig) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    return buf.getvalue()


_MARKERS = ["o", "s", "^", "D", "v", "P", "X"]
_STYLES = ["-", "--", "-.", ":"]


def _series(ax, x, y, err, j, n, label, *, span, strong=False):
    """One curve of a sweep: offset sideways by its index (so that identical curves
    stay visible), its own marker and line style, Monte Carlo error bars."""
    dx = (j - (n - 1) / 2) * 0.015 * span if n > 1 else 0.0
    y = np.where(np.asarray(y, dtype=float) > 0, y, np.nan)  # u = 0: below the resolution
    ax.errorbar(np.asarray(x, dtype=float) + dx, y, yerr=err, marker=_MARKERS[j % 7],
                ms=4.5 if strong else 4, lw=1.8 if strong else 1.0, capsize=2,
                ls=_STYLES[j % 4] if not strong else "-", color=_COLORS[j % len(_COLORS)],
                label=label, mfc="white" if j else None, zorder=2 if strong else 3 + j)


def _y_from_zero(ax, values):
    """Linear axes start at zero, so that Monte Carlo noise does not look like a trend;
    a series over more than a factor 30 gets a log axis instead."""
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    if v.size and np.all(v > 0) and v.max() / v.min() > 30:
        ax.set_yscale("log")
    else:
        ax.set_ylim(bottom=0, top=max(ax.get_ylim()[1], 1e-12))


def sweep_figure(table, vary: dict, measurands: list, units: dict, *, xlabel: str = "",
                 base=None) -> bytes:
    """Standard uncertainty against the first swept field, one panel per measurand.

    Error bars are the Monte Carlo standard error of a standard deviation,
    u / sqrt(2 (N - 1)). Other swept fields and estimators make the series, each with
    its own marker and a small sideways offset. ``base``: the study's value of the
    field, marked by a dotted line.
    """
    import textwrap

    fields = list(vary)
    x = fields[0]
    others = fields[1:]
    n = len(measurands)
    cols = 3 if n in (3, 5, 6, 9) else min(n, 4)
    rows = math.ceil(n / cols)
    group_keys = others + (["estimator"] if table["estimator"].nunique() > 1 else [])
    width = min(2.35 * cols + 0.3, 7.4)
    xlabel = "\n".join(textwrap.wrap(xlabel or x, int(13 * (width - 0.3) / cols)))
    series = min(table.groupby(group_keys).ngroups if group_keys else 0, 7)
    entries = series + (base is not None)
    legend_rows = max(1, math.ceil(entries / 4))
    fig, axes = _panels(rows, cols, width, 2.0 * rows + 0.55 + 0.2 * legend_rows,
                        legend_rows=legend_rows, label_lines=xlabel.count("\n") + 1, dpi=120)
    xs = table[x].astype(float)
    span = float(xs.max() - xs.min()) or 1.0
    for k, name in enumerate(measurands):
        ax = axes[k // cols][k % cols]
        sub = table[table["measurand"] == name]
        groups = [((), sub)] if not group_keys else list(sub.groupby(group_keys, sort=False))
        for j, (key, g) in enumerate(groups[:7]):
            g = g.sort_values(x)
            key = key if isinstance(key, tuple) else (key,)
            label = ", ".join(str(v) if f == "estimator" else f"{f} = {v}"
                              for f, v in zip(group_keys, key, strict=False)) or None
            _series(ax, g[x], g["u"], g["u"] / np.sqrt(2 * (g["trials"] - 1)), j,
                    min(len(groups), 7), label, span=span)
        if base is not None:
            ax.axvline(float(base), color="#555555", lw=0.8, ls=":")
        ax.set_title(name, fontsize=9)
        ax.set_xlabel(xlabel, fontsize=7.5)
        ax.set_ylabel(f"u [{unit(units[name])}]", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)
        _y_from_zero(ax, sub["u"])
    for k in range(n, rows * cols):
        axes[k // cols][k % cols].set_visible(False)
    handles, labels = axes[0][0].get_legend_handles_labels()
    if base is not None:
        from matplotlib.lines import Line2D

        handles.append(Line2D([], [], color="#555555", lw=0.8, ls=":"))
        labels.append("study set-up")
    if labels:
        fig.legend(handles, labels, fontsize=7, loc="lower center", ncol=min(len(labels), 4),
                   frameon=False)
    return _png(fig)


def _drawn_legend(axes) -> tuple[list, list]:
    """Legend entries of the curves drawn in any panel (a curve drawn nowhere has none)."""
    handles, labels = [], []
    for ax in np.ravel(axes):
        for h, lab in zip(*ax.get_legend_handles_labels(), strict=True):
            lines = h.lines if hasattr(h, "lines") else (h,)
            ys = [np.asarray(getattr(ln, "get_ydata", lambda: [])(), dtype=float)
                  for ln in lines if ln is not None and hasattr(ln, "get_ydata")]
            drawn = any(np.isfinite(y).any() for y in ys if y.size)
            if drawn and lab not in labels:
                handles.append(h)
                labels.append(lab)
    return handles, labels


def lever_figure(table, field: str, measurands: list, units: dict, *, estimator: str,
                 recommended: str, base, targets: dict, xlabel: str,
                 marked: dict | None = None, coverage: float = 1.0) -> bytes:
    """The customer's sweep: u against one lever for the measurands that matter,
    ``estimator`` drawn strong (the recommended one where the sweep ran it), the other
    estimators hollow and offset, the
    study's set-up starred and the target u (``targets``: measurand -> (u, what)) as a
    dashed line. The y axis starts at zero and ends above the recommended estimator and
    the target; an estimator beyond it is marked "off scale" in the legend. ``marked``
    (measurand -> u) is the study's set-up with the estimator the tables use, starred at
    exactly the tables' value (without it, the sweep's own point of ``estimator``). With
    ``coverage`` (k) != 1 every u (the sweep's, ``targets``' and ``marked``'s) is drawn as
    U = k u."""
    from matplotlib.lines import Line2D

    import textwrap

    n = len(measurands)
    cols = min(n, 4)
    rows = math.ceil(n / cols)
    width = 7.0 if cols > 2 else 2.8 * cols + 1.0
    fig = _figure(width, 1.9 * rows + 0.6)
    xlabel = "\n".join(textwrap.wrap(xlabel, int(13 * width / cols)))
    axes = fig.subplots(rows, cols, squeeze=False)
    if coverage != 1:
        table = table.assign(u=coverage * table["u"])
        targets = {n: (coverage * t, what) for n, (t, what) in targets.items()}
        marked = None if marked is None else {n: coverage * v for n, v in marked.items()}
    ests = [estimator] + [e for e in table["estimator"].unique() if e != estimator]
    xs = table[field].astype(float)
    span = float(xs.max() - xs.min()) or 1.0
    off_scale = set()
    for k, name in enumerate(measurands):
        ax = axes[k // cols][k % cols]
        sub = table[table["measurand"] == name]
        mine = sub[sub["estimator"] == estimator]
        star = None if marked is None else marked.get(name)
        top = 1.25 * max([float(mine["u"].max()) if len(mine) else 0.0]
                         + ([targets[name][0]] if name in targets else [])
                         + ([star] if star is not None and np.isfinite(star) else []))
        for j, est in enumerate(ests):
            g = sub[sub["estimator"] == est].sort_values(field)
            if not len(g):
                continue
            if est != estimator and float(g["u"].max()) > top:
                off_scale.add(est)
            _series(ax, g[field], g["u"], g["u"] / np.sqrt(2 * (g["trials"] - 1)), j,
                    len(ests), est, span=2.0 * span, strong=est == estimator)
            at = g[np.isclose(g[field].astype(float), float(base))]
            if est == estimator and len(at) and marked is None:
                star = float(at["u"].iloc[0])
        if star is not None and np.isfinite(star) and star > 0:
            ax.plot([float(base)], [star], "*", ms=12, color="#222222", zorder=6)
        if name in targets:
            ax.axhline(targets[name][0], color="#b3261e", lw=1.0, ls="--")
        ax.set_title(name, fontsize=9)
        ax.set_xlabel(xlabel, fontsize=7.5)
        ax.set_ylabel(f"{'u' if coverage == 1 else f'U (k = {coverage:g})'} "
                      f"[{unit(units[name])}]",
                      fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)
        ax.set_ylim(0, top if top > 0 else 1.0)
    for k in range(n, rows * cols):
        axes[k // cols][k % cols].set_visible(False)
    handles, labels = _drawn_legend(axes)
    labels = [f"{x} (recommended)" if x == recommended else
              f"{x} (off scale)" if x in off_scale else x for x in labels]
    handles.append(Line2D([], [], marker="*", ms=10, ls="", color="#222222"))
    labels.append("study set-up" if marked is None else
                  f"study set-up, {recommended} (the tables' value)")
    shown = {what if coverage == 1 else what.replace("u for", "U for")
             for name, (_, what) in targets.items() if name in measurands}
    if shown:
        handles.append(Line2D([], [], color="#b3261e", lw=1.0, ls="--"))
        labels.append(" / ".join(sorted(shown)))
    fig.legend(handles, labels, fontsize=7, loc="outside lower center",
               ncol=min(len(labels), 4), frameon=False)
    return _png(fig)


def acceptance_figure(verdicts: list) -> bytes:
    """One panel per toleranced measurand: the tolerance (black lines), the conformance
    zone (green), the guard bands (amber), the non-conformance zone (red), the population
    of items (prior, grey curve) and the measured value with its coverage interval."""
    n = len(verdicts)
    cols = min(n, 3)
    rows = math.ceil(n / cols)
    fig = _figure(2.45 * cols + 0.2, 1.3 * rows + 0.55)
    axes = fig.subplots(rows, cols, squeeze=False)
    zone = {"pass": "#2e7d32", "fail": "#b3261e"}
    for k, v in enumerate(verdicts):
        ax = axes[k // cols][k % cols]
        lo = v.lower if v.lower is not None else None
        hi = v.upper if v.upper is not None else None
        w = v.guard_band if math.isfinite(v.guard_band) else 0.0
        points = [x for x in (lo, hi, v.measured_low, v.measured_high, v.measured)
                  if x is not None and math.isfinite(x)]
        width = (hi - lo) if lo is not None and hi is not None else max(abs(p) for p in points)
        left = min(points + [(lo if lo is not None else min(points)) - w]) - 0.25 * width
        left = 0.0 if getattr(v, "zone", None) else left  # a position deviation: >= 0
        right = max(points + [(hi if hi is not None else max(points)) + w]) + 0.25 * width
        a_lo = lo + w if lo is not None else left
        a_hi = hi - w if hi is not None else right
        if lo is not None:
            ax.axvspan(left, lo - w, color="#b3261e", alpha=0.14, lw=0)
        if hi is not None:
            ax.axvspan(hi + w, right, color="#b3261e", alpha=0.14, lw=0)
        for t in (lo, hi):
            if t is not None:
                ax.axvspan(t - w, t + w, color="#f0a500", alpha=0.35, lw=0)
                ax.axvline(t, color="k", lw=1.1)
        if a_hi > a_lo:
            ax.axvspan(a_lo, a_hi, color="#2e7d32", alpha=0.16, lw=0)
        if v.prior is not None:
            grid = np.linspace(left, right, 400)
            pdf = np.asarray(v.prior.pdf(grid), dtype=float)
            if np.all(np.isfinite(pdf)) and pdf.max() > 0:
                ax.plot(grid, 0.9 * pdf / pdf.max(), color="#555555", lw=1.0)
        if v.measured is not None:
            color = zone.get(v.verdict, "#8a5a00")
            err = [[v.measured - v.measured_low], [v.measured_high - v.measured]]
            ax.errorbar([v.measured], [0.45], xerr=err, fmt="o", ms=6, color=color, capsize=4,
                        lw=1.6, zorder=5)
        ax.set_xlim(left, right)
        ax.set_ylim(0, 1.0)
        ax.set_yticks([])
        ax.tick_params(labelsize=7)
        ax.set_title(f"{v.measurand}: {verdict_short(v.verdict)}", fontsize=7.5, loc="left")
        ax.set_xlabel(f"{v.measurand} [{unit(v.unit)}]", fontsize=7)
        ax.xaxis.set_major_locator(_max_n(5))
    for k in range(n, rows * cols):
        axes[k // cols][k % cols].set_visible(False)
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    handles = [Patch(color="#2e7d32", alpha=0.3), Patch(color="#f0a500", alpha=0.5),
               Patch(color="#b3261e", alpha=0.2), Line2D([], [], color="k", lw=1.1),
               Line2D([], [], color="#555555", lw=1.0),
               Line2D([], [], marker="o", color="#444444", lw=1.6)]
    labels = ["pass", "guard band: conditional pass / fail", "fail", "tolerance",
              "population (prior)", "measured, 95 % interval"]
    fig.legend(handles, labels, fontsize=7, loc="outside lower center", ncol=3, frameon=False)
    return _png(fig)


def pareto_figure(table, front: list, best: int | None) -> bytes:
    """Duration against the worst ratio of predicted uncertainty to target."""
    fig = _figure(5.6, 3.4)
    ax = fig.add_subplot()
    ax.scatter(table["duration_s"] / 60, table["worst"], s=12, color="#999999",
               label="candidates (linearised prediction)")
    f = table.loc[front].sort_values("duration_s")
    ax.plot(f["duration_s"] / 60, f["worst"], "-o", ms=4, color=_COLORS[0], label="Pareto front")
    if best is not None:
        b = table.loc[best]
        ax.scatter([b["duration_s"] / 60], [b["worst"]], s=120, marker="*", color=_COLORS[1],
                   zorder=5, label="recommended (confirmed by Monte Carlo)")
    ax.axhline(1.0, color="k", lw=0.8, ls="--")
    ax.set_xlabel("duration of the test [min]")
    ax.set_ylabel("worst U / target (same k)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    return _png(fig)


def budget_figure(budget) -> bytes:
    """Share of each error source in each measurand's variance (GUM budget)."""
    pivot = budget.pivot_table(index="output", columns="input", values="share", sort=False)
    pivot = pivot.loc[:, pivot.max(axis=0) > 0.001]
    pivot = pivot[pivot.max(axis=0).sort_values(ascending=False).index]
    fig = _figure(6.4, 0.28 * len(pivot) + 1.2 + 0.2 * math.ceil(len(pivot.columns) / 4))
    ax = fig.add_subplot()
    left = np.zeros(len(pivot))
    colours = qualitative_colors(len(pivot.columns))
    for j, src in enumerate(pivot.columns):
        vals = pivot[src].to_numpy()
        ax.barh(range(len(pivot)), vals, left=left, color=colours[j], label=src)
        left += vals
    ax.set_yticks(range(len(pivot)), pivot.index, fontsize=8)
    ax.invert_yaxis()
    ax.set_xlim(0, 1)
    ax.set_xlabel("share of u² (fraction of the variance)")
    ax.grid(alpha=0.3, axis="x")
    fig.legend(fontsize=7, loc="outside lower center", ncol=min(len(pivot.columns), 4),
               frameon=False)
    return _png(fig)


def histogram_figure(result, names: list | None = None) -> bytes:
    """Monte Carlo distribution of the measurands ``names`` (default: all), with true
    value and coverage interval."""
    index = {m.name: i for i, m in enumerate(result.measurands)}
    chosen = [index[n] for n in (names or list(index))]
    cols = min(len(chosen), 4)
    rows = math.ceil(len(chosen) / cols)
    fig, axes = _panels(rows, cols, 1.75 * cols + 0.5, 1.45 * rows + 0.65, dpi=120)
    for k, i in enumerate(chosen):
        m = result.measurands[i]
        ax = axes[k // cols][k % cols]
        values = result.mc.samples(m.name)
        if values is not None:
            ax.hist(values, bins=50, color=_COLORS[0], alpha=0.75)
        ax.axvline(result.true[i], color="k", lw=1, label="true")
        ax.axvspan(result.mc.low[i], result.mc.high[i], color=_COLORS[1], alpha=0.15,
                   label="coverage interval")
        ax.set_title(f"{m.name} [{unit(m.unit)}]", fontsize=8)
        ax.tick_params(labelsize=6)
        ax.set_yticks([])
        ax.xaxis.set_major_locator(_max_n(4))
    for k in range(len(chosen), rows * cols):
        axes[k // cols][k % cols].set_visible(False)
    handles, labels = axes[0][0].get_legend_handles_labels()
    fig.legend(handles, labels, fontsize=7, loc="lower center", ncol=2, frameon=False)
    return _png(fig)


def robust_limit(groups, *, factor: float = 4.0) -> float | None:
    """An axis half-range that an outlier does not squash: 1.5 times the 90th percentile
    of the values when the largest exceeds ``factor`` times it, else None (autoscale)."""
    v = np.concatenate([np.ravel(np.asarray(g, dtype=float)) for g in groups])
    v = v[np.isfinite(v)]
    if v.size < 3:
        return None
    typical = float(np.percentile(v, 90))
    if typical <= 0 or v.max() <= factor * typical:
        return None
    return 1.5 * typical


def estimator_figure(results: dict) -> bytes:
    """Bias with +-2u bars per estimator and measurand, in units of the first estimator's u
    (so measurands in um and urad share one axis)."""
    first = next(iter(results.values()))
    names = [m.name for m in first.measurands]
    u1 = np.where(np.asarray(first.mc.std) > 0, first.mc.std, 1.0)
    k = len(results)
    fig = _figure(6.4, min(0.16 * len(names) * k + 1.3, 9.0))
    ax = fig.add_subplot()
    lim = robust_limit([np.abs(np.asarray(r.bias) / u1) + 2 * np.asarray(r.mc.std) / u1
                        for r in results.values()])
    for j, (est, r) in enumerate(results.items()):
        y = np.arange(len(names)) + (j - (k - 1) / 2) * 0.8 / max(k, 1)
        x = np.asarray(r.bias) / u1
        err = 2 * np.asarray(r.mc.std) / u1
        inside = np.abs(x) <= (lim if lim is not None else np.inf)
        colour = _COLORS[j % len(_COLORS)]
        ax.errorbar(np.where(inside, x, np.nan), y, xerr=np.where(inside, err, np.nan),
                    fmt="o", ms=3, capsize=2, lw=1, color=colour, label=est)
        for xi, yi in zip(x[~inside], y[~inside], strict=True):  # outliers: marked, printed
            edge = 0.97 * lim * np.sign(xi)
            ax.plot([edge], [yi], ">" if xi > 0 else "<", ms=6, color=colour)
            ax.annotate(f"{xi:.3g}", (edge, yi), xytext=(-4 if xi > 0 else 4, 3),
                        textcoords="offset points", fontsize=6, color=colour,
                        ha="right" if xi > 0 else "left")
    if lim is not None:
        ax.set_xlim(-lim, lim)
    ax.axvline(0, color="k", lw=0.8)
    ax.set_yticks(range(len(names)), names, fontsize=7 if len(names) > 8 else 8)
    ax.set_ylim(len(names) - 0.5, -0.5)
    ax.set_xlabel("bias ± 2u, in units of u of the first estimator"
                  + ("; triangles: beyond the axis, value printed" if lim is not None else ""))
    ax.grid(alpha=0.3, axis="x")
    fig.legend(fontsize=7, loc="outside lower center", ncol=len(results), frameon=False)
    return _png(fig)


def corner_figure(samples: dict) -> bytes:
    """Pairwise scatter and marginal histograms of posterior samples (label -> array)."""
    from matplotlib.ticker import MaxNLocator

    names = list(samples)[:6]
    n = len(names)
    size = max(1.7 * n + 0.8, 3.6)
    fig = _figure(size, size)
    axes = fig.subplots(n, n, squeeze=False)
    for i, a in enumerate(names):
        ya = np.asarray(samples[a])
        for j, b in enumerate(names):
            ax = axes[i][j]
            ax.tick_params(labelsize=6)
            # at most 4 ticks a panel: "-12.5-10.0" must not run together
            ax.xaxis.set_major_locator(MaxNLocator(4))
            ax.yaxis.set_major_locator(MaxNLocator(4))
            xb = np.asarray(samples[b])
            if j > i:
                ax.set_visible(False)
                continue
            if i == j:
                ax.hist(ya, bins=40, color=_COLORS[0], alpha=0.8)
                ax.axvline(ya.mean(), color="k", lw=0.8)
                ax.set_yticks([])
            else:
                ax.plot(xb[:4000], ya[:4000], ".", ms=1.5, color=_COLORS[0], alpha=0.3,
                        rasterized=True)
                ax.axvline(xb.mean(), color="k", lw=0.6)
                ax.axhline(ya.mean(), color="k", lw=0.6)
            if i == n - 1:
                ax.set_xlabel(b, fontsize=7)
            else:
                ax.set_xticklabels([])
            if j == 0 and i > 0:
                ax.set_ylabel(a, fontsize=7)
            elif j > 0:
                ax.set_yticklabels([])
    return _png(fig)


def trace_figure(chains: dict, discard: int = 0) -> bytes:
    """Walker traces per parameter (name -> array of shape (steps, walkers))."""
    names = list(chains)[:6]
    fig = _figure(6.4, 1.05 * len(names) + 0.7)
    axes = fig.subplots(len(names), 1, squeeze=False, sharex=True)
    for i, name in enumerate(names):
        ax = axes[i][0]
        c = np.asarray(chains[name])
        ax.plot(c, lw=0.4, alpha=0.5, color=_COLORS[0])
        if discard:
            ax.axvspan(0, discard, color="#999999", alpha=0.25, lw=0)
        ax.set_ylabel(name, fontsize=7)
        ax.tick_params(labelsize=6)
        ax.grid(alpha=0.3)
    axes[-1][0].set_xlabel("step of the sampler")
    return _png(fig)


def path_figure(path: dict) -> bytes:
    """A planned 2D path: ``polylines`` (list of (N, 2) arrays), ``points`` (name -> (x, y)),
    ``circles`` (list of (cx, cy, r, label))."""
    fig = _figure(4.6, 4.6)
    ax = fig.add_subplot()
    for cx, cy, r, label in path.get("circles", []):
        t = np.linspace(0, 2 * np.pi, 361)
        ax.plot(cx + r * np.cos(t), cy + r * np.sin(t), lw=0.8, color="#777777", ls="--")
        if label:
            ax.annotate(label, (cx, cy), fontsize=7, color="#555555")
    for j, line in enumerate(path.get("polylines", [])):
        line = np.asarray(line)
        ax.plot(line[:, 0], line[:, 1], lw=1.4, color=_COLORS[j % len(_COLORS)])
    points = {n: (float(x), float(y)) for n, (x, y) in path.get("points", {}).items()}
    span = max([abs(c) for xy in points.values() for c in xy] + [1e-9])
    merged: list = []  # points that coincide (within 2 % of the drawing) share one label
    for name, xy in points.items():
        near = next((m for m in merged if math.dist(m[1], xy) <= 0.02 * span), None)
        if near is None:
            merged.append([[name], xy])
        else:
            near[0].append(name)
    for names, (x, y) in merged:
        ax.plot([x], [y], "o", ms=5, color="k")
        ax.annotate(" = ".join(names), (x, y), textcoords="offset points", xytext=(4, 4),
                    fontsize=8)
    if "view" in path:  # (cx, cy, half-size): keep the drawing on the part that matters
        cx, cy, half = path["view"]
        ax.set_xlim(cx - half, cx + half)
        ax.set_ylim(cy - half, cy + half)
    ax.set_aspect("equal")
    ax.set_xlabel("x [mm]")
    ax.set_ylabel("y [mm]")
    ax.grid(alpha=0.3)
    return _png(fig)


def bands_figure(tables: dict) -> bytes:
    """u of each error function against position: one row of panels per estimator,
    translational functions [um] left, angular [urad] right (``tables``: estimator ->
    DataFrame with function, unit, position_mm, std, status)."""
    ests = list(tables)
    fig = _figure(7.2, 2.5 * len(ests) + 0.8)
    axes = fig.subplots(len(ests), 2, squeeze=False, sharey="col")
    for r, est in enumerate(ests):
        t = tables[est]
        t = t[np.isfinite(t["std"]) & (t["status"] == "identified")]
        for c, kind in enumerate(("um", "urad")):
            ax = axes[r][c]
            sub = t[t["unit"] == kind]
            for j, (name, g) in enumerate(sub.groupby("function", sort=False)):
                if g["position_mm"].nunique() < 2:
                    continue  # a constant (squareness)
                ax.plot(g["position_mm"], g["std"], lw=1.3, color=_COLORS[j % len(_COLORS)],
                        ls="-" if j < len(_COLORS) else "--", label=name)
            ax.set_title(f"{est}: {'positioning and straightness' if kind == 'um' else 'angular'}",
                         fontsize=8)
            ax.set_xlabel("position along the axis [mm]", fontsize=7)
            ax.set_ylabel(f"u [{unit(kind)}]", fontsize=7)
            ax.tick_params(labelsize=6)
            ax.grid(alpha=0.3)
            if r == 0:
                ax.legend(fontsize=6, ncol=3)
    return _png(fig)


def along_figure(panels: list, cols: int = 5) -> bytes:
    """Errors along the travel, as ISO 230-1 draws them: one small panel per error
    function (a row per axis), its measured values against position (line; hollow markers
    outside the measured travel: extrapolated) with the pointwise 95 % band (dark) and the
    simultaneous one (light), the tolerance (black dashed) where one is given, and the
    residual predicted after compensation about zero (orange lines: its pointwise band;
    dotted: its simultaneous band).

    ``panels``: one dict per function with ``function``, ``unit``, ``row`` (the axis's
    row), ``position``, ``value``, ``low``, ``high``, ``sim_low``, ``sim_high``,
    ``extrapolated`` (arrays over the positions), ``tolerance`` ((lower, upper) or None)
    and, where there is a correction, ``res_low``, ``res_high``, ``res_sim_low``,
    ``res_sim_high``."""
    rows = max(p["row"] for p in panels) + 1
    fig = _figure(7.2, 1.3 * rows + 0.45)
    axes = fig.subplots(rows, cols, squeeze=False)
    used = set()
    blue, orange = _COLORS[0], _COLORS[1]
    for p in panels:
        col = sum(1 for q in panels[:panels.index(p)] if q["row"] == p["row"])
        ax = axes[p["row"]][col]
        used.add((p["row"], col))
        x = np.asarray(p["position"], dtype=float)
        ax.fill_between(x, p["sim_low"], p["sim_high"], color=blue, alpha=0.13, lw=0)
        ax.fill_between(x, p["low"], p["high"], color=blue, alpha=0.32, lw=0)
        if "res_low" in p:
            for y in (p["res_low"], p["res_high"]):
                ax.plot(x, y, color=orange, lw=0.9)
            for y in (p["res_sim_low"], p["res_sim_high"]):
                ax.plot(x, y, color=orange, lw=0.9, ls=":")
        ax.plot(x, p["value"], color=blue, lw=1.1)
        ex = np.asarray(p["extrapolated"], dtype=bool)
        v = np.asarray(p["value"], dtype=float)
        ax.plot(x[~ex], v[~ex], "o", ms=1.8, color=blue)
        if ex.any():
            ax.plot(x[ex], v[ex], "o", ms=3, mfc="white", color=blue)
        for t in p.get("tolerance") or ():
            if t is not None:
                ax.axhline(t, color="k", lw=0.9, ls="--")
        ax.axhline(0.0, color="#999999", lw=0.5)
        ax.set_title(f"{p['function']} [{unit(p['unit'])}]", fontsize=7.5, loc="left", pad=2)
        ax.tick_params(labelsize=6, length=2, pad=1)
        ax.xaxis.set_major_locator(_max_n(4))
        ax.yaxis.set_major_locator(_max_n(4))
        ax.grid(alpha=0.25, lw=0.4)
        ax.set_xlabel(f"{'xyz'[p['row']]} [mm]", fontsize=6.5, labelpad=1)
    for r in range(rows):
        for c in range(cols):
            if (r, c) not in used:
                axes[r][c].set_visible(False)
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    legend = [(Line2D([], [], color=blue, lw=1.1, marker="o", ms=2), "measured"),
              (Patch(color=blue, alpha=0.45), "95 % band, pointwise"),
              (Patch(color=blue, alpha=0.15), "95 % band, simultaneous")]
    if any(p.get("tolerance") for p in panels):
        legend.append((Line2D([], [], color="k", lw=0.9, ls="--"), "tolerance"))
    if any("res_low" in p for p in panels):
        legend += [(Line2D([], [], color=orange, lw=0.9),
                    "after compensation (predicted), pointwise"),
                   (Line2D([], [], color=orange, lw=0.9, ls=":"),
                    "after compensation, simultaneous")]
    if any(np.any(p["extrapolated"]) for p in panels):
        legend.append((Line2D([], [], color=blue, marker="o", ms=3, mfc="white", lw=0),
                       "extrapolated"))
    handles, labels = zip(*legend)
    fig.legend(handles, labels, fontsize=6.5, loc="outside lower center", ncol=3,
               frameon=False)
    return _png(fig)
