// The hptvsim dashboard: create, run, watch and cancel episodes; browse the episode list.
// Talks to the service's REST API under /api/v1 and its server-sent events; live data follow the
// frame schema (frames.gen.js, generated from hptvsim/viz/frames.py) and are checked against it.

import { validate, VERSION } from "./schema.js";
import { TopDownMap, lineChart } from "./draw.js";

const API = "/api/v1";
const ACTIVE = new Set(["queued", "running"]);
const $ = (id) => document.getElementById(id);

/** Everything the page knows; exposed as window.hptvsim for tests and curious users. */
const state = {
  config: null,
  scenarios: [],
  policies: [],
  episodes: [],
  current: null, // {id, static, series, es, status}
  schemaErrors: [],
  framesSeen: 0,
  lastFrame: null,
};
window.hptvsim = state;

// --- the API ----------------------------------------------------------------------------------

function apiKey() {
  return localStorage.getItem("hptvsim-api-key") || "";
}

/** A URL with the API key as a query parameter (for EventSource, links and images). */
function withKey(url) {
  const key = apiKey();
  if (!key) return url;
  return url + (url.includes("?") ? "&" : "?") + "api_key=" + encodeURIComponent(key);
}

async function api(path, options = {}) {
  const headers = { Accept: "application/json", ...(options.headers || {}) };
  if (options.body !== undefined) headers["Content-Type"] = "application/json";
  const key = apiKey();
  if (key) headers["X-API-Key"] = key;
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
  $("schema-state").textContent =
    `frame schema ${VERSION}: ${state.framesSeen} frames checked` +
    (state.schemaErrors.length ? `, ${state.schemaErrors.length} problems (see the console)` : ", all conform");
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
    $("service-state").className = "pill ok";
    $("key-box").hidden = !state.config.auth;
    if (state.config.viser_url) {
      $("link-viser").href = withKey(state.config.viser_url); // the live view asks for the key too
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

async function loadChoices() {
  state.scenarios = await api("/scenarios");
  state.policies = await api("/policies");
  const sel = $("f-scenario");
  sel.replaceChildren(...state.scenarios.map((s) => option(s.name)));
  sel.value = state.scenarios.some((s) => s.name === "target") ? "target" : state.scenarios[0]?.name;
  $("filter-scenario").replaceChildren(option("", "any"), ...state.scenarios.map((s) => option(s.name)));
  $("filter-policy").replaceChildren(option("", "any"), ...state.policies.map((p) => option(p.name)));
  const byRole = (role) => state.policies.filter((p) => p.roles.includes(role)).map((p) => option(p.name));
  $("f-pursuer-policy").replaceChildren(...byRole("pursuer"));
  $("f-evader-policy").replaceChildren(...byRole("evader"));
  $("f-pursuer-policy").value = "scripted:pure_pursuit";
  $("f-evader-policy").value = "scripted:potential_field";
  showScenario();
}

function showScenario() {
  const s = state.scenarios.find((x) => x.name === $("f-scenario").value);
  if (!s) return;
  const n = s.agents.length;
  const roles = Object.values(s.roles || {});
  const p = roles.filter((r) => r === "pursuer").length;
  $("scenario-info").textContent =
    `${s.description || ""} ${s.task} task, ${s.site_size[0]} m × ${s.site_size[1]} m, ` +
    `${p} pursuer(s) and ${n - p} evader(s), dt ${s.dt} s, up to ${s.max_steps} steps.`;
  $("scenario-map").src = withKey(`${API}/scenarios/${encodeURIComponent(s.name)}/map.png`);
  $("f-max-steps").placeholder = `scenario's (${s.max_steps})`;
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
    $("live-text").textContent = `cannot cancel: ${err.message}`;
  }
}

// --- watching one episode ---------------------------------------------------------------------

const map = new TopDownMap($("map-canvas"));
let redrawPending = false;

function newSeries(st) {
  return {
    t: [],
    distance: new Map(st.agents.map((a) => [a.name, []])),
    ret: new Map(st.agents.map((a) => [a.name, []])),
  };
}

function setStatus(status) {
  const b = $("live-status");
  b.textContent = status;
  b.className = `badge ${status}`;
  $("cancel-button").hidden = !ACTIVE.has(status);
  if (state.current) state.current.status = status;
}

function watch(ep) {
  if (state.current?.es) state.current.es.close();
  state.current = { id: ep.id, static: null, series: null, es: null, status: ep.status, episode: ep };
  $("live-id").textContent = ep.id;
  $("live-metrics").replaceChildren();
  $("live-links").replaceChildren();
  $("live-progress").style.width = "0%";
  $("live-text").textContent = `${ep.scenario}, seed ${ep.seed}: ${ep.status}`;
  setStatus(ep.status);
  highlightRow();
  if (!ACTIVE.has(ep.status)) {
    showFinished(ep.id);
    return;
  }
  const es = new EventSource(withKey(`${API}/episodes/${ep.id}/events?static=true&frames=true`));
  state.current.es = es;
  const mine = () => state.current && state.current.es === es;
  es.addEventListener("status", (e) => {
    if (!mine()) return;
    const d = JSON.parse(e.data);
    setStatus(d.status);
    if (d.final) {
      es.close();
      showFinished(ep.id);
      refreshList();
    }
  });
  es.addEventListener("static", (e) => {
    if (!mine()) return;
    const st = checkSchema("EpisodeStatic", withoutEpisode(JSON.parse(e.data)));
    state.current.static = st;
    state.current.series = newSeries(st);
    map.setStatic(st);
  });
  es.addEventListener("progress", (e) => {
    if (!mine()) return;
    const d = JSON.parse(e.data);
    const max = d.max_steps || state.current.static?.max_steps || 1;
    $("live-progress").style.width = `${Math.min(100, (100 * d.step) / max)}%`;
    $("live-text").textContent = `step ${d.step} of at most ${max}, t = ${(d.t ?? d.time ?? 0).toFixed(1)} s`;
  });
  es.addEventListener("frame", (e) => {
    if (!mine() || !state.current.static) return;
    state.framesSeen += 1;
    const f = checkSchema("Frame", withoutEpisode(JSON.parse(e.data)));
    state.lastFrame = f;
    const s = state.current.series;
    s.t.push(f.time);
    for (const a of f.agents) {
      s.distance.get(a.name)?.push(a.distance);
      s.ret.get(a.name)?.push(a.episode_return);
    }
    map.showFrame(f);
    if (!redrawPending) {
      redrawPending = true;
      requestAnimationFrame(() => {
        redrawPending = false;
        drawSeries();
      });
    }
  });
  es.onerror = () => {
    if (mine() && es.readyState === EventSource.CLOSED) $("live-text").textContent += " (stream closed)";
  };
}

function drawSeries() {
  const c = state.current;
  if (!c?.static || !c.series) return;
  const colour = new Map(c.static.agents.map((a) => [a.name, a.color]));
  const mk = (m) => [...m].map(([name, ys]) => ({ label: name, color: colour.get(name), xs: c.series.t, ys }));
  lineChart($("plot-distance"), mk(c.series.distance), {
    title: "distance to the target [m]",
    xlabel: "time [s]",
    hline: c.static.task === "pursuit" ? { y: c.static.capture_distance, label: "capture" } : null,
  });
  lineChart($("plot-return"), mk(c.series.ret), { title: "return", xlabel: "time [s]" });
}

async function showFinished(id) {
  const c = state.current;
  try {
    const ep = await api(`/episodes/${id}`);
    if (state.current !== c) return;
    c.episode = ep;
    setStatus(ep.status);
    $("live-progress").style.width = ep.status === "finished" ? "100%" : $("live-progress").style.width;
    const sum = ep.summary;
    $("live-text").textContent =
      `${ep.scenario}, seed ${ep.seed}: ${ep.status}` +
      (sum ? `, ${sum.outcome} after ${sum.steps} steps (${sum.sim_time.toFixed(1)} s simulated, ` +
        `${sum.wall_time.toFixed(2)} s wall)` : "") +
      (ep.error ? ` (${ep.error})` : "");
    showMetrics(sum);
    showLinks(ep);
    if (!c.static) {
      try {
        c.static = checkSchema("EpisodeStatic", await api(`/episodes/${id}/static`));
        map.setStatic(c.static);
      } catch (err) {
        console.info("no static part:", err.message);
      }
    }
    if (ep.has_trajectory && c.static) {
      const traj = checkSchema("Trajectories", await api(`/episodes/${id}/trajectory?format=json`));
      if (state.current !== c) return;
      c.series = { t: traj.time, distance: new Map(), ret: new Map() };
      for (const a of traj.agents) {
        c.series.distance.set(a.name, a.distance);
        let acc = 0;
        c.series.ret.set(a.name, a.reward.map((r) => (acc += r)));
      }
      map.showPaths(traj);
      const last = traj.step.length - 1;
      if (last >= 0) {
        map.showFrame({
          step: traj.step[last],
          time: traj.time[last],
          agents: traj.agents.map((a) => ({ name: a.name, x: a.x[last], y: a.y[last], psi: a.psi[last], active: false })),
        });
      }
      drawSeries();
    }
  } catch (err) {
    $("live-text").textContent = `cannot load episode ${id}: ${err.message}`;
  }
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

function link(href, text) {
  const a = document.createElement("a");
  a.href = withKey(href);
  a.textContent = text;
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
    box.append(link(`${API}/episodes/${ep.id}/trajectory?format=csv`, "trajectory (CSV)"));
    box.append(link(`${API}/episodes/${ep.id}/trajectory?format=parquet`, "trajectory (Parquet)"));
    box.append(link(`${API}/episodes/${ep.id}/trajectory?format=json`, "trajectory (JSON)"));
  }
  if (state.config?.viser_url) {
    const a = link(withKey(state.config.viser_url), "live 3D view");
    a.target = "_blank";
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
      tr.append(
        cell(new Date(ep.created_at).toLocaleTimeString()),
        cell(ep.id.slice(0, 8), "mono"),
        cell(ep.label ? `${ep.scenario} (${ep.label})` : ep.scenario),
        cell(pols, "policies"),
        cell(String(ep.seed)),
        st,
        cell(String(ep.steps)),
        cell(ep.summary?.outcome || ""),
        cell(fmt(ep.summary?.metrics?.min_distance)),
        actions,
      );
      tr.addEventListener("click", () => watch(ep));
      return tr;
    }),
  );
  highlightRow();
}

