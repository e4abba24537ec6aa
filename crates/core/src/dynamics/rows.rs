//! The dynamics of many states at once, each a row of flat, row-major arrays (`B x N`): what
//! the bindings hand over from NumPy. Every function checks the rows, evaluates the torque of
//! each row (time `t`), and returns flat outputs in row order.
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

/// Row-major `N x N` mass matrices, one per row of `theta`.
pub fn mass_matrices(chain: &Chain, theta: &[f64]) -> Result<Vec<f64>> {
    let n = chain.n();
    let b = count("theta", theta.len(), n)?;
    let mut out = vec![0.0; b * n * n];
    for (row, o) in theta.chunks(n).zip(out.chunks_mut(n * n)) {
        chain.mass_matrix_into(row, o);
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

/// `(theta_dot, p_dot)` of Hamilton's equations for each row.
pub fn hamilton<T: TorqueSource>(chain: &Chain, theta: &[f64], p: &[f64], t: f64, torque: &mut T) -> Result<(Vec<f64>, Vec<f64>)> {
    let n = chain.n();
    let b = same_rows(("theta", theta), ("p", p), n)?;
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
