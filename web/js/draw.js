// Drawing on canvases: the episode map (a chart: axes in metres, north arrow, scale bar, shaded
// seabed, smooth obstacle outlines, sonar fans) and line plots. No libraries.
// Colours come from hptvsim/palette.py through the generated module (DISPLAY).

import { DISPLAY } from "./frames.gen.js";

const GRID = "#2a3a50";
const AXIS = "#93a4b8";
const TEXT = "#d0d7e0";
const FONT = "11px system-ui, sans-serif";
const SMALL_FONT = "10px system-ui, sans-serif";
const HIT_FRACTION = 0.98; // as hptvsim.episodes.stepper.HIT_FRACTION: a beam this close to its maximum saw nothing

/** Colours of episodes compared on one timeline (distinct from the agents' warm palette). */
export const EPISODE_COLORS = ["#e6edf5", "#4dd0e1", "#b388ff", "#9ccc65"];
export const EPISODE_DASHES = [[], [7, 4], [2, 3], [10, 3, 2, 3]];

function rgbOf(hex) {
  const c = hex.replace("#", "");
  return [parseInt(c.slice(0, 2), 16), parseInt(c.slice(2, 4), 16), parseInt(c.slice(4, 6), 16)];
}

/** The colour at t in [0, 1] of a ramp of [t, [r, g, b]] stops, linear between them. */
function rampRgb(stops, t) {
  t = Math.min(1, Math.max(0, t));
  for (let k = 1; k < stops.length; k++) {
    const [t1, c1] = stops[k];
    const [t0, c0] = stops[k - 1];
    if (t <= t1) {
      const f = t1 > t0 ? (t - t0) / (t1 - t0) : 0;
      return c0.map((v, i) => v + f * (c1[i] - v));
    }
  }
  return stops[stops.length - 1][1];
}

/** The seabed's colour at depth fraction t in [0, 1] (palette.DEPTH_STOPS). */
function depthRgb(t) {
  return rampRgb(DISPLAY.depth_stops, t);
}

/** Sonar range colour of a range fraction: cyan near through sky blue to pale (palette.SONAR_RANGE_STOPS). */
export function rangeColor(frac) {
  const c = rampRgb(DISPLAY.sonar_range_stops, frac).map(Math.round);
  return `rgb(${c[0]},${c[1]},${c[2]})`;
}

/**
 * Where each sonar beam of a 3-D-game agent ends, in NED [m] (frame schema, "Two games"): beam k
 * points along b = (cos e cos a, cos e sin a, sin e) in the body frame (azimuth a = beam_angles[k]
 * from the bow towards starboard, elevation e = beam_elevations[k] positive down), turned into NED
 * by R = Rz(psi) Ry(theta) Rx(phi) (hptvsim/sensors/sonar3d.py). The ends are the frame's hits.
 *
 * @param {{x: number, y: number, z: number, phi?: number, theta?: number, psi: number, ranges: number[]}} a
 * @param {{beam_angles: number[], beam_elevations: number[], max_range: number}} info
 * A beam without an echo that rises to the surface ends there (the sea surface is no echo), so its
 * end is put there rather than at max_range.
 *
 * @returns {Array<{x: number, y: number, z: number, r: number, hit: boolean, level: boolean}>}
 *   r: the measured range; level: the beam is in the row nearest the body's x-y plane
 *   (elevation closest to 0).
 */
export function beamEnds3d(a, info) {
  const els = info.beam_elevations || [];
  const flat = Math.min(...els.map(Math.abs));
  const [cf, sf] = [Math.cos(a.phi || 0), Math.sin(a.phi || 0)];
  const [ct, st] = [Math.cos(a.theta || 0), Math.sin(a.theta || 0)];
  const [cp, sp] = [Math.cos(a.psi), Math.sin(a.psi)];
  return a.ranges.map((r, k) => {
    const az = info.beam_angles[k];
    const el = els[k] || 0;
    const b = [Math.cos(el) * Math.cos(az), Math.cos(el) * Math.sin(az), Math.sin(el)];
    const d = [
      cp * ct * b[0] + (-sp * cf + cp * st * sf) * b[1] + (sp * sf + cp * cf * st) * b[2],
      sp * ct * b[0] + (cp * cf + sf * st * sp) * b[1] + (-cp * sf + st * sp * cf) * b[2],
      -st * b[0] + ct * sf * b[1] + ct * cf * b[2],
    ];
    const hit = r < HIT_FRACTION * info.max_range;
    const len = !hit && d[2] < 0 && a.z >= 0 ? Math.min(r, a.z / -d[2]) : r;
    return {
      x: a.x + len * d[0],
      y: a.y + len * d[1],
      z: a.z + len * d[2],
      r,
      hit,
      level: Math.abs(Math.abs(el) - flat) < 1e-9,
    };
  });
}

function niceStep(raw) {
  const mag = 10 ** Math.floor(Math.log10(raw));
  return [1, 2, 5, 10].map((m) => m * mag).find((s) => s >= raw) || raw;
}

function niceTicks(lo, hi, n) {
  if (!(hi > lo)) return [lo];
  const step = niceStep((hi - lo) / n);
  const out = [];
  for (let v = Math.ceil(lo / step - 1e-9) * step; v <= hi + 1e-9 * step; v += step) out.push(+v.toPrecision(12));
  return out;
}

function tickText(t) {
  if (Math.abs(t) >= 1e6) return `${+(t / 1e6).toPrecision(3)}M`;
  if (Math.abs(t) >= 1e4) return `${+(t / 1e3).toPrecision(3)}k`;
  return String(+t.toPrecision(5));
}

function offscreen(w, h) {
  const c = document.createElement("canvas");
  c.width = Math.max(1, Math.round(w));
  c.height = Math.max(1, Math.round(h));
  return c;
}

/**
 * The map of an episode, drawn as a chart: north up, east right (x north, y east as in the frame
 * schema), axes in metres, a north arrow, a scale bar and a depth colour bar.
 *
 * setStatic(EpisodeStatic) draws the site; showFrame(Frame) adds the vehicles, their live trails and
 * sonar fans; setReplay(Trajectories) then showStep(k) shows step k of a finished episode.
 */
export class TopDownMap {
  /**
   * @param {HTMLCanvasElement} canvas
   * @param {{compact?: boolean}} options compact: smaller margins and no colour bar (previews).
   */
  constructor(canvas, options = {}) {
    this.canvas = canvas;
    this.compact = !!options.compact;
    this.static = null;
    this.background = null;
    this.trails = new Map();
    this.frame = null;
    this.replay = null;
    this.step = null;
    this.sonar = true;
    this.caption = "";
    this.collisions = []; // each agent's first collision: {agent, collided_with, step, x, y}
  }

  /** Canvas pixel of the point x north, y east [m]. */
  px(x, y) {
    const [x0, y0] = this.static.site.origin;
    const lx = this.static.site.size[0];
    return [this.ox + (y - y0) * this.scale, this.oy + (lx - (x - x0)) * this.scale];
  }

