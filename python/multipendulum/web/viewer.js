// The viewer page: form, canvas, readouts and energy-error plot around the engine (engine.js).
// Every value typed, loaded from a scenario or read from the URL goes through the same path:
// fields (strings) -> setup (numbers) -> a new simulation built by the core, which checks it.
// Nothing is applied unless the core accepts it; the message says what was refused.
import { ADAPTIVE, DEFAULTS as CORE_DEFAULTS, EngineError, loadEngine, METHOD_INFO, METHODS } from "./engine.js";
import { fromToml, parseInline, parseToml, ScenarioError, toInline } from "./scenario.js";

const MAX_N = 100;
const TRAIL_SECONDS = 2;
const PLOT_POINTS = 1500;
const FRAME_BUDGET_MS = 10; // integration time per frame; beyond it the run slows down instead
const DEG = Math.PI / 180;
/** The core's energy error: |E - E0| over the potential well's depth plus the largest kinetic
 *  energy; with losses or a drive, the residual of the balance E - E0 = W - D over the same scale. */
const ERROR_LABEL = "energy error |ΔE|/(g Σ|hᵢ| + T_max)";
const BALANCE_LABEL = "balance residual |ΔE − W + D|/(g Σ|hᵢ| + T_max)";

// The page's own defaults; method, tol and atol are the core's, filled in once it has loaded.
const DEFAULTS = {
  n: "2", kind: "points", lengths: "1", masses: "1", g: "9.81", theta: "130, 160",
  method: "", dt: "0.002", tol: "", speed: "1", omega: "0", com: "", inertia: "",
  atol: "", name: "", damping: "0", friction: "0", friction_velocity: "", pivot_x: "", pivot_y: "",
  cart_mass: "", cart_damping: "0", cart_x0: "0", cart_v0: "0", cart_force: "", torque: "",
};
const FIELDS = Object.keys(DEFAULTS);
const LIST_FIELDS = ["lengths", "masses", "theta", "omega", "com", "inertia", "damping", "friction"];
const LABELS = {
  n: "N", lengths: "Lengths", masses: "Masses", g: "g", theta: "Angles", omega: "Angular velocities",
  com: "Centres of mass", inertia: "Inertias", dt: "dt", tol: "Tolerance", atol: "atol", speed: "Speed",
  damping: "Damping", friction: "Friction", friction_velocity: "Friction velocity", pivot_x: "Pivot x",
  pivot_y: "Pivot y", cart_mass: "Cart mass", cart_damping: "Cart damping", cart_x0: "Cart x₀", cart_v0: "Cart v₀",
  cart_force: "Cart force", torque: "Torque",
};
// Which field a core message is about (the core names its arguments).
const FIELD_OF_MESSAGE = [
  [/^lengths/, "lengths"], [/^(masses|link \d+ leaves|the sum of masses)/, "masses"], [/^com/, "com"],
  [/^inertia/, "inertia"], [/^g /, "g"], [/^theta0/, "theta"], [/^omega0/, "omega"], [/^dt /, "dt"],
  [/^rtol/, "tol"], [/^atol/, "atol"], [/^method/, "method"], [/^friction_velocity/, "friction_velocity"],
  [/^damping/, "damping"], [/^friction/, "friction"], [/^cart mass/, "cart_mass"], [/^cart damping/, "cart_damping"],
  [/^a chain on a cart/, "cart_mass"], [/^cart state/, "cart_x0"], [/^pivot x/, "pivot_x"], [/^pivot y/, "pivot_y"], [/^cart_force/, "cart_force"],
  [/^(joint )?torque|^(amplitude|frequency|phase|offset|values|t)\[/, "torque"],
];

/** A value the page refuses before the core sees it; `field` names the input. */
class FieldError extends Error {
  constructor(field, message) {
    super(message);
    this.field = field;
  }
}

const $ = (id) => document.getElementById(id);
const form = $("setup");
const view = $("view");
const plot = $("plot");
const ui = {
  play: $("play"), step: $("step"), reset: $("reset"), share: $("share"), load: $("load"),
  message: $("message"), name: $("name"), status: $("status"),
  t: $("t"), energy: $("energy"), error: $("error"), errorLabel: $("error-label"), steps: $("steps"), fps: $("fps"),
  kinetic: $("kinetic"), potential: $("potential"), work: $("work"), dissipated: $("dissipated"), cartX: $("cart-x"),
  pivot: $("pivot"),
};

const state = {
  engine: null,
  fields: { ...DEFAULTS },
  setup: null,
  sim: null,
  playing: false,
  clock: 0, // the simulated time the display should be at
  lagging: false,
  trail: [], // [t, x, y] of the tip (lab frame)
  pivotTrail: [], // [t, x, y] of the base
  history: [], // [t, energy error]
  terms: null, // the core's energy terms of the state shown
  view: null, // the world point at the canvas centre (it follows a cart in jumps)
  lastFrame: 0,
  fps: 0,
  drag: null,
  failed: false,
};

// ---- Fields -> setup ---------------------------------------------------------------------------

const fmt = (x) => String(+x.toPrecision(12));

function number(field, text) {
  const s = String(text).trim();
  const v = Number(s);
  // "NaN" and "Infinity" are passed on: the core refuses them with its own message.
  if (s === "" || (Number.isNaN(v) && s !== "NaN")) {
    throw new FieldError(field, `${LABELS[field]}: ${s === "" ? "enter a number" : `"${s}" is not a number`}`);
  }
  return v;
}

function list(field, text, n, { optional = false } = {}) {
  const s = String(text).trim();
  if (s === "") {
    if (optional) return null;
    throw new FieldError(field, `${LABELS[field]}: enter one number for every link, or ${n} numbers`);
  }
  const values = s.split(/[\s,;]+/).filter(Boolean).map((tok) => number(field, tok));
  if (values.length === 1) return new Array(n).fill(values[0]);
  if (values.length !== n) {
    throw new FieldError(field, `${LABELS[field]}: expected 1 number or ${n} (one per link), got ${values.length}`);
  }
  return values;
}

/** A signal field (TOML inline, as in a scenario file): null when empty. */
function signalField(field, text) {
  const s = String(text).trim();
  if (s === "") return null;
  try {
    return parseInline(s);
  } catch (e) {
    if (!(e instanceof ScenarioError)) throw e;
    throw new FieldError(field, `${LABELS[field]}: ${e.message.replace(/^line 1: /, "")} (a number, or { kind = "sinusoid", ... } as in a scenario file)`);
  }
}

function optionalNumber(field, text) {
  return String(text).trim() === "" ? null : number(field, text);
}

function parseSpeed(text) {
  const allowed = [...form.elements.speed.options].map((o) => o.value);
  if (!allowed.includes(String(text))) {
    throw new FieldError("speed", `Speed must be one of ${allowed.join(", ")}, got "${text}"`);
  }
  return Number(text);
}

function parseFields(f) {
  const ntext = String(f.n).trim();
  const n = Number(ntext);
  if (!/^\d+$/.test(ntext) || n < 1 || n > MAX_N) {
    throw new FieldError("n", `N must be a whole number from 1 to ${MAX_N}, got "${ntext}"`);
  }
  const speed = parseSpeed(f.speed);
  const points = f.kind !== "rods";
  if (f.kind !== "points" && f.kind !== "rods") {
    throw new FieldError("kind", `Links must be "points" or "rods", got "${f.kind}"`);
  }
  const method = String(f.method);
  const pivot = { x: signalField("pivot_x", f.pivot_x), y: signalField("pivot_y", f.pivot_y) };
  const cartMass = optionalNumber("cart_mass", f.cart_mass);
  const torque = signalField("torque", f.torque);
  if (torque != null && (typeof torque !== "object" || Array.isArray(torque))) {
    throw new FieldError("torque", 'Torque: expected a table as in a scenario file\'s [torque], e.g. { kind = "constant", convention = "joint", value = [1, 0] }');
  }
  return {
    name: String(f.name ?? ""),
    kind: f.kind,
    lengths: list("lengths", f.lengths, n),
    masses: list("masses", f.masses, n),
    com: points ? list("com", f.com, n, { optional: true }) : null,
    inertia: points ? list("inertia", f.inertia, n, { optional: true }) : null,
    g: number("g", f.g),
    theta: list("theta", f.theta, n).map((x) => x * DEG),
    omega: list("omega", f.omega, n).map((x) => x * DEG),
    damping: list("damping", f.damping, n),
    friction: list("friction", f.friction, n),
    friction_velocity: optionalNumber("friction_velocity", f.friction_velocity),
    pivot: pivot.x == null && pivot.y == null ? null : Object.fromEntries(Object.entries(pivot).filter(([, v]) => v != null)),
    cart: cartMass == null ? null : {
      mass: cartMass, damping: number("cart_damping", f.cart_damping), x0: number("cart_x0", f.cart_x0),
      v0: number("cart_v0", f.cart_v0), force: signalField("cart_force", f.cart_force),
    },
    torque,
    method,
    dt: ADAPTIVE.has(method) ? 0 : number("dt", f.dt),
    rtol: ADAPTIVE.has(method) ? number("tol", f.tol) : CORE_DEFAULTS.rtol,
    atol: ADAPTIVE.has(method) ? number("atol", f.atol) : CORE_DEFAULTS.atol,
    speed,
  };
}

/** Apply fields: build a new simulation from them, or leave everything as it was and say why. */
function apply(fields, { keepPlaying = true, url = true } = {}) {
  let setup, sim;
  try {
    setup = parseFields(fields);
    sim = state.engine.simulation(setup);
  } catch (e) {
    if (!(e instanceof FieldError || e instanceof EngineError)) throw e;
    const field = e.field ?? FIELD_OF_MESSAGE.find(([re]) => re.test(e.message))?.[1];
    refuse(field, e.message);
    return false;
  }
  state.sim?.free();
  state.fields = { ...fields };
  state.setup = setup;
  state.sim = sim;
  writeForm(state.fields);
  markInvalid(null);
  hideMessage();
  restart();
  if (!keepPlaying) setPlaying(false);
  if (url) updateUrl(); // not on every pointer move while dragging: browsers throttle that
  return true;
}

function refuse(field, message) {
  markInvalid(field);
  showMessage(`Not applied: ${message}`);
}

function restart() {
  // The energy error is the core's, defined once for every report (never re-derived here).
  const s = state.setup;
  const ideal = !s.pivot && !s.cart && !s.torque && ![...s.damping, ...s.friction].some((v) => v !== 0);
  ui.errorLabel.textContent = ideal ? ERROR_LABEL : BALANCE_LABEL;
  for (const el of document.querySelectorAll("[data-term=cart]")) el.hidden = !s.cart;
  for (const el of document.querySelectorAll("[data-term=pivot]")) el.hidden = !s.pivot;
  state.view = null;
  state.clock = 0;
  state.trail = [];
  state.pivotTrail = [];
  state.history = [];
  state.failed = false;
  state.lagging = false;
  record();
  draw();
}

// ---- Form and URL ------------------------------------------------------------------------------

function readForm() {
  const f = { ...state.fields };
  for (const name of FIELDS) if (form.elements[name]) f[name] = form.elements[name].value;
  return f;
}

function writeForm(f) {
  for (const name of FIELDS) {
    const el = form.elements[name];
    if (el && el.value !== f[name]) el.value = f[name];
  }
  const adaptive = ADAPTIVE.has(f.method);
  for (const label of form.querySelectorAll("label[data-for]")) {
    const want = label.dataset.for;
    label.hidden = (want === "fixed" && adaptive) || (want === "adaptive" && !adaptive) || (want === "points" && f.kind === "rods")
      || (want === "cart" && String(f.cart_mass).trim() === "");
  }
  ui.name.textContent = f.name;
}

function markInvalid(field) {
  for (const el of form.querySelectorAll("input, select")) el.removeAttribute("aria-invalid");
  if (field && form.elements[field]) {
    form.elements[field].setAttribute("aria-invalid", "true");
    form.elements[field].closest("details")?.setAttribute("open", "");
  }
}

function showMessage(text, info = false) {
  ui.message.textContent = text;
  ui.message.classList.toggle("info", info);
  ui.message.hidden = false;
}

function hideMessage() {
  ui.message.hidden = true;
  ui.message.textContent = "";
}

function updateUrl() {
  const params = new URLSearchParams();
  for (const name of FIELDS) {
    const always = ["n", "kind", "lengths", "masses", "g", "theta", "method"].includes(name);
    const relevant = name === "dt" ? !ADAPTIVE.has(state.fields.method) : ["tol", "atol"].includes(name) ? ADAPTIVE.has(state.fields.method) : true;
    if (relevant && (always || state.fields[name] !== DEFAULTS[name])) params.set(name, state.fields[name]);
  }
  history.replaceState(null, "", `${location.pathname}?${params}`);
}

function fieldsFromUrl() {
  const params = new URLSearchParams(location.search);
  const f = { ...DEFAULTS };
  let any = false;
  for (const name of FIELDS) {
    if (params.has(name)) {
      f[name] = params.get(name);
      any = true;
    }
  }
  return any ? f : null;
}

/** Resize the per-link lists when N changes: cut, or repeat the last value. */
function resizeLists(f, n) {
  for (const name of LIST_FIELDS) {
    const parts = String(f[name]).split(/[\s,;]+/).filter(Boolean);
    if (parts.length > 1 && parts.length !== n) {
      while (parts.length < n) parts.push(parts[parts.length - 1]);
      f[name] = parts.slice(0, n).join(", ");
    }
  }
}

const compress = (values) => (values.every((v) => v === values[0]) ? fmt(values[0]) : values.map(fmt).join(", "));

/** Fields from a scenario (parsed TOML, or the JSON `multipendulum serve` makes). */
function fieldsFromScenario(s) {
  const f = { ...state.fields };
  f.name = s.name || "";
  f.n = String(s.lengths.length);
  f.kind = s.kind;
  f.lengths = compress(s.lengths);
  f.masses = compress(s.masses);
  f.com = s.com ? compress(s.com) : "";
  f.inertia = s.inertia ? compress(s.inertia) : "";
  f.g = fmt(s.g);
  f.theta = compress(s.theta.map((x) => x / DEG));
  f.omega = compress(s.omega.map((x) => x / DEG));
  // The losses and the drive: what the scenario gives, else none (not the previous setup's).
  f.damping = s.damping ? compress(s.damping) : DEFAULTS.damping;
  f.friction = s.friction ? compress(s.friction) : DEFAULTS.friction;
  f.friction_velocity = s.friction_velocity != null ? fmt(s.friction_velocity) : DEFAULTS.friction_velocity;
  const signal = (v) => (v == null ? "" : v.kind === "constant" && typeof v.value === "number" ? fmt(v.value) : toInline(v));
  f.pivot_x = signal(s.pivot?.x);
  f.pivot_y = signal(s.pivot?.y);
  f.cart_mass = s.cart ? fmt(s.cart.mass) : "";
  f.cart_damping = s.cart ? fmt(s.cart.damping ?? 0) : DEFAULTS.cart_damping;
  f.cart_x0 = s.cart ? fmt(s.cart.x0 ?? 0) : DEFAULTS.cart_x0;
  f.cart_v0 = s.cart ? fmt(s.cart.v0 ?? 0) : DEFAULTS.cart_v0;
  f.cart_force = signal(s.cart?.force);
  f.torque = s.torque ? toInline(s.torque) : "";
  f.method = s.method;
  if (s.dt != null) f.dt = fmt(s.dt);
  f.tol = fmt(s.rtol ?? CORE_DEFAULTS.rtol);
  f.atol = fmt(s.atol ?? CORE_DEFAULTS.atol);
  return f;
}

function applyScenario(s, source) {
  if (apply(fieldsFromScenario(s), { keepPlaying: false })) {
    const notes = s.notes?.length ? ` (${s.notes.join("; ")})` : "";
    showMessage(`Loaded ${source}${notes}. Press Play.`, true);
  }
}

// ---- Running -----------------------------------------------------------------------------------

function setPlaying(on) {
  state.playing = on && !state.failed;
  ui.play.textContent = state.playing ? "❚❚ Pause" : "▶ Play";
}

/** Bring the simulation to the display clock within the frame's time budget. */
function advance(target) {
  const sim = state.sim;
  const chunk = Math.max(1, Math.floor(4000 / sim.n));
  const deadline = performance.now() + FRAME_BUDGET_MS;
  let reached = false;
  while (!reached && performance.now() < deadline) reached = sim.advanceTo(target, chunk);
  return reached;
}

function guarded(fn) {
  try {
    fn();
  } catch (e) {
    if (!(e instanceof EngineError)) throw e;
    state.failed = true;
    setPlaying(false);
    showMessage(`Stopped: ${e.message}. Reset, or choose a smaller dt or tolerance.`);
  }
  record();
}

function record() {
  const sim = state.sim;
  const t = sim.t;
  const terms = (state.terms = sim.terms());
  const [bx, by] = terms.base;
  const tip = sim.positions().slice(-2);
  for (const [trail, x, y] of [[state.trail, bx + tip[0], by + tip[1]], [state.pivotTrail, bx, by]]) {
    const last = trail[trail.length - 1];
    if (!last || t > last[0]) trail.push([t, x, y]);
    while (trail.length > 2 && t - trail[0][0] > TRAIL_SECONDS) trail.shift();
  }
  const h = state.history;
  if (!h.length || t > h[h.length - 1][0]) {
    h.push([t, terms.residual]);
    if (h.length > PLOT_POINTS) state.history = h.filter((_, i) => i % 2 === 0 || i === h.length - 1);
  }
}

function frame(now) {
  requestAnimationFrame(frame);
  const wall = state.lastFrame ? Math.min((now - state.lastFrame) / 1000, 0.1) : 0;
  state.lastFrame = now;
  if (wall > 0) state.fps = state.fps ? 0.95 * state.fps + 0.05 / wall : 1 / wall;
  if (state.playing && state.sim) {
    state.clock += wall * state.setup.speed;
    guarded(() => {
      const reached = advance(state.clock);
      state.lagging = !reached;
      if (!reached) state.clock = state.sim.t; // no catching up: slow motion instead
    });
  }
  draw();
}

// ---- Drawing -----------------------------------------------------------------------------------

function fitCanvas(canvas) {
  const dpr = window.devicePixelRatio || 1;
  const w = Math.round(canvas.clientWidth * dpr);
  const h = Math.round(canvas.clientHeight * dpr);
  if (w > 0 && h > 0 && (canvas.width !== w || canvas.height !== h)) {
    canvas.width = w;
    canvas.height = h;
  }
  return dpr;
}

/** How far a pivot axis goes from the origin (m), read off its signal. */
function reach(sig) {
  if (sig == null) return 0;
  if (typeof sig === "number") return Math.abs(sig);
  if (sig.kind === "constant") return Math.abs(sig.value);
  if (sig.kind === "sinusoid") return Math.abs(sig.offset ?? 0) + Math.abs(sig.amplitude);
  return Math.max(...sig.values.map(Math.abs));
}

/** World (m) to canvas pixels: the origin (or, on a cart, a point of the rail that jumps to
 *  follow it) in the middle, the stretched chain and the pivot's travel just fit. */
function viewTransform() {
  const s = state.setup;
  const chain = s.lengths.reduce((a, b) => a + b, 0);
  const total = chain + Math.hypot(reach(s.pivot?.x), reach(s.pivot?.y));
  const size = Math.min(view.width, view.height);
  const scale = (0.47 * size) / total;
  if (state.view == null) state.view = [s.cart ? s.cart.x0 : 0, 0];
  if (s.cart && state.terms) {
    // Recentre when the cart nears the edge, in a jump: the rail's ticks show it moving.
    const x = state.terms.base[0];
    const half = (0.5 * view.width) / scale;
    if (Math.abs(x - state.view[0]) > 0.8 * half) state.view = [x, 0];
  }
  return { cx: view.width / 2 - state.view[0] * scale, cy: view.height / 2 + state.view[1] * scale, scale, total };
}

const linkColor = (i, n) => `hsl(${n > 1 ? 212 - (190 * i) / (n - 1) : 212}, 62%, 45%)`;

function draw() {
  if (!state.sim) return;
  const dpr = fitCanvas(view);
  const ctx = view.getContext("2d");
  const { cx, cy, scale, total } = viewTransform();
  const px = (x) => cx + x * scale;
  const py = (y) => cy - y * scale;
  ctx.clearRect(0, 0, view.width, view.height);
  const { lengths, masses, kind } = state.setup;
  const n = lengths.length;
  const [bx, by] = state.terms.base;
  const pos = state.sim.positions().map((v, i) => v + (i % 2 ? by : bx));

  if (state.setup.cart) drawRail(ctx, px, py, scale, total, dpr);
  if (state.setup.pivot) {
    // The pivot's recent path.
    ctx.strokeStyle = "rgba(29, 39, 51, 0.35)";
    ctx.lineWidth = 1.5 * dpr;
    ctx.beginPath();
    state.pivotTrail.forEach(([, x, y], i) => (i ? ctx.lineTo(px(x), py(y)) : ctx.moveTo(px(x), py(y))));
    ctx.stroke();
  }

  // The tip's trail, fading with age.
  const trail = state.trail;
  const now = state.sim.t;
  ctx.lineCap = "round";
  ctx.lineWidth = 2 * dpr;
  for (let i = 1; i < trail.length; i++) {
    const age = (now - trail[i][0]) / TRAIL_SECONDS;
    ctx.strokeStyle = `rgba(230, 120, 30, ${Math.max(0, 0.85 * (1 - age))})`;
    ctx.beginPath();
    ctx.moveTo(px(trail[i - 1][1]), py(trail[i - 1][2]));
    ctx.lineTo(px(trail[i][1]), py(trail[i][2]));
    ctx.stroke();
  }

  // Links, then bobs (point masses) on top.
  const shortest = Math.min(...lengths) * scale;
  const rodWidth = Math.min(Math.max(0.14 * shortest, 2.5 * dpr), 12 * dpr);
  ctx.lineWidth = kind === "rods" ? rodWidth : Math.max(1.5 * dpr, Math.min(3 * dpr, 0.05 * shortest));
  let x0 = bx, y0 = by;
  for (let i = 0; i < n; i++) {
    ctx.strokeStyle = kind === "rods" ? linkColor(i, n) : "#3b4652";
    ctx.beginPath();
    ctx.moveTo(px(x0), py(y0));
    ctx.lineTo(px(pos[2 * i]), py(pos[2 * i + 1]));
    ctx.stroke();
    x0 = pos[2 * i];
    y0 = pos[2 * i + 1];
  }
  if (kind !== "rods") {
    const heaviest = Math.max(...masses) || 1;
    const base = Math.min(Math.max(0.3 * shortest, 2.5 * dpr), 14 * dpr);
    for (let i = 0; i < n; i++) {
      const r = Math.max(1.5 * dpr, base * Math.cbrt(masses[i] / heaviest));
      ctx.fillStyle = linkColor(i, n);
      ctx.beginPath();
      ctx.arc(px(pos[2 * i]), py(pos[2 * i + 1]), r, 0, 2 * Math.PI);
      ctx.fill();
    }
  }
  // The pivot.
  ctx.fillStyle = "#1d2733";
  ctx.beginPath();
  ctx.arc(px(bx), py(by), 4 * dpr, 0, 2 * Math.PI);
  ctx.fill();

  drawPlot();
  readouts();
}

/** The cart's colour (the tests find the block by it). */
const CART_COLOR = "#a0722a";

/** The rail (y = 0) with ticks every `step` m, and the cart, a block centred on the pivot. */
function drawRail(ctx, px, py, scale, total, dpr) {
  const y = py(0);
  ctx.strokeStyle = "#9aa4ae";
  ctx.lineWidth = 2 * dpr;
  ctx.beginPath();
  ctx.moveTo(0, y);
  ctx.lineTo(view.width, y);
  ctx.stroke();
  const step = 10 ** Math.floor(Math.log10(total / 2));
  const left = (0 - px(0)) / scale, right = (view.width - px(0)) / scale;
  ctx.lineWidth = 1 * dpr;
  ctx.beginPath();
  for (let k = Math.ceil(left / step); k <= Math.floor(right / step); k++) {
    ctx.moveTo(px(k * step), y);
    ctx.lineTo(px(k * step), y + 6 * dpr);
  }
  ctx.stroke();
  const w = Math.max(24 * dpr, 0.18 * total * scale), h = 0.5 * w;
  ctx.fillStyle = CART_COLOR;
  ctx.fillRect(px(state.terms.base[0]) - w / 2, y - h / 2, w, h);
}

function drawPlot() {
  const dpr = fitCanvas(plot);
  const ctx = plot.getContext("2d");
  const W = plot.width, H = plot.height;
  ctx.clearRect(0, 0, W, H);
  const h = state.history;
  const floor = -17;
  const logs = h.map(([, e]) => (e > 0 ? Math.max(Math.log10(e), floor) : floor));
  let hi = Math.ceil(Math.max(-12, ...logs));
  let lo = Math.floor(Math.min(hi - 4, ...logs));
  const tMax = Math.max(1, h.length ? h[h.length - 1][0] : 0);
  const left = 44 * dpr, right = 8 * dpr, top = 8 * dpr, bottom = 18 * dpr;
  const X = (t) => left + ((W - left - right) * t) / tMax;
  const Y = (l) => top + ((H - top - bottom) * (hi - l)) / (hi - lo);
  ctx.font = `${10 * dpr}px system-ui, sans-serif`;
  ctx.fillStyle = "#66717d";
  ctx.strokeStyle = "#e6e9ed";
  ctx.lineWidth = 1;
  const every = Math.max(1, Math.ceil((hi - lo) / 5));
  ctx.textAlign = "right";
  ctx.textBaseline = "middle";
  for (let l = hi; l >= lo; l -= every) {
    ctx.beginPath();
    ctx.moveTo(left, Y(l));
    ctx.lineTo(W - right, Y(l));
    ctx.stroke();
    ctx.fillText(`1e${l}`, left - 4 * dpr, Y(l));
  }
  ctx.textAlign = "left";
  ctx.textBaseline = "bottom";
  ctx.fillText(`${ui.errorLabel.textContent} over t = 0 … ${fmt(+tMax.toFixed(1))} s`, left + 4 * dpr, H - 2 * dpr);
  if (!h.length) return;
  ctx.strokeStyle = "#2f6fb3";
  ctx.lineWidth = 1.5 * dpr;
  ctx.beginPath();
  h.forEach(([t], i) => (i ? ctx.lineTo(X(t), Y(logs[i])) : ctx.moveTo(X(t), Y(logs[i]))));
  ctx.stroke();
}

function readouts() {
  const sim = state.sim;
  const terms = state.terms;
  const joules = (v) => `${v.toPrecision(6)} J`;
  ui.t.textContent = `${sim.t.toFixed(3)} s`;
  ui.energy.textContent = `${terms.energy.toPrecision(9)} J`;
  ui.error.textContent = terms.residual.toExponential(2);
  ui.kinetic.textContent = joules(terms.kinetic);
  ui.potential.textContent = joules(terms.potential);
  ui.work.textContent = joules(terms.workIn);
  ui.work.title = `torque ${joules(terms.work.torque)}, pivot ${joules(terms.work.pivot)}, cart force ${joules(terms.work.cart)}`;
  ui.dissipated.textContent = joules(terms.dissipated);
  if (terms.cart) ui.cartX.textContent = `${terms.cart.x.toFixed(3)} m`;
  ui.pivot.textContent = `${terms.base[0].toFixed(4)}, ${terms.base[1].toFixed(4)} m`;
  ui.steps.textContent = String(sim.steps);
  ui.fps.textContent = state.playing && state.fps ? state.fps.toFixed(0) : "–";
  const s = state.setup;
  const how = ADAPTIVE.has(s.method) ? `rtol ${fmt(s.rtol)}` : `dt ${fmt(s.dt)} s`;
  const extras = [];
  if (s.damping.some((v) => v !== 0)) extras.push("damped");
  if (s.friction.some((v) => v !== 0)) extras.push("friction");
  if (s.pivot) extras.push(`moving pivot (${Object.keys(s.pivot).join(", ")})`);
  if (s.cart) extras.push(`on a ${fmt(s.cart.mass)} kg cart${s.cart.force != null ? " pushed" : ""}`);
  if (s.torque) extras.push(`${s.torque.convention ?? "generalized"} ${s.torque.kind} torque`);
  const what = `${s.lengths.length} ${s.kind === "rods" ? "rod" : "point mass"}${s.lengths.length > 1 ? (s.kind === "rods" ? "s" : "es") : ""}`
    + (extras.length ? `, ${extras.join(", ")}` : "");
  const lag = state.playing && state.lagging ? " · slower than real time: the integrator cannot keep up" : "";
  ui.status.textContent = `${what} · ${s.method}, ${how} · ${s.speed} × real time${lag}`;
}

// ---- Dragging links ----------------------------------------------------------------------------

/** The pointer in canvas pixels (inside the border, at the backing store's resolution). */
function pointer(e) {
  const rect = view.getBoundingClientRect();
  const k = view.width / view.clientWidth;
  return [(e.clientX - rect.left - view.clientLeft) * k, (e.clientY - rect.top - view.clientTop) * k];
}

/** The link under the pointer (index), within a few pixels, or -1. */
function linkAt(mx, my) {
  const { cx, cy, scale } = viewTransform();
  const pos = state.sim.positions();
  const [bx, by] = state.terms.base;
  const tolerance = 12 * (window.devicePixelRatio || 1);
  let best = -1, bestD = tolerance;
  let x0 = cx + bx * scale, y0 = cy - by * scale;
  for (let i = 0; i < state.sim.n; i++) {
    const x1 = cx + (bx + pos[2 * i]) * scale, y1 = cy - (by + pos[2 * i + 1]) * scale;
    const dx = x1 - x0, dy = y1 - y0;
    const u = Math.max(0, Math.min(1, ((mx - x0) * dx + (my - y0) * dy) / (dx * dx + dy * dy || 1)));
    const d = Math.hypot(mx - (x0 + u * dx), my - (y0 + u * dy));
    if (d <= bestD) { best = i; bestD = d; } // ties go to the outer link: its end is grabbed
    x0 = x1; y0 = y1;
  }
  return best;
}

view.addEventListener("pointerdown", (e) => {
  if (!state.sim) return;
  const [mx, my] = pointer(e);
  const link = linkAt(mx, my);
  if (link < 0) return;
  view.setPointerCapture(e.pointerId);
  state.drag = { link, wasPlaying: state.playing };
  setPlaying(false);
  dragTo(mx, my);
});

view.addEventListener("pointermove", (e) => {
  const [mx, my] = pointer(e);
  if (!state.drag) {
    if (state.sim) view.style.cursor = linkAt(mx, my) >= 0 ? "grab" : "default";
    return;
  }
  view.style.cursor = "grabbing";
  dragTo(mx, my);
});

function endDrag() {
  if (!state.drag) return;
  const { wasPlaying } = state.drag;
  state.drag = null;
  view.style.cursor = "default";
  updateUrl();
  setPlaying(wasPlaying);
}
view.addEventListener("pointerup", endDrag);
view.addEventListener("pointercancel", endDrag);

/** Point the dragged link at the pointer; the links below keep their absolute angles. */
function dragTo(mx, my) {
  const { cx, cy, scale } = viewTransform();
  const i = state.drag.link;
  const pos = state.sim.positions();
  const [x0, y0] = i > 0 ? [pos[2 * i - 2], pos[2 * i - 1]] : [0, 0];
  // The pointer relative to the pivot, as the positions are.
  const [bx, by] = state.terms.base;
  const wx = (mx - cx) / scale - bx, wy = (cy - my) / scale - by;
  const angle = Math.atan2(wx - x0, -(wy - y0)) / DEG;
  const theta = state.setup.theta.map((x) => x / DEG);
  theta[i] = Math.round(angle * 10) / 10;
  apply({ ...state.fields, theta: theta.map(fmt).join(", "), omega: "0" }, { url: false });
}

// ---- Controls ----------------------------------------------------------------------------------

form.addEventListener("change", (e) => {
  const f = readForm();
  if (e.target.name === "speed") {
    // Playback speed only: the run goes on.
    try {
      state.setup.speed = parseSpeed(f.speed);
      state.fields.speed = f.speed;
      updateUrl();
    } catch (err) {
      if (!(err instanceof FieldError)) throw err;
      refuse(err.field, err.message);
    }
    return;
  }
  if (e.target.name === "n" && /^\s*\d+\s*$/.test(f.n) && +f.n >= 1 && +f.n <= MAX_N) resizeLists(f, +f.n);
  apply(f);
});
form.addEventListener("submit", (e) => e.preventDefault());

ui.play.addEventListener("click", () => {
  if (state.failed) apply(state.fields);
  setPlaying(!state.playing);
});
ui.reset.addEventListener("click", () => apply(state.fields));
ui.step.addEventListener("click", () => {
  setPlaying(false);
  if (state.failed) return;
  guarded(() => state.sim.advanceTo(Infinity, 1));
  state.clock = state.sim.t;
  draw();
});
ui.share.addEventListener("click", async () => {
  updateUrl();
  try {
    await navigator.clipboard.writeText(location.href);
    showMessage("Link to this setup copied.", true);
  } catch {
    showMessage(`Link to this setup: ${location.href}`, true);
  }
});
ui.load.addEventListener("change", async () => {
  // The scenario, and the CSV files of its tables if they were chosen with it.
  const chosen = [...ui.load.files];
  ui.load.value = "";
  if (!chosen.length) return;
  const file = chosen.find((f) => /\.toml$/i.test(f.name)) ?? chosen[0];
  const others = new Map();
  for (const f of chosen) if (f !== file) others.set(f.name, await f.text());
  try {
    applyScenario(fromToml(parseToml(await file.text()), others), file.name);
  } catch (e) {
    if (!(e instanceof ScenarioError)) throw e;
    showMessage(`Cannot load ${file.name}: ${e.message}`);
  }
});
document.addEventListener("keydown", (e) => {
  if (e.key === " " && !["INPUT", "SELECT", "BUTTON", "SUMMARY"].includes(e.target.tagName)) {
    e.preventDefault();
    ui.play.click();
  }
});

// ---- Start -------------------------------------------------------------------------------------

async function main() {
  try {
    state.engine = await loadEngine();
  } catch (e) {
    showMessage(`The engine did not load: ${e.message}`);
    return;
  }
  Object.assign(DEFAULTS, { method: CORE_DEFAULTS.method, tol: fmt(CORE_DEFAULTS.rtol), atol: fmt(CORE_DEFAULTS.atol) });
  for (const m of METHODS) {
    const info = METHOD_INFO[m];
    const kind = info.adaptive ? "adaptive" : info.symplectic ? "symplectic" : "fixed step";
    form.elements.method.append(new Option(`${m} (order ${info.order}, ${kind})`, m));
  }
  const fromUrl = fieldsFromUrl();
  const scenario = new URLSearchParams(location.search).get("scenario");
  apply(DEFAULTS);
  if (fromUrl) apply(fromUrl);
  if (scenario) {
    const url = new URL(scenario, location.href);
    if (url.origin !== location.origin) {
      showMessage("Not loaded: a scenario must come from this page's own server.");
    } else {
      const response = await fetch(url);
      if (response.ok) applyScenario(await response.json(), url.pathname.split("/").pop());
      else showMessage(`Cannot load the scenario ${url.pathname}: HTTP ${response.status}`);
    }
  }
  window.multipendulum = { engine: state.engine, state, apply };
  document.body.dataset.ready = "true";
  requestAnimationFrame(frame);
}

main();
