// The flip-map explorer: a map of first-flip times computed in the browser by the core's lane
// kernel (engine.firstFlips, the same kernel as mp.flip_map), and the viewer beside it running
// the pendulum of any clicked cell. Values are checked as on the viewer page: the page refuses
// what it cannot read, the core what it does not accept, and the message says why.
import { EngineError, loadEngine } from "./engine.js";

const DEG = Math.PI / 180;
/** The most cells per side: a map of 400 x 400 is 160 000 pendulums. */
const MAX_RESOLUTION = 400;
/** Rows per slice of work between two frames (the page stays responsive, Cancel works). */
const SLICE_MS = 40;

const $ = (id) => document.getElementById(id);
const form = $("setup");
const map = $("map");
const legend = $("legend");
const ui = {
  compute: $("compute"), cancel: $("cancel"), message: $("message"), progress: $("progress"), status: $("status"),
  cell: $("cell"), pendulum: $("pendulum"),
};

const state = {
  engine: null,
  job: null, // the map being computed: { setup, times, row, cancelled }
  done: null, // the last finished map: { setup, times }
  chosen: null, // [i, j] of the clicked cell
};

/** A value the page refuses before the core sees it; `field` names the input. */
class FieldError extends Error {
  constructor(field, message) {
    super(message);
    this.field = field;
  }
}

/** `count` numbers from a field (or one for both, with `oneForAll`). */
function numbers(field, label, count, { oneForAll = false } = {}) {
  const parts = String(form.elements[field].value).split(/[\s,;]+/).filter(Boolean);
  const values = parts.map((p) => {
    const v = Number(p);
    // "NaN" and "Infinity" are passed on: the core refuses them with its own message.
    if (Number.isNaN(v) && p !== "NaN") throw new FieldError(field, `${label}: "${p}" is not a number`);
    return v;
  });
  if (oneForAll && values.length === 1) return new Array(count).fill(values[0]);
  if (values.length !== count) {
    const want = oneForAll ? `1 number or ${count}` : `${count} number${count > 1 ? "s" : ""}`;
    throw new FieldError(field, `${label}: expected ${want}, got ${values.length}`);
  }
  return values;
}

/** The form's values as a map's setup, or a FieldError naming the field. */
function readSetup() {
  const [a1, b1] = numbers("theta1", "θ₁ from, to", 2);
  const [a2, b2] = numbers("theta2", "θ₂ from, to", 2);
  for (const [field, a, b, label] of [["theta1", a1, b1, "θ₁"], ["theta2", a2, b2, "θ₂"]]) {
    if (!(Number.isFinite(a) && Number.isFinite(b) && a < b)) {
      throw new FieldError(field, `${label} from, to: "from" must be less than "to", both finite, got ${a}, ${b}`);
    }
  }
  const res = String(form.elements.resolution.value).trim();
  if (!/^\d+$/.test(res) || +res < 2 || +res > MAX_RESOLUTION) {
    throw new FieldError("resolution", `Resolution must be a whole number from 2 to ${MAX_RESOLUTION}, got "${res}"`);
  }
  const link = form.elements.link.value;
  return {
    chain: {
      kind: form.elements.kind.value,
      lengths: numbers("lengths", "Lengths", 2, { oneForAll: true }),
      masses: numbers("masses", "Masses", 2, { oneForAll: true }),
      g: numbers("g", "g", 1)[0],
    },
    theta1: [a1, b1],
    theta2: [a2, b2],
    resolution: +res,
    tMax: numbers("t_max", "Up to t", 1)[0],
    dt: numbers("dt", "dt", 1)[0],
    link: link === "any" ? null : +link,
  };
}

/** The starting angles (rad) of cell (i, j): column i along θ₁, row j along θ₂ (bottom up). */
function cellAngles(setup, i, j) {
  const n = setup.resolution;
  const at = ([a, b], k) => a + ((b - a) * (k + 0.5)) / n;
  return [at(setup.theta1, i) * DEG, at(setup.theta2, j) * DEG];
}

function showMessage(text, info = false) {
  ui.message.textContent = text;
  ui.message.classList.toggle("info", info);
  ui.message.hidden = false;
}

function markInvalid(name) {
  for (const el of form.querySelectorAll("input, select")) el.removeAttribute("aria-invalid");
  if (name && form.elements[name]) form.elements[name].setAttribute("aria-invalid", "true");
}

