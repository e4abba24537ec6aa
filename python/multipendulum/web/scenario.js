// Scenario files of the command-line tool (TOML, docs/cli.md) read in the page: a small TOML
// reader for the subset scenario files use (tables, keys, strings, numbers, booleans, arrays,
// inline tables), and the mapping to the viewer's setup. `multipendulum serve` checks a
// scenario with the Python package and serves it as JSON in the same shape as `fromToml` gives.
// A table in a CSV file (a torque, a pivot axis, the cart force) is read when the file is chosen
// together with the scenario.

export class ScenarioError extends Error {
  constructor(message) {
    super(message);
    this.name = "ScenarioError";
  }
}

// ---- TOML (subset) ---------------------------------------------------------------------------

/** Parse TOML text into plain objects. Refuses what it does not understand, with the line. */
export function parseToml(text) {
  const root = {};
  let table = root;
  let pos = 0;
  let line = 1;
  const fail = (msg) => { throw new ScenarioError(`line ${line}: ${msg}`); };
  const peek = () => text[pos];
  const skipSpace = (newlines) => {
    for (;;) {
      const c = text[pos];
      if (c === " " || c === "\t" || c === "\r") pos++;
      else if (c === "#") { while (pos < text.length && text[pos] !== "\n") pos++; }
      else if (newlines && c === "\n") { pos++; line++; }
      else return;
    }
  };
  const key = () => {
    skipSpace(false);
    const c = peek();
    if (c === '"' || c === "'") return string();
    const m = /^[A-Za-z0-9_-]+/.exec(text.slice(pos));
    if (!m) fail(`expected a key, got ${JSON.stringify(text.slice(pos, pos + 10))}`);
    pos += m[0].length;
    return m[0];
  };
  const dottedKey = () => {
    const parts = [key()];
    for (;;) {
      skipSpace(false);
      if (peek() !== ".") return parts;
      pos++;
      parts.push(key());
    }
  };
  const string = () => {
    const quote = text[pos++];
    let out = "";
    for (;;) {
      if (pos >= text.length || text[pos] === "\n") fail("unterminated string");
      const c = text[pos++];
      if (c === quote) return out;
      if (c === "\\" && quote === '"') {
        const e = text[pos++];
        const simple = { n: "\n", t: "\t", r: "\r", '"': '"', "\\": "\\", b: "\b", f: "\f" };
        if (e in simple) out += simple[e];
        else if (e === "u" || e === "U") {
          const len = e === "u" ? 4 : 8;
          out += String.fromCodePoint(parseInt(text.slice(pos, pos + len), 16));
          pos += len;
        } else fail(`unknown escape \\${e}`);
      } else out += c;
    }
  };
  const value = () => {
    skipSpace(false);
    const c = peek();
    if (c === '"' || c === "'") {
      if (text.startsWith(c.repeat(3), pos)) fail("multi-line strings are not supported here");
      return string();
    }
    if (c === "[") {
      pos++;
      const arr = [];
      for (;;) {
        skipSpace(true);
        if (peek() === "]") { pos++; return arr; }
        arr.push(value());
        skipSpace(true);
        if (peek() === ",") pos++;
        else if (peek() !== "]") fail("expected ',' or ']' in an array");
      }
    }
    if (c === "{") {
      pos++;
      const obj = {};
      skipSpace(false);
      if (peek() === "}") { pos++; return obj; }
      for (;;) {
        const k = dottedKey();
        skipSpace(false);
        if (text[pos++] !== "=") fail("expected '=' in an inline table");
        assign(obj, k, value());
        skipSpace(false);
        const d = text[pos++];
        if (d === "}") return obj;
        if (d !== ",") fail("expected ',' or '}' in an inline table");
      }
    }
    const m = /^[^\s,\]}#]+/.exec(text.slice(pos));
    if (!m) fail("expected a value");
    pos += m[0].length;
    const word = m[0];
    if (word === "true") return true;
    if (word === "false") return false;
    const special = { inf: Infinity, "+inf": Infinity, "-inf": -Infinity, nan: NaN, "+nan": NaN, "-nan": NaN };
    if (word in special) return special[word];
    if (/^[+-]?(\d[\d_]*)(\.\d[\d_]*)?([eE][+-]?\d[\d_]*)?$/.test(word)) return Number(word.replace(/_/g, ""));
    return fail(`unsupported value ${JSON.stringify(word)}`);
  };
  const assign = (obj, parts, v) => {
    let t = obj;
    for (const p of parts.slice(0, -1)) {
      if (!(p in t)) t[p] = {};
      t = t[p];
      if (typeof t !== "object" || Array.isArray(t)) fail(`key ${parts.join(".")} is not a table`);
    }
    const last = parts[parts.length - 1];
    if (last in t) fail(`key ${parts.join(".")} defined twice`);
    t[last] = v;
  };
  for (;;) {
    skipSpace(true);
    if (pos >= text.length) return root;
    if (peek() === "[") {
      pos++;
      if (peek() === "[") fail("arrays of tables are not used in scenario files");
      const parts = dottedKey();
      skipSpace(false);
      if (text[pos++] !== "]") fail("expected ']' after a table name");
      table = root;
      for (const p of parts) {
        if (!(p in table)) table[p] = {};
        table = table[p];
        if (typeof table !== "object" || Array.isArray(table)) fail(`[${parts.join(".")}] is not a table`);
      }
    } else {
      const parts = dottedKey();
      skipSpace(false);
      if (text[pos++] !== "=") fail(`expected '=' after ${parts.join(".")}`);
      assign(table, parts, value());
    }
    skipSpace(false);
    if (pos < text.length && text[pos] !== "\n") fail("expected the end of the line");
  }
}

