"""The browser viewer: its server (plain Python) and the page in a real headless chromium.

The server tests check what `multipendulum serve` promises: 127.0.0.1 by default, only the
viewer's own files (no path traversal, however encoded), every parameter checked. The browser
tests drive Debian's chromium with Playwright: the page loads cleanly, the pendulum moves, the
energy readout stays at the integrator's accuracy, bad input is refused with a message, a
scenario loads, the URL shares the setup, and one step of the WebAssembly engine equals the
Python package's to 1e-12; dragging the pivot or the cart shakes the running chain within the
acceleration bound while the energy balance holds, the phase plot follows its link, and the
flip-map explorer computes the Python package's map bit for bit and runs a clicked cell.

Without chromium or Playwright (`make test` installs both when it can) the browser tests are
skipped with the reason; with MULTIPENDULUM_REQUIRE_BROWSER=1 (CI) they fail instead.
"""
import http.client
import io
import json
import math
import os
import re
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

import multipendulum as mp
from multipendulum.cli import main
from multipendulum.scenario import load_scenario
from multipendulum.viewer import WASM_NAME, make_server, parse_host, parse_port, web_dir

ROOT = Path(__file__).resolve().parents[1]
CHROMIUM = os.environ.get("MULTIPENDULUM_CHROMIUM", "/usr/bin/chromium")
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync"]


# ----------------------------------------------------------------------------------------------
# The server


@pytest.fixture
def serve():
    """Start a viewer server in a thread; yields a function making one (stopped afterwards)."""
    servers = []

    def start(**kwargs):
        server = make_server(port=0, quiet=True, **kwargs)
        threading.Thread(target=server.serve_forever, daemon=True).start()
        servers.append(server)
        return server

    yield start
    for server in servers:
        server.shutdown()
        server.server_close()


def request(server, path, method="GET", host=None):
    """A raw request: the path is sent exactly as given (no client-side normalisation)."""
    addr, port = server.server_address[:2]
    conn = http.client.HTTPConnection(addr, port, timeout=10)
    conn.putrequest(method, path, skip_host=True, skip_accept_encoding=True)
    conn.putheader("Host", host or f"{addr}:{port}")
    conn.endheaders()
    resp = conn.getresponse()
    body = resp.read()
    conn.close()
    return resp.status, dict(resp.getheaders()), body


@pytest.fixture
def fake_web(tmp_path):
    """A web directory with a secret next to it and things inside it that must not be served."""
    root = tmp_path / "web"
    root.mkdir()
    (root / "index.html").write_text("<!doctype html><title>fake</title>")
    (root / WASM_NAME).write_bytes(b"\0asm\1\0\0\0")
    (root / "viewer.js").write_text("export {};")
    (root / "notes.py").write_text("SECRET = 'py'")
    (root / ".hidden.js").write_text("SECRET")
    (root / "sub").mkdir()
    (root / "sub" / "inner.js").write_text("SECRET")
    (tmp_path / "secret.txt").write_text("SECRET")
    return root


def test_binds_127_0_0_1_by_default(serve, fake_web):
    server = serve(root=fake_web)
    assert server.socket.getsockname()[0] == "127.0.0.1"
    assert server.url.startswith("http://127.0.0.1:")
    args = __import__("multipendulum.cli", fromlist=["build_parser"]).build_parser().parse_args(["serve"])
    assert args.host == "127.0.0.1"


TRAVERSALS = [
    "/../secret.txt", "/..%2fsecret.txt", "/..%2Fsecret.txt", "/%2e%2e/secret.txt", "/%2e%2e%2fsecret.txt",
    "/..%5csecret.txt", "/....//secret.txt", "/%252e%252e%252fsecret.txt", "/.%2e/secret.txt",
    "//etc/passwd", "/%2fetc%2fpasswd", "/etc/passwd", "/../../../../../../etc/passwd",
    "/..%2f..%2f..%2f..%2f..%2f..%2fetc%2fpasswd", "/sub/inner.js", "/sub%2finner.js", "/notes.py",
    "/.hidden.js", "/index.html%00.js", "/./viewer.js/../../secret.txt", "http://127.0.0.1/../secret.txt",
]


@pytest.mark.parametrize("path", TRAVERSALS)
def test_serves_nothing_outside_its_own_files(serve, fake_web, path):
    server = serve(root=fake_web)
    status, _, body = request(server, path)
    assert status == 404, (path, status)
    assert b"SECRET" not in body and b"root:" not in body


def test_absolute_paths_of_real_files_are_not_served(serve, fake_web):
    server = serve(root=fake_web)
    for target in (fake_web.parent / "secret.txt", fake_web / "index.html", Path("/etc/passwd")):
        for path in (str(target), "/" + str(target), str(target).replace("/", "%2f")):
            status, _, body = request(server, path)
            assert status == 404 and b"SECRET" not in body, (path, status)


def test_serves_its_files_with_their_types_and_a_strict_policy(serve, fake_web):
    server = serve(root=fake_web)
    status, headers, body = request(server, "/")
    assert status == 200 and body.startswith(b"<!doctype html>")
    assert headers["Content-Type"] == "text/html; charset=utf-8"
    assert "default-src 'self'" in headers["Content-Security-Policy"]
    assert headers["X-Content-Type-Options"] == "nosniff"
    status, headers, body = request(server, f"/{WASM_NAME}?v=1")
    assert (status, headers["Content-Type"], body) == (200, "application/wasm", b"\0asm\1\0\0\0")
    status, headers, body = request(server, "/viewer.js", method="HEAD")
    assert status == 200 and body == b"" and headers["Content-Type"].startswith("text/javascript")
    assert request(server, "/viewer.js", method="POST")[0] == 501
    assert request(server, "/scenario.json")[0] == 404  # none without a scenario


def test_refuses_foreign_host_headers(serve, fake_web):
    """A page elsewhere cannot reach the viewer through a DNS name rebound to 127.0.0.1."""
    server = serve(root=fake_web)
    assert request(server, "/", host="evil.example:80")[0] == 403
    assert request(server, "/", host=f"localhost:{server.server_address[1]}")[0] == 200


