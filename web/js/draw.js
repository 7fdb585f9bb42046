// Drawing on canvases: the top-down map of an episode and line plots. No libraries.

const GRID = "#2a3a50";
const AXIS = "#93a4b8";
const FONT = "11px system-ui, sans-serif";

/** Canvas pixels per CSS pixel, so drawings stay sharp. */
function prepare(canvas) {
  const ctx = canvas.getContext("2d");
  ctx.setTransform(1, 0, 0, 1, 0, 0);
  ctx.clearRect(0, 0, canvas.width, canvas.height);
  return ctx;
}

/**
 * Top-down map, north up and east right (x north, y east as in the frame schema).
 * setStatic(EpisodeStatic) draws the obstacle map and the site; showFrame(Frame) adds vehicles,
 * trails and sonar hits; showPaths(Trajectories) draws whole paths.
 */
export class TopDownMap {
  constructor(canvas) {
    this.canvas = canvas;
    this.static = null;
    this.trails = new Map();
    this.frame = null;
    this.paths = null;
  }

  setStatic(st) {
    this.static = st;
    this.trails = new Map(st.agents.map((a) => [a.name, []]));
    this.frame = null;
    this.paths = null;
    const [lx, ly] = st.site.size;
    const pad = 12;
    const w = this.canvas.width - 2 * pad;
    const h = this.canvas.height - 2 * pad;
    this.scale = Math.min(w / ly, h / lx); // px per m
    this.ox = pad + (w - ly * this.scale) / 2;
    this.oy = pad + (h - lx * this.scale) / 2;
    this.draw();
  }

  px(x, y) {
    const [x0, y0] = this.static.site.origin;
    const lx = this.static.site.size[0];
    return [this.ox + (y - y0) * this.scale, this.oy + (lx - (x - x0)) * this.scale];
  }

  showFrame(frame) {
    this.frame = frame;
    for (const a of frame.agents) {
      const t = this.trails.get(a.name);
      if (!t) continue;
      if (frame.step === 0) t.length = 0;
      t.push([a.x, a.y]);
      if (t.length > 4000) t.splice(0, t.length - 4000);
    }
    this.draw();
  }

  showPaths(traj) {
    this.paths = traj;
    this.draw();
  }

  draw() {
    const ctx = prepare(this.canvas);
    const st = this.static;
    if (!st) return;
    const ob = st.obstacles;
    const res = ob.coarse_resolution;
    ctx.fillStyle = "#132338";
    const [sx0, sy0] = this.px(st.site.origin[0] + st.site.size[0], st.site.origin[1]);
    ctx.fillRect(sx0, sy0, st.site.size[1] * this.scale, st.site.size[0] * this.scale);
    ctx.fillStyle = "#8a6e4b";
    ob.rows.forEach((row, i) => {
      const x = ob.extent[0] + (i + 1) * res; // north edge of the row
      for (let j = 0; j < row.length; j++) {
        if (row[j] !== "#") continue;
        const [px, py] = this.px(x, ob.extent[2] + j * res);
        ctx.fillRect(px, py, res * this.scale + 0.5, res * this.scale + 0.5);
      }
    });
    ctx.strokeStyle = "#d0d7e0";
    ctx.lineWidth = 1;
    ctx.strokeRect(sx0, sy0, st.site.size[1] * this.scale, st.site.size[0] * this.scale);
    const colour = new Map(st.agents.map((a) => [a.name, a.color]));
    for (const a of st.agents) {
      if (!a.goal) continue;
      const [gx, gy] = this.px(a.goal[0], a.goal[1]);
      ctx.strokeStyle = a.color;
      ctx.setLineDash([3, 3]);
      ctx.beginPath();
      ctx.arc(gx, gy, Math.max(3, (a.goal_radius || 1) * this.scale), 0, 2 * Math.PI);
      ctx.stroke();
      ctx.setLineDash([]);
    }
    const polyline = (pts, color, width) => {
      if (pts.length < 2) return;
      ctx.strokeStyle = color;
      ctx.lineWidth = width;
      ctx.beginPath();
      pts.forEach(([x, y], k) => {
        const [px, py] = this.px(x, y);
        if (k === 0) ctx.moveTo(px, py);
        else ctx.lineTo(px, py);
      });
      ctx.stroke();
    };
    if (this.paths) {
      for (const a of this.paths.agents) {
        polyline(a.x.map((x, k) => [x, a.y[k]]), colour.get(a.name) || "#fff", 1.5);
      }
    }
    for (const [name, pts] of this.trails) polyline(pts, colour.get(name) || "#fff", 1.5);
    const f = this.frame;
    if (!f) return;
    ctx.fillStyle = "#ff5a5a";
    for (const a of f.agents) {
      for (const [hx, hy] of a.hits || []) {
        const [px, py] = this.px(hx, hy);
        ctx.fillRect(px - 1, py - 1, 2, 2);
      }
    }
    for (const a of f.agents) {
      const [px, py] = this.px(a.x, a.y);
      const c = colour.get(a.name) || "#fff";
      ctx.fillStyle = c;
      ctx.strokeStyle = c;
      ctx.beginPath();
      ctx.arc(px, py, 4.5, 0, 2 * Math.PI);
      ctx.fill();
      // heading: psi clockwise from north; on screen north is up
      ctx.lineWidth = 2;
      ctx.beginPath();
      ctx.moveTo(px, py);
      ctx.lineTo(px + 12 * Math.sin(a.psi), py - 12 * Math.cos(a.psi));
      ctx.stroke();
      if (!a.active) {
        ctx.strokeStyle = "#fff";
        ctx.lineWidth = 1;
        ctx.beginPath();
        ctx.arc(px, py, 7, 0, 2 * Math.PI);
        ctx.stroke();
      }
    }
    ctx.fillStyle = AXIS;
    ctx.font = FONT;
    ctx.fillText(`t = ${f.time.toFixed(1)} s, step ${f.step}`, 8, this.canvas.height - 6);
    ctx.fillText("N ↑", this.canvas.width - 28, 14);
  }
}