  setStatic(st) {
    this.static = st;
    this.trails = new Map(st.agents.map((a) => [a.name, []]));
    this.frame = null;
    this.replay = null;
    this.step = null;
    this.collisions = [];
    const [lx, ly] = st.site.size;
    const m = this.compact ? { l: 36, r: 8, t: 8, b: 30 } : { l: 50, r: 58, t: 10, b: 38 };
    const w = this.canvas.width - m.l - m.r;
    const h = this.canvas.height - m.t - m.b;
    this.scale = Math.min(w / ly, h / lx); // px per m
    this.ox = m.l + (w - ly * this.scale) / 2;
    this.oy = m.t + (h - lx * this.scale) / 2;
    this.siteW = ly * this.scale;
    this.siteH = lx * this.scale;
    this.background = this.drawBackground();
    this.draw();
  }

  setSonar(on) {
    this.sonar = on;
    this.draw();
  }

  showFrame(frame) {
    this.frame = frame;
    this.replay = null;
    if (frame.step === 0) this.collisions = [];
    for (const a of frame.agents) {
      if (a.collision && a.collided_with && !this.collisions.some((c) => c.agent === a.name)) {
        this.collisions.push({ agent: a.name, collided_with: a.collided_with, step: frame.step, x: a.x, y: a.y });
      }
      const t = this.trails.get(a.name);
      if (!t) continue;
      if (frame.step === 0) t.length = 0;
      t.push([a.x, a.y]);
      if (t.length > 8000) t.splice(0, t.length - 8000);
    }
    this.draw();
  }

  /** A finished episode's collisions (its summary's `collisions`), marked from their step on. */
  setCollisions(list) {
    this.collisions = (list || []).slice();
    this.draw();
  }

  /** A cross and "agent: what" where each collision shown so far happened. */
  drawCollisions(ctx, info) {
    ctx.font = FONT;
    ctx.textAlign = "left";
    ctx.textBaseline = "bottom";
    for (const c of this.collisions) {
      if (this.replay && this.step !== null && c.step > this.replay.step[this.step]) continue;
      const [px, py] = this.px(c.x, c.y);
      ctx.strokeStyle = "#ff4d4d";
      ctx.lineWidth = 2.5;
      ctx.beginPath();
      ctx.moveTo(px - 7, py - 7);
      ctx.lineTo(px + 7, py + 7);
      ctx.moveTo(px + 7, py - 7);
      ctx.lineTo(px - 7, py + 7);
      ctx.stroke();
      const text = `${c.agent}: ${c.collided_with}`;
      const w = ctx.measureText(text).width;
      ctx.fillStyle = "rgba(13, 21, 32, 0.75)";
      ctx.fillRect(px + 9, py - 26, w + 6, 16);
      ctx.fillStyle = info.get(c.agent)?.color || "#fff";
      ctx.fillText(text, px + 12, py - 11);
    }
  }

  /** A finished episode's trajectories (frame schema `Trajectories`), shown step by step. */
  setReplay(traj) {
    this.replay = traj;
    this.showStep(traj.step.length - 1);
  }

  /** Show row k of the replay: paths up to k, vehicles and sonar fans at k. */
  showStep(k) {
    if (!this.replay) return;
    const n = this.replay.step.length;
    this.step = Math.max(0, Math.min(n - 1, k));
    this.draw();
  }

  /** Agents' states to draw now: [{name, x, y, psi, ranges, active}] (3-D game: also z, phi, theta, altitude). */
  current() {
    if (this.replay && this.step !== null) {
      const k = this.step;
      const last = this.replay.step.length - 1;
      return this.replay.agents.map((a) => {
        let ranges = null;
        if (a.ranges) {
          // the nearest step at or before k that carried sonar
          for (let j = k; j >= Math.max(0, k - 50); j--) {
            if (a.ranges[j] && a.ranges[j].length) {
              ranges = a.ranges[j];
              break;
            }
          }
        }
        const s = { name: a.name, x: a.x[k], y: a.y[k], psi: a.psi[k], ranges, active: k < last };
        if (a.z) Object.assign(s, { z: a.z[k], phi: a.phi?.[k] ?? 0, theta: a.theta?.[k] ?? 0, altitude: a.altitude?.[k] ?? null });
        return s;
      });
    }
    return this.frame ? this.frame.agents : [];
  }

  time() {
    if (this.replay && this.step !== null) return [this.replay.time[this.step], this.replay.step[this.step]];
    return this.frame ? [this.frame.time, this.frame.step] : null;
  }

  drawBackground() {
    const st = this.static;
    const bg = offscreen(this.canvas.width, this.canvas.height);
    const ctx = bg.getContext("2d");
    const [x0, y0] = st.site.origin;
    const [lx, ly] = st.site.size;
    const [sx, sy] = this.px(x0 + lx, y0); // top-left of the site
    ctx.save();
    ctx.beginPath();
    ctx.rect(sx, sy, this.siteW, this.siteH);
    ctx.clip();
    ctx.fillStyle = "#0d1520";
    ctx.fillRect(sx, sy, this.siteW, this.siteH);
    const shade = this.seabedImage();
    if (shade) {
      ctx.imageSmoothingEnabled = true;
      ctx.imageSmoothingQuality = "high";
      const [ex0, ex1, ey0, ey1, dx, dy] = shade.extent;
      const [ax, ay] = this.px(ex1 + dx / 2, ey0 - dy / 2);
      ctx.drawImage(shade.canvas, ax, ay, (ey1 - ey0 + dy) * this.scale, (ex1 - ex0 + dx) * this.scale);
    }
    const obstacles = this.obstacleLayer();
    if (obstacles) ctx.drawImage(obstacles, 0, 0);
    ctx.restore();
    // site outline, axes, ticks
    ctx.strokeStyle = TEXT;
    ctx.lineWidth = 1;
    ctx.strokeRect(sx + 0.5, sy + 0.5, this.siteW - 1, this.siteH - 1);
    ctx.font = FONT;
    ctx.fillStyle = AXIS;
    ctx.strokeStyle = AXIS;
    const nTicks = this.compact ? 3 : 5;
    this.goalLabels = []; // boxes of the goal labels (3-D game), which depth labels keep clear of
    ctx.textAlign = "center";
    ctx.textBaseline = "top";
    for (const t of niceTicks(y0, y0 + ly, nTicks)) {
      const [px] = this.px(x0, t);
      ctx.beginPath();
      ctx.moveTo(px, sy + this.siteH);
      ctx.lineTo(px, sy + this.siteH + 4);
      ctx.stroke();
      ctx.fillText(tickText(t), px, sy + this.siteH + 6);
    }
    ctx.textAlign = "right";
    ctx.textBaseline = "middle";
    for (const t of niceTicks(x0, x0 + lx, nTicks)) {
      const [, py] = this.px(t, y0);
      ctx.beginPath();
      ctx.moveTo(sx - 4, py);
      ctx.lineTo(sx, py);
      ctx.stroke();
      ctx.fillText(tickText(t), sx - 6, py);
    }
    ctx.textAlign = "center";
    ctx.textBaseline = "bottom";
    ctx.fillText("east y [m]", sx + this.siteW / 2, this.canvas.height - 2);
    ctx.save();
    ctx.translate(10, sy + this.siteH / 2);
    ctx.rotate(-Math.PI / 2);
    ctx.textBaseline = "top";
    ctx.fillText("north x [m]", 0, 0);
    ctx.restore();
    if (!this.compact && shade) this.colourBar(ctx, sx + this.siteW + 14, sy, shade.range);
    this.northArrow(ctx, sx + this.siteW - 18, sy + 10);
    this.scaleBar(ctx, sx + 10, sy + this.siteH - 12);
    // what labels keep clear of besides each other (the caption's box: see draw)
    const bar = niceStep(st.site.size[1] / 5) * this.scale;
    this.furniture = [
      [sx + this.siteW - 31, sy + 8, 26, 26], // the north arrow
      [sx + 6, sy + this.siteH - 28, bar + 8, 22], // the scale bar
    ];
    for (const a of st.agents) {
      if (!a.goal) continue;
      const [gx, gy] = this.px(a.goal[0], a.goal[1]);
      ctx.strokeStyle = a.color;
      ctx.lineWidth = 1.5;
      ctx.setLineDash([3, 3]);
      ctx.beginPath();
      const rad = Math.max(3, (a.goal_radius || 1) * this.scale);
      ctx.arc(gx, gy, rad, 0, 2 * Math.PI);
      ctx.stroke();
      ctx.setLineDash([]);
      if (a.goal.length > 2 && Number.isFinite(a.goal[2])) {
        // 3-D game: the goal is a point at a depth
        ctx.fillStyle = a.color;
        ctx.font = FONT;
        ctx.textAlign = "left";
        ctx.textBaseline = "middle";
        const text = `goal z ${+a.goal[2].toFixed(1)} m`;
        ctx.fillText(text, gx + rad + 3, gy);
        this.goalLabels.push([gx + rad + 3, gy - 7, ctx.measureText(text).width, 14]);
      }
    }
    return bg;
  }

