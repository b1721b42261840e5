// The technician's page: the bench's one session, live from the station (server-sent events),
// driven by the buttons. Every browser shows the same session; any of them may answer.
"use strict";

const $ = (id) => document.getElementById(id);
const SPAN = 10;                        // seconds of the session clock in the plots
const live = {stream: [], rate: [], cursor: 0, session: null, asked: null};
// what the bench script (bench/serve.py) reads: updates drawn and their lag behind the samples
window.stationStats = {updates: 0, lags: [], first: null};

async function post(action, body) {
  const reply = await fetch(`/api/${action}`, {method: "POST",
    headers: {"Content-Type": "application/json"}, body: JSON.stringify(body || {})});
  const answer = await reply.json();
  if (!reply.ok) throw new Error(answer.error || reply.statusText);
  return answer;
}
async function get(path) {
  const reply = await fetch(path);
  const answer = await reply.json();
  if (!reply.ok) throw new Error(answer.error || reply.statusText);
  return answer;
}
function act(action, body, where) {
  $(where).textContent = "";
  return post(action, body).catch((e) => { $(where).textContent = e.message; });
}
function cell(row, text, tag) {
  const c = document.createElement(tag || "td"); c.textContent = text; row.appendChild(c); return c;
}
function table(rows, head) {
  const t = document.createElement("table"); t.className = "facts";
  if (head) { const r = t.insertRow(); head.forEach((h) => cell(r, h, "th")); }
  for (const row of rows) { const r = t.insertRow(); row.forEach((x) => cell(r, x)); }
  return t;
}

// -- setup -------------------------------------------------------------------------------------
async function loadBench() {
  const bench = await get("/api/bench");
  $("profile").replaceChildren(...bench.profiles.map((p) => new Option(p, p)));
  const open = bench.sessions.filter((s) => s.resumable && s.name !== live.session);
  const span = $("resumable"); span.replaceChildren();
  if (open.length) {
    const pick = document.createElement("select"); pick.id = "resume-session";
    open.forEach((s) => pick.add(new Option(`${s.name} (${s.done} of ${s.planned})`, s.name)));
    const go = document.createElement("button"); go.textContent = "Resume session";
    go.onclick = () => act("resume", {session: pick.value}, "setup-error");
    span.append("interrupted: ", pick, " ", go);
  }
}
async function checkDevices() {
  $("devices").textContent = "checking…"; $("setup-error").textContent = "";
  try {
    const d = await get(`/api/devices?profile=${encodeURIComponent($("profile").value)}`);
    $("devices").replaceChildren(table(d.devices.map((x) => [x.device, x.state]), ["device", "state"]));
  } catch (e) { $("devices").textContent = ""; $("setup-error").textContent = e.message; }
}
function start() {
  live.stream = []; live.rate = []; live.cursor = 0;
  act("start", {profile: $("profile").value, serial: $("serial").value.trim()}, "setup-error");
}

