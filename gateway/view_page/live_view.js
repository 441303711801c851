// leadthrough live view in a plain browser: a Foxglove WebSocket client of `leadthrough view`
// (subprotocol foxglove.sdk.v1, which foxglove-sdk's server requires, or foxglove.websocket.v1,
// the same protocol's older name; index.html lists both). It subscribes to the joint states
// (leadthrough.JointState), the arm's link origins (leadthrough.ArmPoints, on /arm/points with
// --config) and the lifecycle, and draws the joint positions over the last seconds and the arm
// in 3D. No libraries, no build step.
"use strict";

const WINDOW_S = 10; // plotted time window [s]
const DRAW_MS = 50; // redraw period [ms]
const RECONNECT_MS = 1000;
const SPIN_RAD_S = 0.12; // the 3D view turns about the vertical while nobody drags it [rad/s]
const PITCH_RAD = 0.35; // the 3D view looks down this much
const TRAIL_POINTS = 400; // tool positions kept for its trail
const MIN_SPAN_DEG = 2; // a plot's vertical range is at least this [deg]
const COLORS = ["#4e9fe5", "#f28e2b", "#59a14f", "#e15759", "#b07aa1", "#edc948"];
const DEG_PER_RAD = 180 / Math.PI;
const MESSAGE_DATA = 1; // binary opcode of a server's message

const body = document.body;
const wsUrl = new URLSearchParams(location.search).get("ws") ||
  `ws://${location.hostname || "127.0.0.1"}:${body.dataset.wsPort}`;
const decoder = new TextDecoder();

const view = {
  jointStates: 0,
  armUpdates: 0,
  samples: [], // {t: [s], q: [deg]}, oldest first, within WINDOW_S of the newest
  arm: null, // the newest leadthrough.ArmPoints message
  armAdvertised: false,
  trail: [], // tool positions [m]
  yaw: 0.8, // [rad]
  dragX: null,
  lastFrameMs: performance.now(),
};

function setText(id, text) {
  document.getElementById(id).textContent = text;
}

// --- the Foxglove WebSocket protocol: advertise -> subscribe -> binary MessageData ---------

function handlerFor(channel) {
  if (channel.encoding !== "json") return null;
  if (channel.schemaName === "leadthrough.JointState") return onJointState;
  if (channel.schemaName === "leadthrough.ArmPoints") {
    view.armAdvertised = true;
    return onArmPoints;
  }
  if (channel.schemaName === "leadthrough.Json" && channel.topic.endsWith("/gateway/lifecycle")) {
    return onLifecycle;
  }
  return null;
}

function connect() {
  const ws = new WebSocket(wsUrl, body.dataset.subprotocols.split(" "));
  ws.binaryType = "arraybuffer";
  const handlers = new Map(); // subscription id -> handler
  let nextId = 1;
  ws.onopen = () => {
    setText("connection", `connected to ${wsUrl}`);
    document.getElementById("connection").classList.remove("down");
  };
  ws.onclose = () => {
    setText("connection", `no connection to ${wsUrl}, retrying`);
    document.getElementById("connection").classList.add("down");
    setTimeout(connect, RECONNECT_MS);
  };
  ws.onmessage = (event) => {
    if (typeof event.data === "string") {
      const msg = JSON.parse(event.data);
      if (msg.op !== "advertise") return;
      const subscriptions = [];
      for (const channel of msg.channels) {
        const handler = handlerFor(channel);
        if (handler === null) continue;
        handlers.set(nextId, handler);
        subscriptions.push({ id: nextId++, channelId: channel.id });
      }
      if (subscriptions.length) ws.send(JSON.stringify({ op: "subscribe", subscriptions }));
      return;
    }
    // opcode (1 byte), subscription id (uint32), log time (uint64 [ns]), payload
    const data = new DataView(event.data);
    if (data.getUint8(0) !== MESSAGE_DATA) return;
    const handler = handlers.get(data.getUint32(1, true));
    if (handler === undefined) return;
    const logTimeS = Number(data.getBigUint64(5, true)) / 1e9;
    handler(JSON.parse(decoder.decode(new Uint8Array(event.data, 13))), logTimeS);
  };
}

// --- messages -------------------------------------------------------------------------------

