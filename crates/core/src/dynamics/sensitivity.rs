//! Forward sensitivities: the derivative of a run's state with respect to its initial state and
//! the chain's parameters, from the variational equations `dS/dt = J S + df/dP`, O(N) per
//! direction.
//!
//! A parameter's forcing `df/dP` comes from the equations of motion written the Newton–Euler
//! way, which are explicit in every parameter. With `n_a = (cos, sin)(theta_a)` and the field
//! `X_i = B + sum_{b<i} l_b K_b + c_i K_i` at the links' centres of mass (`K_b` per link, `B` at
//! the base), every term has the shape
//!
//! `Y_a = P_a . (c_a m_a X_a + l_a sum_{i>a} m_i X_i)`, and `Z = sum_i m_i X_i . x` for the cart,
//!
//! explicit in `l`, `m`, `c` and (through `B`) `g`:
//! - the residual of the accelerations (`K = theta_ddot n - omega^2 (sin, -cos)`, `B = (x_ddot, 0)
//!   - gravity`, `P = n`) plus `I theta_ddot - Q`: `M q_ddot = F` differentiated at fixed
//!   accelerations gives the forcing of the Lagrangian form, `-d(residual)/dP`;
//! - the momenta (`K = omega n`, `B = (v, 0)`, `P = n`) plus `I omega`;
//! - `dL/dtheta_a`: the same field with `P_a = omega_a (-sin, cos)(theta_a)` (the kinetic
//!   energy's), and `K = 0`, `B = gravity`, `P = n` (the potential's), plus the joints' losses:
//!   with the momenta's derivative, the forcing of Hamilton's equations.
//!
//! The joint losses `u_j = -b_j w_j - f_j tanh(w_j / v_s)` enter as `Q_j = u_j - u_{j+1}`.
use super::general::{saturating_tanh, Load, TANGENT_SCRATCH};
use super::system::{Evaluated, Form};
use super::{Singular, Workspace, PIVOT_TOL};
use crate::error::{Error, Result};
use crate::model::Chain;

/// What a run's sensitivities can be taken with respect to (each N entries, `g` one).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Input {
    Theta0,
    Omega0,
    Lengths,
    Masses,
    Com,
    Inertia,
    G,
    Damping,
    Friction,
}

impl Input {
    /// The inputs' names, in this order (Python and the docs read them).
    pub const NAMES: [&'static str; 9] = ["theta0", "omega0", "lengths", "masses", "com", "inertia", "g", "damping", "friction"];
    const ALL: [Input; 9] =
        [Input::Theta0, Input::Omega0, Input::Lengths, Input::Masses, Input::Com, Input::Inertia, Input::G, Input::Damping, Input::Friction];

    pub fn parse(name: &str) -> Result<Self> {
        match Self::NAMES.iter().position(|&s| s == name) {
            Some(i) => Ok(Self::ALL[i]),
            None => Err(Error::input(format!("unknown sensitivity {name:?}: the inputs are {}", Self::NAMES.map(|s| format!("\"{s}\"")).join(", ")))),
        }
    }

    pub fn name(self) -> &'static str {
        Self::NAMES[Self::ALL.iter().position(|&i| i == self).unwrap()]
    }

    /// The number of entries (directions) of the input for `n` links.
    pub fn len(self, n: usize) -> usize {
        if self == Input::G {
            1
        } else {
            n
        }
    }

    /// The directions of this input, in entry order.
    fn directions(self, n: usize) -> impl Iterator<Item = Direction> {
        (0..self.len(n)).map(move |j| match self {
            Input::Theta0 => Direction::Theta(j),
            Input::Omega0 => Direction::Omega(j),
            Input::Lengths => Direction::Param(Param::Length(j)),
            Input::Masses => Direction::Param(Param::Mass(j)),
            Input::Com => Direction::Param(Param::Com(j)),
            Input::Inertia => Direction::Param(Param::Inertia(j)),
            Input::G => Direction::Param(Param::Gravity),
            Input::Damping => Direction::Param(Param::Damping(j)),
            Input::Friction => Direction::Param(Param::Friction(j)),
        })
    }
}

/// One of the chain's parameters.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Param {
    Length(usize),
    Mass(usize),
    Com(usize),
    Inertia(usize),
    Gravity,
    Damping(usize),
    Friction(usize),
}

/// One sensitivity direction: an initial angle or rate, or a parameter.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Direction {
    Theta(usize),
    Omega(usize),
    Param(Param),
}

/// The directions of `inputs` (each once, in the given order) for `n` links.
pub fn directions(inputs: &[Input], n: usize) -> Result<Vec<Direction>> {
    for (i, a) in inputs.iter().enumerate() {
        if inputs[..i].contains(a) {
            return Err(Error::input(format!("sensitivity {:?} is given twice", a.name())));
        }
    }
    Ok(inputs.iter().flat_map(|i| i.directions(n)).collect())
}

#[inline(always)]
fn dot(a: [f64; 2], b: [f64; 2]) -> f64 {
    a[0] * b[0] + a[1] * b[1]
}

/// The field `X_i` of one evaluation and its suffix sums (the module's notation).
#[derive(Debug, Clone, Default)]
pub(crate) struct Field {
    k: Vec<[f64; 2]>,
    x: Vec<[f64; 2]>,
    /// `sum_{i>=a} m_i X_i`, N + 1 entries.
    phi: Vec<[f64; 2]>,
    /// `d B / d g`.
    dbase_g: [f64; 2],
}

impl Field {
    pub fn new(n: usize) -> Self {
        Field { k: vec![[0.0; 2]; n], x: vec![[0.0; 2]; n], phi: vec![[0.0; 2]; n + 1], dbase_g: [0.0; 2] }
    }
}

/// Work buffers of the forcings for one chain size.
#[derive(Debug, Clone, Default)]
pub struct Scratch {
    field: Field,
    gravity: Field,
    proj: Vec<[f64; 2]>,
    kin: Vec<[f64; 2]>,
    /// Suffix sums of the masses, `sum_{i>=a} m_i`, N + 1 entries.
    below: Vec<f64>,
    pub(crate) b: Vec<f64>,
    pub(crate) dp: Vec<f64>,
    pub(crate) dpdot: Vec<f64>,
    /// Whether some direction needs the fields themselves (a length, mass or centre of mass);
    /// g, the inertias and the losses need only the projections ([`Chain::prepare_forcing`]).
    fields: bool,
}

impl Scratch {
    pub fn new(chain: &Chain) -> Self {
        let n = chain.n();
        let mut below = vec![0.0; n + 1];
        for i in (0..n).rev() {
            below[i] = below[i + 1] + chain.masses[i];
        }
        Scratch {
            field: Field::new(n),
            gravity: Field::new(n),
            proj: vec![[0.0; 2]; n],
            kin: vec![[0.0; 2]; n],
            below,
            b: vec![0.0; n],
            dp: vec![0.0; n],
            dpdot: vec![0.0; n],
            fields: true,
        }
    }

    /// For the directions `dirs` only: the fields are then filled only if one needs them.
    fn for_directions(chain: &Chain, dirs: &[Direction]) -> Self {
        let fields = dirs.iter().any(|d| matches!(d, Direction::Param(Param::Length(_) | Param::Mass(_) | Param::Com(_))));
        Scratch { fields, ..Scratch::new(chain) }
    }
}

/// Rates of the state a forcing is taken at: the Lagrangian form's accelerations, or the
/// Hamiltonian form's velocities.
pub(crate) enum At<'a> {
    Lagrangian { omega: &'a [f64], accel: &'a [f64], x_ddot: f64 },
    Hamiltonian { omega: &'a [f64], v: f64 },
}

impl Chain {
    /// `X_i` and its suffix sums for `K` (in `f.k`) and base `base` (if `fields`; `d B / d g`
    /// always).
    fn fill_field(&self, f: &mut Field, base: [f64; 2], dbase_g: [f64; 2], fields: bool) {
        f.dbase_g = dbase_g;
        if !fields {
            return;
        }
        let n = self.n();
        let mut alpha = base;
        for i in 0..n {
            let (k, c, l) = (f.k[i], self.com[i], self.lengths[i]);
            f.x[i] = [alpha[0] + c * k[0], alpha[1] + c * k[1]];
            alpha = [alpha[0] + l * k[0], alpha[1] + l * k[1]];
        }
        f.phi[n] = [0.0; 2];
        for i in (0..n).rev() {
            let m = self.masses[i];
            f.phi[i] = [f.phi[i + 1][0] + m * f.x[i][0], f.phi[i + 1][1] + m * f.x[i][1]];
        }
    }