function highlightRow() {
  for (const tr of document.querySelectorAll("#episode-table tbody tr")) {
    tr.classList.toggle("selected", tr.dataset.id === state.current?.id);
  }
}

let listTimer = null;
function refreshSoon() {
  clearTimeout(listTimer);
  listTimer = setTimeout(refreshList, 400);
}

function followAll() {
  // status changes of every episode keep the list fresh
  const es = new EventSource(withKey(`${API}/events`));
  es.addEventListener("status", refreshSoon);
  es.onerror = () => {
    es.close();
    setTimeout(followAll, 5000);
  };
}

// --- start ------------------------------------------------------------------------------------

async function start() {
  $("api-key").value = apiKey();
  $("api-key").addEventListener("change", () => {
    localStorage.setItem("hptvsim-api-key", $("api-key").value);
    location.reload();
  });
  $("f-scenario").addEventListener("change", showScenario);
  $("episode-form").addEventListener("submit", createEpisode);
  $("cancel-button").addEventListener("click", cancelCurrent);
  $("refresh-button").addEventListener("click", refreshList);
  for (const id of ["filter-status", "filter-scenario", "filter-policy"]) $(id).addEventListener("change", refreshList);
  lineChart($("plot-distance"), [], { title: "distance to the target [m]" });
  lineChart($("plot-return"), [], { title: "return" });
  try {
    await loadConfig();
    await loadChoices();
    await refreshList();
    followAll();
    setInterval(refreshList, 15000);
    document.body.dataset.ready = "true";
  } catch (err) {
    $("form-error").textContent = `the service did not answer: ${err.message}`;
  }
}

start();
