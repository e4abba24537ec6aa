//! The model beyond the seeds, in the same O(N) recursion as the ideal chain ([`super`]):
//! - joint losses ([`crate::model::Joints`]): joint torques `u_i` map to the generalized forces
//!   `Q_i = u_i - u_{i+1}`;
//! - a moving pivot: its acceleration `a` acts on the angles like the gravity vector
//!   `(-a_x, -g - a_y)` ([`Load::gravity`]);
//! - a cart: the base slides along x, one more generalized coordinate `x` placed first. Its row
//!   and column of the mass matrix are `M_c + M` and `h_b cos(theta_b)`; the elimination already
//!   yields the whole chain's articulated inertia at the base, so the cart costs O(1) more.
//!
//! In the Hamiltonian form the momenta are `p_x = (M_c + M) v + sum_b h_b cos(theta_b) omega_b`
//! and `p_a = (A omega)_a + h_a cos(theta_a) v`. With a moving pivot `p = A omega` is the momentum
//! in the pivot's frame: its Lagrangian `T_rel - U_eff(theta, t)` differs from the lab frame's by
//! a total time derivative, so it gives the same motion, and its Hamiltonian keeps the Gauss
//! methods symplectic when there are no losses.
//!
//! The tangent (variational) equations of both forms are here too, for the Jacobian of the
//! implicit methods' Newton iteration, linearisation and Lyapunov exponents: torques and the cart
//! force are taken as functions of time, the losses are differentiated exactly.
use super::{Articulated, Singular, Workspace, PIVOT_TOL};
use crate::model::Chain;

/// What acts on the chain at one instant besides its torques.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Load {
    /// The effective gravity on the angles: `(0, -g)` on a fixed pivot, `(-a_x, -g - a_y)` on a
    /// pivot accelerating at `a`.
    pub gravity: [f64; 2],
    /// The horizontal force applied to the cart (its damping is the chain's).
    pub cart_force: f64,
}

impl Load {
    /// A fixed pivot, no cart force.
    pub fn still(chain: &Chain) -> Self {
        Load { gravity: [0.0, -chain.g()], cart_force: 0.0 }
    }

    /// A pivot accelerating at `acc`.
    pub fn pivot(chain: &Chain, acc: [f64; 2]) -> Self {
        Load { gravity: [-acc[0], -chain.g() - acc[1]], cart_force: 0.0 }
    }
}

/// Besides the angles' rates: the cart's (`x_ddot` in the Lagrangian form, `v` and `p_x_dot`
/// in the Hamiltonian one) and the power the joints dissipate.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Rates {
    pub cart: f64,
    pub cart_momentum_rate: f64,
    pub losses: f64,
}

/// `tanh(x)`, with the saturated range taken at once: beyond |x| = 19.07 `tanh` rounds to
/// +-1 in float64 (1 - tanh(19.07) < 2^-54), so the result is libm's, bit for bit, without its
/// cost. Friction at rates far above its regularisation rate lives there.
#[inline(always)]
pub(crate) fn saturating_tanh(x: f64) -> f64 {
    if x.abs() > 19.07 {
        1.0f64.copysign(x)
    } else {
        x.tanh()
    }
}

/// Scratch values the tangent equations need per link.
pub const TANGENT_SCRATCH: usize = 8;

impl Chain {
    /// The loss torque of joint `i` turning at `w`: `-b_i w - f_i tanh(w / v_s)`.
    #[inline(always)]
    fn joint_loss(&self, i: usize, w: f64) -> f64 {
        let j = &self.joints;
        let mut u = -j.damping[i] * w;
        if j.friction[i] != 0.0 {
            u -= j.friction[i] * saturating_tanh(w * j.inv_velocity);
        }
        u
    }

    /// Add the joints' loss forces at rates `omega` to `q` and return the power they dissipate,
    /// `sum_i -u_i w_i >= 0`. (From the free end: `Q_i = u_i - u_{i+1}` with `u_{i+1}` in hand.)
    #[inline]
    pub fn add_losses(&self, omega: &[f64], q: &mut [f64]) -> f64 {
        let n = omega.len();
        let (mut next, mut power) = (0.0, 0.0);
        for i in (0..n).rev() {
            let w = omega[i] - if i > 0 { omega[i - 1] } else { 0.0 };
            let u = self.joint_loss(i, w);
            q[i] += u - next;
            next = u;
            power -= u * w;
        }
        power
    }

