// The notebook widget (multipendulum.notebook.Widget, made by mp.widget): the viewer's engine, the
// core compiled to WebAssembly (its bytes sent by Python), running a chain in a notebook cell.
// Python sets the setup (checked there first); every change restarts the run from its start
// state, built and checked again by the core, as the page's Apply does: a value the core refuses
// is not applied, and the widget says why. The state goes back to Python ten times a second.
// No physics here. Drag the pivot (or the cart) to shake the running chain, as on the page.
import { ADAPTIVE, EngineError, engineFromBytes, LIMITS } from "./engine.js";
import { ChainView, reach } from "./draw.js";
import { arrayBuffer, element, seconds, Ticker } from "./cell.js";

// The values Python sets that make a new run (`_restart`: Python's `restart()`).
const PARAMETERS = ["theta0", "omega0", "g", "damping", "friction", "method", "dt", "rtol", "atol", "cart_x0", "cart_v0", "_restart"];

/** The engine's setup (engine.js `simulation`) from the model: the chain and its drive, fixed
 *  when the widget was made, and the values Python may change. */
function setupOf(model) {
  const c = model.get("_chain");
  return {
    kind: "points", lengths: c.lengths, masses: c.masses, com: c.com, inertia: c.inertia,
    g: model.get("g"), damping: model.get("damping"), friction: model.get("friction"),
    friction_velocity: c.friction_velocity, pivot: c.pivot, torque: c.torque,
    cart: c.cart && { ...c.cart, x0: model.get("cart_x0"), v0: model.get("cart_v0") },
    method: model.get("method"), dt: model.get("dt") ?? 0, rtol: model.get("rtol"), atol: model.get("atol"),
    theta: model.get("theta0"), omega: model.get("omega0"),
    draggable: true,
  };
}

/** One widget's run, shared by its views. */
class Runner {
  constructor(model) {
    this.model = model;
    this.engine = null;
    this.sim = null;
    this.setup = null;
    this.terms = null;
    this.clock = 0;
    this.failed = false;
    this.lagging = false;
    this.message = "";
    this.reported = null;
    this.ticker = new Ticker((wall) => this.tick(wall), () => this.report());
  }

  async start() {
    try {
      this.engine = await engineFromBytes(new Uint8Array(arrayBuffer(this.model.get("_wasm"))));
    } catch (e) {
      this.say(`The engine did not load: ${e.message}`);
      return;
    }
    const n = this.model.get("_chain").lengths.length;
    if (n > LIMITS.viewer_max_links) {
      this.say(`This chain has ${n} links; the viewer shows at most ${LIMITS.viewer_max_links}. `
        + "Run it with mp.simulate and write a video with mp.animate(sol, path).");
      return;
    }
    this.rebuild();
    // Several values may change in one message (Python's `set`): one rebuild for all of them.
    let pending = false;
    const later = () => {
      if (pending) return;
      pending = true;
      queueMicrotask(() => {
        pending = false;
        this.rebuild();
      });
    };
    for (const name of PARAMETERS) this.model.on(`change:${name}`, later);
    // Play after a failed step starts again, as the button does.
    this.model.on("change:playing", () => {
      if (this.model.get("playing") && this.failed) this.rebuild();
    });
  }

  /** A new run from the model's setup, or, if the core refuses it, the old one and a message. */
  rebuild() {
    if (!this.engine) return false;
    let sim;
    try {
      sim = this.engine.simulation(setupOf(this.model));
    } catch (e) {
      if (!(e instanceof EngineError)) throw e;
      this.say(`Not applied: ${e.message}`);
      return false;
    }
    this.sim?.free();
    this.sim = sim;
    this.setup = sim.params;
    this.clock = 0;
    this.failed = false;
    this.lagging = false;
    this.message = "";
    for (const view of this.ticker.views) view.restart();
    this.record();
    this.report();
    this.ticker.drawAll();
    return true;
  }

  /** Show `text` in every view and tell Python (`error`). */
  say(text) {
    this.message = text;
    for (const view of this.ticker.views) view.draw();
    this.report();
  }

  /** Run `fn`; a failed step stops the run with the core's message. */
  guarded(fn) {
    try {
      fn();
    } catch (e) {
      if (!(e instanceof EngineError)) throw e;
      this.failed = true;
      this.model.set("playing", false);
      this.model.save_changes();
      this.say(`Stopped: ${e.message}. Press Play to start again, or choose a smaller dt or tolerance.`);
    }
    this.record();
  }

  tick(wall) {
    if (!this.sim || this.failed || !this.model.get("playing")) return;
    this.clock += wall * this.model.get("speed");
    this.guarded(() => {
      const reached = this.sim.advanceWithin(this.clock);
      this.lagging = !reached;
      if (!reached) this.clock = this.sim.t; // no catching up: slow motion instead
    });
  }

  record() {
    if (!this.sim) return;
    const terms = (this.terms = this.sim.terms());
    const pos = this.sim.positions();
    for (const view of this.ticker.views) view.chainView.record(this.sim.t, pos, terms.base);
  }

  toggle() {
    const play = !this.model.get("playing");
    this.model.set("playing", play);
    this.model.save_changes();
  }

  /** The state to Python, when it changed. */
  report() {
    const sim = this.sim;
    const key = `${sim ? sim.t : "-"} ${this.message}`;
    if (key === this.reported) return;
    this.reported = key;
    const state = { error: this.message };
    if (sim && this.terms) {
      const T = this.terms;
      Object.assign(state, {
        t: sim.t, theta: sim.theta(), omega: sim.omega(), energy: T.energy, kinetic: T.kinetic, potential: T.potential,
        work: T.workIn, dissipated: T.dissipated, energy_error: T.residual, base: T.base,
      });
    }
    this.model.set(state);
    this.model.save_changes();
  }