function onJointState(msg, logTimeS) {
  // The driver's stamp [s] (steady); non-finite numbers arrive as strings ("NaN").
  const stamp = Number(msg.stamp_s);
  const t = Number.isFinite(stamp) ? stamp : logTimeS;
  const samples = view.samples;
  if (samples.length && t < samples[samples.length - 1].t - 1) samples.length = 0; // a new driver
  samples.push({ t, q: msg.q_rad.map((v) => Number(v) * DEG_PER_RAD) });
  while (samples.length && samples[0].t < t - WINDOW_S) samples.shift();
  view.jointStates += 1;
  setText("joint-states", String(view.jointStates));
  setText("cycle", String(msg.cycle));
}

function onArmPoints(msg) {
  view.arm = msg;
  view.trail.push(msg.tool_m);
  if (view.trail.length > TRAIL_POINTS) view.trail.shift();
  view.armUpdates += 1;
  setText("arm-updates", String(view.armUpdates));
}

function onLifecycle(msg) {
  const state = String((msg.message || {}).state || "unknown");
  const element = document.getElementById("lifecycle");
  element.textContent = state.toUpperCase();
  element.className = state;
}

// --- drawing ---------------------------------------------------------------------------------

function fitCanvas(canvas) {
  const ratio = window.devicePixelRatio || 1;
  const width = Math.max(1, Math.round(canvas.clientWidth * ratio));
  const height = Math.max(1, Math.round(canvas.clientHeight * ratio));
  if (canvas.width !== width || canvas.height !== height) {
    canvas.width = width;
    canvas.height = height;
  }
  const ctx = canvas.getContext("2d");
  ctx.setTransform(ratio, 0, 0, ratio, 0, 0);
  ctx.clearRect(0, 0, canvas.clientWidth, canvas.clientHeight);
  return [ctx, canvas.clientWidth, canvas.clientHeight];
}

function drawPlots() {
  const [ctx, width, height] = fitCanvas(document.getElementById("plots"));
  const samples = view.samples;
  const left = 96, right = 12, top = 28, bottom = 30;
  const n = samples.length ? samples[0].q.length : 6;
  const stripH = (height - top - bottom) / n;
  const tNow = samples.length ? samples[samples.length - 1].t : 0;
  const xOf = (t) => left + (width - left - right) * (1 - (tNow - t) / WINDOW_S);
  ctx.font = "12px system-ui, sans-serif";
  ctx.fillStyle = "#dde3ea";
  ctx.fillText(`joint position q [deg], last ${WINDOW_S} s`, left, 18);
  for (let j = 0; j < n; j++) {
    const y0 = top + j * stripH, y1 = y0 + stripH - 6;
    let lo = Infinity, hi = -Infinity;
    for (const s of samples) {
      if (Number.isFinite(s.q[j])) { lo = Math.min(lo, s.q[j]); hi = Math.max(hi, s.q[j]); }
    }
    if (!Number.isFinite(lo)) { lo = -1; hi = 1; }
    const mid = (lo + hi) / 2, half = Math.max(hi - lo, MIN_SPAN_DEG) / 2 * 1.1;
    const yOf = (q) => y1 - (y1 - y0) * (q - (mid - half)) / (2 * half);
    ctx.strokeStyle = "#2a3038";
    ctx.strokeRect(left, y0, width - left - right, y1 - y0);
    ctx.fillStyle = COLORS[j % COLORS.length];
    ctx.font = "bold 13px system-ui, sans-serif";
    ctx.fillText(`J${j + 1}`, 8, y0 + 16);
    ctx.font = "12px system-ui, sans-serif";
    const last = samples.length ? samples[samples.length - 1].q[j] : NaN;
    ctx.fillText(Number.isFinite(last) ? `${last.toFixed(2)}°` : "-", 8, y0 + 32);
    ctx.fillStyle = "#8a96a3";
    ctx.fillText((mid + half).toFixed(1), left - 44, y0 + 10);
    ctx.fillText((mid - half).toFixed(1), left - 44, y1);
    ctx.strokeStyle = COLORS[j % COLORS.length];
    ctx.lineWidth = 1.5;
    ctx.beginPath();
    let pen = false;
    for (const s of samples) {
      if (!Number.isFinite(s.q[j])) { pen = false; continue; }
      if (pen) ctx.lineTo(xOf(s.t), yOf(s.q[j])); else ctx.moveTo(xOf(s.t), yOf(s.q[j]));
      pen = true;
    }
    ctx.stroke();
  }
  ctx.fillStyle = "#8a96a3";
  for (let s = 0; s <= WINDOW_S; s += 2) {
    ctx.fillText(`${s - WINDOW_S}`, xOf(tNow - WINDOW_S + s) - 6, height - 12);
  }
  ctx.fillText("t [s]", 8, height - 12);
  if (!samples.length) {
    ctx.fillStyle = "#dde3ea";
    ctx.fillText("waiting for joint states", left + 12, top + 20);
  }
}

