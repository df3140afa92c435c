// rovlink operator page: telemetry from the WebSocket /ws, orders over REST,
// velocity from keys and gamepad over the same WebSocket while we hold control.
//
// Safety rules this page keeps: velocity is sent only while a key or stick is
// off neutral, repeated every TICK_MS (the server falls back to neutral when
// the repeats stop); neutral is sent at once when the last key is released,
// when the window loses focus or is hidden, and when control is lost.
"use strict";

const TICK_MS = 100;
const CLIENT_HEADER = "X-Rovlink-Client";
const NEUTRAL = { vx: 0, vy: 0, vz: 0, vyaw: 0 };
// KeyboardEvent.code names physical keys, so the mapping holds on any layout.
// Filled from GET /api/config (the console's one key map, the scene's too).
let KEYMAP = {};
const AXIS_WORDS = { vx: ["surge back", "surge forward"], vy: ["sway left", "sway right"],
                     vz: ["up", "down"], vyaw: ["yaw left", "yaw right"] };

const page = {
  ws: null,
  clientId: null,
  config: null,
  holder: false,
  held: new Set(),
  lastSent: NEUTRAL,
  shownImage: null,      // "img:decoded_bytes" on screen
  loadingImage: false,
  wantedImage: null,
  roi: null,             // [x0, y0, x1, y1] in picture pixels, or null
  drag: null,            // picture-pixel start of a ROI drag
  lastPose: null,
  failsafeActive: false,
  failsafeAt: null,      // Date.now() when FAILSAFE was last reported
  linkState: null,       // "up" | "degraded" | "lost" | "replay" | "starting" | "port down"
  alerts: 0,             // alarm sounds started (the tests read it)
  audio: null,
  orders: {},            // id -> the order as last shown (its fate: state, reason, text, outcome)
  frames: {},            // object id -> its last "Frame it": {text, outcome, orderId}
  wallOffset: null,      // clock time minus session time (from telemetry)
  roiSent: null,         // {id, roi}: the pilot's ROI as sent in IMAGE order id
  logEntries: [],        // every log line seen, oldest first (GET /api/log, then events)
  logKeys: new Map(),    // "t|text" -> its entry (a line comes again when its alert is cleared)
  history: [],           // kept pictures' metadata (GET /api/images)
  historyKey: "",        // serial and counts the history was fetched for
  shownPast: null,       // n of the kept picture shown large, or null: the latest complete one
  lastState: null,       // the last telemetry snapshot (for the clock-driven refresh)
};

const $ = (id) => document.getElementById(id);

// ---------------------------------------------------------------------------
// WebSocket
// ---------------------------------------------------------------------------

// The key this page opens its 3D scene with; the server lets that scene
// order while this page holds control (and only then).  One per page load,
// so it survives our WebSocket reconnecting.
const SCENE_KEY = Array.from(crypto.getRandomValues(new Uint8Array(16)),
                             (b) => b.toString(16).padStart(2, "0")).join("");

function connect() {
  const scheme = location.protocol === "https:" ? "wss" : "ws";
  const ws = new WebSocket(`${scheme}://${location.host}/ws?name=${encodeURIComponent(pageName())}` +
                           `&scene_key=${SCENE_KEY}`);
  page.ws = ws;
  ws.onmessage = (ev) => onMessage(JSON.parse(ev.data));
  ws.onopen = () => setBadge($("connection"), "online", "good");
  ws.onclose = (ev) => {
    // Our id and any control we held died with the socket.  How many times and how
    // (a test that finds control gone reads it here).
    const closes = (+(document.body.dataset.socketCloses || "0").split(" ")[0] || 0) + 1;
    document.body.dataset.socketCloses = `${closes} (last code ${ev.code})`;
    page.clientId = null;
    setHolder(false);
    setBadge($("connection"), "offline", "bad");
    $("control-text").textContent = "reconnecting…";
    setTimeout(connect, 1000);
  };
}

// Two pages on one machine must be told apart in "X has control".
const PAGE_TAG = Math.random().toString(16).slice(2, 6);

function pageName() {
  return `browser ${navigator.platform || ""}`.trim().slice(0, 33) + ` #${PAGE_TAG}`;
}

function onMessage(msg) {
  switch (msg.type) {
    case "hello":
      page.clientId = msg.client_id;
      document.body.dataset.clientId = msg.client_id;
      if (!page.config) { setupControls(msg.config); setupScene(msg.config); }
      page.config = msg.config;
      break;
    case "wish":
      renderWish(msg.wish);
      break;
    case "order":
      renderOrder(msg.order);
      break;
    case "target":
      renderTarget(msg.target);
      break;
    case "telemetry":
      render(msg);
      // Telemetry messages rendered so far: a page that acted on none is not yet current.
      document.body.dataset.telemetry = String((+document.body.dataset.telemetry || 0) + 1);
      break;
    case "control":
      renderControl(msg.control);
      break;
    case "image":
      renderImageProgress(msg.image);
      break;
    case "log":
      addLog([msg.entry]);
      break;
    case "error":
      showError(msg.message);
      break;
    case "failsafe":
      // The ROV failed safe: a HOLD of its own begins, even if an earlier one (a STOP's)
      // was still shown; a centring before it does not count for it (a key held since
      // is told to centre, as the ROV ignores it until then).
      if (msg.failsafe && !page.failsafeActive) page.neutralSinceHold = isNeutral(wish());
      page.failsafeActive = msg.failsafe;
      renderFailsafe(msg.failsafe);
      break;
  }
}

function send(obj) {
  if (page.ws && page.ws.readyState === WebSocket.OPEN) page.ws.send(JSON.stringify(obj));
}

// ---------------------------------------------------------------------------
// REST
// ---------------------------------------------------------------------------

async function api(path, body, method = "POST") {
  const headers = { "Content-Type": "application/json" };
  if (page.clientId) headers[CLIENT_HEADER] = page.clientId;
  try {
    const resp = await fetch(path, method === "GET" ? { headers } : { method, headers, body: JSON.stringify(body ?? {}) });
    const text = await resp.text();
    const data = text ? JSON.parse(text) : null;
    if (!resp.ok) {
      showError(`${path}: ${(data && data.message) || resp.status}`);
      return null;
    }
    return data ?? {};  // 204: done, nothing to say
  } catch (err) {
    showError(`${path}: ${err}`);
    return null;
  }
}

function showError(text) {
  const box = $("error");
  box.textContent = text;
  box.hidden = false;
  clearTimeout(showError.timer);
  showError.timer = setTimeout(() => { box.hidden = true; }, 5000);
}

// ---------------------------------------------------------------------------
// Control
// ---------------------------------------------------------------------------

// ---------------------------------------------------------------------------
// The console's one mode list and key map (GET /api/config)
// ---------------------------------------------------------------------------

// The mode selector shows the vehicle's mode, unless the pilot is choosing one: it has
// the focus, or was changed and not yet sent (Set mode), for a few seconds.
function followVehicleMode(mode) {
  const select = $("mode-select");
  const choosing = document.activeElement === select || Date.now() - (page.modeChosenAt || 0) < 5000;
  if (choosing || ![...select.options].some((o) => o.value === mode)) return;
  select.value = mode;
}

function setupControls(config) {
  KEYMAP = {};
  for (const [key, [axis, sign]] of Object.entries(config.keys)) KEYMAP[`Key${key}`] = [axis, sign];
  const select = $("mode-select");
  select.replaceChildren(...config.modes.map((m) => Object.assign(document.createElement("option"), { textContent: m })));
  const rows = Object.entries(config.keys).map(([key, [axis, sign]]) => {
    const tr = document.createElement("tr");
    tr.innerHTML = `<td><kbd>${key}</kbd></td><td>${AXIS_WORDS[axis][sign > 0 ? 1 : 0]}</td>`;
    return tr;
  });
  const stop = document.createElement("tr");
  stop.innerHTML = "<td><kbd>Space</kbd> <kbd>Esc</kbd></td><td>STOP (from anywhere, the 3D view too; " +
    "Esc in a text field, where Space types)</td>";
  $("keymap").replaceChildren(...rows, stop);
  // The same keys in one line beside the instruments, where the eyes are while driving.
  const pairs = {};
  for (const [key, [axis, sign]] of Object.entries(config.keys)) (pairs[axis] ||= [])[sign > 0 ? 0 : 1] = key;
  $("key-hint").replaceChildren(...Object.entries(pairs).map(([axis, [plus, minus]]) => {
    const span = document.createElement("span");
    span.innerHTML = `<kbd>${plus}</kbd>/<kbd>${minus}</kbd> ${{ vx: "surge", vy: "sway", vz: "heave", vyaw: "yaw" }[axis]}`;
    span.title = `${plus}: ${AXIS_WORDS[axis][1]}, ${minus}: ${AXIS_WORDS[axis][0]}`;
    return span;
  }), Object.assign(document.createElement("span"), { innerHTML: "<kbd>Space</kbd>/<kbd>Esc</kbd> STOP" }));
  $("gain").value = config.key_gain;
  $("gain-value").textContent = `${Math.round(config.key_gain * 100)} %`;
  const t = config.default_target;
  $("goto-x").value = t.x_m; $("goto-y").value = t.y_m; $("goto-z").value = t.z_m; $("goto-yaw").value = t.yaw_deg;
  $("shift").max = config.limits.shift[1];
  $("budget").max = config.limits.budget_bytes[1];
  applyCapabilities(config.capabilities || {});
  document.body.dataset.configured = "1";
}