    /// Add `d Y_a / d param` (projections `proj`) to `out`; returns `d Z / d param`. O(N).
    fn field_derivative(&self, f: &Field, below: &[f64], proj: &[[f64; 2]], param: Param, out: &mut [f64]) -> f64 {
        let n = self.n();
        let (l, m, c, h) = (&self.lengths, &self.masses, &self.com, &self.h);
        match param {
            Param::Mass(j) => {
                let xj = f.x[j];
                for a in 0..j {
                    out[a] += l[a] * dot(proj[a], xj);
                }
                out[j] += c[j] * dot(proj[j], xj);
                xj[0]
            }
            Param::Com(j) => {
                let (kj, xj) = (f.k[j], f.x[j]);
                for a in 0..j {
                    out[a] += l[a] * m[j] * dot(proj[a], kj);
                }
                out[j] += m[j] * (dot(proj[j], xj) + c[j] * dot(proj[j], kj));
                m[j] * kj[0]
            }
            Param::Length(j) => {
                let (kj, s) = (f.k[j], below[j + 1]);
                for a in 0..j {
                    out[a] += l[a] * s * dot(proj[a], kj);
                }
                out[j] += dot(proj[j], f.phi[j + 1]) + l[j] * s * dot(proj[j], kj);
                for a in j + 1..n {
                    out[a] += h[a] * dot(proj[a], kj);
                }
                s * kj[0]
            }
            Param::Gravity => {
                for a in 0..n {
                    out[a] += h[a] * dot(proj[a], f.dbase_g);
                }
                below[0] * f.dbase_g[0]
            }
            Param::Inertia(_) | Param::Damping(_) | Param::Friction(_) => 0.0,
        }
    }

    /// `d Q / d param` of the joints' losses at rates `omega`, added to `out`.
    fn loss_derivative(&self, omega: &[f64], param: Param, out: &mut [f64]) {
        let (j, du) = match param {
            Param::Damping(j) | Param::Friction(j) => {
                let w = omega[j] - if j > 0 { omega[j - 1] } else { 0.0 };
                let du = match param {
                    Param::Damping(_) => -w,
                    _ => -saturating_tanh(w * self.joints.inv_velocity),
                };
                (j, du)
            }
            _ => return,
        };
        out[j] += du;
        if j > 0 {
            out[j - 1] -= du;
        }
    }

    /// Prepare the forcings of the directions at one state (the angles' trig in `ws`). O(N).
    pub(crate) fn prepare_forcing(&self, at: &At, load: &Load, sc: &mut Scratch, ws: &Workspace) {
        let n = self.n();
        let (s, c) = (&ws.sin[..n], &ws.cos[..n]);
        let [gx, gy] = load.gravity;
        let fields = sc.fields;
        for a in 0..n {
            sc.proj[a] = [c[a], s[a]];
        }
        match *at {
            At::Lagrangian { omega, accel, x_ddot } => {
                if fields {
                    for a in 0..n {
                        let (dd, w2) = (accel[a], omega[a] * omega[a]);
                        sc.field.k[a] = [dd * c[a] - w2 * s[a], dd * s[a] + w2 * c[a]];
                    }
                }
                self.fill_field(&mut sc.field, [x_ddot - gx, -gy], [0.0, 1.0], fields);
            }
            At::Hamiltonian { omega, v } => {
                for a in 0..n {
                    sc.kin[a] = [-omega[a] * s[a], omega[a] * c[a]];
                }
                if fields {
                    for a in 0..n {
                        sc.field.k[a] = [omega[a] * c[a], omega[a] * s[a]];
                    }
                    sc.gravity.k.fill([0.0; 2]);
                }
                self.fill_field(&mut sc.field, [v, 0.0], [0.0, 0.0], fields);
                self.fill_field(&mut sc.gravity, [gx, gy], [0.0, -1.0], fields);
            }
        }
    }

    /// The Lagrangian form's forcing of `param` into `sc.b` (angles) and returned (the cart's):
    /// `-d r / d param`, `r = M q_ddot - F` at fixed accelerations. After [`Chain::prepare_forcing`].
    pub(crate) fn lagrangian_forcing(&self, omega: &[f64], accel: &[f64], param: Param, sc: &mut Scratch) -> f64 {
        let Scratch { field, below, proj, b, .. } = sc;
        b.fill(0.0);
        let mut bx = self.field_derivative(field, below, proj, param, b);
        if let Param::Inertia(j) = param {
            b[j] += accel[j];
        }
        for v in b.iter_mut() {
            *v = -*v;
        }
        bx = -bx;
        self.loss_derivative(omega, param, b);
        bx
    }

    /// The Hamiltonian form's forcing of `param`: the momenta's derivative at fixed rates into
    /// `sc.dp` (the cart's returned first) and `p_dot`'s at fixed angles and rates into `sc.dpdot`
    /// (the cart's `p_x_dot` has none). After [`Chain::prepare_forcing`].
    pub(crate) fn hamiltonian_forcing(&self, omega: &[f64], param: Param, sc: &mut Scratch) -> f64 {
        let Scratch { field, gravity, below, proj, kin, dp, dpdot, .. } = sc;
        dp.fill(0.0);
        dpdot.fill(0.0);
        // (The rates' field has no gravity, `d B / d g = 0`: g moves only the potential's terms.)
        let dpx = self.field_derivative(field, below, proj, param, dp);
        if let Param::Inertia(j) = param {
            dp[j] += omega[j];
        }
        self.field_derivative(field, below, kin, param, dpdot);
        self.field_derivative(gravity, below, proj, param, dpdot);
        self.loss_derivative(omega, param, dpdot);
        dpx
    }

    /// The momenta's derivative along `(d_theta, d_omega, d_v)` at rates `(omega, v)`: into
    /// `dp`, the cart's returned (for the Hamiltonian form's initial sensitivities). The rates
    /// enter linearly; the angles through `hamilton_tangent` (whose `d omega` at `d p = 0` is
    /// `-M^-1 (dM) omega`).
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn momenta_tangent(
        &self,
        theta: &[f64],
        (omega, v): (&[f64], f64),
        (d_theta, d_omega, d_v): (&[f64], &[f64], f64),
        dp: &mut [f64],
        scratch: &mut [f64],
        ws: &mut Workspace,
    ) -> std::result::Result<f64, Singular> {
        let n = self.n();
        let zero = vec![0.0; n];
        let (mut w, mut junk) = (vec![0.0; n], vec![0.0; n]);
        let (dv0, _) = self.hamilton_tangent(theta, (omega, v), [0.0, 0.0], (d_theta, &zero, 0.0), &mut w, &mut junk, scratch, ws)?;
        // (dM) omega = -M w; then M d_omega on top.
        for a in 0..n {
            w[a] = d_omega[a] - w[a];
        }
        Ok(self.momenta_general(theta, &w, d_v - dv0, dp, ws))
    }
}

/// What the tangents share between directions at one state: the mass matrix's factorisation
/// (left in the workspace by [`Chain::eliminate`]) and coupled sums of the rates. The
/// Lagrangian tangent's are the coefficients of `d theta` ([`Chain::sums`]: gravity's, and the
/// coupled sums of `omega^2` (cosine part) and of the accelerations (sine part)); with them a
/// direction costs one fused pass and a solve without divisions: the same
/// equations as [`Chain::tangent_general`] (which the Jacobian and the Lyapunov runs keep, bit
/// for bit), regrouped (tested equal to round-off). The Hamiltonian tangent's are those of
/// `omega` (both parts); a direction then costs two coupled sums and the solve, not the
/// angles' trig and a factorisation of its own as [`Chain::hamilton_tangent_forced`] does.
#[derive(Debug, Clone, Default)]
pub(crate) struct Shared {
    /// The cosine and sine parts of the Hamiltonian tangent's coupled sums of `omega` (the
    /// Lagrangian's [`Chain::sums`] keeps its summands there).
    cos_sums: Vec<f64>,
    sin_sums: Vec<f64>,
    /// The Lagrangian tangent's coefficient of each `d theta_a` ([`Chain::sums`]).
    stiffness: Vec<f64>,
    scratch: Vec<f64>,
}

impl Shared {
    fn new(n: usize) -> Self {
        Shared { cos_sums: vec![0.0; n], sin_sums: vec![0.0; n], stiffness: vec![0.0; n], scratch: vec![0.0; n] }
    }
}

impl Chain {
    /// Fill `sh` at a state (the angles' trig in `ws`) and factor the mass matrix into `ws`.
    #[cfg(test)]
    fn share(&self, omega: &[f64], accel: &[f64], gravity: [f64; 2], sh: &mut Shared, ws: &mut Workspace) -> std::result::Result<(), Singular> {
        self.sums(omega, accel, gravity, sh, ws);
        self.factor(sh, ws)
    }

    /// The Lagrangian tangent's coefficient of `d theta_a` into `sh.stiffness`, the same for
    /// every direction: gravity's `h_a (g_y cos theta_a - g_x sin theta_a)`, plus the sine part
    /// of [`Chain::coupled_sums`] of the accelerations less the cosine part of `omega^2`'s. The
    /// two coupled sums are only ever needed as that difference, so it is summed directly: two
    /// running sums each way, of `l_b (a_b cos theta_b - w_b^2 sin theta_b)` and `l_b (a_b sin
    /// theta_b + w_b^2 cos theta_b)` from above (`h_b` from below), not four.
    fn sums(&self, omega: &[f64], accel: &[f64], [gx, gy]: [f64; 2], sh: &mut Shared, ws: &Workspace) {
        let n = self.n();
        let (l, h, s, c) = (&self.lengths[..n], &self.h[..n], &ws.sin[..n], &ws.cos[..n]);
        let Shared { stiffness, cos_sums: e1, sin_sums: e2, .. } = sh;
        let (k, e1, e2, omega, accel) = (&mut stiffness[..n], &mut e1[..n], &mut e2[..n], &omega[..n], &accel[..n]);
        let (mut x, mut y) = (0.0, 0.0);
        for a in 0..n {
            let w2 = omega[a] * omega[a];
            (e1[a], e2[a]) = (accel[a] * c[a] - w2 * s[a], accel[a] * s[a] + w2 * c[a]);
            k[a] = h[a] * ((gy * c[a] - gx * s[a]) + (s[a] * x - c[a] * y));
            x += l[a] * e1[a];
            y += l[a] * e2[a];
        }
        let (mut x, mut y) = (0.0, 0.0);
        for a in (0..n).rev() {
            k[a] += l[a] * (s[a] * x - c[a] * y);
            x += h[a] * e1[a];
            y += h[a] * e2[a];
        }
    }

