// The hptvsim dashboard: create, run, watch and cancel episodes; scrub finished ones; compare
// episodes on one timeline; browse the episode list.
// Talks to the service's REST API under /api/v1 and its server-sent events; live data follow the
// frame schema (frames.gen.js, generated from hptvsim/episodes/frames.py) and are checked against it.

import { validate, VERSION } from "./schema.js";
import { TopDownMap, panelChart, lineChart, rangeColor, EPISODE_COLORS, EPISODE_DASHES } from "./draw.js";

const API = "/api/v1";
const ACTIVE = new Set(["queued", "running"]);
const $ = (id) => document.getElementById(id);

/** Everything the page knows; exposed as window.hptvsim for tests and curious users. */
const state = {
  config: null,
  scenarios: [],
  policies: [],
  episodes: [],
  current: null, // {id, static, series, traj, es, status, episode}
  compare: null, // {items: [{id, episode, static, traj, map}], t: [s], playing}
  compareIds: new Set(),
  schemaErrors: [],
  framesSeen: 0,
  lastFrame: null,
};
window.hptvsim = state;

// --- the API ----------------------------------------------------------------------------------

// The API key lives in this tab's session storage (gone when the tab closes, never shared with
// other tabs or written to disk by the browser's local storage) and travels only in the X-API-Key
// header: never in an address, where browser history, proxies and access logs would keep it.
const KEY_NAME = "hptvsim-api-key";
if (localStorage.getItem(KEY_NAME) !== null) {
  // an earlier dashboard kept the key in local storage: move it to this session, and forget it there
  sessionStorage.setItem(KEY_NAME, localStorage.getItem(KEY_NAME));
  localStorage.removeItem(KEY_NAME);
}

function apiKey() {
  return sessionStorage.getItem(KEY_NAME) || "";
}

function keyHeaders(extra = {}) {
  const key = apiKey();
  return key ? { ...extra, "X-API-Key": key } : { ...extra };
}

/**
 * Server-sent events read with fetch, so the key goes in a header (EventSource cannot send one).
 * Like EventSource it reconnects after the server's `retry` when a stream ends, and it waits the
 * server's Retry-After when the service is busy (429/503). `addEventListener(name, fn)` sets the
 * function of `{data}` an event calls; `onClosed(reason)` is called once it stops for good (an
 * HTTP error such as a wrong key).
 */
function openEvents(url, onClosed) {
  const abort = new AbortController();
  const handlers = {};
  const stream = {
    closed: false,
    close() { this.closed = true; abort.abort(); },
    addEventListener(name, fn) { handlers[name] = fn; },
  };
  const dispatch = (block) => {
    let event = "message";
    const data = [];
    for (const line of block.split(/\r?\n/)) {
      if (!line || line.startsWith(":")) continue;
      const at = line.indexOf(":");
      const field = at < 0 ? line : line.slice(0, at);
      const value = at < 0 ? "" : line.slice(at + 1).replace(/^ /, "");
      if (field === "event") event = value;
      else if (field === "data") data.push(value);
      else if (field === "retry" && /^\d+$/.test(value)) retry = Number(value);
    }
    if (data.length && handlers[event] && !stream.closed) handlers[event]({ data: data.join("\n") });
  };
  let retry = 2000;
  (async () => {
    while (!stream.closed) {
      let wait = retry;
      try {
        const res = await fetch(url, { headers: keyHeaders({ Accept: "text/event-stream" }), signal: abort.signal, cache: "no-store" });
        if (res.status === 429 || res.status === 503) {
          wait = 1000 * Math.max(1, Number(res.headers.get("Retry-After")) || 2);
        } else if (!res.ok) {
          stream.closed = true;
          if (onClosed) onClosed(`HTTP ${res.status}`);
          return;
        } else {
          const reader = res.body.pipeThrough(new TextDecoderStream()).getReader();
          let buf = "";
          for (;;) {
            const { value, done } = await reader.read();
            if (done) break;
            buf += value;
            for (let m = buf.match(/\r?\n\r?\n/); m; m = buf.match(/\r?\n\r?\n/)) {
              dispatch(buf.slice(0, m.index));
              buf = buf.slice(m.index + m[0].length);
            }
          }
        }
      } catch (err) {
        if (stream.closed) return;
      }
      if (stream.closed) return;
      await new Promise((ok) => setTimeout(ok, wait));
    }
  })();
  return stream;
}

/** Save a file the API serves, sending the key in its header (a plain link could not). */
async function download(url, name) {
  const res = await fetch(url, { headers: keyHeaders() });
  if (!res.ok) throw new Error(`${name}: HTTP ${res.status}`);
  const blobUrl = URL.createObjectURL(await res.blob());
  const a = document.createElement("a");
  a.href = blobUrl;
  a.download = name;
  document.body.append(a);
  a.click();
  a.remove();
  setTimeout(() => URL.revokeObjectURL(blobUrl), 60_000);
}

async function api(path, options = {}) {
  const headers = keyHeaders({ Accept: "application/json", ...(options.headers || {}) });
  if (options.body !== undefined) headers["Content-Type"] = "application/json";
  const res = await fetch(API + path, {
    ...options,
    headers,
    body: options.body === undefined ? undefined : JSON.stringify(options.body),
  });
  if (res.status === 204) return null;
  let data = null;
  try {
    data = await res.json();
  } catch {
    data = null;
  }
  if (!res.ok) {
    const detail = data?.detail || res.statusText;
    const fields = (data?.errors || []).map((e) => `${e.field}: ${e.message}`).join("\n");
    const err = new Error(fields && !String(detail).includes(fields) ? `${detail}\n${fields}` : String(detail));
    err.status = res.status;
    throw err;
  }
  return data;
}

function checkSchema(kind, data) {
  const errors = validate(kind, data);
  if (errors.length) {
    state.schemaErrors.push(...errors.slice(0, 5));
    console.warn(`frame schema: ${kind} does not conform`, errors);
  }
  $("schema-state").textContent = state.schemaErrors.length
    ? ` (${state.schemaErrors.length} values did not: see the browser console)`
    : "";
  return data;
}

function withoutEpisode(data) {
  const { episode, ...rest } = data;
  return rest;
}

// --- setup: config, scenarios, policies -------------------------------------------------------

async function loadConfig() {
  try {
    state.config = await api("/config");
    $("service-state").textContent = `service ${state.config.version || ""} up`;
    $("footer-version").textContent = `hptvsim ${state.config.version || ""}`;
    $("service-state").className = "pill ok";
    $("key-box").hidden = !state.config.auth;
    if (state.config.viser_url) {
      $("link-viser").href = state.config.viser_url; // the live view asks for the key itself
      $("link-viser").hidden = false;
    }
    if (state.config.limits?.max_steps) $("f-max-steps").max = state.config.limits.max_steps;
  } catch (err) {
    $("service-state").textContent = err.status === 401 ? "API key needed" : "service unreachable";
    $("service-state").className = "pill bad";
    $("key-box").hidden = err.status !== 401;
    throw err;
  }
}

function option(value, text = value) {
  const o = document.createElement("option");
  o.value = value;
  o.textContent = text;
  return o;
}