function drawArm(nowMs) {
  const [ctx, width, height] = fitCanvas(document.getElementById("arm"));
  if (view.dragX === null) view.yaw += SPIN_RAD_S * (nowMs - view.lastFrameMs) / 1000;
  view.lastFrameMs = nowMs;
  ctx.font = "12px system-ui, sans-serif";
  ctx.fillStyle = "#dde3ea";
  ctx.fillText("arm (forward kinematics), world frame [m]", 12, 18);
  const arm = view.arm;
  if (arm === null) {
    ctx.fillText(view.armAdvertised ? "waiting for the arm" :
      "no arm: start `leadthrough view` with --config CELL.toml", 12, 40);
    return;
  }
  const reach = Math.max(1, ...arm.positions_m.map((p) => Math.hypot(p[0], p[1], p[2])));
  const centerZ = reach / 2;
  const scale = 0.55 * Math.min(width, height) / reach;
  const cosYaw = Math.cos(view.yaw), sinYaw = Math.sin(view.yaw);
  const cp = Math.cos(PITCH_RAD), sp = Math.sin(PITCH_RAD);
  // world -> screen: turn about z by yaw, tilt about the screen's x by the pitch, perspective
  const project = ([x, y, z]) => {
    const xr = cosYaw * x - sinYaw * y, yr = sinYaw * x + cosYaw * y, zr = z - centerZ;
    const depth = cp * yr + sp * zr, up = cp * zr - sp * yr;
    const k = 1 / (1 + 0.15 * depth / reach);
    return [width / 2 + scale * k * xr, height / 2 + 20 - scale * k * up];
  };
  const line = (a, b, color, lineWidth) => {
    const [pa, pb] = [project(a), project(b)];
    ctx.strokeStyle = color;
    ctx.lineWidth = lineWidth;
    ctx.beginPath();
    ctx.moveTo(pa[0], pa[1]);
    ctx.lineTo(pb[0], pb[1]);
    ctx.stroke();
  };
  // the floor: 0.5 m squares under the arm's horizontal reach
  const grid = Math.ceil(Math.max(...arm.positions_m.map((p) => Math.hypot(p[0], p[1]))) * 2) / 2;
  for (let g = -grid; g <= grid; g += 0.5) {
    line([g, -grid, 0], [g, grid, 0], "#232a32", 1);
    line([-grid, g, 0], [grid, g, 0], "#232a32", 1);
  }
  line([0, 0, 0], [0.3, 0, 0], "#e15759", 2);
  line([0, 0, 0], [0, 0.3, 0], "#59a14f", 2);
  line([0, 0, 0], [0, 0, 0.3], "#4e9fe5", 2);
  ctx.lineCap = "round";
  const index = new Map(arm.links.map((name, i) => [name, i]));
  arm.links.forEach((name, i) => {
    const parent = index.get(arm.parents[i]);
    if (parent !== undefined) line(arm.positions_m[parent], arm.positions_m[i], "#8fa3b8", 9);
  });
  ctx.lineCap = "butt";
  ctx.strokeStyle = "#e15759";
  ctx.lineWidth = 1;
  ctx.beginPath();
  view.trail.forEach((p, i) => {
    const [px, py] = project(p);
    if (i) ctx.lineTo(px, py); else ctx.moveTo(px, py);
  });
  ctx.stroke();
  const dot = (p, color, radius) => {
    const [px, py] = project(p);
    ctx.fillStyle = color;
    ctx.beginPath();
    ctx.arc(px, py, radius, 0, 2 * Math.PI);
    ctx.fill();
  };
  arm.positions_m.forEach((p) => dot(p, "#f28e2b", 5));
  dot(arm.tool_m, "#e15759", 6);
  ctx.fillStyle = "#dde3ea";
  const tool = arm.tool_m.map((v) => v.toFixed(3)).join("  ");
  ctx.fillText(`tool  x y z = ${tool} m   (cycle ${arm.cycle})`, 12, height - 12);
}

function draw() {
  drawPlots();
  drawArm(performance.now());
}

const armCanvas = document.getElementById("arm");
armCanvas.addEventListener("pointerdown", (e) => { view.dragX = e.clientX; });
window.addEventListener("pointerup", () => { view.dragX = null; });
window.addEventListener("pointermove", (e) => {
  if (view.dragX === null) return;
  view.yaw += (e.clientX - view.dragX) * 0.01;
  view.dragX = e.clientX;
});

connect();
setInterval(draw, DRAW_MS);
draw();