    /// The derivative of [`Chain::add_losses`] along `d_omega`, added to `dq`.
    pub(super) fn add_loss_tangent(&self, omega: &[f64], d_omega: &[f64], dq: &mut [f64]) {
        let j = &self.joints;
        let (b, f, vs) = (&j.damping, &j.friction, j.friction_velocity);
        let (mut prev, mut d_prev) = (0.0, 0.0);
        for i in 0..omega.len() {
            let (w, dw) = (omega[i] - prev, d_omega[i] - d_prev);
            prev = omega[i];
            d_prev = d_omega[i];
            let mut slope = b[i];
            if f[i] != 0.0 {
                let th = saturating_tanh(w / vs);
                slope += f[i] / vs * (1.0 - th * th);
            }
            let du = -slope * dw;
            dq[i] += du;
            if i > 0 {
                dq[i - 1] -= du;
            }
        }
    }

    /// The cart's pivot of the elimination: `M_c + M - G_xx`, the inertia the cart feels.
    #[inline]
    pub(super) fn cart_inertia(&self, art: Articulated) -> Result<f64, Singular> {
        let total = self.cart.map_or(0.0, |c| c.mass) + self.total_mass();
        let den = total - art.gxx;
        if !(den > PIVOT_TOL * total) {
            return Err(Singular(0));
        }
        Ok(den)
    }

    /// `theta_ddot` into `out` (and the cart's `x_ddot`) of the general model, with the cart
    /// moving at `cart_v`. O(N).
    #[allow(clippy::too_many_arguments)]
    #[inline]
    pub fn accelerations_general(
        &self,
        theta: &[f64],
        omega: &[f64],
        cart_v: f64,
        tau: &[f64],
        load: &Load,
        out: &mut [f64],
        ws: &mut Workspace,
    ) -> Result<Rates, Singular> {
        let n = theta.len();
        if n == 2 {
            // Compiled a second time for AVX2 + FMA where the CPU has them, as the ideal double
            // pendulum's ([`Chain::accelerations_double`]).
            #[cfg(target_arch = "x86_64")]
            if crate::trig::lanes::fma() {
                // SAFETY: the CPU has AVX2 and FMA.
                return unsafe { self.accelerations_general_double_fma(theta, omega, cart_v, tau, load, out, ws) };
            }
            return self.accelerations_general_double::<false>(theta, omega, cart_v, tau, load, out, ws);
        }
        let (l, h) = (&self.lengths[..n], &self.h[..n]);
        let (omega, tau, out) = (&omega[..n], &tau[..n], &mut out[..n]);
        self.trig(theta, ws);
        let [gx, gy] = load.gravity;
        // Gravity and the centripetal pull of the links above; the cart's row gathers
        // sum_b h_b sin(theta_b) omega_b^2.
        let (mut cu, mut su) = (0.0, 0.0);
        for a in 0..n {
            let (s, c) = (ws.sin[a], ws.cos[a]);
            out[a] = tau[a] + h[a] * (gx * c + gy * s - (s * cu - c * su));
            let w2l = omega[a] * omega[a] * l[a];
            cu += w2l * c;
            su += w2l * s;
        }
        let pull = if self.cart.is_some() { (0..n).map(|a| h[a] * ws.sin[a] * omega[a] * omega[a]).sum() } else { 0.0 };
        let (mut cd, mut sd) = (0.0, 0.0);
        let below = |a: usize, c: f64, s: f64| {
            let e = -l[a] * (s * cd - c * sd);
            let w2h = omega[a] * omega[a] * h[a];
            cd += w2h * c;
            sd += w2h * s;
            e
        };
        let lossy = self.lossy_joints();
        // Q_a = u_a - u_{a+1} from the free end, the joint below's torque carried; each joint's
        // power kept for the sum from the base that the forward pass takes. (One loop for both
        // cases: a copy without the losses compiled to a slower elimination.)
        let mut power = std::mem::take(&mut ws.power);
        let solve = || {
            let mut next = 0.0;
            let art = self.eliminate_loaded(
                ws,
                out,
                |a, r| {
                    if !lossy {
                        return r;
                    }
                    let w = if a > 0 { omega[a] - omega[a - 1] } else { omega[0] };
                    let u = self.joint_loss(a, w);
                    power[a] = u * w;
                    let q = u - next;
                    next = u;
                    r + q
                },
                below,
            )?;
            let x_ddot = match self.cart {
                Some(cart) => (load.cart_force - cart.damping * cart_v + pull - art.wx) / self.cart_inertia(art)?,
                None => 0.0,
            };
            let mut losses = 0.0;
            self.substitute_from(ws, out, x_ddot, |a, _, _, _| {
                if lossy {
                    losses -= power[a];
                }
            });
            Ok(Rates { cart: x_ddot, cart_momentum_rate: 0.0, losses })
        };
        let rates = solve();
        ws.power = power;
        rates
    }