  /** The seabed mesh as a small shaded-relief image (one pixel per vertex), north row first. */
  seabedImage() {
    const t = this.static.terrain;
    const [mx, my] = t.shape;
    if (!(mx > 1 && my > 1) || t.vertices.length !== mx * my) return null;
    const z = (i, j) => t.vertices[i * my + j][2];
    let lo = Infinity, hi = -Infinity;
    for (const v of t.vertices) {
      if (v[2] >= 0) { lo = Math.min(lo, v[2]); hi = Math.max(hi, v[2]); }
    }
    if (!Number.isFinite(lo)) { lo = 0; hi = 1; }
    if (hi - lo < 1e-6) { lo -= 1; hi += 1; }
    const x00 = t.vertices[0][0], y00 = t.vertices[0][1];
    const dx = (t.vertices[(mx - 1) * my][0] - x00) / (mx - 1);
    const dy = (t.vertices[my - 1][1] - y00) / (my - 1);
    // relief: light from the north-west at 45 degrees, slopes exaggerated so the steep ones show
    const slopes = [];
    for (let i = 1; i < mx - 1; i += 2) {
      for (let j = 1; j < my - 1; j += 2) {
        slopes.push(Math.hypot((z(i + 1, j) - z(i - 1, j)) / (2 * dx), (z(i, j + 1) - z(i, j - 1)) / (2 * dy)));
      }
    }
    slopes.sort((a, b) => a - b);
    const steep = slopes.length ? slopes[Math.floor(0.95 * (slopes.length - 1))] : 0;
    const exag = steep > 0 ? Math.min(3, 0.3 / steep) : 1;
    const alt = Math.PI / 4;
    const L = [Math.cos(alt) * Math.SQRT1_2, -Math.cos(alt) * Math.SQRT1_2, Math.sin(alt)]; // north, east, up
    const c = offscreen(my, mx);
    const ctx = c.getContext("2d");
    const img = ctx.createImageData(my, mx);
    const land = rgbOf(DISPLAY.land_color);
    for (let i = 0; i < mx; i++) {
      for (let j = 0; j < my; j++) {
        const d = z(i, j);
        const gN = (z(Math.min(mx - 1, i + 1), j) - z(Math.max(0, i - 1), j)) / (2 * dx);
        const gE = (z(i, Math.min(my - 1, j + 1)) - z(i, Math.max(0, j - 1))) / (2 * dy);
        // the surface is -depth: its normal is (gN, gE, 1) scaled by the exaggeration
        const n = [gN * exag, gE * exag, 1];
        const norm = Math.hypot(n[0], n[1], n[2]);
        const lit = (n[0] * L[0] + n[1] * L[1] + n[2] * L[2]) / norm / L[2];
        const f = Math.min(1.25, Math.max(0.55, 0.35 + 0.65 * lit));
        const base = d < 0 ? land : depthRgb((d - lo) / (hi - lo));
        const p = 4 * ((mx - 1 - i) * my + j);
        img.data[p] = Math.min(255, base[0] * f);
        img.data[p + 1] = Math.min(255, base[1] * f);
        img.data[p + 2] = Math.min(255, base[2] * f);
        img.data[p + 3] = 255;
      }
    }
    ctx.putImageData(img, 0, 0);
    return { canvas: c, extent: [x00, x00 + dx * (mx - 1), y00, y00 + dy * (my - 1), dx, dy], range: [lo, hi] };
  }

  /**
   * The obstacles at the operating depth: the coarse cells' occupancy, interpolated bilinearly
   * to screen resolution and cut at one half, so outlines are smooth curves rather than blocks.
   */
  obstacleLayer() {
    const ob = this.static.obstacles;
    const rows = ob.rows;
    if (!rows.length || !rows.some((r) => r.includes("#"))) return null;
    const nx = rows.length;
    const ny = rows[0].length;
    const res = ob.coarse_resolution;
    const small = offscreen(ny + 2, nx + 2);
    const sctx = small.getContext("2d");
    const occ = sctx.createImageData(ny + 2, nx + 2);
    for (let i = 0; i < nx; i++) {
      for (let j = 0; j < ny; j++) {
        if (rows[i][j] !== "#") continue;
        const p = 4 * ((nx - i) * (ny + 2) + (j + 1)); // row 0 of the image is the north edge
        occ.data[p] = occ.data[p + 1] = occ.data[p + 2] = 255;
        occ.data[p + 3] = 255;
      }
    }
    sctx.putImageData(occ, 0, 0);
    const W = this.canvas.width, H = this.canvas.height;
    const big = offscreen(W, H);
    const bctx = big.getContext("2d");
    bctx.imageSmoothingEnabled = true;
    bctx.imageSmoothingQuality = "low"; // bilinear: no overshoot
    // the small image's pixel centres are the coarse cells' centres; it has one cell of padding
    const [ax, ay] = this.px(ob.extent[0] + (nx + 1) * res, ob.extent[2] - res);
    bctx.drawImage(small, ax, ay, (ny + 2) * res * this.scale, (nx + 2) * res * this.scale);
    const img = bctx.getImageData(0, 0, W, H);
    const d = img.data;
    const inside = new Uint8Array(W * H);
    for (let k = 0; k < W * H; k++) inside[k] = d[4 * k + 3] >= 128 ? 1 : 0;
    const fill = rgbOf(DISPLAY.obstacle_color);
    const edge = [52, 36, 20];
    for (let yy = 0; yy < H; yy++) {
      for (let xx = 0; xx < W; xx++) {
        const k = yy * W + xx;
        const p = 4 * k;
        if (!inside[k]) { d[p + 3] = 0; continue; }
        const border =
          (xx > 0 && !inside[k - 1]) || (xx < W - 1 && !inside[k + 1]) ||
          (yy > 0 && !inside[k - W]) || (yy < H - 1 && !inside[k + W]);
        const c = border ? edge : fill;
        d[p] = c[0]; d[p + 1] = c[1]; d[p + 2] = c[2]; d[p + 3] = border ? 255 : 235;
      }
    }
    bctx.putImageData(img, 0, 0);
    return big;
  }

