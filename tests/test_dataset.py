"""Datasets (mp.make_dataset, mp.load_dataset, `multipendulum dataset`): every record obeys
Hamilton's equations against an independent derivation, the files are reproducible byte for byte,
Zarr and NPZ hold the same arrays, the split is by trajectory, the loader serves a DataLoader, and
bad input is refused before any work with its exact message.

The reference is derived here with sympy from Cartesian positions alone (nothing is read from the
package): the centre of mass of link i relative to the pivot, ``r_i = sum_{j<i} l_j (sin q_j,
-cos q_j) + c_i (sin q_i, -cos q_i)``; velocities by the chain rule; in the pivot's frame
``L = T_rel + sum m_i gvec . r_i`` with the effective gravity ``gvec = (-a_x, -g - a_y)`` of a pivot
accelerating at ``a`` (the pivot's acceleration evaluated here from its sinusoid). Then
``p = dL/dqdot``, ``-dH/dq = dL/dq`` (at fixed p and at fixed qdot: the Legendre transform),
``pdot = d/dt dL/dqdot = (d p / d q) qdot + (d p / d qdot) qddot`` on the records' q, qdot and
qddot, and the lab-frame energy from the lab velocities ``v_pivot + J qdot``. The generalized
forces of the joints are the couples' virtual work: joint i turns at ``w_i = qdot_i - qdot_{i-1}``
with the torque ``u_i = -b_i w_i - f_i tanh(w_i / v_s)`` (plus a motor's), acting ``+u_i`` on link
i and ``-u_i`` on link i-1.
"""
from __future__ import annotations

import hashlib
import json
import os
import pickle
import re
import subprocess
import sys
import textwrap
from functools import lru_cache
from pathlib import Path

import numpy as np
import pytest
import sympy as sp

import multipendulum as mp
import multipendulum._dataset as dsmod
from multipendulum.cli import main

ROOT = Path(__file__).resolve().parents[1]
TOL = 1e-10


# ---------------------------------------------------------------------------------------------
# The independent reference (N = 2)
# ---------------------------------------------------------------------------------------------
@lru_cache(maxsize=None)
def reference():
    q = sp.symbols("q1 q2")
    w = sp.symbols("w1 w2")
    a = sp.symbols("a1 a2")
    l = sp.symbols("l1 l2")
    m = sp.symbols("m1 m2")
    c = sp.symbols("c1 c2")
    inertia = sp.symbols("I1 I2")
    gx, gy, g, vx, vy, yp = sp.symbols("gx gy g vx vy yp")
    pos = []
    for i in range(2):
        x = sum(l[j] * sp.sin(q[j]) for j in range(i)) + c[i] * sp.sin(q[i])
        y = sum(-l[j] * sp.cos(q[j]) for j in range(i)) - c[i] * sp.cos(q[i])
        pos.append((x, y))
    vel = [tuple(sum(sp.diff(r, q[j]) * w[j] for j in range(2)) for r in ri) for ri in pos]
    t_rel = sum(m[i] * (vel[i][0] ** 2 + vel[i][1] ** 2) / 2 + inertia[i] * w[i] ** 2 / 2 for i in range(2))
    lag = t_rel + sum(m[i] * (gx * pos[i][0] + gy * pos[i][1]) for i in range(2))
    p = [sp.diff(lag, w[i]) for i in range(2)]
    dl_dq = [sp.diff(lag, q[i]) for i in range(2)]
    p_dot = [sum(sp.diff(p[i], q[j]) * w[j] + sp.diff(p[i], w[j]) * a[j] for j in range(2)) for i in range(2)]
    mass = [[sp.diff(p[i], w[j]) for j in range(2)] for i in range(2)]
    t_lab = sum(m[i] * ((vx + vel[i][0]) ** 2 + (vy + vel[i][1]) ** 2) / 2 + inertia[i] * w[i] ** 2 / 2
                for i in range(2))
    energy = t_lab + sum(m[i] * g * (yp + pos[i][1]) for i in range(2))
    args = (*q, *w, *a, *l, *m, *c, *inertia, gx, gy, g, vx, vy, yp)
    fn = (lambda e: sp.lambdify(args, e, modules="numpy", cse=True))
    return {"p": fn(p), "dl_dq": fn(dl_dq), "p_dot": fn(p_dot), "mass": fn(mass), "energy": fn(energy)}


def _sin(s, t):
    """A pivot axis given as a sinusoid dict (or a number): position, velocity, acceleration at t."""
    if not isinstance(s, dict):
        return float(s) + 0 * t, 0 * t, 0 * t
    arg = s["frequency"] * t + s.get("phase", 0.0)
    amp, om = s["amplitude"], s["frequency"]
    return s.get("offset", 0.0) + amp * np.sin(arg), amp * om * np.cos(arg), -amp * om**2 * np.sin(arg)


