// walkaround HUD: the live feed over the WebSocket, the top view, operator commands and
// the virtual joystick. No framework, no build step: served as is by executive.hud.
"use strict";

const $ = (id) => document.getElementById(id);
const hud = { scene: null, tick: null, you: false, held: null, pickFollow: false, ws: null };
const map = $("map");
const ctx = map.getContext("2d");
const view = { scale: 18, cx: 0, cy: 0 }; // pixels per metre, centre of view in A

function send(message) {
  if (hud.ws && hud.ws.readyState === WebSocket.OPEN) hud.ws.send(JSON.stringify(message));
}
function command(name, params = {}) { send({ type: "command", command: name, ...params }); }

function connect() {
  const scheme = location.protocol === "https:" ? "wss" : "ws";
  const ws = new WebSocket(`${scheme}://${location.host}/ws${location.search}`);
  hud.ws = ws;
  ws.onopen = () => { setBadge("link", "live", "ok"); send({ type: "claim" }); };
  ws.onclose = () => { setBadge("link", "link lost", "bad"); stopJoystick(); setTimeout(connect, 1000); };
  ws.onmessage = (event) => {
    const msg = JSON.parse(event.data);
    if (msg.type === "scene") { hud.scene = msg; $("mission").textContent = `${msg.mission} · ${msg.aircraft}`; }
    else if (msg.type === "tick") { hud.tick = msg; render(); }
    else if (msg.type === "control") { hud.you = msg.you; hud.held = msg.held; showControl(); }
    else if (msg.type === "answer") { toast(msg.ok ? msg.text : `refused: ${msg.text}`, !msg.ok); }
  };
}

function setBadge(id, text, kind) { const el = $(id); el.textContent = text; el.className = `badge ${kind || ""}`; }
function showControl() {
  setBadge("control", hud.you ? "in control" : "view only", hud.you ? "ok" : "");
  for (const b of document.querySelectorAll("#actions button")) b.disabled = !hud.you && b.id !== "claim";
  $("claim").disabled = hud.you || hud.held !== null;
}
let toastTimer = null;
function toast(text, bad) {
  const hint = $("map-hint"); hint.textContent = text; hint.style.color = bad ? "#ff6b6b" : "#ffd479";
  clearTimeout(toastTimer); toastTimer = setTimeout(() => { hint.textContent = hud.pickFollow ? "tap the person to follow" : ""; }, 3000);
}

// -- the top view ------------------------------------------------------------------------------
function toScreen(x, y) { return [map.width / 2 + (x - view.cx) * view.scale, map.height / 2 - (y - view.cy) * view.scale]; }
function toWorld(px, py) { return [view.cx + (px - map.width / 2) / view.scale, view.cy - (py - map.height / 2) / view.scale]; }
function poly(points, stroke, fill) {
  if (!points.length) return;
  ctx.beginPath();
  points.forEach(([x, y], i) => { const [u, v] = toScreen(x, y); if (i) ctx.lineTo(u, v); else ctx.moveTo(u, v); });
  ctx.closePath();
  if (fill) { ctx.fillStyle = fill; ctx.fill(); }
  if (stroke) { ctx.strokeStyle = stroke; ctx.stroke(); }
}

