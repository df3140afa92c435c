// rovlink operator page: the gamepad.  console.js asks this module, every
// TICK_MS, for the sticks' wish and for a STOP press; it owns nothing else of
// the gamepad.  Interface (window.rovGamepad):
//   wish()        -> {vx, vy, vz, vyaw} fractions -1..1 after mapping, deadzone, expo and gain,
//                    or null without a pad (and while the settings wait for a button press)
//   stopPressed() -> true once per press of a STOP button
//   connected()   -> the Gamepad object or null
//   onChange(fn)  -> fn(text) when a pad connects or goes, or its gain step changes
//                    (for the page's status line)
//
// The pilot's settings live in <details id="gamepad-settings"> (rendered here)
// and in localStorage under STORE_KEY; a stored value that is not valid is
// ignored, field by field, and the default used instead.
//
// Shaping, per vehicle axis: the chosen stick axis, or a pair of buttons read
// as one axis (the triggers RT - LT, or the bumpers RB - LB: each button's
// analog value 0..1, the first one positive), inverted if asked ->
// deadzone: |x| <= deadzone gives exactly 0, past it the rest of the travel is
// rescaled to 0..1, so the output starts from 0 at the edge, never jumps ->
// expo: out = (1 - e) * r + e * r^3 (same sign as the stick) -> times the
// current gain step -> clamped to -1..1.
//
// Safety decisions:
// - A pad that disconnects, or that getGamepads() stops listing, gives null:
//   console.js then sends neutral once (the dead man lets go).
// - STOP is edge-detected per button: a STOP button fires once per press; a
//   button that becomes a STOP button while it is held does not fire until
//   it is pressed again.
// - While a button capture waits ("press the pad button for STOP / gain"),
//   wish() is null (the pad drives nothing, console.js sends neutral) and the
//   current STOP buttons stay active: pressing one fires STOP as always.  A
//   STOP button is never taken as a gain button (refused, said on the page);
//   a button captured for STOP stops being a gain button.  The gain buttons
//   do nothing while a capture waits.  A capture ends after CAPTURE_MS, on
//   Cancel or Escape, or when the pad goes.
// - At least one pad button is always STOP (the page's STOP button and Space
//   stay STOP whatever the pad does).
// - The current gain step is saved with the settings and restored on load.
// - The pad that connected last is the one that drives (a second pad that
//   connects takes over, at its own stick positions).
// - A page reads the stored settings when it loads; two pages open at once
//   each keep their own until reloaded (the last one changed is saved).
"use strict";

