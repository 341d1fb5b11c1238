// mtplan explore: the page. The whole design lives here and in the URL (?d=...); the
// server computes from what each request carries, so two tabs never share a design.
"use strict";

const $ = (id) => document.getElementById(id);
const state = { tab: Math.random().toString(36).slice(2) + Date.now().toString(36), design: null, info: null, procedures: [], changes: 0, sent: 0, rendered: 0,
                inflight: false, pending: false, t0: 0, latencies: [], figureLatencies: [], drawn: 0, job: null,
                sensTimer: null, lastResult: null, history: [], snapshot: null,
                scenarios: [], glossary: null };
window.mtplan = state;  // for tests and the benchmark

// ------------------------------------------------------------------ helpers
function fmt3(x) {
  if (x === null || x === undefined || !isFinite(x)) return "-";
  return String(Number(Number(x).toPrecision(3)));
}
function fmt4(x) {
  if (x === null || x === undefined || !isFinite(x)) return "-";
  return String(Number(Number(x).toPrecision(4)));
}
// a number as typed, scientific notation included ("1e6" is 1000000); the text itself when
// it is not one, so that the server names the field it refuses
function number(text, empty) {
  const t = String(text).trim();
  if (t === "") return empty;
  const x = Number(t);
  return Number.isFinite(x) ? x : t;
}
function pct(x) { return (x === null || x === undefined) ? "-" : fmt4(100 * x) + " %"; }
function duration(s) {
  if (!isFinite(s)) return "-";
  if (s < 120) return s.toFixed(0) + " s";
  if (s < 7200) return (s / 60).toFixed(1) + " min";
  return (s / 3600).toFixed(2) + " h";
}
function el(tag, attrs, ...kids) {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs || {})) {
    if (k === "class") e.className = v; else if (k === "text") e.textContent = v;
    else if (k.startsWith("on")) e.addEventListener(k.slice(2), v); else e.setAttribute(k, v);
  }
  for (const k of kids) if (k !== null && k !== undefined) e.append(k);
  return e;
}
async function api(path, body) {
  const opts = body === undefined ? {} : { method: "POST", body: JSON.stringify(body),
                                           headers: { "Content-Type": "application/json" } };
  const r = await fetch(path, opts);
  const text = await r.text();
  if (r.status === 403 && /^Token missing/.test(text)) toLogin();  // the server was started again
  let data;
  try { data = JSON.parse(text); } catch (e) { data = { error: text.trim() || r.statusText }; }
  if (!r.ok) { const e = new Error(data.error || r.statusText); e.status = r.status; throw e; }
  return data;
}
function b64encode(obj) {
  const bytes = new TextEncoder().encode(JSON.stringify(obj));
  let s = ""; for (const b of bytes) s += String.fromCharCode(b);
  return btoa(s).replace(/\+/g, "-").replace(/\//g, "_").replace(/=+$/, "");
}
function b64decode(text) {
  const s = atob(text.replace(/-/g, "+").replace(/_/g, "/"));
  return JSON.parse(new TextDecoder().decode(Uint8Array.from(s, (c) => c.charCodeAt(0))));
}
function toLogin() {
  // the launch's token is no longer this server's: ask for it, and come back to this design
  if (state.design) pushURL();
  location.assign("/login?next=" + encodeURIComponent(location.pathname + location.search));
}
function banner(text) { const b = $("banner"); b.textContent = text || ""; b.hidden = !text; }
function pushURL() {
  const url = new URL(location.href);
  url.searchParams.set("d", b64encode(state.design));
  history.replaceState(null, "", url);
}

// ------------------------------------------------------------------ controls
function fieldValue(f) {
  const v = state.design.setup[f.name];
  if (v !== undefined) return v;
  if (f.default === null || f.default === undefined) return "";
  return Array.isArray(f.default) ? f.default.join(",") : String(f.default);
}
function rangeText(f) {
  if (f.choices) return "one of " + f.choices.join(", ");
  const parts = [];
  if (f.low !== null) parts.push((f.low_open ? "> " : "\u2265 ") + f.low);
  if (f.high !== null) parts.push((f.high_open ? "< " : "\u2264 ") + f.high);
  let t = parts.join(" and ");
  if (f.kind === "tuple") {
    const lo = f.min_len, hi = f.max_len;
    const n = lo && hi ? (lo === hi ? ` of ${lo}` : ` of ${lo} to ${hi}`)
      : lo ? ` of \u2265 ${lo}` : hi ? ` of \u2264 ${hi}` : "";
    t = "list" + n + (t ? ", each " + t : "");
  }
  if (f.kind === "int") t = "integer " + t;
  if (f.optional) t += (t ? "; " : "") + "empty: default";
  return t;
}
const UNITS = { um: "\u00b5m", urad: "\u00b5rad", c: "\u00b0C", deg: "\u00b0", k: "K",
                arcsec: "\u2033", mm_min: "mm/min", per_s: "1/s" };
function unitText(u) {
  // a unit suffix as an engineer writes it: um_per_deg is µm/°, ppm_per_k is ppm/K
  if (!u) return u;
  if (u in UNITS) return UNITS[u];
  return u.split("_per_").map((p) => (p === "per" ? "1" : (UNITS[p] ?? p))).join("/");
}
function label(f) {
  let name = f.name;
  if (f.unit && name.endsWith("_" + f.unit)) name = name.slice(0, -f.unit.length - 1);
  return name.replace(/_/g, " ");
}
function setValue(name, value, lever) {
  state.design.setup[name] = String(value);
  if (lever) state.design.lever = name;
  changed();
}
function makeField(f) {
  const value = fieldValue(f);
  const row = el("div", { class: "field", id: "row-" + f.name,
                          title: f.source_doc ? `${f.doc} Source: ${f.source_doc}` : f.doc });
  const input = el("span", { class: "input" });
  let box;
  if (f.choices) {
    box = el("select", { id: "f-" + f.name });
    for (const c of f.choices) box.append(el("option", { value: c, text: c }));
    box.value = value;
    box.addEventListener("change", () => setValue(f.name, box.value, false));
  } else if (f.kind === "bool") {
    box = el("input", { id: "f-" + f.name, type: "checkbox" });
    box.checked = value === "true" || value === "True";
    box.addEventListener("change", () => setValue(f.name, box.checked ? "true" : "false", false));
  } else if (f.kind === "tuple" || f.kind === "str") {
    box = el("input", { id: "f-" + f.name, type: "text", value, placeholder: f.optional ? "default" : "" });
    box.addEventListener("change", () => setValue(f.name, box.value, false));
  } else {
    box = el("input", { id: "f-" + f.name, type: "text", inputmode: "decimal", value,
                        placeholder: f.optional ? "default" : "" });
    if (f.slider) {  // the server's choice: a range of the order of the value
      const step = f.kind === "int" ? 1 : (f.high - f.low) / 500;
      const slider = el("input", { id: "s-" + f.name, type: "range", min: f.low, max: f.high,
                                   "aria-label": `${label(f)} slider${f.unit ? ` [${unitText(f.unit)}]` : ""}`,
                                   step, value: value === "" ? f.low : value });
      slider.addEventListener("input", () => { box.value = slider.value; setValue(f.name, slider.value, true); });
      box.addEventListener("change", () => { if (isFinite(+box.value)) slider.value = box.value; });
      input.append(slider);
    }
    box.addEventListener("change", () => setValue(f.name, box.value, true));
  }
  input.append(box);
  if (f.source) {
    const on = el("input", { id: "on-" + f.source, type: "checkbox", title: "switch the source on or off",
                             "aria-label": `error source ${f.source} on` });
    on.checked = !state.design.off.includes(f.source);
    on.addEventListener("change", () => {
      const off = new Set(state.design.off);
      if (on.checked) off.delete(f.source); else off.add(f.source);
      state.design.off = [...off];
      row.classList.toggle("off", !on.checked);
      changed();
    });
    row.classList.toggle("off", !on.checked);
    row.append(el("label", { for: "f-" + f.name }, on, " " + label(f)));
  } else {
    row.append(el("label", { for: "f-" + f.name, text: label(f) }));
  }
  row.append(input, el("span", { class: "unit", text: unitText(f.unit) }),
             el("span", { class: "range", text: rangeText(f) }),
             el("span", { class: "error", id: "err-" + f.name }));
  return row;
}
function buildControls() {
  const info = state.info;
  $("title").textContent = info.title;
  for (const id of ["levers", "sources", "others", "vary"]) $(id).replaceChildren();
  for (const f of info.fields) {
    const where = f.source ? "sources" : (f.lever ? "levers" : "others");
    $(where).append(makeField(f));
    if (f.lever && f.kind !== "bool") {
      const box = el("input", { id: "v-" + f.name, type: "text", value: state.design.vary[f.name] || "",
                                "aria-label": `${label(f)}: values for the planner to try`,
                                placeholder: "values to try, e.g. 4,6,8" });
      box.addEventListener("change", () => {
        if (box.value.trim()) state.design.vary[f.name] = box.value; else delete state.design.vary[f.name];
        pushURL();
      });
      $("vary").append(el("div", { class: "field" }, el("label", { text: label(f) + (f.unit ? ` [${unitText(f.unit)}]` : "") }), box));
    }
  }
  const est = $("estimator");
  est.replaceChildren(...info.estimators.map((e) => el("option", { value: e, text: e,
                                                                   title: (info.estimator_help || {})[e] || "" })));
  est.value = state.design.estimator || info.default_estimator;
  est.title = (info.estimator_help || {})[est.value] || "";
  $("procedure").value = info.name;
  $("seed").value = state.design.seed ?? 0;
  $("trials").value = state.design.trials ?? 10000;
  buildAcceptance();
}
const TOL_LABEL = { lower: "lower tolerance limit", upper: "upper tolerance limit",
                    prior: "population of machines (normal:MEAN,SD or gamma:SHAPE,SCALE)" };
function buildAcceptance(measurands) {
  // one row per measurand of the current set-up (they change with the axis, the sub-machines)
  measurands = measurands || state.info.measurands;
  state.accNames = measurands.map((m) => m.name).join(",");
  const body = $("acceptance").querySelector("tbody");
  body.replaceChildren();
  for (const m of measurands) {
    const tol = state.design.tolerances[m.name] || {};
    const inp = (key, cls) => {
      const i = el("input", { id: `tol-${key}-${m.name}`, type: "text", class: cls || "",
                              "aria-label": `${m.name}: ${TOL_LABEL[key]} [${unitText(m.unit)}]`,
                              value: tol[key] ?? (key === "rule" ? "iso14253" : "") });
      i.addEventListener("change", () => {
        const t = { ...(state.design.tolerances[m.name] || {}) };
        t[key] = i.value;
        if (key === "prior") { delete t.prior_csv; delete t.prior_name; }
        if (!t.rule) t.rule = "iso14253";
        if ((t.lower ?? "") === "" && (t.upper ?? "") === "") delete state.design.tolerances[m.name];
        else state.design.tolerances[m.name] = t;
        changed();
      });
      return i;
    };
    const rule = el("select", { id: `tol-rule-${m.name}`, "aria-label": `${m.name}: decision rule` });
    for (const r of ["simple", "iso14253", "dobbert", "guard:1", "target-pfa:0.02"])
      rule.append(el("option", { value: r, text: r }));
    rule.value = tol.rule || "iso14253";
    rule.dataset.term = "simple";  // the glossary's row of the decision rules
    rule.addEventListener("change", () => {
      const t = { ...(state.design.tolerances[m.name] || {}), rule: rule.value };
      state.design.tolerances[m.name] = t; changed();
    });
    const out = (k) => el("td", { id: `acc-${k}-${m.name}`, text: "-" });
    // a population from measured values: the file's content is sent, never a path
    const upload = el("input", { id: `tol-csv-${m.name}`, type: "file", accept: ".csv,text/csv",
                                 "aria-label": `${m.name}: upload a CSV of measured values as the population` });
    upload.addEventListener("change", async () => {
      const f = upload.files[0];
      if (!f) return;
      const t = { ...(state.design.tolerances[m.name] || {}), prior_csv: await f.text(),
                  prior_name: f.name, prior: "" };
      if (!t.rule) t.rule = "iso14253";
      state.design.tolerances[m.name] = t;
      $(`tol-prior-${m.name}`).value = "";
      $(`tol-prior-${m.name}`).placeholder = f.name;
      changed();
    });
    const csv = el("label", { class: "button small", title: "population from a CSV file of measured values" }, "CSV", upload);
    body.append(el("tr", { id: "acc-" + m.name },
      el("td", {}, codeCell(m), ` [${unitText(m.unit)}]`),
      el("td", {}, inp("lower")), el("td", {}, inp("upper")),
      el("td", { class: "prior-cell" }, inp("prior", "prior"), csv), el("td", {}, rule),
      out("tur"), out("gb"), out("limits"), out("pfa"), out("pfr")));
  }
}

// ------------------------------------------------------------------ evaluation
function markJobStale() {
  const res = $("job-result");
  if (res.childElementCount && !res.classList.contains("stale")) {  // computed for an earlier set-up
    res.classList.add("stale");
    res.prepend(el("div", { class: "stale-note", id: "job-stale", text: "Old: computed for an earlier set-up; run it again for this one." }));
  }
}
function changed() {
  state.changes += 1;
  markJobStale();
  const now = JSON.stringify(state.design);
  if (state.snapshot && state.snapshot !== now && !state.undoing) state.history.push(state.snapshot);
  state.snapshot = now; state.undoing = false;
  state.t0 = performance.now();
  estimateOld();
  refresh();  // the link follows with the figures, once the numbers are on the screen
}
async function refresh() {
  if (state.inflight) { state.pending = true; return; }
  state.inflight = true;
  const asked = state.changes, t0 = state.t0;
  $("status").textContent = "computing\u2026"; $("status").className = "status busy";
  let result;
  try {
    result = await api("/api/evaluate", { design: state.design, tab: state.tab, change: asked });
  } catch (e) {
    result = { ok: false, problems: [String(e.message || e)], field_errors: {} };
  }
  state.inflight = false;
  if (state.pending) { state.pending = false; refresh(); }
  if (asked < state.rendered) return;
  render(result);
  state.rendered = asked;
  if (asked === state.changes && t0) state.latencies.push(performance.now() - t0);
  document.body.dataset.rendered = String(asked);
  drawFigures(result, asked, t0);
  scheduleSensitivity();
  scheduleEstimate();
  schedulePositions();
  if (result.ok && result.measurands.some((m) => m.pending)) scheduleCheck();
}
function scheduleCheck() {
  clearTimeout(state.checkTimer);
  state.checkTimer = setTimeout(checkFirstOrder, 300);  // not while a lever is being moved
}
function settled() {
  // the numbers on the page answer the newest change and none is being computed: only
  // then do the curve and the spot check start (asked earlier, they take the CPU that the
  // next numbers need; the render of the newest change asks for them again)
  return !state.inflight && state.rendered === state.changes;
}
async function checkFirstOrder() {
  // the small Monte Carlo that each first-order u is judged against: the server answers
  // with the numbers as checked (passed, failed, or too costly to check live), and only
  // checked numbers get acceptance figures and a verdict
  const asked = state.changes, r = state.lastResult;
  if (!r || !r.ok || !settled()) return;
  let c;
  try { c = await api("/api/check", { design: state.design, tab: state.tab, change: asked }); }
  catch (e) {  // never swallowed: the cells say that the check failed, and why
    if (asked !== state.changes || state.lastResult !== r) return;
    if (e.status === 429 || e.status === 503) { scheduleCheck(); return; }  // busy: asked again
    for (const m of r.measurands.filter((x) => x.pending)) {
      Object.assign(m, { trust: "no", pending: false, why: `the check could not be made: ${e.message}`,
                         todo: "change the set-up, or confirm it by Monte Carlo" });
      if (m.acceptance) m.acceptance = { error: `no decision: u(${m.name}) failed its check: ${m.todo}`, withheld: "no" };
    }
    render(r);
    document.body.dataset.checked = String(asked);
    return;
  }
  if (c.superseded || asked !== state.changes || state.lastResult !== r) return;
  render(c);
  document.body.dataset.checked = String(asked);
}
function render(r) {
  state.lastResult = r;
  document.querySelectorAll(".field .error").forEach((e) => { e.textContent = ""; });
  document.querySelectorAll(".field.bad").forEach((e) => e.classList.remove("bad"));
  for (const [f, msg] of Object.entries(r.field_errors || {})) {
    const e = $("err-" + f);
    if (e) { e.textContent = msg; $("row-" + f).classList.add("bad"); }
  }
  const tbody = $("measurands").querySelector("tbody");
  if (!r.ok) {
    banner((r.problems || []).join(" ") || "Fix the marked fields: the set-up is not evaluated.");
    $("status").textContent = r.refused === "cost"
      ? "not evaluated: too costly for a live answer (see the message above)"
      : "not evaluated: the set-up is refused (see the marked fields)";
    $("status").className = "status err";
    tbody.querySelectorAll("td.u, td.U").forEach((c) => { c.textContent = "-"; });
    if (r.measurand_names && r.measurand_names.map((m) => m.name).join(",") !== state.accNames) buildAcceptance(r.measurand_names);
    for (const id of ["sens-plot", "budget-plot"]) $(id).classList.add("stale");
    $("verdict").textContent = "";
    renderHelp(r);
    scheduleReport();
    return;
  }
  // a check that failed for the whole set-up is said once, above the numbers
  const whole = r.measurands.find((m) => m.whole);
  banner(whole ? `First order failed its check: ${whole.why.replace(/\.$/, "")}; ${whole.todo}.` : "");
  $("budget-plot").classList.remove("stale");
  if (r.measurands.map((m) => m.name).join(",") !== state.accNames) buildAcceptance(r.measurands);
  const pending = r.measurands.some((m) => m.pending);
  $("status").textContent = pending ? "checking first order against a small Monte Carlo\u2026" : "up to date";
  $("status").className = pending ? "status busy" : "status";
  $("duration").textContent = duration(r.duration_s);
  $("method").textContent = `${r.method}, estimator ${r.estimator}`;
  tbody.replaceChildren();
  for (const m of r.measurands) {
    const shares = Object.entries(m.budget).map(([s, u]) => [s, m.u > 0 ? (u * u) / (m.u * m.u) : 0])
      .sort((a, b) => b[1] - a[1]).filter((x) => x[1] > 0.005).slice(0, 3)
      .map(([s, x]) => `${s} ${(100 * x).toFixed(0)} %`).join(", ");
    const target = el("input", { id: "t-" + m.name, type: "text", value: state.design.targets[m.name] ?? "" });
    target.addEventListener("change", () => {
      if (target.value.trim()) state.design.targets[m.name] = target.value; else delete state.design.targets[m.name];
      changed();
    });
    // a target is met only by a number that is trusted: never by one first order gets wrong
    const trusted = m.trust === "ok";
    const cls = [m.target === undefined ? "" : (!trusted ? "" : (m.U <= m.target ? "meet" : "miss")),
                 m.trust === "no" ? "untrusted" : (m.trust === "unchecked" ? "unchecked" : "")].join(" ").trim();
    const shown = (x) => (m.trust === "no" ? "first order not reliable" : fmt3(x));
    const tip = m.trust === "ok" ? "" : `${m.why}; ${m.todo}`;
    target.setAttribute("aria-label", `${m.name}: target U (k = 2) [${unitText(m.unit)}]`);
    tbody.append(el("tr", { id: "m-" + m.name, class: cls, "data-trust": m.trust || "" },
      el("td", {}, codeCell(m)), el("td", { text: unitText(m.unit) }),
      el("td", { class: "u", text: shown(m.u), title: tip }), el("td", { class: "U", text: shown(m.U), title: tip }),
      el("td", {}, target, m.target_error ? el("span", { class: "err", text: " " + m.target_error }) : null),
      trustNote(m, shares)));
    const a = m.acceptance;
    const set = (k, t) => { const c = $(`acc-${k}-${m.name}`); if (c) c.textContent = t; };
    const tur = $(`acc-tur-${m.name}`);
    if (tur) tur.classList.toggle("errcell", !!(a && a.error));  // wraps: never clipped
    if (a && a.error) { set("tur", a.error); ["gb", "limits", "pfa", "pfr"].forEach((k) => set(k, "")); }
    else if (a && a.acceptance_limits) {
      set("tur", a.tur === null ? "none (one-sided)" : fmt4(a.tur)); set("gb", fmt4(a.guard_band));
      const [al, au] = a.acceptance_limits;
      set("limits", al === null ? `\u2264 ${fmt4(au)}` : (au === null ? `\u2265 ${fmt4(al)}` : `[${fmt4(al)}, ${fmt4(au)}]`));
      set("pfa", pct(a.pfa)); set("pfr", pct(a.pfr));
    } else ["tur", "gb", "limits", "pfa", "pfr"].forEach((k) => set(k, "-"));
  }
  renderIdent(r.identifiability);
  renderBudgetTable(r);
  renderRisk(r);
  verdict(r);
  renderSpecific(r);
  renderHelp(r);
  scheduleReport();
}
function trustNote(m, shares) {
  // the last cell of a measurand's row: its largest sources when its u is checked (or being
  // checked); else why it is not, what to do, and the button that checks it where the check
  // is too costly for a live answer
  const cell = el("td", { class: "sources", id: "note-" + m.name });
  if (m.trust === "ok" || m.pending) cell.textContent = shares || (m.u > 0 ? "" : "u = 0 at first order");
  else if (m.trust === "no") cell.append(el("span", { class: "failed", text: m.whole
    ? "check failed: the check's Monte Carlo fails for this set-up (the message above says why and what to do)"
    : `check failed: ${m.why}; ${m.todo}.` }));
  else {
    cell.append(el("span", { class: "notchecked", text: `${m.why}. ` }));
    {
      const b = el("button", { class: "small", id: "check-" + m.name, text: `Check (about ${duration(m.check_s || 0)})`,
                               title: "check these numbers by the same small Monte Carlo, in the background" });
      b.addEventListener("click", () => startJob("check"));
      cell.append(b);
    }
  }
  return cell;
}
function drawFigures(r, asked, t0) {
  // The numbers first, then the figures: the budget plot (Plotly, about half the page's work
  // for a change) and the link are drawn after the frame that shows the numbers, and only
  // for the newest result (one that a newer change overtakes is never drawn).
  state.figuresFor = asked;
  requestAnimationFrame(() => setTimeout(() => {
    if (state.figuresFor !== asked) return;
    pushURL();
    if (r.ok) renderBudget(r);
    state.drawn = asked;
    if (asked === state.changes && t0) state.figureLatencies.push(performance.now() - t0);
    document.body.dataset.drawn = String(asked);
  }, 0));
}
function renderIdent(id) {
  const box = $("ident");
  const und = id.undetermined.length
    ? el("span", { class: "warn", id: "undetermined", text: "not determined: " + id.undetermined.join(", ") })
    : el("span", { id: "undetermined", text: "every measurand is determined by the readings" });
  box.replaceChildren(
    el("span", { id: "rank", "data-term": "rank", text: `rank ${id.rank} of ${id.n_params} (${id.parameters})` }),
    el("span", { id: "condition", "data-term": "condition", text: "condition number " + (id.condition === null ? "\u221e" : fmt3(id.condition)) }),
    el("span", { id: "valuation", "data-term": "O1", text: "valuation O1 " + fmt3(id.valuation) + " (larger is better, 0 when rank deficient)" }),
    und);
}
const PALETTE = ["#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2",
  "#7f7f7f", "#bcbd22", "#17becf", "#aec7e8", "#ffbb78", "#98df8a", "#ff9896", "#c5b0d5",
  "#c49c94", "#f7b6d2", "#c7c7c7", "#dbdb8d", "#9edae5"];
function renderBudget(r) {
  if (!window.Plotly) return;
  const names = r.measurands.map((m) => m.name);
  const sources = [...new Set(r.measurands.flatMap((m) => Object.keys(m.budget)))];
  const traces = sources.map((s, i) => ({
    type: "bar", orientation: "h", name: s, y: names, marker: { color: PALETTE[i % PALETTE.length] },
    x: r.measurands.map((m) => (m.u > 0 ? 100 * (m.budget[s] || 0) ** 2 / (m.u * m.u) : 0)),
    hovertemplate: `${s}: %{x:.1f} %<extra></extra>`,
  }));
  const legendRows = Math.ceil(sources.length / 5);
  const h = Math.max(200, 20 * names.length + 70) + 22 * legendRows;  // plot: h - 58 - 22 rows
  $("budget-plot").style.height = h + "px";
  Plotly.react("budget-plot", traces, {
    barmode: "stack", margin: { l: 90, r: 10, t: 38, b: 20 + 22 * legendRows }, height: h,
    xaxis: { title: { text: "share of u\u00b2 [%]" }, range: [0, 100], side: "top" },
    yaxis: { autorange: "reversed" },
    legend: { orientation: "h", y: -8 / (h - 58 - 22 * legendRows), yanchor: "top", font: { size: 11 } },
  }, PLOT_CONFIG("budget"));
}
function logAxis(values) {
  // a logarithmic axis where U spans more than a factor 20 over the lever's range
  const pos = values.filter((v) => v > 0 && isFinite(v));
  if (pos.length && Math.max(...pos) / Math.min(...pos) > 20) return { type: "log" };
  return { rangemode: "tozero" };
}
function scheduleSensitivity() {
  clearTimeout(state.sensTimer);
  state.sensTimer = setTimeout(sensitivity, 120);
}
async function sensitivity() {
  const field = state.design.lever;
  if (!field) {  // none chosen yet: say how, rather than leave an empty frame
    $("sens-msg").textContent = "Move a lever (its slider or its value) to see U against it over its range.";
    return;
  }
  if (!state.lastResult || !state.lastResult.ok || !settled()) return;
  const lf = state.info.fields.find((f) => f.name === field);
  $("lever-name").textContent = lf ? label(lf) : field;
  const asked = state.changes;
  let s;
  try { s = await api("/api/sensitivity", { design: state.design, field, tab: state.tab, change: asked }); }
  catch (e) {  // said beside the plot: Plotly's own DOM stays, so the next curve draws
    $("sens-msg").textContent = "no sensitivity curve: " + e.message;
    $("sens-plot").classList.add("stale");
    return;
  }
  if (s.superseded || asked !== state.changes || !window.Plotly) return;
  $("sens-msg").textContent = "";
  $("sens-plot").classList.remove("stale");
  const withTarget = Object.keys(s.targets).filter((n) => n in s.U);
  let shown = withTarget.length ? withTarget : Object.keys(s.U);
  const unit = s.units[shown[0]];  // one unit on the axis: never um and urad together
  const other = shown.filter((n) => s.units[n] !== unit);
  shown = shown.filter((n) => s.units[n] === unit && !(s.untrusted || []).includes(n)).slice(0, 8);
  $("sens-msg").textContent = [other.length ? `not drawn (other unit): ${other.join(", ")}` : "",
    (s.untrusted || []).length ? `not drawn (first order not reliable): ${s.untrusted.join(", ")}` : ""].filter(Boolean).join("; ");
  const lever = state.info.fields.find((f) => f.name === s.field);
  const colours = ["#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b", "#e377c2", "#17becf"];
  const traces = [], shapes = [];
  shown.forEach((n, i) => {
    const c = colours[i % colours.length];
    traces.push({ x: s.x, y: s.U[n], mode: "lines+markers", name: `${n} [${unitText(s.units[n])}]`,
                  line: { color: c }, marker: { size: 5 } });
    if (n in s.targets) shapes.push({ type: "line", xref: "paper", x0: 0, x1: 1, y0: +s.targets[n],
                                      y1: +s.targets[n], line: { color: c, dash: "dash", width: 1.5 } });
  });
  if (s.current !== null) shapes.push({ type: "line", yref: "paper", y0: 0, y1: 1, x0: s.current,
                                        x1: s.current, line: { color: "#444", width: 1.5, dash: "dot" } });
  Plotly.react("sens-plot", traces, {
    margin: { l: 60, r: 10, t: 10, b: 45 }, height: 300, shapes,
    xaxis: { title: { text: `${lever ? label(lever) : s.field}${s.unit ? ` [${unitText(s.unit)}]` : ""} (dotted: current value)` } },
    yaxis: { title: { text: `U (k = 2) [${unitText(unit)}]` }, ...logAxis(shown.flatMap((n) => s.U[n])) },
    legend: { font: { size: 11 } },
  }, PLOT_CONFIG("sensitivity"));
  $("sens-plot").dataset.field = s.field;
}


// ------------------------------------------------------------------ views
const PLOT_CONFIG = (name) => ({ displaylogo: false, responsive: true, modeBarButtons: [["toImage"]],
                                 toImageButtonOptions: { filename: `${state.design.procedure}_${name}`, scale: 2 } });
function decision(m) {
  // what the design decides of one toleranced measurand, and its risks in plain words: the
  // judgement of mtplan.plans.acceptance (that of `mtplan accept`), one-sided ones included
  return `${m.name} ${m.acceptance.judgement.text}`;
}
function verdict(r) {
  // one line: what the design can decide
  const parts = [];
  const und = (r.identifiability && r.identifiability.undetermined) || [];
  if (und.length) parts.push(`it cannot determine ${und.join(", ")}`);
  const bad = r.measurands.filter((m) => m.trust === "no").map((m) => m.name);
  if (bad.length) parts.push(`first order failed its check for ${bad.join(", ")}`);
  // no decision on a number that is not checked: say why none is given
  for (const m of r.measurands.filter((x) => x.acceptance && x.acceptance.withheld))
    parts.push(`no verdict on ${m.name}: its u ${m.trust === "no" ? "failed its check" : (m.pending ? "is being checked" : "is not checked (" + m.why.replace(/^not checked: /, "") + ")")}`);
  const decided = r.measurands.filter((m) => m.trust === "ok" && m.acceptance && !m.acceptance.error && m.acceptance.acceptance_limits);
  for (const m of decided) parts.push(decision(m));
  const targeted = r.measurands.filter((m) => m.target !== undefined && m.trust === "ok");
  if (targeted.length) {
    const miss = targeted.filter((m) => m.U > m.target);
    parts.push(miss.length ? `${miss.map((m) => m.name).join(", ")} miss${miss.length === 1 ? "es" : ""} the target U` : "every target U is met");
  }
  if (!decided.length) {
    // what it could decide: a tolerance of +-4 U (TUR 4) or wider
    const ok = r.measurands.filter((m) => m.trust === "ok" && m.U > 0 && !und.includes(m.name));
    if (ok.length) parts.push("at a TUR of 4 it decides tolerances of \u00b14 U or wider: " +
      ok.slice(0, 4).map((m) => `${m.name} \u00b1${fmt3(4 * m.U)} ${unitText(m.unit)}`).join(", ") +
      (ok.length > 4 ? `, and ${ok.length - 4} more` : "") + " (enter a tolerance for its risks)");
  }
  $("verdict").textContent = parts.length ? "Verdict: " + parts.join("; ") + "." : "";
}
function fillSelect(id, names, keep) {
  const sel = $(id), was = sel.value;
  if ([...sel.options].map((o) => o.value).join(",") !== names.join(","))
    sel.replaceChildren(...names.map((n) => el("option", { value: n, text: n })));
  if (names.includes(keep)) sel.value = keep; else if (names.includes(was)) sel.value = was;
}
function renderBudgetTable(r) {
  fillSelect("budget-of", r.measurands.map((m) => m.name), state.budgetOf);
  const m = r.measurands.find((x) => x.name === $("budget-of").value) || r.measurands[0];
  const body = $("budget-table").querySelector("tbody");
  const doc = Object.fromEntries(state.info.fields.filter((f) => f.source).map((f) => [f.source, f.source_doc || f.doc]));
  body.replaceChildren(...(m.budget_table || []).map((b) => el("tr", {},
    el("td", { text: b.source, title: doc[b.source] || "" }),
    el("td", { text: b.input_u === null ? "-" : `${fmt3(b.input_u)} ${unitText(b.input_unit)}` }),
    el("td", { text: b.c === null ? "-" : `${fmt3(b.c)} ${unitText(m.unit)}/${unitText(b.input_unit)}` }),
    el("td", { text: `${fmt3(b.contribution)} ${unitText(m.unit)}` }),
    el("td", { text: b.share === null ? "-" : (b.share < 1e-4 ? "< 0.01 %" : pct(b.share)) }))));
  $("budget-table").classList.toggle("stale", m.trust === "no");
}
function renderRisk(r) {
  const names = r.measurands.filter((m) => m.acceptance && !m.acceptance.error && m.acceptance.acceptance_limits).map((m) => m.name);
  fillSelect("risk-of", names, state.riskOf);
  const m = r.measurands.find((x) => x.name === $("risk-of").value);
  const area = $("risk-plot").parentElement;  // no empty frames where there is no curve
  if (!m || !window.Plotly) {
    $("risk-msg").hidden = false;
    area.hidden = true;
    return;
  }
  area.hidden = false;
  const a = m.acceptance, unit = unitText(m.unit);
  for (const id of ["risk-plot", "zone-plot"]) $(id).classList.remove("stale");
  $("risk-msg").hidden = !!a.curve;
  if (a.curve) {
    Plotly.react("risk-plot", [
      { x: a.curve.guard_band, y: a.curve.pfa.map((p) => 100 * p), name: "PFA", mode: "lines", line: { color: "#d62728" } },
      { x: a.curve.guard_band, y: a.curve.pfr.map((p) => 100 * p), name: "PFR", mode: "lines", line: { color: "#1f77b4" } },
      { x: [a.guard_band, a.guard_band], y: [100 * a.pfa, 100 * a.pfr], name: "this design", mode: "markers",
        marker: { size: 10, color: "#222", symbol: "diamond" } },
    ], { margin: { l: 55, r: 10, t: 10, b: 45 }, height: 280, legend: { font: { size: 11 } },
         xaxis: { title: { text: `guard band w [${unit}]` }, rangemode: "tozero" },
         yaxis: { title: { text: "probability [%]" }, rangemode: "tozero" } }, PLOT_CONFIG("risk"));
  } else Plotly.purge("risk-plot");
  // the zones of ISO 14253-1 on the measurand's axis (from mtplan.plans.acceptance.zones):
  // a one-sided tolerance's open side runs to the edge of the view, and is not rejected
  const z = a.zones, [x0, x1] = z.view, at = (x, end) => (x === null ? end : x);
  const band = (xa, xb, y0, y1, color, text) => ({ type: "rect", x0: at(xa, x0), x1: at(xb, x1), y0, y1,
                                                   fillcolor: color, line: { width: 0 }, layer: "below", name: text });
  const mid = (lim) => (at(lim[0], x0) + at(lim[1], x1)) / 2;
  Plotly.react("zone-plot", [
    { x: [mid(z.tolerance)], y: [2.5], mode: "text", text: ["tolerance zone"], showlegend: false, hoverinfo: "skip" },
    { x: [mid(z.acceptance)], y: [1.5], mode: "text", text: ["accept"], showlegend: false, hoverinfo: "skip" },
  ], { margin: { l: 70, r: 10, t: 10, b: 45 }, height: 280, showlegend: false,
       shapes: [band(z.tolerance[0], z.tolerance[1], 2, 3, "#cfe8d4", "tolerance"),
                band(z.acceptance[0], z.acceptance[1], 1, 2, "#9fd3a9", "acceptance"),
                ...z.reject.map(([p, q]) => band(p, q, 1, 2, "#f4c7c3", "reject")),
                ...z.uncertainty.map(([p, q]) => band(p, q, 0.1, 0.9, "#c9d7ea", "U at a limit"))],
       xaxis: { title: { text: `${m.name} [${unit}]` }, range: [x0, x1] },
       yaxis: { range: [0, 3.2], tickvals: [0.5, 1.5, 2.5], ticktext: ["\u00b1U at limits", "decision", "specification"], fixedrange: true } },
    PLOT_CONFIG("zones"));
}
function renderHistogram(r) {
  // the Monte Carlo values of one measurand with its tolerance and acceptance limits
  const ms = r.measurands.filter((m) => m.histogram);
  if (!ms.length || !window.Plotly) return;
  const box = el("div", { id: "mc-hist", class: "plot" });
  const sel = el("select", { id: "mc-hist-of", "aria-label": "Measurand of the Monte Carlo histogram" },
                 ...ms.map((m) => el("option", { value: m.name, text: m.name })));
  $("job-result").append(el("h3", {}, "Monte Carlo values of ", sel), box);
  const draw = () => {
    const m = ms.find((x) => x.name === sel.value), h = m.histogram, unit = unitText(m.unit);
    const mids = h.edges.slice(0, -1).map((e, i) => (e + h.edges[i + 1]) / 2);
    const tol = state.design.tolerances[m.name] || {};
    const acc = ((state.lastResult && state.lastResult.measurands) || []).find((x) => x.name === m.name);
    const lim = acc && acc.acceptance && acc.acceptance.acceptance_limits;
    const shapes = [], line = (x, color, dash) => shapes.push({ type: "line", x0: x, x1: x, yref: "paper", y0: 0, y1: 1, line: { color, dash, width: 2 } });
    for (const k of ["lower", "upper"]) if (tol[k] !== undefined && tol[k] !== "") line(+tol[k], "#b3261e", "solid");
    if (lim) for (const x of lim) if (x !== null) line(x, "#1e7b34", "dash");  // one-sided: one
    Plotly.react(box, [{ type: "bar", x: mids, y: h.counts, marker: { color: "#6d8fb3" }, name: "trials" }],
      { margin: { l: 55, r: 10, t: 10, b: 45 }, height: 260, bargap: 0, shapes,
        xaxis: { title: { text: `${m.name} [${unit}] (red: tolerance limits, green dashed: acceptance limits)` } },
        yaxis: { title: { text: "trials" } } }, PLOT_CONFIG("montecarlo_" + m.name));
  };
  sel.addEventListener("change", draw);
  draw();
}
function tableCSV(id) {
  // a table as shown, inputs by their values
  const rows = [...$(id).querySelectorAll("tr")].map((tr) => [...tr.children].map((c) => {
    const i = c.querySelector("input:not([type=file]), select");
    const t = i ? i.value : c.textContent;
    return /[",\n]/.test(t) ? `"${t.replace(/"/g, '""')}"` : t;
  }).join(","));
  const a = el("a", { href: URL.createObjectURL(new Blob([rows.join("\n") + "\n"], { type: "text/csv" })),
                      download: `${state.design.procedure}_${id}.csv` });
  document.body.append(a); a.click(); a.remove();
}
function undo() {
  const prev = state.history.pop();
  if (!prev) { banner("Nothing to undo."); return; }
  state.undoing = true;
  const design = JSON.parse(prev);
  if (design.procedure !== state.design.procedure || !state.info) openDesign(design);
  else { state.design = design; buildControls(); changed(); }
}
//: the terms of the page's own headings and figures, by their glossary names
const TERMS = ["u", "U", "target", "share", "c_i", "T_L", "prior", "simple", "TUR", "w", "A_L",
               "PFA", "PFR", "conditional PFA", "O1", "rank"];
function term(name) { return (state.glossary || []).find((g) => g.names.includes(name)); }
function helpText(g) { return `${g.label}: ${g.meaning}`; }
function applyTerms() {
  // every heading that names a term says what it means (the glossary's words)
  document.querySelectorAll("[data-term]").forEach((e) => {
    const g = term(e.dataset.term);
    if (g) { e.title = helpText(g); e.classList.add("term"); }
  });
}
function codeCell(m) {
  // a measurand's code, its help as a tooltip and a link to its entry in the help list
  const tip = m.help || m.description || "";
  return m.anchor ? el("a", { class: "code", href: "#" + m.anchor, title: tip, text: m.name })
                  : el("span", { class: "code", title: tip, text: m.name });
}
function openHelp(id) {
  $("help").open = true;
  const target = $(id) || $("help");
  target.scrollIntoView({ block: "center" });
  document.querySelectorAll("#help-list .hit").forEach((e) => e.classList.remove("hit"));
  state.helpHit = target.tagName === "DT" ? id : null;  // kept when a new result redraws the list
  if (state.helpHit) target.classList.add("hit");
}
function renderHelp(r) {
  // every code and term on the page, in the glossary's words and the procedure's own
  // (a refused set-up too: its measurands are those of the acceptance table)
  if (!state.glossary || !state.info) return;
  const measurands = (r && r.ok ? r.measurands : r && r.measurand_names) || state.info.measurands;
  applyTerms();
  const items = [], seen = new Set();
  const add = (id, label, text) => {
    if (seen.has(id)) return;
    seen.add(id);
    items.push(el("dt", { id, text: label }), el("dd", { text }));
  };
  const group = (text) => items.push(el("dt", { class: "group", text }));
  group("Terms (docs/glossary.md)");
  for (const t of TERMS) { const g = term(t); if (g) add(g.anchor, g.label, `${g.meaning} (${g.section})`); }
  group("Measurands of this set-up");
  for (const m of measurands) {
    const g = m.anchor && state.glossary.find((x) => x.anchor === m.anchor);
    if (g) add(g.anchor, g.label, `${g.meaning} (${g.section})`);
    else add("help-m-" + m.name, m.name, m.description);
  }
  group(`Estimators of ${state.info.name}`);
  for (const [name, text] of Object.entries(state.info.estimator_help || {})) add("help-est-" + name, name, text);
  group("The test's levers");
  for (const f of state.info.fields.filter((x) => x.lever))
    add("help-f-" + f.name, label(f) + (f.unit ? ` [${unitText(f.unit)}]` : ""), f.doc);
  group("Error sources");
  for (const f of state.info.fields.filter((x) => x.source))
    add("help-s-" + f.source, f.source, f.source_doc || f.doc);
  $("help-list").replaceChildren(...items);
  // the entry the user opened stays marked when a later result redraws the list
  if (state.helpHit && $(state.helpHit)) $(state.helpHit).classList.add("hit");
}

// ------------------------------------------------------------------ jobs
function estimateOld() {
  // the time said is that of the design shown, never of an earlier one
  state.estimates = (state.estimates || 0) + 1;
  $("job-estimate").textContent = "estimating the Monte Carlo's time\u2026";
  $("job-estimate").className = "label";
  delete $("job-estimate").dataset.design;
}
function scheduleEstimate() {
  clearTimeout(state.estimateTimer);
  state.estimateTimer = setTimeout(() => {
    if (!settled()) return;  // the render of the newest change asks again
    const r = state.lastResult;
    if (r && r.ok) jobEstimate();
    else { estimateOld(); $("job-estimate").textContent = "no Monte Carlo time: the set-up is not evaluated"; }
  }, 250);
}
async function jobEstimate() {
  // the time a Monte Carlo of these trials would take, said before it starts; after every
  // change of the set-up, the seed or the trials (an answer overtaken by a change is dropped)
  const asked = (state.estimates = (state.estimates || 0) + 1), design = JSON.stringify(state.design);
  let text, cls;
  try {
    const e = await api("/api/jobs/estimate", { kind: "confirm", design: state.design });
    [text, cls] = e.fits ? [`${e.design.trials} trials: ${e.text}`, "label"] : [e.refusal, "err"];
  } catch (e) { [text, cls] = [e.message, "err"]; }
  if (asked !== state.estimates) return;
  $("job-estimate").textContent = text;
  $("job-estimate").className = cls;
  $("job-estimate").dataset.design = design;
}
async function startJob(kind) {
  if (state.job) await cancelJob();
  let id;
  $("job-area").scrollIntoView({ block: "nearest" });
  try { id = (await api("/api/jobs", { kind, design: state.design })).id; }
  catch (e) { $("job-result").replaceChildren(el("span", { class: "err", id: "job-error", text: e.message })); return; }
  state.job = { id, kind, changes: state.changes };
  $("job").hidden = false;
  $("job-label").textContent = { confirm: "Monte Carlo running", check: "Checking first order", cheapest: "Planner searching" }[kind];
  $("job-progress").removeAttribute("value");
  $("job-result").replaceChildren();
  $("job-result").classList.remove("stale");
  pollJob(id);
}
async function pollJob(id) {
  if (!state.job || state.job.id !== id) return;
  let s;
  try { s = await api("/api/jobs/" + id); } catch (e) { s = { state: "error", error: e.message }; }
  if (!state.job || state.job.id !== id) return;
  if (s.state === "running") {
    if (s.total) { $("job-progress").value = s.done / s.total; $("job-label").textContent = `Monte Carlo: ${s.done} of ${s.total} trials`; }
    else $("job-label").textContent = `${{ confirm: "Monte Carlo", check: "Checking first order", cheapest: "Planner" }[state.job.kind]}: ${s.elapsed_s.toFixed(0)} s`;
    setTimeout(() => pollJob(id), 300);
    return;
  }
  const changedSince = state.job.changes !== state.changes;
  state.job = null;
  $("job").hidden = true;
  $("job-result").classList.remove("stale");
  if (s.state === "error") $("job-result").replaceChildren(el("span", { class: "err", id: "job-error", text: s.error }));
  else if (s.state === "cancelled") $("job-result").replaceChildren(el("span", { id: "job-cancelled", text: "cancelled" }));
  else if (s.kind === "confirm") showConfirm(s.result);
  else if (s.kind === "check") {  // the server keeps the check: the numbers again, checked
    $("job-result").replaceChildren(el("span", { id: "check-done", text: "First order checked: the numbers above are marked by it." }));
    if (!changedSince) { state.t0 = 0; refresh(); }
  }
  else showPlan(s.result);
  if (changedSince) markJobStale();
  $("job-result").scrollIntoView({ block: "nearest" });
}
async function cancelJob() {
  if (!state.job) return;
  const id = state.job.id;
  state.job = null;
  $("job").hidden = true;
  try { await api(`/api/jobs/${id}/cancel`, {}); } catch (e) { /* finished meanwhile */ }
  $("job-result").replaceChildren(el("span", { id: "job-cancelled", text: "cancelled" }));
}
function showConfirm(r) {
  const rows = r.measurands.map((m) => el("tr", { id: "mc-" + m.name },
    el("td", { text: m.name }), el("td", { text: unitText(m.unit) }),
    el("td", { class: "mc-u", text: fmt3(m.u) }), el("td", { class: "mc-U", text: fmt3(m.U) }),
    el("td", { text: fmt3(2 * m.predicted_u) }),
    el("td", { text: m.predicted_u > 0 ? fmt3(m.u / m.predicted_u) : "-" }),
    el("td", { text: `[${fmt3(m.interval[0])}, ${fmt3(m.interval[1])}]` })));
  const head = el("tr", {}, ...["Measurand", "Unit", "MC u", "MC U (k=2)", "predicted U", "MC / predicted u", "95 % interval"].map((t) => el("th", { text: t })));
  $("job-result").replaceChildren(
    el("div", { id: "mc-summary", text: `Monte Carlo: ${r.trials} trials, seed ${r.seed}, estimator ${r.estimator} (as mtplan simulate)` }),
    el("table", { id: "mc-table" }, el("thead", {}, head), el("tbody", {}, ...rows)),
    ...(r.findings || []).map((f) => el("div", { class: "err", text: f })));
  renderHistogram(r);
}
function showPlan(r) {
  const best = r.best;
  const now = (state.lastResult && state.lastResult.setup) || {};
  const changes = Object.entries(best.setup).filter(([k, v]) => String(v) !== String(now[k]));
  const use = el("button", { id: "use-plan", text: "Use this set-up" });
  use.addEventListener("click", () => {
    for (const [k, v] of Object.entries(best.setup)) {
      if (v === null) continue;
      state.design.setup[k] = Array.isArray(v) ? v.join(",") : String(v);
    }
    buildControls(); changed();
  });
  $("job-result").replaceChildren(
    el("div", { id: "plan-summary", text: `Cheapest of ${r.tried} candidates: ${duration(best.duration_s)}; ` +
      Object.entries(best.confirmed || {}).map(([n, u]) => `${n} U = ${fmt3(u)} (Monte Carlo)`).join(", ") }),
    el("div", { text: "Set-up: " + changes.map(([k, v]) => `${k} = ${v}`).join(", ") }), use);
}

// ------------------------------------------------------------------ export / load
async function exportStudy() {
  try {
    const { toml } = await api("/api/export", state.design);
    state.lastExport = toml;
    const a = el("a", { href: URL.createObjectURL(new Blob([toml], { type: "application/toml" })),
                        download: `${state.design.procedure}_study.toml` });
    document.body.append(a); a.click(); a.remove();
  } catch (e) { banner("Export refused: " + e.message); }
}
async function loadStudy(text) {
  try {
    const { design } = await api("/api/load", { toml: text });
    await openDesign(design);
  } catch (e) { banner("The study file was not loaded: " + e.message); }
}

// ------------------------------------------------------------------ start
async function openDesign(design) {
  state.design = design;
  state.info = await api("/api/procedure/" + design.procedure);
  if (!state.design.estimator) state.design.estimator = state.info.default_estimator;
  buildControls();
  changed();
}
function blank(name) {
  return { procedure: name, setup: {}, off: [], estimator: null, tolerances: {}, targets: {},
           vary: {}, lever: null, seed: 0, trials: 10000 };
}
async function init() {
  const { procedures, initial } = await api("/api/procedures");
  state.procedures = procedures;
  $("procedure").replaceChildren(...procedures.map((p) => el("option", { value: p.name, text: `${p.name}: ${p.title}` })));
  let design = initial || blank("rotary_axis");
  const d = new URL(location.href).searchParams.get("d");
  if (d) { try { design = b64decode(d); } catch (e) { banner("The link's design could not be read; starting from the defaults."); } }
  design = { ...blank(design.procedure || "rotary_axis"), ...design };
  await openDesign(design);
  $("procedure").addEventListener("change", () => openDesign(blank($("procedure").value)));
  $("estimator").addEventListener("change", () => {
    state.design.estimator = $("estimator").value;
    $("estimator").title = (state.info.estimator_help || {})[state.design.estimator] || "";
    changed();
  });
  document.addEventListener("click", (e) => {  // a code's link opens its help entry
    const a = e.target.closest("a[href^='#help']");
    if (!a) return;
    e.preventDefault();
    openHelp(a.getAttribute("href").slice(1));
  });
  $("seed").addEventListener("change", () => { state.design.seed = number($("seed").value, 0); pushURL(); renderReport(state.lastResult); jobEstimate(); });
  $("trials").addEventListener("change", () => { state.design.trials = number($("trials").value, 10000); pushURL(); renderReport(state.lastResult); jobEstimate(); });
  $("confirm").addEventListener("click", () => startJob("confirm"));
  $("cheapest").addEventListener("click", () => startJob("cheapest"));
  $("job-cancel").addEventListener("click", cancelJob);
  $("export").addEventListener("click", exportStudy);
  $("reset").addEventListener("click", () => openDesign(blank(state.design.procedure)));
  $("undo").addEventListener("click", undo);
  $("keep").addEventListener("click", keepScenario);
  $("print").addEventListener("click", () => window.print());
  document.querySelectorAll("button.csv").forEach((b) => b.addEventListener("click", () => tableCSV(b.dataset.table)));
  $("budget-of").addEventListener("change", () => { state.budgetOf = $("budget-of").value; renderBudgetTable(state.lastResult); });
  $("risk-of").addEventListener("change", () => { state.riskOf = $("risk-of").value; renderRisk(state.lastResult); });
  api("/api/glossary").then((g) => { state.glossary = g.terms; renderHelp(state.lastResult); }).catch(() => {});
  specificInit();
  state.scenarios = loadScenarios();
  renderScenarios();
  $("load").addEventListener("change", async () => {
    const f = $("load").files[0]; if (f) await loadStudy(await f.text()); $("load").value = "";
  });
  document.body.dataset.ready = "1";
}
init().catch((e) => banner("The page could not start: " + e.message));
