// The engine: multipendulum's Rust core compiled to WebAssembly (crates/wasm), wrapped for
// JavaScript. No physics here: this module moves numbers in and out of the module's memory and
// turns failed calls into EngineError with the core's own message.

/** A failed call: `message` is the core's (e.g. "lengths[1] must be > 0 and finite, got -1");
 *  `kind` is "input" (bad values) or "integration" (the run could not continue). */
export class EngineError extends Error {
  constructor(message, kind) {
    super(message);
    this.name = "EngineError";
    this.kind = kind;
  }
}

// The core's facts, read from the module once it is loaded (`loadEngine`): integrator names
// shared with the Python package and the CLI, which of them adapt their step, the defaults.
/** Integrator names, in the core's order. */
export let METHODS = [];
/** The methods that choose their own step (tolerances instead of dt). */
export let ADAPTIVE = new Set();
/** The core's defaults: { rtol, atol, max_steps, friction_velocity, method }. */
export let DEFAULTS = {};
/** Per method: { order, symplectic, implicit, adaptive, needs_dt, forms }. */
export let METHOD_INFO = {};
/** The core's limits: { min_rtol, max_angle, max_chaos_steps, viewer_max_links, ... }. */
export let LIMITS = {};

const DONE = 0;
const BUDGET = 1;
const INPUT_ERROR = -1;
// The signal forms of crates/wasm (SIGNAL_*).
const SIGNAL = { constant: 0, sinusoid: 1, linear: 2, cubic: 3 };
const TERMS = 12;
/** Integration time per animation frame (ms): beyond it a run shows in slow motion instead. */
export const FRAME_BUDGET_MS = 10;

/** Load the module (next to this file unless `url` says otherwise). */
export async function loadEngine(url = new URL("./multipendulum.wasm", import.meta.url)) {
  const response = await fetch(url);
  if (!response.ok) {
    throw new Error(`cannot load ${url}: HTTP ${response.status} (run \`make build\` to build it)`);
  }
  // Not instantiateStreaming: some static servers do not send application/wasm.
  return engineFromBytes(await response.arrayBuffer());
}

/** The engine from the module's bytes (an ArrayBuffer or a view of one: the notebook widget
 *  gets them from Python, not from a URL); reads the core's facts as `loadEngine` does. */
export async function engineFromBytes(bytes) {
  const { instance } = await WebAssembly.instantiate(bytes, {});
  const engine = new Engine(instance.exports);
  const facts = engine.facts();
  METHODS = facts.method_order;
  METHOD_INFO = facts.methods;
  ADAPTIVE = new Set(METHODS.filter((m) => facts.methods[m].adaptive));
  DEFAULTS = facts.defaults;
  LIMITS = facts.limits;
  return engine;
}

export class Engine {
  constructor(exports) {
    this.x = exports;
  }

  f64(ptr, n) {
    return new Float64Array(this.x.memory.buffer, ptr, n);
  }

  /** The core's facts (methods, defaults, limits), as the module states them. */
  facts() {
    // The calls first: the first one builds the text and may grow (and so detach) the memory.
    const ptr = this.x.mp_facts_ptr();
    const len = this.x.mp_facts_len();
    return JSON.parse(new TextDecoder().decode(new Uint8Array(this.x.memory.buffer, ptr, len)));
  }

  lastError() {
    const bytes = new Uint8Array(this.x.memory.buffer, this.x.mp_error_ptr(), this.x.mp_error_len());
    return new TextDecoder().decode(bytes);
  }

  /** Copy `values` (or nothing, for null) into fresh memory; returns [ptr, bytes]. */
  put(values) {
    if (values == null) return [0, 0];
    const bytes = 8 * Math.max(values.length, 1);
    const ptr = this.x.mp_alloc(bytes);
    this.f64(ptr, values.length).set(values);
    return [ptr, bytes];
  }