/** The game a scenario plays ("planar" or "3d"; scenarios listed by an older service: planar). */
function gameOf(name) {
  return state.scenarios.find((s) => s.name === name)?.game || "planar";
}

/** A scenario's name as the choosers show it: 3-D scenarios are tagged. */
function scenarioText(s) {
  return s.game === "3d" ? `${s.name} · 3-D` : s.name;
}

/** A small tag that marks a 3-D scenario or episode. */
function tag3d() {
  const t = document.createElement("span");
  t.className = "tag game-3d";
  t.textContent = "3-D";
  t.title = "the 3-D game: vehicles that dive";
  return t;
}

async function loadChoices() {
  state.scenarios = await api("/scenarios");
  state.policies = await api("/policies");
  const sel = $("f-scenario");
  sel.replaceChildren(...state.scenarios.map((s) => option(s.name, scenarioText(s))));
  sel.value = state.scenarios.some((s) => s.name === "target") ? "target" : state.scenarios[0]?.name;
  $("filter-scenario").replaceChildren(option("", "any"), ...state.scenarios.map((s) => option(s.name, scenarioText(s))));
  $("filter-policy").replaceChildren(option("", "any"), ...state.policies.map((p) => option(p.name)));
  showScenario(true);
}

/**
 * Offer for each role only the policies that play the scenario's game (`games` of GET /policies;
 * a policy listed without it plays every game), keeping a choice that still fits.
 */
function fillPolicies(game) {
  for (const [role, id] of [["pursuer", "f-pursuer-policy"], ["evader", "f-evader-policy"]]) {
    const sel = $(id);
    const keep = sel.value;
    const fits = state.policies.filter((p) => p.roles.includes(role) && (!p.games || p.games.includes(game)));
    sel.replaceChildren(...fits.map((p) => option(p.name)));
    if (fits.some((p) => p.name === keep)) sel.value = keep;
  }
}

const previewMap = new TopDownMap($("scenario-canvas"), { compact: true });
state.previewMap = previewMap; // for tests: where its labels went (previewMap.labels)
const previews = new Map();

/** The scenario's description, its map (drawn like the episode map) and its default policies. */
async function showScenario(setDefaults = true) {
  const s = state.scenarios.find((x) => x.name === $("f-scenario").value);
  if (!s) return;
  const n = s.agents.length;
  const roles = Object.values(s.roles || {});
  const p = roles.filter((r) => r === "pursuer").length;
  const text =
    `${s.description || ""} ${s.task} task, ${s.site_size[0]} m × ${s.site_size[1]} m, ` +
    `${p} pursuer(s) and ${n - p} evader(s), dt ${s.dt} s, up to ${s.max_steps} steps.`;
  $("scenario-info").replaceChildren(...(s.game === "3d" ? [tag3d(), " "] : []), text);
  $("f-max-steps").placeholder = `scenario's (${s.max_steps})`;
  fillPolicies(s.game || "planar");
  if (setDefaults && s.default_policies) {
    // the service's defaults (hptvsim.zoo.default_policy): the shipped trained policies
    for (const [role, id] of [["pursuer", "f-pursuer-policy"], ["evader", "f-evader-policy"]]) {
      const want = s.default_policies[role];
      if ([...$(id).options].some((o) => o.value === want)) $(id).value = want;
    }
  }
  const legend = $("scenario-legend");
  legend.replaceChildren(
    ...s.agents.map((a) => {
      const span = document.createElement("span");
      span.className = "key";
      span.style.setProperty("--c", s.colors[a]);
      span.textContent = a;
      return span;
    }),
  );
  try {
    let pv = previews.get(s.name);
    if (!pv) {
      pv = await api(`/scenarios/${encodeURIComponent(s.name)}/preview`);
      previews.set(s.name, pv);
    }
    if ($("f-scenario").value !== s.name) return;
    previewMap.setStatic(checkSchema("EpisodeStatic", pv.static));
    previewMap.caption = "spawn poses";
    previewMap.showFrame(checkSchema("Frame", pv.frame));
  } catch (err) {
    $("scenario-info").append(` (no map: ${err.message})`);
  }
}

// --- creating and cancelling ------------------------------------------------------------------

async function createEpisode(ev) {
  ev.preventDefault();
  $("form-error").textContent = "";
  const scenario = state.scenarios.find((x) => x.name === $("f-scenario").value);
  const policies = {};
  for (const agent of scenario.agents) {
    const role = scenario.roles[agent];
    policies[agent] = role === "pursuer" ? $("f-pursuer-policy").value : $("f-evader-policy").value;
  }
  const body = {
    scenario: scenario.name,
    policies,
    seed: Number($("f-seed").value || 0),
    backend: $("f-backend").value,
    record: $("f-record").checked,
    label: $("f-label").value,
  };
  if ($("f-max-steps").value) body.max_steps = Number($("f-max-steps").value);
  if ($("f-fidelity").value) body.sensor_fidelity = $("f-fidelity").value;
  $("run-button").disabled = true;
  try {
    const ep = await api("/episodes", { method: "POST", body });
    await refreshList();
    watch(ep);
  } catch (err) {
    $("form-error").textContent = err.message;
  } finally {
    $("run-button").disabled = false;
  }
}

async function cancelCurrent() {
  if (!state.current) return;
  try {
    await api(`/episodes/${state.current.id}/cancel`, { method: "POST" });
  } catch (err) {
    if (state.current) setStatus(state.current.status, `cannot cancel: ${err.message}`);
  }
}

// --- series for the plots --------------------------------------------------------------------

const TERMS = [
  ["r_C", "Σ r_C, obstacle within the safe distance (Eq. 17)"],
  ["r_E1", "Σ r_E1, closing on the target (Eq. 18)"],
  ["r_E2", "Σ r_E2, target within capture distance (Eq. 19)"],
];
const WEIGHT = { r_C: "delta_C", r_E1: "delta_E1", r_E2: "delta_E2" }; // [task.reward]'s weight of each term
const DELTA = { r_C: "δ_C", r_E1: "δ_E1", r_E2: "δ_E2" };

const weightsOf = new Map(); // scenario name -> its [task.reward] (GET /scenarios/{name}), or null

/**
 * The reward weights (delta_C, delta_E1, delta_E2 of Eq. 20) of a shipped scenario's episodes,
 * from its tables; null where the service has no such scenario (a twin episode, an inline one).
 */
async function scenarioWeights(name) {
  if (!weightsOf.has(name)) {
    let w = null;
    if (state.scenarios.some((s) => s.name === name)) {
      try {
        w = (await api(`/scenarios/${encodeURIComponent(name)}`))?.task?.reward || null;
      } catch {
        w = null;
      }
    }
    weightsOf.set(name, w);
  }
  return weightsOf.get(name);
}

/** Whether one step's reward is the weighted sum of its terms (Eq. 20; a crash's penalty and an agent done, with reward 0, aside). */
function rewardFits(w, a, k) {
  const sum = w.delta_C * a.r_C[k] + w.delta_E1 * a.r_E1[k] + w.delta_E2 * a.r_E2[k];
  const r = a.reward[k];
  const close = (x, y) => Math.abs(x - y) <= 1e-6 * (1 + Math.abs(x) + Math.abs(y));
  return close(r, sum) || r === 0 || close(r, sum - (w.crash_penalty || 0));
}