// What the link carries (GET /api/config capabilities): on the acoustic link there are
// no sticks and no "next picture", and pictures are thumbnails asked for one at a time.
// What it cannot do is left out of the page, never shown to fail.
function applyCapabilities(caps) {
  page.noSticks = caps.velocity === false;
  document.body.dataset.profile = caps.profile || "radio";
  if (page.noSticks) {
    for (const id of ["keys", "key-hint"]) $(id).style.display = "none";
    $("wish").closest("tr").hidden = true;
  }
  if (caps.next_image === false) $("next-image").hidden = true;
  page.noFollow = caps.follow === false;
  if (caps.picture === "thumbnail") {
    $("mono").closest("label").hidden = true;
    $("apply-image").textContent = "Ask for a thumbnail";
    $("apply-image").title = "the ROV sends one 80x60 grey thumbnail, coded at this budget (and ROI, if you dragged one)";
    const heading = $("image-settings").querySelector("h2");
    if (heading) heading.textContent = "Thumbnail";
    $("budget").value = Math.min(+$("budget").value, caps.image_budget_max || 198, 198);
    $("budget").step = 10;
  }
}

function setHolder(holder) {
  if (page.holder && !holder) {
    page.held.clear();
    page.lastSent = NEUTRAL;
  }
  page.holder = holder;
  document.body.classList.toggle("holder", holder);
  $("take").hidden = holder;
  $("release").hidden = !holder;
  for (const el of document.querySelectorAll(".needs-control")) el.disabled = !holder;
}

function renderControl(c) {
  setHolder(!!c.you);
  const warn = $("unattended");
  warn.hidden = !c.unattended_warning;
  if (c.unattended_warning) {
    const disarm = c.disarm_unattended_s ? ` It will be disarmed after ${Math.round(c.disarm_unattended_s)} s.` : "";
    warn.textContent = `The vehicle is ARMED and nobody has control (${Math.round(c.unattended_s)} s): ` +
      `take control or disarm.${disarm}`;
  }
  let text;
  const centre = c.centre_to_drive || (c.you && heldThroughHold());
  if (c.you) text = centre ? "You have control: centre the sticks to drive." : "You have control.";
  else if (c.held) text = `Watching: ${c.holder} has control` + (c.centre_to_drive ? " (sticks not centred yet)." : ".");
  else text = "Watching: nobody has control.";
  $("control-text").textContent = text;
  $("control-text").classList.toggle("centre-to-drive", !!centre);
  // Asked to re-centre (just taken control, after a STOP): our input as it is now.
  // Neutral re-centres at once; held keys or a held stick drive only once centred.
  if (c.you && c.centre_to_drive) sendVelocity(true);
}

// ---------------------------------------------------------------------------
// Velocity from keys and gamepad
// ---------------------------------------------------------------------------

function wish() {
  const gain = parseFloat($("gain").value);
  const v = { vx: 0, vy: 0, vz: 0, vyaw: 0 };
  for (const code of page.held) {
    const [axis, sign] = KEYMAP[code];
    v[axis] += sign * gain;
  }
  // The gamepad's sticks (gamepad.js: mapping, deadzone, expo, gain).
  const pad = window.rovGamepad ? window.rovGamepad.wish() : null;
  if (pad) { v.vx += pad.vx; v.vy += pad.vy; v.vz += pad.vz; v.vyaw += pad.vyaw; }
  for (const k of Object.keys(v)) v[k] = Math.round(Math.max(-1, Math.min(1, v[k])) * 1000) / 1000;
  return v;
}

function isNeutral(v) { return v.vx === 0 && v.vy === 0 && v.vz === 0 && v.vyaw === 0; }
function same(a, b) { return a.vx === b.vx && a.vy === b.vy && a.vz === b.vz && a.vyaw === b.vyaw; }

function sendVelocity(force) {
  if (!page.holder || page.noSticks) return;
  const v = wish();
  // Repeat while off neutral (the dead man); neutral once, on the change.
  if (!isNeutral(v) || !same(v, page.lastSent) || force) {
    send({ type: "velocity", ...v });
    page.lastSent = v;
  }
}

function textField(ev) {
  const t = ev.target;
  return !!t && (t.tagName === "TEXTAREA" || t.isContentEditable
    || (t.tagName === "INPUT" && !["range", "checkbox", "radio", "button", "submit", "color"].includes(t.type)));
}

function typing(ev) {
  const t = ev.target;
  return t && (t.tagName === "INPUT" && t.type !== "range" && t.type !== "checkbox" || t.tagName === "SELECT"
    || t.tagName === "TEXTAREA");
}

function onKeyDown(ev) {
  wakeAudio();
  // STOP is one key away from any focus: Escape everywhere, Space everywhere but in a
  // text field (where it types a space: a filter's words never stop the vehicle).
  const plain = !ev.ctrlKey && !ev.metaKey && !ev.altKey;
  if (plain && (ev.code === "Escape" || (ev.code === "Space" && !textField(ev)))) {
    ev.preventDefault();
    if (!ev.repeat) stop();
    return;
  }
  if (typing(ev) || ev.ctrlKey || ev.metaKey || ev.altKey) return;
  if (!(ev.code in KEYMAP)) return;
  ev.preventDefault();
  if (!page.holder) {
    if (!ev.repeat) showError("Take control to drive.");
    return;
  }
  if (!page.held.has(ev.code)) {
    page.held.add(ev.code);
    sendVelocity();
  }
}

function onKeyUp(ev) {
  if (page.held.delete(ev.code)) sendVelocity(true);
}

function letGo() {
  page.held.clear();
  sendVelocity(true);
}

function pollGamepadButtons() {
  if (window.rovGamepad && window.rovGamepad.stopPressed()) stop();
}

function stop() {
  page.lastSent = NEUTRAL;
  // Over the socket when it is open; else over REST at once (a socket reconnecting after a
  // drop must not swallow a STOP).
  if (page.ws && page.ws.readyState === WebSocket.OPEN) send({ type: "stop" });
  else api("/api/orders/stop");
  // After STOP our input as it is now is sent, keys held through it included: the console
  // takes none of it as a drive until it has been centred, and says so ("centre the sticks
  // to drive").  Forgetting a held key here would re-centre at once, and its next repeat
  // would drive again without a word.
  sendVelocity(true);
}

// The ROV shows HOLD (after a STOP, or after its failsafe) and ignores a wish until it sees
// a neutral one: while the pilot's own input has stayed off centre since the HOLD came,
// the page says "centre the sticks to drive".
function watchHold(hold) {
  if (hold && !page.holdSeen) page.neutralSinceHold = isNeutral(wish());
  page.holdSeen = !!hold;
}

function heldThroughHold() {
  if (!page.holdSeen || !page.holder) return false;
  if (isNeutral(wish())) page.neutralSinceHold = true;
  return !page.neutralSinceHold;
}

// ---------------------------------------------------------------------------
// Rendering
// ---------------------------------------------------------------------------

const fmt = (x, digits = 2) => (x === null || x === undefined ? "—" : Number(x).toFixed(digits));

function poseText(p) {
  if (!p) return "—";
  return `x ${fmt(p.x_m)} y ${fmt(p.y_m)} z ${fmt(p.z_m)} m, yaw ${fmt(p.yaw_deg, 0)}°`;
}

function setBadge(el, text, cls) {
  el.textContent = text;
  el.className = `badge ${cls || ""}`;
}

