"""Forward sensitivities (``mp.simulate(..., sensitivities=...)``) against high-order central
differences of the package's own runs, for every input, chain kind and method; the Gauss
methods' symplectic map; and the refusals."""
import numpy as np
import pytest

import multipendulum as mp
from multipendulum.errors import InputError

T_EVAL = np.array([0.0, 0.4, 1.0])
THETA0, OMEGA0 = [0.6, -0.4, 0.9], [0.3, -0.2, 0.5]


def params(kind, n):
    """The explicit parameters of a chain of `kind` (each varied alone by the differences)."""
    lengths = np.array([1.0, 0.8, 1.2][:n])
    masses = np.array([1.0, 0.7, 0.9][:n])
    p = dict(lengths=lengths, masses=masses, g=9.81)
    if kind == "points":
        p.update(com=lengths.copy(), inertia=np.zeros(n))
    elif kind == "rods":
        p.update(com=lengths / 2, inertia=masses * lengths**2 / 12)
    else:
        p.update(com=np.array([0.55, 0.35, 0.7][:n]), inertia=np.array([0.04, 0.02, 0.06][:n]))
    if kind in ("damped", "cart_damped"):
        p.update(damping=np.array([0.3, 0.2, 0.25][:n]), friction=np.array([0.05, 0.04, 0.03][:n]))
    return p


def make(kind, p):
    extra = {}
    if "damping" in p:
        extra.update(damping=p["damping"], friction=p["friction"], friction_velocity=0.5)
    if kind.startswith("cart"):
        extra.update(cart=mp.Cart(1.5, damping=0.2))
    return mp.Chain(p["lengths"], p["masses"], com=p["com"], inertia=p["inertia"], g=p["g"], **extra)


def run(kind, p, method, sens=None, theta0=None, omega0=None, **kw):
    n = len(p["lengths"])
    chain = make(kind, p)
    dt = None if method == "dop853" else 0.01
    tol = dict(rtol=1e-13, atol=1e-15) if method == "dop853" else {}
    extra = dict(cart_v0=0.3, cart_force=mp.Sinusoid([0.5], [2.0])) if kind.startswith("cart") else {}
    extra.update(kw)
    return mp.simulate(chain, THETA0[:n] if theta0 is None else theta0, OMEGA0[:n] if omega0 is None else omega0,
                       1.0, method=method, dt=dt, t_eval=T_EVAL, sensitivities=sens, **tol, **extra)


def state(sol):
    parts = [sol.theta, sol.omega]
    if sol.cart_x is not None:
        parts += [sol.cart_x[:, None], sol.cart_v[:, None]]
    return np.concatenate(parts, axis=-1)


def five_point(f, x=1.0):
    """The derivative at 0 of f(e), to O(h^4), h scaled to the size of the input x."""
    h = 1e-3 * max(abs(x), 0.1)
    return (f(-2 * h) - 8 * f(-h) + 8 * f(h) - f(2 * h)) / (12 * h)


def differences(kind, p, method, name):
    """d state / d input by central differences, (T, S, k)."""
    n = len(p["lengths"])
    cols = []
    for j in range(1 if name == "g" else n):
        def f(e):
            if name in ("theta0", "omega0"):
                x0 = np.array((THETA0 if name == "theta0" else OMEGA0)[:n], dtype=float)
                x0[j] += e
                return state(run(kind, p, method, **{name: x0}))
            q = {k: (v.copy() if isinstance(v, np.ndarray) else v) for k, v in p.items()}
            if name == "g":
                q["g"] += e
            else:
                q[name][j] += e
            return state(run(kind, q, method))
        value = {"theta0": THETA0, "omega0": OMEGA0}.get(name, p.get(name))
        cols.append(five_point(f, value if name == "g" else value[j]))
    return np.stack(cols, axis=-1)


def check(kind, n, method, names):
    p = params(kind, n)
    sol = run(kind, p, method, sens=names)
    for name in names:
        got = sol.sensitivities[name]
        want = differences(kind, p, method, name)
        assert got.shape == want.shape == (T_EVAL.size, 2 * n + (2 if kind.startswith("cart") else 0),
                                          1 if name == "g" else n)
        # Relative to the largest derivative (at least 1: some vanish, e.g. a single link's
        # length beyond its centre of mass).
        scale = max(np.max(np.abs(want)), 1.0)
        assert np.max(np.abs(got - want)) <= 1e-7 * scale, (kind, method, name, got - want)