def test_serves_a_checked_scenario_as_json(serve, fake_web):
    scenario = load_scenario(ROOT / "examples" / "triple.toml")
    server = serve(root=fake_web, scenario=scenario)
    status, headers, _ = request(server, "/")
    assert status == 302 and headers["Location"] == "/?scenario=scenario.json"
    status, headers, body = request(server, "/scenario.json")
    assert status == 200 and headers["Content-Type"] == "application/json"
    data = json.loads(body)
    assert data["name"] == "Triple pendulum" and data["method"] == "gauss6" and data["dt"] == 0.002
    np.testing.assert_allclose(data["theta"], np.radians([90, 120, 150]), rtol=1e-15)
    assert data["lengths"] == [1.0, 1.0, 1.0] and data["kind"] == "points" and data["notes"] == []
    assert data["torque"] is data["pivot"] is data["cart"] is data["damping"] is None
    # A torque table from its CSV file, with its samples; the notes no longer say it is ignored.
    driven = json.loads(request(serve(root=fake_web, scenario=load_scenario(ROOT / "examples" / "driven_rod.toml")),
                                "/scenario.json")[2])
    assert driven["notes"] == []
    torque = driven["torque"]
    assert (torque["kind"], torque["convention"], torque["interpolation"]) == ("table", "joint", "cubic")
    csv = np.loadtxt(ROOT / "examples" / "driven_rod.csv", delimiter=",", comments="#", skiprows=3)
    np.testing.assert_array_equal(torque["t"], csv[:, 0])
    np.testing.assert_array_equal(np.asarray(torque["values"])[:, 0], csv[:, 1])
    kapitza = json.loads(request(serve(root=fake_web, scenario=load_scenario(ROOT / "examples" / "kapitza.toml")),
                                 "/scenario.json")[2])
    assert kapitza["pivot"] == {"y": {"kind": "sinusoid", "amplitude": 0.02, "frequency": 300.0,
                                      "phase": math.pi / 2, "offset": 0.0}}
    damped = json.loads(request(serve(root=fake_web, scenario=load_scenario(ROOT / "examples" / "damped_double.toml")),
                                "/scenario.json")[2])
    assert damped["damping"] == [0.08, 0.05] and damped["friction"] is None


@pytest.mark.parametrize("value, message", [
    ("-1", "port must be a whole number from 0 to 65535, got -1"),
    ("65536", "port must be a whole number from 0 to 65535, got 65536"),
    ("8e3", "port must be a whole number from 0 to 65535, got '8e3'"),
    ("", "port must be a whole number from 0 to 65535, got ''"),
])
def test_bad_ports_are_refused(value, message):
    with pytest.raises(mp.InputError, match=re.escape(message)):
        parse_port(value)


def test_hosts_must_be_addresses():
    assert parse_host("localhost") == "127.0.0.1"
    assert parse_host("::1") == "::1"
    for bad in ("example.com", "127.0.0.1; rm -rf /", "", "999.1.1.1"):
        with pytest.raises(mp.InputError, match="host must be an IP address"):
            parse_host(bad)


@pytest.mark.parametrize("argv, message", [
    (["serve", "--port", "70000"], "port must be a whole number from 0 to 65535, got 70000"),
    (["serve", "--host", "example.com"], "host must be an IP address"),
    (["serve", "missing.toml"], "missing.toml"),
])
def test_serve_refuses_bad_arguments(capsys, argv, message):
    assert main(argv) == 1
    assert message in capsys.readouterr().err


def test_a_missing_build_is_reported(tmp_path):
    (tmp_path / "index.html").write_text("")
    with pytest.raises(mp.InputError, match=r"multipendulum\.wasm is missing \(run `make build`\)"):
        make_server(root=tmp_path)


def test_the_serve_command_prints_its_address_and_serves(tmp_path):
    if not (web_dir() / WASM_NAME).exists():
        pytest.fail(f"{web_dir() / WASM_NAME} is missing: run `make build`")
    proc = subprocess.Popen([sys.executable, "-m", "multipendulum", "serve", "--port", "0", "-q"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        line = proc.stdout.readline()
        m = re.match(r"multipendulum viewer at http://127\.0\.0\.1:(\d+)/ ", line)
        assert m, line
        conn = http.client.HTTPConnection("127.0.0.1", int(m.group(1)), timeout=10)
        conn.request("GET", "/index.html")
        resp = conn.getresponse()
        assert resp.status == 200 and b"multipendulum viewer" in resp.read()
    finally:
        proc.terminate()
        proc.wait(timeout=10)


# ----------------------------------------------------------------------------------------------
# The page in chromium


def _browser_missing():
    if not os.access(CHROMIUM, os.X_OK):
        return f"{CHROMIUM} is not installed (make test installs Debian's chromium as root)"
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        return "Playwright for Python is not installed (make test pip-installs it into .venv)"
    return None


@pytest.fixture(scope="module")
def browser():
    reason = _browser_missing()
    if reason:
        if os.environ.get("MULTIPENDULUM_REQUIRE_BROWSER"):
            pytest.fail(f"browser tests required but {reason}")
        pytest.skip(reason)
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw:
        b = pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS, headless=True)
        yield b
        b.close()


@pytest.fixture(scope="module")
def site():
    """The real viewer files, served as `multipendulum serve` does."""
    if not (web_dir() / WASM_NAME).exists():
        pytest.fail(f"{web_dir() / WASM_NAME} is missing: run `make build`")
    server = make_server(port=0, quiet=True)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    yield server
    server.shutdown()
    server.server_close()


class Page:
    """A page with its console errors collected."""

    def __init__(self, browser, url):
        self.context = browser.new_context(viewport={"width": 1200, "height": 900})
        self.page = self.context.new_page()
        self.errors = []
        self.page.on("console", lambda m: m.type == "error" and self.errors.append(m.text))
        self.page.on("pageerror", lambda e: self.errors.append(str(e)))
        self.page.goto(url)
        self.page.wait_for_selector("body[data-ready=true]", timeout=15000)

    def js(self, expr, arg=None):
        return self.page.evaluate(expr, arg)

    def wait(self, expr, timeout=15.0):
        """Poll `expr` until true (not wait_for_function: the page's policy forbids its eval)."""
        for _ in range(int(timeout / 0.05)):
            if self.js(expr):
                return
            self.page.wait_for_timeout(50)
        raise AssertionError(f"timed out waiting for {expr}")

    @property
    def t(self):
        return self.js("multipendulum.state.sim.t")

    def set(self, name, value):
        """Type into a field as a user does: the page applies it on change."""
        self.page.fill(f"[name={name}]", str(value))
        self.page.locator(f"[name={name}]").dispatch_event("change")

    def message(self):
        loc = self.page.locator("#message")
        return loc.inner_text() if loc.is_visible() else ""

    def close(self):
        self.context.close()


@pytest.fixture
def open_page(browser, site):
    pages = []

    def opener(query=""):
        p = Page(browser, site.url + query)
        pages.append(p)
        return p

    yield opener
    for p in pages:
        p.close()


def _canvas(page):
    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(page.page.locator("#view").screenshot())).convert("RGB")).astype(int)


