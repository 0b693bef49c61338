// The supervisor console: renders the session's snapshot and live events (SSE), posts commands.
"use strict";
const $ = (id) => document.getElementById(id);
const ACTIONS = ["L1", "L2", "L3", "L4", "RF1", "RF2"];
const FEEDBACK = {0: "", 1: "encouraging", 2: "challenging"};
let S = null;            // the snapshot, kept up to date by the events
let ended = false;       // the session is over: nothing is live, no control acts
let chart = null, eegChart = null;
const eegSeries = [[], []];

function pill(id, text, cls) { const el = $(id); el.textContent = text; el.className = "pill " + (cls || ""); }
function fmt(x, d = 2) { return x === null || x === undefined || x === "" ? "–" : Number(x).toFixed(d); }
function letters(el, text, cmp) {
  el.innerHTML = "";
  [...(text || "")].forEach((ch, i) => {
    const s = document.createElement("span"); s.textContent = ch;
    if (cmp !== undefined) s.className = cmp[i] === ch ? "right" : "wrong";
    el.appendChild(s);
  });
}

function renderHeader() {
  if (ended) { renderEnded(); return; }
  const m = S.machine || {};
  const status = S.summary ? S.summary.status : (S.paused ? "paused" : (m.state ? "running" : "starting"));
  pill("status", status, S.summary ? (S.summary.exit_code === 0 ? "ok" : "warn") : (S.paused ? "warn" : "ok"));
  pill("machine", "state: " + (m.state || "–"));
  pill("robot", "robot: " + S.robot, S.robot === "connected" ? "ok" : "bad");
  const lost = S.eeg_missing;
  pill("eeg-alert", lost ? `no EEG for ${lost.missing_turns} turns (${lost.reason || "no value"})` : "", lost ? "bad" : "");
  $("eeg-alert").hidden = !lost;
  const sess = S.session || {};
  $("policy-name").textContent = sess.policy || "";
}

function renderTurn() {
  const t = S.turn;
  if (!t) return;
  $("turn-no").textContent = "#" + t.turn + " of " + ((S.session || {}).turns || "?");
  $("turn-level").textContent = "Level " + t.level;
  $("turn-feedback").textContent = FEEDBACK[t.feedback] ? "· " + FEEDBACK[t.feedback] + " feedback" : "";
  $("turn-action").textContent = "action " + t.action + " chosen in " + t.chosen_in;
  letters($("sequence"), t.sequence);
  letters($("presses"), S.presses.map((p) => p.letter || "?").join(""), t.expected === undefined ? t.sequence : t.expected);
  $("turn-notes").textContent = t.notes || "";
  renderProbs();
}

function renderProbs() {
  const t = S.turn, box = $("probs");
  box.innerHTML = "";
  if (!t || !t.probabilities) { box.textContent = "this policy has no probabilities"; return; }
  $("policy-state").textContent = "P(action | " + t.chosen_in + ")";
  ACTIONS.forEach((a) => {
    const p = t.probabilities[a] || 0, row = document.createElement("div");
    row.className = "prob";
    row.innerHTML = `<span>${a}</span><div><div class="b${a === t.action ? " chosen" : ""}" style="width:${(100 * p).toFixed(1)}%"></div></div><span>${p.toFixed(2)}</span>`;
    box.appendChild(row);
  });
}

function renderPolicyStatus() {
  // What a personalising policy believes: the posterior over user models and what it follows.
  const p = S.policy_status, box = $("policy-status");
  if (!p || !p.posterior) { box.textContent = ""; return; }
  // posterior_text names each model as the terminal does ("user model 3", the words of the policy line)
  const ranked = Object.entries(p.posterior).sort((a, b) => b[1] - a[1]);
  box.textContent = "posterior: " + (p.posterior_text || ranked.map(([n, w]) => n + " " + fmt(w)).join(" | ")) +
    (p.following ? " · policy: " + (p.policy || p.following) : " · assessment");
}

function rowClass(r) {
  if (r.invalid === true || r.invalid === "True") return "invalid";
  if (r.success === null || r.success === "") return "interrupted";
  return r.success ? "pass" : "fail";
}

// The turn table's columns are the task's: [row key, header] pairs sent in the session event (tasks.base.table_fields).
const SHOW = {
  feedback: (v) => FEEDBACK[v] || "",
  success: (v) => (v === null || v === undefined || v === "" ? "–" : (v === true || v === "True" ? "✓" : "✗")),
  score: (v) => (v === null || v === undefined || v === "" ? "–" : v),
  engagement: (v) => fmt(v),
};
let shownFields = null;  // the header drawn (JSON of the fields), redrawn when the task's fields change