function newSeries(st) {
  const per = () => new Map(st.agents.map((a) => [a.name, []]));
  // depth and seabed (depth z + altitude) [m]: 3-D game only; speeds [m/s] and attitude [deg]: a
  // real vehicle's log (twin episodes); misfit: steps whose reward is not Eq. 20 of the weights
  return {
    t: [], distance: per(), terms: { r_C: per(), r_E1: per(), r_E2: per() }, hasTerms: true, depth: per(), seabed: per(),
    speed: per(), heave: per(), roll: per(), pitch: per(), weights: null, misfit: 0, checked: 0,
    heading: new Map(st.agents.map((a) => [a.name, { xs: [], ys: [] }])), // [deg], its own times (gaps where it wraps)
  };
}

const DEG = 180 / Math.PI;

/** Heading [deg] in [0, 360), NaN where it wraps (no line across the plot from 359 to 0). */
function headingDeg(psi, prev) {
  const h = (((psi * DEG) % 360) + 360) % 360;
  return prev !== undefined && Number.isFinite(prev) && Math.abs(h - prev) > 180 ? [NaN, h] : [h];
}

/** The speeds and attitude of one vehicle's row (or frame) k, appended to the series. */
function addMotion(s, name, u, v, w, phi, theta, psi) {
  s.speed.get(name)?.push(Math.hypot(u, v));
  s.heave.get(name)?.push(Number.isFinite(w) ? w : NaN);
  s.roll.get(name)?.push(Number.isFinite(phi) ? phi * DEG : NaN);
  s.pitch.get(name)?.push(Number.isFinite(theta) ? theta * DEG : NaN);
}

/** Series of a finished episode's trajectories: distances and the running sums of the terms. */
function seriesOfTrajectory(st, traj) {
  const s = newSeries(st);
  s.t = traj.time;
  for (const a of traj.agents) {
    s.distance.set(a.name, a.distance);
    a.x.forEach((_, k) => addMotion(s, a.name, a.u[k], a.v[k], a.w?.[k], a.phi?.[k], a.theta?.[k]));
    // the heading with a gap where it wraps: its own times
    const hx = [];
    const hy = [];
    a.psi.forEach((psi, k) => {
      for (const h of headingDeg(psi, hy[hy.length - 1])) {
        hx.push(traj.time[k]);
        hy.push(h);
      }
    });
    s.heading.set(a.name, { xs: hx, ys: hy });
    if (a.z) {
      s.depth.set(a.name, a.z);
      s.seabed.set(a.name, a.altitude ? a.z.map((z, k) => z + a.altitude[k]) : []);
    }
    for (const [term] of TERMS) {
      if (!a[term]) {
        s.hasTerms = false;
        continue;
      }
      let acc = 0;
      s.terms[term].set(a.name, a[term].map((r) => (acc += r)));
    }
  }
  return s;
}

/** Weigh the series' terms with w if every step's reward is their weighted sum (see rewardFits). */
function checkWeights(s, traj, w) {
  s.weights = w;
  s.misfit = 0;
  s.checked = 0;
  if (!w || !s.hasTerms) return;
  for (const a of traj.agents) {
    if (!a.reward) continue;
    for (let k = 1; k < a.reward.length; k++) {
      s.checked += 1;
      if (!rewardFits(w, a, k)) s.misfit += 1;
    }
  }
}

function addFrame(s, f) {
  s.t.push(f.time);
  for (const a of f.agents) {
    s.distance.get(a.name)?.push(a.distance);
    addMotion(s, a.name, a.u, a.v, a.w, a.phi, a.theta);
    const h = s.heading.get(a.name);
    if (h) {
      for (const v of headingDeg(a.psi, h.ys[h.ys.length - 1])) {
        h.xs.push(f.time);
        h.ys.push(v);
      }
    }
    if (s.weights && f.step > 0 && Number.isFinite(a.reward) && Number.isFinite(a.r_C)) {
      s.checked += 1;
      const one = { reward: [a.reward], r_C: [a.r_C], r_E1: [a.r_E1], r_E2: [a.r_E2] };
      if (!rewardFits(s.weights, one, 0)) s.misfit += 1;
    }
    if (Number.isFinite(a.z)) {
      s.depth.get(a.name)?.push(a.z);
      s.seabed.get(a.name)?.push(Number.isFinite(a.altitude) ? a.z + a.altitude : NaN);
    }
    for (const [term] of TERMS) {
      const ys = s.terms[term].get(a.name);
      if (ys) ys.push((ys.length ? ys[ys.length - 1] : 0) + (f.step === 0 ? 0 : a[term]));
    }
  }
}

/** Whether an episode's static part is a real vehicle's log (`hptvsim twin`), not a simulation. */
function isTwin(st) {
  return st?.backend === "log";
}

/**
 * How the reward-term plots are drawn: weighted with the episode's weights where every step's
 * reward is their weighted sum (then the three panels add up to the return, Eq. 20), else the
 * unweighted terms, said so, with the weights where known.
 */
function termsScale(series) {
  const w = series.weights;
  const weighted = !!w && series.misfit === 0;
  const num = (v) => (Math.abs(v) >= 0.01 || v === 0 ? String(+v.toPrecision(3)) : v.toExponential(1));
  const panels = TERMS.map(([term, title]) => {
    const rest = title.slice(title.indexOf(",") + 1).trim();
    if (weighted) return { term, factor: w[WEIGHT[term]], title: `${DELTA[term]} Σ ${term} (${DELTA[term]} = ${num(w[WEIGHT[term]])}), ${rest}` };
    const note = w ? `unweighted (${DELTA[term]} = ${num(w[WEIGHT[term]])} in the return)` : "unweighted";
    return { term, factor: 1, title: `Σ ${term}, ${note}, ${rest}` };
  });
  return { weighted, panels, ylabel: "reward" };
}

/** Distance and reward-term plots of one episode (its own layout for a real vehicle's log); cursor: a time [s] to mark. */
function drawEpisodePlots(st, series, cursor) {
  // vehicles without a sonar (a real vehicle's log) have no fans to show
  $("show-sonar").parentElement.hidden = st.agents.every((a) => !a.beam_angles?.length);
  if (isTwin(st)) {
    drawTwinPlots(st, series, cursor);
    return;
  }
  setPlotLayout(false);
  const info = st.agents;
  const pursuit = st.task === "pursuit";
  const shown = pursuit ? info.filter((a) => a.role === "pursuer") : info;
  const mk = (m, agents) =>
    agents.map((a) => ({ label: a.name, color: a.color, xs: series.t, ys: m.get(a.name) || [] }));
  lineChart($("plot-distance"), mk(series.distance, shown), {
    title: pursuit ? "distance from each pursuer to the evader" : "distance to the goal",
    ylabel: "distance [m]",
    xlabel: "simulated time [s]",
    hline: pursuit ? { y: st.capture_distance, label: `capture (${st.capture_distance} m)` } : null,
    cursor,
  });
  const scale = termsScale(series);
  const weigh = (m, f) => new Map([...m].map(([k, ys]) => [k, f === 1 ? ys : ys.map((y) => f * y)]));
  const terms = panelChart(
    $("plot-terms"),
    scale.panels.map(({ term, factor, title }) => ({
      title,
      ylabel: scale.ylabel,
      series: series.hasTerms ? mk(weigh(series.terms[term], factor), info) : [],
    })),
    {
      xlabel: "simulated time [s]",
      cursor,
      endDots: true,
      empty: series.hasTerms ? "no data yet" : "this episode was stored without its reward terms",
    },
  );
  // what is drawn, for tests: each panel's plot area and data range, in TERMS' order, and the weights
  state.termsPlot = {
    terms: TERMS.map(([term]) => term),
    areas: terms,
    weighted: scale.weighted,
    factors: scale.panels.map((p) => p.factor),
    titles: scale.panels.map((p) => p.title),
  };
  drawDepthPlot(st, series, cursor);
}