    /// The mass matrix's factorisation into `ws` (the angles' trig there).
    fn factor(&self, sh: &mut Shared, ws: &mut Workspace) -> std::result::Result<(), Singular> {
        sh.scratch.fill(0.0);
        self.eliminate(ws, &mut sh.scratch, |_, _, _| 0.0)?;
        Ok(())
    }

    /// Solve `M x = r` for `k = rows.len()` right-hand sides at once with the factorisation in
    /// `ws` (no divisions): column `c`'s `x` (holding `r`) at `xs[c * stride + off..][..n]`, its
    /// cart row `rows[c]` (the cart's own right-hand side), replaced by the base's acceleration
    /// along x, `(row - w_x)` over the cart's articulated inertia (0 without a cart). Each
    /// column solves the equations of [`Chain::eliminate`] and [`Chain::substitute_from`],
    /// regrouped ([`Chain::solve_block`]; equal to round-off, a column's bits not depending on
    /// the other columns); side by side, the columns' chains of dependent operations (each link
    /// waits on the sums of the links before it) overlap instead of running one after another.
    /// `at`: `(stride, off)`.
    fn solve_factored_many(&self, ws: &Workspace, xs: &mut [f64], at: (usize, usize), rows: &mut [f64]) -> std::result::Result<(), Singular> {
        let k = rows.len();
        // The cart's articulated inertia is the same for every column (the factorisation's).
        let cart = match self.cart {
            Some(_) => Some(self.cart_inertia(super::Articulated { gxx: ws.gxx, wx: 0.0 })?),
            None => None,
        };
        let mut first = 0;
        // Four columns at a time, their running sums in registers; then the one to three left.
        while first < k {
            match k - first {
                1 => self.solve_block::<1>(ws, cart, xs, at, first, rows),
                2 => self.solve_block::<2>(ws, cart, xs, at, first, rows),
                3 => self.solve_block::<3>(ws, cart, xs, at, first, rows),
                _ => self.solve_block::<4>(ws, cart, xs, at, first, rows),
            }
            first += (k - first).min(4);
        }
        Ok(())
    }

    /// [`Chain::solve_factored_many`] for the `B` columns from `first` on; `cart`: the cart's
    /// articulated inertia, if there is a cart.
    #[inline(always)]
    fn solve_block<const B: usize>(&self, ws: &Workspace, cart: Option<f64>, xs: &mut [f64], (stride, off): (usize, usize), first: usize, rows: &mut [f64]) {
        let n = self.n();
        let (l, s, c) = (&self.lengths[..n], &ws.sin[..n], &ws.cos[..n]);
        let (u, dinv) = (&ws.u[..n], &ws.dinv[..n]);
        let mut start = [0; B];
        for (j, at) in start.iter_mut().enumerate() {
            *at = (first + j) * stride + off;
        }
        let (mut wx, mut wy) = ([0.0; B], [0.0; B]);
        // Each pass carries two running sums `w` from link to link, `w' = w + u rho` with `rho
        // = x - l . w` (elimination; `u` over `d`, `l = (l c, l s)`), `w' = w + l x_a` with `x_a
        // = x / d - u . w` (substitution), and the solve is bound by that chain's latency, not
        // by its arithmetic. Written as `w' = A w + b` with the link's `A = I - u l^T` (its
        // transpose in the substitution) formed off the chain, a link waits on the one before
        // for one product and two sums instead of three products and three sums; the link's
        // own value (`rho`, `x_a`) is formed off the chain too. The same equations as
        // `eliminate` and `substitute_from` (tested equal to round-off), regrouped.
        let coefficients = |a: usize| (l[a] * c[a], l[a] * s[a], u[a][0] * dinv[a], u[a][1] * dinv[a]);
        for a in (0..n).rev() {
            let (lc, ls, ux, uy) = coefficients(a);
            let (a00, a01, a10, a11) = (1.0 - ux * lc, ux * ls, uy * lc, 1.0 - uy * ls);
            for j in 0..B {
                let x = &mut xs[start[j] + a];
                let (x0, px, py) = (*x, wx[j], wy[j]);
                *x = x0 - (lc * px + ls * py);
                wx[j] = (a00 * px + ux * x0) - a01 * py;
                wy[j] = (a11 * py + uy * x0) - a10 * px;
            }
        }
        for j in 0..B {
            let row = &mut rows[first + j];
            *row = match cart {
                Some(inertia) => (*row - wx[j]) / inertia,
                None => 0.0,
            };
            // The substitution's prefix sums start at the base's acceleration (`substitute_from`).
            (wx[j], wy[j]) = (*row, 0.0);
        }
        for a in 0..n {
            let (lc, ls, ux, uy) = coefficients(a);
            let (b00, b01, b10, b11) = (1.0 - lc * ux, lc * uy, ls * ux, 1.0 - ls * uy);
            let (bx, by) = (lc * dinv[a], ls * dinv[a]);
            for j in 0..B {
                let x = &mut xs[start[j] + a];
                let (x0, px, py) = (*x, wx[j], wy[j]);
                *x = x0 * dinv[a] - (ux * px + uy * py);
                wx[j] = (b00 * px + bx * x0) - b01 * py;
                wy[j] = (b11 * py + by * x0) - b10 * px;
            }
        }
    }

    /// Fill `sh` for the Hamiltonian tangent at rates `omega` (the angles' trig in
    /// `ws`) and factor the mass matrix into `ws`.
    #[cfg(test)]
    fn hamilton_share(&self, omega: &[f64], sh: &mut Shared, ws: &mut Workspace) -> std::result::Result<(), Singular> {
        self.hamilton_sums(omega, sh, ws);
        self.factor(sh, ws)
    }

    /// The Hamiltonian tangent's coupled sums (of `omega`) into `sh`.
    fn hamilton_sums(&self, omega: &[f64], sh: &mut Shared, ws: &Workspace) {
        let n = self.n();
        self.coupled_sums(ws, &omega[..n], &mut sh.sin_sums, &mut sh.cos_sums);
    }

    /// The Hamiltonian tangent ([`Chain::hamilton_tangent_forced`]'s equations) reusing the shared
    /// sums and factorisation, in three parts so that the solves of many directions run side by
    /// side: this, [`Chain::solve_factored_many`], [`Chain::hamilton_tangent_finish`]. First, after
    /// [`Chain::hamilton_sums`], the right-hand side of `M d(v, omega) = d(p_x, p) - (dM)(v,
    /// omega)` into `d_omega` (its cart row returned), and the terms of `d p_dot` that do not
    /// depend on `d omega` into `d_pdot`. `scratch` holds 3 N values.
    #[allow(clippy::too_many_arguments)]
    fn hamilton_tangent_rhs(
        &self,
        (omega, v): (&[f64], f64),
        gravity: [f64; 2],
        (d_theta, d_p, d_px): (&[f64], &[f64], f64),
        forcing: Option<(&[f64], f64, &[f64])>,
        sh: &Shared,
        d_omega: &mut [f64],
        d_pdot: &mut [f64],
        scratch: &mut [f64],
        ws: &Workspace,
    ) -> f64 {
        let n = self.n();
        let (u, rest) = scratch.split_at_mut(n);
        let (s_tw, rest) = rest.split_at_mut(n);
        let (c_tw, _) = rest.split_at_mut(n);
        let (s_w, c_w) = (&sh.sin_sums[..n], &sh.cos_sums[..n]);
        let (h, [gx, gy]) = (&self.h[..n], gravity);
        let (sin, cos) = (&ws.sin[..n], &ws.cos[..n]);
        let (d_omega, d_pdot) = (&mut d_omega[..n], &mut d_pdot[..n]);
        for a in 0..n {
            u[a] = d_theta[a] * omega[a];
        }
        self.coupled_sums(ws, u, s_tw, c_tw);
        let mut row = d_px;
        for a in 0..n {
            let (s, c) = (sin[a], cos[a]);
            d_omega[a] = d_p[a] + d_theta[a] * s_w[a] - s_tw[a] + h[a] * s * d_theta[a] * v;
            row += h[a] * s * d_theta[a] * omega[a];
            d_pdot[a] = h[a] * (gy * c - gx * s) * d_theta[a] - omega[a] * (d_theta[a] * c_w[a] - c_tw[a]) - h[a] * v * c * d_theta[a] * omega[a];
        }
        if let Some((dp, dp_x, dpdot)) = forcing {
            for a in 0..n {
                d_omega[a] -= dp[a];
                d_pdot[a] += dpdot[a];
            }
            row -= dp_x;
        }
        row
    }

