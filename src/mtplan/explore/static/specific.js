// mtplan explore: the specific risk of a value measured on a machine (JCGM 106: the
// probability that the measurand is outside its tolerance given the measured value y and
// the design's u, with the population as the prior when one is entered) and the decision
// the rule makes for it. The value is part of the design (its tolerance row's `measured`),
// so the server computes it with `mtplan accept --measured`'s function, from a u that was
// checked; the link and the print keep it.
"use strict";

function specificMeasurands(r) {
  return r && r.ok ? r.measurands.filter((m) => (state.design.tolerances[m.name] || {}).lower || (state.design.tolerances[m.name] || {}).upper) : [];
}
function renderSpecific(r) {
  const ms = specificMeasurands(r);
  $("specific").hidden = !ms.length;
  if (!ms.length) return;
  fillSelect("specific-of", ms.map((m) => m.name), state.specificOf);
  const m = ms.find((x) => x.name === $("specific-of").value) || ms[0];
  const tol = state.design.tolerances[m.name] || {}, box = $("specific-value");
  if (document.activeElement !== box) box.value = tol.measured ?? "";
  box.setAttribute("aria-label", `${m.name}: a measured value [${unitText(m.unit)}]`);
  $("specific-unit").textContent = unitText(m.unit);
  $("specific-out").className = "label";
  $("specific-out").textContent = specificText(m, tol);
  if (m.acceptance && m.acceptance.error) $("specific-out").className = "err";
}
function specificText(m, tol) {
  // the specific risk of the measured value in words
  const a = m.acceptance;
  if ((tol.measured ?? "") === "") return "enter a value measured on a machine for its risk of being out of tolerance";
  if (m.trust !== "ok") return `no specific risk until u(${m.name}) is checked against its Monte Carlo (${checkWords(m)})`;
  if (!a || a.error) return "no specific risk: " + ((a && a.error) || `u(${m.name}) gives no acceptance figures`);
  if (a.specific_risk === null || a.specific_risk === undefined) return "no specific risk for this value";
  const y = `${fmt4(a.measured)} ${unitText(m.unit)}`;
  return `P(${m.name} outside its tolerance | y = ${y}) = ${pct(a.specific_risk)}` +
    `${a.prior ? " (with the population as prior)" : " (normal, from y and u alone)"}; ` +
    `the rule ${a.rule} ${a.decision === "accept" ? "accepts" : "rejects"} it`;
}
function specificInit() {
  $("specific-of").addEventListener("change", () => { state.specificOf = $("specific-of").value; renderSpecific(state.lastResult); });
  $("specific-value").addEventListener("change", () => {
    const name = $("specific-of").value, t = { ...(state.design.tolerances[name] || {}) };
    if (!name) return;
    t.measured = $("specific-value").value.trim();
    if (t.measured === "") delete t.measured;
    state.design.tolerances[name] = t;
    changed();
  });
}