// ---- Computing, a row at a time ----------------------------------------------------------------

function start() {
  let setup;
  try {
    setup = readSetup();
    // One pendulum first: the core checks the chain and the times before the map starts.
    const [t1, t2] = cellAngles(setup, 0, 0);
    state.engine.firstFlips(setup.chain, [t1, t2], [0, 0], setup.tMax, setup.dt, setup.link);
  } catch (e) {
    if (!(e instanceof FieldError || e instanceof EngineError)) throw e;
    markInvalid(e.field ?? fieldOf(e.message));
    showMessage(`Not computed: ${e.message}`);
    return;
  }
  markInvalid(null);
  ui.message.hidden = true;
  shareUrl();
  if (state.job) state.job.cancelled = true;
  const n = setup.resolution;
  state.job = { setup, times: new Float64Array(n * n).fill(NaN), row: 0, cancelled: false, began: performance.now() };
  state.chosen = null;
  ui.progress.hidden = false;
  ui.progress.value = 0;
  ui.cancel.disabled = false;
  document.body.dataset.computing = "true";
  requestAnimationFrame(() => work(state.job));
}

/** Which field a core message is about. */
function fieldOf(message) {
  return [[/^lengths/, "lengths"], [/^masses|link \d+ leaves/, "masses"], [/^g /, "g"], [/^t_max/, "t_max"],
    [/^dt|t_max \/ dt/, "dt"]].find(([re]) => re.test(message))?.[1];
}

function work(job) {
  if (job.cancelled) return;
  const { setup } = job;
  const n = setup.resolution;
  const until = performance.now() + SLICE_MS;
  try {
    while (job.row < n && performance.now() < until) {
      const theta = [], omega = new Array(2 * n).fill(0);
      for (let i = 0; i < n; i++) theta.push(...cellAngles(setup, i, job.row));
      job.times.set(state.engine.firstFlips(setup.chain, theta, omega, setup.tMax, setup.dt, setup.link), job.row * n);
      job.row += 1;
    }
  } catch (e) {
    if (!(e instanceof EngineError)) throw e;
    finish(job, `Stopped: ${e.message}`);
    return;
  }
  ui.progress.value = job.row / n;
  drawMap(job);
  if (job.row < n) {
    requestAnimationFrame(() => work(job));
  } else {
    const seconds = (performance.now() - job.began) / 1000;
    state.done = job;
    finish(job, null);
    const flipped = job.times.filter((t) => Number.isFinite(t)).length;
    ui.status.textContent = `${n * n} pendulums, rk4 at dt = ${setup.dt} s up to ${setup.tMax} s, in ${seconds.toFixed(2)} s`
      + ` · ${((100 * flipped) / (n * n)).toFixed(1)} % flip`;
  }
}

function finish(job, message) {
  if (state.job === job) state.job = null;
  ui.progress.hidden = true;
  ui.cancel.disabled = true;
  delete document.body.dataset.computing;
  if (message) showMessage(message);
}

// ---- Drawing -----------------------------------------------------------------------------------

/** The colour of a flip time: early flips bright, late ones dark, none (or not yet) near black. */
function colour(t, tMax) {
  if (Number.isNaN(t)) return [240, 242, 245];
  if (!Number.isFinite(t)) return [18, 22, 30];
  const u = Math.min(1, Math.max(0, Math.log1p(t) / Math.log1p(tMax))); // 0: at once, 1: at t_max
  // From warm yellow through red and violet to deep blue.
  const stops = [[255, 236, 140], [240, 120, 40], [180, 40, 90], [80, 30, 140], [30, 40, 90]];
  const x = u * (stops.length - 1), k = Math.min(stops.length - 2, Math.floor(x)), f = x - k;
  return stops[k].map((c, m) => Math.round(c + f * (stops[k + 1][m] - c)));
}

function drawMap(job) {
  const { setup, times } = job;
  const n = setup.resolution;
  const ctx = map.getContext("2d");
  const image = ctx.createImageData(n, n);
  for (let j = 0; j < n; j++) {
    for (let i = 0; i < n; i++) {
      const [r, g, b] = colour(times[j * n + i], setup.tMax);
      const p = 4 * ((n - 1 - j) * n + i); // θ₂ upwards
      image.data.set([r, g, b, 255], p);
    }
  }
  const off = new OffscreenCanvas(n, n);
  off.getContext("2d").putImageData(image, 0, 0);
  ctx.imageSmoothingEnabled = false;
  ctx.clearRect(0, 0, map.width, map.height);
  ctx.drawImage(off, 0, 0, map.width, map.height);
  if (state.chosen && state.done === job) {
    const [i, j] = state.chosen;
    const w = map.width / n;
    ctx.strokeStyle = "#fff";
    ctx.lineWidth = 2;
    ctx.strokeRect(i * w - 1, (n - 1 - j) * w - 1, w + 2, w + 2);
  }
  drawLegend(setup.tMax);
}