def _bob_centre(pixels, rgb):
    """Centre of the pixels of one bob's colour."""
    mask = np.all(np.abs(pixels - np.array(rgb)) <= 6, axis=-1)
    ys, xs = np.nonzero(mask)
    assert len(xs) > 20, "the bob is not on the canvas"
    return np.array([xs.mean(), ys.mean()])


def test_page_loads_and_runs_with_no_console_errors(open_page):
    p = open_page()
    assert p.page.title() == "multipendulum viewer"
    p.page.click("#play")
    p.wait("multipendulum.state.sim.t > 0.5")
    p.page.click("#play")
    assert p.errors == []
    assert p.message() == ""


def test_the_page_works_from_any_static_file_server(browser):
    """Python's plain http.server, with none of `multipendulum serve`'s own headers."""
    import functools
    from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer

    class Quiet(SimpleHTTPRequestHandler):
        def log_message(self, *args):
            pass

    server = ThreadingHTTPServer(("127.0.0.1", 0), functools.partial(Quiet, directory=str(web_dir())))
    threading.Thread(target=server.serve_forever, daemon=True).start()
    try:
        p = Page(browser, f"http://127.0.0.1:{server.server_address[1]}/index.html")
        p.page.click("#play")
        p.wait("multipendulum.state.sim.t > 0.3")
        assert p.errors == [] and p.message() == ""
        p.close()
    finally:
        server.shutdown()
        server.server_close()


def test_the_pendulum_moves(open_page):
    import colorsys

    p = open_page()
    # The outer bob's colour, as the page draws it: hsl(22, 62%, 45%).
    tip = [round(255 * c) for c in colorsys.hls_to_rgb(22 / 360, 0.45, 0.62)]
    before = _canvas(p)
    p.page.click("#play")
    p.wait("multipendulum.state.sim.t > 0.4")
    p.page.click("#play")
    after = _canvas(p)
    changed = np.any(before != after, axis=-1).mean()
    assert changed > 0.001, f"only {changed:.2%} of the pixels changed"
    moved = np.linalg.norm(_bob_centre(after, tip) - _bob_centre(before, tip))
    assert moved > 20, f"the outer bob moved {moved:.1f} px"
    assert p.js("document.getElementById('t').textContent") != "0.000 s"


@pytest.mark.parametrize("method, query", [
    ("dop853", "method=dop853&tol=1e-10&atol=1e-12"),
    ("gauss6", "method=gauss6&dt=0.002"),
], ids=["dop853", "gauss6"])
def test_energy_readout_stays_at_the_integrators_accuracy_for_10_s(open_page, method, query):
    """The page's readout over 10 s of the chaotic double pendulum, against the same integrator
    run by the Python package (all steps), and for dop853 against its tolerance."""
    p = open_page(f"?n=2&lengths=1&masses=1&theta=130,160&speed=4&{query}")
    settings = dict(method="dop853", rtol=1e-10, atol=1e-12) if method == "dop853" else dict(method="gauss6", dt=0.002)
    ref = mp.simulate(mp.Chain([1, 1], [1, 1]), np.radians([130, 160]), [0, 0], 10.0, **settings)
    bound = 10 * ref.stats.energy_error
    if method == "dop853":
        bound = min(bound, 100 * 1e-10)
    p.page.click("#play")
    readouts = []
    while p.t < 10.0:
        readouts.append(float(p.js("document.getElementById('error').textContent")))
        p.page.wait_for_timeout(100)
    p.page.click("#play")
    assert len(readouts) > 10 and max(readouts) > 0
    assert max(readouts) < bound, (max(readouts), bound)
    plotted = p.js("Math.max(...multipendulum.state.history.map(([t, e]) => e))")
    assert plotted < bound, (plotted, bound)
    assert p.errors == []


@pytest.mark.parametrize("field, value, message", [
    ("lengths", "-1", "lengths[0] must be > 0 and finite, got -1"),
    ("lengths", "1, -0.5", "lengths[1] must be > 0 and finite, got -0.5"),
    ("n", "0", 'N must be a whole number from 1 to 100, got "0"'),
    ("n", "101", 'N must be a whole number from 1 to 100, got "101"'),
    ("theta", "NaN", "theta0[0] must be finite, got NaN"),
    ("masses", "abc", 'Masses: "abc" is not a number'),
    ("g", "NaN", "g must be finite, got NaN"),
    ("tol", "0", "rtol must be >= 1e-15 and finite, got 0"),
    ("damping", "-0.1", "damping[0] must be >= 0 and finite, got -0.1"),
    ("damping", "0.1, NaN", "damping[1] must be >= 0 and finite, got NaN"),
    ("friction", "-1", "friction[0] must be >= 0 and finite, got -1"),
    ("cart_mass", "0", "cart mass must be > 0 and finite, got 0"),
    ("pivot_y", "{ kind = \"table\", t = [0], values = [0] }", "pivot y: a cubic table needs at least 2 samples, got 1"),
    ("pivot_x", "{ kind = \"sine\" }", "pivot x: kind must be"),
    ("torque", "{ kind = \"constant\", convention = \"joint\", value = [1, 2, 3] }",
     "torque: value must have 2 entries (one per link), got 3"),
])
def test_bad_input_is_refused_with_a_visible_message(open_page, field, value, message):
    p = open_page()
    p.page.click("#play")
    p.set(field, value)
    assert message in p.message()
    assert p.page.locator(f"[name={field}]").get_attribute("aria-invalid") == "true"
    # The pendulum runs on with its last good setup: no NaN, not frozen.
    t0 = p.t
    p.wait(f"multipendulum.state.sim.t > {t0} + 0.2")
    assert all(math.isfinite(v) for v in p.js("multipendulum.state.sim.positions()"))
    assert "NaN" not in p.js("document.querySelector('.readouts').textContent")
    p.set(field, {"n": "2", "theta": "130, 160", "tol": "1e-10", "torque": ""}.get(field, "1"))
    assert p.message() == "" and p.page.locator(f"[name={field}]").get_attribute("aria-invalid") is None
    assert p.errors == []


def test_a_failed_integration_stops_with_a_message(open_page):
    p = open_page("?n=2&method=gauss6&dt=0.5&theta=130,160")
    p.page.click("#play")
    p.page.wait_for_selector("#message:not([hidden])", timeout=10000)
    assert "did not converge" in p.message()
    assert all(math.isfinite(v) for v in p.js("multipendulum.state.sim.positions()"))
    assert p.errors == []


