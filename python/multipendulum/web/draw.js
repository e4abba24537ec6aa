// Drawing a chain, shared by the viewer page, the flip-map explorer and the notebook widget:
// the chain with its tip's trail, the pivot's path or the cart on its rail, and a small phase
// plot. No physics here: positions come from the engine (or a computed solution).

/** How long the tip's trail lasts (s). */
export const TRAIL_SECONDS = 2;
/** The cart's colour (the tests find the block by it). */
export const CART_COLOR = "#a0722a";
const PHASE_SECONDS = 12;

/** Match the canvas's backing store to its size on screen; the device pixel ratio. */
export function fitCanvas(canvas) {
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
export function reach(sig) {
  if (sig == null) return 0;
  if (typeof sig === "number") return Math.abs(sig);
  if (sig.kind === "constant") return Math.abs(sig.value);
  if (sig.kind === "sinusoid") return Math.abs(sig.offset ?? 0) + Math.abs(sig.amplitude);
  return Math.max(...sig.values.map(Math.abs));
}

const linkColor = (i, n) => `hsl(${n > 1 ? 212 - (190 * i) / (n - 1) : 212}, 62%, 45%)`;

/**
 * A canvas showing one chain. `chain`: { lengths, masses, kind: "points" | "rods", cart (bool),
 * x0 (where a cart starts), reach (how far the pivot travels, m) }. Each frame: `record(t, pos,
 * base)` adds to the trails, `draw(pos, base)` paints (`pos`: the far end of each link relative
 * to the base, [x0, y0, x1, y1, ...]; `base`: [x, y] in the lab frame).
 */
export class ChainView {
  constructor(canvas, chain) {
    this.canvas = canvas;
    this.chain = chain;
    this.reset();
  }

  /** Forget the trails and recentre (a new run). */
  reset() {
    this.trail = []; // [t, x, y] of the tip (lab frame)
    this.baseTrail = []; // [t, x, y] of the base
    this.centre = null; // the world point at the canvas centre (it follows a cart in jumps)
    this.now = 0;
  }

  record(t, pos, base) {
    const [bx, by] = base;
    const n = pos.length / 2;
    for (const [trail, x, y] of [[this.trail, bx + pos[2 * n - 2], by + pos[2 * n - 1]], [this.baseTrail, bx, by]]) {
      const last = trail[trail.length - 1];
      if (last && t < last[0]) trail.length = 0; // time went back: a new run
      if (!last || t > last[0]) trail.push([t, x, y]);
      while (trail.length > 2 && t - trail[0][0] > TRAIL_SECONDS) trail.shift();
    }
    this.now = t;
  }

  /** World (m) to canvas pixels: the origin (or, on a cart, a point of the rail that jumps to
   *  follow it) in the middle, the stretched chain and the pivot's travel just fit. `base`: the
   *  base's position now (the cart's, to follow it). */
  transform(base) {
    const { canvas, chain } = this;
    const total = chain.lengths.reduce((a, b) => a + b, 0) + (chain.reach ?? 0);
    const size = Math.min(canvas.width, canvas.height);
    const scale = (0.47 * size) / total;
    if (this.centre == null) this.centre = [chain.cart ? chain.x0 ?? 0 : 0, 0];
    if (chain.cart && base) {
      // Recentre when the cart nears the edge, in a jump: the rail's ticks show it moving.
      const half = (0.5 * canvas.width) / scale;
      if (Math.abs(base[0] - this.centre[0]) > 0.8 * half) this.centre = [base[0], 0];
    }
    const cx = canvas.width / 2 - this.centre[0] * scale, cy = canvas.height / 2 + this.centre[1] * scale;
    return {
      cx, cy, scale, total,
      toPixels: (x, y) => [cx + x * scale, cy - y * scale],
      toWorld: (mx, my) => [(mx - cx) / scale, (cy - my) / scale],
    };
  }

  /** The pointer of a mouse event in canvas pixels (inside the border, at the backing store's
   *  resolution). */
  pointer(e) {
    const c = this.canvas;
    const rect = c.getBoundingClientRect();
    const k = c.width / c.clientWidth;
    return [(e.clientX - rect.left - c.clientLeft) * k, (e.clientY - rect.top - c.clientTop) * k];
  }

  /** The link under the pixel (mx, my), within a few pixels, or -1. */
  linkAt(mx, my, pos, base) {
    const { toPixels } = this.transform(base);
    const tolerance = 12 * (window.devicePixelRatio || 1);
    let best = -1, bestD = tolerance;
    let [x0, y0] = toPixels(base[0], base[1]);
    for (let i = 0; i < pos.length / 2; i++) {
      const [x1, y1] = toPixels(base[0] + pos[2 * i], base[1] + pos[2 * i + 1]);
      const dx = x1 - x0, dy = y1 - y0;
      const u = Math.max(0, Math.min(1, ((mx - x0) * dx + (my - y0) * dy) / (dx * dx + dy * dy || 1)));
      const d = Math.hypot(mx - (x0 + u * dx), my - (y0 + u * dy));
      if (d <= bestD) { best = i; bestD = d; } // ties go to the outer link: its end is grabbed
      x0 = x1; y0 = y1;
    }
    return best;
  }

  /** Whether the pixel (mx, my) is on the base: the pivot's dot, or the cart's block. */
  onBase(mx, my, base) {
    const { toPixels, total, scale } = this.transform(base);
    const [px, py] = toPixels(base[0], base[1]);
    const dpr = window.devicePixelRatio || 1;
    if (this.chain.cart) {
      const [w, h] = this.cartSize(total, scale, dpr);
      return Math.abs(mx - px) <= w / 2 + 4 * dpr && Math.abs(my - py) <= h / 2 + 4 * dpr;
    }
    return Math.hypot(mx - px, my - py) <= 10 * dpr;
  }

  cartSize(total, scale, dpr) {
    const w = Math.max(24 * dpr, 0.18 * total * scale);
    return [w, 0.5 * w];
  }

  draw(pos, base, { target = null } = {}) {
    const { canvas, chain } = this;
    const dpr = fitCanvas(canvas);
    const ctx = canvas.getContext("2d");
    const { scale, total, toPixels } = this.transform(base);
    const P = (x, y) => toPixels(x, y);
    ctx.clearRect(0, 0, canvas.width, canvas.height);
    const { lengths, masses, kind } = chain;
    const n = lengths.length;
    const [bx, by] = base;

    if (chain.cart) this.drawRail(ctx, P, scale, total, dpr, bx);
    if (this.baseTrail.length > 1 && !chain.cart) {
      // The pivot's recent path.
      ctx.strokeStyle = "rgba(29, 39, 51, 0.35)";
      ctx.lineWidth = 1.5 * dpr;
      ctx.beginPath();
      this.baseTrail.forEach(([, x, y], i) => (i ? ctx.lineTo(...P(x, y)) : ctx.moveTo(...P(x, y))));
      ctx.stroke();
    }
    if (target) {
      // Where the pointer pulls the base.
      const [tx, ty] = P(target[0], target[1]);
      ctx.strokeStyle = "rgba(47, 111, 179, 0.7)";
      ctx.lineWidth = 1.5 * dpr;
      ctx.setLineDash([4 * dpr, 3 * dpr]);
      ctx.beginPath();
      ctx.moveTo(...P(bx, by));
      ctx.lineTo(tx, ty);
      ctx.stroke();
      ctx.setLineDash([]);
      ctx.beginPath();
      ctx.arc(tx, ty, 5 * dpr, 0, 2 * Math.PI);
      ctx.stroke();
    }

    // The tip's trail, fading with age.
    const trail = this.trail;
    ctx.lineCap = "round";
    ctx.lineWidth = 2 * dpr;
    for (let i = 1; i < trail.length; i++) {
      const age = (this.now - trail[i][0]) / TRAIL_SECONDS;
      ctx.strokeStyle = `rgba(230, 120, 30, ${Math.max(0, 0.85 * (1 - age))})`;
      ctx.beginPath();
      ctx.moveTo(...P(trail[i - 1][1], trail[i - 1][2]));
      ctx.lineTo(...P(trail[i][1], trail[i][2]));
      ctx.stroke();
    }

    // Links, then bobs (point masses) on top.
    const shortest = Math.min(...lengths) * scale;
    const rodWidth = Math.min(Math.max(0.14 * shortest, 2.5 * dpr), 12 * dpr);
    ctx.lineWidth = kind === "rods" ? rodWidth : Math.max(1.5 * dpr, Math.min(3 * dpr, 0.05 * shortest));
    let x0 = bx, y0 = by;
    for (let i = 0; i < n; i++) {
      const x1 = bx + pos[2 * i], y1 = by + pos[2 * i + 1];
      ctx.strokeStyle = kind === "rods" ? linkColor(i, n) : "#3b4652";
      ctx.beginPath();
      ctx.moveTo(...P(x0, y0));
      ctx.lineTo(...P(x1, y1));
      ctx.stroke();
      x0 = x1;
      y0 = y1;
    }
    if (kind !== "rods") {
      const heaviest = Math.max(...masses) || 1;
      const size = Math.min(Math.max(0.3 * shortest, 2.5 * dpr), 14 * dpr);
      for (let i = 0; i < n; i++) {
        const r = Math.max(1.5 * dpr, size * Math.cbrt(masses[i] / heaviest));
        ctx.fillStyle = linkColor(i, n);
        ctx.beginPath();
        ctx.arc(...P(bx + pos[2 * i], by + pos[2 * i + 1]), r, 0, 2 * Math.PI);
        ctx.fill();
      }
    }
    // The pivot.
    ctx.fillStyle = "#1d2733";
    ctx.beginPath();
    ctx.arc(...P(bx, by), 4 * dpr, 0, 2 * Math.PI);
    ctx.fill();
  }

  /** The rail (y = 0) with ticks every `step` m, and the cart, a block centred on the pivot. */
  drawRail(ctx, P, scale, total, dpr, cartX) {
    const { canvas } = this;
    const y = P(0, 0)[1];
    const x0 = P(0, 0)[0];
    ctx.strokeStyle = "#9aa4ae";
    ctx.lineWidth = 2 * dpr;
    ctx.beginPath();
    ctx.moveTo(0, y);
    ctx.lineTo(canvas.width, y);
    ctx.stroke();
    const step = 10 ** Math.floor(Math.log10(total / 2));
    const left = (0 - x0) / scale, right = (canvas.width - x0) / scale;
    ctx.lineWidth = 1 * dpr;
    ctx.beginPath();
    for (let k = Math.ceil(left / step); k <= Math.floor(right / step); k++) {
      ctx.moveTo(P(k * step, 0)[0], y);
      ctx.lineTo(P(k * step, 0)[0], y + 6 * dpr);
    }
    ctx.stroke();
    const [w, h] = this.cartSize(total, scale, dpr);
    ctx.fillStyle = CART_COLOR;
    ctx.fillRect(P(cartX, 0)[0] - w / 2, y - h / 2, w, h);
  }
}

/** The angle wrapped to (-pi, pi]. */
const wrap = (a) => a - 2 * Math.PI * Math.ceil((a - Math.PI) / (2 * Math.PI));

/**
 * A small phase plot: the angle of one link (wrapped to (-pi, pi]) against its angular
 * velocity, over the last few seconds, the current state a dot.
 */
export class PhasePlot {
  constructor(canvas) {
    this.canvas = canvas;
    this.reset();
  }

  reset() {
    this.points = []; // [t, theta, omega]
    this.span = 1; // the largest |omega| seen (rad/s), for the vertical scale
  }

  record(t, theta, omega) {
    const p = this.points;
    const last = p[p.length - 1];
    if (last && t < last[0]) p.length = 0;
    if (!last || t > last[0]) p.push([t, wrap(theta), omega]);
    while (p.length > 2 && t - p[0][0] > PHASE_SECONDS) p.shift();
    this.span = Math.max(this.span, Math.abs(omega));
  }

  draw(label) {
    const { canvas } = this;
    const dpr = fitCanvas(canvas);
    const ctx = canvas.getContext("2d");
    const W = canvas.width, H = canvas.height;
    ctx.clearRect(0, 0, W, H);
    const pad = 6 * dpr;
    const X = (th) => W / 2 + ((W / 2 - pad) * th) / Math.PI;
    const Y = (om) => H / 2 - ((H / 2 - pad) * om) / (1.1 * this.span);
    ctx.strokeStyle = "#e6e9ed";
    ctx.lineWidth = 1;
    ctx.beginPath();
    ctx.moveTo(X(0), 0); ctx.lineTo(X(0), H);
    ctx.moveTo(0, Y(0)); ctx.lineTo(W, Y(0));
    ctx.stroke();
    ctx.font = `${10 * dpr}px system-ui, sans-serif`;
    ctx.fillStyle = "#66717d";
    ctx.textBaseline = "top";
    ctx.fillText(`${label}: θ ∈ (−π, π] →, ω ↑ (±${this.span.toPrecision(2)} rad/s)`, pad, pad / 2);
    const p = this.points;
    if (!p.length) return;
    ctx.strokeStyle = "#2f6fb3";
    ctx.lineWidth = 1.2 * dpr;
    ctx.beginPath();
    for (let i = 0; i < p.length; i++) {
      // A wrap across ±pi breaks the line instead of drawing it across the plot.
      if (i && Math.abs(p[i][1] - p[i - 1][1]) < Math.PI) ctx.lineTo(X(p[i][1]), Y(p[i][2]));
      else ctx.moveTo(X(p[i][1]), Y(p[i][2]));
    }
    ctx.stroke();
    const [, th, om] = p[p.length - 1];
    ctx.fillStyle = "#e6781e";
    ctx.beginPath();
    ctx.arc(X(th), Y(om), 3.5 * dpr, 0, 2 * Math.PI);
    ctx.fill();
  }
}