const PLOT_SIZE = { "plot-distance": [210, 300], "plot-terms": [330, 380] }; // [px] heights: pursuit, twin
const PLOT_LABELS = {
  "plot-distance": ["each pursuer's distance to the evader over time", "each vehicle's speeds over time (recorded)"],
  "plot-terms": ["each agent's reward terms over time", "each vehicle's roll, pitch and heading over time (recorded)"],
};

/** The plots' sizes and descriptions for a simulated episode or (twin) a real vehicle's log. */
function setPlotLayout(twin) {
  for (const [id, heights] of Object.entries(PLOT_SIZE)) {
    const c = $(id);
    const h = heights[twin ? 1 : 0];
    if (c.height !== h) c.height = h;
    c.setAttribute("aria-label", PLOT_LABELS[id][twin ? 1 : 0]);
  }
  document.getElementById("live").classList.toggle("twin", twin);
}

/**
 * A real vehicle's events (arming, disarming, flight modes) as the twin's static part lists them
 * in its description ("Events: armed at 207.0 s; mode MANUAL at 0.8 s."), times [s] since the log's
 * first sample; those at one time (within 1 % of the record) are joined.
 */
function twinEvents(st, span) {
  const m = /Events: (.*?)(?: and \d+ more)?\.\s*$/.exec(st.description || "");
  if (!m || m[1] === "none") return [];
  const out = [];
  for (const part of m[1].split("; ")) {
    const e = /^(.*) at (-?[\d.]+) s$/.exec(part.trim());
    if (!e) continue;
    const t = Number(e[2]); // on the frames' time axis (the log's: replay.episode_of)
    const last = out[out.length - 1];
    if (last && Math.abs(t - last.t) <= 0.01 * span) last.label += `, ${e[1]}`;
    else out.push({ t, label: e[1], color: /disarm/.test(e[1]) ? "#93a4b8" : /arm/.test(e[1]) ? "#2fb380" : "#e0a43a" });
  }
  return out;
}

/**
 * A real vehicle's log: its speeds (horizontal over ground and heave) and its attitude (roll,
 * pitch, heading) over the recorded time, one line per vehicle in its colour, its events (modes,
 * arming) marked on each; the depth plot under them. No distance, no rewards: nothing was pursued.
 */
function drawTwinPlots(st, series, cursor) {
  setPlotLayout(true);
  const t0 = series.t.length ? series.t[0] : 0;
  const span = series.t.length ? series.t[series.t.length - 1] - t0 : 1;
  const marks = twinEvents(st, span);
  const mk = (m) => st.agents.map((a) => ({ label: a.name, color: a.color, xs: series.t, ys: m.get(a.name) || [] }));
  const speeds = panelChart(
    $("plot-distance"),
    [
      { title: "horizontal speed √(u² + v²) of each vehicle", ylabel: "speed [m/s]", series: mk(series.speed) },
      { title: "heave speed w (positive down)", ylabel: "w [m/s]", series: mk(series.heave) },
    ],
    { xlabel: "recorded time [s]", cursor, marks, empty: "no samples yet" },
  );
  const heading = st.agents.map((a) => {
    const h = series.heading.get(a.name);
    return { label: a.name, color: a.color, xs: h?.xs || [], ys: h?.ys || [] };
  });
  const attitude = panelChart(
    $("plot-terms"),
    [
      { title: "roll φ", ylabel: "roll [deg]", series: mk(series.roll) },
      { title: "pitch θ", ylabel: "pitch [deg]", series: mk(series.pitch) },
      { title: "heading ψ (clockwise from north)", ylabel: "heading [deg]", series: heading },
    ],
    { xlabel: "recorded time [s]", cursor, marks, empty: "no samples yet" },
  );
  state.termsPlot = null;
  state.twinPlot = {
    events: marks,
    speedAreas: speeds,
    attitudeAreas: attitude,
    agents: st.agents.map((a) => a.name),
    points: st.agents.map((a) => (series.speed.get(a.name) || []).length),
  };
  drawDepthPlot(st, series, cursor, marks);
}

const SEABED_FILL = "rgba(217, 199, 154, 0.07)"; // the palette's land colour, faint: below the seabed

/**
 * The 3-D game's depth over time: one line per vehicle in its colour, depth growing downward from
 * the surface at the top; the seabed under each vehicle (its depth z + altitude) dashed in the same
 * colour with the ground below it shaded; the goal's depth in goto. Hidden in the planar game.
 */
function drawDepthPlot(st, series, cursor, marks = []) {
  const canvas = $("plot-depth");
  canvas.hidden = st.game !== "3d";
  if (canvas.hidden) return;
  const twin = isTwin(st);
  // a log does not know the seabed (its static part's is a placeholder): none is drawn
  const seabed = twin ? [] : st.agents.map((a) => ({
    label: "",
    color: a.color,
    dash: [5, 4],
    fill: SEABED_FILL,
    xs: series.t,
    ys: series.seabed.get(a.name) || [],
  }));
  const depth = st.agents.map((a) => ({ label: a.name, color: a.color, xs: series.t, ys: series.depth.get(a.name) || [] }));
  const key = twin ? [] : [{ label: "seabed under each (dashed)", color: "#93a4b8", dash: [5, 4], xs: [], ys: [] }];
  const goal = st.agents.find((a) => a.goal && a.goal.length > 2 && Number.isFinite(a.goal[2]));
  const areas = lineChart(canvas, [...seabed, ...depth, ...key], {
    title: twin ? "depth of each vehicle, recorded (surface at the top)" : "depth of each vehicle (surface at the top)",
    ylabel: "depth z [m]",
    xlabel: twin ? "recorded time [s]" : "simulated time [s]",
    flip: true,
    ymin: 0,
    hline: goal ? { y: goal.goal[2], label: `goal depth (${+goal.goal[2].toFixed(1)} m)` } : null,
    cursor,
    marks,
  });
  // what is drawn, for tests: the series' agents and lengths, and where the plot area is
  state.depthPlot = { agents: depth.map((d) => d.label), points: depth.map((d) => d.ys.length), area: areas?.[0] || null };
}

// --- watching one episode ---------------------------------------------------------------------

