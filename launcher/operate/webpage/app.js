// The launch's live page: a table kept current from the server's event stream (a snapshot, then changes).
"use strict";
const nodes = new Map();      // name -> the node's fields (as launcher status --json)
const sparks = new Map();     // name -> [[cpu, rss], ...], the last minute
const HISTORY = 60;
const SIGNALS = {1: "SIGHUP", 2: "SIGINT", 6: "SIGABRT", 9: "SIGKILL", 11: "SIGSEGV", 15: "SIGTERM"};
const liveLines = [];          // [text, level ("" or WARN, ERROR, FATAL: a /rosout line of an output="log" node)]
let shownNode = null;         // whose recent output the pane shows (null: every node's, live)
let starting = "";            // what the page says while the launch sets up, until it has made its nodes

const $ = (id) => document.getElementById(id);
const text = (v) => (v === null || v === undefined) ? "-" : String(v);

function duration(s) {
  if (s === null || s === undefined) return "-";
  s = Math.floor(s);
  if (s < 60) return s + "s";
  if (s < 3600) return Math.floor(s / 60) + "m" + String(s % 60).padStart(2, "0") + "s";
  if (s < 86400) return Math.floor(s / 3600) + "h" + String(Math.floor(s % 3600 / 60)).padStart(2, "0") + "m";
  return Math.floor(s / 86400) + "d" + String(Math.floor(s % 86400 / 3600)).padStart(2, "0") + "h";
}
function size(n) {
  if (n === null || n === undefined) return "-";
  for (const [scale, unit] of [[1e9, "GB"], [1e6, "MB"], [1e3, "kB"]]) if (n >= scale) return (n / scale).toFixed(1) + unit;
  return n + "B";
}
const given = (v) => v !== null && v !== undefined;
function lastExit(n) {  // how its last run that ended did end, also while it runs again (launcher status's LAST EXIT)
  const [code, sig] = "last_exit_code" in n ? [n.last_exit_code, n.last_exit_signal] : [n.exit_code, n.exit_signal];
  if (given(sig)) return SIGNALS[sig] || "signal " + sig;
  if (given(code)) return "code " + code;
  return "-";
}
function keepLastExit(n, c) {  // a change whose exit fields are set anew is a run's end (fleet.state.keep_last_exit)
  const before = [n.exit_code, n.exit_signal].map((v) => given(v) ? v : null);
  const after = [c.exit_code, c.exit_signal].map((v) => given(v) ? v : null);
  if ((after[0] !== null || after[1] !== null) && (after[0] !== before[0] || after[1] !== before[1])) {
    [n.last_exit_code, n.last_exit_signal, n.last_exit_at] = [after[0], after[1], c.time];
  }
}
function spark(values, max, color) {
  const w = 60, h = 16;
  if (values.length < 2) return "";
  const top = Math.max(max, ...values) || 1;
  const pts = values.map((v, i) => (i * w / (HISTORY - 1)).toFixed(1) + "," + (h - (v || 0) / top * h).toFixed(1));
  return `<polyline points="${pts.join(" ")}" stroke="${color}"/>`;
}

function rowOf(name) {
  let tr = document.getElementById("row-" + name);
  if (!tr) {
    tr = document.createElement("tr");
    tr.id = "row-" + name;
    tr.dataset.node = name;
    tr.innerHTML = '<td class="name"></td><td class="state"></td><td class="reg"></td><td class="pid num"></td><td class="uptime num"></td>' +
      '<td class="restarts num"></td><td class="exit"></td><td class="cpu num"></td><td class="rss num"></td>' +
      '<td class="host"></td><td class="hist"><svg class="spark" width="60" height="16"></svg></td><td class="actions">' +
      '<button data-verb="start">start</button> <button data-verb="stop">stop</button> ' +
      '<button data-verb="restart">restart</button></td>';
    tr.querySelector(".name").textContent = name;
    tr.querySelector(".name").addEventListener("click", () => showOutput(name));
    for (const b of tr.querySelectorAll("button")) b.addEventListener("click", () => control(b.dataset.verb, name));
    $("nodes").tBodies[0].appendChild(tr);
  }
  return tr;
}

