"""Fuzz target: the core's public constructors and a short run, through the Python binding
(atheris / libFuzzer).

From the fuzzer's bytes: a chain (``mp.Chain`` or ``mp.Chain.rods``, any N, any numbers, NaN
and inf included, arrays of any length), states, a torque and run settings; then the chain's
methods and a short ``mp.simulate`` (``max_steps`` bounds it). Only ``mp.InputError`` and, for a
run, ``mp.IntegrationError`` are accepted, each with a message; results must hold no NaN. Any
other exception -- above all a Rust panic, which pyo3 raises as ``PanicException`` (a
``BaseException``) -- is a crash that libFuzzer reports with its input.

    python fuzz/fuzz_core.py -max_total_time=60 out/fuzz/core fuzz/corpus
"""
import math
import sys

import atheris

with atheris.instrument_imports():
    import numpy as np

    import multipendulum as mp

METHODS = mp.METHODS  # the core's list, as it states it


def _numbers(fdp, n):
    """n floats; mostly ordinary values, sometimes anything at all (NaN, inf, 1e308, -0.0)."""
    if fdp.ConsumeIntInRange(0, 3) == 0:
        return [fdp.ConsumeRegularFloat() if fdp.ConsumeBool() else fdp.ConsumeFloat() for _ in range(n)]
    return [fdp.ConsumeFloatInRange(-10.0, 10.0) for _ in range(n)]


def _length(fdp, n):
    """Usually n, sometimes another length (a shape error the API must name)."""
    return n if fdp.ConsumeIntInRange(0, 7) else fdp.ConsumeIntInRange(0, 2 * n + 2)


def _expected(e):
    if not str(e).strip():
        raise AssertionError(f"{type(e).__name__} without a message")


def _finite(name, value):
    a = np.asarray(value, dtype=float)
    if np.isnan(a).any():
        raise AssertionError(f"NaN in {name}")


def TestOneInput(data: bytes) -> None:
    fdp = atheris.FuzzedDataProvider(data)
    n = fdp.ConsumeIntInRange(1, 6) if fdp.ConsumeIntInRange(0, 15) else fdp.ConsumeIntInRange(0, 300)
    try:
        lengths = _numbers(fdp, n)
        masses = _numbers(fdp, _length(fdp, n))
        g = fdp.ConsumeFloat() if fdp.ConsumeIntInRange(0, 7) == 0 else 9.81
        if fdp.ConsumeBool():
            chain = mp.Chain.rods(lengths, masses, g=g)
        else:
            com = _numbers(fdp, _length(fdp, n)) if fdp.ConsumeBool() else None
            inertia = [abs(x) for x in _numbers(fdp, _length(fdp, n))] if fdp.ConsumeBool() else None
            chain = mp.Chain(lengths, masses, com=com, inertia=inertia, g=g)
    except mp.InputError as e:
        _expected(e)
        return
    theta = _numbers(fdp, _length(fdp, chain.n))
    omega = _numbers(fdp, _length(fdp, chain.n))
    try:
        _finite("mass_matrix", chain.mass_matrix(theta))
        _finite("energy", chain.energy(theta, omega))
        _finite("accelerations", chain.accelerations(theta, omega))
    except (mp.InputError, mp.IntegrationError) as e:
        _expected(e)
    method = METHODS[fdp.ConsumeIntInRange(0, 3)] if fdp.ConsumeIntInRange(0, 15) else fdp.ConsumeUnicode(6)
    t_end = fdp.ConsumeFloatInRange(0.0, 2.0) if fdp.ConsumeIntInRange(0, 7) else fdp.ConsumeFloat()
    dt = fdp.ConsumeFloatInRange(1e-3, 0.1) if fdp.ConsumeIntInRange(0, 7) else fdp.ConsumeFloat()
    kwargs = dict(method=method, dt=None if method == "dop853" and fdp.ConsumeBool() else dt, max_steps=2000)
    choice = fdp.ConsumeIntInRange(0, 3)
    if choice == 1:
        kwargs["torque"] = _numbers(fdp, _length(fdp, chain.n))
    elif choice == 2:
        kwargs["joint_torque"] = mp.Sinusoid(_numbers(fdp, _length(fdp, chain.n)), fdp.ConsumeFloat())
    elif choice == 3:
        k = fdp.ConsumeIntInRange(0, 4)
        kwargs["torque"] = mp.Table(sorted(_numbers(fdp, k)), [_numbers(fdp, chain.n) for _ in range(k)],
                                    kind=("linear", "cubic", "")[fdp.ConsumeIntInRange(0, 2)])
    if fdp.ConsumeBool() and math.isfinite(t_end) and t_end > 0:
        kwargs["t_eval"] = np.linspace(0.0, t_end, fdp.ConsumeIntInRange(1, 50))
    try:
        sol = mp.simulate(chain, theta, omega, t_end, **kwargs)
    except (mp.InputError, mp.IntegrationError) as e:
        _expected(e)
        return
    for name in ("theta", "omega", "p", "energy"):
        _finite(name, getattr(sol, name))


def main() -> None:
    atheris.Setup(sys.argv, TestOneInput)
    atheris.Fuzz()


if __name__ == "__main__":
    main()