const map = new TopDownMap($("map-canvas"));
state.map = map;
state.rangeColor = rangeColor; // the sonar colour of a range fraction (tests check pixels against it)
let redrawPending = false;

/** Order of an episode's statuses: a later one never gives way to an earlier one. */
function statusRank(status) {
  return status === "queued" ? 0 : status === "running" ? 1 : 2;
}

/**
 * The watched episode's status, the one value its badge, the text beside it and its row in the
 * list all show (`detail`: what the text says after it; undefined keeps the current one). A
 * status older than the one shown (a list polled before the stream's news) changes nothing.
 */
function setStatus(status, detail) {
  const c = state.current;
  if (!c) return;
  if (statusRank(status) < statusRank(c.status)) status = c.status;
  c.status = status;
  if (detail !== undefined) c.detail = detail;
  const b = $("live-status");
  b.textContent = status;
  b.className = `badge ${status}`;
  $("cancel-button").hidden = !ACTIVE.has(status);
  const ep = c.episode;
  const what = ep.backend === "log" ? ep.label || ep.scenario : `${ep.scenario}, seed ${ep.seed}`; // a log has no seed
  $("live-text").textContent = `${what}: ${status}${c.detail ? `, ${c.detail}` : ""}`;
  const listed = state.episodes.find((e) => e.id === c.id);
  if (listed) listed.status = status;
  const row = document.querySelector(`#episode-table tbody tr[data-id="${CSS.escape(c.id)}"] .badge`);
  if (row && row.textContent !== status) {
    row.textContent = status;
    row.className = `badge ${status}`;
  }
}

function setTimeline(enabled, n = 0) {
  stopPlaying();
  $("scrub").disabled = !enabled;
  $("play-button").disabled = !enabled;
  $("scrub").max = String(Math.max(0, n - 1));
  if (!enabled) $("scrub-time").textContent = "live";
}

function watch(ep) {
  if (state.current?.es) state.current.es.close();
  state.current = { id: ep.id, static: null, series: null, traj: null, es: null, status: ep.status, detail: "", episode: ep };
  history.replaceState(null, "", `#episode=${ep.id}`);
  $("live-id").textContent = ep.id;
  $("live-metrics").replaceChildren();
  $("live-links").replaceChildren();
  $("live-progress").style.width = "0%";
  setStatus(ep.status, "");
  setTimeline(false);
  $("plot-depth").hidden = gameOf(ep.scenario) !== "3d"; // until the episode's static part says
  highlightRow();
  if (!ACTIVE.has(ep.status)) {
    showFinished(ep.id);
    return;
  }
  const es = openEvents(`${API}/episodes/${ep.id}/events?static=true&frames=true`, (why) => {
    if (mine()) setStatus(state.current.status, `${state.current.detail} (stream closed: ${why})`);
  });
  state.current.es = es;
  const mine = () => state.current && state.current.es === es;
  es.addEventListener("status", (e) => {
    if (!mine()) return;
    const d = JSON.parse(e.data);
    setStatus(d.status);
    if (d.final) {
      es.close();
      showFinished(ep.id);
    }
    refreshList(); // the table agrees with the live view at once, not at the next poll
  });
  const weights = scenarioWeights(ep.scenario);
  es.addEventListener("static", (e) => {
    if (!mine()) return;
    const st = checkSchema("EpisodeStatic", withoutEpisode(JSON.parse(e.data)));
    state.current.static = st;
    const series = newSeries(st);
    state.current.series = series;
    if (!isTwin(st)) weights.then((w) => { series.weights = w; });
    map.caption = "";
    map.setStatic(st);
    if (st.game === "3d") drawDepthPlot(st, state.current.series, null);
    else $("plot-depth").hidden = true;
  });
  es.addEventListener("progress", (e) => {
    if (!mine()) return;
    const d = JSON.parse(e.data);
    const max = d.max_steps || state.current.static?.max_steps || 1;
    $("live-progress").style.width = `${Math.min(100, (100 * d.step) / max)}%`;
    setStatus(state.current.status, `step ${d.step} of at most ${max}, t = ${(d.t ?? d.time ?? 0).toFixed(1)} s`);
  });
  es.addEventListener("frame", (e) => {
    if (!mine() || !state.current.static) return;
    state.framesSeen += 1;
    const f = checkSchema("Frame", withoutEpisode(JSON.parse(e.data)));
    state.lastFrame = f;
    addFrame(state.current.series, f);
    map.showFrame(f);
    if (!redrawPending) {
      redrawPending = true;
      requestAnimationFrame(() => {
        redrawPending = false;
        const c = state.current;
        if (c?.static && c.series && !c.traj) drawEpisodePlots(c.static, c.series, null);
      });
    }
  });
}

async function showFinished(id) {
  const c = state.current;
  try {
    const ep = await api(`/episodes/${id}`);
    if (state.current !== c) return;
    c.episode = ep;
    $("live-progress").style.width = ep.status === "finished" ? "100%" : $("live-progress").style.width;
    const sum = ep.summary;
    const twin = ep.backend === "log";
    const detail = [
      sum && twin ? `recorded: a real vehicle's log, ${sum.steps + 1} samples up to t = ${sum.sim_time.toFixed(1)} s` : "",
      sum && !twin ? `${sum.outcome} after ${sum.steps} steps (${sum.sim_time.toFixed(1)} s simulated, ` +
        `${sum.wall_time.toFixed(2)} s wall)` : "",
      ep.error ? `(${ep.error})` : "",
    ].filter(Boolean).join(" ");
    setStatus(ep.status, detail);
    if (twin) $("live-metrics").replaceChildren(); // the twin's own, once its trajectory is loaded
    else showMetrics(sum);
    showLinks(ep);
    if (!c.static) {
      try {
        c.static = checkSchema("EpisodeStatic", await api(`/episodes/${id}/static`));
        map.setStatic(c.static);
      } catch (err) {
        console.info("no static part:", err.message);
      }
    }
    if (c.static?.game === "3d" && !ep.has_trajectory) drawDepthPlot(c.static, c.series || newSeries(c.static), null);
    if (ep.has_trajectory && c.static) {
      const traj = checkSchema("Trajectories", await api(`/episodes/${id}/trajectory?format=json`));
      if (state.current !== c) return;
      const w = isTwin(c.static) ? null : await scenarioWeights(ep.scenario);
      if (state.current !== c) return;
      c.traj = traj;
      c.series = seriesOfTrajectory(c.static, traj);
      checkWeights(c.series, traj, w);
      if (isTwin(c.static)) showTwin(c.static, traj);
      map.caption = "";
      map.setReplay(traj);
      map.setCollisions(sum?.collisions);
      setTimeline(true, traj.step.length);
      scrubTo(traj.step.length - 1);
    }
  } catch (err) {
    if (state.current === c) setStatus(c.status, `cannot load episode ${id}: ${err.message}`);
  }
}

/** Show row k of the current finished episode on the map and as a cursor on the plots. */
function scrubTo(k) {
  const c = state.current;
  if (!c?.traj) return;
  const n = c.traj.step.length;
  k = Math.max(0, Math.min(n - 1, Math.round(k)));
  $("scrub").value = String(k);
  map.showStep(k);
  const t = c.traj.time[k];
  $("scrub-time").textContent = `t = ${t.toFixed(1)} s of ${c.traj.time[n - 1].toFixed(1)} s, step ${c.traj.step[k]}`;
  drawEpisodePlots(c.static, c.series, t);
}