function render(s) {
  // Session seconds to clock time (a replay's own clock).
  if (s.wall && s.pose) page.wallOffset = s.wall - s.pose.t;
  watchHold(s.pose.hold);
  renderControl(s.control);
  const pose = s.pose;
  page.lastPose = pose.received;
  $("replaying").hidden = !s.replaying;
  renderLink(s.link);
  const lost = s.link.state === "lost";
  $("pose-received").textContent = poseText(pose.received) +
    (lost && s.link.since_reply_s !== null ? ` (${fmt(s.link.since_reply_s, 0)} s old)` : "");
  // Lost: the prediction stops where the ROV's failsafe stopped it; say how uncertain it is instead.
  $("pose-predicted").textContent = poseText(pose.predicted) +
    (pose.uncertainty_m !== null && pose.uncertainty_m !== undefined && pose.uncertainty_m >= 0.5
      ? ` ± ${fmt(pose.uncertainty_m, 1)} m` : "");

  $("pose-table").classList.toggle("stale", lost);
  $("image-frame").classList.toggle("stale", lost);
  $("image-done-frame").classList.toggle("stale", lost);
  page.lastState = s;
  renderInstruments(s);
  latchChip($("hold"), !!pose.hold, "HOLD", "HOLD released", "warn");
  latchChip($("stopping"), !!pose.stopping, "STOP in force",
            $("stop-fate").dataset.state === "acknowledged" ? "STOP confirmed" : "STOP ended", "bad");
  $("attitude").hidden = !pose.received || pose.attitude_valid !== false;
  $("cancel-stop").hidden = !(pose.stopping && s.orders.some((o) => o.kind === "STOP" &&
                                                              o.state === "not carried out"));
  if (pose.received) {
    setBadge($("armed"), pose.armed ? "ARMED" : "DISARMED", pose.armed ? "warn" : "");
    setBadge($("mode"), pose.mode, "");
    followVehicleMode(pose.mode);
  }
  renderWish(s.velocity_wish);
  renderTarget(s.target);
  renderWorld(s.world);

  const l = s.link;
  $("link-since-reply").textContent = l.since_reply_s === null ? "—" : `${fmt(l.since_reply_s, 1)} s`;
  $("link-reply-rate").textContent = `${fmt(l.reply_rate_hz, 1)} Hz`;
  $("link-poll-rate").textContent = `${fmt(l.poll_rate_hz, 1)} Hz`;
  $("link-rtt").textContent = l.round_trip_s === null ? "—" : `${fmt(l.round_trip_s * 1000, 0)} ms`;
  $("link-lost").textContent = `${l.reports} / ${l.reports_lost === null ? "—" : l.reports_lost}`;
  $("link-crc").textContent = `${l.bad_frames}`;
  const secure = l.version === "2" || l.version === "acoustic";
  $("link-version").textContent = l.version === "acoustic" ? "acoustic (Modem-M64), authenticated"
    : secure ? "2, authenticated" : "1.1, INSECURE (no key)";
  $("link-version").classList.toggle("insecure", !secure);
  $("link-auth").textContent = `${l.inauthentic_frames ?? 0} / ${l.late_replies ?? 0}`;
  if (l.auth_alert && !page.authAlert) showError("ALERT: frames fail authentication and no reply comes (another key or operator, a forger, or heavy noise)");
  page.authAlert = !!l.auth_alert;
  $("link-bps").textContent = `${fmt(l.bytes_per_s, 0)} B/s`;
  $("link-odo-age").textContent = l.odometry_age_s === null ? "—" : `${fmt(l.odometry_age_s, 2)} s`;
  $("link-bytes").textContent = `${l.bytes_sent} / ${l.bytes_received}`;
  renderFailsafe(l.failsafe || page.failsafeActive);
  setBadge($("autopilot"), l.autopilot ? "AUTOPILOT" : "NO AUTOPILOT", l.autopilot ? "good" : "bad");
  // Degraded says which figure crossed its threshold: in a few words on the badge, whole in
  // its tooltip and in the link card.
  const degraded = l.degraded_short ? `link degraded: ${l.degraded_short}` : "link degraded";
  const badge = processDown(l) ? ["LINK PROCESS DOWN", "bad"] : portDown(l) ? ["MODEM PORT DOWN", "bad"]
    : { up: ["link up", "good"], degraded: [degraded, "warn"], lost: ["LINK LOST", "bad"],
        replay: ["REPLAY", "warn"], starting: ["link starting", ""] }[l.state] || [l.state, ""];
  setBadge($("link-up"), badge[0], badge[1]);
  $("link-up").title = l.degraded_reason || "";
  $("link-why").textContent = l.state === "degraded" && l.degraded_reason ? l.degraded_reason : "—";

  renderImageProgress(s.image);
  renderPictureWait(s.image.waiting);
  for (const o of s.orders) renderOrder(o, true);
  renderList($("orders"), s.orders.slice(-8).reverse(), orderText);
  addLog(s.log);
}

// A wish fraction in the pilot's units: the vehicle model's steady state
// (GET /api/config wish_scale, console/control.py), so "about".
function wishUnits(axis, f) {
  const sc = page.config && page.config.wish_scale && page.config.wish_scale[axis];
  if (!sc || !f) return 0;
  if (sc.kind === "rate") return sc.max * f;
  const thrust = sc.thrust_n * Math.abs(f);
  const v = (-sc.lin + Math.sqrt(sc.lin * sc.lin + 4 * sc.quad * thrust)) / (2 * sc.quad);
  return Math.sign(f) * v;
}

function renderWish(w) {
  const parts = [];
  const names = { vx: ["forward", "back"], vy: ["right", "left"], vz: ["down", "up"], vyaw: ["turn right", "turn left"] };
  for (const axis of ["vx", "vy", "vz", "vyaw"]) {
    if (!w[axis]) continue;
    const v = wishUnits(axis, w[axis]);
    const unit = axis === "vyaw" ? "°/s" : "m/s";
    parts.push(`${names[axis][w[axis] > 0 ? 0 : 1]} ${Math.abs(v).toFixed(axis === "vyaw" ? 0 : 2)} ${unit}`);
  }
  $("wish").textContent = parts.length ? `≈ ${parts.join(", ")}` : "neutral";
  $("wish").title = `fractions: vx ${fmt(w.vx)} vy ${fmt(w.vy)} vz ${fmt(w.vz)} vyaw ${fmt(w.vyaw)}`;
  document.body.dataset.wish = JSON.stringify(w);
}

// ---------------------------------------------------------------------------
// Instruments: from the last reply; grey when old (link lost) or not measured
// ---------------------------------------------------------------------------

function renderInstruments(s) {
  const pose = s.pose;
  const r = pose.received;
  const lost = s.link.state === "lost";
  const attOk = !!r && pose.attitude_valid !== false;
  const posOk = !!r && pose.position_valid !== false;
  const target = s.target && s.target.sent ? s.target : null;
  const mark = (id, ok) => {
    const el = $(id);
    el.classList.toggle("stale", !!r && lost);
    el.classList.toggle("invalid", !ok);
    el.dataset.valid = ok && !lost ? "1" : "0";
  };
  // An acoustic status carries a heading, no roll or pitch (tilt_valid false): not shown as measured.
  const tiltOk = attOk && pose.tilt_valid !== false;
  mark("inst-attitude", tiltOk);
  mark("inst-heading", attOk);
  mark("inst-depth", posOk);
  const I = window.rovInstruments;
  if (I) {
    I.attitude($("attitude-indicator"), tiltOk ? r.roll_deg : null, tiltOk ? r.pitch_deg : null, tiltOk && !lost);
    I.heading($("heading-tape"), attOk ? r.yaw_deg : null, target ? target.yaw_deg : null, attOk && !lost);
    I.depth($("depth-tape"), posOk ? r.z_m : null, target ? target.z_m : null, posOk && !lost);
  }
  $("attitude-text").textContent = tiltOk ? `roll ${fmt(r.roll_deg, 0)}° pitch ${fmt(r.pitch_deg, 0)}°`
    : attOk ? "roll — pitch — (not reported on this link)" : "roll — pitch —";
  $("heading-text").textContent = attOk ? `heading ${fmt((r.yaw_deg % 360 + 360) % 360, 0)}°` +
    (target ? `, target ${fmt((target.yaw_deg % 360 + 360) % 360, 0)}°` : "") : "heading —";
  $("depth-text").textContent = posOk ? `depth ${fmt(r.z_m, 1)} m` + (target ? `, target ${fmt(target.z_m, 1)}` : "")
    : "depth —";
  const v = pose.velocity;
  const speed = (x, unit, digits = 2) => (v && !lost ? `${fmt(x, digits)} ${unit}` : "—");
  $("speed-forward").textContent = speed(v && v.forward_mps, "m/s");
  $("speed-right").textContent = speed(v && v.right_mps, "m/s");
  // Vertical: up positive, as a pilot reads a climb.
  $("speed-vertical").textContent = v && !lost ? `${v.down_mps > 0.005 ? "down" : v.down_mps < -0.005 ? "up" : ""} ${fmt(Math.abs(v.down_mps))} m/s` : "—";
  $("speed-yaw").textContent = speed(v && v.yaw_dps, "°/s", 0);
  for (const id of ["speed-forward", "speed-right", "speed-vertical", "speed-yaw"]) {
    $(id).classList.toggle("stale", !!r && lost);
  }
  // The acoustic link's status comes every few seconds: its age, and when the next is due.
  $("odometry-age").textContent = pose.odometry_age_s === null || pose.odometry_age_s === undefined ? "—"
    : `${fmt(pose.odometry_age_s, 1)} s old` + (pose.next_report_in_s === null || pose.next_report_in_s === undefined
      ? "" : `, next status in ${fmt(pose.next_report_in_s, 0)} s`);
}

// ---------------------------------------------------------------------------
// The log: clock time, alerts apart, filterable
// ---------------------------------------------------------------------------

// The session's clock: this computer's, or in a replay the recording's (from telemetry).
function nowWall() {
  const s = page.lastState;
  return s && s.replaying && s.wall ? s.wall : Date.now() / 1000;
}

const clockTime = (wall) => (wall ? new Date(wall * 1000).toLocaleTimeString([], { hour12: false }) : "");

function addLog(entries) {
  let added = false;
  for (const e of entries || []) {
    const key = `${e.t}|${e.text}`;
    const known = page.logKeys.get(key);
    if (known) {
      // The same line again: its alert's cause may have ended meanwhile.
      if (known.cleared_wall !== e.cleared_wall) { known.cleared_wall = e.cleared_wall; added = true; }
      continue;
    }
    page.logKeys.set(key, e);
    page.logEntries.push(e);
    added = true;
  }
  if (!added) return;
  page.logEntries.sort((a, b) => a.t - b.t);
  if (page.logEntries.length > 500) {
    for (const e of page.logEntries.splice(0, page.logEntries.length - 500)) page.logKeys.delete(`${e.t}|${e.text}`);
  }
  renderLog();
}