def test_bad_values_in_the_url_are_refused(open_page):
    p = open_page("?n=0&lengths=1&masses=1&theta=0")
    assert 'N must be a whole number from 1 to 100, got "0"' in p.message()
    assert p.js("multipendulum.state.sim.n") == 2  # the default pendulum
    p = open_page("?n=2&method=euler&lengths=1&masses=1&theta=0")
    assert 'method must be one of rk4, dop853, gauss4, gauss6, got "euler"' in p.message()
    p = open_page("?n=2&lengths=1&masses=1&theta=0&speed=1e9")
    assert 'Speed must be one of 0.25, 0.5, 1, 2, 4, got "1e9"' in p.message()


@pytest.mark.parametrize("n", [1, 5, 100])
@pytest.mark.parametrize("kind", ["points", "rods"])
def test_one_wasm_step_equals_the_python_package(open_page, n, kind):
    p = open_page()
    rng = np.random.default_rng(n)
    lengths, masses = rng.uniform(0.3, 1.5, n), rng.uniform(0.2, 2.0, n)
    theta0, omega0 = rng.uniform(-3, 3, n), rng.uniform(-2, 2, n)
    dt = 0.01
    params = dict(kind=kind, lengths=lengths.tolist(), masses=masses.tolist(), g=9.81, method="rk4", dt=dt,
                  theta=theta0.tolist(), omega=omega0.tolist())
    got = p.js("""(p) => {
        const sim = multipendulum.engine.simulation(p);
        sim.advanceTo(p.dt, 1);
        const out = {t: sim.t, theta: sim.theta(), omega: sim.omega(), energy: sim.energy, e0: sim.initialEnergy};
        sim.free();
        return out;
    }""", params)
    chain = mp.Chain.rods(lengths, masses) if kind == "rods" else mp.Chain(lengths, masses)
    sol = mp.simulate(chain, theta0, omega0, dt, method="rk4", dt=dt, t_eval=[dt])
    assert got["t"] == dt
    np.testing.assert_allclose(got["theta"], sol.theta[-1], rtol=0, atol=1e-12)
    np.testing.assert_allclose(got["omega"], sol.omega[-1], rtol=0, atol=1e-12)
    assert abs(got["e0"] - chain.energy(theta0, omega0)) <= 1e-12 * max(1, abs(got["e0"]))
    assert abs(got["energy"] - sol.energy[-1]) <= 1e-12 * max(1, abs(got["energy"]))


def test_a_scenario_file_loads(open_page):
    p = open_page()
    p.page.set_input_files("#load", str(ROOT / "examples" / "triple.toml"))
    p.wait("multipendulum.state.sim.n === 3")
    assert "Loaded triple.toml" in p.message()
    assert p.page.locator("#name").inner_text() == "Triple pendulum"
    assert p.page.input_value("[name=method]") == "gauss6" and p.page.input_value("[name=dt]") == "0.002"
    assert p.page.input_value("[name=theta]") == "90, 120, 150"
    p.page.set_input_files("#load", str(ROOT / "examples" / "chain50.toml"))
    p.wait("multipendulum.state.sim.n === 50")
    theta = p.js("multipendulum.state.setup.theta")
    np.testing.assert_allclose(theta, np.radians(np.linspace(90, 45, 50)), atol=1e-12)
    # A torque table in a CSV file: refused (nothing applied) unless the file is chosen with it.
    p.page.set_input_files("#load", str(ROOT / "examples" / "driven_rod.toml"))
    p.wait("document.getElementById('message').textContent.includes('driven_rod')")
    assert "torque.file': driven_rod.csv was not chosen" in p.message()
    assert p.js("multipendulum.state.sim.n") == 50
    p.page.set_input_files("#load", [str(ROOT / "examples" / "driven_rod.toml"), str(ROOT / "examples" / "driven_rod.csv")])
    p.wait("multipendulum.state.sim.n === 1")
    assert "Loaded driven_rod.toml. Press Play." == p.message()
    torque = p.js("multipendulum.state.setup.torque")
    # The same table as the Python package reads from the CSV file.
    ref = load_scenario(ROOT / "examples" / "driven_rod.toml").torque
    assert (torque["kind"], torque["convention"], torque["interpolation"]) == ("table", "joint", "cubic")
    assert torque["t"] == list(ref.params["t"]) and torque["values"] == [list(r) for r in ref.params["values"]]
    p.page.set_input_files("#load", files=[{"name": "bad.toml", "mimeType": "text/plain",
                                            "buffer": b"[chain]\nlengths = [1, -1]\nmasses = [1, 1]\n"
                                                      b"[initial]\nunit = 'degrees'\ntheta = [0, 0]\n"}])
    p.wait("document.getElementById('message').textContent.includes('lengths[1]')")
    assert p.js("multipendulum.state.setup.kind") == "rods"  # still the driven rod: nothing applied
    p.page.set_input_files("#load", files=[{"name": "broken.toml", "mimeType": "text/plain", "buffer": b"[chain\n"}])
    p.wait("document.getElementById('message').textContent.includes('broken.toml')")
    assert "line 1" in p.message()
    assert p.errors == []


def test_a_served_scenario_is_the_starting_setup(browser):
    server = make_server(port=0, quiet=True, scenario=load_scenario(ROOT / "examples" / "chain50.toml"))
    threading.Thread(target=server.serve_forever, daemon=True).start()
    try:
        p = Page(browser, server.url)
        p.wait("multipendulum.state.sim.n === 50")
        assert p.page.locator("#name").inner_text() == "50-link chain released from a curve"
        assert p.page.input_value("[name=tol]") == "1e-9" and p.errors == []
        p.close()
    finally:
        server.shutdown()
        server.server_close()


def test_the_url_shares_the_setup(open_page):
    p = open_page()
    p.set("n", "3")
    p.set("lengths", "1, 0.5, 0.25")
    p.page.select_option("[name=kind]", "rods")
    p.page.select_option("[name=method]", "rk4")
    p.set("dt", "0.001")
    url = p.page.url
    q = open_page(url[url.index("?"):])
    for name, value in [("n", "3"), ("kind", "rods"), ("lengths", "1, 0.5, 0.25"), ("method", "rk4"),
                        ("dt", "0.001"), ("theta", "130, 160, 160")]:
        assert q.page.input_value(f"[name={name}]") == value, name
    assert q.js("multipendulum.state.sim.n") == 3 and q.errors == []
    # The playback speed is shared too, and changing it does not restart the run.
    q.page.click("#play")
    q.wait("multipendulum.state.sim.t > 0.3")
    q.page.select_option("[name=speed]", "2")
    assert q.t > 0.3 and "speed=2" in q.page.url