  colourBar(ctx, x, y, [lo, hi]) {
    const rgb = (t) => {
      const c = depthRgb(t);
      return `rgb(${c[0] | 0},${c[1] | 0},${c[2] | 0})`;
    };
    const labels = [tickText(+lo.toFixed(0)), tickText(+hi.toFixed(0))];
    this.gradientBar(ctx, x, y, Math.min(160, this.siteH), rgb, labels, "depth");
  }

  /** A vertical colour bar of height h: colourAt(t) for t from 0 (top) to 1, two end labels, a name over "[m]". */
  gradientBar(ctx, x, y, h, colourAt, [top, bottom], name) {
    const w = 10;
    for (let k = 0; k < h; k++) {
      ctx.fillStyle = colourAt(k / (h - 1));
      ctx.fillRect(x, y + k, w, 1.5);
    }
    ctx.strokeStyle = AXIS;
    ctx.lineWidth = 1;
    ctx.strokeRect(x + 0.5, y + 0.5, w, h);
    ctx.font = FONT;
    ctx.fillStyle = AXIS;
    ctx.textAlign = "left";
    ctx.textBaseline = "middle";
    ctx.fillText(top, x + w + 3, y + 4);
    ctx.fillText(bottom, x + w + 3, y + h - 3);
    ctx.textBaseline = "top";
    ctx.fillText(name, x - 2, y + h + 4);
    ctx.fillText("[m]", x - 2, y + h + 17);
  }

  northArrow(ctx, x, y) {
    ctx.fillStyle = "rgba(13, 21, 32, 0.65)";
    ctx.beginPath();
    ctx.arc(x, y + 11, 13, 0, 2 * Math.PI);
    ctx.fill();
    ctx.fillStyle = TEXT;
    ctx.beginPath();
    ctx.moveTo(x, y + 2);
    ctx.lineTo(x + 5, y + 14);
    ctx.lineTo(x, y + 11);
    ctx.lineTo(x - 5, y + 14);
    ctx.closePath();
    ctx.fill();
    ctx.font = "bold 10px system-ui, sans-serif";
    ctx.textAlign = "center";
    ctx.textBaseline = "top";
    ctx.fillText("N", x, y + 14);
    ctx.font = FONT;
  }

  scaleBar(ctx, x, y) {
    const metres = niceStep(this.static.site.size[1] / 5);
    const len = metres * this.scale;
    ctx.fillStyle = "rgba(13, 21, 32, 0.65)";
    ctx.fillRect(x - 4, y - 16, len + 8, 22);
    ctx.strokeStyle = TEXT;
    ctx.lineWidth = 2;
    ctx.beginPath();
    ctx.moveTo(x, y - 4);
    ctx.lineTo(x, y);
    ctx.lineTo(x + len, y);
    ctx.lineTo(x + len, y - 4);
    ctx.stroke();
    ctx.lineWidth = 1;
    ctx.fillStyle = TEXT;
    ctx.textAlign = "center";
    ctx.textBaseline = "bottom";
    ctx.fillText(`${metres} m`, x + len / 2, y - 3);
  }

  /** True when the episode plays the 3-D game (vehicles that dive). */
  get is3d() {
    return this.static?.game === "3d";
  }

  /** One vehicle's sonar fan: a translucent coverage polygon and the beams coloured by range. */
  drawFan(ctx, a, info) {
    if (!a.ranges || !a.ranges.length) return;
    if (this.is3d && info.beam_elevations && Number.isFinite(a.z)) {
      this.drawFan3d(ctx, a, info);
      return;
    }
    const n = a.ranges.length;
    const maxR = info.max_range;
    const ends = a.ranges.map((r, k) => {
      const ang = a.psi + info.beam_angles[k];
      return [a.x + r * Math.cos(ang), a.y + r * Math.sin(ang)];
    });
    const [cx, cy] = this.px(a.x, a.y);
    ctx.fillStyle = info.color + "22";
    ctx.beginPath();
    const full = n > 2 && Math.abs(info.beam_angles[n - 1] - info.beam_angles[0]) > 1.5 * Math.PI;
    if (!full) ctx.moveTo(cx, cy);
    ends.forEach(([ex, ey], k) => {
      const [px, py] = this.px(ex, ey);
      if (k === 0 && full) ctx.moveTo(px, py);
      else ctx.lineTo(px, py);
    });
    ctx.closePath();
    ctx.fill();
    ctx.lineWidth = 1.6;
    a.ranges.forEach((r, k) => {
      const [px, py] = this.px(ends[k][0], ends[k][1]);
      const hit = r < HIT_FRACTION * maxR;
      ctx.strokeStyle = hit ? rangeColor(r / maxR) : "rgba(200, 215, 230, 0.22)";
      ctx.lineWidth = hit ? 1.8 : 1;
      ctx.beginPath();
      ctx.moveTo(cx, cy);
      ctx.lineTo(px, py);
      ctx.stroke();
      if (hit) {
        ctx.fillStyle = rangeColor(r / maxR);
        ctx.beginPath();
        ctx.arc(px, py, 2.4, 0, 2 * Math.PI);
        ctx.fill();
      }
    });
  }

  /**
   * A 3-D-game vehicle's sonar seen from above: every beam's end projected on the horizontal
   * plane (beamEnds3d, the frame's hit points). The level row's footprint is the translucent
   * polygon and its beams without an echo are faint lines; each beam with an echo is a ray to
   * its hit, coloured by range (the other rows' beams without an echo end at the surface or in
   * open water, and are left out).
   */
  drawFan3d(ctx, a, info) {
    const ends = beamEnds3d(a, info);
    const [cx, cy] = this.px(a.x, a.y);
    const level = ends.filter((e) => e.level);
    if (level.length > 2) {
      ctx.fillStyle = info.color + "22";
      ctx.beginPath();
      level.forEach((e, k) => {
        const [px, py] = this.px(e.x, e.y);
        if (k === 0) ctx.moveTo(px, py);
        else ctx.lineTo(px, py);
      });
      ctx.closePath();
      ctx.fill();
    }
    ctx.strokeStyle = "rgba(200, 215, 230, 0.22)";
    ctx.lineWidth = 1;
    for (const e of level) {
      if (e.hit) continue;
      const [px, py] = this.px(e.x, e.y);
      ctx.beginPath();
      ctx.moveTo(cx, cy);
      ctx.lineTo(px, py);
      ctx.stroke();
    }
    // far hits first, so the near (red) ones stay on top
    const hits = ends.filter((e) => e.hit).sort((p, q) => q.r - p.r);
    for (const e of hits) {
      const [px, py] = this.px(e.x, e.y);
      const c = rangeColor(e.r / info.max_range);
      ctx.strokeStyle = c;
      ctx.lineWidth = 1.8;
      ctx.beginPath();
      ctx.moveTo(cx, cy);
      ctx.lineTo(px, py);
      ctx.stroke();
      ctx.fillStyle = c;
      ctx.beginPath();
      ctx.arc(px, py, 2.4, 0, 2 * Math.PI);
      ctx.fill();
    }
  }

