// rovlink operator page: the instruments (attitude indicator, heading tape,
// depth tape), drawn on canvases from what console.js hands them.  They hold
// no state of their own: every draw is from the latest reply's values, and a
// value that is not valid (null) or old (`stale`) is drawn grey with no needle.
"use strict";

(() => {
  const SKY = "#2f6fa8", GROUND = "#7a5230", LINE = "#ffffff", MARK = "#f1c40f", TARGET = "#50e678";
  const GREY_SKY = "#4a5660", GREY_GROUND = "#3a3a3a";

  function ctxOf(canvas) {
    // Draw at the device's pixel ratio for crisp ticks.
    const dpr = window.devicePixelRatio || 1;
    const w = canvas.clientWidth || canvas.width, h = canvas.clientHeight || canvas.height;
    if (canvas.width !== Math.round(w * dpr) || canvas.height !== Math.round(h * dpr)) {
      canvas.width = Math.round(w * dpr);
      canvas.height = Math.round(h * dpr);
    }
    const ctx = canvas.getContext("2d");
    ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    return [ctx, w, h];
  }

  // Attitude: a horizon turned by roll and moved by pitch (4 px a degree),
  // a fixed aircraft symbol, a roll scale with a pointer.
  function attitude(canvas, roll, pitch, ok) {
    const [ctx, w, h] = ctxOf(canvas);
    const r = Math.min(w, h) / 2 - 2;
    ctx.clearRect(0, 0, w, h);
    ctx.save();
    ctx.translate(w / 2, h / 2);
    ctx.beginPath();
    ctx.arc(0, 0, r, 0, 2 * Math.PI);
    ctx.clip();
    const valid = ok && roll !== null && pitch !== null;
    const pxPerDeg = r / 30;
    ctx.save();
    if (valid) ctx.rotate((-roll * Math.PI) / 180);
    const shift = valid ? Math.max(-r, Math.min(r, pitch * pxPerDeg)) : 0;
    ctx.fillStyle = valid ? SKY : GREY_SKY;
    ctx.fillRect(-2 * r, -2 * r + shift, 4 * r, 2 * r);
    ctx.fillStyle = valid ? GROUND : GREY_GROUND;
    ctx.fillRect(-2 * r, shift, 4 * r, 2 * r);
    ctx.strokeStyle = LINE;
    ctx.lineWidth = 1.5;
    ctx.beginPath();
    ctx.moveTo(-2 * r, shift); ctx.lineTo(2 * r, shift);
    ctx.stroke();
    if (valid) {
      ctx.lineWidth = 1;
      ctx.fillStyle = LINE;
      ctx.font = "9px sans-serif";
      for (const p of [-20, -10, 10, 20]) {
        const y = shift - p * pxPerDeg;
        const half = Math.abs(p) === 10 ? r * 0.25 : r * 0.4;
        ctx.beginPath(); ctx.moveTo(-half, y); ctx.lineTo(half, y); ctx.stroke();
        ctx.fillText(String(p), half + 3, y + 3);
      }
    }
    ctx.restore();
    // Roll scale and pointer
    ctx.strokeStyle = LINE;
    for (const a of [-60, -45, -30, -20, -10, 0, 10, 20, 30, 45, 60]) {
      const t = ((a - 90) * Math.PI) / 180;
      const inner = a % 30 === 0 ? r - 10 : r - 6;
      ctx.beginPath();
      ctx.moveTo(Math.cos(t) * inner, Math.sin(t) * inner);
      ctx.lineTo(Math.cos(t) * r, Math.sin(t) * r);
      ctx.stroke();
    }
    if (valid) {
      ctx.save();
      ctx.rotate((-roll * Math.PI) / 180);
      ctx.fillStyle = MARK;
      ctx.beginPath();
      ctx.moveTo(0, -r + 11); ctx.lineTo(-5, -r + 19); ctx.lineTo(5, -r + 19);
      ctx.closePath(); ctx.fill();
      ctx.restore();
    }
    // The vehicle: fixed
    ctx.strokeStyle = MARK;
    ctx.lineWidth = 3;
    ctx.beginPath();
    ctx.moveTo(-r * 0.5, 0); ctx.lineTo(-r * 0.15, 0); ctx.lineTo(0, r * 0.1);
    ctx.lineTo(r * 0.15, 0); ctx.lineTo(r * 0.5, 0);
    ctx.stroke();
    if (!valid) {
      ctx.fillStyle = "#ff8c7a";
      ctx.font = "bold 13px sans-serif";
      ctx.textAlign = "center";
      ctx.fillText("NO DATA", 0, -r * 0.35);
    }
    ctx.restore();
  }

  const CARDINAL = { 0: "N", 45: "NE", 90: "E", 135: "SE", 180: "S", 225: "SW", 270: "W", 315: "NW" };

  // Heading: a tape 120 degrees wide centred on the heading; the target's
  // heading (a position order) as a green mark.
  function heading(canvas, hdg, target, ok) {
    const [ctx, w, h] = ctxOf(canvas);
    ctx.clearRect(0, 0, w, h);
    ctx.fillStyle = "#0f2230";
    ctx.fillRect(0, 0, w, h);
    const valid = ok && hdg !== null;
    const centre = valid ? hdg : 0;
    const span = 120;
    const pxPerDeg = w / span;
    ctx.strokeStyle = valid ? LINE : "#667";
    ctx.fillStyle = valid ? LINE : "#667";
    ctx.font = "11px sans-serif";
    ctx.textAlign = "center";
    const start = Math.floor((centre - span / 2) / 5) * 5;
    for (let a = start; a <= centre + span / 2; a += 5) {
      const x = w / 2 + (a - centre) * pxPerDeg;
      const norm = ((a % 360) + 360) % 360;
      const major = norm % 15 === 0;
      ctx.beginPath();
      ctx.moveTo(x, h - 4);
      ctx.lineTo(x, h - (major ? 18 : 10));
      ctx.stroke();
      const label = norm % 45 === 0 ? CARDINAL[norm] : norm % 15 === 0 ? String(norm) : null;
      // Only whole labels: one cut by the tape's edge reads as another number ("00" for 300).
      if (label !== null) {
        const half = ctx.measureText(label).width / 2;
        if (x - half >= 0 && x + half <= w) ctx.fillText(label, x, h - 22);
      }
    }
    if (valid && target !== null && target !== undefined) {
      let d = ((target - centre + 540) % 360) - 180;
      d = Math.max(-span / 2, Math.min(span / 2, d));
      const x = w / 2 + d * pxPerDeg;
      ctx.fillStyle = TARGET;
      ctx.fillRect(x - 3, 0, 6, 10);
    }
    ctx.fillStyle = valid ? MARK : "#ff8c7a";
    ctx.beginPath();
    ctx.moveTo(w / 2, h - 2); ctx.lineTo(w / 2 - 6, h - 12 + 12); ctx.lineTo(w / 2 + 6, h - 12 + 12);
    ctx.fill();
    ctx.strokeStyle = valid ? MARK : "#ff8c7a";
    ctx.lineWidth = 2;
    ctx.beginPath(); ctx.moveTo(w / 2, 0); ctx.lineTo(w / 2, h); ctx.stroke();
    ctx.lineWidth = 1;
    ctx.font = "bold 14px sans-serif";
    ctx.fillStyle = valid ? MARK : "#ff8c7a";
    ctx.fillText(valid ? `${Math.round(((hdg % 360) + 360) % 360)}°` : "NO DATA", w / 2 + (valid ? 24 : 40), 14);
  }

  // Depth: a vertical tape, 10 m tall, deeper down; the target depth as a green mark.
  function depth(canvas, z, target, ok) {
    const [ctx, w, h] = ctxOf(canvas);
    ctx.clearRect(0, 0, w, h);
    ctx.fillStyle = "#0f2230";
    ctx.fillRect(0, 0, w, h);
    const valid = ok && z !== null;
    const centre = valid ? z : 0;
    const span = 10;
    const pxPerM = h / span;
    ctx.strokeStyle = valid ? LINE : "#667";
    ctx.fillStyle = valid ? LINE : "#667";
    ctx.font = "11px sans-serif";
    ctx.textAlign = "left";
    for (let d = Math.floor(centre - span / 2); d <= centre + span / 2; d += 0.5) {
      const y = h / 2 + (d - centre) * pxPerM;
      const whole = Math.abs(d - Math.round(d)) < 1e-6;
      ctx.beginPath();
      ctx.moveTo(w - 4, y);
      ctx.lineTo(w - (whole ? 16 : 10), y);
      ctx.stroke();
      if (whole) ctx.fillText(`${d}`, w - 40, y + 4);
    }
    if (valid && centre - span / 2 < 0) {  // the surface
      ctx.fillStyle = "#1d4f72";
      ctx.fillRect(0, 0, w, h / 2 - centre * pxPerM);
    }
    if (valid && target !== null && target !== undefined) {
      const y = Math.max(2, Math.min(h - 2, h / 2 + (target - centre) * pxPerM));
      ctx.fillStyle = TARGET;
      ctx.fillRect(w - 18, y - 3, 18, 6);
    }
    ctx.strokeStyle = valid ? MARK : "#ff8c7a";
    ctx.lineWidth = 2;
    ctx.beginPath(); ctx.moveTo(0, h / 2); ctx.lineTo(w, h / 2); ctx.stroke();
    ctx.lineWidth = 1;
    ctx.fillStyle = valid ? MARK : "#ff8c7a";
    ctx.font = "bold 13px sans-serif";
    ctx.fillText(valid ? `${z.toFixed(1)} m` : "NO DATA", 2, h / 2 - 5);
  }

  window.rovInstruments = { attitude, heading, depth };
})();