  /**
   * A signal as the module takes it: [kind, rows, data]. `s` is a number (a constant), or
   * { kind: "constant", value } | { kind: "sinusoid", amplitude, frequency, phase?, offset? } |
   * { kind: "table", t, values, interpolation? } (values: one row per time). `n`: the columns
   * (one per link for a torque, else null: one number each).
   */
  signal(s, what, n = null, cubicOnly = false) {
    const bad = (msg) => { throw new EngineError(`${what}: ${msg}`, "input"); };
    const values = (v, name) => {
      const a = n == null ? [v] : Array.isArray(v) ? v : new Array(n).fill(v);
      if (!a.every((x) => typeof x === "number")) bad(`${name} must be ${n == null ? "a number" : "numbers"}`);
      if (n != null && a.length !== n) bad(`${name} must have ${n} entries (one per link), got ${a.length}`);
      return a;
    };
    if (typeof s === "number") return [SIGNAL.constant, 0, values(s, "value")];
    if (s == null || typeof s !== "object") bad(`expected a number or a signal { kind, ... }, got ${s}`);
    if (s.kind === "constant") return [SIGNAL.constant, 0, values(s.value, "value")];
    if (s.kind === "sinusoid") {
      return [SIGNAL.sinusoid, 0, ["amplitude", "frequency", "phase", "offset"].flatMap(
        (k) => values(s[k] ?? (k === "phase" || k === "offset" ? 0 : undefined), k))];
    }
    if (s.kind === "table") {
      const interp = s.interpolation ?? (cubicOnly ? "cubic" : "linear");
      if (interp !== "linear" && interp !== "cubic") bad(`interpolation must be "linear" or "cubic", got ${JSON.stringify(interp)}`);
      if (!Array.isArray(s.t) || !Array.isArray(s.values)) bad("a table needs the arrays t and values");
      const rows = s.values.map((row, i) => {
        const r = n == null ? (Array.isArray(row) ? row : [row]) : row;
        if (!Array.isArray(r) || r.length !== (n ?? 1)) bad(`values[${i}] must have ${n ?? 1} entries, got ${Array.isArray(r) ? r.length : 1}`);
        return r;
      });
      return [SIGNAL[interp], s.t.length, [...s.t, ...rows.flat()]];
    }
    return bad(`kind must be "constant", "sinusoid" or "table", got ${JSON.stringify(s.kind)}`);
  }

  /**
   * First-flip times of undriven double pendulums, by the core's lane kernel: `p` is a chain as
   * for `simulation` (2 links; kind, lengths, masses, com?, inertia?, g), `theta` and `omega`
   * hold the initial states row by row (2 values each), rk4 at `dt` up to `tMax`, `link` 0 or 1
   * (null: either). Returns a Float64Array of times (Infinity: no flip before tMax).
   */
  firstFlips(p, theta, omega, tMax, dt, link = null) {
    const b = theta.length / 2;
    if (!Number.isInteger(b) || omega.length !== theta.length) {
      throw new EngineError("theta and omega must both hold 2 values per pendulum", "input");
    }
    const allocs = [];
    const put = (v) => {
      const a = this.put(v);
      allocs.push(a);
      return a[0];
    };
    try {
      const out = put(new Array(b).fill(0));
      const status = this.x.mp_first_flips(
        p.kind === "rods" ? 1 : 0, put(p.lengths), put(p.masses), put(p.com), put(p.inertia), p.g,
        put(theta), put(omega), b, tMax, dt, link == null ? -1 : link, out,
      );
      if (status < 0) throw new EngineError(this.lastError(), "input");
      return Float64Array.from(this.f64(out, b));
    } finally {
      for (const [ptr, bytes] of allocs) if (ptr) this.x.mp_free(ptr, bytes);
    }
  }

