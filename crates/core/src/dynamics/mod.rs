//! O(N) dynamics of the chain, in both of the seeds' formulations.
//!
//! The mass matrix is `A_ab = K_ab cos(theta_a - theta_b)` with `K_aa = diag_a` and
//! `K_ab = l_min(a,b) h_max(a,b)` off the diagonal. With `n_a = (cos theta_a, sin theta_a)` row `a`
//! of `A x` reads `diag_a x_a + h_a n_a . P_a + l_a n_a . Q_a`, where `P_a = sum_{b<a} l_b n_b x_b`
//! and `Q_a = sum_{b>a} h_b n_b x_b`: a diagonal plus two rank-2 semiseparable parts. `solve`
//! eliminates from the free end towards the pivot (the downstream links act on joint `a+1` like
//! an articulated 2x2 inertia `G` and a bias `w`), then substitutes forwards: O(N), no N x N storage.
//!
//! Lagrangian form: `A(theta) theta_ddot = tau - g h sin(theta) - sum_b K_ab sin(theta_a - theta_b) omega_b^2`.
//! Hamiltonian form: `theta_dot = A^-1 p`,
//! `p_dot_a = tau_a - g h_a sin(theta_a) - omega_a sum_b K_ab sin(theta_a - theta_b) omega_b`.
pub mod base;
pub mod general;
pub mod lanes;
pub mod reference;
pub mod rows;
pub mod sensitivity;
pub mod system;
pub mod torque;

use crate::model::Chain;
use crate::trig::sin_cos;

/// Chains from this many links take their `sin`/`cos` eight at a time (`Chain::trig`).
const TRIG_VECTOR_MIN: usize = 8;

/// Pivots below this fraction of the diagonal mean the mass matrix is numerically singular.
pub(crate) const PIVOT_TOL: f64 = 1e-14;

/// The mass matrix lost positive definiteness at link `.0` (a near-singular configuration).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Singular(pub usize);

impl Singular {
    pub fn reason(self) -> String {
        format!("the mass matrix is singular at link {} in this configuration", self.0)
    }
}

/// The x parts of the articulated inertia and bias at the base after [`Chain::eliminate`]
/// (a cart moves along x only).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Articulated {
    pub gxx: f64,
    pub wx: f64,
}

/// Work buffers for one chain size; reuse one per thread in hot loops.
#[derive(Debug, Clone)]
pub struct Workspace {
    sin: Vec<f64>,
    cos: Vec<f64>,
    u: Vec<[f64; 2]>,
    dinv: Vec<f64>,
    /// The last elimination's articulated inertia term `G_xx` (with `u` and `dinv`, the
    /// factorisation whole: a cart's solve against it needs it).
    gxx: f64,
    /// The power each joint's losses dissipate (the general model's).
    power: Vec<f64>,
}

impl Workspace {
    pub fn new(n: usize) -> Self {
        Workspace { sin: vec![0.0; n], cos: vec![0.0; n], u: vec![[0.0; 2]; n], dinv: vec![0.0; n], gxx: 0.0, power: vec![0.0; n] }
    }
}

impl Chain {
    #[inline(always)]
    fn trig(&self, theta: &[f64], ws: &mut Workspace) {
        let n = theta.len();
        // Long chains: eight angles at a time where the CPU has AVX2 + FMA (within 1 ulp of glibc).
        if n >= TRIG_VECTOR_MIN && crate::trig::lanes::sin_cos_slice(theta, &mut ws.sin[..n], &mut ws.cos[..n]) {
            return;
        }
        for ((t, s), c) in theta.iter().zip(&mut ws.sin[..n]).zip(&mut ws.cos[..n]) {
            (*s, *c) = sin_cos(*t);
        }
    }

    /// Backward elimination of `A x = r` (`x` holds `r` on entry, the reduced right-hand side
    /// `rho` on exit); the caller finishes with `substitute`. `extra(a)` is added to `r_a` just
    /// before it is used, so callers can fold in suffix sums over the links below `a`.
    ///
    /// Returns the whole chain as the base sees it: with `P_0` the base's acceleration (in the
    /// `n` coordinates), `sum_b h_b n_b x_b = w - G P_0` (the articulated inertia `G` and bias
    /// `w` at joint 0), which is what a cart needs.
    #[inline(always)]
    fn eliminate(&self, ws: &mut Workspace, x: &mut [f64], extra: impl FnMut(usize, f64, f64) -> f64) -> Result<Articulated, Singular> {
        self.eliminate_loaded(ws, x, |_, r| r, extra)
    }

