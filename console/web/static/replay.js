// rovlink operator page: the replay timeline (a console started by `rovlink replay`).
//
// Renders into <div id="replay-bar" hidden>: play/pause, a slider over the
// recording (dragging seeks when released, as do the arrow keys), the time
// shown and the length, and the playback speed.  It asks GET /api/replay once
// at load: a live console has no timeline and the bar stays hidden.  While
// replaying it reads the state every POLL_MS and, between reads, moves the time
// on by itself (t + elapsed x speed), so the clock runs smoothly.  Commands are
// POST /api/replay/pause, /resume, /seek {t}, /speed {speed}; they need no
// control (nothing of a replay reaches a vehicle).
//
// For tests and scripts the bar carries data-state ("playing" | "paused" |
// "ended") and data-t (the session time shown, seconds).
//
// A jump (a seek or a restart, from this page or any other client) rewrites the
// session's past: the page is told by a "rovlink:replay-jump" event on window
// (detail: the replay state), so that what it keeps of the past (the log lines
// it has seen) can be read again.
"use strict";

(() => {
  const POLL_MS = 500;
  const DRAW_MS = 100;
  const $ = (id) => document.getElementById(id);
  const bar = $("replay-bar");
  if (!bar) return;

  const replay = {
    state: null,        // the last GET /api/replay
    at: 0,              // performance.now() when it was read
    dragging: false,    // the slider is held: polls must not move it
    busy: false,        // a command is on its way
    commands: 0,        // commands sent: a read started before the last one is stale
    seeks: null,        // the server's seek count last seen
    pollFailed: false,  // the last read failed (its message is shown)
  };

  const CSS = `
#replay-bar { background: var(--card, #15293a); border: 2px solid var(--warn, #d68910); border-radius: 6px;
              padding: 6px 8px; display: flex; flex-wrap: wrap; gap: 6px; align-items: center; }
#replay-bar[hidden] { display: none; }
#replay-bar .replay-title { font-weight: 700; color: var(--warn, #d68910); letter-spacing: .05em; }
#replay-bar #replay-play { min-width: 64px; }
#replay-bar #replay-slider { flex: 1 1 100%; order: 10; margin: 0; accent-color: var(--warn, #d68910); }
#replay-bar #replay-time { flex: 1; font-variant-numeric: tabular-nums; }
#replay-bar #replay-error { flex: 1 1 100%; order: 11; color: #f5b7b1; font-size: 12px; }
#replay-bar #replay-error:empty { display: none; }`;

  function clock(t) {
    if (t === null || t === undefined || !Number.isFinite(t)) return "–";
    const m = Math.floor(t / 60);
    const s = t - 60 * m;
    return `${m}:${s.toFixed(1).padStart(4, "0")}`;
  }

  function build(state) {
    const style = document.createElement("style");
    style.textContent = CSS;
    document.head.appendChild(style);
    bar.setAttribute("role", "group");
    bar.setAttribute("aria-label", "replay timeline");
    bar.innerHTML = `
      <span class="replay-title">REPLAY</span>
      <button id="replay-play" type="button"></button>
      <span id="replay-time"></span>
      <label class="dim">speed <select id="replay-speed" aria-label="playback speed"></select></label>
      <input id="replay-slider" type="range" min="0" step="0.1" aria-label="session time">
      <div id="replay-error" role="status"></div>`;
    bar.querySelector(".replay-title").title = `a recorded session: ${state.file ?? ""}`;
    const speed = $("replay-speed");
    const speeds = [...new Set([...(state.speeds || []), state.speed])].sort((a, b) => a - b);
    for (const s of speeds) speed.add(new Option(`${s}x`, String(s)));
    const slider = $("replay-slider");
    slider.max = String(state.duration);

    $("replay-play").addEventListener("click", () => {
      const s = shownState();
      command(s === "playing" ? "pause" : "resume");
    });
    // While held the slider only shows where it would go; the seek goes on release.
    slider.addEventListener("pointerdown", () => { replay.dragging = true; });
    slider.addEventListener("input", () => {
      replay.dragging = true;
      $("replay-time").textContent = `${clock(+slider.value)} / ${clock(replay.state.duration)}`;
    });
    slider.addEventListener("change", () => {
      replay.dragging = false;
      command("seek", { t: Math.min(+slider.value, replay.state.duration) });
    });
    // A press and release without a move fires no "change".
    slider.addEventListener("pointerup", () => setTimeout(() => { replay.dragging = false; }, 0));
    speed.addEventListener("change", () => command("speed", { speed: +speed.value }));
    bar.hidden = false;
  }

  function shownTime() {
    const s = replay.state;
    if (!s) return null;
    if (s.paused || s.ended) return s.t;
    return Math.min(s.duration, s.t + (performance.now() - replay.at) / 1000 * s.speed);
  }

  function shownState() {
    const s = replay.state;
    return s.ended ? "ended" : s.paused ? "paused" : "playing";
  }

  function draw() {
    const s = replay.state;
    if (!s) return;
    const t = shownTime();
    const state = shownState();
    bar.dataset.state = state;
    bar.dataset.t = t.toFixed(2);
    const play = $("replay-play");
    play.textContent = state === "playing" ? "❚❚ Pause" : state === "ended" ? "↻ Again" : "▶ Play";
    play.title = state === "playing" ? "pause the replay" : state === "ended" ? "play from the start" : "play on";
    if (!replay.dragging) {
      $("replay-slider").value = String(t);
      $("replay-time").textContent = `${clock(t)} / ${clock(s.duration)}`;
    }
    const speed = $("replay-speed");
    if (document.activeElement !== speed && +speed.value !== s.speed) {
      if (![...speed.options].some((o) => +o.value === s.speed)) speed.add(new Option(`${s.speed}x`, String(s.speed)));
      speed.value = String(s.speed);
    }
  }

  function take(state) {
    replay.state = state;
    if (replay.seeks !== null && state.seeks > replay.seeks) {
      window.dispatchEvent(new CustomEvent("rovlink:replay-jump", { detail: state }));
    }
    replay.seeks = Math.max(replay.seeks ?? 0, state.seeks);
    replay.at = performance.now();
    draw();
  }

  async function read() {
    const resp = await fetch("/api/replay", { cache: "no-store" });
    if (!resp.ok) throw new Error(`GET /api/replay: HTTP ${resp.status}`);
    return resp.json();
  }

  async function command(what, body) {
    replay.busy = true;
    replay.commands += 1;
    $("replay-error").textContent = "";
    try {
      const resp = await fetch(`/api/replay/${what}`, {
        method: "POST", headers: { "Content-Type": "application/json" }, body: JSON.stringify(body ?? {}) });
      const answer = await resp.json().catch(() => ({}));
      if (!resp.ok) throw new Error(answer.message || `HTTP ${resp.status}`);
      take(answer);
    } catch (err) {
      $("replay-error").textContent = `${what}: ${err.message}`;
    } finally {
      replay.busy = false;
    }
  }

  async function poll() {
    if (replay.busy || replay.dragging) return;
    const commands = replay.commands;
    try {
      const state = await read();
      if (replay.pollFailed) $("replay-error").textContent = "";
      replay.pollFailed = false;
      // A command answered meanwhile is newer than what this read saw.
      if (!replay.busy && !replay.dragging && commands === replay.commands) take(state);
    } catch (err) {
      // The console is gone or restarting: say so, keep the last state.
      replay.pollFailed = true;
      $("replay-error").textContent = `the console does not answer (${err.message})`;
    }
  }

  async function start() {
    let state;
    try {
      state = await read();
    } catch {
      return;  // an older console without the timeline: nothing to show
    }
    if (!state.available) return;  // a live console: the bar stays hidden
    build(state);
    take(state);
    setInterval(poll, POLL_MS);
    setInterval(draw, DRAW_MS);
  }

  start();
})();