function drawLegend(tMax) {
  const ctx = legend.getContext("2d");
  const W = legend.width, H = legend.height;
  ctx.clearRect(0, 0, W, H);
  const bar = W - 70;
  for (let x = 0; x < bar; x++) {
    const u = x / (bar - 1);
    const [r, g, b] = colour(Math.expm1(u * Math.log1p(tMax)), tMax);
    ctx.fillStyle = `rgb(${r}, ${g}, ${b})`;
    ctx.fillRect(x, 0, 1, 14);
  }
  ctx.fillStyle = "rgb(18, 22, 30)";
  ctx.fillRect(bar + 10, 0, 60, 14);
  ctx.fillStyle = "#66717d";
  ctx.font = "11px system-ui, sans-serif";
  ctx.textBaseline = "top";
  ctx.fillText("flips at once", 0, 18);
  ctx.textAlign = "right";
  ctx.fillText(`at ${tMax} s`, bar, 18);
  ctx.fillText("never", W, 18);
}

// ---- A clicked cell ----------------------------------------------------------------------------

map.addEventListener("click", (e) => {
  const job = state.done;
  if (!job) return;
  const rect = map.getBoundingClientRect();
  const n = job.setup.resolution;
  const i = Math.min(n - 1, Math.floor(((e.clientX - rect.left) / rect.width) * n));
  const j = Math.min(n - 1, Math.floor((1 - (e.clientY - rect.top) / rect.height) * n));
  choose(job, i, j);
});

/** Run the pendulum of cell (i, j) in the viewer beside the map. */
function choose(job, i, j) {
  state.chosen = [i, j];
  drawMap(job);
  const { setup } = job;
  const n = setup.resolution;
  const [t1, t2] = cellAngles(setup, i, j).map((a) => a / DEG);
  const t = job.times[j * n + i];
  const fmt = (x) => String(+x.toPrecision(10));
  ui.cell.textContent = `θ₁ = ${t1.toFixed(2)}°, θ₂ = ${t2.toFixed(2)}°: `
    + (Number.isFinite(t) ? `flips at t = ${t.toFixed(3)} s` : `no flip before ${setup.tMax} s`);
  const c = setup.chain;
  const params = new URLSearchParams({
    n: "2", kind: c.kind, lengths: c.lengths.map(fmt).join(", "), masses: c.masses.map(fmt).join(", "),
    g: fmt(c.g), theta: `${fmt(t1)}, ${fmt(t2)}`, omega: "0", method: "rk4", dt: fmt(setup.dt), play: "1",
  });
  ui.pendulum.hidden = false;
  ui.pendulum.src = `index.html?${params}`;
}

// ---- Start -------------------------------------------------------------------------------------

const FIELDS = ["kind", "lengths", "masses", "g", "theta1", "theta2", "resolution", "t_max", "dt", "link"];

/** The form's fields from the URL (a shared map); the page's defaults for the others. */
function fieldsFromUrl() {
  const params = new URLSearchParams(location.search);
  for (const name of FIELDS) if (params.has(name)) form.elements[name].value = params.get(name);
}

/** The URL says the map being computed, to share it. */
function shareUrl() {
  const params = new URLSearchParams();
  for (const name of FIELDS) params.set(name, form.elements[name].value);
  history.replaceState(null, "", `${location.pathname}?${params}`);
}

form.addEventListener("submit", (e) => {
  e.preventDefault();
  start();
});
ui.cancel.addEventListener("click", () => {
  if (!state.job) return;
  state.job.cancelled = true;
  finish(state.job, null);
  showMessage("Cancelled.", true);
});

async function main() {
  try {
    state.engine = await loadEngine();
  } catch (e) {
    showMessage(`The engine did not load: ${e.message}`);
    return;
  }
  window.multipendulum = { engine: state.engine, state, choose };
  fieldsFromUrl();
  document.body.dataset.ready = "true";
  start();
}

main();