// -- the live session --------------------------------------------------------------------------
function showPositions(view) {
  const box = $("positions"); const done = new Set(view.done || []);
  if (box.childElementCount !== view.total) {
    box.replaceChildren(...Array.from({length: view.total}, (_, k) => {
      const s = document.createElement("span"); s.textContent = k + 1; return s; }));
  }
  [...box.children].forEach((s, k) => {
    s.className = done.has(k) ? "done" : (k === view.position && view.state !== "done" ? "now" : "");
  });
}
function showView(view, snap) {
  if (!view) return;
  live.stream = PLOT.trim(live.stream.concat(view.series.map(([, t, v]) => [t, v])), SPAN);
  live.rate = PLOT.trim(live.rate.concat(view.rates.map(([, t, r]) => [t, [r]])), SPAN);
  live.cursor = view.cursor;
  PLOT.draw($("stream"), live.stream, SPAN);
  PLOT.draw($("rate"), live.rate, SPAN);
  const stats = window.stationStats; stats.updates += 1;
  if (view.arrived) stats.lags.push(Date.now() / 1000 - view.arrived);
  if (view.total) {
    showPositions(view);
    $("step").textContent = `position ${Math.min(view.position + 1, view.total)} of ${view.total}`;
    $("phase").textContent = ["aborted", "paused", "failed"].includes(snap.state) ?
      `${snap.state}: the session stopped` : (view.phase || "");
    $("left").textContent = view.time_left == null ? "" : `about ${Math.round(view.time_left)} s of bench time left`;
  }
  const s = view.stillness;
  const share = s.dispersion == null ? 0 : Math.max(0, Math.min(1, 1 - (s.dispersion - 1) / (2 * s.leave)));
  $("still-bar").style.width = `${Math.round(100 * share)}%`;
  $("still-bar").className = s.still ? "" : "moving";
  $("still-words").textContent = s.still == null ? "measuring…" :
    `${s.still ? "still" : "moving"} (dispersion ${s.dispersion})`;
  $("table").textContent = view.table || "";
  $("watchdog").textContent = view.watchdog || "";
  $("table-row").hidden = !view.table; $("watchdog-row").hidden = !view.watchdog;
  $("rate-plot").hidden = !view.rates.length && !live.rate.length;
  $("stream-caption").textContent = `IMU stream: ${view.channels.join(", ")} (SI units, last ${SPAN} s)`;
  $("imu").textContent = view.feeds.map((f) => `${f.rate} samples/s, ${f.samples} received, ${f.gaps} gaps; ${f.link}`).join(" | ");
  const windows = Object.entries(view.windows || {});
  $("windows").replaceChildren(...windows.map(([name, w]) => {
    const d = document.createElement("div"); d.className = "window";
    d.innerHTML = `<b></b> <div class="meter"><div style="width:${Math.round(100 * w.fraction)}%"></div></div> <span></span>`;
    d.querySelector("b").textContent = `${name} window`; d.querySelector("span").textContent = w.words;
    return d;
  }));
  const pose = snap.asked && snap.asked.orientation ? snap.asked : view.pose;
  const key = pose ? JSON.stringify(pose.orientation) : "";
  if (key !== live.pose) { POSE.draw($("pose"), pose && pose.orientation, !!view.table); live.pose = key; }
  $("instruction").textContent = pose && !snap.asked ? pose.text : "";
  $("pose").parentElement.hidden = !pose && view.state === "done";
}
function showAsked(asked) {
  $("ask").hidden = !asked;
  if (!asked) { live.asked = null; return; }
  live.asked = asked.id;
  $("ask-text").textContent = asked.text;
  $("done").hidden = asked.kind !== "wait";
  $("yes").hidden = $("no").hidden = asked.kind !== "confirm";
}
function showResult(snap) {
  const r = live.dismissed === snap.session ? null : snap.result; $("result").hidden = !r;
  if (!r || live.shown === snap.session) return;
  live.shown = snap.session;
  const v = r.verdict;
  $("verdict").className = `verdict ${v ? v.overall : ""}`;
  $("verdict").innerHTML = "";
  $("verdict").append(v ? v.overall : "CALIBRATED");
  const note = document.createElement("small");
  note.textContent = v ? `${v.parameters.length} parameters tested; unit ${snap.serial}` : "no tolerances in the bench profile";
  $("verdict").append(note);
  const out = v ? v.parameters.filter((p) => p.verdict !== "pass") : [];
  $("out-of-tolerance").replaceChildren(...(out.length ? [table(out.map((p) =>
    [p.verdict.toUpperCase(), p.name, `${p.value.toPrecision(6)} ± ${p.sigma.toPrecision(2)}`,
     `${p.nominal} ± ${p.limit}`]), ["", "parameter", "value", "tolerance"])] : []));
  $("outputs").replaceChildren(...r.files.map(([label, name]) => {
    const a = document.createElement("a"); a.href = `/files/${encodeURIComponent(name)}`;
    a.textContent = label; a.target = "_blank"; return a; }));
}
function show(snap) {
  const state = snap.state;
  $("state").textContent = snap.session ? `${state}: ${snap.serial}` : state;
  $("state").className = `badge ${state}`;
  const active = state !== "idle" && live.dismissed !== snap.session;
  $("session").hidden = !active;
  $("setup").hidden = ["running", "concluding", "paused"].includes(state) ||
    (!!snap.result && live.dismissed !== snap.session);
  $("unit").textContent = snap.serial ? `unit ${snap.serial}` : "";
  $("file").textContent = snap.session || "";
  $("pause").disabled = state !== "running";
  $("abort").disabled = state !== "running";
  $("resume").disabled = !["paused", "aborted", "failed"].includes(state) || !snap.session;
  $("session-error").textContent = snap.error || "";
  if (state === "concluding") $("step").textContent = "calibrating…";
  showAsked(snap.asked);
  showView(snap.view, snap);
  $("messages").replaceChildren(...snap.messages.slice().reverse().map((m) => {
    const li = document.createElement("li"); li.textContent = m; return li; }));
  showResult(snap);
  if (live.state !== state) { live.session = snap.session; live.state = state; loadBench().catch(() => {}); }
}

function follow() {
  const source = new EventSource(`/api/events?since=${live.cursor}`);
  source.onmessage = (event) => {
    const snap = JSON.parse(event.data);
    if (window.stationStats.first === null) window.stationStats.first = performance.now();
    show(snap);
  };
  source.onerror = () => { $("state").textContent = "reconnecting…"; };
}

// -- the unit's history and the line -----------------------------------------------------------
async function history() {
  $("records").textContent = "";
  try {
    const h = await get(`/api/history?serial=${encodeURIComponent($("history-serial").value.trim())}`);
    $("records").replaceChildren(table(h.calibrations.map((c) =>
      [c.created, c.verdict || "-", c.bench || "-", (c.calibration_path || "").split("/").pop()]),
      ["when", "verdict", "bench", "calibration file"]));
  } catch (e) { $("records").textContent = e.message; }
}
async function line() {
  $("records").textContent = "";
  try {
    const l = await get("/api/line");
    $("records").replaceChildren(table(Object.entries(l).map(([k, v]) =>
      [k, typeof v === "object" ? JSON.stringify(v) : String(v)])));
  } catch (e) { $("records").textContent = e.message; }
}

$("start").onclick = start;
$("serial").addEventListener("keydown", (e) => { if (e.key === "Enter") start(); });  // a scanner's Enter
$("check").onclick = checkDevices;
$("pause").onclick = () => act("pause", {}, "session-error");
$("resume").onclick = () => act("resume", {}, "session-error");
$("abort").onclick = () => act("abort", {}, "session-error");
$("done").onclick = () => act("answer", {id: live.asked, value: "done"}, "session-error");
$("yes").onclick = () => act("answer", {id: live.asked, value: "yes"}, "session-error");
$("no").onclick = () => act("answer", {id: live.asked, value: "no"}, "session-error");
$("again").onclick = () => { live.dismissed = live.session; $("serial").value = ""; $("serial").focus(); };
$("history").onclick = history;
$("line").onclick = line;
loadBench().catch((e) => { $("setup-error").textContent = e.message; });
follow();