def expected(ds, config):
    """Per record (B, T, ...): p, dL/dq, p_dot (from the records' qddot), the mass matrix, the lab
    energy, and the generalized force Q of the losses and torques."""
    q, w, acc = ds["q"], ds["qdot"], ds["qddot"]
    b, T, _ = q.shape
    t = np.broadcast_to(ds.t, (b, T))
    par = {k: np.broadcast_to(ds[k][:, None, :], (b, T, 2)) for k in ("lengths", "masses", "com", "inertia")}
    g = np.broadcast_to(ds["g"][:, None], (b, T))
    pivot = config.get("pivot") or {}
    xp, vxp, axp = _sin(pivot.get("x", 0.0), t)
    yp, vyp, ayp = _sin(pivot.get("y", 0.0), t)
    args = [q[..., 0], q[..., 1], w[..., 0], w[..., 1], acc[..., 0], acc[..., 1]]
    for k in ("lengths", "masses", "com", "inertia"):
        args += [par[k][..., 0], par[k][..., 1]]
    args += [-axp, -g - ayp, g, vxp, vyp, yp]
    f = reference()
    stack = (lambda key: np.moveaxis(np.broadcast_arrays(*f[key](*args)), 0, -1))
    out = {"p": stack("p"), "dl_dq": stack("dl_dq"), "p_dot": stack("p_dot")}
    out["mass"] = np.stack([np.stack(np.broadcast_arrays(*row), -1) for row in f["mass"](*args)], -2)
    out["energy"] = np.broadcast_to(f["energy"](*args), (b, T))
    # Generalized forces: the joints' couples and the driving torques.
    rel = w - np.concatenate([np.zeros((b, T, 1)), w[..., :-1]], axis=-1)
    u = np.zeros_like(w)
    if "damping" in ds.fields:
        u -= ds["damping"][:, None, :] * rel
    if "friction" in ds.fields:
        u -= ds["friction"][:, None, :] * np.tanh(rel / config.get("friction_velocity", 1e-3))
    torque = config.get("torque")
    tau = np.zeros_like(w)
    if torque is not None:
        if torque["kind"] == "constant":
            value = np.broadcast_to(np.asarray(torque["value"], float), (b, T, 2))
        else:  # sinusoid
            amp, om, ph, off = (np.asarray(torque.get(k, 0.0), float) for k in ("amplitude", "frequency", "phase", "offset"))
            value = off + amp * np.sin(om * t[..., None] + ph)
        if torque.get("convention", "generalized") == "joint":
            u = u + value
        else:
            tau = tau + value
    out["Q"] = u - np.concatenate([u[..., 1:], np.zeros((b, T, 1))], axis=-1) + tau
    return out


def close(got, want, what, tol=TOL):
    err = np.abs(got - want) / (1.0 + np.abs(want))
    worst = np.unravel_index(np.argmax(err), err.shape)
    assert err.max() <= tol, f"{what}: relative error {err.max():.3g} at {worst}: {got[worst]} vs {want[worst]}"


# ---------------------------------------------------------------------------------------------
# The physics of every record
# ---------------------------------------------------------------------------------------------
CASES = {
    # random general bodies, conservative
    "conservative": dict(trajectories=6, t_end=1.0, sample_dt=0.05, seed=11, links=2,
                         lengths={"low": 0.5, "high": 1.5}, masses={"low": [0.5, 1.0], "high": [2.0, 3.0]},
                         com={"low": 0.2, "high": 0.6}, inertia={"low": 0.0, "high": 0.1}, g={"low": 5.0, "high": 15.0},
                         theta={"low": -2.0, "high": 2.0}, omega={"low": -1.0, "high": 1.0}),
    # rods at drawn energies, damped, with friction and a generalized sinusoidal torque
    "losses and torque": dict(trajectories=5, t_end=1.0, sample_dt=0.05, seed=12, links=2, kind="rods",
                              lengths=[1.0, 0.7], masses={"low": 0.5, "high": 2.0}, damping={"low": 0.0, "high": 0.3},
                              friction=0.05, friction_velocity=0.1, energy={"low": -10.0, "high": 20.0},
                              torque={"kind": "sinusoid", "amplitude": [0.5, -0.3], "frequency": [3.0, 5.0],
                                      "phase": [0.0, 1.0], "offset": [0.1, 0.0]}),
    # a shaken pivot, point masses, a constant joint-motor torque
    "pivot": dict(trajectories=4, t_end=0.5, sample_dt=0.025, seed=13, lengths=[1.0, 0.8], masses=[1.0, 0.5],
                  damping=[0.1, 0.0], theta={"low": -0.5, "high": 0.5},
                  torque={"kind": "constant", "convention": "joint", "value": [0.2, -0.1]},
                  pivot={"x": {"kind": "sinusoid", "amplitude": 0.05, "frequency": 20.0},
                         "y": {"kind": "sinusoid", "amplitude": 0.1, "frequency": 30.0, "phase": 0.5, "offset": 0.2}}),
}


