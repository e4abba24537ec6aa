// The viewer page: form, canvas, readouts and energy-error plot around the engine (engine.js).
// Every value typed, loaded from a scenario or read from the URL goes through the same path:
// fields (strings) -> setup (numbers) -> a new simulation built by the core, which checks it.
// Nothing is applied unless the core accepts it; the message says what was refused.
import { ADAPTIVE, DEFAULTS as CORE_DEFAULTS, EngineError, LIMITS, loadEngine, METHOD_INFO, METHODS } from "./engine.js";
import { ChainView, fitCanvas, PhasePlot, reach } from "./draw.js";
import { fromToml, parseInline, parseToml, ScenarioError, toInline } from "./scenario.js";

const PLOT_POINTS = 1500;
const DEG = Math.PI / 180;
// The most links the page shows (the core's fact, read once the engine has loaded).
let MAX_LINKS = 0;
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
const phaseCanvas = $("phase");
const ui = {
  play: $("play"), step: $("step"), reset: $("reset"), share: $("share"), load: $("load"),
  message: $("message"), name: $("name"), status: $("status"),
  t: $("t"), energy: $("energy"), error: $("error"), errorLabel: $("error-label"), steps: $("steps"), fps: $("fps"),
  kinetic: $("kinetic"), potential: $("potential"), work: $("work"), dissipated: $("dissipated"), cartX: $("cart-x"),
  pivot: $("pivot"), phaseLink: $("phase-link"),
};

const state = {
  engine: null,
  fields: { ...DEFAULTS },
  setup: null,
  sim: null,
  playing: false,
  clock: 0, // the simulated time the display should be at
  lagging: false,
  chainView: null, // the canvas's drawing of the chain (draw.js)
  phase: new PhasePlot(phaseCanvas),
  history: [], // [t, energy error]
  terms: null, // the core's energy terms of the state shown
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
  if (!/^\d+$/.test(ntext) || n < 1 || n > MAX_LINKS) {
    throw new FieldError("n", `N must be a whole number from 1 to ${MAX_LINKS}, got "${ntext}"`);
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
    draggable: true, // the pivot or the cart can be pulled while the chain runs
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
  state.chainView = new ChainView(view, {
    lengths: s.lengths, masses: s.masses, kind: s.kind, cart: !!s.cart, x0: s.cart?.x0 ?? 0,
    reach: Math.hypot(reach(s.pivot?.x), reach(s.pivot?.y)),
  });
  state.phase.reset();
  if (+ui.phaseLink.value > s.lengths.length) ui.phaseLink.value = String(s.lengths.length);
  ui.phaseLink.max = String(s.lengths.length);
  state.clock = 0;
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
  state.chainView.record(t, sim.positions(), terms.base);
  const k = phaseIndex();
  state.phase.record(t, sim.theta()[k], sim.omega()[k]);
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
      const reached = state.sim.advanceWithin(state.clock);
      state.lagging = !reached;
      if (!reached) state.clock = state.sim.t; // no catching up: slow motion instead
    });
  }
  draw();
}

// ---- Drawing -----------------------------------------------------------------------------------

/** The link whose phase the small plot shows (0-based). */
function phaseIndex() {
  const k = Math.round(+ui.phaseLink.value) - 1;
  return Math.min(Math.max(Number.isFinite(k) ? k : 0, 0), state.sim.n - 1);
}