/** A value as TOML writes it inline (the form's pivot, torque and cart force fields). */
export function toInline(v) {
  if (typeof v === "number") {
    if (Number.isNaN(v)) return "nan";
    if (!Number.isFinite(v)) return v > 0 ? "inf" : "-inf";
    return String(v); // the shortest text that reads back as the same number
  }
  if (typeof v === "string") return JSON.stringify(v);
  if (typeof v === "boolean") return String(v);
  if (Array.isArray(v)) return `[${v.map(toInline).join(", ")}]`;
  if (v && typeof v === "object") return `{ ${Object.entries(v).map(([k, x]) => `${k} = ${toInline(x)}`).join(", ")} }`;
  throw new ScenarioError(`cannot write ${v} as TOML`);
}

/** Parse one inline TOML value (a number, an array, an inline table). */
export function parseInline(text) {
  return parseToml(`value = ${text}`).value;
}

/** A CSV table: `t`, then `columns` values per line ('#' comments and a header line allowed). */
export function parseCsv(text, name, columns, what) {
  const t = [];
  const values = [];
  let headerSeen = false;
  text.split("\n").forEach((raw, i) => {
    const line = raw.replace(/#.*/, "").trim();
    if (!line) return;
    const cells = line.split(",").map((c) => c.trim());
    if (!t.length && !headerSeen && cells.some((c) => c === "" || Number.isNaN(Number(c)))) {
      headerSeen = true;
      return;
    }
    if (cells.length !== columns + 1) {
      throw new ScenarioError(`${name} line ${i + 1}: expected ${columns + 1} columns (t, then ${what}), got ${cells.length}`);
    }
    const row = cells.map((c) => {
      const v = Number(c);
      if (c === "" || Number.isNaN(v)) throw new ScenarioError(`${name} line ${i + 1}: "${c}" is not a number`);
      return v;
    });
    t.push(row[0]);
    values.push(row.slice(1));
  });
  return { t, values };
}

// ---- Scenario --------------------------------------------------------------------------------

const isNumber = (v) => typeof v === "number";

function perLink(v, key, n, ramp = false) {
  if (isNumber(v)) {
    if (n == null) throw new ScenarioError(`key '${key}': a single number needs the number of links: give chain.n or lists`);
    return new Array(n).fill(v);
  }
  if (ramp && v && typeof v === "object" && !Array.isArray(v)) {
    if (!isNumber(v.from) || !isNumber(v.to)) throw new ScenarioError(`key '${key}': a ramp needs numbers from and to`);
    return Array.from({ length: n }, (_, i) => (n > 1 ? v.from + (v.to - v.from) * i / (n - 1) : v.from));
  }
  if (!Array.isArray(v) || !v.every(isNumber)) {
    throw new ScenarioError(`key '${key}': expected a number or an array of numbers (one per link)`);
  }
  if (n != null && v.length !== n) throw new ScenarioError(`key '${key}': expected ${n} values (one per link), got ${v.length}`);
  return v.slice();
}

const isTable = (v) => v != null && typeof v === "object" && !Array.isArray(v);

/** Refuse keys a table does not take, as the Python reader does. */
function onlyKeys(t, key, allowed) {
  for (const k of Object.keys(t)) {
    if (!allowed.includes(k)) throw new ScenarioError(`key '${key}.${k}': unknown key (expected one of ${allowed.join(", ")})`);
  }
}

/**
 * A signal of the scenario (a pivot axis, the cart force, a torque's parameters): a number, or
 * { kind = "sinusoid", ... } or { kind = "table", t, values | file }. `files`: the CSV files
 * chosen with the scenario, by name. `columns`: the table's columns besides t (a torque's, one
 * per link; null: one number per time).
 */
function signal(v, key, files, { columns = null, what = "the value", cubic = false } = {}) {
  if (isNumber(v)) return { kind: "constant", value: v };
  if (!isTable(v)) throw new ScenarioError(`key '${key}': expected a number or a table { kind = "sinusoid" or "table", ... }`);
  if (v.kind === "sinusoid") {
    onlyKeys(v, key, ["kind", "amplitude", "frequency", "phase", "offset"]);
    for (const k of ["amplitude", "frequency"]) if (!(k in v)) throw new ScenarioError(`key '${key}.${k}': missing`);
    return { kind: "sinusoid", amplitude: v.amplitude, frequency: v.frequency, phase: v.phase ?? 0, offset: v.offset ?? 0 };
  }
  if (v.kind === "table") {
    onlyKeys(v, key, cubic ? ["kind", "t", "values", "file"] : ["kind", "t", "values", "file", "interpolation"]);
    const interpolation = cubic ? "cubic" : v.interpolation ?? "linear";
    if (v.file != null) {
      if (typeof v.file !== "string") throw new ScenarioError(`key '${key}.file': expected a file name`);
      if (!files.has(v.file)) {
        throw new ScenarioError(`key '${key}.file': ${v.file} was not chosen: choose it together with the scenario`);
      }
      const table = parseCsv(files.get(v.file), v.file, columns ?? 1, what);
      return { kind: "table", t: table.t, values: columns == null ? table.values.map((r) => r[0]) : table.values, interpolation };
    }
    if (!Array.isArray(v.t) || !Array.isArray(v.values)) {
      throw new ScenarioError(`key '${key}': a table needs the arrays t and values, or file = "NAME.csv"`);
    }
    return { kind: "table", t: v.t, values: v.values, interpolation };
  }
  throw new ScenarioError(`key '${key}.kind': expected "sinusoid" or "table", got ${JSON.stringify(v.kind)}`);
}

/** The scenario's [torque] as the engine takes it (per-link parameters). */
function torque(t, n, files) {
  if (!isTable(t)) throw new ScenarioError("key 'torque': expected a table ([torque])");
  const convention = t.convention;
  if (convention !== "generalized" && convention !== "joint") {
    throw new ScenarioError(`key 'torque.convention': expected "generalized" or "joint", got ${JSON.stringify(convention)}`);
  }
  const keys = { constant: ["value"], sinusoid: ["amplitude", "frequency", "phase", "offset"], table: ["file", "interpolation"] }[t.kind];
  if (!keys) throw new ScenarioError(`key 'torque.kind': expected "constant", "sinusoid" or "table", got ${JSON.stringify(t.kind)}`);
  onlyKeys(t, "torque", ["kind", "convention", ...keys]);
  if (t.kind === "constant") return { kind: "constant", convention, value: perLink(t.value, "torque.value", n) };
  if (t.kind === "sinusoid") {
    const p = (k, d) => perLink(t[k] ?? d, `torque.${k}`, n);
    return { kind: "sinusoid", convention, amplitude: p("amplitude"), frequency: p("frequency"), phase: p("phase", 0), offset: p("offset", 0) };
  }
  const table = signal({ kind: "table", file: t.file, interpolation: t.interpolation }, "torque", files,
    { columns: n, what: "one torque per link" });
  return { ...table, convention };
}

/**
 * The viewer's setup from a parsed scenario: { name, kind, lengths, masses, com, inertia, g,
 * damping, friction, friction_velocity, theta (rad), omega (rad/s), method, dt, rtol, atol,
 * pivot: { x?, y? } | null, cart: { mass, damping, x0, v0, force } | null, torque | null, notes }.
 * Values are checked by the core when the simulation is built; here only the structure.
 * `files` (a Map, name -> text) holds the CSV files chosen with the scenario.
 */
export function fromToml(raw, files = new Map()) {
  const chain = raw.chain;
  const initial = raw.initial;
  const sim = raw.simulation ?? {};
  if (!chain || typeof chain !== "object") throw new ScenarioError("missing the [chain] table");
  if (!initial || typeof initial !== "object") throw new ScenarioError("missing the [initial] table");
  const kind = chain.kind ?? "points";
  if (kind !== "points" && kind !== "rods") throw new ScenarioError(`key 'chain.kind': expected "points" or "rods", got ${JSON.stringify(kind)}`);
  let n = chain.n;
  if (n != null && !(Number.isInteger(n) && n >= 1)) throw new ScenarioError(`key 'chain.n': must be a whole number >= 1, got ${n}`);
  if (n == null) {
    const list = ["lengths", "masses", "com", "inertia"].map((k) => chain[k]).find(Array.isArray);
    n = list ? list.length : null;
  }
  const lengths = perLink(chain.lengths, "chain.lengths", n);
  n = lengths.length;
  const unit = initial.unit;
  if (unit !== "degrees" && unit !== "radians") throw new ScenarioError(`key 'initial.unit': expected "degrees" or "radians", got ${JSON.stringify(unit)}`);
  const scale = unit === "degrees" ? Math.PI / 180 : 1;
  const g = chain.g ?? 9.81;
  if (!isNumber(g)) throw new ScenarioError("key 'chain.g': expected a number");
  const method = sim.method ?? "dop853";
  const notes = [];
  let pivot = null;
  if (raw.pivot != null) {
    if (!isTable(raw.pivot)) throw new ScenarioError("key 'pivot': expected a table ([pivot])");
    onlyKeys(raw.pivot, "pivot", ["x", "y"]);
    pivot = {};
    for (const axis of ["x", "y"]) {
      if (raw.pivot[axis] != null) pivot[axis] = signal(raw.pivot[axis], `pivot.${axis}`, files, { what: `${axis} in m`, cubic: true });
    }
  }
  let cart = null;
  if (raw.cart != null) {
    const c = raw.cart;
    if (!isTable(c)) throw new ScenarioError("key 'cart': expected a table ([cart])");
    onlyKeys(c, "cart", ["mass", "damping", "x0", "v0", "force"]);
    for (const k of ["mass", "damping", "x0", "v0"]) {
      if (c[k] != null && !isNumber(c[k])) throw new ScenarioError(`key 'cart.${k}': expected a number`);
    }
    if (c.mass == null) throw new ScenarioError("key 'cart.mass': missing (the cart's mass in kg)");
    cart = {
      mass: c.mass, damping: c.damping ?? 0, x0: c.x0 ?? 0, v0: c.v0 ?? 0,
      force: c.force != null ? signal(c.force, "cart.force", files, { what: "force in N" }) : null,
    };
  }
  const losses = (k) => (chain[k] != null ? perLink(chain[k], `chain.${k}`, n) : null);
  if (chain.friction_velocity != null && !isNumber(chain.friction_velocity)) {
    throw new ScenarioError("key 'chain.friction_velocity': expected a number");
  }
  return {
    name: typeof raw.name === "string" ? raw.name : "",
    kind,
    lengths,
    masses: perLink(chain.masses, "chain.masses", n),
    com: chain.com != null ? perLink(chain.com, "chain.com", n) : null,
    inertia: chain.inertia != null ? perLink(chain.inertia, "chain.inertia", n) : null,
    g,
    damping: losses("damping"),
    friction: losses("friction"),
    friction_velocity: chain.friction_velocity ?? null,
    theta: perLink(initial.theta, "initial.theta", n, true).map((x) => x * scale),
    omega: perLink(initial.omega ?? 0, "initial.omega", n, true).map((x) => x * scale),
    method,
    dt: sim.dt ?? null,
    rtol: sim.rtol ?? null, // null: the core's default
    atol: sim.atol ?? null,
    pivot,
    cart,
    torque: raw.torque != null ? torque(raw.torque, n, files) : null,
    notes,
  };
}