function renderLog() {
  const level = $("log-level").value;
  const words = $("log-filter").value.trim().toLowerCase();
  const wanted = (e) => (level === "all" || (level === "alert" && e.level === "alert")
    || (level === "warn" && e.level !== "info") || (level === "info" && e.level === "info"))
    && (!words || e.text.toLowerCase().includes(words));
  const line = (e) => {
    const li = document.createElement("li");
    li.textContent = `${clockTime(e.wall)} ${e.text}` + (e.cleared_wall ? ` — cleared ${clockTime(e.cleared_wall)}` : "");
    li.className = (e.level || "info") + (e.cleared_wall ? " cleared" : "");
    return li;
  };
  const shown = page.logEntries.filter(wanted).slice(-100).reverse();
  $("log").replaceChildren(...shown.map(line));
  $("log").dataset.count = shown.length;
  // The last alerts stand apart, above the routine lines.
  const alerts = page.logEntries.filter((e) => e.level === "alert").slice(-3).reverse();
  $("alerts").replaceChildren(...alerts.map(line));
}

// When an order reached its state: its t_<state> (session seconds) as clock time.
function orderClock(o) {
  const t = o[`t_${o.state}`] ?? o.t_queued;
  return page.wallOffset === null || t === undefined ? "" : clockTime(t + page.wallOffset);
}

function orderText(o) {
  const guided = o.kind === "POSITION" ? " (GUIDED)" : "";
  const left = distanceLeft(o);
  return `${orderClock(o)} #${o.id} ${o.kind}${guided}: ${o.text}${left}${waitedFor(o)}`;
}

// An order the vehicle has not answered shows how long it has waited (the fate is
// the vehicle's to say: the console never gives up on its behalf).
function waitedFor(o) {
  const s = page.lastState;
  if (o.outcome !== "pending" || !s || typeof s.wall !== "number" || page.wallOffset === null) return "";
  return `, ${fmt(Math.max(0, s.wall - (o.t_queued + page.wallOffset)), 0)} s`;
}

function distanceLeft(o) {
  const open = o.outcome === "pending" || o.state === "acknowledged";
  return o.kind === "POSITION" && open && o.distance_left_m !== null && o.distance_left_m !== undefined
    ? `, ${fmt(o.distance_left_m, 1)} m to go` : "";
}

// Each order's fate beside the control that gave it: the newest of its kind.
const FATE_OF = { ARM: "arm-fate", DISARM: "arm-fate", MODE: "mode-fate", POSITION: "goto-fate", IMAGE: "image-fate",
                  STOP: "stop-fate" };

// The fate's colour is the server's `outcome` (console/session/fates.py): pending,
// done, bad; "ended" (cancelled, aborted: by someone's choice) has none.
function fateClass(o) {
  return o.outcome === "ended" ? "" : o.outcome;
}

function renderFate(o) {
  const el = $(FATE_OF[o.kind] || "");
  if (!el || +(el.dataset.id || 0) > o.id) return;  // late news of an older order
  const what = { ARM: "arm", DISARM: "disarm", MODE: `mode ${o.mode}`, POSITION: `go-to #${o.id}`,
                 IMAGE: `image settings #${o.id}` }[o.kind];
  let text = `${what}: ${o.text}${distanceLeft(o)}${waitedFor(o)} ${orderClock(o)}`;
  const thumbnail = document.body.dataset.profile === "acoustic";
  if (o.kind === "IMAGE" && thumbnail) {
    text = `thumbnail #${o.id}: ` + ({ acknowledged: "taken by the ROV, its packets coming", done: "received" }[o.state]
      || o.text) + ` ${orderClock(o)}`;
  } else if (o.kind === "IMAGE" && o.state === "acknowledged") {
    text = `${what}: in force from the next picture ${orderClock(o)}`;
  }
  // In the top bar, short: the whole state is in its tooltip.
  const pending = o.outcome === "pending";
  const waiting = o.state === "waiting" ? ` (not yet${waitedFor(o)})` : "";
  if (o.kind === "ARM" || o.kind === "DISARM") {
    const verb = o.kind === "ARM" ? "arm" : "disarm";
    text = pending ? `${verb}ing…${waiting}` : o.state === "followed" ? `${verb}ed ✓ ${orderClock(o)}`
      : `${verb}: ${o.text}`;
  } else if (o.kind === "MODE") {
    text = pending ? `${o.mode}…${waiting}` : o.state === "followed" ? `${o.mode} ✓ ${orderClock(o)}`
      : `${o.mode}: ${o.text}`;
  } else if (o.kind === "STOP") {
    // acknowledged, reason "holding in POS_HOLD" -> "STOP ✓ holding in POS_HOLD 07:00:48"
    text = pending ? "STOP sent…" : o.state === "acknowledged"
      ? `STOP ✓ ${o.reason || "confirmed"} ${orderClock(o)}` : `STOP ${o.text} ${orderClock(o)}`;
  }
  el.textContent = text;
  el.title = `#${o.id} ${o.kind}: ${o.text}`;
  el.className = `fate ${fateClass(o)}`;
  el.dataset.id = o.id;
  el.dataset.state = o.state;
}

// Every order's fate is shown; a refusal or rejection also pops up once.
function renderOrder(o, quiet) {
  // Each change of an order counts up its version: a telemetry made before an event it
  // follows never takes back what the event said (a go-to "arrived", then "0.9 m to go").
  const shown = page.orders[o.id];
  if (shown && (shown.version || 0) > (o.version || 0)) return;
  renderFate(o);
  const before = page.orders[o.id] ? page.orders[o.id].state : undefined;
  page.orders[o.id] = o;
  if (page.roiSent && page.roiSent.id === o.id && before !== o.state) renderRoiStatus();
  if (page.follow && page.follow.id === o.id && before !== o.state) renderTrack(lastImageState);
  for (const [id, f] of Object.entries(page.frames)) {
    const first = f.orderId === null ? null : page.orders[f.orderId];
    if (f.orderId === o.id || (first && first.then === o.id)) renderFrameFate(id);
  }
  const bad = o.outcome === "bad" && o.state !== "unknown";  // unknown: in the log, not a pop-up
  if (bad && before !== o.state && !quiet) showError(`${o.kind} order #${o.id} ${o.text}`);
  if (!quiet) {
    const ul = $("orders");
    const li = Object.assign(document.createElement("li"), { textContent: orderText(o) });
    if (bad) li.className = "refused";
    li.dataset.id = o.id;
    const old = ul.querySelector(`li[data-id="${o.id}"]`);
    if (old) old.replaceWith(li); else ul.prepend(li);
    ul.dataset.lines = "";
  }
}

// What the ROV measured of the world (console/session/world.py): the seabed's depth, or why
// it is unknown (then the 3-D scene draws no floor), and the objects it recognised, each
// with its age; "Go to" fills the go-to with a stand-off facing it and previews it.
function renderWorld(w) {
  if (!w) return;
  const seabed = $("seabed-text");
  const text = w.seabed_depth_m === null ? `seabed depth unknown: ${w.seabed_unknown_why}`
    : `seabed at ${fmt(w.seabed_depth_m, 1)} m (altitude ${fmt(w.altitude_m, 1)} m, ${fmt(w.altitude_age_s, 0)} s ago` +
      `${w.altitude_stale ? ", OLD" : ""})` + (w.records_ignored ? `; ${w.records_ignored} bad object records ignored` : "");
  if (seabed.textContent !== text) seabed.textContent = text;
  seabed.className = w.seabed_depth_m === null || w.altitude_stale ? "stale" : "";
  const ul = $("objects");
  const key = w.objects.map((o) => `${o.id}:${o.updated_t}`).join(",");
  if (ul.dataset.key === key) {
    for (const li of ul.children) {  // only the ages move
      const o = w.objects.find((x) => `${x.id}` === li.dataset.id);
      if (o) li.querySelector(".age").textContent = `${fmt(o.age_s, 0)} s ago`;
    }
    return;
  }
  ul.dataset.key = key;
  ul.replaceChildren(...w.objects.map((o) => {
    const li = document.createElement("li");
    li.dataset.id = o.id;
    li.append(`#${o.id} ${o.class} ${fmt(o.length_m, 1)} × ${fmt(o.width_m, 1)} m at N ${fmt(o.north_m, 1)} ` +
      `E ${fmt(o.east_m, 1)}, heading ${fmt(o.heading_deg, 0)}°, ${Math.round(o.confidence * 100)} %, `);
    const age = Object.assign(document.createElement("span"), { className: "age", textContent: `${fmt(o.age_s, 0)} s ago` });
    const go = Object.assign(document.createElement("button"), {
      type: "button", className: "needs-control object-goto", textContent: "Go to",
      title: "fill in a go-to that stops short of it, facing it, and preview it (Go to sends it)" });
    go.onclick = () => approachObject(o.id);
    go.disabled = !page.holder;
    const frame = Object.assign(document.createElement("button"), {
      type: "button", className: "needs-control object-frame", textContent: "Frame it",
      title: "the next picture's ROI on it, where it lies in the picture from where the ROV is, and FOLLOW where " +
             "the link carries it (said here when it is not in view)" });
    frame.onclick = () => frameObject(o.id);
    frame.disabled = !page.holder;
    const fate = Object.assign(document.createElement("span"), { className: "fate object-frame-fate" });
    fate.setAttribute("role", "status");
    li.append(age, " ", go, " ", frame, " ", fate);
    renderFrameFate(o.id, fate);
    return li;
  }));
}