function draw() {
  if (!state.sim) return;
  const drag = state.drag;
  state.chainView.draw(state.sim.positions(), state.terms.base, { target: drag?.base ? drag.target : null });
  drawPlot();
  state.phase.draw(`link ${phaseIndex() + 1}`);
  readouts();
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

// ---- Dragging: a link sets the start, the base moves the running chain -----------------------
//
// Grabbing a link sets its starting angle (the run pauses and restarts from the new angles).
// Grabbing the pivot (or the cart) drags the base while the chain runs: the engine pulls the
// base towards the pointer as a critically damped spring (a pivot follows through the model's
// moving-pivot physics, a cart is pulled along its rail by a force), so the acceleration stays
// bounded however fast the pointer moves (crates/wasm: FOLLOW_RATE, FOLLOW_ACCELERATION).

view.addEventListener("pointerdown", (e) => {
  if (!state.sim || state.failed) return;
  const [mx, my] = state.chainView.pointer(e);
  const pos = state.sim.positions(), base = state.terms.base;
  if (state.chainView.onBase(mx, my, base)) {
    view.setPointerCapture(e.pointerId);
    state.drag = { base: true, target: base };
    setPlaying(true);
    pullTo(mx, my);
    return;
  }
  const link = state.chainView.linkAt(mx, my, pos, base);
  if (link < 0) return;
  view.setPointerCapture(e.pointerId);
  state.drag = { link, wasPlaying: state.playing };
  setPlaying(false);
  dragTo(mx, my);
});

view.addEventListener("pointermove", (e) => {
  const [mx, my] = state.chainView?.pointer(e) ?? [0, 0];
  if (!state.drag) {
    if (state.sim) {
      const base = state.terms.base;
      view.style.cursor = state.chainView.onBase(mx, my, base) ? "move"
        : state.chainView.linkAt(mx, my, state.sim.positions(), base) >= 0 ? "grab" : "default";
    }
    return;
  }
  view.style.cursor = state.drag.base ? "move" : "grabbing";
  if (state.drag.base) pullTo(mx, my);
  else dragTo(mx, my);
});

function endDrag() {
  if (!state.drag) return;
  const drag = state.drag;
  state.drag = null;
  view.style.cursor = "default";
  if (drag.base) {
    guarded(() => state.sim.release());
    return;
  }
  updateUrl();
  setPlaying(drag.wasPlaying);
}
view.addEventListener("pointerup", endDrag);
view.addEventListener("pointercancel", endDrag);

/** Pull the base towards the pointer (lab frame; a cart only along its rail). */
function pullTo(mx, my) {
  const { toWorld } = state.chainView.transform(state.terms.base);
  const [x, y] = toWorld(mx, my);
  state.drag.target = state.setup.cart ? [x, 0] : [x, y];
  guarded(() => state.sim.follow(...state.drag.target));
}

/** Point the dragged link at the pointer; the links below keep their absolute angles. */
function dragTo(mx, my) {
  const i = state.drag.link;
  const pos = state.sim.positions();
  const [x0, y0] = i > 0 ? [pos[2 * i - 2], pos[2 * i - 1]] : [0, 0];
  // The pointer relative to the pivot, as the positions are.
  const [bx, by] = state.terms.base;
  const [px, py] = state.chainView.transform(state.terms.base).toWorld(mx, my);
  const angle = Math.atan2(px - bx - x0, -(py - by - y0)) / DEG;
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
  if (e.target.name === "n" && /^\s*\d+\s*$/.test(f.n) && +f.n >= 1 && +f.n <= MAX_LINKS) resizeLists(f, +f.n);
  apply(f);
});
form.addEventListener("submit", (e) => e.preventDefault());
ui.phaseLink.addEventListener("change", () => {
  state.phase.reset();
  if (state.sim) record();
});

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
  MAX_LINKS = LIMITS.viewer_max_links;
  form.elements.n.max = String(MAX_LINKS);
  for (const m of METHODS) {
    const info = METHOD_INFO[m];
    const kind = info.adaptive ? "adaptive" : info.symplectic ? "symplectic" : "fixed step";
    form.elements.method.append(new Option(`${m} (order ${info.order}, ${kind})`, m));
  }
  const fromUrl = fieldsFromUrl();
  // `play=1` (the flip-map explorer's link to a cell): start running at once.
  const play = new URLSearchParams(location.search).get("play") === "1";
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
  if (play && !state.failed) setPlaying(true);
  window.multipendulum = { engine: state.engine, state, apply };
  document.body.dataset.ready = "true";
  requestAnimationFrame(frame);
}

main();
