//! The ideal chain's accelerations for many states at once, in lanes (structure of arrays:
//! `theta[link][lane]`): plain loops over fixed-size arrays that LLVM vectorises across states.
//! The arithmetic is [`Chain::accelerations_into`]'s, operation for operation and unfused (so
//! the AVX-512, AVX2 and portable builds give the same bits): the closed form of two links, the
//! O(N) recursion (`eliminate`, `substitute`) otherwise. Only `sin`/`cos` differ: the lanes'
//! fdlibm kernels ([`crate::trig::lanes`], within 1 ulp of glibc's), so a state agrees with the
//! per-state route to round-off, not bit for bit.
use super::{Singular, PIVOT_TOL};
use crate::model::Chain;
use crate::trig::lanes::{sin_cos, Lane, LANES};

/// Per-link lanes the recursion keeps between its passes.
#[derive(Debug, Clone)]
pub struct LaneScratch {
    sin: Vec<Lane>,
    cos: Vec<Lane>,
    ux: Vec<Lane>,
    uy: Vec<Lane>,
    dinv: Vec<Lane>,
}

impl LaneScratch {
    pub fn new(n: usize) -> Self {
        let z = vec![[0.0; LANES]; n];
        LaneScratch {
            sin: z.clone(),
            cos: z.clone(),
            ux: z.clone(),
            uy: z.clone(),
            dinv: z,
        }
    }
}

/// Active lanes whose mass matrix failed the pivot test, and the first link that failed.
#[derive(Debug, Clone, Copy)]
pub struct LaneSingular {
    pub link: Singular,
    pub lanes: [bool; LANES],
}

/// `theta_ddot` of every lane for generalized torques `tau`, into `out` (each `N` lanes). A lane
/// not in `active` (a value > 0) is computed too but never fails.
#[inline(always)]
pub fn accelerations(
    chain: &Chain,
    theta: &[Lane],
    omega: &[Lane],
    tau: &[Lane],
    out: &mut [Lane],
    s: &mut LaneScratch,
    active: &Lane,
) -> Result<(), LaneSingular> {
    if chain.n() == 2 {
        return double(chain, theta, omega, tau, out, active);
    }
    recursion(chain, theta, omega, tau, out, s, active)
}

/// Fold the lanes that failed a test (active ones only) into `bad`; whether any did.
#[inline(always)]
fn failed(ok: &[bool; LANES], active: &Lane, bad: &mut [bool; LANES]) -> bool {
    let mut any = false;
    for i in 0..LANES {
        let b = (active[i] > 0.0) & !ok[i];
        bad[i] |= b;
        any |= b;
    }
    any
}

/// [`Chain::accelerations_double`] in lanes.
#[inline(always)]
fn double(
    chain: &Chain,
    theta: &[Lane],
    omega: &[Lane],
    tau: &[Lane],
    out: &mut [Lane],
    active: &Lane,
) -> Result<(), LaneSingular> {
    let (d1, d2, h1, h2, g) = (
        chain.diag[0],
        chain.diag[1],
        chain.h[0],
        chain.h[1],
        chain.g,
    );
    let k = chain.lengths[0] * h2;
    let tol = PIVOT_TOL * d1 * d2;
    let (s1, c1) = sin_cos(&theta[0]);
    let (s2, c2) = sin_cos(&theta[1]);
    let mut ok = [true; LANES];
    let (mut a0, mut a1) = ([0.0; LANES], [0.0; LANES]);
    for i in 0..LANES {
        let (s12, c12) = (s1[i] * c2[i] - c1[i] * s2[i], c1[i] * c2[i] + s1[i] * s2[i]);
        let r1 = tau[0][i] - g * h1 * s1[i] - k * s12 * omega[1][i] * omega[1][i];
        let r2 = tau[1][i] - g * h2 * s2[i] + k * s12 * omega[0][i] * omega[0][i];
        let kc = k * c12;
        let det = d1 * d2 - kc * kc;
        ok[i] = det > tol;
        let inv = 1.0 / det;
        a0[i] = (d2 * r1 - kc * r2) * inv;
        a1[i] = (d1 * r2 - kc * r1) * inv;
    }
    (out[0], out[1]) = (a0, a1);
    let mut bad = [false; LANES];
    if failed(&ok, active, &mut bad) {
        return Err(LaneSingular {
            link: Singular(0),
            lanes: bad,
        });
    }
    Ok(())
}