PARAMETERS = ["lengths", "masses", "com", "inertia", "g"]


@pytest.mark.parametrize("method", ["rk4", "dop853", "gauss4", "gauss6"])
@pytest.mark.parametrize("kind", ["points", "rods", "general"])
def test_sensitivities_match_central_differences_of_the_runs(kind, method):
    # (Point masses have no inertia to move both ways: the other kinds cover it.)
    check(kind, 2, method, ["theta0", "omega0"] + [q for q in PARAMETERS if not (kind == "points" and q == "inertia")])


@pytest.mark.parametrize("method", ["rk4", "dop853", "gauss6"])
@pytest.mark.parametrize("kind", ["damped", "cart", "cart_damped"])
def test_with_losses_and_a_cart(kind, method):
    names = ["theta0", "omega0"] + PARAMETERS + (["damping", "friction"] if "damped" in kind else [])
    check(kind, 2, method, names)


@pytest.mark.parametrize("method", ["rk4", "gauss6"])
@pytest.mark.parametrize("n", [2, 3])
def test_directions_that_need_no_fields(n, method):
    # g, the inertias and the losses alone: the run skips the fields that lengths, masses and
    # centres of mass need. rk4 in the Lagrangian form (N = 2: its closed form; N = 3: the
    # recursion), gauss6 in the Hamiltonian form; with and without a cart.
    for kind in ("damped", "cart_damped"):
        check(kind, n, method, ["g", "inertia", "damping", "friction"])


@pytest.mark.parametrize("n", [1, 3])
def test_any_number_of_links(n):
    check("general", n, "rk4", ["theta0", "omega0"] + PARAMETERS)


def test_a_moving_pivot():
    # The pivot's acceleration enters as gravity; the derivatives still match the runs'.
    pivot = mp.Pivot(y=mp.Sinusoid(0.05, 40.0))
    p = params("general", 2)
    sol = run("general", p, "rk4", sens=["theta0", "g", "lengths"], pivot=pivot)
    for name in ("theta0", "g", "lengths"):
        n = 2
        cols = []
        for j in range(1 if name == "g" else n):
            def f(e):
                if name == "theta0":
                    x0 = np.array(THETA0[:n])
                    x0[j] += e
                    return state(run("general", p, "rk4", theta0=x0, pivot=pivot))
                q = {k: (v.copy() if isinstance(v, np.ndarray) else v) for k, v in p.items()}
                if name == "g":
                    q["g"] += e
                else:
                    q[name][j] += e
                return state(run("general", q, "rk4", pivot=pivot))
            # The shaken chain bends its map sharply: a finer stencil (h = 1e-4).
            cols.append(five_point(f, 0.1))
        want = np.stack(cols, axis=-1)
        assert np.max(np.abs(sol.sensitivities[name] - want)) <= 1e-7 * np.max(np.abs(want))


@pytest.mark.parametrize("method", ["gauss4", "gauss6"])
def test_the_gauss_methods_map_of_theta_p_is_symplectic(method):
    # d(theta, p)(t) / d(theta0, p0) = C(t) C(0)^-1, C the derivatives with respect to
    # (theta0, omega0); symplectic: M^T J M = J to round-off, long after the start.
    n = 3
    chain = mp.Chain([1.0, 0.8, 1.2], [1.0, 0.7, 0.9])
    sol = mp.simulate(chain, [2.0, -1.0, 2.5], [0.0, 1.0, -0.5], 10.0, method=method, dt=0.005,
                      t_eval=[0.0, 5.0, 10.0], sensitivities=["theta0", "omega0"])
    c = sol.canonical_sensitivities
    whole = np.concatenate([c["theta0"], c["omega0"]], axis=-1)
    j = np.block([[np.zeros((n, n)), np.eye(n)], [-np.eye(n), np.zeros((n, n))]])
    for r in (1, 2):
        m = whole[r] @ np.linalg.inv(whole[0])
        assert np.max(np.abs(m)) > 10  # a chaotic run: the map stretches
        assert np.max(np.abs(m.T @ j @ m - j)) < 1e-12 * np.max(np.abs(m)) ** 2
    # The rk4 run's map is not symplectic: the check can fail.
    rk = mp.simulate(chain, [2.0, -1.0, 2.5], [0.0, 1.0, -0.5], 2.0, method="rk4", dt=0.05,
                     t_eval=[0.0, 2.0], sensitivities=["theta0", "omega0"], form="hamiltonian")
    w = np.concatenate([rk.canonical_sensitivities["theta0"], rk.canonical_sensitivities["omega0"]], axis=-1)
    m = w[1] @ np.linalg.inv(w[0])
    assert np.max(np.abs(m.T @ j @ m - j)) > 1e-6 * np.max(np.abs(m)) ** 2


