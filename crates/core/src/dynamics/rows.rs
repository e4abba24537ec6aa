//! The dynamics of many states at once, each a row of flat, row-major arrays (`B x N`): what
//! the bindings hand over from NumPy. Every function checks the rows, evaluates the torque of
//! each row (time `t`), and returns flat outputs in row order.
use super::base::{Force, Motion, Pivot};
use super::general::{Load, TANGENT_SCRATCH};
use super::reference::{self, Algorithm};
use super::torque::TorqueSource;
use super::{Singular, Workspace};
use crate::error::{Error, Result};
use crate::model::Chain;

/// The number of rows of `len` values of `n` each; refuses a partial or empty row.
pub fn count(name: &str, len: usize, n: usize) -> Result<usize> {
    if len % n != 0 || len == 0 {
        return Err(Error::input(format!("{name} must have shape (..., {n}), got {len} numbers")));
    }
    Ok(len / n)
}

fn same_rows(a: (&str, &[f64]), b: (&str, &[f64]), n: usize) -> Result<usize> {
    let rows = count(a.0, a.1.len(), n)?;
    if b.1.len() != a.1.len() {
        return Err(Error::input(format!("{} and {} must have the same shape, got {} and {} numbers", a.0, b.0, a.1.len(), b.1.len())));
    }
    Ok(rows)
}

fn singular(t: f64) -> impl Fn(Singular) -> Error {
    move |s| Error::integration(t, s.reason())
}

/// Row-major `N x N` mass matrices, one per row of `theta` (`(N+1) x (N+1)`, the cart first,
/// for a chain on a cart).
pub fn mass_matrices(chain: &Chain, theta: &[f64]) -> Result<Vec<f64>> {
    let n = chain.n();
    let b = count("theta", theta.len(), n)?;
    let m = n + usize::from(chain.cart().is_some());
    let mut out = vec![0.0; b * m * m];
    for (row, o) in theta.chunks(n).zip(out.chunks_mut(m * m)) {
        chain.mass_matrix_general(row, o);
    }
    Ok(out)
}

/// What acts on the rows' base: a pivot's motion (evaluated at the rows' time), the cart's
/// velocity (one value, or one per row) and the cart's applied force.
pub struct Base<'a> {
    pub pivot: Option<&'a Pivot>,
    pub cart_v: &'a [f64],
    pub force: Option<&'a mut Force>,
}

impl Base<'_> {
    pub fn none() -> Self {
        Base { pivot: None, cart_v: &[], force: None }
    }

    /// Whether the ideal chain's routes apply (nothing moves the base: no pivot, or one held
    /// at the origin).
    pub fn still(&self) -> bool {
        self.pivot.map_or(true, |p| p.is_origin()) && self.force.is_none() && self.cart_v.iter().all(|&v| v == 0.0)
    }

    fn check(&self, chain: &Chain, rows: usize) -> Result<()> {
        if chain.cart().is_none() && (self.force.is_some() || self.cart_v.iter().any(|&v| v != 0.0)) {
            return Err(Error::input("cart_v and cart_force need a chain with a cart (Chain(..., cart=Cart(mass)))"));
        }
        if chain.cart().is_some() && self.pivot.is_some() {
            return Err(Error::input("a chain on a cart has no prescribed pivot motion: the cart moves the base"));
        }
        crate::error::check_finite("cart_v", self.cart_v)?;
        if !(self.cart_v.len() <= 1 || self.cart_v.len() == rows) {
            return Err(Error::input(format!("cart_v must be one value or one per state ({rows}), got {}", self.cart_v.len())));
        }
        Ok(())
    }

    fn cart_v(&self, row: usize) -> f64 {
        match self.cart_v.len() {
            0 => 0.0,
            1 => self.cart_v[0],
            _ => self.cart_v[row],
        }
    }

    fn motion(&self, t: f64) -> Result<Motion> {
        self.pivot.map_or(Ok(Motion::default()), |p| p.eval(t))
    }
}