  free() {
    this.ticker.stop();
    this.sim?.free();
    this.sim = null;
  }
}

const joules = (v) => `${v.toPrecision(6)} J`;
const fmt = (x) => String(+x.toPrecision(12));

class WidgetView {
  constructor(runner, model, el) {
    this.runner = runner;
    this.model = model;
    this.drag = null;
    el.classList.add("multipendulum-widget");
    this.canvas = element("canvas.mp-view");
    this.play = element("button.mp-play", { type: "button" });
    this.reset = element("button.mp-reset", { type: "button", text: "↺ Reset" });
    this.time = element("output.mp-t");
    this.energy = element("output.mp-energy");
    this.terms = element("div.mp-terms");
    this.status = element("p.mp-status");
    this.message = element("div.mp-message", { role: "alert" });
    const bar = element("div.mp-bar");
    bar.append(this.play, this.reset, this.time, this.energy);
    el.append(this.canvas, bar, this.terms, this.status, this.message);
    this.play.addEventListener("click", () => runner.toggle());
    this.reset.addEventListener("click", () => runner.rebuild());
    this.sizeCanvas();
    model.on("change:height", () => this.sizeCanvas());
    this.restart();
    this.listen();
  }

  sizeCanvas() {
    this.canvas.style.height = `${this.model.get("height")}px`;
  }

  /** A new run: fresh trails, the view fitted to the chain and its drive. */
  restart() {
    const c = this.model.get("_chain");
    this.chainView = new ChainView(this.canvas, {
      lengths: c.lengths, masses: c.masses, kind: c.look, cart: !!c.cart, x0: this.model.get("cart_x0"),
      reach: Math.hypot(reach(c.pivot?.x), reach(c.pivot?.y)),
    });
  }

  draw() {
    const r = this.runner;
    this.message.textContent = r.message;
    this.message.hidden = !r.message;
    this.play.textContent = this.model.get("playing") ? "❚❚ Pause" : "▶ Play";
    if (!r.sim || !r.terms) return;
    const T = r.terms;
    this.chainView.draw(r.sim.positions(), T.base, { target: this.drag ? this.drag.target : null });
    this.time.textContent = `t = ${seconds(r.sim.t)}`;
    this.energy.textContent = `E = ${T.energy.toPrecision(9)} J`;
    const parts = [`kinetic ${joules(T.kinetic)}`, `potential ${joules(T.potential)}`];
    if (T.workIn !== 0) parts.push(`work in ${joules(T.workIn)}`);
    if (T.dissipated !== 0) parts.push(`dissipated ${joules(T.dissipated)}`);
    parts.push(`energy error ${T.residual.toExponential(2)}`);
    this.terms.textContent = parts.join(" · ");
    const s = r.setup;
    const n = s.lengths.length;
    const look = this.model.get("_chain").look;
    const how = ADAPTIVE.has(s.method) ? `rtol ${fmt(s.rtol)}` : `dt ${fmt(s.dt)} s`;
    const lag = this.model.get("playing") && r.lagging ? " · slower than real time: the integrator cannot keep up" : "";
    this.status.textContent = `${n} ${look === "rods" ? "rod" : "point mass"}${n > 1 ? (look === "rods" ? "s" : "es") : ""}`
      + `${s.cart ? " on a cart" : ""} · ${s.method}, ${how} · ${this.model.get("speed")} × real time${lag}`;
  }

  // Dragging the base (the pivot, or the cart along its rail) while the chain runs, as on the
  // page: the engine pulls the base towards the pointer within its acceleration bound.
  listen() {
    const canvas = this.canvas;
    canvas.addEventListener("pointerdown", (e) => {
      const r = this.runner;
      if (!r.sim || r.failed || !r.terms) return;
      const [mx, my] = this.chainView.pointer(e);
      if (!this.chainView.onBase(mx, my, r.terms.base)) return;
      canvas.setPointerCapture(e.pointerId);
      this.drag = { target: r.terms.base };
      if (!this.model.get("playing")) r.toggle();
      this.pullTo(mx, my);
    });
    canvas.addEventListener("pointermove", (e) => {
      const r = this.runner;
      if (!r.terms) return;
      const [mx, my] = this.chainView.pointer(e);
      if (this.drag) this.pullTo(mx, my);
      else canvas.style.cursor = this.chainView.onBase(mx, my, r.terms.base) ? "move" : "default";
    });
    const end = () => {
      if (!this.drag) return;
      this.drag = null;
      canvas.style.cursor = "default";
      if (this.runner.sim && !this.runner.failed) this.runner.guarded(() => this.runner.sim.release());
    };
    canvas.addEventListener("pointerup", end);
    canvas.addEventListener("pointercancel", end);
  }

  pullTo(mx, my) {
    const r = this.runner;
    const [x, y] = this.chainView.transform(r.terms.base).toWorld(mx, my);
    this.drag.target = r.setup.cart ? [x, 0] : [x, y];
    r.guarded(() => r.sim.follow(...this.drag.target));
  }
}

export default () => {
  let runner = null;
  return {
    async initialize({ model }) {
      runner = new Runner(model);
      await runner.start();
      return () => runner.free();
    },
    render({ model, el }) {
      const view = new WidgetView(runner, model, el);
      runner.ticker.attach(view);
      runner.record();
      view.draw();
      return () => runner.ticker.detach(view);
    },
  };
};