function draw(name) {
  const n = nodes.get(name), tr = rowOf(name), running = n.state === "running";
  const cell = (c) => tr.querySelector("." + c);
  cell("state").textContent = n.state + (n.over_limit && Object.keys(n.over_limit).length ? " (over " +
    Object.keys(n.over_limit).join(", ") + ")" : "");
  cell("state").className = "state state-" + n.state + (n.over_limit && Object.keys(n.over_limit).length ? " over" : "");
  // a process runs ("running"); a ROS node is up once its run is registered with the master too
  cell("reg").textContent = ["running", "stalled", "hung"].includes(n.state) ? (n.registered ? "yes" : "no") : "-";
  cell("pid").textContent = running && n.pid ? n.pid : "-";
  cell("uptime").textContent = running && n.started_at ? duration(Date.now() / 1000 - n.started_at) : "-";
  cell("restarts").textContent = text(n.restarts || 0);
  cell("exit").textContent = lastExit(n);
  cell("cpu").textContent = running && n.cpu !== null && n.cpu !== undefined ? Math.round(100 * n.cpu) + "%" : "-";
  cell("rss").textContent = running ? size(n.rss) : "-";
  cell("host").textContent = n.host || "";
  const h = sparks.get(name) || [];
  tr.querySelector("svg").innerHTML = spark(h.map((s) => s[0]), 0.05, "#c60") + spark(h.map((s) => s[1]), 0, "#06c");
}

function sizeText(n) {
  return n >= 1e9 ? (n / 1e9).toFixed(1) + "GB" : n >= 1e6 ? (n / 1e6).toFixed(1) + "MB"
    : n >= 1e3 ? (n / 1e3).toFixed(1) + "kB" : n + "B";
}
function addOutput(name, chunk, level = "") {
  for (const line of chunk.split("\n")) if (line) liveLines.push(["[" + name + "] " + (level ? level + " " : "") + line, level]);
  if (liveLines.length > 2000) liveLines.splice(0, liveLines.length - 2000);
  if (shownNode === null) {
    const pre = $("output"), atEnd = pre.scrollTop + pre.clientHeight >= pre.scrollHeight - 4;
    showLive();
    if (atEnd) pre.scrollTop = pre.scrollHeight;
  }
}
function showLive() {  // every node's lines, a /rosout line in its level's colour
  $("output").replaceChildren(...liveLines.map(([t, level]) => {
    const span = document.createElement("span");
    span.textContent = t + "\n";
    if (level) span.className = "level-" + level;
    return span;
  }));
}

function handle(ev) {
  if (ev.type === "snapshot") {
    $("title").textContent = "launch " + ev.uri + " (run " + ev.run_id + ")";
    for (const [name, h] of Object.entries(ev.history || {})) sparks.set(name, h.slice(-HISTORY));
    for (const n of ev.nodes) { nodes.set(n.name, n); draw(n.name); }
    starting = ev.starting;  // (a launch still setting up: no row yet)
    if (starting) $("message").textContent = starting;
  } else if (ev.type === "started") {  // (it has made its nodes: their rows come with their changes)
    if ($("message").textContent === starting) $("message").textContent = "";
    starting = "";
  } else if (ev.type === "changes") {
    for (const c of ev.changes) {
      if (!c.node) continue;  // (a line of the run's own: a reload, the launch's end)
      let n = nodes.get(c.node);
      if (!n) { n = {name: c.node}; nodes.set(c.node, n); }  // (a node a reload added)
      const newRun = c.state === "running" && (n.state !== "running" || n.pid !== c.pid);
      keepLastExit(n, c);
      Object.assign(n, c);
      if (newRun) n.started_at = c.time;
      if (c.state !== "running") { n.cpu = null; n.rss = null; }
      draw(c.node);
      addOutput(c.node, c.state + (c.state === "running" && c.pid ? " pid " + c.pid : "") +
        (c.registered ? " registered at " + c.uri : "") + "\n");
    }
  } else if (ev.type === "samples") {
    for (const [name, s] of Object.entries(ev.samples)) {
      const n = nodes.get(name);
      if (!n) continue;
      [n.cpu, n.rss] = s;
      draw(name);
    }
  } else if (ev.type === "output") {
    // (a flood: the launch gave only a node's newest output, and says how much it passed over)
    for (const [name, size] of Object.entries(ev.skipped || {}))
      addOutput(name, "... " + sizeText(size) + " of output passed over (`launcher logs " + name + "` has every line)");
    for (const [name, chunk] of Object.entries(ev.output)) addOutput(name, chunk);
    for (const [name, level, line] of ev.log || []) addOutput(name, line, level);
  } else if (ev.type === "gone") {
    $("message").textContent = "the launch has ended";
  }
}