  /**
   * Start a simulation at t = 0. `p`: { kind: "points" | "rods", lengths, masses, com?, inertia?,
   * g, method, dt, rtol, atol, theta (rad), omega (rad/s) }, and optionally the losses and the
   * base: damping (N m s/rad) and friction (N m), one per joint; friction_velocity (rad/s);
   * cart: { mass, damping?, x0?, v0?, force? }; pivot: { x?, y? } (m); torque: { convention:
   * "generalized" | "joint", kind, ... } (N m, one column per link). Signals as in `signal`.
   * `draggable: true` lets the base be pulled while it runs (`Simulation.follow`).
   * Arrays have one entry per link. Throws EngineError for values the core refuses.
   */
  simulation(p) {
    const n = p.lengths.length;
    const same = (name) => {
      const a = p[name];
      if (a != null && a.length !== n) {
        throw new EngineError(`${name} must have ${n} entries (one per link), got ${a.length}`, "input");
      }
    };
    ["masses", "com", "inertia", "theta", "omega", "damping", "friction"].forEach(same);
    const allocs = [];
    const put = (v) => {
      const a = this.put(v);
      allocs.push(a);
      return a[0];
    };
    const name = new TextEncoder().encode(String(p.method));
    const namePtr = this.x.mp_alloc(Math.max(name.length, 1));
    allocs.push([namePtr, Math.max(name.length, 1)]);
    new Uint8Array(this.x.memory.buffer, namePtr, name.length).set(name);
    const setup = this.x.mp_setup_new();
    const check = (status) => {
      if (status < 0) throw new EngineError(this.lastError(), "input");
    };
    const signal = (fn, sig) => {
      const [kind, rows, data] = sig;
      check(fn(kind, rows, put(data), data.length));
    };
    try {
      if (p.draggable) this.x.mp_setup_draggable(setup);
      if (p.damping != null || p.friction != null || p.friction_velocity != null) {
        this.x.mp_setup_losses(setup, n, put(p.damping), put(p.friction), p.friction_velocity ?? DEFAULTS.friction_velocity);
      }
      if (p.cart != null) {
        const c = p.cart;
        this.x.mp_setup_cart(setup, c.mass, c.damping ?? 0, c.x0 ?? 0, c.v0 ?? 0);
        if (c.force != null) {
          signal((...a) => this.x.mp_setup_cart_force(setup, ...a), this.signal(c.force, "cart_force"));
        }
      }
      for (const [i, axis] of ["x", "y"].entries()) {
        if (p.pivot?.[axis] != null) {
          signal((...a) => this.x.mp_setup_pivot(setup, i, ...a), this.signal(p.pivot[axis], `pivot ${axis}`, null, true));
        }
      }
      if (p.torque != null) {
        const conv = p.torque.convention ?? "generalized";
        if (conv !== "generalized" && conv !== "joint") {
          throw new EngineError(`torque.convention must be "generalized" or "joint", got ${JSON.stringify(conv)}`, "input");
        }
        signal((...a) => this.x.mp_setup_torque(setup, conv === "joint" ? 1 : 0, ...a), this.signal(p.torque, "torque", n));
      }
      const handle = this.x.mp_sim_new(
        n, p.kind === "rods" ? 1 : 0, put(p.lengths), put(p.masses), put(p.com), put(p.inertia),
        p.g, namePtr, name.length, p.dt ?? 0, p.rtol ?? DEFAULTS.rtol, p.atol ?? DEFAULTS.atol,
        put(p.theta), put(p.omega ?? new Array(n).fill(0)), setup,
      );
      if (handle === 0) throw new EngineError(this.lastError(), "input");
      return new Simulation(this, handle, n, p);
    } finally {
      this.x.mp_setup_free(setup);
      for (const [ptr, bytes] of allocs) if (ptr) this.x.mp_free(ptr, bytes);
    }
  }
}

export class Simulation {
  constructor(engine, handle, n, params) {
    this.engine = engine;
    this.x = engine.x;
    this.handle = handle;
    this.n = n;
    this.params = params;
    this.bytes = 8 * Math.max(2 * n, TERMS);
    this.buf = this.x.mp_alloc(this.bytes); // 2N f64 (or the terms) for results
    this.hasCart = params.cart != null;
  }

  /** Advance towards time `t` with at most `maxSteps` steps; true once reached. Throws
   *  EngineError if the run cannot continue (the state stays at the last good one). */
  advanceTo(t, maxSteps = 1e6) {
    const status = this.x.mp_sim_advance(this.handle, t, Math.min(maxSteps, 4294967295) >>> 0);
    if (status === DONE) return true;
    if (status === BUDGET) return false;
    throw new EngineError(this.engine.lastError(), status === INPUT_ERROR ? "input" : "integration");
  }

