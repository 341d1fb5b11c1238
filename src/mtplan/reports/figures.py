"""Figures for the reports (matplotlib, object API only: no pyplot global state).

Every function takes result objects or tables and returns PNG bytes; nothing here
computes an uncertainty. Values are in the measurands' display units.
"""

from __future__ import annotations

import io
import math

import numpy as np

__all__ = ["bands_figure", "sweep_figure", "pareto_figure", "budget_figure", "histogram_figure",
           "estimator_figure", "corner_figure", "trace_figure", "path_figure"]

_COLORS = ["#1f5fa8", "#d9622b", "#3a923a", "#b0306d", "#7a5cc2", "#8c6d31", "#2a9fa8"]


def _figure(w=6.4, h=3.6):
    from matplotlib.figure import Figure

    fig = Figure(figsize=(w, h), dpi=140, layout="constrained")
    return fig


def _max_n(n):
    from matplotlib.ticker import MaxNLocator

    return MaxNLocator(n)


def _png(fig) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    return buf.getvalue()


def sweep_figure(table, vary: dict, measurands: list, units: dict) -> bytes:
    """Standard uncertainty against the first swept field, one panel per measurand.

    Error bars are the Monte Carlo standard error of a standard deviation,
    u / sqrt(2 (N - 1)). Other swept fields and estimators make the series.
    """
    fields = list(vary)
    x = fields[0]
    others = fields[1:]
    n = len(measurands)
    cols = min(n, 3)
    rows = math.ceil(n / cols)
    fig = _figure(3.0 * cols + 0.6, 2.4 * rows + 0.6)
    axes = fig.subplots(rows, cols, squeeze=False)
    group_keys = others + (["estimator"] if table["estimator"].nunique() > 1 else [])
    for k, name in enumerate(measurands):
        ax = axes[k // cols][k % cols]
        sub = table[table["measurand"] == name]
        groups = [((), sub)] if not group_keys else list(sub.groupby(group_keys, sort=True))
        for j, (key, g) in enumerate(groups[:7]):
            g = g.sort_values(x)
            err = g["std"] / np.sqrt(2 * (g["trials"] - 1))
            key = key if isinstance(key, tuple) else (key,)
            label = ", ".join(f"{f}={v}" for f, v in zip(group_keys, key, strict=False)) or None
            ax.errorbar(g[x], g["std"], yerr=err, marker="o", ms=3, lw=1.2, capsize=2,
                        color=_COLORS[j % len(_COLORS)], label=label)
        ax.set_title(name, fontsize=9)
        ax.set_xlabel(x, fontsize=8)
        ax.set_ylabel(f"u [{units[name]}]", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)
        if np.all(sub["std"] > 0) and sub["std"].max() / max(sub["std"].min(), 1e-300) > 30:
            ax.set_yscale("log")
    for k in range(n, rows * cols):
        axes[k // cols][k % cols].set_visible(False)
    handles, labels = axes[0][0].get_legend_handles_labels()
    if labels:
        fig.legend(handles, labels, fontsize=7, loc="outside lower center",
                   ncol=min(len(labels), 4))
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
    ax.set_ylabel("worst u / target")
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
    for j, src in enumerate(pivot.columns):
        vals = pivot[src].to_numpy()
        ax.barh(range(len(pivot)), vals, left=left, color=_COLORS[j % len(_COLORS)], label=src)
        left += vals
    ax.set_yticks(range(len(pivot)), pivot.index, fontsize=8)
    ax.invert_yaxis()
    ax.set_xlim(0, 1)
    ax.set_xlabel("share of u² (fraction of the variance)")
    ax.grid(alpha=0.3, axis="x")
    fig.legend(fontsize=7, loc="outside lower center", ncol=min(len(pivot.columns), 4),
               frameon=False)
    return _png(fig)


def histogram_figure(result) -> bytes:
    """Monte Carlo distribution of each measurand, with true value and interval."""
    ms = result.measurands
    cols = min(len(ms), 4)
    rows = math.ceil(len(ms) / cols)
    fig = _figure(2.4 * cols + 0.4, 2.0 * rows + 0.4)
    axes = fig.subplots(rows, cols, squeeze=False)
    for i, m in enumerate(ms):
        ax = axes[i // cols][i % cols]
        values = result.mc.samples(m.name)
        if values is not None:
            ax.hist(values, bins=60, color=_COLORS[0], alpha=0.75)
        ax.axvline(result.true[i], color="k", lw=1, label="true")
        ax.axvspan(result.mc.low[i], result.mc.high[i], color=_COLORS[1], alpha=0.15,
                   label="coverage interval")
        ax.set_title(f"{m.name} [{m.unit}]", fontsize=8)
        ax.tick_params(labelsize=6)
        ax.set_yticks([])
        ax.xaxis.set_major_locator(_max_n(4))
    for k in range(len(ms), rows * cols):
        axes[k // cols][k % cols].set_visible(False)
    handles, labels = axes[0][0].get_legend_handles_labels()
    fig.legend(handles, labels, fontsize=7, loc="outside lower center", ncol=2, frameon=False)
    return _png(fig)


def estimator_figure(results: dict) -> bytes:
    """Bias with +-2u bars per estimator and measurand, in units of the first estimator's u
    (so measurands in um and urad share one axis)."""
    first = next(iter(results.values()))
    names = [m.name for m in first.measurands]
    u1 = np.where(np.asarray(first.mc.std) > 0, first.mc.std, 1.0)
    k = len(results)
    fig = _figure(6.4, min(0.16 * len(names) * k + 1.3, 9.0))
    ax = fig.add_subplot()
    for j, (est, r) in enumerate(results.items()):
        y = np.arange(len(names)) + (j - (k - 1) / 2) * 0.8 / max(k, 1)
        ax.errorbar(np.asarray(r.bias) / u1, y, xerr=2 * np.asarray(r.mc.std) / u1, fmt="o",
                    ms=3, capsize=2, lw=1, color=_COLORS[j % len(_COLORS)], label=est)
    ax.axvline(0, color="k", lw=0.8)
    ax.set_yticks(range(len(names)), names, fontsize=7 if len(names) > 8 else 8)
    ax.set_ylim(len(names) - 0.5, -0.5)
    ax.set_xlabel("bias ± 2u, in units of u of the first estimator")
    ax.grid(alpha=0.3, axis="x")
    fig.legend(fontsize=7, loc="outside lower center", ncol=len(results), frameon=False)
    return _png(fig)


def corner_figure(samples: dict) -> bytes:
    """Pairwise scatter and marginal histograms of posterior samples (label -> array)."""
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
    for name, (x, y) in path.get("points", {}).items():
        ax.plot([x], [y], "o", ms=5, color="k")
        ax.annotate(name, (x, y), textcoords="offset points", xytext=(4, 4), fontsize=8)
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
        for c, unit in enumerate(("um", "urad")):
            ax = axes[r][c]
            sub = t[t["unit"] == unit]
            for j, (name, g) in enumerate(sub.groupby("function", sort=False)):
                if g["position_mm"].nunique() < 2:
                    continue  # a constant (squareness)
                ax.plot(g["position_mm"], g["std"], lw=1.3, color=_COLORS[j % len(_COLORS)],
                        ls="-" if j < len(_COLORS) else "--", label=name)
            ax.set_title(f"{est}: {'positioning and straightness' if unit == 'um' else 'angular'}",
                         fontsize=8)
            ax.set_xlabel("position along the axis [mm]", fontsize=7)
            ax.set_ylabel(f"u [{unit}]", fontsize=7)
            ax.tick_params(labelsize=6)
            ax.grid(alpha=0.3)
            if r == 0:
                ax.legend(fontsize=6, ncol=3)
    return _png(fig)