    /// The last part of the Hamiltonian tangent ([`Chain::hamilton_tangent_rhs`]), once
    /// `d_omega` and the cart's `dv` are solved: the rest of `d p_dot`; returns `(dv, d p_x_dot)`.
    #[allow(clippy::too_many_arguments)]
    fn hamilton_tangent_finish(
        &self,
        (omega, v): (&[f64], f64),
        dv: f64,
        sh: &Shared,
        d_omega: &[f64],
        d_pdot: &mut [f64],
        scratch: &mut [f64],
        ws: &Workspace,
    ) -> (f64, f64) {
        let n = self.n();
        let (s_dw, rest) = scratch.split_at_mut(n);
        let (c_dw, _) = rest.split_at_mut(n);
        let (h, s_w, sin) = (&self.h[..n], &sh.sin_sums[..n], &ws.sin[..n]);
        let (d_omega, d_pdot) = (&d_omega[..n], &mut d_pdot[..n]);
        self.coupled_sums(ws, d_omega, s_dw, c_dw);
        for a in 0..n {
            let s = sin[a];
            d_pdot[a] -= d_omega[a] * s_w[a] + omega[a] * s_dw[a] + h[a] * (dv * s * omega[a] + v * s * d_omega[a]);
        }
        if self.lossy_joints() {
            self.add_loss_tangent(&omega[..n], d_omega, d_pdot);
        }
        (dv, self.cart.map_or(0.0, |cart| -cart.damping * dv))
    }

    /// [`Chain::tangent_general`] (with a parameter's forcing) after [`Chain::share`]:
    /// `d theta_ddot` into `out`, `d x_ddot` returned. One direction at a time: [`Columns::rates`] builds every direction's right-hand
    /// side ([`Chain::tangent_shared_rhs`]) and solves them side by side; the tests hold this
    /// against the unshared tangent.
    #[cfg(test)]
    #[allow(clippy::too_many_arguments)]
    fn tangent_shared(
        &self,
        omega: &[f64],
        rates: (&[f64], f64),
        direction: (&[f64], &[f64], f64),
        forcing: Option<(&[f64], f64)>,
        sh: &Shared,
        out: &mut [f64],
        ws: &Workspace,
    ) -> std::result::Result<f64, Singular> {
        let mut row = [self.tangent_shared_rhs(omega, rates, direction, forcing, sh, out, ws)];
        self.solve_factored_many(ws, out, (0, 0), &mut row)?;
        Ok(row[0])
    }

    /// The right-hand side `M d q_ddot = r` of the Lagrangian tangent along one direction after
    /// [`Chain::sums`] into `out`, its cart row returned (0 without a cart), for
    /// [`Chain::solve_factored_many`].
    #[allow(clippy::too_many_arguments)]
    fn tangent_shared_rhs(
        &self,
        omega: &[f64],
        (accel, x_ddot): (&[f64], f64),
        (d_theta, d_omega, d_v): (&[f64], &[f64], f64),
        forcing: Option<(&[f64], f64)>,
        sh: &Shared,
        out: &mut [f64],
        ws: &Workspace,
    ) -> f64 {
        let n = self.n();
        let (l, h, s, c) = (&self.lengths[..n], &self.h[..n], &ws.sin[..n], &ws.cos[..n]);
        let cart = self.cart.is_some();
        // d(rhs) = (gravity - cos_sums + sin_sums) d theta ([`Chain::sums`]) + cos(d theta omega^2)
        //          - sin(2 omega d omega + d theta accel), the last two in one pass each way:
        // with u = d theta omega^2 and w = 2 omega d omega + d theta accel, the coupled sums
        // combine into sum l (u c + w s, u s - w c) from above and sum h (...) from below.
        let (mut pa, mut pb) = (0.0, 0.0);
        let mut row = 0.0;
        for a in 0..n {
            let (sa, ca, dth) = (s[a], c[a], d_theta[a]);
            let u = dth * omega[a] * omega[a];
            let w = 2.0 * omega[a] * d_omega[a] + dth * accel[a];
            out[a] = dth * sh.stiffness[a] + h[a] * (ca * pa + sa * pb);
            if cart {
                out[a] += h[a] * sa * dth * x_ddot;
                row += h[a] * (ca * u + sa * w);
            }
            pa += l[a] * (u * ca + w * sa);
            pb += l[a] * (u * sa - w * ca);
        }
        let (mut qa, mut qb) = (0.0, 0.0);
        for a in (0..n).rev() {
            let (sa, ca) = (s[a], c[a]);
            out[a] += l[a] * (ca * qa + sa * qb);
            let u = d_theta[a] * omega[a] * omega[a];
            let w = 2.0 * omega[a] * d_omega[a] + d_theta[a] * accel[a];
            qa += h[a] * (u * ca + w * sa);
            qb += h[a] * (u * sa - w * ca);
        }
        if self.lossy_joints() {
            self.add_loss_tangent(omega, d_omega, out);
        }
        if let Some((b, b_x)) = forcing {
            for a in 0..n {
                out[a] += b[a];
            }
            row += b_x;
        }
        match self.cart {
            Some(cart) => row - cart.damping * d_v,
            None => 0.0,
        }
    }
}

/// The sensitivity columns of a run: the directions, and the buffers their rates need.
#[derive(Debug, Clone)]
pub struct Columns {
    pub dirs: Vec<Direction>,
    form: Form,
    /// Values per column: the mechanical state, `(theta, omega | p, (x, v | p_x))`.
    pub mech: usize,
    sc: Scratch,
    shared: Shared,
    ws: Workspace,
    scratch: Vec<f64>,
    zero: Vec<f64>,
    /// Per column: the cart's row of the solve.
    rows: Vec<f64>,
}

impl Columns {
    pub fn new(chain: &Chain, form: Form, dirs: Vec<Direction>) -> Self {
        let n = chain.n();
        let mech = 2 * n + if chain.cart.is_some() { 2 } else { 0 };
        Columns {
            form,
            mech,
            sc: Scratch::for_directions(chain, &dirs),
            shared: Shared::new(n),
            ws: Workspace::new(n),
            scratch: vec![0.0; TANGENT_SCRATCH * n],
            zero: vec![0.0; n],
            rows: vec![0.0; dirs.len()],
            dirs,
        }
    }

    /// Values of all columns together.
    pub fn len(&self) -> usize {
        self.mech * self.dirs.len()
    }

    pub fn is_empty(&self) -> bool {
        self.dirs.is_empty()
    }

    /// The rates `out` of the columns `cols` at the mechanical state `y` with rates `dy` (the
    /// system's right-hand side there): `dS/dt = J S + df/dP`, O(N) per column. The columns
    /// share the state's trig, coupled sums and factorisation; each builds its right-hand side,
    /// then all are solved side by side, then (Hamiltonian form) each finishes its `d p_dot`.
    /// `evaluated`: what the system's evaluation at `y` left
    /// ([`crate::dynamics::system::ChainSystem::evaluated`]), which is then not computed again.
    #[allow(clippy::too_many_arguments)]
    pub fn rates(
        &mut self,
        chain: &Chain,
        load: &Load,
        y: &[f64],
        dy: &[f64],
        cols: &[f64],
        out: &mut [f64],
        evaluated: Evaluated,
    ) -> std::result::Result<(), Singular> {
        if chain.n() == 2 {
            self.rates_double(chain, load, y, dy, cols, out, evaluated)
        } else {
            let factored = match evaluated {
                Evaluated::Factored(ws) => Some(ws),
                _ => None,
            };
            self.rates_general(chain, load, y, dy, cols, out, factored)
        }
    }