def test_dragging_a_link_sets_its_starting_angle(open_page):
    from urllib.parse import parse_qs, urlsplit

    p = open_page("?n=2&lengths=1&masses=1&theta=0,0")
    box = p.page.locator("#view").bounding_box()
    inner = box["width"] - 2, box["height"] - 2  # inside the 1 px border
    cx, cy = box["x"] + 1 + inner[0] / 2, box["y"] + 1 + inner[1] / 2
    scale = 0.47 * min(inner) / 2.0  # CSS pixels per metre: the stretched chain (2 m) just fits
    # Grab the outer link half way along (it hangs straight down) and pull it out to the right.
    p.page.mouse.move(cx, cy + 1.5 * scale)
    p.page.mouse.down()
    p.page.mouse.move(cx + 0.7 * scale, cy + 1.7 * scale, steps=5)
    p.page.mouse.move(cx + 2 * scale, cy + 1.0 * scale, steps=5)
    p.page.mouse.up()
    theta = [float(v) for v in p.page.input_value("[name=theta]").split(",")]
    assert theta[0] == 0 and abs(theta[1] - 90) <= 0.5, theta
    assert parse_qs(urlsplit(p.page.url).query)["theta"] == [p.page.input_value("[name=theta]")]
    assert p.t == 0 and p.errors == []


def test_a_hundred_links_run(open_page):
    p = open_page("?n=100&lengths=0.02&masses=0.01&theta=60")
    before = p.js("multipendulum.state.sim.positions()")
    p.page.click("#play")
    p.wait("multipendulum.state.sim.t > 1")
    p.page.click("#play")
    after = p.js("multipendulum.state.sim.positions()")
    assert len(after) == 200 and all(math.isfinite(v) for v in after) and after != before
    assert p.errors == []


# ----------------------------------------------------------------------------------------------
# Losses, the moving pivot, the cart and torques in the page


def _served(browser, scenario):
    """A page opened on `multipendulum serve SCENARIO` (the Python package checks the file)."""
    server = make_server(port=0, quiet=True, scenario=scenario)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    page = Page(browser, server.url)
    page.wait("document.getElementById('message').textContent.startsWith('Loaded')")
    return server, page


@pytest.fixture
def served(browser):
    opened = []

    def start(scenario):
        server, page = _served(browser, scenario)
        opened.append((server, page))
        return page

    yield start
    for server, page in opened:
        page.close()
        server.shutdown()
        server.server_close()


def _run_terms(p, until, every=0.25):
    """Play until sim.t > `until`, sampling the page's terms (the core's) about every `every` s."""
    p.page.click("#play")
    samples = []
    while True:
        terms = p.js("({t: multipendulum.state.sim.t, ...multipendulum.state.terms})")
        if not samples or terms["t"] >= samples[-1]["t"] + every:
            samples.append(terms)
        if terms["t"] > until:
            break
        p.page.wait_for_timeout(40)
    p.page.click("#play")
    return samples


def test_a_damped_pendulum_loses_energy_to_its_dissipated_term(served):
    p = served(load_scenario(ROOT / "examples" / "damped_double.toml"))
    assert p.page.input_value("[name=damping]") == "0.08, 0.05"
    assert "balance residual" in p.page.locator("#error-label").inner_text()
    p.page.select_option("[name=speed]", "4")
    samples = _run_terms(p, 6.0)
    assert len(samples) > 8
    energy = [s["energy"] for s in samples]
    dissipated = [s["dissipated"] for s in samples]
    # Damping alone: dE/dt = -2R <= 0, and what is lost is what was dissipated.
    assert all(b <= a + 1e-9 for a, b in zip(energy, energy[1:])), energy
    assert all(b >= a - 1e-12 for a, b in zip(dissipated, dissipated[1:])), dissipated
    assert energy[-1] < energy[0] - 1.0 and dissipated[-1] > 1.0, (energy, dissipated)
    e0 = p.js("multipendulum.state.sim.initialEnergy")
    for s in samples:
        assert abs(s["energy"] - e0 + s["dissipated"]) <= 1e-7 * e0
        assert s["residual"] < 1e-7 and s["workIn"] == 0
    # The readouts show the same terms.
    shown = float(p.js("document.getElementById('dissipated').textContent").split()[0])
    assert shown == pytest.approx(p.js("multipendulum.state.terms.dissipated"), rel=1e-5)
    assert p.errors == []


CART_SCENARIO = b"""
name = "Pushed cart"
[chain]
lengths = [0.6]
masses = [0.5]
[cart]
mass = 1.0
damping = 0.2
x0 = -0.2
force = { kind = "sinusoid", amplitude = 3.0, frequency = 4.0 }
[initial]
unit = "degrees"
theta = [20.0]
[simulation]
method = "dop853"
"""


def _cart_pixels(page):
    # The block's colour, as the page draws it (CART_COLOR in viewer.js).
    pixels = _canvas(page)
    mask = np.all(np.abs(pixels - np.array([0xA0, 0x72, 0x2A])) <= 6, axis=-1)
    ys, xs = np.nonzero(mask)
    return len(xs), (xs.mean() if len(xs) else None)


def _cart_drawn_at(p, x):
    """Where the view draws a cart at `x` (m): the block's centre in the screenshot's pixels."""
    return p.js(f"""(() => {{
        const v = multipendulum.state.chainView, c = v.canvas;
        return c.clientLeft + v.transform(null).toPixels({x!r}, 0)[0] * c.clientWidth / c.width;
    }})()""")


def test_a_cart_scenario_draws_the_cart_and_moves_it(open_page):
    p = open_page()
    assert _cart_pixels(p)[0] == 0  # no cart on the default pendulum
    p.page.set_input_files("#load", files=[{"name": "cart.toml", "mimeType": "text/plain", "buffer": CART_SCENARIO}])
    p.wait("multipendulum.state.setup.cart !== null")
    assert p.message() == "Loaded cart.toml. Press Play."
    assert p.page.input_value("[name=cart_mass]") == "1"
    assert p.page.input_value("[name=cart_force]") == '{ kind = "sinusoid", amplitude = 3, frequency = 4, phase = 0, offset = 0 }'
    count, x_before = _cart_pixels(p)
    assert count > 200, count
    assert p.js("multipendulum.state.terms.cart.x") == -0.2
    assert abs(x_before - _cart_drawn_at(p, -0.2)) < 2, (x_before, _cart_drawn_at(p, -0.2))
    assert p.page.locator("#cart-x").inner_text() == "-0.200 m"
    samples = _run_terms(p, 0.5, every=0.05)
    xs = [s["cart"]["x"] for s in samples]
    assert max(xs) - min(xs) > 0.05, xs
    assert p.page.locator("#cart-x").inner_text() != "-0.200 m"
    # Where the run paused depends on the frames' timing (the cart swings back and forth): play
    # on until the cart is well away from its start, then the block must be drawn where the
    # cart is. The view follows a cart in jumps (recentring it near the edge), so "where the cart
    # is" is the view's own transform of its x, and the block moved on the canvas unless the
    # view jumped to it.
    p.page.click("#play")
    p.wait("Math.abs(multipendulum.state.terms.cart.x + 0.2) > 0.1")
    p.page.click("#play")
    x, centre = p.js("[multipendulum.state.terms.cart.x, multipendulum.state.chainView.centre[0]]")
    count, x_after = _cart_pixels(p)
    assert count > 200 and abs(x_after - _cart_drawn_at(p, x)) < 2, (x_after, _cart_drawn_at(p, x))
    if centre == -0.2:  # the view stayed: the block moved with the cart
        assert abs(x_after - x_before) > 5 and (x_after - x_before) * (x + 0.2) > 0, (x_before, x_after, x)
    # The pivot rides on the cart: the base is the cart's position at y = 0.
    last = samples[-1]
    assert last["base"] == [last["cart"]["x"], 0]
    assert last["work"]["cart"] != 0 and last["dissipated"] > 0 and last["residual"] < 1e-7
    assert p.errors == []


