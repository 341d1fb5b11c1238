// mtplan explore: named scenarios side by side. They are kept in the browser's storage
// (localStorage, per server address), so a reload or a restart of the server keeps them;
// the server keeps none. Each is renamed in its heading, opened, exported as a study
// (the TOML that `mtplan report` reads) or removed; another tab sees the change.
"use strict";

const SCENARIO_KEY = "mtplan.explore.scenarios";

function scenarioValid(c) {
  return c && typeof c === "object" && typeof c.name === "string" && c.design && typeof c.design === "object" &&
    typeof c.design.procedure === "string" && c.result && Array.isArray(c.result.measurands);
}
function loadScenarios() {
  // what this browser kept (an unreadable store is an empty one, never a failure)
  try {
    const s = JSON.parse(localStorage.getItem(SCENARIO_KEY) || "[]");
    return Array.isArray(s) ? s.filter(scenarioValid) : [];
  } catch (e) { return []; }
}
function saveScenarios() {
  try { localStorage.setItem(SCENARIO_KEY, JSON.stringify(state.scenarios)); }
  catch (e) { banner("The scenarios could not be kept in this browser's storage (" + e.message + "): they last until the page is closed."); }
}
function scenarioSummary(r) {
  // what the comparison shows of a result: U and its check per measurand, the duration
  return { duration_s: r.duration_s, estimator: r.estimator,
           measurands: r.measurands.map((m) => ({ name: m.name, unit: m.unit, U: m.U, trust: m.trust })) };
}
function keepScenario() {
  const r = state.lastResult;
  if (!r || !r.ok) { banner("Only an evaluated design can be kept as a scenario."); return; }
  state.scenarios.push({ name: `${state.scenarios.length + 1}: ${state.design.procedure}, ${state.design.estimator}`,
                         design: JSON.parse(JSON.stringify(state.design)), result: scenarioSummary(r),
                         kept: new Date().toISOString() });
  saveScenarios();
  renderScenarios();
}
function download(text, name, type) {
  const a = el("a", { href: URL.createObjectURL(new Blob([text], { type })), download: name });
  document.body.append(a); a.click(); a.remove();
}
async function exportScenario(c) {
  // a scenario as a study file: the same export as the page's own design
  try {
    const { toml } = await api("/api/export", c.design);
    state.lastExport = toml;
    download(toml, `${c.name.replace(/[^A-Za-z0-9_-]+/g, "_").replace(/^_+|_+$/g, "") || "scenario"}_study.toml`, "application/toml");
  } catch (e) { banner(`The scenario "${c.name}" was not exported: ${e.message}`); }
}
function renderScenarios() {
  const body = $("scenarios").querySelector("tbody");
  $("scenarios-msg").hidden = state.scenarios.length > 0;
  if (!state.scenarios.length) { body.replaceChildren(); return; }
  const key = (x) => `${x.name} [${unitText(x.unit)}]`;
  const names = [...new Set(state.scenarios.flatMap((c) => c.result.measurands.map(key)))];
  const cell = (c, n) => {
    const m = c.result.measurands.find((x) => key(x) === n);
    return el("td", { text: !m ? "" : (m.trust === "no" ? "not reliable" : fmt3(m.U)) });
  };
  const head = el("tr", {}, el("th", { text: "U (k = 2)" }), ...state.scenarios.map((c, i) => {
    const name = el("input", { type: "text", class: "scenario-name", value: c.name, "aria-label": `name of scenario ${i + 1}` });
    name.addEventListener("change", () => { c.name = name.value.trim() || c.name; saveScenarios(); renderScenarios(); });
    const open = el("button", { text: "open", title: "make this scenario the page's design" });
    open.addEventListener("click", () => openDesign(JSON.parse(JSON.stringify(c.design))));
    const study = el("button", { text: "study", class: "scenario-study", title: "export this scenario as a study TOML (mtplan report reads it)" });
    study.addEventListener("click", () => exportScenario(c));
    const drop = el("button", { text: "\u00d7", title: "remove this scenario", "aria-label": `remove scenario ${i + 1}` });
    drop.addEventListener("click", () => { state.scenarios.splice(i, 1); saveScenarios(); renderScenarios(); });
    return el("th", {}, name, " ", open, study, drop);
  }));
  const changes = el("tr", {}, el("td", { text: "set-up changes" }), ...state.scenarios.map((c) =>
    el("td", { class: "sources", text: [`${c.design.procedure}, ${c.result.estimator || c.design.estimator}`,
      ...Object.entries(c.design.setup).map(([k, v]) => `${k} = ${v}`),
      ...(c.design.off || []).map((s) => `${s} off`)].join(", ") })));
  const dur = el("tr", {}, el("td", { text: "duration" }), ...state.scenarios.map((c) => el("td", { text: duration(c.result.duration_s) })));
  body.replaceChildren(head, changes, dur, ...names.map((n) => el("tr", {}, el("td", { text: n }), ...state.scenarios.map((c) => cell(c, n)))));
}
// another tab of the same designer kept, renamed or removed one
window.addEventListener("storage", (e) => {
  if (e.key !== SCENARIO_KEY) return;
  state.scenarios = loadScenarios();
  renderScenarios();
});