    /// [`Columns::rates`] of the double pendulum, on a cart or not, in closed form: at N = 2 the
    /// recursions' fixed cost outweighs their arithmetic (and the Lagrangian evaluation, a
    /// closed form too, leaves no factorisation to reuse). The tangents are
    /// [`Chain::tangent_shared_rhs`]'s and [`Chain::hamilton_tangent_rhs`]'s at N = 2 written out
    /// (tested equal to round-off), with `M = [[d_1, k c_12], [k c_12, d_2]]`, `k = l_1 h_2`,
    /// `d_12 = d theta_1 - d theta_2` and `G_a = h_a (g_y cos theta_a - g_x sin theta_a)`:
    ///
    /// - Lagrangian: `M d omega_dot = r`, `r_1 = G_1 d theta_1 - k (c_12 w_2^2 d_12 + s_12 (2 w_2
    ///   d w_2 - a_2 d_12))`, `r_2 = G_2 d theta_2 + k (c_12 w_1^2 d_12 + s_12 (2 w_1 d w_1 + a_1
    ///   d_12))`;
    /// - Hamiltonian: `M d omega = d p + k s_12 d_12 (w_2, w_1)`, then
    ///   `d p_dot_1 = G_1 d theta_1 - q`, `d p_dot_2 = G_2 d theta_2 + q`,
    ///   `q = k (c_12 d_12 w_1 w_2 + s_12 (d w_1 w_2 + w_1 d w_2))`;
    ///
    /// then the losses' terms and the forcings ([`Chain::lagrangian_forcing`]'s and
    /// [`Chain::hamiltonian_forcing`]'s, written out: a link parameter's through the derivatives
    /// of `M`'s entries and `h_a`); the 2 x 2 solve by the adjugate, one division per evaluation.
    /// A cart adds its row, coupled to the links by `b_a = h_a cos theta_a` (`M`'s third row
    /// `(b_1, b_2, total mass)`): the derivatives of `b`, of the cart's velocity terms (`h_a sin
    /// theta_a w_a^2` in its row; `-h_a sin theta_a v w_a` in `p_dot_a`) and of its damping; the
    /// 3 x 3 solve closes with the Schur complement, one more division per evaluation.
    #[allow(clippy::too_many_arguments)]
    fn rates_double(
        &mut self,
        chain: &Chain,
        load: &Load,
        y: &[f64],
        dy: &[f64],
        cols: &[f64],
        out: &mut [f64],
        evaluated: Evaluated,
    ) -> std::result::Result<(), Singular> {
        let (m, form) = (self.mech, self.form);
        let Columns { dirs, ws: own, .. } = self;
        let ws: &Workspace = match evaluated {
            Evaluated::Trig(ws) | Evaluated::Factored(ws) => ws,
            Evaluated::Nothing => {
                let [(s1, c1), (s2, c2)] = crate::trig::lanes::sin_cos_pair(y[0], y[1]);
                (own.sin[0], own.cos[0], own.sin[1], own.cos[1]) = (s1, c1, s2, c2);
                own
            }
        };
        let (s1, c1, s2, c2) = (ws.sin[0], ws.cos[0], ws.sin[1], ws.cos[1]);
        let (d1, d2, h1, h2) = (chain.diag[0], chain.diag[1], chain.h[0], chain.h[1]);
        let k = chain.lengths[0] * h2;
        let (s12, c12) = (s1 * c2 - c1 * s2, c1 * c2 + s1 * s2);
        let kc = k * c12;
        let det = d1 * d2 - kc * kc;
        // The evaluation's own test (the recursion's pivot at link 0 is det / d2).
        if !(det > PIVOT_TOL * d1 * d2) {
            return Err(Singular(0));
        }
        let inv = 1.0 / det;
        // det A^-1 applied to (a, b), A the links' 2 x 2 block: the adjugate's product.
        let adj = |a: f64, b: f64| [d2 * a - kc * b, d1 * b - kc * a];
        // With a cart, `b = h cos theta` couples it to the links and its row closes the system
        // with the Schur complement `total - b . A^-1 b` (scaled by det, as the evaluation's).
        let cart = chain.cart.map(|c| (c.mass + chain.total_mass(), c.damping));
        let (b1, b2) = (h1 * c1, h2 * c2);
        // The coupling's derivative, `d b_a = dh_a cos theta_a - h_a sin theta_a d theta_a`.
        let db = |dh1: f64, dh2: f64, dt1: f64, dt2: f64| (dh1 * c1 - h1 * s1 * dt1, dh2 * c2 - h2 * s2 * dt2);
        let zb = adj(b1, b2);
        let schur = match cart {
            Some((total, _)) => {
                let schur_det = total * det - (b1 * zb[0] + b2 * zb[1]);
                if !(schur_det > PIVOT_TOL * total * det) {
                    return Err(Singular(0));
                }
                1.0 / schur_det
            }
            None => 0.0,
        };
        // `M (d a, d x_ddot) = (r, r_x)`: the links' rows, then (with a cart) its row.
        let solve = |r: [f64; 2], rx: f64| {
            let ra = adj(r[0], r[1]);
            let x = if cart.is_some() { (rx * det - (b1 * ra[0] + b2 * ra[1])) * schur } else { 0.0 };
            ([(ra[0] - zb[0] * x) * inv, (ra[1] - zb[1] * x) * inv], x)
        };
        let [gx, gy] = load.gravity;
        let (g1, g2) = (h1 * (gy * c1 - gx * s1), h2 * (gy * c2 - gx * s2));
        // Gravity's generalized forces per unit h_a, and their derivatives along g.
        let (f1, f2) = (gx * c1 + gy * s1, gx * c2 + gy * s2);
        let lossy = chain.lossy_joints();
        let (l1, m1, m2, c_1, c_2) = (chain.lengths[0], chain.masses[0], chain.masses[1], chain.com[0], chain.com[1]);
        // A link parameter's derivatives of d_a = I_a + m_a c_a^2 + l_a^2 m_below, h_a = m_a c_a
        // + l_a m_below and k ([`Chain::new`]'s; a lower link's length moves none), and of the
        // total mass a cart carries.
        let derivatives = |dir: Direction| match dir {
            Direction::Param(Param::Inertia(0)) => (1.0, 0.0, 0.0, 0.0, 0.0, 0.0),
            Direction::Param(Param::Inertia(_)) => (0.0, 1.0, 0.0, 0.0, 0.0, 0.0),
            Direction::Param(Param::Length(0)) => (2.0 * l1 * m2, 0.0, m2, 0.0, m2 * c_2, 0.0),
            Direction::Param(Param::Mass(0)) => (c_1 * c_1, 0.0, c_1, 0.0, 0.0, 1.0),
            Direction::Param(Param::Mass(_)) => (l1 * l1, c_2 * c_2, l1, c_2, l1 * c_2, 1.0),
            Direction::Param(Param::Com(0)) => (2.0 * m1 * c_1, 0.0, m1, 0.0, 0.0, 0.0),
            Direction::Param(Param::Com(_)) => (0.0, 2.0 * m2 * c_2, 0.0, m2, l1 * m2, 0.0),
            _ => (0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
        };
        // `-d/dg` of gravity's `-g h_a sin theta_a` and a loss coefficient's `d Q / d P`.
        let explicit = |dir: Direction, omega: &[f64], r: &mut [f64; 2]| match dir {
            Direction::Param(Param::Gravity) => {
                r[0] -= h1 * s1;
                r[1] -= h2 * s2;
            }
            Direction::Param(p @ (Param::Damping(_) | Param::Friction(_))) => chain.loss_derivative(omega, p, r),
            _ => {}
        };
        match form {
            Form::Lagrangian => {
                let (w1, w2, a1, a2) = (y[2], y[3], dy[2], dy[3]);
                let xdd = if cart.is_some() { dy[5] } else { 0.0 };
                let (kw1, kw2) = (kc * w1 * w1, kc * w2 * w2);
                // What multiplies the derivatives in `-d(M a - F)/dP`, row by row.
                let (k1, k2) = (c12 * a2 + s12 * w2 * w2, c12 * a1 - s12 * w1 * w1);
                for (c, &dir) in dirs.iter().enumerate() {
                    let (col, o) = (&cols[c * m..(c + 1) * m], &mut out[c * m..(c + 1) * m]);
                    let (dt1, dt2, dw1, dw2) = (col[0], col[1], col[2], col[3]);
                    let d12 = dt1 - dt2;
                    let mut r =
                        [g1 * dt1 - (kw2 * d12 + k * s12 * (2.0 * w2 * dw2 - a2 * d12)), g2 * dt2 + (kw1 * d12 + k * s12 * (2.0 * w1 * dw1 + a1 * d12))];
                    if lossy {
                        chain.add_loss_tangent(&y[2..4], &col[2..4], &mut r);
                    }
                    explicit(dir, &y[2..4], &mut r);
                    let (dd1, dd2, dh1, dh2, dk, dtotal) = derivatives(dir);
                    r[0] -= dd1 * a1 - dh1 * f1 + dk * k1;
                    r[1] -= dd2 * a2 - dh2 * f2 + dk * k2;
                    let mut rx = 0.0;
                    if let Some((_, damping)) = cart {
                        // The cart's row `r_x = F - c v + sum h_a sin theta_a w_a^2`.
                        let (dv, (db1, db2)) = (col[5], db(dh1, dh2, dt1, dt2));
                        r[0] -= db1 * xdd;
                        r[1] -= db2 * xdd;
                        rx = (dh1 * s1 + h1 * c1 * dt1) * w1 * w1 + 2.0 * h1 * s1 * w1 * dw1 + (dh2 * s2 + h2 * c2 * dt2) * w2 * w2 + 2.0 * h2 * s2 * w2 * dw2
                            - damping * dv
                            - (db1 * a1 + db2 * a2 + dtotal * xdd);
                        o[4] = dv;
                    }
                    let ([e1, e2], ex) = solve(r, rx);
                    (o[0], o[1], o[2], o[3]) = (dw1, dw2, e1, e2);
                    if cart.is_some() {
                        o[5] = ex;
                    }
                }
            }
            Form::Hamiltonian => {
                let (w1, w2) = (dy[0], dy[1]);
                let v = if cart.is_some() { dy[4] } else { 0.0 };
                let (ks, ww) = (k * s12, w1 * w2);
                for (c, &dir) in dirs.iter().enumerate() {
                    let (col, o) = (&cols[c * m..(c + 1) * m], &mut out[c * m..(c + 1) * m]);
                    let (dt1, dt2, dp1, dp2) = (col[0], col[1], col[2], col[3]);
                    let d12 = dt1 - dt2;
                    let (dd1, dd2, dh1, dh2, dk, dtotal) = derivatives(dir);
                    let (db1, db2) = db(dh1, dh2, dt1, dt2);
                    // The momenta's derivative at fixed rates, `(dM/dP) omega`, comes off first
                    // (with a cart, `p_a` has `b_a v` and `p_x = total v + b . omega`).
                    let dpx = if cart.is_some() { col[5] } else { 0.0 };
                    let ([dw1, dw2], dv) = solve(
                        [dp1 + ks * d12 * w2 - (dd1 * w1 + dk * c12 * w2) - db1 * v, dp2 + ks * d12 * w1 - (dk * c12 * w1 + dd2 * w2) - db2 * v],
                        dpx - (db1 * w1 + db2 * w2 + dtotal * v),
                    );
                    let q = k * (c12 * d12 * ww + s12 * (dw1 * w2 + w1 * dw2));
                    let mut r = [g1 * dt1 - q, g2 * dt2 + q];
                    if lossy {
                        chain.add_loss_tangent(&dy[..2], &[dw1, dw2], &mut r);
                    }
                    explicit(dir, &dy[..2], &mut r);
                    // `p_dot`'s derivative at fixed angles and rates.
                    r[0] += dh1 * f1 - dk * s12 * ww;
                    r[1] += dh2 * f2 + dk * s12 * ww;
                    if let Some((_, damping)) = cart {
                        // `p_dot_a`'s `-h_a sin theta_a v w_a`; `p_x_dot = F - c v`.
                        r[0] -= dh1 * s1 * v * w1 + h1 * (c1 * dt1 * v * w1 + s1 * (dv * w1 + v * dw1));
                        r[1] -= dh2 * s2 * v * w2 + h2 * (c2 * dt2 * v * w2 + s2 * (dv * w2 + v * dw2));
                        (o[4], o[5]) = (dv, -damping * dv);
                    }
                    (o[0], o[1], o[2], o[3]) = (dw1, dw2, r[0], r[1]);
                }
            }
        }
        Ok(())
    }

    /// [`Columns::rates`] by the O(N) recursions.
    #[allow(clippy::too_many_arguments)]
    fn rates_general(
        &mut self,
        chain: &Chain,
        load: &Load,
        y: &[f64],
        dy: &[f64],
        cols: &[f64],
        out: &mut [f64],
        factored: Option<&Workspace>,
    ) -> std::result::Result<(), Singular> {
        let n = chain.n();
        let m = self.mech;
        let cart = chain.cart.is_some();
        let Columns { dirs, sc, shared, ws: own, scratch, rows, .. } = self;
        // The parameters' forcings need their fields; the initial state's directions do not.
        let params = dirs.iter().any(|d| matches!(d, Direction::Param(_)));
        let ws: &Workspace = match factored {
            Some(ws) => ws,
            None => {
                chain.trig(&y[..n], own);
                chain.factor(shared, own)?;
                own
            }
        };
        match self.form {
            Form::Lagrangian => {
                let (omega, accel) = (&y[n..2 * n], &dy[n..2 * n]);
                let x_ddot = if cart { dy[2 * n + 1] } else { 0.0 };
                if params {
                    chain.prepare_forcing(&At::Lagrangian { omega, accel, x_ddot }, load, sc, ws);
                }
                chain.sums(omega, accel, load.gravity, shared, ws);
                for (c, dir) in dirs.iter().enumerate() {
                    let (col, o) = (&cols[c * m..(c + 1) * m], &mut out[c * m..(c + 1) * m]);
                    let forcing = match *dir {
                        Direction::Param(p) => Some(chain.lagrangian_forcing(omega, accel, p, sc)),
                        _ => None,
                    };
                    let dv = if cart { col[2 * n + 1] } else { 0.0 };
                    let (head, tail) = o.split_at_mut(n);
                    head.copy_from_slice(&col[n..2 * n]);
                    rows[c] = chain.tangent_shared_rhs(
                        omega,
                        (accel, x_ddot),
                        (&col[..n], &col[n..2 * n], dv),
                        forcing.map(|bx| (&sc.b[..], bx)),
                        shared,
                        &mut tail[..n],
                        ws,
                    );
                    if cart {
                        o[2 * n] = dv;
                    }
                }
                chain.solve_factored_many(ws, out, (m, n), rows)?;
                if cart {
                    for (c, &dx) in rows.iter().enumerate() {
                        out[c * m + 2 * n + 1] = dx;
                    }
                }
            }
            Form::Hamiltonian => {
                let omega = &dy[..n];
                let v = if cart { dy[2 * n] } else { 0.0 };
                if params {
                    chain.prepare_forcing(&At::Hamiltonian { omega, v }, load, sc, ws);
                }
                chain.hamilton_sums(omega, shared, ws);
                for (c, dir) in dirs.iter().enumerate() {
                    let (col, o) = (&cols[c * m..(c + 1) * m], &mut out[c * m..(c + 1) * m]);
                    let dpx = match *dir {
                        Direction::Param(p) => Some(chain.hamiltonian_forcing(omega, p, sc)),
                        _ => None,
                    };
                    let d_px = if cart { col[2 * n + 1] } else { 0.0 };
                    let (head, tail) = o.split_at_mut(n);
                    rows[c] = chain.hamilton_tangent_rhs(
                        (omega, v),
                        load.gravity,
                        (&col[..n], &col[n..2 * n], d_px),
                        dpx.map(|dpx| (&sc.dp[..], dpx, &sc.dpdot[..])),
                        shared,
                        head,
                        &mut tail[..n],
                        scratch,
                        ws,
                    );
                }
                chain.solve_factored_many(ws, out, (m, 0), rows)?;
                for (c, &dv) in rows.iter().enumerate() {
                    let o = &mut out[c * m..(c + 1) * m];
                    let (head, tail) = o.split_at_mut(n);
                    let (dv, dpxd) = chain.hamilton_tangent_finish((omega, v), dv, shared, head, &mut tail[..n], scratch, ws);
                    if cart {
                        o[2 * n] = dv;
                        o[2 * n + 1] = dpxd;
                    }
                }
            }
        }
        Ok(())
    }

    /// The columns at the start, from `(theta0, omega0, v0)`: unit vectors in the Lagrangian
    /// form; in the Hamiltonian one the momenta's derivatives along each direction (the run is
    /// given rates, so `p0` moves with the angles and the parameters).
    pub fn initial(&mut self, chain: &Chain, load: &Load, theta0: &[f64], omega0: &[f64], v0: f64, out: &mut [f64]) -> std::result::Result<(), Singular> {
        let (n, m, cart) = (chain.n(), self.mech, chain.cart.is_some());
        out.fill(0.0);
        let Columns { dirs, sc, ws, scratch, zero, .. } = self;
        if self.form == Form::Hamiltonian {
            chain.trig(theta0, ws);
            chain.prepare_forcing(&At::Hamiltonian { omega: omega0, v: v0 }, load, sc, ws);
        }
        let mut unit = vec![0.0; n];
        for (c, dir) in dirs.iter().enumerate() {
            let o = &mut out[c * m..(c + 1) * m];
            match (self.form, *dir) {
                (Form::Lagrangian, Direction::Theta(j)) => o[j] = 1.0,
                (Form::Lagrangian, Direction::Omega(j)) => o[n + j] = 1.0,
                (Form::Lagrangian, Direction::Param(_)) => {}
                (Form::Hamiltonian, Direction::Param(p)) => {
                    let dpx = chain.hamiltonian_forcing(omega0, p, sc);
                    o[n..2 * n].copy_from_slice(&sc.dp);
                    if cart {
                        o[2 * n + 1] = dpx;
                    }
                }
                (Form::Hamiltonian, Direction::Theta(j) | Direction::Omega(j)) => {
                    unit.fill(0.0);
                    unit[j] = 1.0;
                    let (dth, dw) = if matches!(dir, Direction::Theta(_)) { (&unit[..], &zero[..]) } else { (&zero[..], &unit[..]) };
                    if let Direction::Theta(_) = dir {
                        o[j] = 1.0;
                    }
                    let (head, tail) = o.split_at_mut(2 * n);
                    let dpx = chain.momenta_tangent(theta0, (omega0, v0), (dth, dw, 0.0), &mut head[n..], scratch, ws)?;
                    if cart {
                        tail[1] = dpx;
                    }
                }
            }
        }
        Ok(())
    }

    /// The columns as derivatives of `(theta, omega, (x, v))` into `out` (row-major: state
    /// entry, then column), from the integrated ones at the mechanical state `y` (in the
    /// Hamiltonian form `(theta, p, (x, p_x))`, turned into rates through the tangent of
    /// `omega = M^-1 p`).
    pub fn output(&mut self, chain: &Chain, load: &Load, y: &[f64], cols: &[f64], out: &mut [f64]) -> std::result::Result<(), Singular> {
        let (n, m, k, cart) = (chain.n(), self.mech, self.dirs.len(), chain.cart.is_some());
        if self.form == Form::Lagrangian {
            for c in 0..k {
                for i in 0..m {
                    out[i * k + c] = cols[c * m + i];
                }
            }
            return Ok(());
        }
        let Columns { dirs, sc, ws, scratch, .. } = self;
        let (theta, p) = (&y[..n], &y[n..2 * n]);
        let px = if cart { y[2 * n + 1] } else { 0.0 };
        let mut omega = vec![0.0; n];
        let v = chain.velocities_general(theta, p, px, &mut omega, ws)?;
        chain.prepare_forcing(&At::Hamiltonian { omega: &omega, v }, load, sc, ws);
        let (mut d_omega, mut junk) = (vec![0.0; n], vec![0.0; n]);
        for (c, dir) in dirs.iter().enumerate() {
            let col = &cols[c * m..(c + 1) * m];
            let dpx = match *dir {
                Direction::Param(q) => Some(chain.hamiltonian_forcing(&omega, q, sc)),
                _ => None,
            };
            let d_px = if cart { col[2 * n + 1] } else { 0.0 };
            let (dv, _) = chain.hamilton_tangent_forced(
                theta,
                (&omega, v),
                load.gravity,
                (&col[..n], &col[n..2 * n], d_px),
                dpx.map(|dpx| (&sc.dp[..], dpx, &sc.dpdot[..])),
                &mut d_omega,
                &mut junk,
                scratch,
                ws,
            )?;
            for i in 0..n {
                out[i * k + c] = col[i];
                out[(n + i) * k + c] = d_omega[i];
            }
            if cart {
                out[2 * n * k + c] = col[2 * n];
                out[(2 * n + 1) * k + c] = dv;
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::Cart;

    fn chains() -> Vec<Chain> {
        let base = Chain::new(&[1.0, 0.7, 1.3], &[1.2, 0.8, 0.5], Some(&[0.6, 0.3, 0.9]), Some(&[0.05, 0.02, 0.1]), 9.81).unwrap();
        vec![
            base.clone(),
            base.clone().with_losses(&[0.3, 0.2, 0.1], &[0.05, 0.03, 0.02], 0.5).unwrap(),
            base.clone().with_cart(Some(Cart::new(2.0, 0.4).unwrap())).unwrap(),
        ]
    }

    /// The chain with `param` moved by `eps`, rebuilt through the public constructors.
    fn moved(chain: &Chain, param: Param, eps: f64) -> Chain {
        let (mut l, mut m, mut c, mut i) = (chain.lengths.clone(), chain.masses.clone(), chain.com.clone(), chain.inertia.clone());
        let (mut g, mut b, mut f) = (chain.g, chain.joints.damping.clone(), chain.joints.friction.clone());
        match param {
            Param::Length(j) => l[j] += eps,
            Param::Mass(j) => m[j] += eps,
            Param::Com(j) => c[j] += eps,
            Param::Inertia(j) => i[j] += eps,
            Param::Gravity => g += eps,
            Param::Damping(j) => b[j] += eps,
            Param::Friction(j) => f[j] += eps,
        }
        let mut out = Chain::new(&l, &m, Some(&c), Some(&i), g).unwrap();
        if chain.lossy_joints() {
            out = out.with_losses(&b, &f, chain.joints.friction_velocity).unwrap();
        }
        if let Some(cart) = chain.cart {
            out = out.with_cart(Some(cart)).unwrap();
        }
        out
    }

    /// Every parameter; the losses' only on the lossy chain (whose damping and friction are
    /// positive, so central differences stay valid chains).
    fn params(chain: &Chain) -> Vec<Param> {
        let mut v = vec![Param::Gravity];
        for j in 0..chain.n() {
            v.extend([Param::Length(j), Param::Mass(j), Param::Com(j), Param::Inertia(j)]);
            if chain.lossy_joints() {
                v.extend([Param::Damping(j), Param::Friction(j)]);
            }
        }
        v
    }

    #[test]
    fn lagrangian_forcings_match_central_differences_of_the_accelerations() {
        let (theta, omega, v) = ([0.4, -1.1, 2.0], [0.7, -0.3, 1.5], 0.35);
        let tau = [0.2, -0.1, 0.05];
        for chain in chains() {
            let n = chain.n();
            let load = Load::still(&chain);
            let mut ws = Workspace::new(n);
            let mut acc = vec![0.0; n];
            let r = chain.accelerations_general(&theta, &omega, v, &tau, &load, &mut acc, &mut ws).unwrap();
            let mut sc = Scratch::new(&chain);
            chain.trig(&theta, &mut ws);
            chain.prepare_forcing(&At::Lagrangian { omega: &omega, accel: &acc, x_ddot: r.cart }, &load, &mut sc, &ws);
            for p in params(&chain) {
                let bx = chain.lagrangian_forcing(&omega, &acc, p, &mut sc);
                let b = sc.b.clone();
                let mut d = vec![0.0; n];
                let zero = vec![0.0; n];
                let mut sh = Shared::new(n);
                chain.share(&omega, &acc, load.gravity, &mut sh, &mut ws).unwrap();
                let dx = chain.tangent_shared(&omega, (&acc, r.cart), (&zero, &zero, 0.0), Some((&b, bx)), &sh, &mut d, &ws).unwrap();
                let eps = 1e-6;
                let at = |e: f64| {
                    let c = moved(&chain, p, e);
                    let mut out = vec![0.0; n];
                    let r = c.accelerations_general(&theta, &omega, v, &tau, &Load::still(&c), &mut out, &mut Workspace::new(n)).unwrap();
                    (out, r.cart)
                };
                let ((hi, xh), (lo, xl)) = (at(eps), at(-eps));
                for a in 0..n {
                    let fd = (hi[a] - lo[a]) / (2.0 * eps);
                    assert!((d[a] - fd).abs() < 1e-6 * (1.0 + fd.abs()), "{p:?} row {a}: {} vs {fd}", d[a]);
                }
                let fd = (xh - xl) / (2.0 * eps);
                assert!((dx - fd).abs() < 1e-6 * (1.0 + fd.abs()), "{p:?} cart: {dx} vs {fd}");
            }
        }
    }

    #[test]
    fn the_shared_tangents_are_the_general_ones() {
        // Both forms; the Hamiltonian along a direction of the state alone and with a
        // parameter's forcing on top.
        let (theta, omega, v) = ([0.4, -1.1, 2.0], [0.7, -0.3, 1.5], 0.35);
        let (dth, dw, dv) = ([0.2, -0.5, 0.3], [0.1, 0.4, -0.6], 0.7);
        let close = |got: f64, want: f64| (got - want).abs() < 1e-13 * want.abs().max(1.0);
        for chain in chains() {
            let n = chain.n();
            let load = Load { gravity: [1.3, -9.0], cart_force: 0.5 };
            let mut ws = Workspace::new(n);
            let mut scratch = vec![0.0; TANGENT_SCRATCH * n];
            let mut acc = vec![0.0; n];
            let r = chain.accelerations_general(&theta, &omega, v, &[0.2, 0.0, -0.1], &load, &mut acc, &mut ws).unwrap();
            let (mut want, mut got) = (vec![0.0; n], vec![0.0; n]);
            let dx0 = chain.tangent_general(&theta, &omega, (&acc, r.cart), &load, (&dth, &dw, dv), &mut want, &mut scratch, &mut ws).unwrap();
            chain.trig(&theta, &mut ws);
            let mut sh = Shared::new(n);
            chain.share(&omega, &acc, load.gravity, &mut sh, &mut ws).unwrap();
            let dx = chain.tangent_shared(&omega, (&acc, r.cart), (&dth, &dw, dv), None, &sh, &mut got, &ws).unwrap();
            for a in 0..n {
                assert!(close(got[a], want[a]), "{a}: {} vs {}", got[a], want[a]);
            }
            assert!(close(dx, dx0));

            // The Hamiltonian form, the same numbers as momenta.
            let (dp, dpx) = (dw, dv);
            let mut sc = Scratch::new(&chain);
            chain.prepare_forcing(&At::Hamiltonian { omega: &omega, v }, &load, &mut sc, &ws);
            for param in [None, Some(Param::Length(1)), Some(Param::Gravity)] {
                let forcing = param.map(|p| {
                    let bx = chain.hamiltonian_forcing(&omega, p, &mut sc);
                    (sc.dp.clone(), bx, sc.dpdot.clone())
                });
                let forcing = forcing.as_ref().map(|(a, b, c)| (&a[..], *b, &c[..]));
                let (mut w0, mut pd0, mut w1, mut pd1) = (vec![0.0; n], vec![0.0; n], vec![0.0; n], vec![0.0; n]);
                let want = chain
                    .hamilton_tangent_forced(&theta, (&omega, v), load.gravity, (&dth, &dp, dpx), forcing, &mut w0, &mut pd0, &mut scratch, &mut ws)
                    .unwrap();
                chain.hamilton_share(&omega, &mut sh, &mut ws).unwrap();
                let mut row = [chain.hamilton_tangent_rhs((&omega, v), load.gravity, (&dth, &dp, dpx), forcing, &sh, &mut w1, &mut pd1, &mut scratch, &ws)];
                chain.solve_factored_many(&ws, &mut w1, (0, 0), &mut row).unwrap();
                let got = chain.hamilton_tangent_finish((&omega, v), row[0], &sh, &w1, &mut pd1, &mut scratch, &ws);
                for a in 0..n {
                    assert!(close(w1[a], w0[a]), "{param:?} d omega {a}: {} vs {}", w1[a], w0[a]);
                    assert!(close(pd1[a], pd0[a]), "{param:?} d p_dot {a}: {} vs {}", pd1[a], pd0[a]);
                }
                assert!(close(got.0, want.0) && close(got.1, want.1));
            }
        }
    }

    #[test]
    fn columns_reusing_the_systems_factorisation_keep_their_bits() {
        use crate::dynamics::system::{ChainSystem, OdeSystem};
        use crate::dynamics::torque::Builtin;
        // Every path that leaves its factorisation (N = 3: the ideal, the lossy and the cart's
        // recursions, both forms; N = 2 in the Hamiltonian form) and those that leave the trig only (N = 2
        // in the Lagrangian form, on a cart and not).
        let two = Chain::new(&[1.0, 0.7], &[1.2, 0.8], Some(&[0.6, 0.3]), Some(&[0.05, 0.02]), 9.81).unwrap();
        let two_on_cart = two.clone().with_cart(Some(Cart::new(2.0, 0.4).unwrap())).unwrap();
        for chain in chains().into_iter().chain([two, two_on_cart]) {
            let n = chain.n();
            for form in Form::ALL {
                let mut sys = ChainSystem::new(&chain, Builtin::None, form);
                let b = sys.dim();
                let y: Vec<f64> = (0..b).map(|i| [0.4, -1.1, 2.0, 0.7, -0.3, 1.5, 0.2, -0.6][i % 8]).collect();
                let mut dy = vec![0.0; b];
                sys.rhs(0.0, &y, &mut dy).unwrap();
                let dirs = directions(&[Input::Theta0, Input::Omega0, Input::Lengths, Input::G], n).unwrap();
                let mut cols = Columns::new(&chain, form, dirs);
                let s: Vec<f64> = (0..cols.len()).map(|i| ((i * 7 % 11) as f64 - 5.0) / 3.0).collect();
                let (mut reused, mut own) = (vec![0.0; cols.len()], vec![0.0; cols.len()]);
                let load = sys.last_load();
                let evaluated = sys.evaluated();
                assert_eq!(matches!(evaluated, Evaluated::Factored(_)), form == Form::Hamiltonian || n != 2);
                cols.rates(&chain, &load, &y, &dy, &s, &mut reused, evaluated).unwrap();
                cols.rates(&chain, &load, &y, &dy, &s, &mut own, Evaluated::Nothing).unwrap();
                let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                assert_eq!(bits(&reused), bits(&own), "N = {n}, {form:?}, cart {}", chain.cart.is_some());
            }
        }
    }

    #[test]
    fn the_double_pendulums_closed_form_columns_are_the_recursions() {
        // Both forms, every input (the losses' on the lossy chains), under gravity with a sideways
        // part (a pivot's acceleration; with a cart, the cart's force instead), at a state where
        // every term of the tangent is nonzero; with and without a cart, lossy and not.
        let two = Chain::new(&[1.0, 0.7], &[1.2, 0.8], Some(&[0.6, 0.3]), Some(&[0.05, 0.02]), 9.81).unwrap();
        let lossy = two.clone().with_losses(&[0.3, 0.2], &[0.05, 0.03], 0.5).unwrap();
        let on_cart = |c: &Chain| c.clone().with_cart(Some(Cart::new(2.0, 0.4).unwrap())).unwrap();
        let (theta, omega, tau, v) = ([0.4, -1.1], [0.7, -0.3], [0.2, -0.1], 0.35);
        for chain in [two.clone(), lossy.clone(), on_cart(&two), on_cart(&lossy)] {
            let cart = chain.cart.is_some();
            let load = if cart { Load { gravity: [0.0, -9.0], cart_force: 0.5 } } else { Load { gravity: [1.3, -9.0], cart_force: 0.0 } };
            let mut inputs = vec![Input::Theta0, Input::Omega0, Input::Lengths, Input::Masses, Input::Com, Input::Inertia, Input::G];
            if chain.lossy_joints() {
                inputs.extend([Input::Damping, Input::Friction]);
            }
            let v = if cart { v } else { 0.0 };
            let mut accel = [0.0; 2];
            let rates = chain.accelerations_general(&theta, &omega, v, &tau, &load, &mut accel, &mut Workspace::new(2)).unwrap();
            let mut p = [0.0; 2];
            let p_x = chain.momenta_general(&theta, &omega, v, &mut p, &mut Workspace::new(2));
            for form in Form::ALL {
                // The state and its rates: (theta, omega, [x, v]) and (omega, accel, [v,
                // x_ddot]), or (theta, p, [x, p_x]) and (omega, p_dot, [v, p_x_dot]) (whose
                // p_dot the columns do not read).
                let (mut y, mut dy) = match form {
                    Form::Lagrangian => (vec![theta[0], theta[1], omega[0], omega[1]], vec![omega[0], omega[1], accel[0], accel[1]]),
                    Form::Hamiltonian => (vec![theta[0], theta[1], p[0], p[1]], vec![omega[0], omega[1], f64::NAN, f64::NAN]),
                };
                if cart {
                    match form {
                        Form::Lagrangian => (y.extend([0.2, v]), dy.extend([v, rates.cart])),
                        Form::Hamiltonian => (y.extend([0.2, p_x]), dy.extend([v, f64::NAN])),
                    };
                }
                let mut cols = Columns::new(&chain, form, directions(&inputs, 2).unwrap());
                let s: Vec<f64> = (0..cols.len()).map(|i| ((i * 7 % 11) as f64 - 5.0) / 3.0).collect();
                let (mut closed, mut general) = (vec![0.0; cols.len()], vec![0.0; cols.len()]);
                cols.rates_double(&chain, &load, &y, &dy, &s, &mut closed, Evaluated::Nothing).unwrap();
                cols.rates_general(&chain, &load, &y, &dy, &s, &mut general, None).unwrap();
                for (i, (a, b)) in closed.iter().zip(&general).enumerate() {
                    assert!((a - b).abs() <= 1e-13 * b.abs().max(1.0), "{form:?}, cart {cart}, value {i}: {a} vs {b}");
                }
            }
        }
    }

    #[test]
    fn hamiltonian_forcings_match_central_differences_of_hamiltons_equations() {
        let (theta, p, px) = ([0.4, -1.1, 2.0], [0.7, -0.3, 1.5], 0.8);
        for chain in chains() {
            let n = chain.n();
            let load = Load::pivot(&chain, [0.0, 0.0]);
            let eval = |c: &Chain| {
                let (mut om, mut pd) = (vec![0.0; n], vec![0.0; n]);
                let r = c
                    .hamilton_general(&theta, &p, px, &mut om, &mut pd, [0.0, -c.g], &mut Workspace::new(n), |_, _, out| {
                        out.fill(0.0);
                        Ok::<f64, ()>(0.0)
                    })
                    .unwrap()
                    .unwrap();
                (om, pd, r.cart, r.cart_momentum_rate)
            };
            let (omega, _, v, _) = eval(&chain);
            let mut ws = Workspace::new(n);
            let mut sc = Scratch::new(&chain);
            chain.trig(&theta, &mut ws);
            chain.prepare_forcing(&At::Hamiltonian { omega: &omega, v }, &load, &mut sc, &ws);
            for q in params(&chain) {
                let dpx = chain.hamiltonian_forcing(&omega, q, &mut sc);
                let (dp, dpdot) = (sc.dp.clone(), sc.dpdot.clone());
                let zero = vec![0.0; n];
                let (mut d_om, mut d_pd, mut scratch) = (vec![0.0; n], vec![0.0; n], vec![0.0; 8 * n]);
                let (dv, _) = chain
                    .hamilton_tangent_forced(
                        &theta,
                        (&omega, v),
                        load.gravity,
                        (&zero, &zero, 0.0),
                        Some((&dp, dpx, &dpdot)),
                        &mut d_om,
                        &mut d_pd,
                        &mut scratch,
                        &mut ws,
                    )
                    .unwrap();
                let eps = 1e-6;
                let (hi, lo) = (eval(&moved(&chain, q, eps)), eval(&moved(&chain, q, -eps)));
                for a in 0..n {
                    let fo = (hi.0[a] - lo.0[a]) / (2.0 * eps);
                    let fp = (hi.1[a] - lo.1[a]) / (2.0 * eps);
                    assert!((d_om[a] - fo).abs() < 1e-6 * (1.0 + fo.abs()), "{q:?} omega {a}: {} vs {fo}", d_om[a]);
                    assert!((d_pd[a] - fp).abs() < 1e-6 * (1.0 + fp.abs()), "{q:?} p_dot {a}: {} vs {fp}", d_pd[a]);
                }
                let fv = (hi.2 - lo.2) / (2.0 * eps);
                assert!((dv - fv).abs() < 1e-6 * (1.0 + fv.abs()), "{q:?} v: {dv} vs {fv}");
            }
        }
    }

    #[test]
    fn momenta_tangents_match_central_differences() {
        let (theta, omega) = ([0.4, -1.1, 2.0], [0.7, -0.3, 1.5]);
        for chain in chains() {
            let (n, cart) = (chain.n(), chain.cart.is_some());
            let v = if cart { 0.35 } else { 0.0 };
            let mut ws = Workspace::new(n);
            for j in 0..2 * n + usize::from(cart) {
                let (mut dth, mut dw, mut dv) = (vec![0.0; n], vec![0.0; n], 0.0);
                match j {
                    j if j < n => dth[j] = 1.0,
                    j if j < 2 * n => dw[j - n] = 1.0,
                    _ => dv = 1.0,
                }
                let mut dp = vec![0.0; n];
                let dpx = chain.momenta_tangent(&theta, (&omega, v), (&dth, &dw, dv), &mut dp, &mut vec![0.0; 8 * n], &mut ws).unwrap();
                let eps = 1e-6;
                let at = |e: f64| {
                    let th: Vec<f64> = (0..n).map(|a| theta[a] + e * dth[a]).collect();
                    let om: Vec<f64> = (0..n).map(|a| omega[a] + e * dw[a]).collect();
                    let mut p = vec![0.0; n];
                    let px = chain.momenta_general(&th, &om, v + e * dv, &mut p, &mut Workspace::new(n));
                    (p, px)
                };
                let ((hi, hx), (lo, lx)) = (at(eps), at(-eps));
                for a in 0..n {
                    let fd = (hi[a] - lo[a]) / (2.0 * eps);
                    assert!((dp[a] - fd).abs() < 1e-7 * (1.0 + fd.abs()), "dir {j} p {a}: {} vs {fd}", dp[a]);
                }
                if chain.cart.is_some() {
                    let fd = (hx - lx) / (2.0 * eps);
                    assert!((dpx - fd).abs() < 1e-7 * (1.0 + fd.abs()), "dir {j} p_x: {dpx} vs {fd}");
                }
            }
        }
    }
}
