"""The browser viewer's local server (``multipendulum serve``).

The viewer is a static page (``multipendulum/web``: HTML, ES modules, CSS and the core compiled to
WebAssembly); any static file server can serve it. This one adds a scenario: it checks the file
with :mod:`multipendulum.scenario` and serves it as ``/scenario.json``, which the page loads when
its URL says ``?scenario=scenario.json``.

It is deliberately small and closed: it binds 127.0.0.1 unless told otherwise, answers GET and
HEAD only, and serves a fixed list of files (the web directory's own files, read when the
server starts, and the scenario). A request path is looked up by name in that list and never
joined to a directory, so ``..``, ``%2f`` and absolute paths cannot reach other files. On a
loopback address it also refuses requests whose ``Host`` is not the server's own (DNS
rebinding). It opens no browser and no other port.
"""
from __future__ import annotations

import ipaddress
import json
import socket
import sys
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any, Dict, Optional, Union
from urllib.parse import unquote, urlsplit

import numpy as np

from ._files import web_dir
from .errors import InputError

__all__ = ["web_dir", "scenario_json", "make_server", "parse_host", "parse_port", "WASM_NAME"]

WASM_NAME = "multipendulum.wasm"
SCENARIO_NAME = "scenario.json"

_TYPES = {
    ".html": "text/html; charset=utf-8",
    ".js": "text/javascript; charset=utf-8",
    ".css": "text/css; charset=utf-8",
    ".wasm": "application/wasm",
    ".json": "application/json",
    ".png": "image/png",
    ".svg": "image/svg+xml",
}
# The page needs its own scripts, WebAssembly compilation and data: URLs (the empty favicon);
# the flip-map explorer shows the viewer in a frame of its own origin.
_POLICY = ("default-src 'self'; script-src 'self' 'wasm-unsafe-eval'; style-src 'self'; "
           "img-src 'self' data:; connect-src 'self'; object-src 'none'; base-uri 'none'; "
           "form-action 'none'; frame-ancestors 'self'")


def _plain(value: Any) -> Any:
    """A scenario's numbers (NumPy arrays and scalars included) as JSON's lists and floats."""
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple, np.ndarray)):
        return [_plain(v) for v in value]
    if isinstance(value, (bool, str)) or value is None:
        return value
    return float(value)


def _signal(spec) -> Optional[Dict[str, Any]]:
    """A :class:`~multipendulum.scenario.SignalSpec` as the page takes it: ``{"kind": ..., **params}``."""
    return None if spec is None else {"kind": spec.kind, **_plain(spec.params)}


def scenario_json(scenario) -> Dict[str, Any]:
    """A checked :class:`~multipendulum.scenario.Scenario` as the page's setup: chain (with its
    losses), start (radians), integrator, and the drive: the pivot's motion or the cart, and the
    torque (tables with their samples, whether they came from a CSV file or not)."""
    chain = scenario.chain

    def floats(values):
        return None if values is None else [float(v) for v in values]

    cart = scenario.cart
    torque = scenario.torque
    return {
        "name": scenario.name,
        "kind": chain["kind"],
        "lengths": floats(chain["lengths"]),
        "masses": floats(chain["masses"]),
        "com": floats(chain.get("com")),
        "inertia": floats(chain.get("inertia")),
        "g": float(chain["g"]),
        "damping": floats(chain.get("damping")),
        "friction": floats(chain.get("friction")),
        "friction_velocity": None if chain.get("friction_velocity") is None else float(chain["friction_velocity"]),
        "theta": floats(scenario.theta0),
        "omega": floats(scenario.omega0),
        "method": scenario.method,
        "dt": scenario.dt,
        "rtol": scenario.rtol,
        "atol": scenario.atol,
        "pivot": None if scenario.pivot is None else {axis: _signal(spec) for axis, spec in scenario.pivot.items()},
        "cart": None if cart is None else {"mass": float(cart.mass), "damping": float(cart.damping), "x0": float(cart.x0),
                                           "v0": float(cart.v0), "force": _signal(cart.force)},
        "torque": None if torque is None else {"kind": torque.kind, "convention": torque.convention,
                                               **_plain(torque.params)},
        "notes": [],
    }


def parse_port(text: Union[str, int]) -> int:
    """A TCP port, 0 (any free port) to 65535."""
    try:
        port = int(str(text), 10)
    except ValueError:
        raise InputError(f"port must be a whole number from 0 to 65535, got {str(text)!r}") from None
    if not 0 <= port <= 65535:
        raise InputError(f"port must be a whole number from 0 to 65535, got {port}")
    return port


