// The notebook player (multipendulum._notebook.Player, made by mp.show or sol.show()): a computed
// solution's frames, sent by Python, drawn as the viewer draws a running chain. No physics and
// no video: Python sends the joint positions of each frame (relative to the base) and the base's
// position; this plays them at `speed` simulated seconds per second, with a time slider.
import { ChainView, TRAIL_SECONDS } from "./draw.js";
import { arrayBuffer, element, seconds, Ticker } from "./cell.js";

/** One widget's playback, shared by its views. */
class Playback {
  constructor(model) {
    this.model = model;
    this.chain = model.get("_chain");
    this.n = this.chain.lengths.length;
    this.t = new Float64Array(arrayBuffer(model.get("_t")));
    this.pos = new Float32Array(arrayBuffer(model.get("_positions")));
    this.base = new Float32Array(arrayBuffer(model.get("_base")));
    this.t0 = this.t[0];
    this.t1 = this.t[this.t.length - 1];
    this.clock = this.clamp(model.get("time"));
    this.k = this.index(this.clock);
    this.reported = null;
    this.ticker = new Ticker((wall) => this.tick(wall), () => this.report());
    // Python seeks by setting `time`; our own reports come back as changes too.
    model.on("change:time", () => {
      const t = model.get("time");
      if (t !== this.reported) this.seek(t);
    });
  }

  clamp(t) {
    return Math.min(Math.max(Number.isFinite(t) ? t : this.t0, this.t0), this.t1);
  }

  /** The last frame at or before time t. */
  index(t) {
    let lo = 0, hi = this.t.length - 1;
    while (lo < hi) {
      const mid = (lo + hi + 1) >> 1;
      if (this.t[mid] <= t) lo = mid;
      else hi = mid - 1;
    }
    return lo;
  }

  positions(k) {
    return this.pos.subarray(2 * this.n * k, 2 * this.n * (k + 1));
  }

  basePosition(k) {
    return [this.base[2 * k], this.base[2 * k + 1]];
  }

  /** Add frames from+1..to to a view's trails. */
  record(view, from, to) {
    for (let k = Math.max(from + 1, 0); k <= to; k++) view.chainView.record(this.t[k], this.positions(k), this.basePosition(k));
  }

  /** Show time t: every view's trails start again from the frames of the trail's length before it. */
  seek(t) {
    this.clock = this.clamp(t);
    this.k = this.index(this.clock);
    for (const view of this.ticker.views) this.fill(view);
  }

  fill(view) {
    view.chainView.reset();
    this.record(view, this.index(this.clock - TRAIL_SECONDS) - 1, this.k);
  }

  tick(wall) {
    if (!this.model.get("playing")) return;
    let clock = this.clock + wall * this.model.get("speed");
    if (clock > this.t1) {
      if (this.model.get("loop") && this.t1 > this.t0) {
        this.seek(this.t0);
        return;
      }
      clock = this.t1;
      this.model.set("playing", false);
      this.model.save_changes();
    }
    const k = this.index(clock);
    for (const view of this.ticker.views) this.record(view, this.k, k);
    this.clock = clock;
    this.k = k;
  }

  toggle() {
    const play = !this.model.get("playing");
    if (play && this.clock >= this.t1) this.seek(this.t0);
    this.model.set("playing", play);
    this.model.save_changes();
  }

  report() {
    if (this.clock === this.reported) return;
    this.reported = this.clock;
    this.model.set("time", this.clock);
    this.model.save_changes();
  }
}

class PlayerView {
  constructor(playback, model, el) {
    this.playback = playback;
    this.model = model;
    el.classList.add("multipendulum-widget");
    this.canvas = element("canvas.mp-view");
    this.play = element("button.mp-play", { type: "button" });
    this.slider = element("input.mp-slider", { type: "range", min: playback.t0, max: playback.t1, step: "any", "aria-label": "time" });
    this.time = element("output.mp-t");
    this.status = element("p.mp-status");
    const bar = element("div.mp-bar");
    bar.append(this.play, this.slider, this.time);
    el.append(this.canvas, bar, this.status);
    const c = playback.chain;
    this.chainView = new ChainView(this.canvas, { lengths: c.lengths, masses: c.masses, kind: c.kind, cart: c.cart, x0: c.x0, reach: c.reach });
    this.play.addEventListener("click", () => playback.toggle());
    this.holding = false; // the slider is being dragged: it sets the time, not the other way round
    this.slider.addEventListener("pointerdown", () => { this.holding = true; });
    for (const type of ["pointerup", "pointercancel", "change"]) this.slider.addEventListener(type, () => { this.holding = false; });
    this.slider.addEventListener("input", () => {
      playback.seek(+this.slider.value);
      playback.report();
    });
    this.sizeCanvas();
    model.on("change:height", () => this.sizeCanvas());
    const links = `${playback.n} ${c.kind === "rods" ? "rod" : "point mass"}${playback.n > 1 ? (c.kind === "rods" ? "s" : "es") : ""}`;
    const note = model.get("_note");
    this.statusText = `${links}${c.cart ? " on a cart" : ""} · ${playback.t.length} frames over ${seconds(playback.t1 - playback.t0)}${note ? ` · ${note}` : ""}`;
    playback.fill(this);
  }

  sizeCanvas() {
    this.canvas.style.height = `${this.model.get("height")}px`;
  }

  draw() {
    const p = this.playback;
    this.chainView.draw(p.positions(p.k), p.basePosition(p.k));
    this.play.textContent = this.model.get("playing") ? "❚❚ Pause" : "▶ Play";
    if (!this.holding) this.slider.value = String(p.clock);
    this.time.textContent = `t = ${seconds(p.t[p.k])}`;
    this.status.textContent = `${this.statusText} · ${this.model.get("speed")} × real time`;
  }
}

export default () => {
  let playback = null;
  return {
    initialize({ model }) {
      playback = new Playback(model);
      return () => playback.ticker.stop();
    },
    render({ model, el }) {
      const view = new PlayerView(playback, model, el);
      playback.ticker.attach(view);
      view.draw();
      return () => playback.ticker.detach(view);
    },
  };
};