@pytest.mark.parametrize("method", ["rk4", "dop853"])
def test_asking_for_sensitivities_leaves_the_run_bit_for_bit(method):
    # dop853 controls the state's error only: the same steps, the same bits.
    chain = mp.Chain([1.0, 0.8], [1.0, 0.7], damping=[0.1, 0.1])
    kw = dict(method=method, dt=None if method == "dop853" else 0.01, t_eval=np.linspace(0, 5, 11))
    plain = mp.simulate(chain, [2.0, 1.0], [0.0, 0.0], 5.0, **kw)
    with_s = mp.simulate(chain, [2.0, 1.0], [0.0, 0.0], 5.0, sensitivities=["lengths", "damping"], **kw)
    assert np.array_equal(plain.theta, with_s.theta) and np.array_equal(plain.omega, with_s.omega)
    assert plain.stats.steps == with_s.stats.steps
    assert plain.sensitivities == {} and plain.canonical_sensitivities is None


def test_batches_carry_a_leading_axis_and_equal_their_single_runs():
    chain = mp.Chain([1.0, 0.8], [1.0, 0.7])
    th0 = np.array([[0.5, 0.1], [1.5, -0.5], [2.5, 1.0]])
    batch = mp.simulate(chain, th0, np.zeros_like(th0), 1.0, method="rk4", dt=0.01, t_eval=T_EVAL,
                        sensitivities=["masses", "g"])
    assert batch.sensitivities["masses"].shape == (3, T_EVAL.size, 4, 2)
    assert batch.sensitivities["g"].shape == (3, T_EVAL.size, 4, 1)
    for b in range(3):
        one = mp.simulate(chain, th0[b], [0.0, 0.0], 1.0, method="rk4", dt=0.01, t_eval=T_EVAL,
                          sensitivities=["masses", "g"])
        assert np.array_equal(one.sensitivities["masses"], batch.sensitivities["masses"][b])


def test_a_python_torque_of_time_is_differentiated_and_one_of_the_state_is_refused():
    chain = mp.Chain([1.0, 0.8], [1.0, 0.7])
    table = mp.simulate(chain, [0.5, 0.1], [0, 0], 1.0, method="rk4", dt=0.01, t_eval=T_EVAL,
                        torque=mp.Sinusoid([0.3, 0.0], [2.0, 1.0]), sensitivities=["lengths"])
    func = mp.simulate(chain, [0.5, 0.1], [0, 0], 1.0, method="rk4", dt=0.01, t_eval=T_EVAL,
                       torque=lambda t: [0.3 * np.sin(2.0 * t), 0.0], sensitivities=["lengths"])
    assert np.allclose(func.sensitivities["lengths"], table.sensitivities["lengths"], rtol=1e-12, atol=1e-14)
    with pytest.raises(InputError, match=r"^sensitivities need torques that depend on time only \(a constant, "
                                         r"Sinusoid, Table or f\(t\)\), not a feedback f\(t, theta, omega\)$"):
        mp.simulate(chain, [0.5, 0.1], [0, 0], 1.0, method="rk4", dt=0.01,
                    torque=lambda t, th, om: -om, sensitivities=["lengths"])


def test_bad_requests_are_refused_with_the_valid_names():
    chain = mp.Chain([1.0, 0.8], [1.0, 0.7])
    names = ", ".join(f'"{s}"' for s in mp.SENSITIVITIES)
    with pytest.raises(InputError, match=rf'^unknown sensitivity "length": the inputs are {names}$'):
        mp.simulate(chain, [0.5, 0.1], [0, 0], 1.0, sensitivities=["length"])
    with pytest.raises(InputError, match=r'^sensitivity "g" is given twice$'):
        mp.simulate(chain, [0.5, 0.1], [0, 0], 1.0, sensitivities=["g", "lengths", "g"])
    with pytest.raises(InputError, match=r"^sensitivities must be a list of names from theta0, omega0"):
        mp.simulate(chain, [0.5, 0.1], [0, 0], 1.0, sensitivities=[1, 2])
    with pytest.raises(InputError, match=r"^checkpoints cannot be combined with sensitivities"):
        mp.simulate(chain, [0.5, 0.1], [0, 0], 1.0, checkpoint="x.ckpt", sensitivities=["g"])
    cart = mp.Chain([1.0], [1.0], cart=mp.Cart(1.0))
    with pytest.raises(InputError, match=r"^sensitivities need a cart force that depends on time only"):
        mp.simulate(cart, [0.5], [0], 1.0, cart_force=lambda t, s: -s[0], sensitivities=["g"])
    # A single name reads as a list of one.
    one = mp.simulate(chain, [0.5, 0.1], [0, 0], 1.0, method="rk4", dt=0.01, sensitivities="g")
    assert list(one.sensitivities) == ["g"]


