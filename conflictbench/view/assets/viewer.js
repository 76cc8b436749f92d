// conflictbench viewer: filters on the index page; plots and synchronised videos on a pair page.
// No dependencies, so the site opens from disk (file://) anywhere.
"use strict";

const SVG = "http://www.w3.org/2000/svg";
const COLORS = { reference: "#1f77b4", conflict: "#d9480f" };

function node(name, attrs, parent, text) {
  const el = document.createElementNS(SVG, name);
  for (const [k, v] of Object.entries(attrs)) el.setAttribute(k, v);
  if (text !== undefined) el.textContent = text;
  if (parent) parent.appendChild(el);
  return el;
}

function ticks(lo, hi, count) {
  const step0 = (hi - lo) / Math.max(count, 1);
  const magnitude = Math.pow(10, Math.floor(Math.log10(step0)));
  const step = [1, 2, 5, 10].map((m) => m * magnitude).find((s) => s >= step0);
  const decimals = Math.max(0, -Math.floor(Math.log10(step) + 1e-9));
  const out = [];  // as text with the step's decimals: no 2.7e-17 where 0 is meant
  for (let i = Math.ceil(lo / step - 1e-9); i * step <= hi + step * 1e-9; i++) out.push((i * step).toFixed(decimals));
  return out;
}

// A line plot as SVG: series = [{points: [[x, y], ...], color, label, dash, marker}]; equal: same scale on both axes.
function linePlot(container, { series, xlabel, ylabel, title, equal = false, width = 360, height = 260, extra = [],
                                compass = null }) {
  const pad = { left: 56, right: 12, top: 38, bottom: 40 };  // the legend sits between the title and the frame
  const all = series.flatMap((s) => s.points).concat(extra.map((e) => e.point));
  const xs = all.map((p) => p[0]), ys = all.map((p) => p[1]);
  let [x0, x1, y0, y1] = [Math.min(...xs), Math.max(...xs), Math.min(...ys), Math.max(...ys)];
  if (!all.length) [x0, x1, y0, y1] = [0, 1, 0, 1];
  if (x1 - x0 < 1e-9) { x0 -= 0.5; x1 += 0.5; }
  if (y1 - y0 < 1e-9) { y0 -= 0.5; y1 += 0.5; }
  const w = width - pad.left - pad.right, h = height - pad.top - pad.bottom;
  if (equal) {  // the same metres per pixel on both axes, centred, with a margin (no point on the frame)
    const scale = Math.max((x1 - x0) / w, (y1 - y0) / h) * 1.08;
    const cx = (x0 + x1) / 2, cy = (y0 + y1) / 2;
    [x0, x1, y0, y1] = [cx - scale * w / 2, cx + scale * w / 2, cy - scale * h / 2, cy + scale * h / 2];
  } else {
    const my = (y1 - y0) * 0.05; y0 -= my; y1 += my;
  }
  const X = (x) => pad.left + (x - x0) / (x1 - x0) * w;
  const Y = (y) => pad.top + h - (y - y0) / (y1 - y0) * h;
  const svg = node("svg", { viewBox: `0 0 ${width} ${height}`, width, height, class: "plot", role: "img" }, container);
  if (title) node("text", { x: pad.left, y: 16, class: "title" }, svg, title);
  node("rect", { x: pad.left, y: pad.top, width: w, height: h, class: "frame" }, svg);
  for (const t of ticks(x0, x1, 5)) {
    node("line", { x1: X(+t), x2: X(+t), y1: pad.top + h, y2: pad.top + h + 4, class: "tick" }, svg);
    node("text", { x: X(+t), y: pad.top + h + 16, class: "tick-label", "text-anchor": "middle" }, svg, t);
  }
  for (const t of ticks(y0, y1, 4)) {
    node("line", { x1: pad.left - 4, x2: pad.left, y1: Y(+t), y2: Y(+t), class: "tick" }, svg);
    node("text", { x: pad.left - 6, y: Y(+t) + 4, class: "tick-label", "text-anchor": "end" }, svg, t);
  }
  if (xlabel) node("text", { x: pad.left + w / 2, y: height - 6, "text-anchor": "middle", class: "axis" }, svg, xlabel);
  if (ylabel) node("text", { x: 12, y: pad.top + h / 2, "text-anchor": "middle", class: "axis",
                             transform: `rotate(-90 12 ${pad.top + h / 2})` }, svg, ylabel);
  const clip = "clip-" + Math.random().toString(36).slice(2);
  node("rect", { x: pad.left, y: pad.top, width: w, height: h }, node("clipPath", { id: clip }, svg));
  const layer = node("g", { "clip-path": `url(#${clip})` }, svg);
  let legendX = pad.left + 6;
  for (const s of series) {
    if (!s.points.length) continue;
    const d = s.points.map((p, i) => `${i ? "L" : "M"}${X(p[0]).toFixed(1)},${Y(p[1]).toFixed(1)}`).join("");
    node("path", { d, stroke: s.color, fill: "none", "stroke-width": 1.6, "stroke-dasharray": s.dash || "none",
                   class: "series" }, layer);
    if (s.marker) {
      const [sx, sy] = s.points[0];
      node("circle", { cx: X(sx), cy: Y(sy), r: 3.5, fill: s.color, class: "start" }, layer);
    }
    if (s.label) {
      node("line", { x1: legendX, x2: legendX + 16, y1: pad.top - 8, y2: pad.top - 8, stroke: s.color,
                     "stroke-width": 2, "stroke-dasharray": s.dash || "none" }, svg);
      node("text", { x: legendX + 20, y: pad.top - 4, class: "legend" }, svg, s.label);
      legendX += 28 + 6.5 * s.label.length;
    }
  }
  if (compass) {  // arrows along the plot's axes, named in the frame the suite's words use
    const ox = pad.left + 14, oy = pad.top + h - 14, len = 26;
    node("line", { x1: ox, y1: oy, x2: ox + len, y2: oy, class: "compass" }, svg);
    node("text", { x: ox + len + 3, y: oy + 4, class: "compass-label" }, svg, compass.x);
    node("line", { x1: ox, y1: oy, x2: ox, y2: oy - len, class: "compass" }, svg);
    node("text", { x: ox - 4, y: oy - len - 4, class: "compass-label" }, svg, compass.y);
  }
  for (const e of extra) {  // marked points: the targets' initial positions
    node("rect", { x: X(e.point[0]) - 4, y: Y(e.point[1]) - 4, width: 8, height: 8, class: "target" }, layer);
    node("text", { x: X(e.point[0]) + 7, y: Y(e.point[1]) - 6, class: "target-label" }, layer, e.label);
  }
  return svg;
}