// "Frame it" (POST /api/world/objects/{id}/frame, the desk's FrameObject): what was decided,
// or why not in one line, beside the button; then the IMAGE order's fate as the vehicle tells it.
async function frameObject(id) {
  const headers = { "Content-Type": "application/json" };
  if (page.clientId) headers[CLIENT_HEADER] = page.clientId;
  let data = null;
  try {
    const resp = await fetch(`/api/world/objects/${id}/frame`, { method: "POST", headers, body: "{}" });
    data = await resp.json();
    page.frames[id] = resp.ok
      ? { text: `${data.text}: ROI [${data.roi.join(", ")}]`, outcome: "pending", orderId: data.id }
      : { text: `not framed: ${data.message || resp.status}`, outcome: "bad", orderId: null };
  } catch (err) {
    page.frames[id] = { text: `not framed: ${err}`, outcome: "bad", orderId: null };
  }
  const f = page.frames[id];
  if (f.orderId !== null && page.orders[f.orderId]) f.outcome = page.orders[f.orderId].outcome;
  renderFrameFate(id);
  return data;
}

function renderFrameFate(id, el) {
  el = el || document.querySelector(`#objects li[data-id="${id}"] .object-frame-fate`);
  const f = page.frames[id];
  if (!el || !f) return;
  const first = f.orderId === null ? null : page.orders[f.orderId];
  // A FOLLOW the ROV rejected (it does not follow) is followed by its ROI sent alone: that
  // order's fate is the frame's.
  const then = first && first.then ? page.orders[first.then] : null;
  const o = then || first;
  let fate = first ? ` · order #${first.id} ${first.text}` : "";
  if (first && first.then) fate += `; the ROI alone: order #${first.then} ${then ? then.text : "queued"}`;
  el.textContent = f.text + fate;
  el.className = `fate object-frame-fate ${o ? fateClass(o) : f.outcome}`;
  el.dataset.outcome = o ? o.outcome : f.outcome;
  el.dataset.order = o ? o.id : (f.orderId === null ? "" : f.orderId);
}

async function approachObject(id) {
  const t = await api(`/api/world/objects/${id}/approach`, undefined, "GET");
  if (!t) return;
  $("goto-x").value = t.x_m; $("goto-y").value = t.y_m; $("goto-z").value = t.z_m; $("goto-yaw").value = t.yaw_deg;
  $("goto-plan").dataset.object = id;
  $("goto-preview").click();
}

function renderTarget(t) {
  if (t === undefined) return;
  const box = $("goto-plan");
  if (!t) { box.dataset.target = ""; return; }
  const key = JSON.stringify([t.x_m, t.y_m, t.z_m, t.yaw_deg, t.order_id]);
  if (box.dataset.target === key) return;
  box.dataset.target = key;
  box.hidden = false;
  // The preview's own words (length, time) stay until the target is sent or changed.
  if (!t.sent && box.dataset.previewed === "1") return;
  box.dataset.previewed = "";
  box.textContent = t.sent
    ? `target x ${fmt(t.x_m)} y ${fmt(t.y_m)} z ${fmt(t.z_m)}: sent as order #${t.order_id} (the vehicle flies it in GUIDED)`
    : `target x ${fmt(t.x_m)} y ${fmt(t.y_m)} z ${fmt(t.z_m)} previewed: not sent; Go to switches the vehicle to GUIDED`;
}

// ---------------------------------------------------------------------------
// Link state: from replies; lost is loud
// ---------------------------------------------------------------------------

// This console's own modem port gone (its USB serial adapter pulled): said at once,
// before the replies stop long enough for LINK LOST.
// (port_error is the console's reason, given only while its port is down: a replay has none.)
function portDown(l) {
  return l.port_error !== null && l.port_error !== undefined;
}

// The console's link process (link/process.py) ended: no poll leaves until it is started
// again.  Said at once, apart from the ROV's silence (LINK LOST) and the modem's port.
function processDown(l) {
  return l.link_process === "down";
}
const PROCESS_BACK_SHOWN_MS = 6000;

function renderLink(l) {
  const was = page.linkState;
  const down = portDown(l);
  const loud = ["lost", "port down", "process down"];
  page.linkState = processDown(l) ? "process down" : down ? "port down" : l.state;
  document.body.dataset.link = page.linkState;
  const banner = $("link-banner");
  if (was === "process down" && !processDown(l)) page.processBackUntil = Date.now() + PROCESS_BACK_SHOWN_MS;
  if (processDown(l)) {
    page.processDownWhy = l.link_process_reason;
    banner.hidden = false;
    banner.className = "";
    $("link-banner-title").textContent = "LINK PROCESS DOWN";
    $("link-banner-text").textContent = `${l.link_process_reason || "it ended"}; starting it again. ` +
      "No poll leaves meanwhile: the ROV stops on its failsafe; orders in flight are shown unknown";
    $("failsafe-inferred").hidden = true;
    if (!loud.includes(was)) alarm();
  } else if (page.processBackUntil && Date.now() < page.processBackUntil && l.state !== "lost" && !down) {
    // Back within a second or two: said long enough to be read, then the banner goes.
    banner.hidden = false;
    banner.className = "replay";
    $("link-banner-title").textContent = "LINK PROCESS STARTED AGAIN";
    $("link-banner-text").textContent = `after ${page.processDownWhy || "its end"}: polls leave again; ` +
      "orders it held are shown unknown";
    $("failsafe-inferred").hidden = true;
  } else if (down) {
    banner.hidden = false;
    banner.className = "";
    $("link-banner-title").textContent = "MODEM PORT DOWN";
    $("link-banner-text").textContent = `${l.port_error}; opening it again. No poll reaches the ROV: it stops on its failsafe`;
    $("failsafe-inferred").hidden = true;
    if (!loud.includes(was)) alarm();
  } else if (l.state === "lost") {
    banner.hidden = false;
    banner.className = "";
    $("link-banner-title").textContent = "LINK LOST";
    $("link-banner-text").textContent = l.since_reply_s === null ? "no reply from the ROV"
      : `no reply from the ROV for ${fmt(l.since_reply_s, 0)} s; pose and picture are old`;
    const fs = $("failsafe-inferred");
    fs.hidden = !l.failsafe_inferred;
    if (l.failsafe_inferred) fs.textContent = `ROV in FAILSAFE (inferred) since ${l.failsafe_inferred_since}`;
    if (!loud.includes(was)) alarm();
  } else if (l.state === "replay") {
    banner.hidden = false;
    banner.className = "replay";
    $("link-banner-title").textContent = "REPLAY";
    $("link-banner-text").textContent = "a recorded session: there is no ROV";
    $("failsafe-inferred").hidden = true;
  } else {
    banner.hidden = true;
    if (loud.includes(was)) stopAlarm();
  }
}

function wakeAudio() {
  // Browsers start sound only after a user gesture: the first key or click.
  if (!page.audio && window.AudioContext) {
    try { page.audio = new AudioContext(); } catch (err) { page.audio = null; }
  }
  if (page.audio && page.audio.state === "suspended") page.audio.resume();
}

function beep() {
  const ctx = page.audio;
  if (!ctx) return;
  const osc = ctx.createOscillator();
  const gain = ctx.createGain();
  osc.type = "square";
  osc.frequency.value = 880;
  gain.gain.value = 0.15;
  osc.connect(gain).connect(ctx.destination);
  osc.start();
  osc.stop(ctx.currentTime + 0.25);
}

function alarm() {
  page.alerts += 1;
  document.body.dataset.alerts = page.alerts;
  wakeAudio();
  beep();
  clearInterval(page.alarmTimer);
  page.alarmTimer = setInterval(beep, 2000);  // until the link returns
}

function stopAlarm() {
  clearInterval(page.alarmTimer);
  page.alarmTimer = null;
}

// A chip of the top bar that came for a reply or two (HOLD released by the next neutral, a
// STOP confirmed at once on a fast link) would be gone before it is read: once shown it
// stays CHIP_MIN_MS, in words that say it has ended.
const CHIP_MIN_MS = 8000;

function latchChip(el, active, activeText, endedText, cls) {
  if (active) el.dataset.at = Date.now();
  const recent = !!el.dataset.at && Date.now() - +el.dataset.at < CHIP_MIN_MS;
  el.hidden = !active && !recent;
  el.textContent = active ? activeText : endedText;
  el.className = `badge ${active ? cls : "ended"}`;
  el.dataset.active = active ? "1" : "";
}

