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
/** The core's defaults: { rtol, atol, max_steps, method }. */
export let DEFAULTS = {};
/** Per method: { order, symplectic, implicit, adaptive, needs_dt, forms }. */
export let METHOD_INFO = {};

const DONE = 0;
const BUDGET = 1;
const INPUT_ERROR = -1;

/** Load the module (next to this file unless `url` says otherwise). */
export async function loadEngine(url = new URL("./multipendulum.wasm", import.meta.url)) {
  const response = await fetch(url);
  if (!response.ok) {
    throw new Error(`cannot load ${url}: HTTP ${response.status} (run \`make build\` to build it)`);
  }
  // Not instantiateStreaming: some static servers do not send application/wasm.
  const { instance } = await WebAssembly.instantiate(await response.arrayBuffer(), {});
  const engine = new Engine(instance.exports);
  const facts = engine.facts();
  METHODS = facts.method_order;
  METHOD_INFO = facts.methods;
  ADAPTIVE = new Set(METHODS.filter((m) => facts.methods[m].adaptive));
  DEFAULTS = facts.defaults;
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
   * Start a simulation at t = 0. `p`: { kind: "points" | "rods", lengths, masses, com?, inertia?,
   * g, method, dt, rtol, atol, theta (rad), omega (rad/s) }. Arrays have one entry per link.
   * Throws EngineError for values the core refuses.
   */
  simulation(p) {
    const n = p.lengths.length;
    const same = (name) => {
      const a = p[name];
      if (a != null && a.length !== n) {
        throw new EngineError(`${name} must have ${n} entries (one per link), got ${a.length}`, "input");
      }
    };
    ["masses", "com", "inertia", "theta", "omega"].forEach(same);
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
    try {
      const handle = this.x.mp_sim_new(
        n, p.kind === "rods" ? 1 : 0, put(p.lengths), put(p.masses), put(p.com), put(p.inertia),
        p.g, namePtr, name.length, p.dt ?? 0, p.rtol ?? DEFAULTS.rtol, p.atol ?? DEFAULTS.atol,
        put(p.theta), put(p.omega ?? new Array(n).fill(0)),
      );
      if (handle === 0) throw new EngineError(this.lastError(), "input");
      return new Simulation(this, handle, n, p);
    } finally {
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
    this.bytes = 16 * n;
    this.buf = this.x.mp_alloc(this.bytes); // 2N f64 for results
  }

  /** Advance towards time `t` with at most `maxSteps` steps; true once reached. Throws
   *  EngineError if the run cannot continue (the state stays at the last good one). */
  advanceTo(t, maxSteps = 1e6) {
    const status = this.x.mp_sim_advance(this.handle, t, Math.min(maxSteps, 4294967295) >>> 0);
    if (status === DONE) return true;
    if (status === BUDGET) return false;
    throw new EngineError(this.engine.lastError(), status === INPUT_ERROR ? "input" : "integration");
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
  /** Joint positions [x0, y0, x1, y1, ...] (m), far end of each link; the pivot is the origin. */
  positions() { return this.read(this.x.mp_sim_positions, 2 * this.n); }

  free() {
    if (this.handle) {
      this.x.mp_sim_free(this.handle);
      this.x.mp_free(this.buf, this.bytes);
      this.handle = 0;
    }
  }
}
