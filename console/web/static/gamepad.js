// rovlink operator page: the gamepad.  console.js asks this module, every
// TICK_MS, for the sticks' wish and for a STOP press; it owns nothing else of
// the gamepad.  Interface (window.rovGamepad):
//   wish()        -> {vx, vy, vz, vyaw} fractions -1..1 after deadzone, or null without a pad
//   stopPressed() -> true once per press of a STOP button
//   connected()   -> the Gamepad object or null
//   onChange(fn)  -> fn(text) when a pad connects or goes (for the page's status line)
"use strict";

(() => {
  const DEADZONE = 0.12;
  const STOP_BUTTONS = [1];
  let index = null;
  let stopWasDown = false;
  const listeners = [];

  function connected() {
    if (index === null || !navigator.getGamepads) return null;
    const pad = navigator.getGamepads()[index];
    return pad && pad.connected ? pad : null;
  }

  function wish() {
    const pad = connected();
    if (!pad) return null;
    const ax = (i) => (Math.abs(pad.axes[i] || 0) < DEADZONE ? 0 : pad.axes[i]);
    return { vx: -ax(1), vy: ax(0), vz: ax(3), vyaw: ax(2) };
  }

  function stopPressed() {
    const pad = connected();
    const down = !!pad && STOP_BUTTONS.some((b) => pad.buttons[b] && pad.buttons[b].pressed);
    const edge = down && !stopWasDown;
    stopWasDown = down;
    return edge;
  }

  function tell(text) { for (const fn of listeners) fn(text); }

  window.addEventListener("gamepadconnected", (ev) => {
    index = ev.gamepad.index;
    tell(`Gamepad: ${ev.gamepad.id}.`);
  });
  window.addEventListener("gamepaddisconnected", (ev) => {
    if (ev.gamepad.index === index) {
      index = null;
      tell("No gamepad.");
    }
  });

  window.rovGamepad = { wish, stopPressed, connected, onChange: (fn) => listeners.push(fn) };
})();