/// The generalized accelerations of the general model (losses, a moving pivot, a cart) of each
/// row: `N` per row, or `N + 1` with the cart's `x_ddot` first. The cart force function sees
/// the state `(0, theta, v, omega)`.
pub fn accelerations_general<T: TorqueSource>(chain: &Chain, theta: &[f64], omega: &[f64], t: f64, torque: &mut T, base: &mut Base) -> Result<Vec<f64>> {
    let n = chain.n();
    crate::error::check_finite("theta", theta)?;
    crate::error::check_finite("omega", omega)?;
    let b = same_rows(("theta", theta), ("omega", omega), n)?;
    base.check(chain, b)?;
    let motion = base.motion(t)?;
    let cart = chain.cart().is_some();
    let m = n + usize::from(cart);
    let mut ws = Workspace::new(n);
    let (mut tau, mut out, mut state) = (vec![0.0; n], vec![0.0; b * m], vec![0.0; 2 * n + 2]);
    for i in 0..b {
        let (th, om) = (&theta[i * n..(i + 1) * n], &omega[i * n..(i + 1) * n]);
        if torque.active() {
            torque.eval(t, th, om, &mut tau)?;
        }
        let v = base.cart_v(i);
        let mut load = if base.pivot.is_some() { Load::pivot(chain, motion.acc) } else { Load::still(chain) };
        if let Some(f) = base.force.as_deref_mut() {
            state[1..=n].copy_from_slice(th);
            state[n + 1] = v;
            state[n + 2..].copy_from_slice(om);
            load.cart_force = f.eval(t, &state)?;
        }
        let o = &mut out[i * m..(i + 1) * m];
        let (head, rest) = o.split_at_mut(m - n);
        let r = chain.accelerations_general(th, om, v, &tau, &load, rest, &mut ws).map_err(singular(t))?;
        if cart {
            head[0] = r.cart;
        }
    }
    Ok(out)
}

/// The exact Jacobian of the general model's first-order system at one state, in the public
/// ordering `(x, theta, v, omega)` (`2N x 2N` without a cart, `(2N+2) x (2N+2)` with one):
/// torques and the cart force taken as depending on time only, the losses exactly.
pub fn jacobian_general<T: TorqueSource>(chain: &Chain, theta: &[f64], omega: &[f64], t: f64, torque: &mut T, base: &mut Base) -> Result<Vec<f64>> {
    let n = chain.n();
    chain.check_state("theta", theta)?;
    chain.check_state("omega", omega)?;
    base.check(chain, 1)?;
    let motion = base.motion(t)?;
    let cart = usize::from(chain.cart().is_some());
    let mut tau = vec![0.0; n];
    if torque.active() {
        torque.eval(t, theta, omega, &mut tau)?;
    }
    let v = base.cart_v(0);
    let mut load = if base.pivot.is_some() { Load::pivot(chain, motion.acc) } else { Load::still(chain) };
    if let Some(f) = base.force.as_deref_mut() {
        let mut state = vec![0.0; 2 * n + 2];
        state[1..=n].copy_from_slice(theta);
        state[n + 1] = v;
        state[n + 2..].copy_from_slice(omega);
        load.cart_force = f.eval(t, &state)?;
    }
    let mut ws = Workspace::new(n);
    let mut acc = vec![0.0; n];
    let r = chain.accelerations_general(theta, omega, v, &tau, &load, &mut acc, &mut ws).map_err(singular(t))?;
    // Coordinates q = (x?, theta), rates (v?, omega): dimension 2 (n + cart).
    let q = n + cart;
    let m = 2 * q;
    let mut jac = vec![0.0; m * m];
    let (mut scratch, mut col) = (vec![0.0; TANGENT_SCRATCH * n], vec![0.0; n]);
    for j in 0..m {
        // Direction: a unit change of coordinate j (a cart position changes nothing).
        let (mut dth, mut dw, mut dv) = (vec![0.0; n], vec![0.0; n], 0.0);
        match (j < q, j % q) {
            (true, k) if k >= cart => dth[k - cart] = 1.0,
            (true, _) => continue,
            (false, k) if k >= cart => dw[k - cart] = 1.0,
            (false, _) => dv = 1.0,
        }
        let dx = chain.tangent_general(theta, omega, (&acc, r.cart), &load, (&dth, &dw, dv), &mut col, &mut scratch, &mut ws).map_err(singular(t))?;
        // d q_dot = d rates; d rates_dot = (d x_ddot, d theta_ddot).
        for i in 0..q {
            jac[i * m + j] = if i < cart { dv } else { dw[i - cart] };
        }
        if cart == 1 {
            jac[q * m + j] = dx;
        }
        for i in 0..n {
            jac[(q + cart + i) * m + j] = col[i];
        }
    }
    Ok(jac)
}

/// The lab-frame `(kinetic, potential)` energies of each row, with the base moving (a pivot at
/// time `t`, or the cart at `cart_v`).
pub fn energies_general(chain: &Chain, theta: &[f64], omega: &[f64], t: f64, base: &Base) -> Result<(Vec<f64>, Vec<f64>)> {
    let n = chain.n();
    let b = same_rows(("theta", theta), ("omega", omega), n)?;
    base.check(chain, b)?;
    let motion = base.motion(t)?;
    let mut ws = Workspace::new(n);
    let mut scratch = vec![0.0; n];
    let (mut kin, mut pot) = (Vec::with_capacity(b), Vec::with_capacity(b));
    for (i, (th, om)) in theta.chunks(n).zip(omega.chunks(n)).enumerate() {
        let base_v = if chain.cart().is_some() { [base.cart_v(i), 0.0] } else { motion.vel };
        kin.push(chain.kinetic_energy_moving(th, om, base_v, &mut scratch, &mut ws));
        pot.push(chain.potential_energy_moving(th, motion.pos[1]));
    }
    Ok((kin, pot))
}