  /**
   * Each 3-D-game vehicle's depth beside its marker: "z 28.4 m", in its colour.
   *
   * Labels never overlap each other, a marker, a goal label or the chart's furniture (north
   * arrow, scale bar, caption: the boxes in `placed`), and stay inside the site. Each takes the
   * first free place of a search outward from its marker: rows beside it (right, then left; above,
   * then below), then farther columns. A label that is not next to its marker (vehicles close
   * together push it away) gets a leader line in its colour from the marker to it. Where no place
   * is free, the one that overlaps least.
   *
   * @param {CanvasRenderingContext2D} ctx
   * @param {Array<{name, x, y, z}>} agents the vehicles (those with a finite z are labelled)
   * @param {Map<string, {color: string}>} info each vehicle's static part
   * @param {Array<[number, number, number, number]>} placed boxes [x, y, w, h] to keep clear of;
   *   the labels' boxes are added
   * @returns {Array<{name, box: number[], leader: number[] | null}>} where each label went (and its
   *   leader line [x0, y0, x1, y1] [px]); kept as this.labels for tests
   */
  depthLabels(ctx, agents, info, placed) {
    ctx.font = FONT;
    const h = 14;
    const [sx, sy] = [this.ox, this.oy];
    const overlap = (x, y, w, b) =>
      Math.max(0, Math.min(x + w, b[0] + b[2]) - Math.max(x, b[0])) * Math.max(0, Math.min(y + h, b[1] + b[3]) - Math.max(y, b[1]));
    const labelled = agents.filter((a) => Number.isFinite(a.z));
    const marks = labelled.map((a) => this.px(a.x, a.y));
    // the distance [px] from a marker to a label's box, and whether a leader line from a marker to
    // a box passes by another marker (it would read as that one's)
    const gap = ([x, y, w], [mx, my]) => Math.hypot(Math.min(Math.max(mx, x), x + w) - mx, Math.min(Math.max(my, y), y + h) - my);
    const passes = (box, i) => {
      const [mx, my] = marks[i];
      const [nx, ny] = [Math.min(Math.max(mx, box[0]), box[0] + box[2]), Math.min(Math.max(my, box[1]), box[1] + h)];
      const len2 = (nx - mx) ** 2 + (ny - my) ** 2;
      if (len2 < 1) return false;
      return marks.some(([ox, oy], j) => {
        if (j === i) return false;
        const t = Math.max(0, Math.min(1, ((ox - mx) * (nx - mx) + (oy - my) * (ny - my)) / len2));
        return Math.hypot(mx + t * (nx - mx) - ox, my + t * (ny - my) - oy) < 8;
      });
    };
    // it reads as another's: nearer another vehicle than its own, unless a leader line joins it to
    // its own and the other is not right beside it; or its leader passes by another vehicle
    const misleads = (box, i, ring) => {
      const own = gap(box, marks[i]);
      const led = ring > 0 && own > 8;
      const nearer = marks.some((o, j) => j !== i && gap(box, o) < own + 2 && (!led || gap(box, o) < 16));
      return nearer || (led && passes(box, i));
    };
    const placeIn = (order) => {
      const taken = [...placed];
      const out = new Array(labelled.length);
      let score = 0;
      for (const i of order) {
        const a = labelled[i];
        const [px, py] = marks[i];
        const text = `z ${a.z.toFixed(1)} m`;
        const w = ctx.measureText(text).width + 4;
        const places = [];
        for (let col = 0; col < 3; col++) {
          for (let row = 0; row < (col ? 8 : 12); row++) {
            for (const side of [1, -1]) {
              const x = side > 0 ? px + 10 + col * (w + 6) : px - 10 - w - col * (w + 6);
              places.push([x, py - 17 - h * row, col + row], [x, py + 3 + h * row, col + row]);
            }
          }
        }
        places.sort((p, q) => p[2] - q[2]); // nearer rings first (stable: right before left, above before below)
        const inSite = ([x, y]) => x >= sx && x + w <= sx + this.siteW && y >= sy && y + h <= sy + this.siteH;
        const inside = places.filter(inSite);
        const cost = ([x, y]) => taken.reduce((sum, b) => sum + overlap(x, y, w, b), 0);
        const free = inside.filter((q) => cost(q) === 0);
        const clear = free.find((q) => !misleads([q[0], q[1], w], i, q[2]));
        const [x, y, ring] = clear || free[0] ||
          (inside.length ? inside.reduce((best, q) => (cost(q) < cost(best) ? q : best)) : places[0]);
        const box = [x, y, w, h];
        taken.push(box);
        score += (clear ? 0 : 1000) + (free.length ? 0 : 10000) + gap(box, marks[i]);
        // a label away from its marker: a line from the marker's edge to the label's nearest point
        let leader = null;
        if (ring > 0) {
          const [nx, ny] = [Math.min(Math.max(px, x), x + w), Math.min(Math.max(py, y), y + h)];
          const d = Math.hypot(nx - px, ny - py);
          if (d > 8) leader = [px + ((nx - px) * 6.5) / d, py + ((ny - py) * 6.5) / d, nx, ny];
        }
        out[i] = { name: a.name, text, color: info.get(a.name)?.color || "#fff", box, leader };
      }
      return { out, score, taken };
    };
    // vehicles close together: the order in which they take their places matters (the first takes
    // the nearest); a few orders are tried and the layout that misleads least, then the tightest, kept
    const idx = labelled.map((_, i) => i);
    const by = (f) => [...idx].sort((p, q) => f(p) - f(q));
    const orders = [idx, [...idx].reverse(), by((i) => marks[i][1]), by((i) => -marks[i][1]), by((i) => marks[i][0]), by((i) => -marks[i][0])];
    let best = null;
    for (const order of orders) {
      const r = placeIn(order);
      if (!best || r.score < best.score - 1e-9) best = r;
    }
    const out = best ? best.out : [];
    if (best) placed.splice(0, placed.length, ...best.taken);
    for (const l of out) {
      if (!l.leader) continue;
      // in its colour over a dark casing: it reads over sonar fans and tracks
      for (const [color, width] of [["rgba(13, 21, 32, 0.85)", 3.2], [l.color, 1.4]]) {
        ctx.strokeStyle = color;
        ctx.lineWidth = width;
        ctx.beginPath();
        ctx.moveTo(l.leader[0], l.leader[1]);
        ctx.lineTo(l.leader[2], l.leader[3]);
        ctx.stroke();
      }
    }
    for (const { box: [x, y, w], text, color } of out) {
      ctx.fillStyle = "rgba(13, 21, 32, 0.72)";
      ctx.fillRect(x, y, w, h);
      ctx.fillStyle = color;
      ctx.textAlign = "left";
      ctx.textBaseline = "middle";
      ctx.fillText(text, x + 2, y + 7.5);
    }
    return out;
  }