def parse_host(text: str) -> str:
    """An IP address to bind (``localhost`` means 127.0.0.1); names are not resolved."""
    if text == "localhost":
        return "127.0.0.1"
    try:
        return str(ipaddress.ip_address(text.strip("[]")))
    except ValueError:
        raise InputError(f"host must be an IP address such as 127.0.0.1 (or localhost), got {text!r}") from None


def _files(root: Path) -> Dict[str, Path]:
    """The servable files: regular files directly in ``root`` (no subdirectories, no dot files)."""
    return {p.name: p for p in sorted(root.iterdir())
            if p.is_file() and not p.name.startswith(".") and p.suffix in _TYPES}


class _Server(ThreadingHTTPServer):
    daemon_threads = True
    allow_reuse_address = True

    def __init__(self, address, files: Dict[str, bytes], redirect: Optional[str], quiet: bool):
        host = address[0]
        self.address_family = socket.AF_INET6 if ":" in host else socket.AF_INET
        self.files = files
        self.redirect = redirect
        self.quiet = quiet
        super().__init__(address, _Handler)
        port = self.server_address[1]
        self.loopback = ipaddress.ip_address(host).is_loopback
        shown = f"[{host}]" if ":" in host else host
        self.allowed_hosts = {f"{shown}:{port}", f"localhost:{port}"}
        self.url = f"http://{shown}:{port}/"


class _Handler(BaseHTTPRequestHandler):
    server: _Server

    def version_string(self) -> str:
        return "multipendulum"

    def do_HEAD(self) -> None:
        self._answer(body=False)

    def do_GET(self) -> None:
        self._answer(body=True)

    def _answer(self, body: bool) -> None:
        if self.server.loopback and self.headers.get("Host", "") not in self.server.allowed_hosts:
            return self._error(HTTPStatus.FORBIDDEN, "unknown Host")
        parts = urlsplit(self.path)
        path = unquote(parts.path)
        if path == "/" and self.server.redirect and not parts.query:
            self.send_response(HTTPStatus.FOUND)
            self.send_header("Location", self.server.redirect)
            self.send_header("Content-Length", "0")
            self.end_headers()
            return
        name = "index.html" if path == "/" else path[1:] if path.startswith("/") else ""
        data = self.server.files.get(name)  # a name in a fixed table, never a path on disk
        if data is None:
            return self._error(HTTPStatus.NOT_FOUND, "not found")
        self.send_response(HTTPStatus.OK)
        self.send_header("Content-Type", _TYPES[Path(name).suffix])
        self.send_header("Content-Length", str(len(data)))
        self.send_header("Cache-Control", "no-cache")
        self.send_header("X-Content-Type-Options", "nosniff")
        self.send_header("Content-Security-Policy", _POLICY)
        self.end_headers()
        if body:
            self.wfile.write(data)

    def _error(self, status: HTTPStatus, text: str) -> None:
        data = f"{int(status)} {text}\n".encode()
        self.send_response(status)
        self.send_header("Content-Type", "text/plain; charset=utf-8")
        self.send_header("Content-Length", str(len(data)))
        self.end_headers()
        if self.command != "HEAD":
            self.wfile.write(data)

    def log_message(self, format: str, *args: Any) -> None:
        if not self.server.quiet:
            sys.stderr.write(f"{self.address_string()} {format % args}\n")


def make_server(host: str = "127.0.0.1", port: int = 0, scenario=None, quiet: bool = False,
                root: Optional[Path] = None) -> _Server:
    """A server for the viewer (not yet serving: call ``serve_forever``). ``scenario`` is a checked
    :class:`~multipendulum.scenario.Scenario`; ``server.url`` is the page's address."""
    host = parse_host(host)
    port = parse_port(port)
    root = web_dir() if root is None else Path(root)
    paths = _files(root)
    if WASM_NAME not in paths or "index.html" not in paths:
        raise InputError(f"the viewer is not built: {root / WASM_NAME} is missing (run `make build`)")
    files = {name: p.read_bytes() for name, p in paths.items()}
    redirect = None
    if scenario is not None:
        files[SCENARIO_NAME] = json.dumps(scenario_json(scenario)).encode()
        redirect = f"/?scenario={SCENARIO_NAME}"
    return _Server((host, port), files, redirect, quiet)