// FAILSAFE often lasts one reply (the first after a silence): the badge
// stays up a while after it clears, so that the pilot sees it happened.
const FAILSAFE_LATCH_MS = 10000;

function renderFailsafe(active) {
  if (active) page.failsafeAt = Date.now();
  const recent = page.failsafeAt !== null && Date.now() - page.failsafeAt < FAILSAFE_LATCH_MS;
  const el = $("failsafe");
  el.hidden = !recent;
  el.textContent = active ? "FAILSAFE" : "FAILSAFE (cleared)";
  el.className = `badge ${active ? "bad" : "warn"}`;
}

function renderList(ul, items, text) {
  const lines = items.map(text);
  if (ul.dataset.lines === JSON.stringify(lines)) return;
  ul.dataset.lines = JSON.stringify(lines);
  ul.replaceChildren(...lines.map((t) => Object.assign(document.createElement("li"), { textContent: t })));
}

// No picture yet: say why (the ROV's codec warming up, the link, pictures off).
function renderPictureWait(why) {
  const card = $("image-card");
  if ((card.dataset.waiting || "") === (why || "")) return;
  card.dataset.waiting = why || "";
  $("no-image").textContent = why || "waiting for the next picture…";
  $("no-image-done").textContent = why || "no complete picture yet";
}

function renderImageProgress(im) {
  // Image events and telemetry snapshots interleave: never step back.
  const card = $("image-card");
  if (String(im.img ?? "") === card.dataset.img && im.received_bytes < +card.dataset.receivedBytes) return;
  const bar = $("image-progress");
  bar.max = im.total_bytes || 1;
  bar.value = im.received_bytes;
  // Nothing arriving yet: the picture's frame says why; no "0 / ? bytes".
  $("image-bytes").textContent = im.total_bytes ? `${im.received_bytes} / ${im.total_bytes} bytes`
    : im.received_bytes ? `${im.received_bytes} bytes so far` : "";
  $("image-id").textContent = im.img === null ? "" : `#${im.serial ?? ""} (IMG ${im.img})${im.complete ? " complete" : ""}` +
    (im.capture ? `, captured ${captureText(im.capture)}` : "");
  renderSkipped(im.skipped);
  card.dataset.img = im.img ?? "";
  card.dataset.receivedBytes = im.received_bytes;
  card.dataset.totalBytes = im.total_bytes ?? "";
  renderTrack(im);
  showImage(im);
  // A picture kept (a partial one the pilot skipped included) is in the strip at once.
  const key = `${im.serial ?? ""}:${im.images_completed ?? ""}:${im.kept ?? ""}`;
  if (key !== page.historyKey) {
    page.historyKey = key;
    loadHistory();
  }
}

// Next image's fate beside it: what the pilot skipped, and that the next picture is coming.
function renderSkipped(k) {
  const el = $("next-image-fate");
  if (!k || el.dataset.wall === String(k.wall)) return;
  el.dataset.wall = k.wall;
  const at = clockTime(k.wall);
  el.textContent = k.n !== null && k.n !== undefined
    ? `skipped picture #${k.n} at ${k.received_bytes}${k.total_bytes ? ` of ${k.total_bytes - 2}` : ""} B, ` +
      `next one coming ${at}`
    : k.received_bytes ? `skipped a picture not yet shown at ${k.received_bytes} B, next one coming ${at}`
      : `skipped before its first bytes came, next one coming ${at}`;
  el.className = "fate done";
  el.dataset.state = "skipped";
}

// ---------------------------------------------------------------------------
// Kept pictures: the last complete one large, a strip to look back, Save
// ---------------------------------------------------------------------------

// The capture is known only between two replies (console/session/radio.py): say so.
function captureText(c) {
  if (!c) return "at an unknown time";
  const age = Math.max(0, nowWall() - c.wall);
  const window = c.not_before_wall === null ? " or earlier" : c.not_after_wall - c.not_before_wall > 1.5
    ? ` to ${clockTime(c.not_after_wall)}` : "";
  return `${clockTime(c.wall)}${window}, ${age < 90 ? `${age.toFixed(0)} s` : `${(age / 60).toFixed(0)} min`} ago`;
}

function poseShort(p) {
  return p ? `x ${fmt(p.x_m, 1)} y ${fmt(p.y_m, 1)} z ${fmt(p.z_m, 1)} m, ${fmt((p.yaw_deg % 360 + 360) % 360, 0)}°` : "position not known";
}

let historyAsked = 0;
let historyShown = 0;
async function loadHistory() {
  const ask = ++historyAsked;
  let history;
  try {
    const resp = await fetch("/api/images", { cache: "no-store" });
    if (!resp.ok) return;
    history = await resp.json();
  } catch (err) {
    return;
  }
  if (ask < historyShown) return;  // an older answer, overtaken
  historyShown = ask;
  page.history = history;
  renderStrip();
  renderShownPicture();
}

function shownEntry() {
  const h = page.history;
  if (page.shownPast !== null) {
    const e = h.find((x) => x.n === page.shownPast);
    if (e) return e;
    page.shownPast = null;  // no longer kept
  }
  for (let i = h.length - 1; i >= 0; i -= 1) if (!h[i].partial) return h[i];
  return null;
}

// Thumbnails are made once per picture and kept while it is kept: only a new
// picture is fetched (an old one may be dropped by the console at any moment).
const thumbs = new Map();

function renderStrip() {
  const shown = shownEntry();
  const kept = new Set(page.history.map((e) => e.n));
  for (const n of thumbs.keys()) if (!kept.has(n)) thumbs.delete(n);
  const buttons = page.history.slice().reverse().map((e) => {
    let b = thumbs.get(e.n);
    if (!b) {
      b = document.createElement("button");
      b.type = "button";
      b.dataset.n = e.n;
      const img = document.createElement("img");
      img.alt = `picture ${e.n}`;
      img.src = `/api/images/${e.n}.png`;
      const label = document.createElement("span");
      label.className = "n";
      label.textContent = `#${e.n}`;  // the number the card, the log and the saved file say
      b.append(img, label);
      thumbs.set(e.n, b);
    }
    b.className = (e.partial ? "partial " : "") + (shown && e.n === shown.n ? "shown" : "");
    b.title = `#${e.n}${partialWords(e, ", partial")}, captured ${captureText(e.capture)}, ${e.bytes} B`;
    b.onclick = () => {
      const newest = page.history.filter((x) => !x.partial).pop();
      page.shownPast = newest && newest.n === e.n ? null : e.n;
      renderStrip();
      renderShownPicture();
    };
    return b;
  });
  $("image-strip").replaceChildren(...buttons);
}

function renderShownPicture() {
  const e = shownEntry();
  const img = $("image-done");
  $("image-save").disabled = !e;
  $("image-latest").hidden = page.shownPast === null;
  $("no-image-done").hidden = !!e;
  img.hidden = !e;  // no broken-image icon before the first picture
  if (!e) { img.removeAttribute("src"); $("image-done-meta").textContent = "—"; return; }
  const src = `/api/images/${e.n}.png`;
  if (img.dataset.n !== String(e.n)) {
    img.src = src;
    img.dataset.n = e.n;
    img.onload = () => drawRoi();
  }
  $("image-done-id").textContent = `#${e.n}${page.shownPast !== null ? " (looking back)" : " latest complete"}`;
  renderShownMeta();
}

// A partial picture: the pilot skipped it (Next image), or the link abandoned it.
const partialWords = (e, more) => (!e.partial ? "" : e.skipped ? ` (skipped by the pilot${more})` : ` (abandoned${more})`);

function renderShownMeta() {
  const e = shownEntry();
  if (!e) return;
  const s = e.settings;
  const roi = s && s.roi ? `ROI ${s.roi.join(",")} shift ${s.shift}` : "no ROI";
  const c = e.capture;
  $("image-done-meta").textContent = `captured ${captureText(c)} at ${poseShort(c && c.pose)}; ` +
    `${e.bytes}${e.total_bytes ? ` / ${e.total_bytes - 2}` : ""} B${partialWords(e, "")}` +
    `${e.seconds !== null ? ` in ${fmt(e.seconds, 1)} s` : ""}, ${roi}`;
}

function savePicture() {
  const e = shownEntry();
  if (!e) return;
  // Said on the page: a browser may save without asking, and the pilot must know which picture went.
  $("image-saved").textContent = `#${e.n} saved (PNG and JSON, see your downloads)`;
  $("image-saved").dataset.n = e.n;
  for (const ext of ["png", "json"]) {
    const a = document.createElement("a");
    a.href = `/api/images/${e.n}.${ext}?download=1`;
    a.download = "";
    document.body.append(a);
    a.click();
    a.remove();
  }
}