(() => {
  const STORE_KEY = "rovlink.gamepad.v1";
  const MAX_AXES = 8;
  const MAX_BUTTONS = 20;
  const CAPTURE_MS = 10000;
  const POLL_MS = 50;        // gain buttons and capture (STOP is polled by console.js)
  const LIVE_MS = 100;       // live state, only while the settings are open
  // Names in the Gamepad API's "standard" mapping (Xbox-style labels).
  const AXIS_NAMES = ["left stick X", "left stick Y", "right stick X", "right stick Y"];
  const BUTTON_NAMES = ["A", "B", "X", "Y", "LB", "RB", "LT", "RT", "Back", "Start", "L3", "R3",
                        "D-pad up", "D-pad down", "D-pad left", "D-pad right", "Home"];
  // Button pairs that may drive a vehicle axis: [plus, minus, name].
  const PAIRS = [[7, 6, "RT \u2212 LT"], [5, 4, "RB \u2212 LB"]];
  const VEHICLE = [["vx", "surge", "forward +"], ["vy", "sway", "right +"],
                   ["vz", "heave", "down +"], ["vyaw", "yaw", "clockwise +"]];
  const DEFAULTS = Object.freeze({
    // Left stick: forward (its Y is negative pushed away) is surge, right is sway;
    // right stick: X is yaw, Y (pulled back, positive) is heave down.
    axes: { vx: { axis: 1, invert: true }, vy: { axis: 0, invert: false },
            vz: { axis: 3, invert: false }, vyaw: { axis: 2, invert: false } },
    deadzone: 0.12,
    expo: 0,
    gainSteps: [25, 50, 75, 100],   // per cent
    gainStep: 3,                    // index in gainSteps
    gainUp: 12,                     // D-pad up; -1: none
    gainDown: 13,                   // D-pad down
    stopButtons: [1],               // B
  });

  // -------------------------------------------------------------------------
  // Settings: validated field by field
  // -------------------------------------------------------------------------

  const isInt = (v, lo, hi) => Number.isInteger(v) && v >= lo && v <= hi;
  const isNum = (v, lo, hi) => typeof v === "number" && Number.isFinite(v) && v >= lo && v <= hi;
  const copy = (o) => JSON.parse(JSON.stringify(o));

  function validSteps(v) {
    if (!Array.isArray(v) || v.length < 1 || v.length > 8 || !v.every((s) => isNum(s, 1, 100))) return null;
    const steps = [...new Set(v.map((s) => Math.round(s)))].sort((a, b) => a - b);
    return steps;
  }

  function sanitize(raw) {
    const d = copy(DEFAULTS);
    const s = copy(DEFAULTS);
    if (!raw || typeof raw !== "object") return s;
    for (const [k] of VEHICLE) {
      const m = raw.axes && raw.axes[k];
      if (m && typeof m === "object") {
        if (isInt(m.axis, -1, MAX_AXES - 1)) s.axes[k].axis = m.axis;
        if (typeof m.invert === "boolean") s.axes[k].invert = m.invert;
        if (Array.isArray(m.buttons) && PAIRS.some(([p, n]) => m.buttons[0] === p && m.buttons[1] === n)) {
          s.axes[k].buttons = [m.buttons[0], m.buttons[1]];
        }
      }
    }
    if (isNum(raw.deadzone, 0, 0.5)) s.deadzone = raw.deadzone;
    if (isNum(raw.expo, 0, 1)) s.expo = raw.expo;
    const steps = validSteps(raw.gainSteps);
    if (steps) s.gainSteps = steps;
    s.gainStep = isInt(raw.gainStep, 0, s.gainSteps.length - 1) ? raw.gainStep : s.gainSteps.length - 1;
    if (Array.isArray(raw.stopButtons) && raw.stopButtons.length > 0
        && raw.stopButtons.every((b) => isInt(b, 0, MAX_BUTTONS - 1))) {
      s.stopButtons = [...new Set(raw.stopButtons)].sort((a, b) => a - b);
    }
    for (const k of ["gainUp", "gainDown"]) {
      if (isInt(raw[k], -1, MAX_BUTTONS - 1)) s[k] = raw[k];
      if (s.stopButtons.includes(s[k])) s[k] = s.stopButtons.includes(d[k]) ? -1 : d[k];
    }
    if (s.gainUp >= 0 && s.gainUp === s.gainDown) s.gainDown = -1;
    return s;
  }

  function load() {
    try {
      const text = window.localStorage.getItem(STORE_KEY);
      return sanitize(text ? JSON.parse(text) : null);
    } catch (err) {
      return sanitize(null);
    }
  }

  function save() {
    try { window.localStorage.setItem(STORE_KEY, JSON.stringify(settings)); } catch (err) { /* private mode */ }
  }

  let settings = load();

  // -------------------------------------------------------------------------
  // The pad
  // -------------------------------------------------------------------------

  let index = null;
  let stopPrev = [];          // each button's pressed state at the last stopPressed()
  let pollPrev = [];          // ... at the last poll() (gain buttons, capture)
  let capture = null;         // { what: "stop" | "gainUp" | "gainDown", until: ms }
  const listeners = [];

  function connected() {
    if (index === null || !navigator.getGamepads) return null;
    const pad = navigator.getGamepads()[index];
    return pad && pad.connected ? pad : null;
  }

  const pressedList = (pad) => Array.from(pad.buttons || [], (b) => !!(b && (b.pressed || b.value > 0.5)));
  const clamp1 = (v) => Math.max(-1, Math.min(1, v));

  // Deadzone rescaled, then expo; exactly 0 inside the deadzone.
  function shape(x, deadzone, expo) {
    if (typeof x !== "number" || !Number.isFinite(x)) return 0;
    const a = Math.min(1, Math.abs(x));
    if (a <= deadzone) return 0;
    const r = (a - deadzone) / (1 - deadzone);
    return Math.sign(x) * Math.min(1, (1 - expo) * r + expo * r * r * r);
  }

  function gain() { return settings.gainSteps[settings.gainStep] / 100; }

  // A button's travel 0..1 (a digital one: 0 or 1).
  function buttonValue(pad, b) {
    const button = pad.buttons && pad.buttons[b];
    if (!button) return 0;
    if (typeof button.value === "number" && button.value > 0) return Math.min(1, button.value);
    return button.pressed ? 1 : 0;
  }

  function rawOf(pad, m) {
    if (m.buttons) return buttonValue(pad, m.buttons[0]) - buttonValue(pad, m.buttons[1]);
    return m.axis >= 0 && pad.axes ? pad.axes[m.axis] || 0 : 0;
  }

  function wishOf(pad) {
    const out = {};
    for (const [k] of VEHICLE) {
      const m = settings.axes[k];
      const raw = rawOf(pad, m);
      const v = shape(m.invert ? -raw : raw, settings.deadzone, settings.expo) * gain();
      out[k] = clamp1(v) || 0;   // no -0
    }
    return out;
  }

  function wish() {
    if (capture) return null;
    const pad = connected();
    return pad ? wishOf(pad) : null;
  }

  function stopPressed() {
    const pad = connected();
    const now = pad ? pressedList(pad) : [];
    const edge = settings.stopButtons.some((b) => now[b] && !stopPrev[b]);
    stopPrev = now;
    return edge;
  }

  function statusText(pad = connected()) {
    if (!pad) return "No gamepad.";
    const g = settings.gainSteps[settings.gainStep];
    return `Gamepad: ${pad.id}.` + (g === 100 ? "" : ` Gain ${g} %.`);
  }

  function tell(text) { for (const fn of listeners) fn(text); }

  function stepGain(by) {
    const next = Math.max(0, Math.min(settings.gainSteps.length - 1, settings.gainStep + by));
    if (next === settings.gainStep) return;
    settings.gainStep = next;
    save();
    renderGain();
    tell(statusText());
  }

  // Gain buttons and capture, by edge (a button held before counts only when pressed again).
  function poll() {
    const pad = connected();
    const now = pad ? pressedList(pad) : [];
    const edges = now.map((down, b) => down && !pollPrev[b]);
    pollPrev = now;
    if (capture) {
      if (!pad) { endCapture("The gamepad went: nothing changed."); return; }
      if (Date.now() > capture.until) { endCapture("No button pressed: nothing changed."); return; }
      const b = edges.indexOf(true);
      if (b >= 0) assign(capture.what, b);
      return;
    }
    if (!pad) return;
    if (settings.gainUp >= 0 && edges[settings.gainUp]) stepGain(+1);
    if (settings.gainDown >= 0 && edges[settings.gainDown]) stepGain(-1);
  }

  window.addEventListener("gamepadconnected", (ev) => {
    index = ev.gamepad.index;
    stopPrev = [];
    pollPrev = [];
    tell(statusText(ev.gamepad));
    renderLive();
  });
  window.addEventListener("gamepaddisconnected", (ev) => {
    if (ev.gamepad.index === index) {
      index = null;
      stopPrev = [];
      pollPrev = [];
      if (capture) endCapture("The gamepad went: nothing changed.");
      tell("No gamepad.");
      renderLive();
    }
  });

  // -------------------------------------------------------------------------
  // Settings UI, inside <details id="gamepad-settings">
  // -------------------------------------------------------------------------

  const box = document.getElementById("gamepad-settings");
  const ui = {};
  const buttonName = (b) => (b < 0 ? "none" : `${b}${BUTTON_NAMES[b] ? ` (${BUTTON_NAMES[b]})` : ""}`);
  const axisName = (a) => (a < 0 ? "none" : `axis ${a}${AXIS_NAMES[a] ? ` (${AXIS_NAMES[a]})` : ""}`);
  const el = (tag, props = {}, ...children) => {
    const e = Object.assign(document.createElement(tag), props);
    e.append(...children);
    return e;
  };
  const fix2 = (v) => (Math.round(v * 100) / 100).toFixed(2);

  const STYLE = `
#gamepad-settings { margin: 6px 0; }
#gamepad-settings .gp-grid { display: grid; grid-template-columns: auto minmax(0, 1fr) auto; gap: 3px 8px; align-items: center; }
#gamepad-settings fieldset { border: 1px solid #2b4357; border-radius: 4px; margin: 6px 0; padding: 4px 8px; }
#gamepad-settings legend { color: var(--dim, #8aa2b4); font-size: 12px; }
#gamepad-settings .gp-buttons { display: flex; flex-wrap: wrap; gap: 2px 8px; font-size: 12px; }
#gamepad-settings .gp-msg { min-height: 1.2em; color: #f1c40f; font-size: 12px; }
#gamepad-settings .gp-bar { position: relative; display: inline-block; width: 90px; height: 8px;
  background: #2b4357; border-radius: 2px; vertical-align: middle; }
#gamepad-settings .gp-bar::before { content: ""; position: absolute; left: 50%; top: 0; bottom: 0; width: 1px; background: #8aa2b4; }
#gamepad-settings .gp-fill { position: absolute; top: 1px; bottom: 1px; background: #2f80c0; }
#gamepad-settings .gp-out .gp-fill { background: #2e8b57; }
#gamepad-settings .gp-live td { font-variant-numeric: tabular-nums; font-size: 12px; padding: 0 6px 0 0; }
#gamepad-settings input[type=number] { width: 64px; }
#gamepad-settings select { max-width: 100%; }
#gamepad-settings svg { background: #0d1b24; border: 1px solid #2b4357; }
#gamepad-settings button.gp-waiting { background: #d68910; }
`;

  function bar(value) {
    const fill = el("span", { className: "gp-fill" });
    const v = clamp1(Number.isFinite(value) ? value : 0);
    fill.style.left = `${50 + Math.min(0, v) * 50}%`;
    fill.style.width = `${Math.abs(v) * 50}%`;
    return fill;
  }

  function select(options, value, onchange, label) {
    const s = el("select", { ariaLabel: label });
    for (const [v, text] of options) s.append(el("option", { value: String(v), textContent: text }));
    s.value = String(value);
    s.onchange = () => onchange(typeof value === "number" ? parseInt(s.value, 10) : s.value);
    return s;
  }

  function numberInput(id, min, max, step, value, onchange) {
    const input = el("input", { id, type: "number", min, max, step, value: String(value) });
    input.onchange = () => {
      const v = parseFloat(input.value);
      if (!Number.isFinite(v)) { input.value = String(onchange(null)); return; }
      input.value = String(onchange(Math.max(min, Math.min(max, v))));
    };
    return input;
  }

  function changed() {
    save();
    renderMappingNote();
    renderCurve();
    renderGain();
    renderLive();
  }

  function message(text) { if (ui.msg) ui.msg.textContent = text; }

  function buildUI() {
    if (!box) return;
    if (!document.getElementById("gamepad-style")) {
      document.head.append(el("style", { id: "gamepad-style", textContent: STYLE }));
    }
    const summary = box.querySelector("summary") || el("summary", { textContent: "Gamepad settings" });
    ui.summaryGain = el("span", { id: "gp-summary-gain", className: "dim" });
    summary.replaceChildren("Gamepad settings ", ui.summaryGain);

    // Mapping: which stick axis (or button pair) drives each vehicle axis, inverted or not.
    const axisOptions = [[-1, "none"], ...Array.from({ length: MAX_AXES }, (_, a) => [a, axisName(a)]),
                         ...PAIRS.map(([p, n, label]) => [`b${p}-${n}`, `buttons ${label}`])];
    const mapping = el("div", { className: "gp-grid" });
    for (const [k, name, sense] of VEHICLE) {
      const m = settings.axes[k];
      const inv = el("input", { type: "checkbox", id: `gp-invert-${k}`, checked: m.invert });
      inv.onchange = () => { settings.axes[k].invert = inv.checked; changed(); };
      const current = m.buttons ? `b${m.buttons[0]}-${m.buttons[1]}` : m.axis;
      const which = select(axisOptions, String(current), (v) => {
        const pair = /^b(\d+)-(\d+)$/.exec(v);
        if (pair) {
          settings.axes[k].buttons = [parseInt(pair[1], 10), parseInt(pair[2], 10)];
        } else {
          delete settings.axes[k].buttons;
          settings.axes[k].axis = parseInt(v, 10);
        }
        changed();
      }, `${name} axis`);
      which.id = `gp-axis-${k}`;
      mapping.append(el("span", { textContent: `${name} (${sense})` }), which, el("label", {}, inv, " invert"));
    }

    // Deadzone and expo, with the response curve they give.
    const dz = numberInput("gp-deadzone", 0, 0.5, 0.01, settings.deadzone, (v) => {
      if (v !== null) { settings.deadzone = v; changed(); }
      return settings.deadzone;
    });
    const expo = numberInput("gp-expo", 0, 1, 0.05, settings.expo, (v) => {
      if (v !== null) { settings.expo = v; changed(); }
      return settings.expo;
    });
    ui.curve = document.createElementNS("http://www.w3.org/2000/svg", "svg");
    ui.curve.setAttribute("width", "80");
    ui.curve.setAttribute("height", "80");
    ui.curve.setAttribute("viewBox", "-1.05 -1.05 2.1 2.1");
    ui.curve.id = "gp-curve";
    ui.mappingNote = el("div", { className: "gp-msg", id: "gp-mapping-note" });
    const shaping = el("div", { className: "row" },
                       el("label", {}, "deadzone ", dz), el("label", {}, "expo ", expo), ui.curve);

    // Gain steps and the two buttons that step through them.
    const steps = el("input", { id: "gp-gain-steps", type: "text", size: 14, value: settings.gainSteps.join(", "),
                                title: "per cent, 1..100, up to 8 steps" });
    steps.onchange = () => {
      const parsed = validSteps(steps.value.split(/[\s,;%]+/).filter(Boolean).map(Number));
      if (!parsed) {
        message("Gain steps: up to 8 numbers from 1 to 100 (per cent).");
      } else {
        const was = gain() * 100;
        settings.gainSteps = parsed;
        // Keep the step nearest to the gain in use (the lower one on a tie).
        let best = 0;
        parsed.forEach((g, i) => { if (Math.abs(g - was) < Math.abs(parsed[best] - was)) best = i; });
        settings.gainStep = best;
        message("");
        changed();
      }
      steps.value = settings.gainSteps.join(", ");
    };
    const buttonOptions = [[-1, "none"], ...Array.from({ length: MAX_BUTTONS }, (_, b) => [b, buttonName(b)])];
    const gainButton = (k, label) => {
      const s = select(buttonOptions, settings[k], (b) => { if (!assign(k, b)) s.value = String(settings[k]); }, label);
      s.id = `gp-${k === "gainUp" ? "gain-up" : "gain-down"}`;
      ui[k] = s;
      return s;
    };
    ui.gainText = el("strong", { id: "gp-gain" });
    const gainBox = el("fieldset", {}, el("legend", { textContent: "gain" }),
      el("div", { className: "row" }, el("label", {}, "steps % ", steps), el("span", {}, "now ", ui.gainText)),
      el("div", { className: "row" },
         el("label", {}, "down ", gainButton("gainDown", "gain down button")), captureButton("gainDown"),
         el("label", {}, "up ", gainButton("gainUp", "gain up button")), captureButton("gainUp")));

    // STOP buttons: ticked, or "press it on the pad".
    ui.stopChecks = el("div", { className: "gp-buttons", id: "gp-stop-buttons" });
    for (let b = 0; b < MAX_BUTTONS; b += 1) {
      const c = el("input", { type: "checkbox", value: String(b), checked: settings.stopButtons.includes(b) });
      c.dataset.button = String(b);
      c.onchange = () => {
        if (c.checked) assign("stopAdd", b);
        else if (settings.stopButtons.length === 1) {
          c.checked = true;
          message("One pad button at least stays STOP.");
        } else {
          settings.stopButtons = settings.stopButtons.filter((x) => x !== b);
          message("");
          changed();
        }
        renderStop();
      };
      ui.stopChecks.append(el("label", {}, c, ` ${buttonName(b)}`));
    }
    ui.stopText = el("strong", { id: "gp-stop" });
    const stopBox = el("fieldset", {}, el("legend", { textContent: "STOP" }),
      el("div", { className: "row" }, el("span", {}, "STOP on ", ui.stopText), captureButton("stop")),
      ui.stopChecks);

    ui.msg = el("div", { className: "gp-msg", id: "gp-msg", role: "status" });
    const reset = el("button", { type: "button", id: "gp-reset", textContent: "Reset to defaults" });
    reset.onclick = () => {
      if (capture) endCapture("");
      settings = sanitize(null);
      save();
      buildUI();
      message("Defaults restored.");
    };

    // Live state: the pad, its raw axes and buttons, what each vehicle axis gets.
    ui.liveId = el("div", { id: "gp-live-id", className: "dim" });
    ui.liveAxes = el("table", { className: "gp-live", id: "gp-live-axes" });
    ui.liveOut = el("table", { className: "gp-live gp-out", id: "gp-live-out" });
    ui.liveButtons = el("div", { id: "gp-live-buttons", className: "dim" });
    const live = el("fieldset", {}, el("legend", { textContent: "live" }), ui.liveId,
                    el("div", { className: "row" }, ui.liveAxes, ui.liveOut), ui.liveButtons);

    box.replaceChildren(summary,
      el("fieldset", {}, el("legend", { textContent: "sticks" }), mapping, ui.mappingNote, shaping),
      gainBox, stopBox, ui.msg, reset, live);
    renderStop();
    renderMappingNote();
    renderCurve();
    renderGain();
    renderLive();
  }

  function captureButton(what) {
    const b = el("button", { type: "button", className: "gp-capture", textContent: "press on pad…" });
    b.dataset.capture = what;
    b.id = `gp-capture-${what}`;
    b.onclick = () => {
      if (capture && capture.what === what) { endCapture("Cancelled: nothing changed."); return; }
      if (!connected()) { message("Connect a gamepad first (press one of its buttons)."); return; }
      startCapture(what);
    };
    return b;
  }

  const captureWords = { stop: "STOP", gainUp: "gain up", gainDown: "gain down" };

  function startCapture(what) {
    const pad = connected();
    capture = { what, until: Date.now() + CAPTURE_MS };
    pollPrev = pad ? pressedList(pad) : [];   // a button already held does not count
    document.body.dataset.gamepadCapture = what;
    for (const b of box.querySelectorAll("button.gp-capture")) {
      const waiting = b.dataset.capture === what;
      b.classList.toggle("gp-waiting", waiting);
      b.textContent = waiting ? "cancel" : "press on pad…";
    }
    message(`Press the pad button for ${captureWords[what]} (the sticks drive nothing meanwhile; ` +
            `the STOP buttons still stop). Escape cancels.`);
    tell(`Gamepad: waiting for the ${captureWords[what]} button; the sticks drive nothing.`);
  }

  function endCapture(text) {
    if (!capture) return;
    capture = null;
    tell(statusText());
    delete document.body.dataset.gamepadCapture;
    if (box) {
      for (const b of box.querySelectorAll("button.gp-capture")) {
        b.classList.remove("gp-waiting");
        b.textContent = "press on pad…";
      }
    }
    message(text);
  }

  // Give button b a role ("stop": the only STOP button; "stopAdd": one more
  // STOP button; "gainUp"/"gainDown").  False if refused.
  function assign(what, b) {
    if (what === "stop" || what === "stopAdd") {
      // A button that becomes STOP while held (the press that chose it) fires
      // only at its next press; one that was STOP already keeps its edge.
      const pad = connected();
      if (pad && !settings.stopButtons.includes(b) && pressedList(pad)[b]) stopPrev[b] = true;
      settings.stopButtons = what === "stop" ? [b] : [...new Set([...settings.stopButtons, b])].sort((x, y) => x - y);
      let note = "";
      for (const k of ["gainUp", "gainDown"]) {
        if (settings[k] === b) { settings[k] = -1; note = ` It is no longer ${captureWords[k]}.`; }
      }
      if (capture) endCapture(`STOP: ${settings.stopButtons.map(buttonName).join(", ")}.${note}`);
      else message(note.trim());
      renderStop();
      changed();
      return true;
    }
    if (b >= 0 && settings.stopButtons.includes(b)) {
      const text = `Button ${buttonName(b)} is a STOP button: not taken for ${captureWords[what]}.`;
      if (capture) endCapture(text); else message(text);
      return false;
    }
    settings[what] = b;
    const other = what === "gainUp" ? "gainDown" : "gainUp";
    let note = "";
    if (b >= 0 && settings[other] === b) { settings[other] = -1; note = ` It is no longer ${captureWords[other]}.`; }
    if (capture) endCapture(`${captureWords[what]}: ${buttonName(b)}.${note}`);
    else message(note.trim());
    changed();
    return true;
  }

  // Two vehicle axes on one stick axis (or button pair) is allowed, but said;
  // so is a button that drives an axis and is also STOP or a gain button.
  function renderMappingNote() {
    if (!ui.mappingNote) return;
    const by = {};
    const notes = [];
    for (const [k, name] of VEHICLE) {
      const m = settings.axes[k];
      const key = m.buttons ? `buttons ${m.buttons.map(buttonName).join(" and ")}` : m.axis >= 0 ? `axis ${m.axis}` : null;
      if (key) (by[key] = by[key] || []).push(name);
      for (const b of m.buttons || []) {
        const also = [settings.stopButtons.includes(b) && "STOP", settings.gainUp === b && "gain up",
                      settings.gainDown === b && "gain down"].filter(Boolean);
        if (also.length) notes.push(`${buttonName(b)} drives ${name} and is also ${also.join(" and ")}.`);
      }
    }
    const shared = Object.entries(by).filter(([, names]) => names.length > 1);
    ui.mappingNote.textContent = [...shared.map(([key, names]) => `${key} drive${key.startsWith("axis") ? "s" : ""} ${names.join(" and ")}.`),
                                  ...notes].join(" ");
  }

  function renderStop() {
    if (!ui.stopText) return;
    ui.stopText.textContent = settings.stopButtons.map(buttonName).join(", ");
    for (const c of ui.stopChecks.querySelectorAll("input")) c.checked = settings.stopButtons.includes(+c.value);
  }

  function renderGain() {
    if (!ui.gainText) return;
    const g = settings.gainSteps[settings.gainStep];
    ui.gainText.textContent = `${g} %`;
    ui.gainText.dataset.value = String(g);
    ui.summaryGain.textContent = `(gain ${g} %)`;
    for (const k of ["gainUp", "gainDown"]) ui[k].value = String(settings[k]);
    document.body.dataset.gamepadGain = String(g);
  }

  function renderCurve() {
    if (!ui.curve) return;
    const pts = [];
    for (let i = -50; i <= 50; i += 1) {
      const x = i / 50;
      pts.push(`${x.toFixed(2)},${(-shape(x, settings.deadzone, settings.expo) * gain()).toFixed(3)}`);
    }
    const ns = "http://www.w3.org/2000/svg";
    const axes = document.createElementNS(ns, "path");
    axes.setAttribute("d", "M-1 0H1M0 -1V1");
    axes.setAttribute("stroke", "#2b4357");
    axes.setAttribute("stroke-width", "0.03");
    const line = document.createElementNS(ns, "polyline");
    line.setAttribute("points", pts.join(" "));
    line.setAttribute("fill", "none");
    line.setAttribute("stroke", "#2e8b57");
    line.setAttribute("stroke-width", "0.05");
    ui.curve.replaceChildren(axes, line);
  }

  function liveRow(label, value, id) {
    const cell = el("span", { className: "gp-bar" }, bar(value));
    const num = el("td", { textContent: Number.isFinite(value) ? fix2(value) : "—" });
    num.dataset.value = String(value);
    const tr = el("tr", {}, el("td", { textContent: label }), el("td", {}, cell), num);
    if (id) tr.id = id;
    return tr;
  }

  // Cheap when closed: nothing is drawn unless the pilot opened the settings.
  function renderLive() {
    if (!box || !box.open || !ui.liveId) return;
    const pad = connected();
    if (!pad) {
      ui.liveId.textContent = "No gamepad: press one of its buttons to wake it.";
      ui.liveAxes.replaceChildren();
      ui.liveOut.replaceChildren();
      ui.liveButtons.textContent = "";
      ui.liveButtons.dataset.pressed = "";
      return;
    }
    ui.liveId.textContent = `${pad.id} (${pad.mapping === "standard" ? "standard mapping" : "mapping not standard: check the axes"})`;
    ui.liveAxes.replaceChildren(...Array.from(pad.axes || [], (v, a) => liveRow(`axis ${a}`, v, `gp-raw-${a}`)));
    const w = wish();
    ui.liveOut.replaceChildren(...VEHICLE.map(([k, name]) => liveRow(name, w ? w[k] : 0, `gp-out-${k}`)));
    const down = pressedList(pad).map((p, b) => (p ? b : -1)).filter((b) => b >= 0);
    const g = settings.gainSteps[settings.gainStep];
    ui.liveButtons.textContent = `buttons pressed: ${down.length ? down.map(buttonName).join(", ") : "none"}` +
      ` · gain ${g} %${capture ? ` · waiting for the ${captureWords[capture.what]} button` : ""}`;
    ui.liveButtons.dataset.pressed = down.join(",");
  }

  let liveTimer = null;
  if (box) {
    buildUI();
    box.addEventListener("toggle", () => {
      // Closing the settings ends a capture: the sticks never stay dead unseen.
      if (!box.open && capture) endCapture("Closed: nothing changed.");
      clearInterval(liveTimer);
      liveTimer = box.open ? setInterval(renderLive, LIVE_MS) : null;
      renderLive();
    });
  }
  window.addEventListener("keydown", (ev) => {
    if (capture && ev.key === "Escape") endCapture("Cancelled: nothing changed.");
  });
  setInterval(poll, POLL_MS);

  window.rovGamepad = { wish, stopPressed, connected, onChange: (fn) => listeners.push(fn) };
})();