  draw() {
    const ctx = this.canvas.getContext("2d");
    ctx.setTransform(1, 0, 0, 1, 0, 0);
    ctx.clearRect(0, 0, this.canvas.width, this.canvas.height);
    const st = this.static;
    if (!st) return;
    ctx.drawImage(this.background, 0, 0);
    const info = new Map(st.agents.map((a) => [a.name, a]));
    const [sx, sy] = this.px(st.site.origin[0] + st.site.size[0], st.site.origin[1]);
    ctx.save();
    ctx.beginPath();
    ctx.rect(sx, sy, this.siteW, this.siteH);
    ctx.clip();
    const polyline = (xs, ys, upto, color, width, alpha = 1) => {
      if (upto < 1) return;
      ctx.globalAlpha = alpha;
      ctx.strokeStyle = color;
      ctx.lineWidth = width;
      ctx.beginPath();
      for (let k = 0; k <= upto; k++) {
        const [px, py] = this.px(xs[k], ys[k]);
        if (k === 0) ctx.moveTo(px, py);
        else ctx.lineTo(px, py);
      }
      ctx.stroke();
      ctx.globalAlpha = 1;
    };
    if (this.replay && this.step !== null) {
      const last = this.replay.step.length - 1;
      for (const a of this.replay.agents) {
        const c = info.get(a.name)?.color || "#fff";
        polyline(a.x, a.y, last, c, 1, 0.3); // the whole path, faint
        polyline(a.x, a.y, this.step, c, 2); // up to now
      }
    } else {
      for (const [name, pts] of this.trails) {
        polyline(pts.map((p) => p[0]), pts.map((p) => p[1]), pts.length - 1, info.get(name)?.color || "#fff", 2);
      }
    }
    const agents = this.current();
    if (this.sonar) for (const a of agents) if (info.has(a.name)) this.drawFan(ctx, a, info.get(a.name));
    for (const a of agents) {
      const [px, py] = this.px(a.x, a.y);
      const c = info.get(a.name)?.color || "#fff";
      ctx.fillStyle = c;
      ctx.strokeStyle = "#0d1520";
      ctx.lineWidth = 1.5;
      ctx.beginPath();
      ctx.arc(px, py, 5.5, 0, 2 * Math.PI);
      ctx.fill();
      ctx.stroke();
      // heading: psi clockwise from north; on screen north is up
      ctx.strokeStyle = c;
      ctx.lineWidth = 2.5;
      ctx.beginPath();
      ctx.moveTo(px, py);
      ctx.lineTo(px + 14 * Math.sin(a.psi), py - 14 * Math.cos(a.psi));
      ctx.stroke();
      if (a.active === false) {
        ctx.strokeStyle = "#fff";
        ctx.lineWidth = 1;
        ctx.beginPath();
        ctx.arc(px, py, 8.5, 0, 2 * Math.PI);
        ctx.stroke();
      }
    }
    this.drawCollisions(ctx, info);
    const now = this.time();
    ctx.font = FONT;
    const clock = now && !this.compact ? `t = ${now[0].toFixed(1)} s (step ${now[1]})` : "";
    const label = [this.caption, clock].filter(Boolean).join(" · ");
    this.labels = [];
    if (this.is3d) {
      // markers, goal labels and the chart's furniture are not to be covered by labels
      const placed = agents.map((a) => this.px(a.x, a.y)).map(([x, y]) => [x - 7, y - 7, 14, 14]);
      placed.push(...(this.goalLabels || []), ...(this.furniture || []));
      if (label) placed.push([sx + 4, sy + 4, ctx.measureText(label).width + 8, 17]);
      this.labels = this.depthLabels(ctx, agents, info, placed);
    }
    ctx.restore();
    ctx.font = FONT;
    ctx.textAlign = "left";
    ctx.textBaseline = "top";
    if (label) {
      const w = ctx.measureText(label).width;
      ctx.fillStyle = "rgba(13, 21, 32, 0.7)";
      ctx.fillRect(sx + 4, sy + 4, w + 8, 17);
      ctx.fillStyle = TEXT;
      ctx.fillText(label, sx + 8, sy + 7);
    }
    if (this.sonar && !this.compact) this.sonarBar(ctx, sx + this.siteW + 14, sy + Math.min(160, this.siteH) + 46);
  }

  /**
   * The sonar's range colours (palette.SONAR_RANGE_STOPS) under the depth bar, from an echo at
   * the vehicle (top) to one at the maximum range (bottom), while the fans are shown. Each echo's
   * colour is its range over its own vehicle's maximum range; the label gives that range in m
   * when every vehicle has the same, else "max".
   */
  sonarBar(ctx, x, y) {
    const h = Math.min(90, this.siteH - (y - this.oy) - 34);
    if (h < 30) return; // a short map: no room under the depth bar
    if (this.static.agents.every((a) => !(a.max_range > 0))) return; // no vehicle has a sonar
    const ranges = [...new Set(this.static.agents.map((a) => a.max_range))];
    const far = ranges.length === 1 ? tickText(+ranges[0].toFixed(0)) : "max";
    this.gradientBar(ctx, x, y, h, rangeColor, ["0", far], "sonar");
  }
}

const LINE_WIDTH = 1.7; // a plotted line [px]
const COINCIDE_PX = 2; // lines closer than this on screen coincide [px]
const SHARE_PX = 6; // where lines coincide, each is drawn in turn for this many pixel columns [px]
const SHARE_MIN_PX = 2 * SHARE_PX; // shorter coincidences (lines crossing) are drawn as crossings [px]

/** Every how many points a line of n points is drawn: at most ~2 points per pixel column. */
function pointStride(n, plotW) {
  return Math.max(1, Math.floor(n / (2 * plotW)));
}

/**
 * Where solid lines of one panel coincide on screen (closer than COINCIDE_PX, with the same time
 * points), so that the line drawn last would hide the others there. In such a stretch the lines
 * take turns: the pixel columns are cut into SHARE_PX-wide slots (counted from the plot's left
 * edge, the same for every line), and of g coinciding lines the one at place p in the group is
 * drawn in the slots whose number is p modulo g only. Every line keeps its width and its colour
 * (no band, no marker), and three pursuers at one depth show as one line dashed in their three
 * colours in turn.
 *
 * Groups are the lines whose screen heights at a point lie within COINCIDE_PX of a neighbour's
 * (sorted by height); a stretch is the run of points over which a line's group stays the same, so
 * all lines of a group have the same stretches. Stretches narrower than SHARE_MIN_PX are lines
 * crossing, drawn as they are.
 *
 * @param {Array<{xs, ys, dash?, fill?}>} series
 * @param {(x: number) => number} X the panel's data-to-screen map of x [px]
 * @param {(y: number) => number} Y the panel's data-to-screen map of y [px]
 * @param {number} plotW the plot's width [px] (lines are compared at ~2 points per pixel column)
 * @returns {Map<object, Array<{x0: number, x1: number, place: number, size: number}>>} for each
 *   series that shares, its stretches: from x0 to x1 [px] it is drawn in the slots of its place.
 */
export function sharedRuns(series, X, Y, plotW) {
  const solid = series.filter((s) => !s.dash && !s.fill && s.xs.length > 1);
  const out = new Map();
  const done = new Set();
  for (const s of solid) {
    if (done.has(s)) continue;
    const n = s.xs.length;
    const sameTimes = (o) => o.xs === s.xs || (o.xs.length === n && o.xs[0] === s.xs[0] && o.xs[n - 1] === s.xs[n - 1]);
    const lines = solid.filter((o) => !done.has(o) && sameTimes(o));
    lines.forEach((o) => done.add(o));
    if (lines.length < 2) continue;
    const stride = pointStride(n, plotW);
    const ks = [];
    for (let k = 0; k < n; k += stride) ks.push(k);
    if (ks[ks.length - 1] !== n - 1) ks.push(n - 1);
    // each line's group at each point: the indices (in `lines`) of the lines it coincides with
    const keys = lines.map(() => new Array(ks.length).fill(""));
    ks.forEach((k, j) => {
      const at = [];
      lines.forEach((o, i) => {
        const y = o.ys[k];
        if (Number.isFinite(y) && Number.isFinite(o.xs[k])) at.push([Y(y), i]);
      });
      at.sort((a, b) => a[0] - b[0]);
      for (let a = 0; a < at.length; ) {
        let b = a;
        while (b + 1 < at.length && at[b + 1][0] - at[b][0] < COINCIDE_PX) b += 1;
        if (b > a) {
          const members = at.slice(a, b + 1).map((m) => m[1]).sort((u, v) => u - v);
          const key = members.join(",");
          for (const i of members) keys[i][j] = key;
        }
        a = b + 1;
      }
    });
    lines.forEach((o, i) => {
      const runs = [];
      for (let j = 0; j < ks.length; ) {
        const key = keys[i][j];
        let e = j;
        while (e + 1 < ks.length && keys[i][e + 1] === key) e += 1;
        if (key) {
          const [x0, x1] = [X(o.xs[ks[j]]), X(o.xs[ks[e]])];
          const members = key.split(",").map(Number);
          if (x1 - x0 >= SHARE_MIN_PX) runs.push({ x0, x1, place: members.indexOf(i), size: members.length });
        }
        j = e + 1;
      }
      if (runs.length) out.set(o, runs);
    });
  }
  return out;
}