function showImage(im) {
  if (!im || !im.decoded_bytes) return;
  lastImageState = im;
  // Keyed on the serial (IMG wraps at 8, and a replay's jump may bring an IMG back).
  const key = `${im.serial ?? im.img}:${im.decoded_bytes}`;
  if (key === page.shownImage) {
    // The same picture, its MAC held since (the acoustic thumbnail): said at once.
    renderVerified(im, key);
    return;
  }
  // A telemetry snapshot taken before the newest decode may arrive after
  // it: never swap in an older picture of the same image.
  const [wantedImg, wantedBytes] = (page.wantedImage || ":").split(":");
  if (String(im.serial ?? im.img) === wantedImg && im.decoded_bytes < +wantedBytes) return;
  const imgNo = im.img;
  page.wantedImage = key;
  if (page.loadingImage) return;   // the load in flight fetches again when done
  page.loadingImage = true;
  // Load off screen, then swap: the old picture stays until the new one is ready.
  const next = new Image();
  const done = () => {
    page.loadingImage = false;
    if (page.wantedImage !== page.shownImage) showImage(lastImageState);
  };
  next.onload = () => {
    const img = $("image");
    img.src = next.src;
    img.hidden = false;
    img.dataset.key = key;
    page.shownImage = key;
    $("no-image").hidden = true;
    const bytes = key.split(":")[1];
    img.dataset.img = imgNo;
    img.dataset.decodedBytes = bytes;
    renderVerified(im, key);
    drawRoi();
    renderRoiStatus();
    done();
  };
  next.onerror = done;
  next.src = `/api/image/latest.png?img=${encodeURIComponent(im.img)}&bytes=${im.decoded_bytes}`;
}
let lastImageState = null;

// Which picture is shown (the next one's first bytes may not be decoded yet), and whether
// its MAC has held (the acoustic thumbnail; null on the radio link, checked per trunk).
function renderVerified(im, key) {
  const [serial, bytes] = key.split(":");
  $("image-decoded").textContent = `showing #${serial} from ${bytes} bytes` +
    (im.verified === false ? " (UNVERIFIED: its MAC has not held yet)" : im.verified ? ", verified" : "");
  $("image-frame").classList.toggle("unverified", im.verified === false);
}

// ---------------------------------------------------------------------------
// Region of interest: dragged on the picture, in the picture's own pixels
// ---------------------------------------------------------------------------

const PICTURES = [["image", "roi-box", "roi-draft"], ["image-done", "roi-box-done", "roi-draft-done"]];

function picturePoint(ev, img = page.dragImg || $("image")) {
  const r = img.getBoundingClientRect();
  const fx = Math.min(1, Math.max(0, (ev.clientX - r.left) / r.width));
  const fy = Math.min(1, Math.max(0, (ev.clientY - r.top) / r.height));
  return [Math.round(fx * img.naturalWidth), Math.round(fy * img.naturalHeight)];
}

function roiFrom(a, b) {
  return [Math.min(a[0], b[0]), Math.min(a[1], b[1]), Math.max(a[0], b[0]), Math.max(a[1], b[1])];
}

// The ROI a picture is coded with (its own settings, never the pilot's latest wish):
// the arriving picture's from the image state, a kept one's from its entry.
function codedRoi(imgId) {
  if (imgId === "image") return lastImageState && lastImageState.settings ? lastImageState.settings.roi : null;
  const e = shownEntry();
  return e && e.settings ? e.settings.roi : null;
}

function placeBox(box, img, roi) {
  if (!roi) { box.hidden = true; return; }
  const sx = img.clientWidth / img.naturalWidth;
  const sy = img.clientHeight / img.naturalHeight;
  Object.assign(box.style, {
    left: `${img.offsetLeft + roi[0] * sx}px`, top: `${img.offsetTop + roi[1] * sy}px`,
    width: `${(roi[2] - roi[0]) * sx}px`, height: `${(roi[3] - roi[1]) * sy}px`,
  });
  box.hidden = false;
}

const sameRoi = (a, b) => !!a && !!b && a.every((v, i) => v === b[i]);

// Solid: the ROI the picture was coded with.  Dashed: the pilot's own (drafted or
// sent), on a picture not coded with it.
function drawRoi(draft = page.roi) {
  for (const [imgId, boxId, draftId] of PICTURES) {
    const img = $(imgId);
    const ready = img.naturalWidth && img.getAttribute("src");
    const coded = ready ? codedRoi(imgId) : null;
    placeBox($(boxId), img, coded);
    placeBox($(draftId), img, ready && draft && !sameRoi(draft, coded) ? draft : null);
  }
}

function setRoi(roi) {
  page.roi = roi;
  page.roiSent = null;
  $("roi-clear").hidden = !roi;
  renderFollowControls();
  renderRoiStatus();
  drawRoi();
}

// Where the pilot's ROI stands: drafted (not sent), sent (order #n), acknowledged
// (from the next picture), in force (a picture coded with it arrived); said once each.
function renderRoiStatus() {
  const roi = page.roi;
  const el = $("roi-text");
  const text = (r) => `${r[0]},${r[1]} – ${r[2]},${r[3]} px`;
  let state = "none";
  if (!roi) {
    el.textContent = "Drag on a picture to choose a region of interest.";
  } else if (sameRoi(roi, codedRoi("image"))) {
    state = "in-force";
    el.textContent = `ROI ${text(roi)}: in force (picture #${lastImageState.serial} on)`;
  } else if (page.roiSent && sameRoi(page.roiSent.roi, roi)) {
    const o = page.orders[page.roiSent.id];
    const outcome = o ? o.outcome : "pending";
    state = outcome === "done" ? "acknowledged" : outcome === "pending" ? "sent" : "failed";
    el.textContent = state === "acknowledged" ? `ROI ${text(roi)}: acknowledged, in force from the next picture`
      : state === "failed" ? `ROI ${text(roi)}: order #${page.roiSent.id} ${o.text}`
        : `ROI ${text(roi)}: sent as order #${page.roiSent.id}, waiting for the ROV`;
  } else {
    state = "drafted";
    el.textContent = `ROI ${text(roi)} drafted: not sent (Apply sends it)`;
  }
  el.dataset.state = state;
}

function wireRoi() {
  for (const [imgId] of PICTURES) {
    const img = $(imgId);
    img.addEventListener("mousedown", (ev) => {
      if (!page.holder || !img.naturalWidth) return;
      ev.preventDefault();
      page.dragImg = img;
      page.drag = picturePoint(ev, img);
    });
  }
  window.addEventListener("mousemove", (ev) => {
    if (page.drag) drawRoi(roiFrom(page.drag, picturePoint(ev)));
  });
  window.addEventListener("mouseup", (ev) => {
    if (!page.drag) return;
    const roi = roiFrom(page.drag, picturePoint(ev));
    page.drag = null;
    page.dragImg = null;
    // A click, not a drag: keep what was chosen before.
    if (roi[2] - roi[0] < 4 || roi[3] - roi[1] < 4) drawRoi();
    else setRoi(roi);
  });
  window.addEventListener("resize", () => drawRoi());
  $("roi-clear").onclick = () => setRoi(null);
}

// ---------------------------------------------------------------------------
// Follow: the ROI follows its object (docs/PROTOCOL.md §10).  The ROV moves it from
// picture to picture; each picture says the ROI it was coded with (drawn solid, from
// its settings) and whether the track holds, was lost (since when) or was dropped.
// ---------------------------------------------------------------------------

// The IMG of the picture a drag starts on: the ROV starts its tracker on that frame.
function wireFollow() {
  for (const [imgId] of PICTURES) {
    $(imgId).addEventListener("mousedown", () => {
      const e = imgId === "image" ? null : shownEntry();
      const img = imgId === "image" ? $("image").dataset.img : e && e.img;
      if (img !== undefined && img !== null && img !== "") page.followDrawnOn = Number(img);
    });
  }
  $("roi-follow").onclick = async () => {
    const roi = page.roi;
    if (!roi || page.followDrawnOn === undefined) return;
    const asked = { roi, img: page.followDrawnOn, keep: $("roi-keep").checked };
    const sent = await api("/api/image/follow", asked);
    if (!sent) return;
    page.follow = { id: sent.id, ...asked };
    setRoi(null);  // the ROV moves it now: the solid box on each picture is where it went
    renderFollowControls();
    renderTrack(lastImageState);
  };
  // The acoustic link's thumbnails come one at a time: the next one names the same ROI on
  // the same thumbnail, and the ROV goes on with its track (docs/PROTOCOL.md §9.3).
  $("follow-again").onclick = async () => {
    const f = page.follow;
    if (!f || !f.roi) return;
    const sent = await api("/api/image/follow", { roi: f.roi, img: f.img, keep: f.keep });
    if (!sent) return;
    page.follow = { ...f, id: sent.id };
    renderTrack(lastImageState);
  };
}

function renderFollowControls() {
  $("roi-follow").hidden = !page.roi || !!page.noFollow;
  $("roi-keep-label").hidden = !page.roi || !!page.noFollow;
  $("follow-again").hidden = !(page.follow && page.follow.roi) || document.body.dataset.profile !== "acoustic";
}

function trackText(track) {
  if (track.state === "holds") return "track holds: the ROI is on the object";
  if (track.state === "lost") {
    return `track LOST for ${fmt(track.lost_for_s, 1)} s: ${track.keep ? "last ROI kept" : "no ROI"}, the ROV still looks`;
  }
  if (track.state === "dropped") return `track DROPPED after ${fmt(track.lost_for_s, 0)} s lost: draw a new ROI`;
  return "track state unknown";
}

