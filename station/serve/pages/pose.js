// The pose to set, drawn: the unit as a box in its fixture on the table, seen from above at an
// angle, the table axis pointing up. `orientation` is the protocol's instruction: a 3 x 3
// rotation table frame -> unit frame (rows: the unit's axes in the table frame).
"use strict";

const POSE = (() => {
  const NS = "http://www.w3.org/2000/svg";
  const HALF = [70, 50, 30];                      // the box's half sizes along the unit's x, y, z
  const COLOURS = ["#d64545", "#2f9e44", "#2b6cb0"];
  const VIEWER = [0.55, -0.75, 0.65];             // towards the eye, table frame

  function project(p) {                            // table frame (z up) -> screen
    return [p[0] * 0.87 + p[1] * 0.5, -p[2] * 0.9 + p[1] * 0.35 - p[0] * 0.25];
  }
  function element(name, attributes, text) {
    const e = document.createElementNS(NS, name);
    for (const [k, v] of Object.entries(attributes)) e.setAttribute(k, v);
    if (text !== undefined) e.textContent = text;
    return e;
  }
  function add(a, b, s) { return a.map((x, i) => x + s * b[i]); }
  function dot(a, b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }

  function draw(svg, orientation, onTable) {
    svg.replaceChildren();
    const table = project([0, 0, -95]);
    svg.appendChild(element("ellipse", {cx: table[0], cy: table[1], rx: 140, ry: 45,
      fill: "#c9d3de", stroke: "#8a99ab"}));
    const top = project([0, 0, 135]);
    svg.appendChild(element("line", {x1: table[0], y1: table[1], x2: top[0], y2: top[1],
      stroke: "#1f3a5f", "stroke-width": 3, "stroke-dasharray": "6 5"}));
    svg.appendChild(element("polygon", {points: `${top[0]},${top[1] - 12} ${top[0] - 7},${top[1] + 2} ${top[0] + 7},${top[1] + 2}`, fill: "#1f3a5f"}));
    svg.appendChild(element("text", {x: top[0] + 10, y: top[1] + 4, class: "axis-label",
      "font-size": 13, fill: "#1f3a5f"}, onTable ? "table axis (up)" : "up"));
    if (!orientation) return;
    const axes = orientation.map((row) => row.map(Number));   // unit axes in the table frame
    const faces = [];
    for (let i = 0; i < 3; i++) {
      for (const sign of [1, -1]) {
        const normal = axes[i].map((x) => sign * x);
        if (dot(normal, VIEWER) <= 0) continue;                 // hidden face
        const [j, k] = [(i + 1) % 3, (i + 2) % 3];
        const centre = normal.map((x) => x * HALF[i]);
        const corners = [[1, 1], [1, -1], [-1, -1], [-1, 1]].map(([a, b]) =>
          project(add(add(centre, axes[j], a * HALF[j]), axes[k], b * HALF[k])));
        faces.push({i, sign, corners, label: project(centre), light: dot(normal, VIEWER)});
      }
    }
    for (const f of faces) {
      svg.appendChild(element("polygon", {points: f.corners.map((c) => c.join(",")).join(" "),
        fill: COLOURS[f.i], "fill-opacity": f.sign > 0 ? 0.25 + 0.5 * f.light : 0.12,
        stroke: "#1c2430", "stroke-width": 2}));
      svg.appendChild(element("text", {x: f.label[0], y: f.label[1] + 6, "text-anchor": "middle",
        "font-size": 20, "font-weight": 700, fill: "#1c2430"}, `${f.sign > 0 ? "+" : "−"}${"XYZ"[f.i]}`));
    }
    const up = [0, 1, 2].map((i) => axes[i][2]);               // the table axis in the unit frame
    svg.appendChild(element("text", {x: 0, y: 140, "text-anchor": "middle", "font-size": 14,
      fill: "#1c2430"}, `${onTable ? "up the table axis" : "up"}: unit (${up.map((x) => x.toFixed(2)).join(", ")})`));
  }
  return {draw};
})();