function render() {
  const t = hud.tick;
  const rect = map.getBoundingClientRect();
  if (map.width !== Math.round(rect.width) || map.height !== Math.round(rect.height)) { map.width = rect.width; map.height = rect.height; }
  if (t.pose) { view.cx = t.pose.x; view.cy = t.pose.y; }
  ctx.clearRect(0, 0, map.width, map.height);
  ctx.lineWidth = 1;
  const s = hud.scene;
  if (s) {
    for (const z of s.zones) poly(z.points, "#c62828", "rgba(198,40,40,0.15)");
    for (const f of s.outline) poly(f, "#5d7890", "rgba(143,180,217,0.08)");
    for (const f of s.footprint) poly(f, "#8fb4d9", "rgba(143,180,217,0.35)");
    for (const cp of s.checkpoints) {
      const [u, v] = toScreen(cp.x, cp.y);
      const done = t.completed.includes(cp.id);
      ctx.fillStyle = done ? "#3fb950" : cp.id === t.checkpoint ? "#ffd479" : "#6e7f8f";
      ctx.beginPath(); ctx.arc(u, v, 5, 0, 2 * Math.PI); ctx.fill();
      ctx.fillText(cp.id, u + 7, v - 7);
    }
  }
  ctx.strokeStyle = "#58a6ff55"; ctx.beginPath();
  t.trail.forEach(([x, y], i) => { const [u, v] = toScreen(x, y); if (i) ctx.lineTo(u, v); else ctx.moveTo(u, v); });
  ctx.stroke();
  ctx.fillStyle = "#e6edf3";
  for (const [x, y] of t.scans) { const [u, v] = toScreen(x, y); ctx.fillRect(u - 1, v - 1, 2, 2); }
  for (const o of t.tracks) {
    const [u, v] = toScreen(o.x, o.y);
    ctx.strokeStyle = "#f0883e"; ctx.beginPath(); ctx.arc(u, v, Math.max(4, o.r * view.scale), 0, 2 * Math.PI); ctx.stroke();
    const [u2, v2] = toScreen(o.x + o.vx, o.y + o.vy);
    ctx.beginPath(); ctx.moveTo(u, v); ctx.lineTo(u2, v2); ctx.stroke();
    ctx.fillStyle = "#f0883e"; ctx.fillText(`#${o.id}`, u + 6, v + 12);
  }
  if (t.pose && s) {
    const { x, y, theta } = t.pose, hl = s.robot.length / 2, hw = s.robot.width / 2;
    const c = Math.cos(theta), sn = Math.sin(theta);
    const corners = [[hl, hw], [-hl, hw], [-hl, -hw], [hl, -hw]].map(([a, b]) => [x + c * a - sn * b, y + sn * a + c * b]);
    poly(corners, "#58a6ff", "rgba(88,166,255,0.5)");
    const [u, v] = toScreen(x, y), [u2, v2] = toScreen(x + c * hl * 1.4, y + sn * hl * 1.4);
    ctx.strokeStyle = "#fff"; ctx.beginPath(); ctx.moveTo(u, v); ctx.lineTo(u2, v2); ctx.stroke();
  }
  panels(t);
}

function panels(t) {
  $("clock").textContent = `t ${t.t.toFixed(1)} s`;
  $("progress-text").textContent = `${t.completed.length} / ${t.total} checkpoints`;
  $("progress-bar").style.width = `${(100 * t.completed.length) / Math.max(1, t.total)}%`;
  $("phase").textContent = `${t.phase}${t.checkpoint ? " · " + t.checkpoint : ""}`;
  $("ttg").textContent = t.time_to_go == null ? "time to go —" : `time to go ${Math.round(t.time_to_go)} s`;
  $("controller").textContent = t.controller;
  $("why").textContent = t.why || "—";
  const alerts = $("alerts"); alerts.replaceChildren();
  for (const a of t.alerts) { const d = document.createElement("div"); d.className = "alert"; d.innerHTML = `<b>${a.kind}</b> `; d.append(a.text); alerts.append(d); }
  const q = t.operator && t.operator.question;
  const box = $("question");
  if (q) {
    if (box.dataset.id !== String(q.id)) {
      box.dataset.id = String(q.id); $("question-text").textContent = q.text;
      const choices = $("question-choices"); choices.replaceChildren();
      for (const choice of q.choices) {
        const b = document.createElement("button"); b.textContent = choice; b.dataset.choice = choice;
        b.onclick = () => command("answer", { choice }); choices.append(b);
      }
    }
    box.hidden = false;
  } else { box.hidden = true; box.dataset.id = ""; }
  results(t.results);
}