// playing: about 30 s for a whole episode, at least real time
let player = null;

function stopPlaying() {
  if (player) cancelAnimationFrame(player.raf);
  player = null;
  $("play-button").textContent = "▶";
  $("compare-play").textContent = "▶";
}

function play(button, get, set, n, duration) {
  if (player) {
    stopPlaying();
    return;
  }
  const speed = Math.max(1, duration / 30); // simulated seconds per real second
  let k = get() >= n - 1 ? 0 : get();
  let last = performance.now();
  button.textContent = "❚❚";
  const tick = (now) => {
    k += (((now - last) / 1000) * speed * (n - 1)) / Math.max(duration, 1e-9);
    last = now;
    set(Math.min(n - 1, k));
    if (k >= n - 1) {
      stopPlaying();
      return;
    }
    player.raf = requestAnimationFrame(tick);
  };
  player = { raf: requestAnimationFrame(tick) };
}

/** One collision of an episode's summary: with what, where [m] and when [s]. */
function collisionText(c) {
  const at = [c.x, c.y, ...(c.z === null || c.z === undefined ? [] : [c.z])].map((v) => v.toFixed(0));
  return `${c.collided_with} at (${at.join(", ")}) m, ${c.time.toFixed(1)} s`;
}

function fmt(v, digits = 1) {
  return v === null || v === undefined ? "–" : typeof v === "number" ? v.toFixed(digits) : String(v);
}

function showMetrics(sum) {
  const box = $("live-metrics");
  box.replaceChildren();
  if (!sum) return;
  const m = sum.metrics || {};
  const items = [
    ["outcome", sum.outcome],
    ["captured", m.captured ? "yes" : "no"],
    ["time to capture [s]", fmt(m.time_to_capture_s)],
    ["collision", m.collision ? "yes" : "no"],
    ["min distance [m]", fmt(m.min_distance)],
    ["final distance [m]", fmt(m.final_distance)],
    ["steps", String(sum.steps)],
  ];
  for (const c of sum.collisions || []) items.push([`${c.agent} collided`, collisionText(c)]);
  for (const [name, value] of Object.entries(m.returns || {})) items.push([`return ${name}`, fmt(value, 1)]);
  for (const [label, value] of items) {
    const d = document.createElement("div");
    const b = document.createElement("b");
    b.textContent = value;
    const s = document.createElement("span");
    s.textContent = label;
    d.append(b, s);
    box.append(d);
  }
}

/**
 * What a real vehicle's log holds: how long it was recorded, its samples, each vehicle's depth
 * range, top speed and track length, and its modes and events (each a button that scrubs there).
 */
function showTwin(st, traj) {
  const box = $("live-metrics");
  box.replaceChildren();
  const n = traj.time.length;
  const items = [
    ["recorded [s]", fmt(traj.time[n - 1] - traj.time[0])],
    ["samples", `${n} (every ${fmt(st.dt, 2)} s)`],
  ];
  for (const a of traj.agents) {
    const info = st.agents.find((b) => b.name === a.name);
    const z = (a.z || []).filter(Number.isFinite);
    let length = 0;
    for (let k = 1; k < a.x.length; k++) length += Math.hypot(a.x[k] - a.x[k - 1], a.y[k] - a.y[k - 1]);
    const top = Math.max(...a.u.map((u, k) => Math.hypot(u, a.v[k])));
    const who = traj.agents.length > 1 ? `${a.name} ` : "";
    items.push(
      [`${who}vehicle`, info?.vehicle_type || a.name],
      // (a depth a hair above the surface, the sensor's noise, as 0.00 rather than -0.00)
      [`${who}depth [m]`, z.length ? `${fmt(Math.max(0, Math.min(...z)), 2)} … ${fmt(Math.max(...z), 2)}` : "–"],
      [`${who}top speed [m/s]`, fmt(top, 2)],
      [`${who}track [m]`, fmt(length, 1)],
    );
  }
  for (const [label, value] of items) {
    const d = document.createElement("div");
    const b = document.createElement("b");
    b.textContent = value;
    const sp = document.createElement("span");
    sp.textContent = label;
    d.append(b, sp);
    box.append(d);
  }
  const t0 = traj.time[0];
  const events = twinEvents(st, traj.time[n - 1] - t0);
  const list = document.createElement("div");
  list.id = "twin-events";
  list.className = "twin-events";
  const head = document.createElement("span");
  head.textContent = events.length ? "modes and events:" : "modes and events: none logged";
  list.append(head);
  for (const e of events) {
    const b = document.createElement("button");
    b.type = "button";
    b.className = "ghost small";
    b.style.borderColor = e.color;
    b.textContent = `${fmt(e.t)} s: ${e.label}`;
    b.title = "show this moment";
    b.addEventListener("click", () => {
      stopPlaying();
      let k = traj.time.findIndex((t) => t >= e.t);
      if (k < 0) k = n - 1;
      scrubTo(k);
    });
    list.append(b);
  }
  box.append(list);
}

/** A download link of the API's; with a key, a click fetches it with the key in a header. */
function link(href, text, name) {
  const a = document.createElement("a");
  a.href = href;
  a.textContent = text;
  a.addEventListener("click", (ev) => {
    if (!apiKey()) return; // no key: the plain link works
    ev.preventDefault();
    download(href, name || a.download || href.split("/").pop()).catch((err) => {
      const c = state.current;
      if (c) setStatus(c.status, `${c.detail ? `${c.detail} ` : ""}(${err.message})`);
    });
  });
  return a;
}

function showLinks(ep) {
  const box = $("live-links");
  box.replaceChildren();
  if (ep.has_recording) {
    const a = link(`${API}/episodes/${ep.id}/recording`, "recording (.rrd)");
    a.download = `${ep.id}.rrd`;
    a.id = "recording-link";
    box.append(a);
  }
  if (ep.has_trajectory) {
    const base = `${API}/episodes/${ep.id}/trajectory?format=`;
    box.append(link(`${base}csv`, "trajectory (CSV)", `${ep.id}-trajectory.csv`));
    box.append(link(`${base}parquet`, "trajectory (Parquet)", `${ep.id}-trajectory.parquet`));
    box.append(link(`${base}json`, "trajectory (JSON)", `${ep.id}-trajectory.json`));
  }
  if (state.config?.viser_url) {
    const a = document.createElement("a"); // the live view asks for the key itself
    a.href = state.config.viser_url;
    a.textContent = "live 3D view";
    a.target = "_blank";
    a.rel = "noopener";
    box.append(a);
  }
}

// --- the episode list -------------------------------------------------------------------------