    /// [`Chain::eliminate`] with `r_a` replaced by `load(a, r_a)` as link `a` comes up (from the
    /// free end): the joint losses, computed where the elimination's chain of divisions leaves
    /// the arithmetic units idle.
    #[inline(always)]
    fn eliminate_loaded(
        &self,
        ws: &mut Workspace,
        x: &mut [f64],
        mut load: impl FnMut(usize, f64) -> f64,
        mut extra: impl FnMut(usize, f64, f64) -> f64,
    ) -> Result<Articulated, Singular> {
        let n = x.len();
        let (l, h, d) = (&self.lengths[..n], &self.h[..n], &self.diag[..n]);
        let (s, c, u, dinv) = (&ws.sin[..n], &ws.cos[..n], &mut ws.u[..n], &mut ws.dinv[..n]);
        let (mut gxx, mut gxy, mut gyy, mut wx, mut wy) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for a in (0..n).rev() {
            let (nx, ny, la) = (c[a], s[a], l[a]);
            let (gnx, gny) = (gxx * nx + gxy * ny, gxy * nx + gyy * ny);
            let pivot = d[a] - la * la * (nx * gnx + ny * gny);
            if !(pivot > PIVOT_TOL * d[a]) {
                return Err(Singular(a));
            }
            let inv = 1.0 / pivot;
            let (ux, uy) = (h[a] * nx - la * gnx, h[a] * ny - la * gny);
            let rho = load(a, x[a]) + extra(a, nx, ny) - la * (nx * wx + ny * wy);
            gxx += ux * ux * inv;
            gxy += ux * uy * inv;
            gyy += uy * uy * inv;
            wx += ux * rho * inv;
            wy += uy * rho * inv;
            u[a] = [ux, uy];
            dinv[a] = inv;
            x[a] = rho;
        }
        ws.gxx = gxx;
        Ok(Articulated { gxx, wx })
    }

    /// Forward substitution after `eliminate`; `each(a, x_a, Px, Py)` sees each solved entry with
    /// the prefix sum `P_a = sum_{b<a} l_b n_b x_b` before `x_a` is added to it.
    #[inline(always)]
    fn substitute(&self, ws: &Workspace, x: &mut [f64], each: impl FnMut(usize, f64, f64, f64)) {
        self.substitute_from(ws, x, 0.0, each)
    }

    /// [`Chain::substitute`] with the base accelerating along x at `base` (`P_0 = (base, 0)`: a cart).
    #[inline(always)]
    fn substitute_from(&self, ws: &Workspace, x: &mut [f64], base: f64, mut each: impl FnMut(usize, f64, f64, f64)) {
        let n = x.len();
        let (l, s, c, u, dinv) = (&self.lengths[..n], &ws.sin[..n], &ws.cos[..n], &ws.u[..n], &ws.dinv[..n]);
        let (mut px, mut py) = (base, 0.0);
        for a in 0..n {
            let xa = (x[a] - (u[a][0] * px + u[a][1] * py)) * dinv[a];
            x[a] = xa;
            each(a, xa, px, py);
            px += l[a] * c[a] * xa;
            py += l[a] * s[a] * xa;
        }
    }

    /// `theta_ddot` for generalized torques `tau` (conjugate to the absolute angles). O(N).
    #[inline]
    pub fn accelerations_into(&self, theta: &[f64], omega: &[f64], tau: &[f64], out: &mut [f64], ws: &mut Workspace) -> Result<(), Singular> {
        match self.n() {
            2 => self.accelerations_double(theta, omega, tau, out, ws),
            _ => self.accelerations_impl(theta, omega, tau, out, ws),
        }
    }

