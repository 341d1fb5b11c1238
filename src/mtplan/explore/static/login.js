// mtplan explore: the login page. It asks for the launch's token, sends it as JSON to
// this server (which sets the cookie) and opens the page it was sent from (?next=...),
// the design in its link included. It reads nothing from the server but the answer.
"use strict";
(function () {
  const next = new URL(location.href).searchParams.get("next") || "/";
  document.getElementById("keeps").hidden = !/[?&]d=/.test(next);
  function token(text) {
    // the printed link or the token alone
    const t = text.trim();
    const m = /[?&]token=([^&#\s]+)/.exec(t);
    return m ? decodeURIComponent(m[1]) : t;
  }
  document.getElementById("login-form").addEventListener("submit", async (e) => {
    e.preventDefault();
    const error = document.getElementById("login-error");
    error.textContent = "";
    let r, data;
    try {
      r = await fetch("/login", { method: "POST", headers: { "Content-Type": "application/json" },
                                  body: JSON.stringify({ token: token(document.getElementById("token").value), next }) });
      data = await r.json().catch(() => ({ error: r.statusText }));
    } catch (err) { error.textContent = "The designer does not answer: is `mtplan explore` running?"; return; }
    if (!r.ok) { error.textContent = data.error || r.statusText; return; }
    location.replace(data.next);  // the server's own path, never another site
  });
  document.body.dataset.ready = "1";
})();