function niceTicks(lo, hi, n) {
  if (!(hi > lo)) return [lo];
  const raw = (hi - lo) / n;
  const mag = 10 ** Math.floor(Math.log10(raw));
  const step = [1, 2, 5, 10].map((m) => m * mag).find((s) => s >= raw) || raw;
  const out = [];
  for (let v = Math.ceil(lo / step) * step; v <= hi + 1e-9; v += step) out.push(v);
  return out;
}

/**
 * A line plot: series = [{label, color, xs, ys}], options {title, xlabel, hline: {y, label}}.
 */
export function lineChart(canvas, series, options = {}) {
  const ctx = prepare(canvas);
  const W = canvas.width;
  const H = canvas.height;
  const m = { l: 48, r: 10, t: 20, b: 28 };
  let x0 = Infinity, x1 = -Infinity, y0 = Infinity, y1 = -Infinity;
  for (const s of series) {
    for (let k = 0; k < s.xs.length; k++) {
      const x = s.xs[k], y = s.ys[k];
      if (!Number.isFinite(x) || !Number.isFinite(y)) continue;
      x0 = Math.min(x0, x); x1 = Math.max(x1, x);
      y0 = Math.min(y0, y); y1 = Math.max(y1, y);
    }
  }
  if (options.hline) { y0 = Math.min(y0, options.hline.y); y1 = Math.max(y1, options.hline.y); }
  ctx.font = FONT;
  ctx.fillStyle = AXIS;
  ctx.fillText(options.title || "", m.l, 13);
  if (!Number.isFinite(x0)) {
    ctx.fillText("no data yet", W / 2 - 30, H / 2);
    return;
  }
  if (x1 === x0) x1 = x0 + 1;
  if (y1 === y0) { y1 += 1; y0 -= 1; }
  const pad = 0.05 * (y1 - y0);
  y0 -= pad; y1 += pad;
  const X = (x) => m.l + ((x - x0) / (x1 - x0)) * (W - m.l - m.r);
  const Y = (y) => H - m.b - ((y - y0) / (y1 - y0)) * (H - m.t - m.b);
  ctx.strokeStyle = GRID;
  ctx.lineWidth = 1;
  for (const t of niceTicks(y0, y1, 4)) {
    ctx.beginPath(); ctx.moveTo(m.l, Y(t)); ctx.lineTo(W - m.r, Y(t)); ctx.stroke();
    ctx.fillText(Math.abs(t) >= 1e4 ? t.toExponential(1) : String(+t.toPrecision(4)), 4, Y(t) + 4);
  }
  for (const t of niceTicks(x0, x1, 6)) {
    ctx.beginPath(); ctx.moveTo(X(t), m.t); ctx.lineTo(X(t), H - m.b); ctx.stroke();
    ctx.fillText(String(+t.toPrecision(4)), X(t) - 8, H - m.b + 13);
  }
  ctx.fillText(options.xlabel || "", W - m.r - 60, H - 3);
  if (options.hline) {
    ctx.strokeStyle = "#e0a43a";
    ctx.setLineDash([4, 4]);
    ctx.beginPath(); ctx.moveTo(m.l, Y(options.hline.y)); ctx.lineTo(W - m.r, Y(options.hline.y)); ctx.stroke();
    ctx.setLineDash([]);
    ctx.fillStyle = "#e0a43a";
    ctx.fillText(options.hline.label || "", W - m.r - 90, Y(options.hline.y) - 3);
  }
  let lx = m.l + 150;
  for (const s of series) {
    ctx.strokeStyle = s.color;
    ctx.lineWidth = 1.6;
    ctx.beginPath();
    let started = false;
    for (let k = 0; k < s.xs.length; k++) {
      const x = s.xs[k], y = s.ys[k];
      if (!Number.isFinite(x) || !Number.isFinite(y)) continue;
      if (!started) { ctx.moveTo(X(x), Y(y)); started = true; } else ctx.lineTo(X(x), Y(y));
    }
    ctx.stroke();
    ctx.fillStyle = s.color;
    ctx.fillText(s.label, lx, 13);
    lx += ctx.measureText(s.label).width + 12;
  }
}