function results(list) {
  const root = $("results");
  if (root.dataset.n === String(list.length) && root.dataset.last === JSON.stringify(list.at(-1) || null)) return;
  root.dataset.n = String(list.length); root.dataset.last = JSON.stringify(list.at(-1) || null);
  root.replaceChildren();
  for (const r of list.slice().reverse()) {
    const row = document.createElement("div"); row.className = "result";
    const cv = document.createElement("canvas"); cv.width = 96; cv.height = 72;
    const g = cv.getContext("2d"); const [w, h] = r.image;
    g.fillStyle = r.detected ? "#3fb950" : "#ff6b6b";
    for (const [u, v] of r.points) { g.beginPath(); g.arc((u / (w || 1)) * cv.width, (v / (h || 1)) * cv.height, 3, 0, 2 * Math.PI); g.fill(); }
    const text = document.createElement("div");
    text.innerHTML = `<span class="${r.detected ? "ok" : "ko"}">${r.detected ? "✔" : "✘"}</span> `;
    text.append(`${r.checkpoint} · ${r.item} (${r.camera}${r.stale ? ", stale" : ""})`);
    row.append(cv, text); root.append(row);
  }
}

// -- operator actions --------------------------------------------------------------------------
$("estop").onclick = () => command("estop");
$("reset").onclick = () => command("reset-estop");
$("pause").onclick = () => command("pause");
$("resume").onclick = () => command("resume");
$("takeover").onclick = () => command("take-over");
$("handback").onclick = () => command("hand-back");
$("abort").onclick = () => { if (confirm("Abort the mission? The robot drives back to the handover point P.")) command("abort"); };
$("claim").onclick = () => send({ type: "claim" });
$("follow").onclick = () => { hud.pickFollow = true; toast("tap the person to follow"); };
map.addEventListener("pointerdown", (event) => {
  if (!hud.pickFollow) return;
  const r = map.getBoundingClientRect();
  const [x, y] = toWorld(event.clientX - r.left, event.clientY - r.top);
  hud.pickFollow = false;
  command("follow", { x, y });
});
map.addEventListener("wheel", (event) => { view.scale = Math.min(200, Math.max(2, view.scale * (event.deltaY < 0 ? 1.2 : 1 / 1.2))); event.preventDefault(); }, { passive: false });

// -- the joystick: a dead-man stream of 10 commands a second while held --------------------------
const JOY = { vMax: 0.5, wMax: 0.6, timer: null, v: 0, w: 0 };
const pad = $("joystick"), knob = $("knob");
function joyAt(event) {
  const r = pad.getBoundingClientRect(), rad = r.width / 2;
  let dx = event.clientX - r.left - rad, dy = event.clientY - r.top - rad;
  const n = Math.hypot(dx, dy); if (n > rad) { dx *= rad / n; dy *= rad / n; }
  knob.style.left = `${rad + dx - 28}px`; knob.style.top = `${rad + dy - 28}px`;
  JOY.v = (-dy / rad) * JOY.vMax; JOY.w = (-dx / rad) * JOY.wMax;
  $("joy-text").textContent = `v ${JOY.v.toFixed(2)} m/s · ω ${JOY.w.toFixed(2)} rad/s`;
}
function stopJoystick() {
  if (JOY.timer !== null) { clearInterval(JOY.timer); JOY.timer = null; command("joystick", { v: 0, omega: 0 }); }
  knob.style.left = "52px"; knob.style.top = "52px"; $("joy-text").textContent = "hold and drag";
}
pad.addEventListener("pointerdown", (event) => {
  pad.setPointerCapture(event.pointerId); joyAt(event);
  const tick = () => command("joystick", { v: JOY.v, omega: JOY.w });
  tick(); JOY.timer = setInterval(tick, 100);
});
pad.addEventListener("pointermove", (event) => { if (JOY.timer !== null) joyAt(event); });
pad.addEventListener("pointerup", stopJoystick);
pad.addEventListener("pointercancel", stopJoystick);

connect();