def test_the_sensitivities_page_examples_run_in_order():
    import re
    from pathlib import Path

    page = Path(__file__).resolve().parents[1] / "docs" / "sensitivities.md"
    blocks = re.findall(r"```python\n(.*?)```", page.read_text(), flags=re.S)
    assert len(blocks) >= 3
    namespace: dict = {}
    for i, block in enumerate(blocks):
        exec(compile(block, f"docs/sensitivities.md python block {i}", "exec"), namespace)
    # The page's claims: the symplectic defect at round-off, the fit near the truth.
    m, j = namespace["m"], namespace["j"]
    assert np.abs(m.T @ j @ m - j).max() / np.abs(m).max() ** 2 < 1e-14
    result = namespace["result"]
    assert np.all(np.abs(result.values["lengths"] - [1.0, 0.8]) < 3 * result.stderr["lengths"])


def test_the_hamiltonian_form_on_a_pivot_shaken_both_ways():
    # The columns of (theta, p) turned into rates through omega = M^-1 p, in the pivot's frame.
    pivot = mp.Pivot(x=mp.Sinusoid(0.03, 15.0), y=mp.Sinusoid(0.05, 20.0))
    chain = mp.Chain([1.0, 0.8], [1.0, 0.7], com=[0.55, 0.35], inertia=[0.04, 0.02])
    kw = dict(method="rk4", dt=0.005, t_eval=T_EVAL, pivot=pivot, form="hamiltonian")
    sol = mp.simulate(chain, [0.6, -0.4], [0.3, -0.2], 1.0, sensitivities=["omega0", "g"], **kw)

    def f(e, j):
        om = np.array([0.3, -0.2])
        om[j] += e
        return state(mp.simulate(chain, [0.6, -0.4], om, 1.0, **kw))
    want = np.stack([five_point(lambda e: f(e, j), 0.1) for j in range(2)], axis=-1)
    assert np.max(np.abs(sol.sensitivities["omega0"] - want)) <= 1e-7 * np.max(np.abs(want))
    assert sol.canonical_sensitivities["g"].shape == sol.sensitivities["g"].shape


def test_events_and_a_terminal_stop_keep_the_columns_to_the_stop():
    chain = mp.Chain([1.0, 0.8], [1.0, 0.7])
    sol = mp.simulate(chain, [2.5, 2.0], [0, 0], 10.0, method="rk4", dt=0.01, t_eval=np.linspace(0, 10, 101),
                      events=[mp.Flip(terminal=True)], sensitivities=["theta0"])
    plain = mp.simulate(chain, [2.5, 2.0], [0, 0], 10.0, method="rk4", dt=0.01, t_eval=np.linspace(0, 10, 101),
                        events=[mp.Flip(terminal=True)])
    assert sol.stopped_at is not None and sol.stopped_at == plain.stopped_at
    assert sol.sensitivities["theta0"].shape == (sol.t.size, 4, 2) and np.array_equal(sol.theta, plain.theta)
    assert np.all(np.isfinite(sol.sensitivities["theta0"]))


def test_the_memory_check_counts_the_columns():
    # 10^5 outputs of 200 links fit; with both initial-state inputs (400 directions of 400
    # values each) they would need over a terabyte: refused before the run.
    chain = mp.Chain(np.ones(200), np.ones(200))
    with pytest.raises(InputError, match=r"^storing 100000 output points of 200 links needs"):
        mp.simulate(chain, np.full(200, 0.1), np.zeros(200), 1.0, method="rk4", dt=1e-5,
                    t_eval=np.linspace(0, 1, 100_000), sensitivities=["theta0", "omega0"])