/// The momenta of each row: `N` per row, or `N + 1` with the cart's `p_x` first.
pub fn momenta_general(chain: &Chain, theta: &[f64], omega: &[f64], base: &Base) -> Result<Vec<f64>> {
    let n = chain.n();
    let b = same_rows(("theta", theta), ("omega", omega), n)?;
    base.check(chain, b)?;
    let cart = usize::from(chain.cart().is_some());
    let m = n + cart;
    let mut ws = Workspace::new(n);
    let mut out = vec![0.0; b * m];
    for (i, ((th, om), o)) in theta.chunks(n).zip(omega.chunks(n)).zip(out.chunks_mut(m)).enumerate() {
        let px = chain.momenta_general(th, om, base.cart_v(i), &mut o[cart..], &mut ws);
        if cart == 1 {
            o[0] = px;
        }
    }
    Ok(out)
}

/// The velocities of each row from its momenta: `p` has `N` per row, or `N + 1` with `p_x`
/// first for a chain on a cart; the result likewise, `(v, omega)`.
pub fn velocities_general(chain: &Chain, theta: &[f64], p: &[f64]) -> Result<Vec<f64>> {
    let n = chain.n();
    let cart = usize::from(chain.cart().is_some());
    let m = n + cart;
    let b = count("theta", theta.len(), n)?;
    if p.len() != b * m {
        return Err(Error::input(format!("p must have shape (..., {m}){}, got {} numbers", if cart == 1 { " (p_x first)" } else { "" }, p.len())));
    }
    let mut ws = Workspace::new(n);
    let mut out = vec![0.0; b * m];
    for ((th, pp), o) in theta.chunks(n).zip(p.chunks(m)).zip(out.chunks_mut(m)) {
        let px = if cart == 1 { pp[0] } else { 0.0 };
        let v = chain.velocities_general(th, &pp[cart..], px, &mut o[cart..], &mut ws).map_err(singular(0.0))?;
        if cart == 1 {
            o[0] = v;
        }
    }
    Ok(out)
}

/// `theta_ddot` of each row by `algorithm` (the reference routes refuse chains too long).
pub fn accelerations<T: TorqueSource>(chain: &Chain, theta: &[f64], omega: &[f64], t: f64, torque: &mut T, algorithm: Algorithm) -> Result<Vec<f64>> {
    let n = chain.n();
    crate::error::check_finite("theta", theta)?;
    crate::error::check_finite("omega", omega)?;
    let b = same_rows(("theta", theta), ("omega", omega), n)?;
    algorithm.check(n)?;
    let mut ws = Workspace::new(n);
    let (mut tau, mut out) = (vec![0.0; n], vec![0.0; b * n]);
    for i in 0..b {
        let (th, om) = (&theta[i * n..(i + 1) * n], &omega[i * n..(i + 1) * n]);
        if torque.active() {
            torque.eval(t, th, om, &mut tau)?;
        }
        let o = &mut out[i * n..(i + 1) * n];
        match algorithm {
            Algorithm::Recursive => chain.accelerations_into(th, om, &tau, o, &mut ws).map_err(singular(t))?,
            Algorithm::Cholesky => o.copy_from_slice(&reference::accelerations_cholesky(chain, th, om, &tau).map_err(singular(t))?),
            Algorithm::Cramer => o.copy_from_slice(&reference::accelerations_cramer(chain, th, om, &tau).map_err(singular(t))?),
        }
    }
    Ok(out)
}

/// The exact Jacobian (row-major `2N x 2N`) of `(omega, theta_ddot)` at one state, the torque
/// taken as depending on time only ([`Chain::jacobian_into`]).
pub fn jacobian<T: TorqueSource>(chain: &Chain, theta: &[f64], omega: &[f64], t: f64, torque: &mut T) -> Result<Vec<f64>> {
    let n = chain.n();
    chain.check_state("theta", theta)?;
    chain.check_state("omega", omega)?;
    let mut tau = vec![0.0; n];
    if torque.active() {
        torque.eval(t, theta, omega, &mut tau)?;
    }
    let mut jac = vec![0.0; 4 * n * n];
    chain.jacobian_into(theta, omega, &tau, &mut jac, &mut Workspace::new(n)).map_err(singular(t))?;
    Ok(jac)
}

