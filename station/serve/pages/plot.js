// Live plots on a canvas: several series over the last `span` seconds of the session's clock.
"use strict";

const PLOT = (() => {
  const COLOURS = ["#d64545", "#2f9e44", "#2b6cb0", "#c98a00", "#7b3fb5", "#138a8a",
                   "#a1502a", "#555e6b", "#e0569b", "#6c8c1a", "#3f5bd6", "#8c6b1a"];

  function draw(canvas, points, span) {          // points: [[t, [v0, v1, ...]], ...]
    const g = canvas.getContext("2d");
    const w = canvas.width, h = canvas.height;
    g.clearRect(0, 0, w, h);
    g.font = "12px system-ui";
    if (!points.length) { g.fillStyle = "#889"; g.fillText("no data yet", 10, 20); return; }
    const end = points[points.length - 1][0], start = end - span;
    let lo = Infinity, hi = -Infinity;
    for (const [, v] of points) for (const x of v) { if (x < lo) lo = x; if (x > hi) hi = x; }
    if (hi - lo < 1e-9) { hi += 1e-3; lo -= 1e-3; }
    const pad = (hi - lo) * 0.08; lo -= pad; hi += pad;
    const X = (t) => 62 + (w - 68) * (t - start) / span;
    const Y = (v) => 6 + (h - 24) * (hi - v) / (hi - lo);
    g.strokeStyle = "#dde3ea"; g.fillStyle = "#667"; g.lineWidth = 1;
    // enough digits that the three labels differ however small the span is beside the level
    const level = Math.max(Math.abs(lo), Math.abs(hi));
    const digits = Math.min(10, Math.max(3, 3 + Math.ceil(Math.log10(level / (hi - lo)))));
    for (const v of [lo + pad, (lo + hi) / 2, hi - pad]) {
      g.beginPath(); g.moveTo(62, Y(v)); g.lineTo(w, Y(v)); g.stroke();
      g.fillText(v.toPrecision(digits), 2, Y(v) + 4);
    }
    g.fillText(`${span} s`, w - 40, h - 4);
    const n = points[0][1].length;
    for (let c = 0; c < n; c++) {
      g.strokeStyle = COLOURS[c % COLOURS.length]; g.lineWidth = 1.5; g.beginPath();
      points.forEach(([t, v], k) => (k ? g.lineTo(X(t), Y(v[c])) : g.moveTo(X(t), Y(v[c]))));
      g.stroke();
    }
  }

  function trim(points, span) {                  // keep the last `span` s (and one before)
    if (!points.length) return points;
    const start = points[points.length - 1][0] - span;
    let k = 0;
    while (k < points.length - 1 && points[k + 1][0] < start) k++;
    return k ? points.slice(k) : points;
  }
  return {draw, trim};
})();