/// [`Chain::accelerations_impl`] (with `eliminate` and `substitute`) in lanes.
#[inline(always)]
fn recursion(
    chain: &Chain,
    theta: &[Lane],
    omega: &[Lane],
    tau: &[Lane],
    out: &mut [Lane],
    s: &mut LaneScratch,
    active: &Lane,
) -> Result<(), LaneSingular> {
    let n = theta.len();
    let (l, h, d, g) = (
        &chain.lengths[..n],
        &chain.h[..n],
        &chain.diag[..n],
        chain.g,
    );
    for a in 0..n {
        (s.sin[a], s.cos[a]) = sin_cos(&theta[a]);
    }
    // Gravity and the centripetal pull of the links above.
    let (mut cu, mut su) = ([0.0; LANES], [0.0; LANES]);
    for a in 0..n {
        let (sa, ca) = (&s.sin[a], &s.cos[a]);
        for i in 0..LANES {
            out[a][i] = tau[a][i] - h[a] * (g * sa[i] + sa[i] * cu[i] - ca[i] * su[i]);
            let w2l = omega[a][i] * omega[a][i] * l[a];
            cu[i] += w2l * ca[i];
            su[i] += w2l * sa[i];
        }
    }
    // Backward elimination, with the links below folded in.
    let (mut cd, mut sd) = ([0.0; LANES], [0.0; LANES]);
    let (mut gxx, mut gxy, mut gyy, mut wx, mut wy) = (
        [0.0; LANES],
        [0.0; LANES],
        [0.0; LANES],
        [0.0; LANES],
        [0.0; LANES],
    );
    let mut singular = None;
    let mut bad = [false; LANES];
    for a in (0..n).rev() {
        let la = l[a];
        let mut ok = [true; LANES];
        for i in 0..LANES {
            let (nx, ny) = (s.cos[a][i], s.sin[a][i]);
            let (gnx, gny) = (gxx[i] * nx + gxy[i] * ny, gxy[i] * nx + gyy[i] * ny);
            let pivot = d[a] - la * la * (nx * gnx + ny * gny);
            ok[i] = pivot > PIVOT_TOL * d[a];
            let inv = 1.0 / pivot;
            let (ux, uy) = (h[a] * nx - la * gnx, h[a] * ny - la * gny);
            let extra = -l[a] * (ny * cd[i] - nx * sd[i]);
            let w2h = omega[a][i] * omega[a][i] * h[a];
            cd[i] += w2h * nx;
            sd[i] += w2h * ny;
            let rho = out[a][i] + extra - la * (nx * wx[i] + ny * wy[i]);
            gxx[i] += ux * ux * inv;
            gxy[i] += ux * uy * inv;
            gyy[i] += uy * uy * inv;
            wx[i] += ux * rho * inv;
            wy[i] += uy * rho * inv;
            s.ux[a][i] = ux;
            s.uy[a][i] = uy;
            s.dinv[a][i] = inv;
            out[a][i] = rho;
        }
        if failed(&ok, active, &mut bad) && singular.is_none() {
            singular = Some(a);
        }
    }
    // Forward substitution.
    let (mut px, mut py) = ([0.0; LANES], [0.0; LANES]);
    for a in 0..n {
        for i in 0..LANES {
            let xa = (out[a][i] - (s.ux[a][i] * px[i] + s.uy[a][i] * py[i])) * s.dinv[a][i];
            out[a][i] = xa;
            px[i] += l[a] * s.cos[a][i] * xa;
            py[i] += l[a] * s.sin[a][i] * xa;
        }
    }
    match singular {
        Some(a) => Err(LaneSingular {
            link: Singular(a),
            lanes: bad,
        }),
        None => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dynamics::Workspace;

    #[test]
    fn lanes_are_the_per_state_accelerations_to_round_off() {
        for chain in [
            Chain::new(&[1.0, 0.7], &[1.0, 2.0], None, None, 9.81).unwrap(),
            Chain::rods(&[1.0, 0.5, 0.8], &[1.0, 0.3, 2.0], 9.81).unwrap(),
            Chain::new(
                &[0.4; 7],
                &[1.0, 0.5, 2.0, 1.0, 0.1, 3.0, 1.0],
                Some(&[0.2; 7]),
                Some(&[0.01; 7]),
                9.81,
            )
            .unwrap(),
        ] {
            let n = chain.n();
            let mut th = vec![[0.0; LANES]; n];
            let mut om = vec![[0.0; LANES]; n];
            let mut tau = vec![[0.0; LANES]; n];
            for a in 0..n {
                for i in 0..LANES {
                    th[a][i] = (a as f64 * 1.3 + i as f64 * 0.7).sin() * 3.0;
                    om[a][i] = (a as f64 * 0.4 - i as f64 * 1.1).cos() * 2.0;
                    tau[a][i] = 0.3 * (a as f64 - i as f64);
                }
            }
            let mut out = vec![[0.0; LANES]; n];
            accelerations(
                &chain,
                &th,
                &om,
                &tau,
                &mut out,
                &mut LaneScratch::new(n),
                &[1.0; LANES],
            )
            .unwrap();
            let mut ws = Workspace::new(n);
            for i in 0..LANES {
                let col = |v: &[Lane]| v.iter().map(|l| l[i]).collect::<Vec<f64>>();
                let mut want = vec![0.0; n];
                chain
                    .accelerations_into(&col(&th), &col(&om), &col(&tau), &mut want, &mut ws)
                    .unwrap();
                for a in 0..n {
                    assert!(
                        (out[a][i] - want[a]).abs() <= 1e-12 * (1.0 + want[a].abs()),
                        "N = {n}, lane {i}, link {a}"
                    );
                }
            }
        }
    }
}