/// `(theta_dot, p_dot)` of Hamilton's equations for each row (with the joints' losses and a
/// moving pivot's motion at `t`; not for a chain on a cart).
pub fn hamilton<T: TorqueSource>(chain: &Chain, theta: &[f64], p: &[f64], t: f64, torque: &mut T, pivot: Option<&Pivot>) -> Result<(Vec<f64>, Vec<f64>)> {
    let n = chain.n();
    let b = same_rows(("theta", theta), ("p", p), n)?;
    if chain.cart().is_some() {
        return Err(Error::input("hamilton() takes a chain on a fixed or moving pivot, not on a cart (simulate with form=\"hamiltonian\" integrates it)"));
    }
    if !chain.is_ideal() || pivot.is_some() {
        let motion = pivot.map_or(Ok(Motion::default()), |p| p.eval(t))?;
        let load = if pivot.is_some() { Load::pivot(chain, motion.acc) } else { Load::still(chain) };
        let mut ws = Workspace::new(n);
        let (mut td, mut pd) = (vec![0.0; b * n], vec![0.0; b * n]);
        let active = torque.active();
        for i in 0..b {
            let r = i * n..(i + 1) * n;
            let th = &theta[r.clone()];
            chain
                .hamilton_general(th, &p[r.clone()], 0.0, &mut td[r.clone()], &mut pd[r], load.gravity, &mut ws, |om, _, out| {
                    if active {
                        torque.eval(t, th, om, out)?;
                    } else {
                        out.fill(0.0);
                    }
                    Ok::<f64, Error>(0.0)
                })
                .map_err(singular(t))??;
        }
        return Ok((td, pd));
    }
    let mut ws = Workspace::new(n);
    let (mut td, mut pd) = (vec![0.0; b * n], vec![0.0; b * n]);
    let active = torque.active();
    for i in 0..b {
        let r = i * n..(i + 1) * n;
        let th = &theta[r.clone()];
        chain
            .hamilton_into(th, &p[r.clone()], &mut td[r.clone()], &mut pd[r], &mut ws, |om, out| {
                if active {
                    torque.eval(t, th, om, out)
                } else {
                    out.fill(0.0);
                    Ok(())
                }
            })
            .map_err(singular(t))??;
    }
    Ok((td, pd))
}

/// The momenta `p = A(theta) omega` of each row.
pub fn momenta(chain: &Chain, theta: &[f64], omega: &[f64]) -> Result<Vec<f64>> {
    let n = chain.n();
    same_rows(("theta", theta), ("omega", omega), n)?;
    let mut ws = Workspace::new(n);
    let mut out = vec![0.0; theta.len()];
    for ((th, om), o) in theta.chunks(n).zip(omega.chunks(n)).zip(out.chunks_mut(n)) {
        chain.momenta_into(th, om, o, &mut ws);
    }
    Ok(out)
}

/// The angular velocities `omega = A(theta)^-1 p` of each row.
pub fn velocities(chain: &Chain, theta: &[f64], p: &[f64]) -> Result<Vec<f64>> {
    let n = chain.n();
    same_rows(("theta", theta), ("p", p), n)?;
    let mut ws = Workspace::new(n);
    let mut out = vec![0.0; theta.len()];
    for ((th, pp), o) in theta.chunks(n).zip(p.chunks(n)).zip(out.chunks_mut(n)) {
        chain.velocities_into(th, pp, o, &mut ws).map_err(singular(0.0))?;
    }
    Ok(out)
}

/// `(kinetic, potential)` energies of each row.
pub fn energies(chain: &Chain, theta: &[f64], omega: &[f64]) -> Result<(Vec<f64>, Vec<f64>)> {
    let n = chain.n();
    let b = same_rows(("theta", theta), ("omega", omega), n)?;
    let mut ws = Workspace::new(n);
    let mut scratch = vec![0.0; n];
    let (mut kin, mut pot) = (Vec::with_capacity(b), Vec::with_capacity(b));
    for (th, om) in theta.chunks(n).zip(omega.chunks(n)) {
        kin.push(chain.kinetic_energy(th, om, &mut scratch, &mut ws));
        pot.push(chain.potential_energy(th));
    }
    Ok((kin, pot))
}

/// Joint positions (`com = false`) or centres of mass (`com = true`), `2N` numbers per row.
pub fn positions(chain: &Chain, theta: &[f64], com: bool) -> Result<Vec<f64>> {
    let n = chain.n();
    count("theta", theta.len(), n)?;
    let mut out = vec![0.0; 2 * theta.len()];
    for (th, o) in theta.chunks(n).zip(out.chunks_mut(2 * n)) {
        if com {
            chain.com_positions_into(th, o);
        } else {
            chain.positions_into(th, o);
        }
    }
    Ok(out)
}