    /// The double pendulum, the most common case, solved in closed form: the same `K`, `h` and
    /// diagonal as the recursion (tests hold the two equal), with `cos`/`sin(theta_1 - theta_2)`
    /// rebuilt from each angle's own pair so that only the two angles' sin/cos are taken. Leaves
    /// the angles' trig in `ws` as the recursion does (what rides along the state reuses it).
    ///
    /// Where the CPU has AVX2 and FMA, a copy compiled for them takes the angles' pair through
    /// the lanes' kernel inline ([`crate::trig::lanes::sin_cos_pair`]); the rest of its
    /// arithmetic is the same operations (Rust never fuses them unasked), so the same bits.
    #[inline(always)]
    fn accelerations_double(&self, theta: &[f64], omega: &[f64], tau: &[f64], out: &mut [f64], ws: &mut Workspace) -> Result<(), Singular> {
        #[cfg(target_arch = "x86_64")]
        if crate::trig::lanes::fma() {
            // SAFETY: the CPU has AVX2 and FMA.
            return unsafe { self.accelerations_double_fma(theta, omega, tau, out, ws) };
        }
        self.accelerations_double_with::<false>(theta, omega, tau, out, ws)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn accelerations_double_fma(&self, theta: &[f64], omega: &[f64], tau: &[f64], out: &mut [f64], ws: &mut Workspace) -> Result<(), Singular> {
        self.accelerations_double_with::<true>(theta, omega, tau, out, ws)
    }

    #[inline(always)]
    fn accelerations_double_with<const FMA: bool>(
        &self,
        theta: &[f64],
        omega: &[f64],
        tau: &[f64],
        out: &mut [f64],
        ws: &mut Workspace,
    ) -> Result<(), Singular> {
        let (d1, d2, h1, h2, g) = (self.diag[0], self.diag[1], self.h[0], self.h[1], self.g);
        let k = self.lengths[0] * h2;
        // Inline, so that the copy compiled for FMA runs the kernel's `mul_add` as instructions.
        let [(s1, c1), (s2, c2)] =
            if FMA { crate::trig::lanes::sin_cos_pair_within(theta[0], theta[1]) } else { crate::trig::lanes::sin_cos_pair(theta[0], theta[1]) };
        (ws.sin[0], ws.cos[0], ws.sin[1], ws.cos[1]) = (s1, c1, s2, c2);
        let (s12, c12) = (s1 * c2 - c1 * s2, c1 * c2 + s1 * s2);
        let r1 = tau[0] - g * h1 * s1 - k * s12 * omega[1] * omega[1];
        let r2 = tau[1] - g * h2 * s2 + k * s12 * omega[0] * omega[0];
        let kc = k * c12;
        let det = d1 * d2 - kc * kc;
        // The recursion's pivot at link 0 is det / d2; same test.
        if !(det > PIVOT_TOL * d1 * d2) {
            return Err(Singular(0));
        }
        let inv = 1.0 / det;
        out[0] = (d2 * r1 - kc * r2) * inv;
        out[1] = (d1 * r2 - kc * r1) * inv;
        Ok(())
    }

    #[inline(always)]
    pub(crate) fn accelerations_impl(&self, theta: &[f64], omega: &[f64], tau: &[f64], out: &mut [f64], ws: &mut Workspace) -> Result<(), Singular> {
        let n = theta.len();
        let (l, h, g) = (&self.lengths[..n], &self.h[..n], self.g);
        let (omega, tau, out) = (&omega[..n], &tau[..n], &mut out[..n]);
        self.trig(theta, ws);
        // Gravity and the centripetal pull of the links above: sum_{b<a} l_b w_b^2 sin(th_a - th_b).
        let (mut cu, mut su) = (0.0, 0.0);
        for a in 0..n {
            let (s, c) = (ws.sin[a], ws.cos[a]);
            out[a] = tau[a] - h[a] * (g * s + s * cu - c * su);
            let w2l = omega[a] * omega[a] * l[a];
            cu += w2l * c;
            su += w2l * s;
        }
        // The links below: l_a sum_{b>a} h_b w_b^2 sin(th_a - th_b), folded into the elimination.
        let (mut cd, mut sd) = (0.0, 0.0);
        self.eliminate(ws, out, |a, c, s| {
            let e = -l[a] * (s * cd - c * sd);
            let w2h = omega[a] * omega[a] * h[a];
            cd += w2h * c;
            sd += w2h * s;
            e
        })?;
        self.substitute(ws, out, |_, _, _, _| {});
        Ok(())
    }

    /// `sum_{b != a} K_ab sin(theta_a - theta_b) u_b` into `sin_out` and the same with `cos` into
    /// `cos_out`, O(N) by prefix sums over the links above and suffix sums over those below.
    /// Needs `ws` trig of the current angles.
    fn coupled_sums(&self, ws: &Workspace, u: &[f64], sin_out: &mut [f64], cos_out: &mut [f64]) {
        let n = u.len();
        let (l, h, s, c) = (&self.lengths[..n], &self.h[..n], &ws.sin[..n], &ws.cos[..n]);
        let (mut pc, mut ps) = (0.0, 0.0);
        for a in 0..n {
            sin_out[a] = h[a] * (s[a] * pc - c[a] * ps);
            cos_out[a] = h[a] * (c[a] * pc + s[a] * ps);
            pc += l[a] * u[a] * c[a];
            ps += l[a] * u[a] * s[a];
        }
        let (mut qc, mut qs) = (0.0, 0.0);
        for a in (0..n).rev() {
            sin_out[a] += l[a] * (s[a] * qc - c[a] * qs);
            cos_out[a] += l[a] * (c[a] * qc + s[a] * qs);
            qc += h[a] * u[a] * c[a];
            qs += h[a] * u[a] * s[a];
        }
    }

    /// The exact Jacobian of the Lagrangian right-hand side `(omega, theta_ddot)` with respect to
    /// `(theta, omega)` at a state with generalized torques `tau` (taken as depending on time
    /// only), row-major `2N x 2N` into `out`: one column per unit tangent vector, from the
    /// variational equations, O(N^2) in all.
    pub fn jacobian_into(&self, theta: &[f64], omega: &[f64], tau: &[f64], out: &mut [f64], ws: &mut Workspace) -> Result<(), Singular> {
        let n = self.n();
        let m = 2 * n;
        let mut acc = vec![0.0; n];
        self.accelerations_into(theta, omega, tau, &mut acc, ws)?;
        let (mut dir, mut col, mut scratch) = (vec![0.0; m], vec![0.0; n], vec![0.0; 6 * n]);
        for j in 0..m {
            dir.fill(0.0);
            dir[j] = 1.0;
            self.tangent_accelerations_into(theta, omega, &acc, &dir[..n], &dir[n..], &mut col, &mut scratch, ws)?;
            for i in 0..n {
                out[i * m + j] = dir[n + i]; // d theta_dot / d(.) = d omega / d(.)
                out[(n + i) * m + j] = col[i];
            }
        }
        Ok(())
    }

    /// The variational (tangent) equations of the Lagrangian form: the derivative of
    /// `theta_ddot(theta, omega)` along `(d_theta, d_omega)`, for torques that depend on time only.
    /// Differentiating `A theta_ddot = r` gives `A d_theta_ddot = dr - (dA) theta_ddot`; every term
    /// is a sum of `K_ab sin/cos(theta_a - theta_b)` against a vector, so it costs O(N) like the
    /// accelerations. `accel` is `theta_ddot` at the same state; `scratch` holds 5N values. The
    /// general model's tangent ([`Chain::tangent_general`]) on a still pivot, bit for bit.
    #[allow(clippy::too_many_arguments)]
    pub fn tangent_accelerations_into(
        &self,
        theta: &[f64],
        omega: &[f64],
        accel: &[f64],
        d_theta: &[f64],
        d_omega: &[f64],
        out: &mut [f64],
        scratch: &mut [f64],
        ws: &mut Workspace,
    ) -> Result<(), Singular> {
        let still = general::Load::still(self);
        self.tangent_general(theta, omega, (accel, 0.0), &still, (d_theta, d_omega, 0.0), out, scratch, ws).map(drop)
    }

    /// `omega = A(theta)^-1 p`. O(N).
    pub fn velocities_into(&self, theta: &[f64], p: &[f64], out: &mut [f64], ws: &mut Workspace) -> Result<(), Singular> {
        let n = self.n();
        self.trig(theta, ws);
        out[..n].copy_from_slice(&p[..n]);
        self.eliminate(ws, &mut out[..n], |_, _, _| 0.0)?;
        self.substitute(ws, &mut out[..n], |_, _, _, _| {});
        Ok(())
    }

    /// Hamilton's equations: `theta_dot = A^-1 p`, then `p_dot`. `tau(omega, out)` writes the
    /// generalized torque once the velocities are known, so state feedback sees them. O(N).
    pub fn hamilton_into<E>(
        &self,
        theta: &[f64],
        p: &[f64],
        theta_dot: &mut [f64],
        p_dot: &mut [f64],
        ws: &mut Workspace,
        tau: impl FnOnce(&[f64], &mut [f64]) -> Result<(), E>,
    ) -> Result<Result<(), E>, Singular> {
        let n = self.n();
        let (l, h, g) = (&self.lengths[..n], &self.h[..n], self.g);
        let (omega, p_dot) = (&mut theta_dot[..n], &mut p_dot[..n]);
        self.trig(theta, ws);
        omega.copy_from_slice(&p[..n]);
        self.eliminate(ws, omega, |_, _, _| 0.0)?;
        self.substitute(ws, omega, |_, _, _, _| {});
        if let Err(e) = tau(omega, p_dot) {
            return Ok(Err(e));
        }
        let (s, c) = (&ws.sin[..n], &ws.cos[..n]);
        // dT/dtheta_a = -omega_a sum_b K_ab sin(th_a - th_b) omega_b, split at a: links above, then below.
        let (mut cu, mut su) = (0.0, 0.0);
        for a in 0..n {
            p_dot[a] -= h[a] * (g * s[a] + omega[a] * (s[a] * cu - c[a] * su));
            cu += l[a] * omega[a] * c[a];
            su += l[a] * omega[a] * s[a];
        }
        let (mut cd, mut sd) = (0.0, 0.0);
        for a in (0..n).rev() {
            p_dot[a] -= l[a] * omega[a] * (s[a] * cd - c[a] * sd);
            cd += h[a] * omega[a] * c[a];
            sd += h[a] * omega[a] * s[a];
        }
        Ok(Ok(()))
    }

    /// `p = A(theta) omega`. O(N).
    pub fn momenta_into(&self, theta: &[f64], omega: &[f64], out: &mut [f64], ws: &mut Workspace) {
        let n = self.n();
        let (l, h, d) = (&self.lengths[..n], &self.h[..n], &self.diag[..n]);
        let (omega, out) = (&omega[..n], &mut out[..n]);
        self.trig(theta, ws);
        let (s, c) = (&ws.sin[..n], &ws.cos[..n]);
        let (mut px, mut py) = (0.0, 0.0);
        for a in 0..n {
            out[a] = d[a] * omega[a] + h[a] * (c[a] * px + s[a] * py);
            px += l[a] * c[a] * omega[a];
            py += l[a] * s[a] * omega[a];
        }
        let (mut qx, mut qy) = (0.0, 0.0);
        for a in (0..n).rev() {
            out[a] += l[a] * (c[a] * qx + s[a] * qy);
            qx += h[a] * c[a] * omega[a];
            qy += h[a] * s[a] * omega[a];
        }
    }

    /// Kinetic energy `T = omega . A omega / 2`. O(N); `scratch` holds N values.
    pub fn kinetic_energy(&self, theta: &[f64], omega: &[f64], scratch: &mut [f64], ws: &mut Workspace) -> f64 {
        self.momenta_into(theta, omega, scratch, ws);
        0.5 * omega.iter().zip(scratch.iter()).map(|(w, p)| w * p).sum::<f64>()
    }

    /// Potential energy `U = sum m_i g y_com_i = -g sum h_i cos(theta_i)`, zero at the pivot height.
    pub fn potential_energy(&self, theta: &[f64]) -> f64 {
        -self.g * self.h.iter().zip(theta).map(|(h, t)| h * t.cos()).sum::<f64>()
    }

    /// Joint positions: row `i` of `out` (length 2N, x then y) is the far end of link `i`.
    pub fn positions_into(&self, theta: &[f64], out: &mut [f64]) {
        let (mut x, mut y) = (0.0, 0.0);
        for (i, (l, t)) in self.lengths.iter().zip(theta).enumerate() {
            let (s, c) = sin_cos(*t);
            x += l * s;
            y -= l * c;
            out[2 * i] = x;
            out[2 * i + 1] = y;
        }
    }

    /// Centres of mass: row `i` of `out` (length 2N) is link `i`'s centre of mass.
    pub fn com_positions_into(&self, theta: &[f64], out: &mut [f64]) {
        let (mut x, mut y) = (0.0, 0.0);
        for (i, ((l, c), t)) in self.lengths.iter().zip(&self.com).zip(theta).enumerate() {
            let (st, ct) = sin_cos(*t);
            out[2 * i] = x + c * st;
            out[2 * i + 1] = y - c * ct;
            x += l * st;
            y -= l * ct;
        }
    }

    /// The dense mass matrix, row-major N x N (for inspection and the reference routes).
    pub fn mass_matrix_into(&self, theta: &[f64], out: &mut [f64]) {
        let n = self.n();
        for a in 0..n {
            for b in 0..n {
                out[a * n + b] = self.coupling(a, b) * (theta[a] - theta[b]).cos();
            }
        }
    }

    /// `K_ab`: the mass matrix without its `cos(theta_a - theta_b)` factor.
    pub(crate) fn coupling(&self, a: usize, b: usize) -> f64 {
        match a.cmp(&b) {
            std::cmp::Ordering::Equal => self.diag[a],
            std::cmp::Ordering::Less => self.lengths[a] * self.h[b],
            std::cmp::Ordering::Greater => self.lengths[b] * self.h[a],
        }
    }
}
