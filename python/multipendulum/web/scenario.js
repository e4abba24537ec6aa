// Scenario files of the command-line tool (TOML, docs/cli.md) read in the page: a small TOML
// reader for the subset scenario files use (tables, keys, strings, numbers, booleans, arrays,
// inline tables), and the mapping to the viewer's setup. `multipendulum serve` checks a
// scenario with the Python package and serves it as JSON in the same shape as `fromToml` gives.

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

/**
 * The viewer's setup from a parsed scenario: { name, kind, lengths, masses, com, inertia, g,
 * theta (rad), omega (rad/s), method, dt, rtol, atol, notes }. Values are checked by the core
 * when the simulation is built; here only the structure.
 */
export function fromToml(raw) {
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
  if (raw.torque) notes.push("its [torque] is not applied here: the viewer shows the undriven chain");
  return {
    name: typeof raw.name === "string" ? raw.name : "",
    kind,
    lengths,
    masses: perLink(chain.masses, "chain.masses", n),
    com: chain.com != null ? perLink(chain.com, "chain.com", n) : null,
    inertia: chain.inertia != null ? perLink(chain.inertia, "chain.inertia", n) : null,
    g,
    theta: perLink(initial.theta, "initial.theta", n, true).map((x) => x * scale),
    omega: perLink(initial.omega ?? 0, "initial.omega", n, true).map((x) => x * scale),
    method,
    dt: sim.dt ?? null,
    rtol: sim.rtol ?? null, // null: the core's default
    atol: sim.atol ?? null,
    notes,
  };
}
