// mtplan explore: the printed design report. One A4 page that only the print shows: the
// set-up with every setting (yes/no ones as yes or no) and each error source as on (with
// its size) or off, the results with their check, the budget, the tolerances, the verdict
// and the design's link; no controls. It is rebuilt with every result the page shows, so
// printing (the Print button, the browser's own, or a PDF made by a script) always has it.
"use strict";

function reportValue(f, v) {
  // a set-up value as the report states it
  if (v === null || v === undefined || v === "") return "default";
  if (f.kind === "bool") return (v === true || v === "true" || v === "True") ? "yes" : "no";
  if (Array.isArray(v)) return v.join(", ");
  return String(v);
}
function reportSetupValue(r, f) {
  // the value the numbers were computed for (the server's set-up), else the page's
  if (r && r.ok && r.setup && f.name in r.setup) return r.setup[f.name];
  const v = state.design.setup[f.name];
  return v !== undefined && v !== "" ? v : f.default;
}
function checkWords(m) {
  // the state of a live number in words: checked, failed (why), or not checked (why)
  if (m.trust === "ok") return "checked";
  if (m.trust === "no") return "failed: " + (m.why || "first order not reliable");
  return "not checked" + (m.why ? ": " + m.why : "");
}
function designLink() {
  // the link that reopens this design (the token is asked for, never written in it)
  return `${location.origin}/?d=${b64encode(state.design)}`;
}
function reportTable(id, head, rows) {
  return el("table", { id }, el("thead", {}, el("tr", {}, ...head.map((h) => el("th", { text: h })))),
            el("tbody", {}, ...rows.map((cells) => el("tr", {}, ...cells.map((c) => el("td", { text: c }))))));
}
function renderReport(r) {
  const box = $("report");
  if (!box || !state.info || !state.design) return;
  const info = state.info, off = new Set(state.design.off || []);
  const named = (f) => label(f) + (f.unit ? ` [${unitText(f.unit)}]` : "");
  const kv = (f, text) => el("div", { class: "kv", "data-field": f.name }, el("span", { class: "k", text: named(f) }), " ", el("b", { text }));
  const fields = (pick) => info.fields.filter(pick).map((f) => kv(f, reportValue(f, reportSetupValue(r, f))));
  const sources = info.fields.filter((f) => f.source).map((f) => el("div", { class: "kv", "data-source": f.source },
    el("span", { class: "k", text: f.source }), " ",
    el("b", { text: off.has(f.source) ? "off" : `on, ${reportValue(f, reportSetupValue(r, f))}${f.unit ? " " + unitText(f.unit) : ""}` })));
  const parts = [
    el("h1", { text: `Design report: ${info.title}` }),
    el("p", { class: "meta", text: `Procedure ${info.name}; estimator ${state.design.estimator}` +
      (r && r.ok ? `; prediction ${r.method}; duration of the test ${duration(r.duration_s)}` : "") +
      `; Monte Carlo: seed ${state.design.seed}, ${state.design.trials} trials; mtplan explore, ${new Date().toISOString().slice(0, 10)}` }),
    el("p", { class: "verdict", id: "report-verdict", text: r && r.ok ? ($("verdict").textContent || "Verdict: none (no tolerance or target entered).")
      : "Not evaluated: " + (((r && r.problems) || []).join(" ") || Object.entries((r && r.field_errors) || {}).map(([k, v]) => `${k}: ${v}`).join(" ") || "the set-up is refused.") }),
    el("h2", { text: "Set-up: the test's levers" }), el("div", { class: "cols", id: "report-levers" }, ...fields((f) => f.lever && !f.source)),
    el("h2", { text: "Error sources (on with its size, or off)" }), el("div", { class: "cols", id: "report-sources" }, ...sources),
    el("h2", { text: "Machine, workpiece and instrument" }), el("div", { class: "cols", id: "report-others" }, ...fields((f) => !f.lever && !f.source)),
  ];
  if (r && r.ok) {
    const shares = (m) => Object.entries(m.budget).map(([s, u]) => [s, m.u > 0 ? (u * u) / (m.u * m.u) : 0])
      .sort((a, b) => b[1] - a[1]).filter((x) => x[1] > 0.005).slice(0, 3).map(([s, x]) => `${s} ${(100 * x).toFixed(0)} %`).join(", ");
    const shown = (m, x) => (m.trust === "no" ? "not reliable" : fmt3(x));
    parts.push(el("h2", { text: "Results (U with k = 2)" }), reportTable("report-measurands",
      ["Measurand", "Unit", "u", "U", "Target U", "Check against Monte Carlo", "Largest sources (share of u\u00b2)"],
      r.measurands.map((m) => [m.name, unitText(m.unit), shown(m, m.u), shown(m, m.U),
                               m.target === undefined ? "" : fmt3(m.target), checkWords(m), shares(m)])));
    const id = r.identifiability;
    if (id) parts.push(el("p", { id: "report-ident", text: `Identifiability: rank ${id.rank} of ${id.n_params} (${id.parameters}); ` +
      `condition number ${id.condition === null ? "\u221e" : fmt3(id.condition)}; valuation O1 ${fmt3(id.valuation)}; ` +
      (id.undetermined.length ? "not determined: " + id.undetermined.join(", ") : "every measurand is determined") }));
    const tol = r.measurands.filter((m) => m.acceptance);
    if (tol.length) {
      parts.push(el("h2", { text: "Tolerances and acceptance (ISO 14253-1 / JCGM 106)" }), reportTable("report-acceptance",
        ["Measurand", "Lower", "Upper", "Prior", "Rule", "TUR", "Guard band", "Acceptance limits", "PFA", "PFR"],
        tol.map((m) => {
          const a = m.acceptance, t = state.design.tolerances[m.name] || {};
          const stated = [m.name, t.lower || "-", t.upper || "-", t.prior_name || t.prior || "-", t.rule || ""];
          // figures only on a number checked against its Monte Carlo
          if (m.trust !== "ok") return [...stated, `no figures: u is ${checkWords(m)}`, "", "", "", ""];
          if (a.error || !a.acceptance_limits) return [...stated, a.error || "no figures", "", "", "", ""];
          return [...stated, fmt4(a.tur), fmt4(a.guard_band), `[${fmt4(a.acceptance_limits[0])}, ${fmt4(a.acceptance_limits[1])}]`, pct(a.pfa), pct(a.pfr)];
        })));
      for (const m of tol) {  // a value measured on a machine: its specific risk and decision
        const t = state.design.tolerances[m.name] || {};
        if ((t.measured ?? "") !== "") parts.push(el("p", { class: "report-specific", text: "Specific risk: " + specificText(m, t) + "." }));
      }
    }
    const m = r.measurands.find((x) => x.name === (state.budgetOf || $("budget-of").value)) || r.measurands[0];
    const rows = (m.budget_table || []).filter((b) => b.share === null || b.share >= 1e-3);
    const rest = (m.budget_table || []).length - rows.length;
    parts.push(el("h2", { text: `Budget of ${m.name}` + (rest ? ` (${rest} sources under 0.1 % of u\u00b2 left out)` : "") }),
      reportTable("report-budget", ["Source", "Input u", "Sensitivity coefficient", "Contribution", "Share of u\u00b2"],
        rows.map((b) => [b.source, b.input_u === null ? "-" : `${fmt3(b.input_u)} ${unitText(b.input_unit)}`,
                         b.c === null ? "-" : `${fmt3(b.c)} ${unitText(m.unit)}/${unitText(b.input_unit)}`,
                         `${fmt3(b.contribution)} ${unitText(m.unit)}`, b.share === null ? "-" : pct(b.share)])));
    const mc = $("mc-summary");
    if (mc && !$("job-result").classList.contains("stale")) parts.push(el("p", { id: "report-mc", text: mc.textContent + ": " +
      [...document.querySelectorAll("#mc-table tbody tr")].map((tr) => `${tr.children[0].textContent} U ${tr.querySelector(".mc-U").textContent}`).join(", ") }));
  }
  const link = designLink();
  parts.push(el("p", { class: "link" }, "Design link (opens this design in `mtplan explore`; the token is asked for): ",
                el("a", { href: link, id: "report-link", text: link })));
  box.replaceChildren(...parts);
}
function scheduleReport() {
  // after the numbers are on the screen (the lever's clock stops there), for the newest
  // result only; printing asks for it again
  clearTimeout(state.reportTimer);
  state.reportTimer = setTimeout(() => renderReport(state.lastResult), 0);
}
window.addEventListener("beforeprint", () => renderReport(state.lastResult));