async function refreshList() {
  const params = new URLSearchParams({ limit: "200" });
  if ($("filter-status").value) params.append("status", $("filter-status").value);
  if ($("filter-scenario").value) params.append("scenario", $("filter-scenario").value);
  if ($("filter-policy").value) params.append("policy", $("filter-policy").value);
  try {
    const page = await api(`/episodes?${params}`);
    state.episodes = page.items;
    const c = state.current;
    const listed = c && state.episodes.find((e) => e.id === c.id);
    if (listed) {
      // the list and the watched episode show one status: the later of what each has heard
      if (statusRank(listed.status) > statusRank(c.status)) setStatus(listed.status);
      listed.status = c.status;
    }
    $("episode-count").textContent = `${state.episodes.length} shown of ${page.total}`;
    renderList();
  } catch (err) {
    $("episode-count").textContent = `cannot list episodes: ${err.message}`;
  }
}

function cell(text, cls) {
  const td = document.createElement("td");
  td.textContent = text;
  if (cls) td.className = cls;
  return td;
}

function renderList() {
  const body = document.querySelector("#episode-table tbody");
  body.replaceChildren(
    ...state.episodes.map((ep) => {
      const tr = document.createElement("tr");
      tr.dataset.id = ep.id;
      const pols = [...new Set(Object.values(ep.policies))].join(", ");
      const badge = document.createElement("span");
      badge.className = `badge ${ep.status}`;
      badge.textContent = ep.status;
      const st = cell("");
      st.append(badge);
      const actions = cell("");
      if (ep.has_recording) {
        const a = link(`${API}/episodes/${ep.id}/recording`, ".rrd");
        a.download = `${ep.id}.rrd`;
        a.addEventListener("click", (e) => e.stopPropagation());
        actions.append(a);
      }
      if (ACTIVE.has(ep.status)) {
        const b = document.createElement("button");
        b.className = "small danger";
        b.textContent = "cancel";
        b.addEventListener("click", async (e) => {
          e.stopPropagation();
          await api(`/episodes/${ep.id}/cancel`, { method: "POST" }).catch(() => {});
          refreshList();
        });
        actions.append(b);
      }
      const pick = cell("");
      const box = document.createElement("input");
      box.type = "checkbox";
      box.className = "pick";
      box.title = "compare this episode";
      box.checked = state.compareIds.has(ep.id);
      box.disabled = !ep.has_trajectory && !state.compareIds.has(ep.id);
      box.addEventListener("click", (e) => e.stopPropagation());
      box.addEventListener("change", () => {
        if (box.checked) state.compareIds.add(ep.id);
        else state.compareIds.delete(ep.id);
        updateCompareButton();
      });
      pick.append(box);
      tr.append(
        pick,
        cell(new Date(ep.created_at).toLocaleTimeString()),
        cell(ep.id.slice(0, 8), "mono"),
        scenarioCell(ep),
        cell(pols, "policies"),
        cell(String(ep.seed)),
        st,
        cell(String(ep.steps)),
        cell(ep.backend === "log" && ep.summary ? "recorded" : ep.summary?.outcome || ""),
        cell(fmt(ep.summary?.metrics?.min_distance)),
        actions,
      );
      tr.addEventListener("click", () => watch(ep));
      return tr;
    }),
  );
  highlightRow();
  updateCompareButton();
}

function scenarioCell(ep) {
  const td = cell(ep.label ? `${ep.scenario} (${ep.label})` : ep.scenario);
  if (gameOf(ep.scenario) === "3d") td.append(" ", tag3d());
  return td;
}

function updateCompareButton() {
  const n = state.compareIds.size;
  const b = $("compare-button");
  b.textContent = n ? `Compare ${n}` : "Compare";
  b.disabled = n < 2 || n > 4;
  b.title = n > 4 ? "at most four episodes at once" : "tick two to four finished episodes";
}

// --- comparing episodes on one timeline --------------------------------------------------------

let compareTurn = 0; // the latest comparison asked for: an older one still loading stops

/** Load episodes and show them side by side on one synchronised timeline (simulated time). */
async function compare(ids, scroll = true) {
  const turn = ++compareTurn;
  ids = [...new Set(ids)].slice(0, 4);
  const box = $("compare-maps");
  box.replaceChildren();
  $("compare").hidden = false;
  $("compare-title").textContent = "loading…";
  history.replaceState(null, "", `#compare=${ids.join(",")}`);
  const items = [];
  try {
    for (const [i, id] of ids.entries()) {
      const [episode, st, traj] = await Promise.all([
        api(`/episodes/${id}`),
        api(`/episodes/${id}/static`),
        api(`/episodes/${id}/trajectory?format=json`),
      ]);
      if (turn !== compareTurn) return;
      checkSchema("EpisodeStatic", st);
      checkSchema("Trajectories", traj);
      const fig = document.createElement("figure");
      fig.className = "compare-item";
      const canvas = document.createElement("canvas");
      canvas.width = 440; // until its figure's width is known (below)
      canvas.height = 480;
      canvas.id = `compare-map-${i}`;
      const cap = document.createElement("figcaption");
      const sw = document.createElement("span");
      sw.className = "key";
      sw.style.setProperty("--c", EPISODE_COLORS[i]);
      sw.textContent = String.fromCharCode(65 + i);
      const pols = [...new Set(Object.values(episode.policies))].join(" vs ");
      const sum = episode.summary;
      cap.append(
        sw,
        ` ${episode.scenario}, seed ${episode.seed}: ${pols}` +
          (sum ? ` — ${sum.outcome} after ${sum.sim_time.toFixed(1)} s` : ""),
      );
      fig.append(canvas, cap);
      box.style.setProperty("--n", String(ids.length));
      box.append(fig);
      // the maps share the comparison's width (a column each): drawn at their shown size
      const w = Math.max(300, Math.round(fig.clientWidth || 440));
      canvas.width = w;
      canvas.height = Math.round((w * 480) / 440);
      const m = new TopDownMap(canvas);
      m.setStatic(st);
      m.caption = String.fromCharCode(65 + i);
      m.setReplay(traj);
      m.setCollisions(sum?.collisions);
      items.push({ id, episode, static: st, traj, map: m });
    }
  } catch (err) {
    if (turn === compareTurn) $("compare-title").textContent = `cannot compare: ${err.message}`;
    return;
  }
  // one timeline: the union of the episodes' times at the finest step
  const dt = Math.min(...items.map((it) => it.static.dt));
  const end = Math.max(...items.map((it) => it.traj.time[it.traj.time.length - 1]));
  const n = Math.round(end / dt) + 1;
  state.compare = { items, dt, n, end };
  $("compare-title").textContent = `${items.length} episodes, one timeline of ${end.toFixed(1)} s`;
  $("compare-scrub").max = String(n - 1);
  $("compare-sonar").checked = true;
  compareTable(items);
  compareTo(n - 1);
  if (scroll) $("compare").scrollIntoView({ behavior: "instant", block: "start" });
}