/**
 * Line plots on one canvas, in panels stacked vertically that share the time axis.
 *
 * A panel may set flip (y grows downward, as depth does), ymin (the y axis starts exactly there,
 * e.g. the surface at depth 0). A series may set dash, fill (a colour filled from the line to the
 * panel's lower edge on screen, e.g. the seabed) and may be legend-only (no points).
 *
 * @param {HTMLCanvasElement} canvas
 * @param {Array<{title: string, ylabel?: string, series: Array<{label, color, xs, ys, dash?, fill?}>,
 *   hline?: {y: number, label: string}, flip?: boolean, ymin?: number}>} panels
 * @param {{xlabel?: string, cursor?: number|null, empty?: string}} options cursor: a time [s] marked by a vertical line.
 * @returns {Array<{left, right, top, bottom, x0, x1, y0, y1, flip}>|null} each panel's plot area
 *   [px] and the data range it shows (null with no data): where a value is drawn.
 */
export function panelChart(canvas, panels, options = {}) {
  const ctx = canvas.getContext("2d");
  ctx.setTransform(1, 0, 0, 1, 0, 0);
  ctx.clearRect(0, 0, canvas.width, canvas.height);
  ctx.font = FONT;
  const W = canvas.width;
  const H = canvas.height;
  // one legend for the whole canvas (series of every panel, each label once), wrapped as needed
  const legend = [];
  const seen = new Set();
  for (const p of panels) {
    for (const s of p.series) {
      if (!s.label || seen.has(s.label)) continue;
      seen.add(s.label);
      legend.push(s);
    }
  }
  const lines = [];
  let line = [];
  let lw = 0;
  for (const s of legend) {
    const w = ctx.measureText(s.label).width + 30;
    if (line.length && lw + w > W - 60) {
      lines.push(line);
      line = [];
      lw = 0;
    }
    line.push([s, lw]);
    lw += w;
  }
  if (line.length) lines.push(line);
  const legendH = 16 * lines.length + 2;
  lines.forEach((items, row) => {
    const y = 10 + 16 * row;
    for (const [s, x0] of items) {
      const x = 60 + x0;
      ctx.strokeStyle = s.color;
      ctx.lineWidth = 2.5;
      ctx.setLineDash(s.dash || []);
      ctx.beginPath(); ctx.moveTo(x, y); ctx.lineTo(x + 18, y); ctx.stroke();
      ctx.setLineDash([]);
      ctx.fillStyle = TEXT;
      ctx.textAlign = "left";
      ctx.textBaseline = "middle";
      ctx.fillText(s.label, x + 22, y);
    }
  });
  const m = { l: 60, r: 14, b: 36, t: legendH };
  const gap = 20;
  const ph = (H - m.t - m.b - gap * panels.length) / Math.max(1, panels.length);
  let x0 = Infinity, x1 = -Infinity;
  for (const p of panels) for (const s of p.series) for (const x of s.xs) if (Number.isFinite(x)) { x0 = Math.min(x0, x); x1 = Math.max(x1, x); }
  if (!Number.isFinite(x0)) {
    ctx.fillStyle = AXIS;
    ctx.textAlign = "left";
    ctx.textBaseline = "bottom";
    panels.forEach((p, i) => ctx.fillText(p.title, m.l, m.t + gap * (i + 1) + ph * i - 4));
    ctx.textAlign = "center";
    ctx.fillText(options.empty || "no data yet", W / 2, H / 2);
    return null;
  }
  if (x1 === x0) x1 = x0 + 1;
  // endDots: a dot marks each line's last point, a little inside the frame's right edge (a jump
  // at the last step, as a capture's +900, would otherwise be a stroke on the frame itself)
  if (options.endDots) x1 += 0.02 * (x1 - x0);
  const X = (x) => m.l + ((x - x0) / (x1 - x0)) * (W - m.l - m.r);
  const areas = [];
  panels.forEach((p, i) => {
    const top = m.t + gap * (i + 1) + ph * i;
    const bottom = top + ph;
    let y0 = Infinity, y1 = -Infinity;
    for (const s of p.series) for (const y of s.ys) if (Number.isFinite(y)) { y0 = Math.min(y0, y); y1 = Math.max(y1, y); }
    if (p.hline) { y0 = Math.min(y0, p.hline.y); y1 = Math.max(y1, p.hline.y); }
    if (!Number.isFinite(y0)) { y0 = 0; y1 = 1; }
    if (y1 === y0) { y1 += 1; y0 -= 1; }
    const pad = 0.06 * (y1 - y0);
    y0 -= pad; y1 += pad;
    if (Number.isFinite(p.ymin)) { y0 = p.ymin; if (!(y1 > y0)) y1 = y0 + 1; }
    const Y = p.flip ? (y) => top + ((y - y0) / (y1 - y0)) * ph : (y) => bottom - ((y - y0) / (y1 - y0)) * ph;
    areas.push({ left: m.l, right: W - m.r, top, bottom, x0, x1, y0, y1, flip: !!p.flip });
    ctx.strokeStyle = GRID;
    ctx.fillStyle = AXIS;
    ctx.lineWidth = 1;
    ctx.textAlign = "right";
    ctx.textBaseline = "middle";
    for (const t of niceTicks(y0, y1, Math.max(3, Math.round(ph / 35)))) {
      ctx.beginPath(); ctx.moveTo(m.l, Y(t)); ctx.lineTo(W - m.r, Y(t)); ctx.stroke();
      ctx.fillText(tickText(t), m.l - 5, Y(t));
    }
    for (const t of niceTicks(x0, x1, 6)) {
      ctx.beginPath(); ctx.moveTo(X(t), top); ctx.lineTo(X(t), bottom); ctx.stroke();
    }
    ctx.strokeStyle = AXIS;
    ctx.strokeRect(m.l + 0.5, top + 0.5, W - m.l - m.r - 1, ph);
    // the panel's title above it
    ctx.textAlign = "left";
    ctx.textBaseline = "bottom";
    ctx.fillStyle = TEXT;
    ctx.fillText(p.title, m.l, top - 4);
    if (p.hline) {
      ctx.strokeStyle = "#e0a43a";
      ctx.setLineDash([4, 4]);
      ctx.lineWidth = 1;
      ctx.beginPath(); ctx.moveTo(m.l, Y(p.hline.y)); ctx.lineTo(W - m.r, Y(p.hline.y)); ctx.stroke();
      ctx.setLineDash([]);
      ctx.fillStyle = "#e0a43a";
      ctx.textAlign = "right";
      ctx.fillText(p.hline.label || "", W - m.r - 4, Y(p.hline.y) - 2);
    }
    ctx.save();
    ctx.beginPath();
    ctx.rect(m.l, top, W - m.l - m.r, ph);
    ctx.clip();
    for (const s of p.series) {
      if (!s.fill || s.xs.length < 2) continue;
      // the area between the line and the panel's lower edge on screen
      ctx.fillStyle = s.fill;
      ctx.beginPath();
      let first = null, lastX = null;
      for (let k = 0; k < s.xs.length; k++) {
        const x = s.xs[k], y = s.ys[k];
        if (!Number.isFinite(x) || !Number.isFinite(y)) continue;
        if (first === null) { first = X(x); ctx.moveTo(first, bottom); }
        ctx.lineTo(X(x), Y(y));
        lastX = X(x);
      }
      if (first !== null) { ctx.lineTo(lastX, bottom); ctx.closePath(); ctx.fill(); }
    }
    // where solid lines coincide, they take turns slot by slot (sharedRuns): each line is
    // clipped away from the slots of the others, so each shows in its own colour, none hidden
    const shared = sharedRuns(p.series, X, Y, W - m.l - m.r);
    ctx.lineJoin = "round"; // no miter spikes where a line turns sharply (a step of a running sum)
    for (const s of p.series) {
      const runs = shared.get(s);
      if (runs) {
        // the plot area less the others' slots (rectangles that do not overlap: the even-odd
        // rule cuts them out of the area)
        ctx.save();
        ctx.beginPath();
        ctx.rect(m.l, top, W - m.l - m.r, ph);
        for (const { x0, x1, place, size } of runs) {
          for (let c = Math.floor((x0 - m.l) / SHARE_PX); m.l + c * SHARE_PX < x1; c++) {
            if (((c % size) + size) % size === place) continue;
            const a = Math.max(x0, m.l + c * SHARE_PX);
            const b = Math.min(x1, m.l + (c + 1) * SHARE_PX);
            if (b > a) ctx.rect(a, top, b - a, ph);
          }
        }
        ctx.clip("evenodd");
      }
      ctx.strokeStyle = s.color;
      ctx.lineWidth = LINE_WIDTH;
      ctx.setLineDash(s.dash || []);
      ctx.beginPath();
      let started = false;
      const stride = pointStride(s.xs.length, W - m.l - m.r);
      for (let k = 0; k < s.xs.length; k += stride) {
        const x = s.xs[k], y = s.ys[k];
        if (!Number.isFinite(x) || !Number.isFinite(y)) { started = false; continue; }
        if (!started) { ctx.moveTo(X(x), Y(y)); started = true; } else ctx.lineTo(X(x), Y(y));
      }
      const k = s.xs.length - 1;
      if (started && k % stride !== 0 && Number.isFinite(s.ys[k])) ctx.lineTo(X(s.xs[k]), Y(s.ys[k]));
      ctx.stroke();
      ctx.setLineDash([]);
      if (runs) ctx.restore();
    }
    ctx.lineJoin = "miter";
    if (options.endDots) {
      // each line's last point as a dot in its colour (outlined: it reads over other lines)
      for (const s of p.series) {
        let k = s.xs.length - 1;
        while (k >= 0 && !(Number.isFinite(s.xs[k]) && Number.isFinite(s.ys[k]))) k--;
        if (k < 0) continue;
        ctx.fillStyle = s.color;
        ctx.strokeStyle = "#0d1520";
        ctx.lineWidth = 1;
        ctx.beginPath();
        ctx.arc(X(s.xs[k]), Y(s.ys[k]), 3.5, 0, 2 * Math.PI);
        ctx.fill();
        ctx.stroke();
      }
    }
    for (const mark of options.marks || []) {
      // an event: a dotted vertical line in every panel, its text in the first one
      if (!(mark.t >= x0 && mark.t <= x1)) continue;
      ctx.strokeStyle = mark.color || "#e0a43a";
      ctx.lineWidth = 1;
      ctx.setLineDash([1, 3]);
      ctx.beginPath(); ctx.moveTo(X(mark.t), top); ctx.lineTo(X(mark.t), bottom); ctx.stroke();
      ctx.setLineDash([]);
    }
    if (Number.isFinite(options.cursor)) {
      ctx.strokeStyle = "#ffffff";
      ctx.lineWidth = 1;
      ctx.setLineDash([2, 2]);
      ctx.beginPath(); ctx.moveTo(X(options.cursor), top); ctx.lineTo(X(options.cursor), bottom); ctx.stroke();
      ctx.setLineDash([]);
    }
    ctx.restore();
    if (p.ylabel) {
      ctx.save();
      ctx.fillStyle = AXIS;
      ctx.translate(3, top + ph / 2);
      ctx.rotate(-Math.PI / 2);
      ctx.textAlign = "center";
      ctx.textBaseline = "top";
      ctx.fillText(p.ylabel, 0, 0);
      ctx.restore();
    }
  });
  // the events' texts along the top of the first panel, one row each where they would overlap
  if (areas.length && options.marks?.length) {
    const a = areas[0];
    const Xa = (x) => a.left + ((x - a.x0) / (a.x1 - a.x0)) * (a.right - a.left);
    const rows = [];
    ctx.font = SMALL_FONT;
    ctx.textAlign = "left";
    ctx.textBaseline = "top";
    const boxes = [];
    for (const mark of options.marks) {
      if (!(mark.t >= a.x0 && mark.t <= a.x1)) continue;
      const w = ctx.measureText(mark.label).width + 4;
      const x = Math.min(a.right - w - 1, Xa(mark.t) + 2);
      let row = 0;
      while (rows[row] !== undefined && rows[row] > x - 2) row++;
      rows[row] = x + w;
      const y = a.top + 2 + 12 * row;
      ctx.fillStyle = "rgba(13, 21, 32, 0.8)";
      ctx.fillRect(x, y, w, 12);
      ctx.fillStyle = mark.color || "#e0a43a";
      ctx.fillText(mark.label, x + 2, y + 1);
      boxes.push({ label: mark.label, t: mark.t, box: [x, y, w, 12] });
    }
    areas.marks = boxes;
    ctx.font = FONT;
  }
  // the shared time axis under the last panel, labels kept inside the canvas
  const bottom = H - m.b;
  ctx.fillStyle = AXIS;
  ctx.textBaseline = "top";
  for (const t of niceTicks(x0, x1, 6)) {
    const text = tickText(t);
    const w = ctx.measureText(text).width;
    const x = Math.min(W - 2 - w / 2, Math.max(w / 2 + 2, X(t)));
    ctx.textAlign = "center";
    ctx.fillText(text, x, bottom + 4);
  }
  ctx.textAlign = "center";
  ctx.fillText(options.xlabel || "", m.l + (W - m.l - m.r) / 2, bottom + 19);
  return areas;
}

/** A single-panel line plot: series = [{label, color, xs, ys}], options {title, ylabel, xlabel, hline, cursor, flip, ymin}. */
export function lineChart(canvas, series, options = {}) {
  const { title = "", ylabel, hline, flip, ymin } = options;
  return panelChart(canvas, [{ title, ylabel, series, hline, flip, ymin }], options);
}