// every second: each node's sample goes into its history (a sample that did not move was not sent), uptimes tick
setInterval(() => {
  for (const [name, n] of nodes) {
    const h = sparks.get(name) || [];
    h.push([n.state === "running" ? n.cpu : null, n.state === "running" ? n.rss : null]);
    if (h.length > HISTORY) h.shift();
    sparks.set(name, h);
    draw(name);
  }
}, 1000);

// The address `launcher web` printed on its terminal carries the run's token in its fragment (#token=...: a
// fragment never reaches a server or a Referer): kept in this tab, and taken out of the address bar (and history).
function takeToken() {
  const m = /(?:^#|&)token=([^&]*)/.exec(location.hash);
  if (!m) return;
  const t = decodeURIComponent(m[1]).trim();
  if (t) sessionStorage.setItem("launcher-token", t);
  const rest = location.hash.slice(1).split("&").filter((p) => !p.startsWith("token=")).join("&");
  history.replaceState(null, "", location.pathname + location.search + (rest ? "#" + rest : ""));
}
takeToken();

function token() {
  let t = sessionStorage.getItem("launcher-token");
  if (!t) {
    t = window.prompt("The run's token (the file launcher-token in the run's log directory):");
    if (t) sessionStorage.setItem("launcher-token", t.trim());
  }
  return t ? t.trim() : null;
}

async function control(verb, name) {
  const t = token();
  if (!t) { $("message").textContent = verb + " needs the run's token"; return; }
  $("message").textContent = verb + " " + name + " ...";
  const r = await fetch("/api/" + verb, {method: "POST", headers: {"Content-Type": "application/json",
    "X-Launcher-Token": t}, body: JSON.stringify({node: name})});
  if (r.status === 403) sessionStorage.removeItem("launcher-token");
  const body = await r.text();
  let msg = body;
  try { msg = JSON.parse(body).message; } catch (e) { /* a plain text refusal */ }
  $("message").textContent = msg;
}

async function showOutput(name) {
  for (const tr of document.querySelectorAll("tr.selected")) tr.classList.remove("selected");
  if (shownNode === name) {
    shownNode = null;
    $("output-title").textContent = "output";
    showLive();
    return;
  }
  shownNode = name;
  rowOf(name).classList.add("selected");
  const r = await fetch("/api/output?node=" + encodeURIComponent(name));
  const body = await r.json();
  $("output-title").textContent = "recent output of " + name + " (click its name again: every node's)";
  $("output").textContent = body.output !== undefined ? body.output : body.error;
}

async function showTopics() {
  const r = await fetch("/api/topics");
  const topics = await r.json();
  const tbody = $("topics").tBodies[0];
  tbody.textContent = "";
  for (const t of topics) {
    const tr = document.createElement("tr");
    for (const v of [t.topic, t.type, t.publishers.join(" "), t.subscribers.join(" ")]) {
      const td = document.createElement("td");
      td.textContent = v;
      tr.appendChild(td);
    }
    tbody.appendChild(tr);
  }
}

function route() {
  const topics = location.hash === "#topics";
  $("nodes-view").hidden = topics;
  $("topics-view").hidden = !topics;
  if (topics) showTopics();
}

window.addEventListener("hashchange", route);
$("reload").addEventListener("click", () => control("reload", ""));
$("forget").addEventListener("click", () => { sessionStorage.removeItem("launcher-token"); $("message").textContent = "token forgotten"; });
route();
const source = new EventSource("/events");
source.onmessage = (m) => handle(JSON.parse(m.data));