function tableFields() { return (S.session || {}).fields || []; }

function renderHead() {
  const fields = tableFields(), key = JSON.stringify(fields);
  if (key === shownFields) return;
  shownFields = key;
  const tr = $("turns").querySelector("thead tr");
  tr.innerHTML = "";
  fields.forEach(([name, header]) => {
    const th = document.createElement("th"); th.textContent = header; th.dataset.field = name; tr.appendChild(th);
  });
}

function renderRows() {
  renderHead();
  const body = $("turns").querySelector("tbody"), fields = tableFields();
  body.innerHTML = "";
  S.rows.slice().reverse().forEach((r) => {
    const tr = document.createElement("tr"); tr.className = rowClass(r);
    fields.forEach(([name]) => {
      const v = r[name], td = document.createElement("td");
      td.textContent = SHOW[name] ? SHOW[name](v) : (v === null || v === undefined ? "" : v);
      td.dataset.field = name;
      if (name === "success") td.className = "ok";
      tr.appendChild(td);
    });
    body.appendChild(tr);
  });
  const last = S.rows.length ? S.rows[S.rows.length - 1] : null;
  $("score").textContent = last ? "total score " + last.total : "";
  renderChart();
}

function renderChart() {
  const done = S.rows.filter((r) => r.success === true || r.success === false);
  const xs = done.map((r) => r.turn);
  const eng = done.map((r) => (r.engagement === null ? null : r.engagement));
  const lvl = done.map((r) => r.level / 4);
  const data = [xs, eng, lvl];
  const width = Math.max(300, $("chart-card").clientWidth - 24);
  if (!chart) {
    chart = new uPlot({ width, height: 200, scales: { x: { time: false }, y: { range: [0, 1] } },
      series: [{ label: "turn" }, { label: "engagement", stroke: "#1f6fd1", width: 2, points: { show: true } },
               { label: "level / 4", stroke: "#b36b00", dash: [4, 4] }],
      axes: [{ label: "turn", incrs: [1, 2, 5, 10, 20, 50] }, {}] }, data, $("chart"));
  } else { chart.setData(data); }
}

function renderTick(tick) {
  const sess = S.session || {};
  // tick.elapsed is wall seconds; session.max_duration_s is in session seconds (sped up by `speed`)
  const el = tick.elapsed, speed = sess.speed || 1, max = sess.max_duration_s ? sess.max_duration_s / speed : null;
  if (el !== undefined && el !== null) {
    $("elapsed").textContent = Math.round(el) + " s" + (max ? " of " + Math.round(max) + " s" : " (no limit)") +
      (speed !== 1 ? " (wall clock; the session runs x" + speed + ")" : "");
    $("elapsed-bar").style.width = max ? Math.min(100, 100 * el / max) + "%" : "0";
  }
  const e = tick.eeg;
  if (!e) { pill("eeg", sess.eeg ? "EEG: waiting" : "EEG: off", sess.eeg ? "warn" : ""); return; }
  pill("eeg", "EEG: " + e.status, e.status === "streaming" ? "ok" : "bad");
  $("eeg-index").textContent = fmt(e.index, 3);
  $("eeg-reason").textContent = e.reason || "";
  const ch = $("channels"); ch.innerHTML = "";
  Object.entries(e.channels || {}).forEach(([name, good]) => {
    const s = document.createElement("span"); s.className = good ? "good" : "poor";
    s.textContent = name + (good ? " contact ok" : " poor contact"); ch.appendChild(s);
  });
  if (e.index !== null && e.index !== undefined) {
    eegSeries[0].push(eegSeries[0].length); eegSeries[1].push(e.index);
    if (eegSeries[0].length > 240) { eegSeries[0].shift(); eegSeries[1].shift(); }
    const width = Math.max(300, $("eeg-card").clientWidth - 24);
    if (!eegChart) {
      eegChart = new uPlot({ width, height: 120, scales: { x: { time: false } }, legend: { show: false },
        series: [{}, { stroke: "#7b3fc4", width: 1.5 }], axes: [{ show: false }, {}] }, eegSeries, $("eeg-chart"));
    } else { eegChart.setData(eegSeries); }
  }
}