    /// [`Chain::accelerations_general_double`] compiled for AVX2 + FMA.
    #[cfg(target_arch = "x86_64")]
    #[allow(clippy::too_many_arguments)]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn accelerations_general_double_fma(
        &self,
        theta: &[f64],
        omega: &[f64],
        cart_v: f64,
        tau: &[f64],
        load: &Load,
        out: &mut [f64],
        ws: &mut Workspace,
    ) -> Result<Rates, Singular> {
        self.accelerations_general_double::<true>(theta, omega, cart_v, tau, load, out, ws)
    }

    /// [`Chain::accelerations_general`] of two links in closed form (the most common chain; the
    /// recursion's fixed cost dominates at N = 2): the 2x2 solve, and with a cart its Schur
    /// complement. Leaves the angles' trig in `ws` as the recursion does.
    /// `FMA`: the copy for AVX2 + FMA, the angles' sin/cos pair inline.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn accelerations_general_double<const FMA: bool>(
        &self,
        theta: &[f64],
        omega: &[f64],
        cart_v: f64,
        tau: &[f64],
        load: &Load,
        out: &mut [f64],
        ws: &mut Workspace,
    ) -> Result<Rates, Singular> {
        let (d1, d2, h1, h2) = (self.diag[0], self.diag[1], self.h[0], self.h[1]);
        let k = self.lengths[0] * h2;
        // Inline, so that the copy compiled for FMA runs the kernel's `mul_add` as instructions.
        let [(s1, c1), (s2, c2)] =
            if FMA { crate::trig::lanes::sin_cos_pair_within(theta[0], theta[1]) } else { crate::trig::lanes::sin_cos_pair(theta[0], theta[1]) };
        (ws.sin[0], ws.cos[0], ws.sin[1], ws.cos[1]) = (s1, c1, s2, c2);
        let (s12, c12) = (s1 * c2 - c1 * s2, c1 * c2 + s1 * s2);
        let [gx, gy] = load.gravity;
        let (w1, w2) = (omega[0], omega[1]);
        let mut r = [tau[0] + h1 * (gx * c1 + gy * s1) - k * s12 * w2 * w2, tau[1] + h2 * (gx * c2 + gy * s2) + k * s12 * w1 * w1];
        let losses = if self.lossy_joints() { self.add_losses(&omega[..2], &mut r) } else { 0.0 };
        let kc = k * c12;
        let det = d1 * d2 - kc * kc;
        if !(det > PIVOT_TOL * d1 * d2) {
            return Err(Singular(0));
        }
        let inv = 1.0 / det;
        // det A^-1 applied to (a, b): the adjugate's product, divided by det at the end.
        let adj = |a: f64, b: f64| (d2 * a - kc * b, d1 * b - kc * a);
        let (ra1, ra2) = adj(r[0], r[1]);
        let (mut a1, mut a2) = (ra1 * inv, ra2 * inv);
        let mut x_ddot = 0.0;
        if let Some(cart) = self.cart {
            // theta_ddot = A^-1 (r - b x_ddot), b = h cos(theta); the cart's row closes it with
            // the Schur complement S = total - b.A^-1 b. Scaled by det, neither S nor x_ddot's
            // numerator waits for 1 / det: two divisions side by side, not one after the other.
            let (b1, b2) = (h1 * c1, h2 * c2);
            let (zb1, zb2) = adj(b1, b2);
            let total = cart.mass + self.total_mass();
            let schur_det = total * det - (b1 * zb1 + b2 * zb2);
            if !(schur_det > PIVOT_TOL * total * det) {
                return Err(Singular(0));
            }
            let rx = load.cart_force - cart.damping * cart_v + h1 * s1 * w1 * w1 + h2 * s2 * w2 * w2;
            x_ddot = (rx * det - (b1 * ra1 + b2 * ra2)) / schur_det;
            a1 = (ra1 - zb1 * x_ddot) * inv;
            a2 = (ra2 - zb2 * x_ddot) * inv;
        }
        out[0] = a1;
        out[1] = a2;
        Ok(Rates { cart: x_ddot, cart_momentum_rate: 0.0, losses })
    }

    /// `omega = A^-1 p` and the cart's `v` from the momenta `(p_x, p)`. O(N).
    pub fn velocities_general(&self, theta: &[f64], p: &[f64], p_x: f64, omega: &mut [f64], ws: &mut Workspace) -> Result<f64, Singular> {
        let n = self.n();
        self.trig(theta, ws);
        omega[..n].copy_from_slice(&p[..n]);
        let art = self.eliminate(ws, &mut omega[..n], |_, _, _| 0.0)?;
        let v = if self.cart.is_some() { (p_x - art.wx) / self.cart_inertia(art)? } else { 0.0 };
        self.substitute_from(ws, &mut omega[..n], v, |_, _, _, _| {});
        Ok(v)
    }

    /// The momenta `p` (into `out`) and the cart's `p_x` of rates `(v, omega)`. O(N).
    pub fn momenta_general(&self, theta: &[f64], omega: &[f64], v: f64, out: &mut [f64], ws: &mut Workspace) -> f64 {
        self.momenta_into(theta, omega, out, ws);
        let Some(cart) = self.cart else { return 0.0 };
        let n = self.n();
        let mut px = (cart.mass + self.total_mass()) * v;
        for a in 0..n {
            let hc = self.h[a] * ws.cos[a];
            out[a] += hc * v;
            px += hc * omega[a];
        }
        px
    }

    /// `sum_b h_b omega_b (cos theta_b, sin theta_b)`: the links' momentum relative to the base
    /// (`M` times the velocity of their centre of mass). Needs `ws` trig of the angles.
    fn relative_momentum(&self, omega: &[f64], ws: &Workspace) -> [f64; 2] {
        let (mut x, mut y) = (0.0, 0.0);
        for a in 0..self.n() {
            let hw = self.h[a] * omega[a];
            x += hw * ws.cos[a];
            y += hw * ws.sin[a];
        }
        [x, y]
    }

    /// [`Chain::relative_momentum`] with the trig of the angles already in `ws`.
    pub(crate) fn momentum_relative_cached(&self, omega: &[f64], ws: &Workspace) -> [f64; 2] {
        self.relative_momentum(omega, ws)
    }

    /// The links' momentum relative to the base at `(theta, omega)`.
    pub fn momentum_relative(&self, theta: &[f64], omega: &[f64], ws: &mut Workspace) -> [f64; 2] {
        self.trig(theta, ws);
        self.relative_momentum(omega, ws)
    }

    /// The lab-frame kinetic energy with the base moving at `base_v` (a pivot's velocity, or
    /// `(v, 0)` for a cart, whose own kinetic energy counts too). `scratch` holds N values.
    pub fn kinetic_energy_moving(&self, theta: &[f64], omega: &[f64], base_v: [f64; 2], scratch: &mut [f64], ws: &mut Workspace) -> f64 {
        let relative = self.kinetic_energy(theta, omega, scratch, ws);
        if base_v == [0.0, 0.0] {
            return relative;
        }
        let r = self.relative_momentum(omega, ws);
        let mass = self.total_mass() + self.cart.map_or(0.0, |c| c.mass);
        relative + base_v[0] * r[0] + base_v[1] * r[1] + 0.5 * mass * (base_v[0] * base_v[0] + base_v[1] * base_v[1])
    }

    /// The lab-frame potential energy with the base at height `base_y`.
    pub fn potential_energy_moving(&self, theta: &[f64], base_y: f64) -> f64 {
        let u = self.potential_energy(theta);
        if base_y == 0.0 {
            u
        } else {
            u + self.g * self.total_mass() * base_y
        }
    }

    /// Hamilton's equations of the general model: `theta_dot = omega`, `p_dot`, the cart's
    /// `v` and `p_x_dot`. `inputs(omega, v, tau_out)` writes the generalized torques into its
    /// buffer and returns the cart force, once the velocities are known. O(N).
    #[allow(clippy::too_many_arguments)]
    pub fn hamilton_general<E>(
        &self,
        theta: &[f64],
        p: &[f64],
        p_x: f64,
        theta_dot: &mut [f64],
        p_dot: &mut [f64],
        gravity: [f64; 2],
        ws: &mut Workspace,
        inputs: impl FnOnce(&[f64], f64, &mut [f64]) -> Result<f64, E>,
    ) -> Result<Result<Rates, E>, Singular> {
        let n = self.n();
        let (l, h) = (&self.lengths[..n], &self.h[..n]);
        let (omega, p_dot) = (&mut theta_dot[..n], &mut p_dot[..n]);
        let v = self.velocities_general(theta, p, p_x, omega, ws)?;
        let force = match inputs(omega, v, p_dot) {
            Ok(f) => f,
            Err(e) => return Ok(Err(e)),
        };
        let losses = if self.lossy_joints() { self.add_losses(omega, p_dot) } else { 0.0 };
        let (s, c) = (&ws.sin[..n], &ws.cos[..n]);
        let [gx, gy] = gravity;
        // dT/dtheta_a: the links above (and the cart's velocity, the base's), then those below.
        let (mut cu, mut su) = (v, 0.0);
        for a in 0..n {
            p_dot[a] += h[a] * (gx * c[a] + gy * s[a] - omega[a] * (s[a] * cu - c[a] * su));
            cu += l[a] * omega[a] * c[a];
            su += l[a] * omega[a] * s[a];
        }
        let (mut cd, mut sd) = (0.0, 0.0);
        for a in (0..n).rev() {
            p_dot[a] -= l[a] * omega[a] * (s[a] * cd - c[a] * sd);
            cd += h[a] * omega[a] * c[a];
            sd += h[a] * omega[a] * s[a];
        }
        let px_dot = self.cart.map_or(0.0, |cart| force - cart.damping * v);
        Ok(Ok(Rates { cart: v, cart_momentum_rate: px_dot, losses }))
    }

    /// The tangent of [`Chain::accelerations_general`] along `(d_theta, d_omega, d_v)`:
    /// `d theta_ddot` into `out`, and `d x_ddot` returned. `accel` and `x_ddot` are the
    /// accelerations at the same state; `scratch` holds 5 N values (the Hamiltonian tangent
    /// needs [`TANGENT_SCRATCH`]). O(N). The ideal chain's tangent is this one on a still pivot.
    #[allow(clippy::too_many_arguments)]
    pub fn tangent_general(
        &self,
        theta: &[f64],
        omega: &[f64],
        (accel, x_ddot): (&[f64], f64),
        load: &Load,
        (d_theta, d_omega, d_v): (&[f64], &[f64], f64),
        out: &mut [f64],
        scratch: &mut [f64],
        ws: &mut Workspace,
    ) -> Result<f64, Singular> {
        let n = self.n();
        self.trig(&theta[..n], ws);
        let (u, rest) = scratch.split_at_mut(n);
        let (ss, rest) = rest.split_at_mut(n);
        let (cs, rest) = rest.split_at_mut(n);
        let (s2, rest) = rest.split_at_mut(n);
        let (c2, _) = rest.split_at_mut(n);
        let out = &mut out[..n];
        let (h, [gx, gy]) = (&self.h[..n], load.gravity);
        for a in 0..n {
            u[a] = omega[a] * omega[a];
        }
        self.coupled_sums(ws, u, ss, cs);
        for a in 0..n {
            // (On a still pivot, gx = 0: the ideal chain's -g h cos(th) dth to the bit.)
            out[a] = (gy * h[a] * ws.cos[a] - gx * h[a] * ws.sin[a]) * d_theta[a] - d_theta[a] * cs[a];
            u[a] = d_theta[a] * omega[a] * omega[a];
        }
        self.coupled_sums(ws, u, ss, cs);
        for a in 0..n {
            out[a] += cs[a];
            u[a] = omega[a] * d_omega[a];
        }
        self.coupled_sums(ws, u, s2, c2);
        self.coupled_sums(ws, &accel[..n], ss, cs);
        for a in 0..n {
            out[a] += -2.0 * s2[a] + d_theta[a] * ss[a];
            u[a] = d_theta[a] * accel[a];
        }
        if self.cart.is_some() {
            for a in 0..n {
                out[a] += h[a] * ws.sin[a] * d_theta[a] * x_ddot;
            }
        }
        self.coupled_sums(ws, u, ss, cs);
        for a in 0..n {
            out[a] -= ss[a];
        }
        if self.lossy_joints() {
            self.add_loss_tangent(&omega[..n], &d_omega[..n], out);
        }
        let mut row = 0.0;
        if let Some(cart) = self.cart {
            row = -cart.damping * d_v;
            for b in 0..n {
                let (s, c) = (ws.sin[b], ws.cos[b]);
                row += h[b] * (c * d_theta[b] * omega[b] * omega[b] + 2.0 * s * omega[b] * d_omega[b] + s * d_theta[b] * accel[b]);
            }
        }
        let art = self.eliminate(ws, out, |_, _, _| 0.0)?;
        let d_x_ddot = if self.cart.is_some() { (row - art.wx) / self.cart_inertia(art)? } else { 0.0 };
        self.substitute_from(ws, out, d_x_ddot, |_, _, _, _| {});
        Ok(d_x_ddot)
    }

    /// The tangent of [`Chain::hamilton_general`] along `(d_theta, d_p, d_p_x)` at rates
    /// `(omega, v)`: `d omega` and `d p_dot` into the outputs, `(d v, d p_x_dot)` returned.
    /// `scratch` holds [`TANGENT_SCRATCH`] N values. O(N).
    #[allow(clippy::too_many_arguments)]
    pub fn hamilton_tangent(
        &self,
        theta: &[f64],
        rates: (&[f64], f64),
        gravity: [f64; 2],
        direction: (&[f64], &[f64], f64),
        d_omega: &mut [f64],
        d_pdot: &mut [f64],
        scratch: &mut [f64],
        ws: &mut Workspace,
    ) -> Result<(f64, f64), Singular> {
        self.hamilton_tangent_forced(theta, rates, gravity, direction, None, d_omega, d_pdot, scratch, ws)
    }

    /// [`Chain::hamilton_tangent`] with a parameter's explicit terms `forcing = (dp, dp_x,
    /// dpdot)`: `dp`, `dp_x` (the momenta's derivative at fixed rates) are subtracted from the
    /// momenta's direction before the solve for `d omega`, and `dpdot` (`p_dot`'s derivative at
    /// fixed angles and rates) is added to `d p_dot` ([`super::sensitivity`]).
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn hamilton_tangent_forced(
        &self,
        theta: &[f64],
        (omega, v): (&[f64], f64),
        gravity: [f64; 2],
        (d_theta, d_p, d_px): (&[f64], &[f64], f64),
        forcing: Option<(&[f64], f64, &[f64])>,
        d_omega: &mut [f64],
        d_pdot: &mut [f64],
        scratch: &mut [f64],
        ws: &mut Workspace,
    ) -> Result<(f64, f64), Singular> {
        let n = self.n();
        self.trig(&theta[..n], ws);
        let (u, rest) = scratch.split_at_mut(n);
        let (s_w, rest) = rest.split_at_mut(n);
        let (c_w, rest) = rest.split_at_mut(n);
        let (s_tw, rest) = rest.split_at_mut(n);
        let (c_tw, rest) = rest.split_at_mut(n);
        let (s_dw, rest) = rest.split_at_mut(n);
        let (c_dw, _) = rest.split_at_mut(n);
        let (h, [gx, gy]) = (&self.h[..n], gravity);
        let (d_omega, d_pdot) = (&mut d_omega[..n], &mut d_pdot[..n]);
        // M d(v, omega) = d(p_x, p) - (dM)(v, omega).
        self.coupled_sums(ws, &omega[..n], s_w, c_w);
        for a in 0..n {
            u[a] = d_theta[a] * omega[a];
        }
        self.coupled_sums(ws, u, s_tw, c_tw);
        let mut row = d_px;
        for a in 0..n {
            let s = ws.sin[a];
            d_omega[a] = d_p[a] + d_theta[a] * s_w[a] - s_tw[a] + h[a] * s * d_theta[a] * v;
            row += h[a] * s * d_theta[a] * omega[a];
        }
        if let Some((dp, dp_x, _)) = forcing {
            for a in 0..n {
                d_omega[a] -= dp[a];
            }
            row -= dp_x;
        }
        let art = self.eliminate(ws, d_omega, |_, _, _| 0.0)?;
        let dv = if self.cart.is_some() { (row - art.wx) / self.cart_inertia(art)? } else { 0.0 };
        self.substitute_from(ws, d_omega, dv, |_, _, _, _| {});
        // d p_dot.
        self.coupled_sums(ws, d_omega, s_dw, c_dw);
        for a in 0..n {
            let (s, c) = (ws.sin[a], ws.cos[a]);
            d_pdot[a] = h[a] * (gy * c - gx * s) * d_theta[a]
                - d_omega[a] * s_w[a]
                - omega[a] * (s_dw[a] + d_theta[a] * c_w[a] - c_tw[a])
                - h[a] * (dv * s * omega[a] + v * c * d_theta[a] * omega[a] + v * s * d_omega[a]);
        }
        if self.lossy_joints() {
            self.add_loss_tangent(&omega[..n], d_omega, d_pdot);
        }
        if let Some((_, _, dpdot)) = forcing {
            for a in 0..n {
                d_pdot[a] += dpdot[a];
            }
        }
        let d_pxdot = self.cart.map_or(0.0, |cart| -cart.damping * dv);
        Ok((dv, d_pxdot))
    }

    /// The dense mass matrix of the general model, row-major: `N x N`, or `(N+1) x (N+1)` with
    /// the cart first.
    pub fn mass_matrix_general(&self, theta: &[f64], out: &mut [f64]) {
        let n = self.n();
        let Some(cart) = self.cart else { return self.mass_matrix_into(theta, out) };
        let m = n + 1;
        out[0] = cart.mass + self.total_mass();
        for a in 0..n {
            let k = self.h[a] * theta[a].cos();
            out[a + 1] = k;
            out[(a + 1) * m] = k;
            for b in 0..n {
                out[(a + 1) * m + b + 1] = self.coupling(a, b) * (theta[a] - theta[b]).cos();
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::Cart;

    fn chains() -> Vec<Chain> {
        let base = Chain::new(&[1.0, 0.8, 0.6], &[1.0, 1.5, 0.7], Some(&[0.5, 0.3, 0.6]), Some(&[0.1, 0.05, 0.02]), 9.81).unwrap();
        let lossy = base.clone().with_losses(&[0.3, 0.1, 0.2], &[0.05, 0.0, 0.1], 0.5).unwrap();
        let cart = lossy.clone().with_cart(Some(Cart::new(2.0, 0.4).unwrap())).unwrap();
        vec![base, lossy, cart]
    }

    fn dense_solve(mut a: Vec<f64>, mut b: Vec<f64>) -> Vec<f64> {
        let m = b.len();
        for k in 0..m {
            let p = (k..m).max_by(|&i, &j| a[i * m + k].abs().total_cmp(&a[j * m + k].abs())).unwrap();
            for j in 0..m {
                a.swap(k * m + j, p * m + j);
            }
            b.swap(k, p);
            for i in k + 1..m {
                let f = a[i * m + k] / a[k * m + k];
                for j in k..m {
                    a[i * m + j] -= f * a[k * m + j];
                }
                b[i] -= f * b[k];
            }
        }
        for k in (0..m).rev() {
            let s: f64 = (k + 1..m).map(|j| a[k * m + j] * b[j]).sum();
            b[k] = (b[k] - s) / a[k * m + k];
        }
        b
    }

    #[test]
    fn the_recursion_solves_the_dense_system_with_a_cart() {
        // M (x_ddot, theta_ddot) = rhs, with the rhs read off the recursion's own inputs: the
        // recursion's answer times the dense matrix gives back the forces.
        let chain = &chains()[2];
        let (theta, omega, v) = ([0.3, -1.1, 2.0], [0.7, -0.2, 1.3], 0.4);
        let mut ws = Workspace::new(3);
        let mut acc = [0.0; 3];
        let load = Load { gravity: [0.0, -9.81], cart_force: 1.5 };
        let r = chain.accelerations_general(&theta, &omega, v, &[0.2, 0.0, -0.1], &load, &mut acc, &mut ws).unwrap();
        let mut mm = vec![0.0; 16];
        chain.mass_matrix_general(&theta, &mut mm);
        let q = [r.cart, acc[0], acc[1], acc[2]];
        let lhs: Vec<f64> = (0..4).map(|i| (0..4).map(|j| mm[i * 4 + j] * q[j]).sum()).collect();
        // The same right-hand side, dense: forces minus the velocity terms.
        let mut p = [0.0; 3];
        let px = chain.momenta_general(&theta, &omega, v, &mut p, &mut ws);
        // p_x and p are M (v, omega): check the momenta against the dense matrix too.
        let vel = [v, omega[0], omega[1], omega[2]];
        let mom: Vec<f64> = (0..4).map(|i| (0..4).map(|j| mm[i * 4 + j] * vel[j]).sum()).collect();
        assert!((mom[0] - px).abs() < 1e-13 && (0..3).all(|a| (mom[a + 1] - p[a]).abs() < 1e-13), "{mom:?} {px} {p:?}");
        let back = dense_solve(mm.clone(), lhs.clone());
        for i in 0..4 {
            assert!((back[i] - q[i]).abs() < 1e-12);
        }
        // Velocities invert momenta.
        let mut w = [0.0; 3];
        let v2 = chain.velocities_general(&theta, &p, px, &mut w, &mut ws).unwrap();
        assert!((v2 - v).abs() < 1e-13 && (0..3).all(|a| (w[a] - omega[a]).abs() < 1e-13));
    }

    #[test]
    fn without_losses_pivot_or_cart_the_general_model_is_the_ideal_one() {
        let chain = &chains()[0];
        let (theta, omega, tau) = ([0.3, -1.1, 2.0], [0.7, -0.2, 1.3], [0.2, 0.0, -0.1]);
        let mut ws = Workspace::new(3);
        let (mut a, mut b) = ([0.0; 3], [0.0; 3]);
        chain.accelerations_into(&theta, &omega, &tau, &mut a, &mut ws).unwrap();
        chain.accelerations_general(&theta, &omega, 0.0, &tau, &Load::still(chain), &mut b, &mut ws).unwrap();
        for i in 0..3 {
            assert!((a[i] - b[i]).abs() < 1e-13 * a[i].abs().max(1.0));
        }
    }

    /// Central differences of the rates along a direction, against the tangent equations.
    #[test]
    fn tangents_match_central_differences_in_both_forms() {
        for chain in chains() {
            let n = 3;
            let cart = chain.cart().is_some();
            let (theta, omega, v) = ([0.3, -1.1, 2.0], [0.7, -0.2, 1.3], if cart { 0.4 } else { 0.0 });
            let (dth, dw, dv) = ([0.2, -0.5, 0.3], [0.1, 0.4, -0.6], if cart { 0.7 } else { 0.0 });
            let load = Load { gravity: [1.3, -9.0], cart_force: 0.5 };
            let tau = [0.2, 0.0, -0.1];
            let mut ws = Workspace::new(n);
            let mut scratch = vec![0.0; TANGENT_SCRATCH * n];
            // Lagrangian.
            let lag = |e: f64, ws: &mut Workspace| {
                let th: Vec<f64> = (0..n).map(|i| theta[i] + e * dth[i]).collect();
                let om: Vec<f64> = (0..n).map(|i| omega[i] + e * dw[i]).collect();
                let mut out = vec![0.0; n];
                let r = chain.accelerations_general(&th, &om, v + e * dv, &tau, &load, &mut out, ws).unwrap();
                (out, r.cart)
            };
            let (acc, xdd) = lag(0.0, &mut ws);
            let mut d = [0.0; 3];
            let dx = chain.tangent_general(&theta, &omega, (&acc, xdd), &load, (&dth, &dw, dv), &mut d, &mut scratch, &mut ws).unwrap();
            let e = 1e-6;
            let ((ap, xp), (am, xm)) = (lag(e, &mut ws), lag(-e, &mut ws));
            for i in 0..n {
                let fd = (ap[i] - am[i]) / (2.0 * e);
                assert!((fd - d[i]).abs() < 1e-6 * fd.abs().max(1.0), "lagrangian {i}: {fd} vs {}", d[i]);
            }
            assert!(((xp - xm) / (2.0 * e) - dx).abs() < 1e-6, "cart: {} vs {dx}", (xp - xm) / (2.0 * e));
            // Hamiltonian.
            let mut p = [0.0; 3];
            let px = chain.momenta_general(&theta, &omega, v, &mut p, &mut ws);
            let (dp, dpx) = ([0.3, 0.1, -0.2], if cart { -0.4 } else { 0.0 });
            let ham = |e: f64, ws: &mut Workspace| {
                let th: Vec<f64> = (0..n).map(|i| theta[i] + e * dth[i]).collect();
                let pp: Vec<f64> = (0..n).map(|i| p[i] + e * dp[i]).collect();
                let (mut td, mut pd) = (vec![0.0; n], vec![0.0; n]);
                let r = chain
                    .hamilton_general(&th, &pp, px + e * dpx, &mut td, &mut pd, load.gravity, ws, |_, _, out: &mut [f64]| {
                        out.copy_from_slice(&tau);
                        Ok::<f64, ()>(load.cart_force)
                    })
                    .unwrap()
                    .unwrap();
                (td, pd, r)
            };
            let (w0, _, r0) = ham(0.0, &mut ws);
            let (mut d_om, mut d_pd) = ([0.0; 3], [0.0; 3]);
            let (d_v, d_pxd) =
                chain.hamilton_tangent(&theta, (&w0, r0.cart), load.gravity, (&dth, &dp, dpx), &mut d_om, &mut d_pd, &mut scratch, &mut ws).unwrap();
            let ((tp, pp, rp), (tm, pm, rm)) = (ham(e, &mut ws), ham(-e, &mut ws));
            for i in 0..n {
                let (f1, f2) = ((tp[i] - tm[i]) / (2.0 * e), (pp[i] - pm[i]) / (2.0 * e));
                assert!((f1 - d_om[i]).abs() < 1e-6 * f1.abs().max(1.0), "d omega {i}: {f1} vs {}", d_om[i]);
                assert!((f2 - d_pd[i]).abs() < 1e-6 * f2.abs().max(1.0), "d p_dot {i}: {f2} vs {}", d_pd[i]);
            }
            assert!(((rp.cart - rm.cart) / (2.0 * e) - d_v).abs() < 1e-6);
            assert!(((rp.cart_momentum_rate - rm.cart_momentum_rate) / (2.0 * e) - d_pxd).abs() < 1e-6);
        }
    }

    #[test]
    fn losses_dissipate_and_map_to_differences() {
        let chain = chains()[1].clone();
        let omega = [0.7, -0.2, 1.3];
        let mut q = [0.0; 3];
        let power = chain.add_losses(&omega, &mut q);
        // Power of the generalized forces is minus the dissipation.
        let pq: f64 = q.iter().zip(&omega).map(|(a, b)| a * b).sum();
        assert!((pq + power).abs() < 1e-14 && power > 0.0);
        // Joint 1 (the base's) turns at omega_1; joint 2 at omega_2 - omega_1.
        let u1 = -0.3 * 0.7 - 0.05 * (0.7f64 / 0.5).tanh();
        let u2 = -0.1 * (-0.2 - 0.7);
        assert!((q[0] - (u1 - u2)).abs() < 1e-15);
    }
}