function renderTrack(im) {
  const el = $("track-text");
  const follow = page.follow;
  let text = "", state = "";
  if (im && im.track) {
    text = `#${im.serial}: ${trackText(im.track)}`;
    state = im.track.state;
  } else if (follow) {
    const o = page.orders[follow.id];
    if (o && o.outcome !== "pending" && o.outcome !== "done") {
      text = `Follow order #${follow.id} ${o.text}: the ROV does not follow`;
      state = "refused";
    } else {
      text = `Follow sent as order #${follow.id} (${o ? o.text : "sent"}), from the next picture`;
      state = "sent";
    }
  }
  el.hidden = !text;
  el.textContent = text;
  el.dataset.state = state;
}

function setupScene(config) {
  const frame = $("scene");
  if (!config || !config.viser_url) {
    $("no-scene").hidden = false;
    return;
  }
  // A scene on this machine's loopback is reached through the host that
  // served this page when the page is opened from elsewhere (--host).
  const url = new URL(config.viser_url, location.href);
  const loopback = ["127.0.0.1", "localhost", "[::1]", "0.0.0.0"];
  if (loopback.includes(url.hostname) && !loopback.includes(location.hostname)) url.hostname = location.hostname;
  // On this machine, the scene from the other name of loopback than this page's: another
  // site, so Chromium draws it in a process of its own, and this page's thread (its socket
  // and keepalive, its keys, STOP) never waits on the scene's drawing (without a graphics
  // card it takes a core; a page sharing its thread lost its socket, and control).
  else if (loopback.includes(url.hostname)) url.hostname = location.hostname === "localhost" ? "127.0.0.1" : "localhost";
  // viser's page connects to the WebSocket named by ?websocket=; its path
  // carries our scene key (console/scene/app.py reads it).
  const wsScheme = url.protocol === "https:" ? "wss:" : "ws:";
  url.pathname = "/";
  url.search = `?websocket=${wsScheme}//${url.host}/rovlink/${SCENE_KEY}`;
  // Opened with ?scene=off: the 3-D scene is not drawn here (without a graphics card
  // it costs a core of a laptop), only offered, watching, in a tab of its own.
  if (new URLSearchParams(location.search).get("scene") === "off") {
    const box = $("no-scene");
    box.textContent = "The 3-D scene is off on this page (opened with ?scene=off): ";
    const own = new URL(url.href);
    own.search = "";  // without this page's key: it watches
    const link = Object.assign(document.createElement("a"), { href: own.href, target: "_blank",
                                                              textContent: "open it on its own (watch only)" });
    box.append(link);
    box.hidden = false;
    document.body.dataset.scene = "off";
    return;
  }
  frame.src = url.href;
  frame.hidden = false;
}

// ---------------------------------------------------------------------------
// Wiring
// ---------------------------------------------------------------------------

function wire() {
  $("take").onclick = async () => {
    const r = await api("/api/control/take", { name: pageName() });
    if (r) renderControl(r.control);
  };
  $("release").onclick = async () => {
    letGo();
    const r = await api("/api/control/release");
    if (r) renderControl(r);
  };
  $("stop").onclick = stop;
  $("cancel-stop").onclick = () => api("/api/orders/stop/cancel");
  $("arm").onclick = () => api("/api/orders/arm", { armed: true });
  $("disarm").onclick = () => api("/api/orders/arm", { armed: false });
  $("set-mode").onclick = () => { page.modeChosenAt = 0; api("/api/orders/mode", { mode: $("mode-select").value }); };
  $("mode-select").onchange = () => { page.modeChosenAt = Date.now(); };
  $("apply-image").onclick = async () => {
    const roi = page.roi;
    const sent = await api("/api/image/settings", {
      roi, shift: parseInt($("shift").value, 10), mono: $("mono").checked, budget_bytes: parseInt($("budget").value, 10),
    });
    if (sent && roi) { page.roiSent = { id: sent.id, roi }; renderRoiStatus(); }
    if (sent) { page.follow = null; renderFollowControls(); renderTrack(null); }  // an IMAGE order ends the following
  };
  const gotoTarget = () => ({
    x_m: parseFloat($("goto-x").value), y_m: parseFloat($("goto-y").value),
    z_m: parseFloat($("goto-z").value), yaw_deg: parseFloat($("goto-yaw").value),
  });
  // Supervised control: Preview shows the target ghost and the path the
  // vehicle would fly in the 3D view (nothing is sent); Go to sends it.
  document.addEventListener("pointerdown", wakeAudio);
  $("goto-preview").onclick = async () => {
    const target = gotoTarget();
    const plan = await api("/api/orders/position/preview", target);
    if (!plan) return;
    const pts = plan.points;
    const end = pts[pts.length - 1];
    let length = 0;
    for (let i = 1; i < pts.length; i += 1) {
      length += Math.hypot(pts[i][0] - pts[i - 1][0], pts[i][1] - pts[i - 1][1], pts[i][2] - pts[i - 1][2]);
    }
    const miss = Math.hypot(end[0] - target.x_m, end[1] - target.y_m, end[2] - target.z_m);
    const box = $("goto-plan");
    box.textContent = `preview: ${length.toFixed(1)} m in about ${((pts.length - 1) * 0.5).toFixed(0)} s, ` +
      `ends ${miss.toFixed(2)} m from the target; not sent. Go to switches the vehicle to GUIDED.`;
    box.dataset.target = "";
    box.dataset.points = pts.length;
    box.dataset.previewed = "1";
    box.hidden = false;
  };
  for (const id of ["goto-x", "goto-y", "goto-z", "goto-yaw"]) {
    $(id).addEventListener("input", () => { $("goto-plan").dataset.previewed = ""; });
  }
  $("goto").onsubmit = async (ev) => {
    ev.preventDefault();
    const sent = await api("/api/orders/position", gotoTarget());
    if (sent) {
      $("goto-plan").textContent = `position order #${sent.id} sent: the vehicle switches to ${sent.mode || "GUIDED"}`;
      $("goto-plan").hidden = false;
    }
  };
  $("goto-here").onclick = () => {
    const p = page.lastPose;
    if (!p) return;
    $("goto-x").value = p.x_m.toFixed(2); $("goto-y").value = p.y_m.toFixed(2);
    $("goto-z").value = p.z_m.toFixed(2); $("goto-yaw").value = p.yaw_deg.toFixed(0);
  };
  wireRoi();
  wireFollow();
  $("next-image").onclick = async () => {
    const el = $("next-image-fate");
    el.textContent = "skipping…";
    el.className = "fate pending";
    el.dataset.state = "asked";
    if ((await api("/api/image/next")) === null && el.dataset.state === "asked") {
      el.textContent = "not skipped (see the message)";
      el.className = "fate bad";
      el.dataset.state = "refused";
    }
  };
  $("image-save").onclick = savePicture;
  $("image-latest").onclick = () => { page.shownPast = null; renderStrip(); renderShownPicture(); };
  $("log-level").onchange = renderLog;
  // A replay jumped (replay.js): what this page kept of the past is read again.
  window.addEventListener("rovlink:replay-jump", () => {
    page.logEntries = [];
    page.logKeys.clear();
    fetch("/api/log").then((r) => r.json()).then((entries) => { renderLog(); addLog(entries); }).catch(() => {});
    page.shownPast = null;
    page.historyKey = "";
    loadHistory();
  });
  $("log-filter").oninput = renderLog;
  fetch("/api/log").then((r) => r.json()).then(addLog).catch(() => {});
  // The clock, and ages that grow while nothing new arrives.
  const tick = () => {
    const replaying = page.lastState && page.lastState.replaying;
    $("clock").textContent = (replaying ? "replay " : "") + clockTime(nowWall());
    renderShownMeta();
    const im = page.lastState && page.lastState.image;
    if (im && im.capture) $("image-id").textContent = `#${im.serial} (IMG ${im.img})${im.complete ? " complete" : ""}, captured ${captureText(im.capture)}`;
  };
  tick();
  setInterval(tick, 1000);
  $("gain").oninput = () => { $("gain-value").textContent = `${Math.round($("gain").value * 100)} %`; };

  // A clicked button keeps no focus: Space is STOP, never "press the last button".
  document.addEventListener("click", (ev) => { if (ev.target.tagName === "BUTTON") ev.target.blur(); });
  window.addEventListener("keydown", onKeyDown);
  window.addEventListener("keyup", onKeyUp);
  window.addEventListener("blur", letGo);
  document.addEventListener("visibilitychange", () => { if (document.hidden) letGo(); });
  if (window.rovGamepad) {
    window.rovGamepad.onChange((text) => {
      $("gamepad").textContent = text;
      if (!window.rovGamepad.connected()) letGo();
    });
  }
  setInterval(() => {
    pollGamepadButtons();
    sendVelocity();
    // Ticks so far: what the page's input loop has had the chance to do (the tests wait on it).
    document.body.dataset.ticks = String((+document.body.dataset.ticks || 0) + 1);
  }, TICK_MS);
  setHolder(false);
  // The one mode list, key map and limits come from the console, then telemetry.
  fetch("/api/config").then((r) => r.json()).then((config) => {
    if (!page.config) { setupControls(config); setupScene(config); page.config = config; }
  }).catch(() => {}).finally(connect);
}

wire();