def _kapitza(served):
    """The Kapitza scenario served and run for 3 s, with its checks; returns the page."""
    p = served(load_scenario(ROOT / "examples" / "kapitza.toml"))
    assert p.page.input_value("[name=pivot_y]").startswith('{ kind = "sinusoid", amplitude = 0.02, frequency = 300')
    assert p.js("multipendulum.state.terms.base") == [0, 0.02]  # y = 0.02 sin(pi/2) at t = 0
    samples = _run_terms(p, 3.0, every=0.01)
    ys = [s["base"][1] for s in samples]
    assert max(ys) - min(ys) > 0.02 and max(abs(y) for y in ys) <= 0.02 + 1e-15, ys
    assert all(s["base"][0] == 0 for s in samples)
    # Above the threshold of stability the shaken rod stays near upright, 8 degrees off at start.
    theta = p.js("multipendulum.state.sim.theta()")[0]
    assert abs(theta - math.pi) < 0.4, theta
    assert max(abs(s["work"]["pivot"]) for s in samples) > 0 and samples[-1]["residual"] < 1e-7
    assert "moving pivot" in p.page.locator("#status").inner_text()
    assert p.page.locator("#pivot").is_visible() and p.errors == []
    return p


def test_a_kapitza_pivot_moves_and_holds_the_pendulum_up(served):
    _kapitza(served)


def test_the_url_shares_the_pivot_and_the_cart(served, open_page):
    p = _kapitza(served)
    url = p.page.url
    q = open_page(url[url.index("?"):])
    assert q.js("multipendulum.state.setup.pivot") == p.js("multipendulum.state.setup.pivot")
    q.page.fill("[name=pivot_y]", "")
    q.set("cart_mass", "2")
    q.set("cart_force", "1.5")
    url = q.page.url
    r = open_page(url[url.index("?"):])
    assert r.js("multipendulum.state.setup.cart") == {"mass": 2, "damping": 0, "x0": 0, "v0": 0, "force": 1.5}
    assert r.page.locator("#cart-x").is_visible() and not r.page.locator("#pivot").is_visible()
    assert r.js("multipendulum.state.setup.pivot") is None and q.errors == r.errors == []


def test_a_torque_scenario_is_driven_and_does_work(served, open_page):
    # From the server: a joint torque table read from its CSV file.
    p = served(load_scenario(ROOT / "examples" / "driven_rod.toml"))
    assert p.message() == "Loaded scenario.json. Press Play."  # no note: the torque is applied
    samples = _run_terms(p, 2.0)
    assert samples[-1]["work"]["torque"] > 0.1 and samples[-1]["workIn"] == samples[-1]["work"]["torque"]
    assert max(s["residual"] for s in samples) < 1e-7
    assert float(p.page.locator("#work").inner_text().split()[0]) > 0.1
    # The pumped rod swings up beyond what its start (5 degrees) could give.
    assert samples[-1]["energy"] > samples[0]["energy"] + 0.1
    # From the page's file input: a generalized sinusoidal torque on a 4-link chain.
    q = open_page()
    q.page.set_input_files("#load", str(ROOT / "examples" / "seed000_driven_chain.toml"))
    q.wait("multipendulum.state.sim.n === 4")
    assert q.message() == "Loaded seed000_driven_chain.toml. Press Play."
    assert "not applied" not in q.message() and "ignored" not in q.message()
    assert q.js("multipendulum.state.setup.torque.amplitude") == [4, 0, 0, 0]
    samples = _run_terms(q, 1.0)
    assert abs(samples[-1]["work"]["torque"]) > 1e-3 and samples[-1]["residual"] < 1e-7
    assert p.errors == [] and q.errors == []


def test_a_bad_damping_in_a_scenario_is_refused_visibly(open_page):
    p = open_page()
    bad = CART_SCENARIO.replace(b"lengths = [0.6]", b"lengths = [0.6]\ndamping = -0.5")
    p.page.set_input_files("#load", files=[{"name": "bad_damping.toml", "mimeType": "text/plain", "buffer": bad}])
    p.wait("document.getElementById('message').textContent.includes('damping')")
    assert p.message() == "Not applied: damping[0] must be >= 0 and finite, got -0.5"
    assert p.page.locator("[name=damping]").get_attribute("aria-invalid") == "true"
    assert p.js("multipendulum.state.setup.cart") is None  # nothing of it applied
    bad = CART_SCENARIO.replace(b"mass = 1.0", b"mass = -1.0")
    p.page.set_input_files("#load", files=[{"name": "bad_cart.toml", "mimeType": "text/plain", "buffer": bad}])
    p.wait("document.getElementById('message').textContent.includes('cart mass')")
    assert p.message() == "Not applied: cart mass must be > 0 and finite, got -1"
    assert p.page.locator("[name=cart_mass]").get_attribute("aria-invalid") == "true"
    assert p.errors == []