function logCommand(c) {
  const li = document.createElement("li");
  li.className = c.accepted ? "" : "refused";
  li.textContent = `${(c.at || "").slice(11, 19)} ${c.kind} (${c.source}) ${c.accepted ? "✓" : "refused"}: ${c.detail || ""}`;
  $("log").prepend(li);
}

function renderSummary() {
  const s = S.summary; if (!s) return;
  $("summary-card").classList.remove("hidden");
  const lv = s.levels.map((l) => `L${l.level}: ${l.played} played, ${l.success_rate === null ? "–" : Math.round(100 * l.success_rate) + "%"}`).join(" · ");
  $("summary").innerHTML = "";
  [`status: ${s.status} (exit ${s.exit_code})`, `turns completed: ${s.turns_completed}, total score ${s.total_score}`,
   `mean engagement: ${fmt(s.mean_engagement)}`, lv].forEach((t) => { const d = document.createElement("div"); d.textContent = t; $("summary").appendChild(d); });
}

function endSession() {
  // The session is over (its summary arrived, or the server said so): say how, and disable the controls.
  ended = true;
  renderEnded();
}

function renderEnded() {
  const s = S && S.summary;
  const how = s ? `${s.status} (exit ${s.exit_code})` : "ended";
  pill("status", "session ended: " + how, s && s.exit_code === 0 ? "ok" : "warn");
  pill("robot", "robot: session ended");
  pill("eeg", "EEG: session ended");
  pill("link", "stream: session ended");
  $("ended").textContent = "The session has ended" + (s ? ": " + how : "") + ". The controls no longer act.";
  $("ended").classList.remove("hidden");
  document.querySelectorAll("#controls button, #controls input, #controls select").forEach((el) => { el.disabled = true; });
}

function renderAll() {
  renderHeader(); renderTurn(); renderRows(); $("log").innerHTML = ""; S.commands.forEach(logCommand); renderSummary(); renderPolicyStatus();
}

function connect() {
  const es = new EventSource("events");
  es.addEventListener("open", () => pill("link", "stream: live", "ok"));
  es.addEventListener("error", () => { if (!ended) pill("link", "stream: reconnecting…", "warn"); });
  es.addEventListener("snapshot", (e) => { S = JSON.parse(e.data); renderAll(); if (S.summary) endSession(); });
  const on = (kind, fn) => es.addEventListener(kind, (e) => { if (S) { fn(JSON.parse(e.data)); } });
  on("session", (d) => { S.session = d; S.robot = d.robot; renderHeader(); renderRows(); });
  on("state", (d) => { S.machine = d; renderHeader(); });
  on("turn_start", (d) => { S.turn = d; S.presses = []; renderTurn(); });
  on("press", (d) => { S.presses.push(d); renderTurn(); });
  on("row", (d) => { S.rows.push(d); renderRows(); });
  on("command", (d) => { S.commands.push(d); logCommand(d); });
  on("pause", (d) => { S.paused = d.paused; renderHeader(); });
  on("robot", (d) => { S.robot = d.robot; renderHeader(); });
  on("summary", (d) => { S.summary = d; renderSummary(); endSession(); });
  on("policy", (d) => { S.policy_status = d; renderPolicyStatus(); });
  on("eeg", (d) => { S.eeg_missing = d.missing_turns ? d : null; renderHeader(); });
  on("tick", (d) => { if (!ended) renderTick(d); });
  es.addEventListener("closed", () => { es.close(); endSession(); });
}

async function send(kind, args) {
  if (ended) return;
  const r = await fetch("command", { method: "POST", headers: { "Content-Type": "application/json" },
                                      body: JSON.stringify({ kind, args: args || {} }) });
  const body = await r.json().catch(() => ({}));
  $("command-feedback").textContent = r.ok ? `${kind} queued (#${body.id}); it acts at the next step of the session`
                                           : `${kind} not sent: ${body.error || r.status}`;
}

$("btn-pause").onclick = () => send("pause");
$("btn-resume").onclick = () => send("resume");
$("btn-stop").onclick = () => { if (confirm("Stop the session? The robot says goodbye.")) send("stop"); };
$("btn-override").onclick = () => send("override", { action: $("override-action").value });
$("btn-repeat").onclick = () => send("repeat");
$("btn-invalid").onclick = () => send("invalid", { turn: S && S.turn ? S.turn.turn : null, note: $("invalid-note").value });
$("btn-note").onclick = () => { send("note", { text: $("note-text").value }); $("note-text").value = ""; };
connect();