@pytest.mark.parametrize("case", list(CASES))
def test_every_record_obeys_hamiltons_equations_against_an_independent_derivation(tmp_path, case):
    config = CASES[case]
    ds = mp.make_dataset(tmp_path / "ds", format="npz", **config)
    ref = expected(ds, config)
    q, qdot = ds["q"], ds["qdot"]
    assert q.shape == (config["trajectories"], int(round(config["t_end"] / config["sample_dt"])) + 1, 2)
    close(ds["p"], ref["p"], "p = dL/dqdot")
    close(ds["dH_dp"], qdot, "dH/dp = qdot")
    close(ds["dH_dp"], np.linalg.solve(ref["mass"], ds["p"][..., None])[..., 0], "dH/dp = M^-1 p")
    close(-ds["dH_dq"], ref["dl_dq"], "-dH/dq = dL/dq")
    forced = "torque" in config or "damping" in config or "friction" in config
    assert ("Q" in ds.fields) == forced
    Q = ds["Q"] if forced else 0.0
    if forced:
        close(ds["Q"], ref["Q"], "Q, the joints' couples and the torques")
        assert np.abs(ds["Q"]).max() > 1e-3  # the check above is not of zeros
    close(ref["p_dot"], -ds["dH_dq"] + Q, "pdot = -dH/dq + Q (pdot from qddot by the chain rule)")
    close(ds["energy"], ref["energy"], "energy = T + U in the lab frame")
    # The parameters of each trajectory are the ones drawn, inside their ranges.
    for key, spec in config.items():
        if isinstance(spec, dict) and key in ("lengths", "masses", "com", "inertia", "g", "damping"):
            v = ds[key]
            assert (v >= np.asarray(spec["low"]) - 1e-15).all() and (v <= np.asarray(spec["high"]) + 1e-15).all()
            assert np.ptp(v, axis=0).min() > 0  # drawn per trajectory
    if config.get("kind") == "rods":
        np.testing.assert_allclose(ds["com"], ds["lengths"] / 2, rtol=1e-15)
        np.testing.assert_allclose(ds["inertia"], ds["masses"] * ds["lengths"] ** 2 / 12, rtol=1e-15)
    if case == "conservative":  # the integrator's own accuracy, and T + U conserved
        drift = np.abs(ds["energy"] - ds["energy"][:, :1]) / (1 + np.abs(ds["energy"][:, :1]))
        assert drift.max() < 1e-8
    if "energy" in config:  # the initial state has the drawn energy, inside its range
        e0 = ds["energy"][:, 0]
        assert (e0 >= config["energy"]["low"] - 1e-9).all() and (e0 <= config["energy"]["high"] + 1e-9).all()
        assert np.ptp(e0) > 1.0


def test_a_drawn_energy_is_the_initial_energy_and_the_angles_stay_in_their_range(tmp_path):
    ds = mp.make_dataset(tmp_path / "e", trajectories=40, t_end=0.2, sample_dt=0.1, seed=5, links=2,
                         theta={"low": [-3.0, -1.0], "high": [3.0, 1.0]}, energy={"low": -5.0, "high": -5.0},
                         format="npz")
    np.testing.assert_allclose(ds["energy"][:, 0], -5.0, rtol=1e-12)
    th0 = ds["q"][:, 0]
    assert (np.abs(th0[:, 0]) <= 3.0).all() and (np.abs(th0[:, 1]) <= 1.0).all()
    # only states whose potential energy is below -5 J were kept (U = -g (2 cos th1 + cos th2) here)
    pot = -9.81 * (2 * np.cos(th0[:, 0]) + np.cos(th0[:, 1]))
    assert (pot <= -5.0 + 1e-9).all()


# ---------------------------------------------------------------------------------------------
# Reproducibility
# ---------------------------------------------------------------------------------------------
REPRO = dict(trajectories=37, t_end=0.6, sample_dt=0.05, seed=21, links=2, lengths={"low": 0.6, "high": 1.4},
             masses=[1.0, 1.5], damping={"low": 0.0, "high": 0.2}, energy={"low": -20.0, "high": 10.0},
             trajectories_per_chain=3, frames={"size": 16}, name="repro")


