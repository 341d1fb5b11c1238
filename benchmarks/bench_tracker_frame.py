"""Speed of the tracker_frame procedure, and what drives its uncertainty (not a test).

1. ``simulate_uncertainty`` for the default set-up (20 000 trials, one job): trials
   per second, and the ratio to drawing the same number of normal variates as all
   its error sources hold (numpy alone); best of a few repeats.
2. Where the time goes in one block: drawing the errors, the forward model, and the
   estimator's stages (spherical to Cartesian and registration, line fits, 3D circle
   fits, the rest).
3. With ``--sweep``: one-at-a-time sweeps (Monte Carlo, 4000 trials each) over the
   tracker distance, the points per axis and per arc, and the A arc, printing the
   standard uncertainty of sub-machine 1's measurands.
4. With ``--compare``: patent against angles over the A arc (Monte Carlo, the sweep's
   trials), std of origin_y/origin_z/ac_offset of sub-machine 1 and their ratio, under
   the error model before issue 17 (every transverse d L error per point) and the
   current one (part of it systematic per test, plus SMR, air, drift, straightness).
5. With ``--budget``: the markdown table of docs/tracker_frame.md, u of every measurand
   before and after the new sources and the share of each source in u^2.

Run: ``.venv/bin/python benchmarks/bench_tracker_frame.py [--trials 20000] [--sweep]
[--compare] [--budget] [--sweep-trials N] [--no-speed]``
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from mtplan.models import get
from mtplan.models import tracker_frame as tf
from mtplan.models.tracker_frame import _estimators as tf_estimators
from mtplan.models.tracker_frame import _layout as tf_layout
from mtplan.fitting.fit3d import fit_circle_3d, fit_circle_3d_angles, fit_line_3d
from mtplan.evaluation.simulation import simulate_uncertainty

from _budget import budget_table, mc_std  # benchmarks/ is the script's folder


def best(fn, repeat=5):
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return min(times)


def speed(trials: int) -> None:
    proc = get("tracker_frame")
    setup = proc.Setup()
    n_var = sum(s.size for s in proc.active_sources(setup).values())
    t_mc = best(lambda: simulate_uncertainty(proc, setup, trials=trials, rng=1, progress=False))
    rng = np.random.default_rng(1)
    t_np = best(lambda: rng.standard_normal((trials, n_var)), repeat=5)
    print(f"tracker_frame default set-up: {setup.n_submachines} sub-machines, "
          f"{tf_layout.n_points(setup)} tracker points, {n_var} error variates per trial, "
          f"block {proc.capabilities.block_size}")
    print(f"simulate_uncertainty, {trials} trials: {t_mc:.3f} s = {trials / t_mc:,.0f} trials/s")
    print(f"numpy alone, {trials} x {n_var} normal variates: {t_np:.3f} s")
    print(f"ratio: {t_mc / t_np:.1f}")

    n = proc.capabilities.block_size
    seq = np.random.SeedSequence(1)
    t_draw = best(lambda: proc.draw_errors(setup, n, seq))
    errors = proc.draw_errors(setup, n, seq)
    truth = proc.Truth()
    t_fwd = best(lambda: proc.forward(setup, truth, errors))
    readings = proc.forward(setup, truth, errors)
    t_est = best(lambda: tf.estimate_patent(setup, readings))
    t_est_ang = best(lambda: tf.estimate_angles(setup, readings))

    def stage_reg():
        xyz = tf_estimators._cartesian(readings)
        rot, t = tf_estimators._register(setup, xyz[:, :4])
        return np.einsum("nij,npj->npi", rot, xyz) + t[:, None, :]

    t_reg = best(stage_reg)
    glob = stage_reg()
    sl = tf_layout.slices(setup)
    k_all = range(1, setup.n_submachines + 1)
    t_lin = best(lambda: [fit_line_3d(glob[:, sl[(g, k)]]) for k in k_all for g in "XYZ"])
    t_circ = best(lambda: [fit_circle_3d(glob[:, sl[(g, k)]]) for k in k_all for g in "CA"])
    iters = max(fit_circle_3d(glob[:, sl[(g, 1)]]).iterations for g in "CA")
    total = t_draw + t_fwd + t_est
    print(f"\none block of {n} trials: {total * 1e3:.0f} ms")
    print(f"  draw errors   {t_draw * 1e3:7.1f} ms  ({t_draw / total:5.1%})")
    print(f"  forward       {t_fwd * 1e3:7.1f} ms  ({t_fwd / total:5.1%})")
    print(f"  estimator     {t_est * 1e3:7.1f} ms  ({t_est / total:5.1%}), of which")
    print(f"    spherical->Cartesian + registration {t_reg * 1e3:6.1f} ms")
    print(f"    line fits (3 per sub-machine)       {t_lin * 1e3:6.1f} ms")
    print(f"    3D circle fits (2 per sub-machine)  {t_circ * 1e3:6.1f} ms "
          f"(up to {iters} Levenberg-Marquardt iterations)")
    rest = t_est - t_reg - t_lin - t_circ
    print(f"    rest                                {rest * 1e3:6.1f} ms")
    th = {g: np.radians(tf_layout.arc_angles(arc, setup.points_per_arc))
          for g, arc in (("C", setup.c_arc_deg), ("A", setup.a_arc_deg))}
    t_circ_ang = best(lambda: [fit_circle_3d_angles(glob[:, sl[(g, k)]], th[g])
                               for k in k_all for g in "CA"])
    print(f"  estimator angles {t_est_ang * 1e3:7.1f} ms, of which circles with angles "
          f"(closed form) {t_circ_ang * 1e3:6.1f} ms")


SHOW = ("origin_x_1", "origin_y_1", "origin_z_1", "rot_x_1", "rot_y_1", "rot_z_1",
        "ac_offset_1", "sq_xy_1", "sq_yz_1", "sq_zx_1")


def sweeps(trials: int) -> None:
    proc = get("tracker_frame")
    grid = {
        "tracker_distance_mm": [2000.0, 4000.0, 8000.0, 16000.0],
        "points_per_axis": [3, 6, 11, 21],
        "points_per_arc": [3, 7, 13, 25],
        "a_arc_deg": [20.0, 60.0, 120.0, 240.0],
        "c_arc_deg": [60.0, 180.0, 360.0],
    }
    head = " ".join(f"{m.rsplit('_', 1)[0]:>10}" for m in SHOW)
    for field, values in grid.items():
        print(f"\nstandard uncertainty of sub-machine 1 [um, urad] ({trials} trials) "
              f"against {field}")
        print(f"{field:>22} {head} {'time [s]':>9}")
        for v in values:
            setup = proc.setup({field: v})
            r = simulate_uncertainty(proc, setup, trials=trials, rng=3, progress=False)
            s = dict(zip([m.name for m in r.measurands], r.mc.std, strict=True))
            row = " ".join(f"{s[m]:10.1f}" for m in SHOW)
            print(f"{v:>22g} {row} {r.duration_s:9.0f}")
    setup = proc.Setup()
    print("\nshare of each source (Monte Carlo, one source at a time), sub-machine 1:")
    from mtplan.evaluation.simulation import source_budget

    b = source_budget(proc, setup, trials=trials, rng=4)
    b = b[b.output.isin(SHOW)].pivot(index="input", columns="output", values="contribution")
    print(b[list(SHOW)].round(1).to_string())


#: the error model before issue 17: every transverse d L error per point (6 um/m), no
#: SMR, air, drift or straightness sources (the same random streams as the new model's)
OLD_SOURCES = ("distance_fixed", "distance_per_length", "transverse_fixed",
               "transverse_per_length", "machine_repeatability", "rotary_positioning")
OLD_SETUP = {"transverse_per_length_um_per_m": 6.0}


def compare(trials: int) -> None:
    """patent against angles over the A arc, the old error model against the new."""
    proc = get("tracker_frame")
    show = ("origin_y_1", "origin_z_1", "ac_offset_1")
    print(f"\npatent -> angles over the A arc, std of sub-machine 1 [um] ({trials} trials, "
          "rng 3); old: d L per point, new: the default sources")
    print(f"{'a_arc_deg':>10} {'model':>5} " + " ".join(f"{m:>26}" for m in show))
    for arc in (20.0, 60.0, 120.0, 240.0):
        for model in ("old", "new"):
            old = model == "old"
            setup = proc.setup({"a_arc_deg": arc, **(OLD_SETUP if old else {})})
            src = OLD_SOURCES if old else None
            s = {est: mc_std(proc, setup, trials, est, src) for est in ("patent", "angles")}
            row = " ".join(f"{s['patent'][m]:8.1f} -> {s['angles'][m]:6.1f} "
                           f"(x{s['patent'][m] / s['angles'][m]:4.1f})" for m in show)
            print(f"{arc:>10g} {model:>5} {row}")


def budget(trials: int, estimator: str = "patent") -> None:
    """Markdown table: u of each measurand before and after the new sources, shares in u^2."""
    proc = get("tracker_frame")
    print(f"\n{estimator}, default set-up; u by Monte Carlo ({trials} trials, rng 3), "
          "shares of u^2 by the GUM budget (linearize) [%]")
    groups = proc.sources(proc.Setup())
    short = {g: g.replace("_per_length", "/L").replace("_fixed", " c").replace("distance", "dist")
             for g in groups}
    print(budget_table(proc, proc.Setup(), (proc.setup(OLD_SETUP), OLD_SOURCES), trials,
                       estimator, short))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=20_000)
    ap.add_argument("--sweep", action="store_true")
    ap.add_argument("--compare", action="store_true")
    ap.add_argument("--budget", action="store_true")
    ap.add_argument("--sweep-trials", type=int, default=4000)
    ap.add_argument("--no-speed", action="store_true")
    args = ap.parse_args(argv)
    if not args.no_speed:
        speed(args.trials)
    if args.sweep:
        sweeps(args.sweep_trials)
    if args.compare:
        compare(args.sweep_trials)
    if args.budget:
        budget(args.sweep_trials)


if __name__ == "__main__":
    main()