  /** Advance towards time `t` for at most `budgetMs` of wall time, in chunks of steps sized
   *  by N (a frame's share of the page or the widget); true once reached. */
  advanceWithin(t, budgetMs = FRAME_BUDGET_MS) {
    const chunk = Math.max(1, Math.floor(4000 / this.n));
    const deadline = performance.now() + budgetMs;
    let reached = false;
    while (!reached && performance.now() < deadline) reached = this.advanceTo(t, chunk);
    return reached;
  }

  get t() { return this.x.mp_sim_t(this.handle); }
  get energy() { return this.x.mp_sim_energy(this.handle); }
  get initialEnergy() { return this.x.mp_sim_initial_energy(this.handle); }
  /** The energy error as the core defines it for every report: |E - E0 - W| over the scale
   *  g sum |h_i| + max T (the potential well's depth plus the largest kinetic energy so far). */
  get energyError() { return this.x.mp_sim_energy_error(this.handle); }
  get steps() { return this.x.mp_sim_steps(this.handle); }
  get evaluations() { return this.x.mp_sim_evaluations(this.handle); }

  read(fn, count) {
    fn(this.handle, this.buf);
    return Array.from(this.engine.f64(this.buf, count));
  }
  theta() { return this.read(this.x.mp_sim_theta, this.n); }
  omega() { return this.read(this.x.mp_sim_omega, this.n); }
  /** Joint positions [x0, y0, x1, y1, ...] (m), far end of each link, relative to the pivot
   *  (add `base()` for the lab frame). */
  positions() { return this.read(this.x.mp_sim_positions, 2 * this.n); }
  /** The base's position [x, y] (m): the pivot's (the origin when fixed), or the cart's at y = 0. */
  base() { return this.read(this.x.mp_sim_base, 2); }

  check(status) {
    if (status < 0) throw new EngineError(this.engine.lastError(), status === INPUT_ERROR ? "input" : "integration");
  }

  /** The base's motion now: { pos: [x, y], vel, acc } (a cart's along the rail, acc zero). */
  baseMotion() {
    this.check(this.x.mp_sim_base_motion(this.handle, this.buf));
    const [x, y, vx, vy, ax, ay] = this.engine.f64(this.buf, 6);
    return { pos: [x, y], vel: [vx, vy], acc: [ax, ay] };
  }

  /** Pull the base towards (x, y) (m, lab frame) from now on: a pivot follows as a critically
   *  damped spring through the moving-pivot physics, a cart is pulled by a force; the
   *  acceleration stays bounded (the engine's FOLLOW_RATE and FOLLOW_ACCELERATION). */
  follow(x, y) { this.check(this.x.mp_sim_follow(this.handle, x, y)); }

  /** The pointer let go: a cart gets its own force back, a pivot settles where it was pulled. */
  release() { this.check(this.x.mp_sim_release(this.handle)); }

  /** The energy terms of the current state, as the core computes them (J, lab frame, work since
   *  t = 0): { kinetic, potential, energy, work: { torque, pivot, cart }, workIn (their sum),
   *  dissipated, residual (the balance's, = energyError), base: [x, y], cart: { x, v } | null }. */
  terms() {
    const status = this.x.mp_sim_terms(this.handle, this.buf);
    if (status < 0) throw new EngineError(this.engine.lastError(), status === INPUT_ERROR ? "input" : "integration");
    const [kinetic, potential, energy, torque, pivot, cart, dissipated, residual, bx, by, x, v] = this.engine.f64(this.buf, TERMS);
    return {
      kinetic, potential, energy, work: { torque, pivot, cart }, workIn: torque + pivot + cart, dissipated, residual,
      base: [bx, by], cart: this.hasCart ? { x, v } : null,
    };
  }

  free() {
    if (this.handle) {
      this.x.mp_sim_free(this.handle);
      this.x.mp_free(this.buf, this.bytes);
      this.handle = 0;
    }
  }
}
