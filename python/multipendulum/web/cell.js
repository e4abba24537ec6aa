// What the notebook widgets (widget.js: mp.widget, player.js: mp.show) share: one clock per
// widget driving all of its views (a widget displayed in two cells shows one run), the state
// sent back to Python about ten times a second, and small DOM helpers. anywidget loads each
// widget as one module: multipendulum/_notebook.py inlines this file and the others it imports.

/** How often a widget's state goes back to Python (ms). */
export const REPORT_MS = 100;

/** The bytes of a binary trait as an ArrayBuffer (anywidget gives a DataView). */
export function arrayBuffer(value) {
  if (value instanceof ArrayBuffer) return value;
  if (ArrayBuffer.isView(value)) return value.buffer.slice(value.byteOffset, value.byteOffset + value.byteLength);
  throw new Error(`expected binary data, got ${Object.prototype.toString.call(value)}`);
}

/** A new element: `tag.class`, with attributes and text. */
export function element(spec, { text = null, ...attrs } = {}) {
  const [tag, ...classes] = spec.split(".");
  const el = document.createElement(tag);
  if (classes.length) el.className = classes.join(" ");
  for (const [k, v] of Object.entries(attrs)) el.setAttribute(k, String(v));
  if (text != null) el.textContent = text;
  return el;
}

/**
 * The animation clock of one widget: while at least one of its views is on the page, calls
 * `tick(wall)` (`wall`: seconds since the last frame, at most 0.1, as the page does) and then
 * `draw()` of every view once per animation frame, and `report()` at most every REPORT_MS.
 */
export class Ticker {
  constructor(tick, report) {
    this.tick = tick;
    this.report = report;
    this.views = new Set();
    this.raf = 0;
    this.last = 0;
    this.lastReport = 0;
    this.frame = this.frame.bind(this);
  }

  attach(view) {
    this.views.add(view);
    if (!this.raf) {
      this.last = 0;
      this.raf = requestAnimationFrame(this.frame);
    }
  }

  detach(view) {
    this.views.delete(view);
    if (!this.views.size) this.stop();
  }

  stop() {
    if (this.raf) cancelAnimationFrame(this.raf);
    this.raf = 0;
  }

  frame(now) {
    this.raf = this.views.size ? requestAnimationFrame(this.frame) : 0;
    const wall = this.last ? Math.min((now - this.last) / 1000, 0.1) : 0;
    this.last = now;
    this.tick(wall);
    this.drawAll();
    if (now - this.lastReport >= REPORT_MS) {
      this.lastReport = now;
      this.report();
    }
  }

  drawAll() {
    for (const view of this.views) view.draw();
  }
}

/** A number of seconds for a readout. */
export const seconds = (t) => `${t.toFixed(3)} s`;