def _tree(path: Path):
    """Every file under path (relative name -> SHA-256 of its bytes)."""
    return {str(p.relative_to(path)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(path.rglob("*")) if p.is_file()}


def _in_subprocess(out: Path, threads: int, **kwargs):
    code = textwrap.dedent(f"""
        import multipendulum as mp
        mp.make_dataset({str(out)!r}, **{REPRO!r}, **{kwargs!r})
    """)
    env = dict(os.environ, RAYON_NUM_THREADS=str(threads))
    subprocess.run([sys.executable, "-c", code], env=env, check=True, capture_output=True, text=True)


def test_the_same_config_and_seed_give_byte_identical_npz_files_whatever_the_chunks_threads_and_scheduler(tmp_path):
    a = mp.make_dataset(tmp_path / "a", format="npz", chunk=5, scheduler="sync", **REPRO)
    mp.make_dataset(tmp_path / "b", format="npz", chunk=64, scheduler="threads", **REPRO)
    _in_subprocess(tmp_path / "c", 1, format="npz", chunk=7, scheduler="processes")
    _in_subprocess(tmp_path / "d", 2, format="npz")
    trees = [_tree(tmp_path / x) for x in "abcd"]
    assert sorted(trees[0]) == ["card.json", "card.md", "data.npz"]
    for other in trees[1:]:
        assert other == trees[0]
    # the card's hashes are those of the arrays as they load
    for name, meta in a.card["arrays"].items():
        assert hashlib.sha256(np.ascontiguousarray(a[name]).data).hexdigest() == meta["sha256"], name
    assert a.card["files"]["data.npz"]["sha256"] == trees[0]["data.npz"]
    # and a different seed gives a different dataset
    other = mp.make_dataset(tmp_path / "e", format="npz", **dict(REPRO, seed=22))
    assert other.card["arrays"]["q"]["sha256"] != a.card["arrays"]["q"]["sha256"]


def test_zarr_read_back_chunk_by_chunk_equals_npz_and_its_files_do_not_depend_on_threads(tmp_path):
    pytest.importorskip("zarr")
    npz = mp.make_dataset(tmp_path / "npz", format="npz", **REPRO)
    z = mp.make_dataset(tmp_path / "z1", format="zarr", chunk=8, scheduler="threads", **REPRO)
    _in_subprocess(tmp_path / "z2", 1, format="zarr", chunk=8, scheduler="sync")
    assert _tree(tmp_path / "z1") == _tree(tmp_path / "z2")
    z3 = mp.make_dataset(tmp_path / "z3", format="zarr", chunk=11, **REPRO)
    for name, meta in npz.card["arrays"].items():  # the arrays' bytes, whatever the format and chunks
        assert z.card["arrays"][name]["sha256"] == meta["sha256"] == z3.card["arrays"][name]["sha256"], name
    import zarr

    group = zarr.open_group(str(tmp_path / "z1" / "data.zarr"), mode="r")
    assert tuple(group["q"].chunks) == (8, 13, 2) and tuple(group["frames"].chunks) == (8, 13, 16, 16)
    pieces = list(z.chunks())
    assert [len(p["index"]) for p in pieces] == [8, 8, 8, 8, 5]
    for name in npz.fields:
        np.testing.assert_array_equal(np.concatenate([p[name] for p in pieces]), npz[name])
    np.testing.assert_array_equal(np.concatenate([p["index"] for p in pieces]), np.arange(37))
    for i in (0, 9, 36, -1):
        for name, v in npz[i].items():
            np.testing.assert_array_equal(z[i][name], v)
    # a split read chunk by chunk: its own trajectories only
    test = z.split("test")
    got = np.concatenate([p["q"] for p in test.chunks(["q"])])
    np.testing.assert_array_equal(got, npz["q"][test.indices])
    np.testing.assert_array_equal(test["q"], got)


def test_chunks_are_written_by_the_tasks_with_memory_bounded_by_the_chunk(tmp_path, monkeypatch):
    pytest.importorskip("zarr")
    seen = []
    real = dsmod._chunk

    def spy(plan, start, stop):
        seen.append(stop - start)
        return real(plan, start, stop)

    monkeypatch.setattr(dsmod, "_chunk", spy)
    mp.make_dataset(tmp_path / "z", format="zarr", chunk=10, scheduler="sync", trajectories=35, t_end=0.2,
                    sample_dt=0.1, links=2)
    assert sorted(seen) == [5, 10, 10, 10]


# ---------------------------------------------------------------------------------------------
# Splits and the loader
# ---------------------------------------------------------------------------------------------
def test_the_split_is_by_trajectory_disjoint_and_complete(tmp_path):
    ds = mp.make_dataset(tmp_path / "s", trajectories=101, t_end=0.1, sample_dt=0.05, links=1, seed=3,
                         split={"train": 0.7, "validation": 0.2, "test": 0.1})
    parts = {name: ds.split(name) for name in ("train", "validation", "test")}
    assert {k: len(v) for k, v in parts.items()} == {"train": 71, "validation": 20, "test": 10} == ds.splits
    idx = [set(p.indices.tolist()) for p in parts.values()]
    assert not (idx[0] & idx[1]) and not (idx[0] & idx[2]) and not (idx[1] & idx[2])
    assert set.union(*idx) == set(range(101))
    for code, (name, part) in enumerate(parts.items()):
        assert (ds["split"][part.indices] == code).all()
        assert all(int(r["split"]) == code for r in part)
        np.testing.assert_array_equal(part["q"], ds["q"][part.indices])
    assert not np.array_equal(parts["train"].indices, np.arange(71))  # drawn, not the first 71
    with pytest.raises(mp.InputError, match=re.escape("split must be one of train, validation, test, got 'dev'")):
        ds.split("dev")


def _collate(records):
    """What a DataLoader's default collation does with dicts of arrays: stack each key."""
    return {k: np.stack([r[k] for r in records]) for k in records[0]}


def test_the_loader_serves_a_dataloader_protocol_without_torch(tmp_path):
    for fmt in ("npz", "zarr"):
        if fmt == "zarr":
            pytest.importorskip("zarr")
        ds = mp.make_dataset(tmp_path / fmt, trajectories=12, t_end=0.2, sample_dt=0.1, links=2, format=fmt,
                             chunk=5, frames=8)
        train = ds.split("train")
        assert len(train) == 10 and len(ds) == 12
        order = np.random.default_rng(0).permutation(len(train))
        batches = [_collate([train[int(i)] for i in order[s:s + 4]]) for s in range(0, len(order), 4)]
        assert [len(b["q"]) for b in batches] == [4, 4, 2]
        assert batches[0]["q"].shape == (4, 3, 2) and batches[0]["frames"].shape == (4, 3, 8, 8)
        assert batches[0]["frames"].dtype == np.uint8
        np.testing.assert_array_equal(batches[0]["q"], ds["q"][train.indices[order[:4]]])
        assert [int(r["index"]) for r in train] == train.indices.tolist()  # iteration, in order
        assert train[-1]["index"] == train.indices[-1]
        with pytest.raises(IndexError):
            train[10]
        with pytest.raises(TypeError):
            train[1.5]  # type: ignore[index]
        again = pickle.loads(pickle.dumps(train))  # as a DataLoader worker receives it
        np.testing.assert_array_equal(again[3]["p"], train[3]["p"])


def test_the_loader_with_torch_if_installed(tmp_path):
    torch = pytest.importorskip("torch")
    from torch.utils.data import DataLoader

    ds = mp.make_dataset(tmp_path / "t", trajectories=10, t_end=0.2, sample_dt=0.1, links=2)
    batches = list(DataLoader(ds.split("train"), batch_size=3, shuffle=True))
    assert sum(len(b["q"]) for b in batches) == 8
    assert isinstance(batches[0]["q"], torch.Tensor) and batches[0]["q"].dtype == torch.float64


def test_the_package_does_not_import_torch():
    code = "import sys, multipendulum as mp; import multipendulum._dataset; print('torch' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"


# ---------------------------------------------------------------------------------------------
# The command line, the config file, the card
# ---------------------------------------------------------------------------------------------
CONFIG_TOML = """
name = "cli test"
trajectories = 9
t_end = 0.3
sample_dt = 0.1
seed = 4
links = 2
lengths = { low = 0.5, high = 1.0 }
theta = { low = -1.0, high = 1.0 }
omega = { low = [-0.5, -1.0], high = [0.5, 1.0] }
frames = 12

[torque]
kind = "sinusoid"
amplitude = [0.1, 0.2]
frequency = 2.0

[pivot]
y = { kind = "sinusoid", amplitude = 0.01, frequency = 10.0 }

[split]
train = 0.5
validation = 0.25
test = 0.25
"""


def test_the_command_line_writes_the_files_make_dataset_writes(tmp_path, capsys):
    cfg = tmp_path / "set.toml"
    cfg.write_text(CONFIG_TOML)
    assert main(["dataset", str(cfg), "-o", str(tmp_path / "cli")]) == 0
    said = capsys.readouterr().out
    assert "cli test: 9 trajectories x 4 samples, N = 2, npz; splits train 5, validation 2, test 2" in said
    assert f"wrote {tmp_path / 'cli' / 'card.json'}" in said
    mp.make_dataset(tmp_path / "py", **mp.read_dataset_config(cfg))
    assert _tree(tmp_path / "cli") == _tree(tmp_path / "py")
    # the card keeps the full config: it makes the same dataset again
    card = json.loads((tmp_path / "cli" / "card.json").read_text())
    assert card["config"]["torque"]["frequency"] == 2.0 and card["seed"] == 4
    assert card["versions"]["multipendulum"] == mp.__version__
    assert card["arrays"]["dH_dq"]["unit"] == "N m" and card["arrays"]["q"]["shape"] == [9, 4, 2]
    mp.make_dataset(tmp_path / "again", **card["config"])
    assert _tree(tmp_path / "again") == _tree(tmp_path / "py")
    md = (tmp_path / "cli" / "card.md").read_text()
    assert "# cli test" in md and card["arrays"]["q"]["sha256"] in md and "| `dH_dp` |" in md
    # options override the file, and say so in the card
    assert main(["dataset", str(cfg), "-o", str(tmp_path / "small"), "--trajectories", "3", "-q"]) == 0
    assert mp.load_dataset(tmp_path / "small").card["config"]["trajectories"] == 3
    assert capsys.readouterr().out == ""
    # and a bad file fails with its name and writes nothing
    cfg.write_text(CONFIG_TOML.replace("trajectories = 9", "trajectories = -9"))
    assert main(["dataset", str(cfg), "-o", str(tmp_path / "bad")]) == 1
    assert capsys.readouterr().err.strip() == f"multipendulum: error: {cfg}: trajectories must be a positive integer, got -9"
    assert not (tmp_path / "bad").exists()


def test_the_subcommand_has_help(capsys):
    assert main(["dataset", "--help"]) == 0
    assert "docs/datasets.md" in capsys.readouterr().out


def test_trajectories_share_a_chain_in_groups(tmp_path):
    ds = mp.make_dataset(tmp_path / "g", trajectories=10, t_end=0.2, sample_dt=0.1, links=2, seed=8,
                         lengths={"low": 0.5, "high": 1.5}, trajectories_per_chain=4, chunk=3)
    np.testing.assert_array_equal(ds["chain_index"], np.arange(10) // 4)
    lengths = ds["lengths"]
    for j in range(3):
        group = lengths[ds["chain_index"] == j]
        assert (group == group[0]).all()
    assert len({tuple(row) for row in lengths}) == 3
    assert len({tuple(row) for row in ds["q"][:, 0]}) == 10  # each trajectory its own start


@pytest.mark.parametrize("name", ["double", "pixels"])
def test_the_example_configs_are_valid_and_make_their_datasets(tmp_path, name):
    config = mp.read_dataset_config(ROOT / "examples" / "datasets" / f"{name}.toml")
    ds = mp.make_dataset(tmp_path / name, **dict(config, trajectories=4, t_end=0.2))
    assert len(ds) == 4 and ds.card["name"] == config["name"]
    if name == "pixels":
        assert ds["frames"].shape == (4, 5, 64, 64) and ds["frames"].max() == 255


def test_the_docs_examples_run_in_order(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    blocks = re.findall(r"```python\n(.*?)```", (ROOT / "docs" / "datasets.md").read_text(), flags=re.S)
    assert len(blocks) >= 3
    namespace: dict = {}
    for i, block in enumerate(blocks):
        exec(compile(block, f"docs/datasets.md python block {i}", "exec"), namespace)


def test_frames_draw_the_chain_where_it_is(tmp_path):
    # One link hanging straight down, at rest, on a 21 x 21 picture of [-1.05, 1.05]^2.
    ds = mp.make_dataset(tmp_path / "f", trajectories=1, t_end=0.1, sample_dt=0.1, links=1, theta=0.0,
                         frames={"size": 21, "line_width": 1.0})
    frame = ds["frames"][0, 0]
    assert ds.card["frames"]["extent"] == pytest.approx(1.05)
    column = frame[:, 10]
    assert (column[10:20] == 255).all() and (column[:10] == 0).all()  # from the pivot (centre) down
    assert frame.sum() == 255 * np.count_nonzero(frame) and np.count_nonzero(frame) == np.count_nonzero(column)


# ---------------------------------------------------------------------------------------------
# Interrupts and failures leave nothing behind
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("fmt", ["npz", "zarr"])
def test_ctrl_c_removes_what_was_written(tmp_path, fmt):
    if fmt == "zarr":
        pytest.importorskip("zarr")

    def stop(fraction):
        if fraction > 0:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        mp.make_dataset(tmp_path / "x", trajectories=30, t_end=0.2, sample_dt=0.1, links=2, chunk=5, format=fmt,
                        progress=stop)
    assert not (tmp_path / "x").exists()
    # a directory of an earlier dataset: replaced, or (interrupted) left without a half dataset
    mp.make_dataset(tmp_path / "y", trajectories=3, t_end=0.2, sample_dt=0.1, links=2)
    with pytest.raises(KeyboardInterrupt):
        mp.make_dataset(tmp_path / "y", trajectories=30, t_end=0.2, sample_dt=0.1, links=2, chunk=5, format=fmt,
                        progress=stop)
    assert list((tmp_path / "y").iterdir()) == []


def test_progress_reports_rising_fractions_to_one(tmp_path):
    seen = []
    mp.make_dataset(tmp_path / "p", trajectories=20, t_end=0.2, sample_dt=0.1, links=2, chunk=4, progress=seen.append)
    assert seen[-1] == 1.0 and seen == sorted(seen) and len(seen) >= 5


# ---------------------------------------------------------------------------------------------
# Bad input: refused before any work, with the exact message
# ---------------------------------------------------------------------------------------------
BASE = dict(trajectories=4, t_end=1.0, sample_dt=0.1, links=2)
BAD = [
    (dict(lengths={"low": 2.0, "high": 1.0}), "lengths is an empty range: lengths.low = 2 > lengths.high = 1"),
    (dict(theta={"low": [0.0, 1.0], "high": [1.0, 0.5]}), "theta is an empty range: theta.low[1] = 1 > theta.high[1] = 0.5"),
    (dict(energy={"low": 3.0, "high": -3.0}), "energy is an empty range: energy.low = 3 > energy.high = -3"),
    (dict(masses={"low": 1.0}), "masses must have both low and high (a range), missing masses.high"),
    (dict(masses={"low": 1.0, "high": 2.0, "mid": 1.5}), "unknown key 'mid' in the range masses; valid keys: low, high"),
    (dict(trajectories=-5), "trajectories must be a positive integer, got -5"),
    (dict(trajectories=0), "trajectories must be a positive integer, got 0"),
    (dict(trajectories=2.5), "trajectories must be a positive integer, got 2.5"),
    (dict(trajectories_per_chain=0), "trajectories_per_chain must be a positive integer, got 0"),
    (dict(chunk=-1), "chunk must be a positive integer, got -1"),
    (dict(frames={"size": 0}), "frames.size must be a positive integer, got 0"),
    (dict(frames={"size": 64, "colour": "red"}), "unknown key 'colour' in frames; valid keys: size, line_width, extent"),
    (dict(t_end=-1.0), "t_end must be > 0, got -1"),
    (dict(sample_dt=2.0), "sample_dt must be <= t_end (1 s), got 2 s"),
    (dict(seed=-1), "seed must be a non-negative integer, got -1"),
    (dict(split={"train": 0.8, "validation": 0.1, "test": 0.2}),
     "split fractions must sum to 1, got 0.8 + 0.1 + 0.2 = 1.1"),
    (dict(split={"train": 0.9, "dev": 0.1}), "unknown key 'dev' in split; valid keys: train, validation, test"),
    (dict(split={"train": 1.2, "validation": -0.2}), "split.validation must be >= 0, got -0.2"),
    (dict(method="euler"), "method must be one of " + ", ".join(mp.METHODS) + ", got 'euler'"),
    (dict(method="rk4"), "method rk4 takes a fixed step: give dt"),
    (dict(format="hdf5"), 'format must be "auto", "npz" or "zarr", got \'hdf5\''),
    (dict(kind="rods", com=0.5), 'com cannot be given with kind = "rods" (uniform rods: com = l/2, inertia = m l^2/12)'),
    (dict(lengths=[1.0, 1.0], masses=[1.0, 1.0, 1.0], links=None), "masses must have 2 entries (one per link), got 3"),
    (dict(links=None), "links (the number of links) is required when no quantity is given per link"),
    (dict(masses={"low": -1.0, "high": 1.0}), "the chain at the low end of every range: masses[0] must be >= 0 and finite, got -1"),
    (dict(omega=0.0, energy={"low": 0.0, "high": 1.0}),
     "omega is 0 for every link, so the rates have no direction to scale to the drawn energy; give omega a range "
     "(e.g. {low = -1, high = 1})"),
    (dict(energy={"low": -100.0, "high": -90.0}),
     "trajectory 0: none of 1000 drawn states has a potential energy below its drawn energy (energy = [-100, -90] J, "
     "theta in the range given); raise energy.high or narrow theta towards the hanging state"),
    (dict(torque=lambda t: [0.0, 0.0]),
     "torque must be built-in (numbers, mp.Sinusoid, mp.Table or their tables): a Python function cannot be kept in "
     "the dataset card, so the dataset could not be made again"),
    (dict(torque={"kind": "sinusoid", "amplitude": 1.0}), "torque.frequency is missing"),
    (dict(pivot={"z": 1.0}), "unknown key 'z' in pivot; valid keys: x, y"),
    (dict(scheduler="nope"), "scheduler must be None, 'threads', 'sync', 'processes', a dask.distributed address "
     "such as 'tcp://host:8786', or a distributed.Client; got 'nope'"),
    (dict(method="rk4", dt=1e-9, t_end=1.0), "rk4 with dt = 1e-09 s takes 1e+09 steps to reach t_end = 1 s, more "
     "than the 1e+08 a run may take; raise dt or shorten t_end"),
]


@pytest.mark.parametrize("changes,message", BAD, ids=[m[:40] for _, m in BAD])
def test_bad_input_is_refused_with_its_message_before_any_work(tmp_path, monkeypatch, changes, message):
    monkeypatch.setattr(dsmod, "_chunk", lambda *a: pytest.fail("work started"))
    kwargs = {k: v for k, v in dict(BASE, **changes).items() if v is not None}
    with pytest.raises(mp.InputError) as info:
        mp.make_dataset(tmp_path / "out", **kwargs)
    assert str(info.value) == message
    assert not (tmp_path / "out").exists()


def test_a_dataset_that_would_not_fit_is_refused_with_the_estimate(tmp_path, monkeypatch):
    monkeypatch.setattr(dsmod, "_chunk", lambda *a: pytest.fail("work started"))
    # one trajectory's samples beyond memory
    with pytest.raises(mp.InputError, match=r"^one trajectory of 1000000000001 samples needs [\d.]+ GiB .*; "
                                            r"raise sample_dt or shorten t_end$"):
        mp.make_dataset(tmp_path / "m", trajectories=2, t_end=1e9, sample_dt=1e-3, links=2)
    # gathered as NPZ beyond memory
    with pytest.raises(mp.InputError, match=r"^gathering a dataset of 3000000 trajectories x 10001 samples "
                                            r"\(1015\.8 KiB each\) as NPZ needs [\d.]+ GiB .*; use format = \"zarr\" "
                                            r"\(written chunk by chunk\)$"):
        mp.make_dataset(tmp_path / "m", trajectories=3_000_000, t_end=100.0, sample_dt=0.01, links=2, format="npz")
    # beyond the disk
    import shutil as _shutil

    monkeypatch.setattr(dsmod.shutil, "disk_usage", lambda p: _shutil._ntuple_diskusage(10**12, 10**12 - 5 * 2**30,
                                                                                         5 * 2**30))
    with pytest.raises(mp.InputError) as info:
        mp.make_dataset(tmp_path / "m", trajectories=1_000_000, t_end=10.0, sample_dt=0.01, links=2, format="zarr")
    assert str(info.value) == (
        f"the dataset needs about 97.0 GiB on disk (1000000 trajectories x 1001 samples (101.7 KiB each), "
        f"uncompressed) but {str(tmp_path)!r} has 5.0 GiB free; write fewer trajectories or samples (raise "
        "sample_dt), or to another disk")
    assert not (tmp_path / "m").exists()


def test_unknown_config_keys_and_foreign_directories_are_refused(tmp_path):
    cfg = tmp_path / "c.toml"
    cfg.write_text("trajectories = 3\nt_end = 1.0\nsample_dt = 0.1\nlinks = 2\nlenghts = 1.0\n")
    with pytest.raises(mp.InputError) as info:
        mp.read_dataset_config(cfg)
    assert str(info.value) == f"{cfg}: unknown key 'lenghts' in the dataset config; valid keys: " + ", ".join(
        dsmod.CONFIG_KEYS)
    with pytest.raises(TypeError):
        mp.make_dataset(tmp_path / "o", trajectories=3, t_end=1.0, sample_dt=0.1, links=2, lenghts=1.0)
    foreign = tmp_path / "mine"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("keep me")
    with pytest.raises(mp.InputError) as info:
        mp.make_dataset(foreign, **BASE)
    assert str(info.value) == (f"output directory {str(foreign)!r} is not empty and holds no dataset written by "
                               "multipendulum; remove it or choose another directory")
    assert (foreign / "notes.txt").read_text() == "keep me"
    with pytest.raises(mp.InputError, match="holds no dataset"):
        mp.load_dataset(foreign)