@pytest.mark.parametrize("case", ["losses_pivot_joint_table", "cart_force_torque"])
def test_one_wasm_step_of_the_extended_model_equals_the_python_package(open_page, case):
    p = open_page()
    n, dt = 3, 0.01
    rng = np.random.default_rng(13)
    lengths, masses = rng.uniform(0.3, 1.5, n), rng.uniform(0.2, 2.0, n)
    theta0, omega0 = rng.uniform(-3, 3, n), rng.uniform(-2, 2, n)
    damping, friction = [0.1, 0.0, 0.3], [0.05, 0.2, 0.0]
    params = dict(kind="rods", lengths=lengths.tolist(), masses=masses.tolist(), g=9.81, method="rk4", dt=dt,
                  theta=theta0.tolist(), omega=omega0.tolist())
    t_tab = [0.0, 0.004, 0.007, 0.02]
    v_tab = [[1.0, -0.5, 0.2], [0.3, 0.1, 0.0], [-0.7, 0.4, 0.9], [0.0, 0.0, 0.5]]
    if case == "losses_pivot_joint_table":
        params.update(damping=damping, friction=friction, friction_velocity=0.01,
                      pivot={"x": {"kind": "table", "t": [0, 0.005, 0.01, 0.02], "values": [0, 0.01, -0.02, 0.0]},
                             "y": {"kind": "sinusoid", "amplitude": 0.03, "frequency": 40.0, "phase": 0.3, "offset": 0.1}},
                      torque={"kind": "table", "convention": "joint", "t": t_tab, "values": v_tab, "interpolation": "cubic"})
        chain = mp.Chain.rods(lengths, masses, damping=damping, friction=friction, friction_velocity=0.01)
        kwargs = dict(pivot=mp.Pivot(x=mp.Table([0, 0.005, 0.01, 0.02], [0, 0.01, -0.02, 0.0], kind="cubic"),
                                     y=mp.Sinusoid(0.03, 40.0, phase=0.3, offset=0.1)),
                      joint_torque=mp.Table(t_tab, v_tab, kind="cubic"))
    else:
        params.update(damping=damping, cart={"mass": 1.7, "damping": 0.4, "x0": 0.3, "v0": -0.2,
                                             "force": {"kind": "table", "t": [0, 0.01], "values": [2.0, -1.0]}},
                      torque={"kind": "sinusoid", "convention": "generalized", "amplitude": [1.0, 0.0, 0.5],
                              "frequency": [3.0, 1.0, 7.0], "phase": [0.0, 0.0, 1.0], "offset": [0.1, 0.0, 0.0]})
        chain = mp.Chain.rods(lengths, masses, damping=damping, cart=mp.Cart(1.7, 0.4))
        kwargs = dict(cart_x0=0.3, cart_v0=-0.2, cart_force=mp.Table([0, 0.01], [2.0, -1.0]),
                      torque=mp.Sinusoid([1.0, 0.0, 0.5], [3.0, 1.0, 7.0], phase=[0.0, 0.0, 1.0], offset=[0.1, 0.0, 0.0]))
    got = p.js("""(p) => {
        const sim = multipendulum.engine.simulation(p);
        sim.advanceTo(p.dt, 1);
        const out = {t: sim.t, theta: sim.theta(), omega: sim.omega(), terms: sim.terms(), base: sim.base()};
        sim.free();
        return out;
    }""", params)
    sol = mp.simulate(chain, theta0, omega0, dt, method="rk4", dt=dt, t_eval=[dt], **kwargs)
    assert got["t"] == dt
    np.testing.assert_allclose(got["theta"], sol.theta[-1], rtol=0, atol=1e-12)
    np.testing.assert_allclose(got["omega"], sol.omega[-1], rtol=0, atol=1e-12)
    terms = got["terms"]
    scale = max(1.0, abs(terms["energy"]))
    assert abs(terms["energy"] - sol.energy[-1]) <= 1e-12 * scale
    for name in ("torque", "pivot", "cart"):
        assert abs(terms["work"][name] - getattr(sol.work, name)[-1]) <= 1e-12 * scale, name
    assert abs(terms["dissipated"] - sol.work.dissipated[-1]) <= 1e-12 * scale
    np.testing.assert_allclose(terms["base"], sol.pivot[-1], rtol=0, atol=1e-14)
    assert got["base"] == terms["base"]
    if case == "cart_force_torque":
        assert terms["cart"]["x"] == pytest.approx(sol.cart_x[-1], abs=1e-12)
        assert terms["cart"]["v"] == pytest.approx(sol.cart_v[-1], abs=1e-12)
    else:
        assert terms["cart"] is None


# ----------------------------------------------------------------------------------------------
# The explorable viewer: dragging the base, the phase plot, the flip-map explorer

# The bound of a dragged base's acceleration (crates/wasm: FOLLOW_ACCELERATION), m/s^2.
FOLLOW_ACCELERATION = 40.0


def _stage(p):
    """The canvas's centre (CSS px) and its scale (CSS px per metre) for a chain of `total` m."""
    box = p.page.locator("#view").bounding_box()
    inner = box["width"] - 2, box["height"] - 2  # inside the 1 px border
    return box["x"] + 1 + inner[0] / 2, box["y"] + 1 + inner[1] / 2, 0.47 * min(inner) / 2


def _drag_base(p, cx, cy, path, hold=1.0, pause_ms=30):
    """Grab the base at (cx, cy), move through `path` (CSS px), sampling the base's motion at
    each point, then hold the last point for `hold` s of simulated time (the run may be slower
    than real time on a busy machine); returns the samples (the pointer is still down)."""
    p.page.mouse.move(cx, cy)
    p.page.mouse.down()
    samples = []
    for x, y in path:
        p.page.mouse.move(x, y)
        p.page.wait_for_timeout(pause_ms)
        samples.append(p.js("({t: multipendulum.state.sim.t, ...multipendulum.state.sim.baseMotion()})"))
    p.wait(f"multipendulum.state.sim.t > {samples[-1]['t'] + hold}", timeout=30)
    return samples


def test_dragging_the_pivot_shakes_the_running_chain_and_its_work_balances(open_page):
    p = open_page("?n=2&lengths=1&masses=1&theta=0,0&method=rk4&dt=0.002")
    cx, cy, scale = _stage(p)
    assert not p.js("multipendulum.state.playing")
    # Out to the right, a fast jerk back and forth, then hold 0.6 m to the right.
    path = [(cx + k * 0.06 * scale, cy) for k in range(1, 11)] + [(cx - 0.5 * scale, cy + 0.3 * scale),
                                                                   (cx + 0.8 * scale, cy)] * 3
    path += [(cx + 0.6 * scale, cy)] * 5
    samples = _drag_base(p, cx, cy, path, hold=1.5)
    assert p.js("multipendulum.state.playing"), "grabbing the base runs the chain"
    assert p.js("multipendulum.state.drag.base") is True
    p.page.mouse.up()
    assert max(max(abs(a) for a in s["acc"]) for s in samples) <= FOLLOW_ACCELERATION * (1 + 1e-9)
    assert max(abs(s["acc"][0]) for s in samples) > 1.0, "the pivot was accelerated"
    terms = p.js("multipendulum.state.terms")
    assert abs(terms["base"][0] - 0.6) < 0.05 and abs(terms["base"][1]) < 0.05, terms["base"]
    # The chain answered through the moving-pivot physics, and the energy balance holds.
    theta = p.js("multipendulum.state.sim.theta()")
    assert max(abs(v) for v in theta) > 0.05, theta
    assert abs(terms["work"]["pivot"]) > 1e-3 and terms["residual"] < 1e-6, terms
    assert p.js("multipendulum.state.playing") and p.errors == []