function pairPage(data) {
  const episodes = ["reference", "conflict"].filter((k) => data[k]);
  const path = (k, a, b) => ({ points: data[k].eef.map((p) => [p[a], p[b]]), color: COLORS[k], label: k,
                               dash: k === "conflict" ? "5 3" : "", marker: true });
  const targets = (a, b) => (data.reference.targets || []).map((p, i) => ({ point: [p[a], p[b]], label: data.target_names[i] || "" }));
  linePlot(document.getElementById("plot-top"), { series: episodes.map((k) => path(k, 0, 1)), equal: true,
    title: "End effector, seen from above", xlabel: "x (m), + = front: towards the camera",
    ylabel: "y (m), + = the image's right", extra: targets(0, 1),
    compass: { x: "+x front (camera)", y: "+y image right = robot's left" } });
  linePlot(document.getElementById("plot-side"), { series: episodes.map((k) => path(k, 0, 2)), equal: true,
    title: "End effector, seen from the side", xlabel: "x (m)", ylabel: "z (m)", extra: targets(0, 2) });
  linePlot(document.getElementById("plot-distance"), {
    series: episodes.map((k) => ({ points: data[k].distance.map((d, t) => [t, d]).filter((p) => p[1] >= 0),
                                   color: COLORS[k], label: k, dash: k === "conflict" ? "5 3" : "" })),
    title: "Distance to the nearest target (TAR's d_t)", xlabel: "recorded state", ylabel: "metres" });
  const names = ["x", "y", "z", "roll", "pitch", "yaw", "gripper"];
  const box = document.getElementById("plot-actions");
  names.forEach((name, j) => linePlot(box, {
    series: episodes.map((k) => ({ points: data[k].actions.map((a, t) => [t, a[j]]), color: COLORS[k],
                                   label: j ? "" : k, dash: k === "conflict" ? "5 3" : "" })),
    title: `action: ${name}`, xlabel: "step", width: 300, height: 180 }));
  const videos = [...document.querySelectorAll("video")];
  const both = document.getElementById("play-both");
  if (both && videos.length === 2) {
    both.addEventListener("click", () => {
      const playing = videos.some((v) => !v.paused && !v.ended);
      videos.forEach((v) => { if (playing) v.pause(); else { v.currentTime = 0; v.play(); } });
      both.textContent = playing ? "Play both from the start" : "Pause both";
    });
    videos.forEach((v) => v.addEventListener("ended", () => {
      if (videos.every((u) => u.paused || u.ended)) both.textContent = "Play both from the start";
    }));
  }
}

function indexPage() {
  const rows = [...document.querySelectorAll("#pairs tbody tr")];
  const selects = [...document.querySelectorAll("#filters select")];
  const count = document.getElementById("count");
  const apply = () => {
    let shown = 0;
    for (const row of rows) {
      const ok = selects.every((s) => !s.value || row.dataset[s.name] === s.value);
      row.hidden = !ok;
      shown += ok;
    }
    count.textContent = `${shown} of ${rows.length} pairs shown`;
  };
  selects.forEach((s) => s.addEventListener("change", apply));
  apply();
}

document.addEventListener("DOMContentLoaded", () => {
  const data = document.getElementById("pair-data");
  if (data) pairPage(JSON.parse(data.textContent));
  else if (document.getElementById("pairs")) indexPage();
});