/** Show simulated time k * dt in every compared episode (an episode that ended stays at its end). */
function compareTo(k) {
  const c = state.compare;
  if (!c) return;
  k = Math.max(0, Math.min(c.n - 1, Math.round(k)));
  $("compare-scrub").value = String(k);
  const t = k * c.dt;
  for (const it of c.items) {
    const row = Math.min(it.traj.time.length - 1, Math.round(t / it.static.dt));
    it.map.showStep(row);
  }
  $("compare-time").textContent = `t = ${t.toFixed(1)} s of ${c.end.toFixed(1)} s`;
  // the nearest pursuer's distance to the evader in each episode
  const series = c.items.map((it, i) => {
    const pursuers = it.static.agents.filter((a) => a.role === "pursuer").map((a) => a.name);
    const rows = it.traj.agents.filter((a) => pursuers.length === 0 || pursuers.includes(a.name));
    const ys = it.traj.time.map((_, r) => Math.min(...rows.map((a) => a.distance[r])));
    return {
      label: `${String.fromCharCode(65 + i)}: ${[...new Set(Object.values(it.episode.policies))].join(" vs ")}`,
      color: EPISODE_COLORS[i],
      dash: EPISODE_DASHES[i],
      xs: it.traj.time,
      ys,
    };
  });
  const st = c.items[0].static;
  const plot = $("compare-distance");
  const width = Math.round(plot.parentElement.clientWidth - 2); // as wide as the card's content
  if (width > 300 && plot.width !== width) plot.width = width;
  lineChart(plot, series, {
    title: "distance from the nearest pursuer to the evader",
    ylabel: "distance [m]",
    xlabel: "simulated time [s]",
    hline: st.task === "pursuit" ? { y: st.capture_distance, label: `capture (${st.capture_distance} m)` } : null,
    cursor: t,
  });
}

function compareTable(items) {
  const table = $("compare-table");
  const head = document.createElement("tr");
  for (const h of ["", "policies", "outcome", "time to capture [s]", "min distance [m]", "collision", "returns"]) {
    const th = document.createElement("th");
    th.textContent = h;
    head.append(th);
  }
  const rows = items.map((it, i) => {
    const tr = document.createElement("tr");
    const m = it.episode.summary?.metrics || {};
    const rets = Object.entries(m.returns || {}).map(([a, v]) => `${a} ${fmt(v, 0)}`).join(", ");
    tr.append(
      cell(String.fromCharCode(65 + i)),
      cell([...new Set(Object.values(it.episode.policies))].join(" vs "), "policies"),
      cell(it.episode.summary?.outcome || it.episode.status),
      cell(fmt(m.time_to_capture_s)),
      cell(fmt(m.min_distance)),
      cell(
        (it.episode.summary?.collisions || []).map((c) => `${c.agent}: ${c.collided_with}`).join("; ") ||
          (m.collision ? "yes" : "no"),
      ),
      cell(rets, "policies"),
    );
    return tr;
  });
  table.replaceChildren(head, ...rows);
}

function closeCompare() {
  compareTurn += 1; // a comparison still loading stops
  stopPlaying();
  state.compare = null;
  $("compare").hidden = true;
  $("compare-maps").replaceChildren();
  if (state.current) history.replaceState(null, "", `#episode=${state.current.id}`);
}

function highlightRow() {
  for (const tr of document.querySelectorAll("#episode-table tbody tr")) {
    tr.classList.toggle("selected", tr.dataset.id === state.current?.id);
  }
}

/**
 * Keep the list fresh by polling: every 3 s while an episode in it is queued or running, else
 * every 15 s. Polling, not a standing event stream, so the page never holds a request open while
 * idle (a headless browser's --virtual-time-budget waits for open requests to end).
 */
function pollList() {
  const busy = state.episodes.some((ep) => ACTIVE.has(ep.status));
  setTimeout(async () => {
    if (!document.hidden) await refreshList();
    pollList();
  }, busy ? 3000 : 15000);
}

// --- the address's fragment ----------------------------------------------------------------------

let hashTurn = 0; // the latest fragment followed: an older one still loading gives way

/**
 * Show what the address's fragment names: `#episode=ID` watches that episode, `#compare=ID,ID`
 * compares those (closing a comparison the fragment no longer names). Called at start and on
 * every `hashchange`; the page's own rewrites of the fragment (history.replaceState) fire none.
 */
async function followHash(scroll) {
  const turn = ++hashTurn;
  const hash = new URLSearchParams(location.hash.slice(1));
  const episode = hash.get("episode");
  const ids = (hash.get("compare") || "").split(",").filter(Boolean);
  if (episode && episode !== state.current?.id) {
    try {
      const ep = await api(`/episodes/${encodeURIComponent(episode)}`);
      if (turn === hashTurn) watch(ep);
    } catch (err) {
      if (turn === hashTurn) $("form-error").textContent = `no episode ${episode}: ${err.message}`;
    }
  }
  if (turn !== hashTurn) return;
  if (ids.length) {
    const shown = state.compare?.items.map((it) => it.id).join(",");
    if (shown !== [...new Set(ids)].slice(0, 4).join(",")) {
      state.compareIds = new Set(ids);
      renderList();
      await compare(ids, scroll);
    }
  } else if (state.compare || !$("compare").hidden) {
    closeCompare();
  }
}

// --- start ------------------------------------------------------------------------------------

async function start() {
  $("api-key").value = apiKey();
  $("api-key").addEventListener("change", () => {
    sessionStorage.setItem(KEY_NAME, $("api-key").value);
    location.reload();
  });
  $("schema-version").textContent = VERSION;
  $("f-scenario").addEventListener("change", () => showScenario(true));
  $("episode-form").addEventListener("submit", createEpisode);
  $("cancel-button").addEventListener("click", cancelCurrent);
  $("refresh-button").addEventListener("click", refreshList);
  for (const id of ["filter-status", "filter-scenario", "filter-policy"]) $(id).addEventListener("change", refreshList);
  $("scrub").addEventListener("input", () => {
    stopPlaying();
    scrubTo(Number($("scrub").value));
  });
  $("play-button").addEventListener("click", () => {
    const c = state.current;
    if (!c?.traj) return;
    const n = c.traj.step.length;
    play($("play-button"), () => Number($("scrub").value), scrubTo, n, c.traj.time[n - 1]);
  });
  $("show-sonar").addEventListener("change", () => map.setSonar($("show-sonar").checked));
  $("compare-button").addEventListener("click", () => compare([...state.compareIds]));
  $("compare-close").addEventListener("click", closeCompare);
  $("compare-scrub").addEventListener("input", () => {
    stopPlaying();
    compareTo(Number($("compare-scrub").value));
  });
  $("compare-play").addEventListener("click", () => {
    const c = state.compare;
    if (c) play($("compare-play"), () => Number($("compare-scrub").value), compareTo, c.n, c.end);
  });
  $("compare-sonar").addEventListener("change", () => {
    for (const it of state.compare?.items || []) it.map.setSonar($("compare-sonar").checked);
  });
  lineChart($("plot-distance"), [], { title: "distance from each pursuer to the evader", xlabel: "simulated time [s]" });
  panelChart($("plot-terms"), TERMS.map(([, title]) => ({ title, series: [] })), { xlabel: "simulated time [s]" });
  try {
    await loadConfig();
    await loadChoices();
    await refreshList();
    await followHash(false);
    // a new fragment (typed, a link followed, history's back and forward) shows what it names
    window.addEventListener("hashchange", () => followHash(true));
    pollList();
    document.body.dataset.ready = "true";
  } catch (err) {
    $("form-error").textContent = `the service did not answer: ${err.message}`;
  }
}

start();