def test_dragging_the_cart_pulls_it_along_its_rail(open_page):
    p = open_page("?n=1&kind=rods&lengths=1&masses=1&theta=0&cart_mass=1&method=rk4&dt=0.002")
    cx, cy, scale = _stage(p)
    count, x_before = _cart_pixels(p)
    assert count > 200
    _drag_base(p, cx, cy, [(cx + k * 0.05 * scale, cy - k * 2) for k in range(1, 11)] + [(cx + 0.5 * scale, cy)] * 5,
               hold=2.0)
    p.page.mouse.up()
    terms = p.js("multipendulum.state.terms")
    # Pulled along the rail only (the pointer also went up), towards the pointer's x.
    assert terms["base"][1] == 0 and terms["cart"]["x"] > 0.25, terms
    assert terms["work"]["cart"] != 0 and terms["residual"] < 1e-6, terms
    assert _cart_pixels(p)[1] > x_before + 10
    assert p.js("multipendulum.state.playing") and p.errors == []


def test_the_phase_plot_follows_the_chosen_link(open_page):
    p = open_page("?n=2&theta=130,160")
    blank = p.page.locator("#phase").screenshot()
    p.page.click("#play")
    p.wait("multipendulum.state.sim.t > 1")
    p.page.click("#play")
    points = p.js("multipendulum.state.phase.points")
    assert len(points) > 20
    t, theta, omega = points[-1]
    assert t == p.t
    wrapped = (p.js("multipendulum.state.sim.theta()")[0] + math.pi) % (2 * math.pi) - math.pi
    assert theta == pytest.approx(wrapped, abs=1e-12) and omega == p.js("multipendulum.state.sim.omega()")[0]
    assert p.page.locator("#phase").screenshot() != blank
    p.page.fill("#phase-link", "2")
    p.page.locator("#phase-link").dispatch_event("change")
    points = p.js("multipendulum.state.phase.points")
    assert len(points) == 1 and points[0][2] == p.js("multipendulum.state.sim.omega()")[1]
    assert p.errors == []


def _explorer(browser, site, query=""):
    p = Page(browser, site.url + "explore.html" + query)
    p.wait("!document.body.dataset.computing")
    return p


def test_the_flip_map_explorer_computes_the_cores_map_and_runs_a_clicked_cell(browser, site):
    p = _explorer(browser, site, "?resolution=8&t_max=2")
    try:
        assert p.page.title() == "multipendulum flip-map explorer"
        assert p.js("multipendulum.state.done.setup.resolution") == 8  # the map of the URL, on opening
        for name, value in [("resolution", "24"), ("t_max", "6"), ("theta1", "-150, 150"), ("masses", "1, 2")]:
            p.page.fill(f"[name={name}]", value)
        p.page.click("#compute")
        p.wait("multipendulum.state.done.setup.resolution === 24 && !document.body.dataset.computing")
        assert "resolution=24" in p.page.url and "masses=1%2C+2" in p.page.url  # the URL shares the map
        times = np.array([math.inf if v is None else v for v in p.js("Array.from(multipendulum.state.done.times)")])
        # The same kernel as the Python package's, cell for cell (rows: theta2 bottom up).
        n = 24
        centres = lambda a, b: np.radians(a + (b - a) * (np.arange(n) + 0.5) / n)
        t1, t2 = np.meshgrid(centres(-150, 150), centres(-180, 180))
        ref = mp.flip_times(mp.Chain([1, 1], [1, 2]), np.stack([t1, t2], axis=-1), t_max=6.0, dt=0.01)
        np.testing.assert_array_equal(times.reshape(n, n), ref)
        assert np.isfinite(ref).any() and np.isinf(ref).any()
        assert "576 pendulums" in p.page.locator("#status").inner_text()
        # Click a cell that flips: the viewer beside the map runs that pendulum.
        j, i = np.argwhere(np.isfinite(ref))[len(np.argwhere(np.isfinite(ref))) // 2]
        box = p.page.locator("#map").bounding_box()
        p.page.mouse.click(box["x"] + (i + 0.5) * box["width"] / n, box["y"] + (n - j - 0.5) * box["height"] / n)
        assert p.js("multipendulum.state.chosen") == [int(i), int(j)]
        assert f"flips at t = {ref[j, i]:.3f} s" in p.page.locator("#cell").inner_text()
        frame = p.page.frame_locator("#pendulum")
        frame.locator("body[data-ready=true]").wait_for(timeout=15000)
        inner = p.page.frames[1]
        for _ in range(100):
            if inner.evaluate("multipendulum.state.sim.t > 0.3"):
                break
            p.page.wait_for_timeout(50)
        assert inner.evaluate("multipendulum.state.playing")
        start = inner.evaluate("multipendulum.state.setup.theta")
        np.testing.assert_allclose(start, [t1[j, i], t2[j, i]], atol=1e-9)
        assert inner.evaluate("multipendulum.state.setup.masses") == [1, 2]
        assert p.errors == []
    finally:
        p.close()


@pytest.mark.parametrize("field, value, message", [
    ("resolution", "abc", 'Not computed: Resolution must be a whole number from 2 to 400, got "abc"'),
    ("resolution", "401", 'Not computed: Resolution must be a whole number from 2 to 400, got "401"'),
    ("theta2", "30, -30", 'Not computed: θ₂ from, to: "from" must be less than "to", both finite, got 30, -30'),
    ("dt", "-1", "Not computed: dt must be > 0 and finite, got -1"),
    ("lengths", "1, x", 'Not computed: Lengths: "x" is not a number'),
    ("masses", "1, -1", "Not computed: masses[1] must be >= 0 and finite, got -1"),
    ("t_max", "1e12", "Not computed: t_max / dt = 1.000e14 steps per trajectory, more than 1e9; use a larger dt or a shorter time"),
])
def test_the_explorer_refuses_bad_values_and_keeps_its_map(browser, site, field, value, message):
    p = _explorer(browser, site, "?resolution=4&t_max=1")
    try:
        before = p.js("multipendulum.state.done.times.length")
        p.page.fill(f"[name={field}]", value)
        p.page.click("#compute")
        assert p.page.locator("#message").inner_text() == message
        assert p.page.get_attribute(f"[name={field}]", "aria-invalid") == "true"
        assert p.js("multipendulum.state.done.times.length") == before and p.errors == []
    finally:
        p.close()
