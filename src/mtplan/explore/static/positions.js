// mtplan explore: where the set-up measures. The points of the readings table that the
// procedure's forward model gives for the set-up without errors (the server's
// /api/positions), seen from above (x, y) and from the side (x, z), one colour per group
// (a rotary position, a plane, a scan, a group of marks). Asked again only when the
// set-up changes, once the numbers are shown.
"use strict";

function schedulePositions() {
  clearTimeout(state.positionsTimer);
  state.positionsTimer = setTimeout(positions, 200);
}
async function positions() {
  const r = state.lastResult;
  if (!r || !r.ok || !settled() || !window.Plotly) return;
  const key = JSON.stringify([state.design.procedure, r.setup]);
  if (state.positionsKey === key) return;
  let p;
  try { p = await api("/api/positions", { design: state.design }); }
  catch (e) { $("positions-msg").textContent = "no picture of the positions: " + e.message; $("positions-plot").classList.add("stale"); return; }
  const now = state.lastResult;  // a newer set-up's numbers came meanwhile: its own turn draws
  if (!now || !now.ok || JSON.stringify([state.design.procedure, now.setup]) !== key) return;
  state.positionsKey = key;
  $("positions-plot").classList.remove("stale");
  const groups = [...new Set(p.group)];
  const size = p.x.length > 600 ? 3 : 6, side = p.z !== null;
  const traces = [];
  groups.forEach((g, i) => {
    const rows = p.group.map((x, k) => (x === g ? k : -1)).filter((k) => k >= 0);
    const name = p.group_by ? `${p.group_by} ${g}` : "points";
    const marker = { size, color: PALETTE[i % PALETTE.length], opacity: 0.75 };
    traces.push({ type: "scatter", mode: "markers", name, legendgroup: name, marker,
                  x: rows.map((k) => p.x[k]), y: rows.map((k) => p.y[k]), xaxis: "x", yaxis: "y" });
    if (side) traces.push({ type: "scatter", mode: "markers", name, legendgroup: name, showlegend: false, marker,
                            x: rows.map((k) => p.x[k]), y: rows.map((k) => p.z[k]), xaxis: "x2", yaxis: "y2" });
  });
  // a phone: the two views one above the other, the groups below them
  const narrow = $("positions-plot").clientWidth < 700, height = narrow && side ? 640 : (narrow ? 420 : 320);
  $("positions-plot").style.height = height + "px";
  const axis = (title, anchor) => ({ title: { text: title }, zeroline: false, ...(anchor ? { scaleanchor: anchor } : {}) });
  const [d1, d2] = narrow ? [[0, 1], [0, 1]] : [[0, 0.47], [0.53, 1]];
  const [h1, h2] = narrow && side ? [[0.58, 1], [0.1, 0.46]] : [[0, 1], [0, 1]];
  Plotly.react("positions-plot", traces, {
    margin: { l: 55, r: 10, t: 24, b: 45 }, height,
    legend: narrow ? { orientation: "h", y: side ? 0 : -0.25, yanchor: "top", font: { size: 11 } } : { font: { size: 11 } },
    xaxis: { ...axis("x [mm]"), domain: side ? d1 : [0, 1] }, yaxis: { ...axis("y [mm]", "x"), domain: h1 },
    ...(side ? { xaxis2: { ...axis("x [mm]"), domain: d2, anchor: "y2" }, yaxis2: { ...axis("z [mm]", "x2"), domain: h2, anchor: "x2" } } : {}),
    annotations: [{ text: "from above (x, y)", xref: "x domain", yref: "y domain", x: 0, y: 1.08, showarrow: false, xanchor: "left", font: { size: 11 } },
                  ...(side ? [{ text: "from the side (x, z)", xref: "x2 domain", yref: "y2 domain", x: 0, y: 1.08, showarrow: false, xanchor: "left", font: { size: 11 } }] : [])],
  }, PLOT_CONFIG("positions"));
  $("positions-msg").textContent = `${p.n} readings` + (p.x.length < p.n ? ` (${p.x.length} drawn, evenly spaced)` : "") + `: ${p.how}.`;
  $("positions-plot").dataset.points = String(p.x.length);
}
