//! The ideal chain's accelerations for many states at once, in lanes (structure of arrays:
//! `theta[link][lane]`): plain loops over fixed-size arrays that LLVM vectorises across states.
//! The arithmetic is [`Chain::accelerations_into`]'s: the closed form of two links, the O(N)
//! recursion (`eliminate`, `substitute`) otherwise, its terms regrouped so that one link's
//! division waits on the one below through a single fused multiply-add (`recursion`); three
//! links without a cart in a closed form of their own, by the adjugate ([`triple`]: one
//! division where the recursion takes two, and no passes over the links). With
//! the lanes' fdlibm `sin`/`cos` ([`crate::trig::lanes`], within 1 ulp of glibc's) and, as the
//! flip kernel does, its product-sums fused by explicit `mul_add` (one correctly rounded
//! operation: a hardware FMA on the AVX paths, glibc's exact `fma()` on the portable one, so
//! every path gives the same bits).
//! A state therefore agrees with the per-state route to round-off, not bit for bit.
use super::general::saturating_tanh;
use super::{Singular, PIVOT_TOL};
use crate::model::Chain;
use crate::trig::lanes::{sin_cos, Lane, LANES};

/// Per-link lanes the recursion keeps between its passes.
#[derive(Debug, Clone)]
pub struct LaneScratch {
    sin: Vec<Lane>,
    cos: Vec<Lane>,
    /// Per link, the elimination's `u / pivot` (x and y) and `1 / pivot`.
    uxi: Vec<Lane>,
    uyi: Vec<Lane>,
    dinv: Vec<Lane>,
    /// `sin` and `cos` hold the angles' trig already ([`LaneScratch::trig_of`]): the next
    /// accelerations take it instead of computing it again (and clear this).
    known: bool,
    /// A tangent follows at these angles ([`tangent`]): the accelerations leave the angles'
    /// trig and the triple pendulum's adjugate here for it. Without one they are dead stores,
    /// a tenth of the stores of the triple pendulum's rk4 step, and are skipped.
    pub(crate) for_tangent: bool,
    /// The triple pendulum's closed form ([`triple`]): its mass matrix's cofactors `C_11, C_12,
    /// C_13, C_22, C_23, C_33` and `1 / det`, for the tangent's solve.
    adjugate: [Lane; 7],
}

impl LaneScratch {
    pub fn new(n: usize) -> Self {
        let z = vec![[0.0; LANES]; n];
        LaneScratch { sin: z.clone(), cos: z.clone(), uxi: z.clone(), uyi: z.clone(), dinv: z, known: false, for_tangent: false, adjugate: [[0.0; LANES]; 7] }
    }

    /// The angles' `sin` and `cos`, computed once for the forces of a moving pivot and the
    /// accelerations that must follow at the same angles ([`accelerations_on`] takes them
    /// instead of computing them again: the same values, the same bits).
    #[inline(always)]
    pub fn trig_of(&mut self, theta: &[Lane]) -> (&[Lane], &[Lane]) {
        for (a, th) in theta.iter().enumerate() {
            (self.sin[a], self.cos[a]) = sin_cos(th);
        }
        self.known = true;
        (&self.sin[..theta.len()], &self.cos[..theta.len()])
    }
}

/// Active lanes whose mass matrix failed the pivot test, and the first link that failed.
#[derive(Debug, Clone, Copy)]
pub struct LaneSingular {
    pub link: Singular,
    pub lanes: [bool; LANES],
    /// The failed lanes whose state was not finite: a blow-up, not a singular configuration
    /// (set by the integrators, which know the stage's state: [`LaneSingular::seen_in`]).
    pub nonfinite: [bool; LANES],
}

impl LaneSingular {
    /// Marks the failed lanes whose stage state `y` is not finite.
    #[inline(always)]
    pub fn seen_in(mut self, y: &[Lane]) -> Self {
        for i in 0..LANES {
            self.nonfinite[i] = self.lanes[i] && y.iter().any(|v| !v[i].is_finite());
        }
        self
    }

    /// Why lane `i` failed, as the scalar route says it ([`crate::dynamics::system::singular`]).
    pub fn reason(&self, i: usize) -> String {
        if self.nonfinite[i] {
            crate::dynamics::system::NON_FINITE.to_string()
        } else {
            self.link.reason()
        }
    }
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
    accelerations_on(chain, theta, omega, tau, out, s, active, None)
}

/// The cart's input and output in lanes: the horizontal force on it (the applied force less its
/// damping's), and `x_ddot` written.
pub struct CartLanes<'a> {
    pub force: &'a Lane,
    pub x_ddot: &'a mut Lane,
}

/// [`accelerations`], of a chain on a cart if `cart` is given (the base sliding along x, the
/// cart first among the coordinates): `theta_ddot` into `out` and the cart's acceleration into
/// `cart.x_ddot`, as [`Chain::accelerations_general`] with a cart: the elimination's articulated
/// inertia at the base closes the cart's row, the substitution starts from its acceleration.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub fn accelerations_on(
    chain: &Chain,
    theta: &[Lane],
    omega: &[Lane],
    tau: &[Lane],
    out: &mut [Lane],
    s: &mut LaneScratch,
    active: &Lane,
    cart: Option<CartLanes>,
) -> Result<(), LaneSingular> {
    match (chain.n(), &cart) {
        (2, _) => double(chain, theta, omega, tau, out, s, active, cart),
        (3, None) => triple(chain, theta, omega, tau, out, s, active),
        _ => recursion(chain, theta, omega, tau, out, s, active, cart),
    }
}

/// The verdict of the pivot tests: `worst` holds, per lane, the first link (from the bottom)
/// whose test an active lane failed, or -1. Lanes of f64, not of `bool`: bytes in memory between
/// the loops cost the generic double pendulum's lanes a fifth of their time in mask conversions.
#[inline(always)]
fn verdict(worst: &Lane) -> Result<(), LaneSingular> {
    // Whether every lane passed (all -1: every sign bit set), the sign bits ANDed together (a
    // test per lane, `any |= w >= 0`, compiled to eight scalar comparisons and branches); the
    // first link only where one failed.
    let mut signs = u64::MAX;
    for w in worst {
        signs &= w.to_bits();
    }
    if signs >> 63 == 1 {
        return Ok(());
    }
    let first = worst.iter().fold(-1.0f64, |a, &w| if w > a { w } else { a });
    Err(LaneSingular { link: Singular(first as usize), lanes: std::array::from_fn(|i| worst[i] >= 0.0), nonfinite: [false; LANES] })
}

/// [`Chain::accelerations_double`] in lanes.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn double(
    chain: &Chain,
    theta: &[Lane],
    omega: &[Lane],
    tau: &[Lane],
    out: &mut [Lane],
    s: &mut LaneScratch,
    active: &Lane,
    cart: Option<CartLanes>,
) -> Result<(), LaneSingular> {
    let (d1, d2, h1, h2, g) = (chain.diag[0], chain.diag[1], chain.h[0], chain.h[1], chain.g);
    let k = chain.lengths[0] * h2;
    let tol = PIVOT_TOL * d1 * d2;
    let ((s1, c1), (s2, c2)) =
        if std::mem::take(&mut s.known) { ((s.sin[0], s.cos[0]), (s.sin[1], s.cos[1])) } else { (sin_cos(&theta[0]), sin_cos(&theta[1])) };
    if s.for_tangent {
        (s.sin[0], s.cos[0], s.sin[1], s.cos[1]) = (s1, c1, s2, c2);
    }
    let mut worst = [-1.0f64; LANES];
    let (mut a0, mut a1, mut xdd) = ([0.0; LANES], [0.0; LANES], [0.0; LANES]);
    let total = chain.cart.map_or(0.0, |c| c.mass) + chain.total_mass();
    let (gh1, gh2, d1d2) = (g * h1, g * h2, d1 * d2);
    for i in 0..LANES {
        let (s12, c12) = (s1[i].mul_add(c2[i], -(c1[i] * s2[i])), c1[i].mul_add(c2[i], s1[i] * s2[i]));
        let r1 = (-gh1).mul_add(s1[i], tau[0][i]) - k * s12 * omega[1][i] * omega[1][i];
        let r2 = (-gh2).mul_add(s2[i], tau[1][i]) + k * s12 * omega[0][i] * omega[0][i];
        let kc = k * c12;
        let det = (-kc).mul_add(kc, d1d2);
        let mut good = det > tol;
        let inv = 1.0 / det;
        a0[i] = d2.mul_add(r1, -(kc * r2)) * inv;
        a1[i] = d1.mul_add(r2, -(kc * r1)) * inv;
        if let Some(c) = &cart {
            // theta_ddot = A^-1 (r - b x_ddot), b = h cos(theta); the cart's row closes it
            // (its Schur complement), as `accelerations_general_double`.
            let (b1, b2) = (h1 * c1[i], h2 * c2[i]);
            let (z1, z2) = (d2.mul_add(b1, -(kc * b2)) * inv, d1.mul_add(b2, -(kc * b1)) * inv);
            let schur = total - (b1 * z1 + b2 * z2);
            good &= schur > PIVOT_TOL * total;
            let (w1, w2) = (omega[0][i], omega[1][i]);
            let rx = c.force[i] + h1 * s1[i] * w1 * w1 + h2 * s2[i] * w2 * w2;
            let x = (rx - (b1 * a0[i] + b2 * a1[i])) / schur;
            a0[i] -= z1 * x;
            a1[i] -= z2 * x;
            xdd[i] = x;
        }
        worst[i] = if (active[i] > 0.0) & !good { 0.0 } else { -1.0 };
    }
    (out[0], out[1]) = (a0, a1);
    if let Some(c) = cart {
        *c.x_ddot = xdd;
    }
    verdict(&worst)
}

/// The triple pendulum (no cart) in closed form: the 3 x 3 mass matrix `K_ab cos(theta_a -
/// theta_b)` (`K_aa` the diagonal, `K_ab = l_a h_b` for `a < b`) solved by its adjugate, one
/// division, where the recursion takes two and its passes over the links. The pivot tests are
/// the recursion's, multiplied out: its second link's pivot is `C_11 / d_3` and its first's
/// `det / C_11` (`C` the cofactors), each against `PIVOT_TOL` times the link's `d`, the lower
/// link failing first. The adjugate and `1 / det` stay in the scratch for the tangent's solve.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn triple(chain: &Chain, theta: &[Lane], omega: &[Lane], tau: &[Lane], out: &mut [Lane], s: &mut LaneScratch, active: &Lane) -> Result<(), LaneSingular> {
    let (d1, d2, d3, g) = (chain.diag[0], chain.diag[1], chain.diag[2], chain.g);
    let (l, h) = (&chain.lengths, &chain.h);
    let (k12, k13, k23) = (l[0] * h[1], l[0] * h[2], l[1] * h[2]);
    let (gh1, gh2, gh3) = (g * h[0], g * h[1], g * h[2]);
    let (tol2, tol1) = (PIVOT_TOL * d2 * d3, PIVOT_TOL * d1);
    let ([s1, s2, s3], [c1, c2, c3]) = if std::mem::take(&mut s.known) {
        ([s.sin[0], s.sin[1], s.sin[2]], [s.cos[0], s.cos[1], s.cos[2]])
    } else {
        let [(s1, c1), (s2, c2), (s3, c3)] = [sin_cos(&theta[0]), sin_cos(&theta[1]), sin_cos(&theta[2])];
        if s.for_tangent {
            s.sin[..3].copy_from_slice(&[s1, s2, s3]);
            s.cos[..3].copy_from_slice(&[c1, c2, c3]);
        }
        ([s1, s2, s3], [c1, c2, c3])
    };
    let ([w1, w2, w3], [t1, t2, t3]) = ([omega[0], omega[1], omega[2]], [tau[0], tau[1], tau[2]]);
    let mut worst = [-1.0f64; LANES];
    let (mut a1, mut a2, mut a3) = ([0.0; LANES], [0.0; LANES], [0.0; LANES]);
    let mut adj = [[0.0; LANES]; 7];
    for i in 0..LANES {
        let (s12, c12) = (s1[i].mul_add(c2[i], -(c1[i] * s2[i])), c1[i].mul_add(c2[i], s1[i] * s2[i]));
        let (s13, c13) = (s1[i].mul_add(c3[i], -(c1[i] * s3[i])), c1[i].mul_add(c3[i], s1[i] * s3[i]));
        let (s23, c23) = (s2[i].mul_add(c3[i], -(c2[i] * s3[i])), c2[i].mul_add(c3[i], s2[i] * s3[i]));
        let (q1, q2, q3) = (w1[i] * w1[i], w2[i] * w2[i], w3[i] * w3[i]);
        let (p12, p13, p23) = (k12 * s12, k13 * s13, k23 * s23);
        let r1 = (-gh1).mul_add(s1[i], t1[i]) - p12.mul_add(q2, p13 * q3);
        let r2 = (-gh2).mul_add(s2[i], t2[i]) + p12.mul_add(q1, -(p23 * q3));
        let r3 = (-gh3).mul_add(s3[i], t3[i]) + p13.mul_add(q1, p23 * q2);
        let (m12, m13, m23) = (k12 * c12, k13 * c13, k23 * c23);
        let c11 = (-m23).mul_add(m23, d2 * d3);
        let c22 = (-m13).mul_add(m13, d1 * d3);
        let c33 = (-m12).mul_add(m12, d1 * d2);
        let c12 = m13.mul_add(m23, -(m12 * d3));
        let c13 = m12.mul_add(m23, -(m13 * d2));
        let c23 = m12.mul_add(m13, -(d1 * m23));
        let det = d1.mul_add(c11, m12.mul_add(c12, m13 * c13));
        let inv = 1.0 / det;
        [a1[i], a2[i], a3[i]] = solve3([c11, c12, c13, c22, c23, c33], inv, [r1, r2, r3]);
        let on = active[i] > 0.0;
        let second = c11 > tol2;
        worst[i] = if on & !second {
            1.0
        } else if on & !(det > tol1 * c11) {
            0.0
        } else {
            -1.0
        };
        (adj[0][i], adj[1][i], adj[2][i], adj[3][i], adj[4][i], adj[5][i], adj[6][i]) = (c11, c12, c13, c22, c23, c33, inv);
    }
    (out[0], out[1], out[2]) = (a1, a2, a3);
    if s.for_tangent {
        s.adjugate = adj;
    }
    verdict(&worst)
}

/// `A^-1 r` of a symmetric 3 x 3 `A` from its cofactors `C_11, C_12, C_13, C_22, C_23, C_33` and
/// `1 / det A` (the triple pendulum's accelerations and their tangent).
#[inline(always)]
fn solve3([c11, c12, c13, c22, c23, c33]: [f64; 6], inv: f64, [r1, r2, r3]: [f64; 3]) -> [f64; 3] {
    [c11.mul_add(r1, c12.mul_add(r2, c13 * r3)) * inv, c12.mul_add(r1, c22.mul_add(r2, c23 * r3)) * inv, c13.mul_add(r1, c23.mul_add(r2, c33 * r3)) * inv]
}

/// [`Chain::accelerations_impl`] (with `eliminate` and `substitute`) in lanes.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn recursion(
    chain: &Chain,
    theta: &[Lane],
    omega: &[Lane],
    tau: &[Lane],
    out: &mut [Lane],
    s: &mut LaneScratch,
    active: &Lane,
    cart: Option<CartLanes>,
) -> Result<(), LaneSingular> {
    let n = theta.len();
    let (l, h, d, g) = (&chain.lengths[..n], &chain.h[..n], &chain.diag[..n], chain.g);
    if !std::mem::take(&mut s.known) {
        for a in 0..n {
            (s.sin[a], s.cos[a]) = sin_cos(&theta[a]);
        }
    }
    // Gravity and the centripetal pull of the links above.
    let (mut cu, mut su) = ([0.0; LANES], [0.0; LANES]);
    for a in 0..n {
        let (sa, ca, ta, w, ha, la) = (s.sin[a], s.cos[a], tau[a], omega[a], h[a], l[a]);
        let mut f = [0.0; LANES];
        for i in 0..LANES {
            f[i] = ta[i] - ha * (g * sa[i] + sa[i] * cu[i] - ca[i] * su[i]);
            let w2l = w[i] * w[i] * la;
            cu[i] += w2l * ca[i];
            su[i] += w2l * sa[i];
        }
        out[a] = f;
    }
    // Backward elimination. Each link's pivot needs the articulated inertia G of every link
    // below it, and G of the link just below needs that link's pivot inverted: a chain of
    // divisions. So the link just below stays pending (its u, 1/pivot and rho), G and w hold
    // the links under it, and the pending link enters the pivot as one term,
    // `pivot = d - l^2 n.G n - l^2 (n.u_p)^2 / pivot_p`, whose other parts are ready before the
    // division below ends: the chain from one division to the next is a fused multiply-add.
    let (mut cd, mut sd) = ([0.0; LANES], [0.0; LANES]);
    let (mut gxx, mut gxy, mut gyy, mut wx, mut wy) = ([0.0; LANES], [0.0; LANES], [0.0; LANES], [0.0; LANES], [0.0; LANES]);
    // Per lane, the first link (from the bottom) whose pivot failed, or -1: kept without a branch
    // per link, so the passes stay vectorised.
    let mut worst = [-1.0f64; LANES];
    // The bottom link first, pending: nothing is below it, so its pivot is its own d, which
    // passes the test.
    let b = n - 1;
    let inv_b = chain.bottom_inv;
    let (mut pux, mut puy, mut pinv, mut prho) = ([0.0; LANES], [0.0; LANES], [inv_b; LANES], out[b]);
    {
        let hb = h[b];
        let (cos, sin, w) = (s.cos[b], s.sin[b], omega[b]);
        let (mut uxi, mut uyi, mut rhoi) = ([0.0; LANES], [0.0; LANES], [0.0; LANES]);
        for i in 0..LANES {
            let (nx, ny) = (cos[i], sin[i]);
            (pux[i], puy[i]) = (hb * nx, hb * ny);
            let w2h = w[i] * w[i] * hb;
            (cd[i], sd[i]) = (w2h * nx, w2h * ny);
            (uxi[i], uyi[i], rhoi[i]) = (pux[i] * inv_b, puy[i] * inv_b, prho[i] * inv_b);
        }
        (s.uxi[b], s.uyi[b], s.dinv[b], out[b]) = (uxi, uyi, [inv_b; LANES], rhoi);
    }
    for a in (0..n - 1).rev() {
        let (la, ha, da) = (l[a], h[a], d[a]);
        let lla = la * la;
        // The link's lanes in locals: stores into the scratch's buffers would otherwise keep
        // LLVM from vectorising across lanes (it cannot tell the buffers apart).
        let (cos, sin, w, force) = (s.cos[a], s.sin[a], omega[a], out[a]);
        let link = a as f64;
        let (mut uxis, mut uyis, mut invs, mut rhois) = ([0.0; LANES], [0.0; LANES], [0.0; LANES], [0.0; LANES]);
        for i in 0..LANES {
            let (nx, ny) = (cos[i], sin[i]);
            // The links under the pending one, then the pending link's term.
            let (gnx, gny) = (gxx[i] * nx + gxy[i] * ny, gxy[i] * nx + gyy[i] * ny);
            let under = da - lla * (nx * gnx + ny * gny);
            let nu = nx * pux[i] + ny * puy[i];
            let pivot = (-(lla * nu * nu)).mul_add(pinv[i], under);
            let fail = (active[i] > 0.0) & !(pivot > PIVOT_TOL * da);
            worst[i] = if fail { worst[i].max(link) } else { worst[i] };
            let inv = 1.0 / pivot;
            let (puxi, puyi, prhoi) = (pux[i] * pinv[i], puy[i] * pinv[i], prho[i] * pinv[i]);
            let (fgx, fgy) = (pux[i].mul_add(nu * pinv[i], gnx), puy[i].mul_add(nu * pinv[i], gny));
            let (ux, uy) = (ha * nx - la * fgx, ha * ny - la * fgy);
            let extra = -la * (ny * cd[i] - nx * sd[i]);
            let w2h = w[i] * w[i] * ha;
            cd[i] += w2h * nx;
            sd[i] += w2h * ny;
            let nw = nu.mul_add(prhoi, nx * wx[i] + ny * wy[i]);
            let rho = force[i] + extra - la * nw;
            // The pending link joins the links under the next one.
            gxx[i] = pux[i].mul_add(puxi, gxx[i]);
            gxy[i] = pux[i].mul_add(puyi, gxy[i]);
            gyy[i] = puy[i].mul_add(puyi, gyy[i]);
            wx[i] = puxi.mul_add(prho[i], wx[i]);
            wy[i] = puyi.mul_add(prho[i], wy[i]);
            (pux[i], puy[i], pinv[i], prho[i]) = (ux, uy, inv, rho);
            (uxis[i], uyis[i], invs[i], rhois[i]) = (ux * inv, uy * inv, inv, rho * inv);
        }
        (s.uxi[a], s.uyi[a], s.dinv[a], out[a]) = (uxis, uyis, invs, rhois);
    }
    let mut base = [0.0; LANES];
    if let Some(c) = cart {
        // The cart's row: (F + sum_b h_b sin(theta_b) w_b^2 - w_x) / (M_c + M - G_xx), the
        // articulated inertia and bias at the base closing it (`accelerations_general`), the
        // top link (still pending) joined to them.
        for i in 0..LANES {
            gxx[i] = pux[i].mul_add(pux[i] * pinv[i], gxx[i]);
            wx[i] = (pux[i] * pinv[i]).mul_add(prho[i], wx[i]);
        }
        let total = chain.cart.map_or(0.0, |c| c.mass) + chain.total_mass();
        let mut pull = [0.0; LANES];
        for a in 0..n {
            for i in 0..LANES {
                pull[i] += h[a] * s.sin[a][i] * omega[a][i] * omega[a][i];
            }
        }
        for i in 0..LANES {
            let den = total - gxx[i];
            let fail = (active[i] > 0.0) & !(den > PIVOT_TOL * total);
            worst[i] = if fail { worst[i].max(0.0) } else { worst[i] };
            base[i] = (c.force[i] + pull[i] - wx[i]) / den;
        }
        *c.x_ddot = base;
    }
    substitute(l, out, s, &base);
    verdict(&worst)
}

/// The tangent of [`accelerations`] along `(d_theta, d_omega)`: `d theta_ddot` of every lane into
/// `out`, for torques that depend on time only, plus `extra`: the generalized forces' own
/// derivative along the direction (the joints' losses: [`add_loss_tangent`]). `accel` is `theta_ddot` at the same state and `s`
/// the scratch of that [`accelerations`] call (its trig and, for N > 3, its elimination, for
/// N = 3 its adjugate, which the solve reuses: the mass matrix is the same). The arithmetic of
/// [`Chain::tangent_accelerations_into`] (`A d_theta_ddot = dr - (dA) theta_ddot`, every term a
/// sum of `K_ab sin/cos(theta_a - theta_b)` against a vector), its five coupled sums fused into
/// one pass up and one down, the rows then solved as the accelerations were (the elimination,
/// or three links' adjugate); the double pendulum in closed form. Agrees with it to round-off.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub fn tangent(chain: &Chain, omega: &[Lane], accel: &[Lane], d_theta: &[Lane], d_omega: &[Lane], extra: Option<&[Lane]>, out: &mut [Lane], s: &LaneScratch) {
    debug_assert!(s.for_tangent, "the accelerations were not told that a tangent follows");
    if chain.n() == 2 {
        return tangent_double(chain, omega, accel, d_theta, d_omega, extra, out, s);
    }
    let n = omega.len();
    let (l, h, g) = (&chain.lengths[..n], &chain.h[..n], chain.g);
    // Up the chain: the links above (prefix sums of l_b u_b n_b for the five vectors u:
    // w^2, d_theta w^2, w d_omega, accel, d_theta accel).
    let mut p = [[0.0; LANES]; 10];
    for a in 0..n {
        let (sa, ca, w, dw, dth, acc) = (s.sin[a], s.cos[a], omega[a], d_omega[a], d_theta[a], accel[a]);
        let (ha, la) = (h[a], l[a]);
        let more = extra.map_or([0.0; LANES], |e| e[a]);
        let mut r = [0.0; LANES];
        for i in 0..LANES {
            let (c, sn, dt) = (ca[i], sa[i], dth[i]);
            r[i] = -g * ha * c * dt + ha * coupled(&p, i, c, sn, dt) + more[i];
            accumulate(&mut p, i, la, c, sn, dt, (w[i], dw[i], acc[i]));
        }
        out[a] = r;
    }
    // Down the chain: the links below (suffix sums of h_b u_b n_b) complete each row.
    let mut q = [[0.0; LANES]; 10];
    for a in (0..n).rev() {
        let (sa, ca, w, dw, dth, acc, r) = (s.sin[a], s.cos[a], omega[a], d_omega[a], d_theta[a], accel[a], out[a]);
        let (ha, la) = (h[a], l[a]);
        let mut row = [0.0; LANES];
        for i in 0..LANES {
            let (c, sn, dt) = (ca[i], sa[i], dth[i]);
            row[i] = r[i] + la * coupled(&q, i, c, sn, dt);
            accumulate(&mut q, i, ha, c, sn, dt, (w[i], dw[i], acc[i]));
        }
        out[a] = row;
    }
    if n == 3 {
        // Solved by the closed form's adjugate.
        let [c11, c12, c13, c22, c23, c33, inv] = &s.adjugate;
        let (r1, r2, r3) = (out[0], out[1], out[2]);
        for i in 0..LANES {
            [out[0][i], out[1][i], out[2][i]] = solve3([c11[i], c12[i], c13[i], c22[i], c23[i], c33[i]], inv[i], [r1[i], r2[i], r3[i]]);
        }
        return;
    }
    // The rows through the accelerations' elimination (its pivots and u), then substituted.
    let (mut wx, mut wy) = ([0.0; LANES], [0.0; LANES]);
    for a in (0..n).rev() {
        let (sa, ca, row) = (s.sin[a], s.cos[a], out[a]);
        let (uxi, uyi, inv, la) = (s.uxi[a], s.uyi[a], s.dinv[a], l[a]);
        let mut rhoi = [0.0; LANES];
        for i in 0..LANES {
            let (c, sn) = (ca[i], sa[i]);
            let rh = row[i] - la * (c * wx[i] + sn * wy[i]);
            wx[i] = uxi[i].mul_add(rh, wx[i]);
            wy[i] = uyi[i].mul_add(rh, wy[i]);
            rhoi[i] = rh * inv[i];
        }
        out[a] = rhoi;
    }
    substitute(l, out, s, &[0.0; LANES]);
}

/// The tangent's coupled sums at a link of lane `i` from the running sums `p` of the links
/// above (or below) it: the cos-sums of `w^2` and `d_theta w^2`, the sin-sums of `w d_omega`,
/// `accel` and `d_theta accel`, combined as the row needs them.
#[inline(always)]
fn coupled(p: &[Lane; 10], i: usize, c: f64, sn: f64, dt: f64) -> f64 {
    let cos1 = c * p[0][i] + sn * p[1][i];
    let cos2 = c * p[2][i] + sn * p[3][i];
    let sin3 = sn * p[4][i] - c * p[5][i];
    let sin4 = sn * p[6][i] - c * p[7][i];
    let sin5 = sn * p[8][i] - c * p[9][i];
    cos2 - dt * cos1 - 2.0 * sin3 + dt * sin4 - sin5
}

/// Add a link's five vectors, weighted by `weight` (`l` going up, `h` going down), to the
/// running sums of lane `i`.
#[inline(always)]
fn accumulate(p: &mut [Lane; 10], i: usize, weight: f64, c: f64, sn: f64, dt: f64, (w, dw, acc): (f64, f64, f64)) {
    let w2 = w * w;
    let u = [w2, dt * w2, w * dw, acc, dt * acc];
    for (q, uq) in u.iter().enumerate() {
        p[2 * q][i] += weight * uq * c;
        p[2 * q + 1][i] += weight * uq * sn;
    }
}

/// [`tangent`] of the double pendulum: with `delta = d_theta_1 - d_theta_2`,
/// `dr_1 = -g h_1 c_1 d_theta_1 - K c_12 delta w_2^2 - 2 K s_12 w_2 d_w_2 + K s_12 delta a_2` (and
/// the mirror for the second row), solved by the 2 x 2 inverse of the accelerations.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn tangent_double(
    chain: &Chain,
    omega: &[Lane],
    accel: &[Lane],
    d_theta: &[Lane],
    d_omega: &[Lane],
    extra: Option<&[Lane]>,
    out: &mut [Lane],
    s: &LaneScratch,
) {
    let (d1, d2, h1, h2, g) = (chain.diag[0], chain.diag[1], chain.h[0], chain.h[1], chain.g);
    let (e1, e2) = extra.map_or(([0.0; LANES], [0.0; LANES]), |e| (e[0], e[1]));
    let k = chain.lengths[0] * h2;
    let (s1, c1, s2, c2) = (s.sin[0], s.cos[0], s.sin[1], s.cos[1]);
    let (mut a0, mut a1) = ([0.0; LANES], [0.0; LANES]);
    for i in 0..LANES {
        let (s12, c12) = (s1[i].mul_add(c2[i], -(c1[i] * s2[i])), c1[i].mul_add(c2[i], s1[i] * s2[i]));
        let (w1, w2) = (omega[0][i], omega[1][i]);
        let delta = d_theta[0][i] - d_theta[1][i];
        let (kc, ks) = (k * c12, k * s12);
        let r1 = -g * h1 * c1[i] * d_theta[0][i] - kc * delta * w2 * w2 - 2.0 * ks * w2 * d_omega[1][i] + ks * delta * accel[1][i] + e1[i];
        let r2 = -g * h2 * c2[i] * d_theta[1][i] + kc * delta * w1 * w1 + 2.0 * ks * w1 * d_omega[0][i] + ks * delta * accel[0][i] + e2[i];
        let inv = 1.0 / (-kc).mul_add(kc, d1 * d2);
        a0[i] = d2.mul_add(r1, -(kc * r2)) * inv;
        a1[i] = d1.mul_add(r2, -(kc * r1)) * inv;
    }
    (out[0], out[1]) = (a0, a1);
}

/// Forward substitution after the elimination (`out` holds the reduced right-hand side
/// divided by the pivot, `rho / pivot`): `x_a = rho_a / pivot_a - (u_a / pivot_a) . P_a`, `P` the
/// prefix sum of `l_b n_b x_b` from the base's acceleration `(base, 0)` (a cart's; zero on a
/// fixed pivot). The divisions were taken by the elimination, so the chain from one link's
/// `x` to the next is three fused multiply-adds.
#[inline(always)]
fn substitute(l: &[f64], out: &mut [Lane], s: &LaneScratch, base: &Lane) {
    let n = out.len();
    let (mut px, mut py) = (*base, [0.0; LANES]);
    for a in 0..n {
        let (la, rhoi, uxi, uyi, cos, sin) = (l[a], out[a], s.uxi[a], s.uyi[a], s.cos[a], s.sin[a]);
        let mut x = [0.0; LANES];
        for i in 0..LANES {
            let xa = (-uxi[i]).mul_add(px[i], (-uyi[i]).mul_add(py[i], rhoi[i]));
            x[i] = xa;
            px[i] = (la * cos[i]).mul_add(xa, px[i]);
            py[i] = (la * sin[i]).mul_add(xa, py[i]);
        }
        out[a] = x;
    }
}

/// The joints' losses at rates `omega` added to the generalized forces `q`, and the power they
/// dissipate (`sum_i -u_i w_i >= 0`) into `power`: [`Chain::add_losses`] in lanes (its joint
/// torques `u_i = -b_i w_i - f_i tanh(w_i / v_s)`, `Q_i = u_i - u_{i+1}`). The friction's `tanh`
/// is libm's per lane (the saturated range at once, as there).
#[inline(always)]
pub fn add_losses(chain: &Chain, omega: &[Lane], q: &mut [Lane], power: &mut Lane) {
    let n = omega.len();
    let j = &chain.joints;
    let (mut next, mut p) = ([0.0; LANES], [0.0; LANES]);
    for a in (0..n).rev() {
        let (b, f, below) = (j.damping[a], j.friction[a], if a > 0 { omega[a - 1] } else { [0.0; LANES] });
        let mut qa = q[a];
        for i in 0..LANES {
            let w = omega[a][i] - below[i];
            let mut u = -b * w;
            if f != 0.0 {
                u -= f * saturating_tanh(w * j.inv_velocity);
            }
            qa[i] += u - next[i];
            next[i] = u;
            p[i] -= u * w;
        }
        q[a] = qa;
    }
    *power = p;
}

/// A moving pivot's acceleration `(a_x, a_y)` (each lane's own) as generalized forces added to
/// `q`: `-h_a (a_x cos theta_a + a_y sin theta_a)`, the change of gravity it makes on each
/// link. The angles' `sin` and `cos` into `trig` (`[sin (N), cos (N)]`), for
/// [`add_pivot_tangent`].
#[inline(always)]
pub fn add_pivot_forces(chain: &Chain, (ax, ay): (&Lane, &Lane), theta: &[Lane], q: &mut [Lane], trig: &mut [Lane]) {
    let n = theta.len();
    for a in 0..n {
        (trig[a], trig[n + a]) = sin_cos(&theta[a]);
    }
    let (sin, cos) = trig.split_at(n);
    add_pivot_forces_from(chain, (ax, ay), (sin, cos), q);
}

/// [`add_pivot_forces`] from the angles' `sin` and `cos`.
#[inline(always)]
pub fn add_pivot_forces_from(chain: &Chain, (ax, ay): (&Lane, &Lane), (sin, cos): (&[Lane], &[Lane]), q: &mut [Lane]) {
    for (a, qa) in q.iter_mut().enumerate().take(sin.len()) {
        let h = chain.h[a];
        for i in 0..LANES {
            qa[i] -= h * ax[i].mul_add(cos[a][i], ay[i] * sin[a][i]);
        }
    }
}

/// The derivative of [`add_pivot_forces`]' forces along `d_theta`, added to `dq`:
/// `h_a (a_x sin theta_a - a_y cos theta_a) d_theta_a`, from the `trig` it left.
#[inline(always)]
pub fn add_pivot_tangent(chain: &Chain, (ax, ay): (&Lane, &Lane), trig: &[Lane], d_theta: &[Lane], dq: &mut [Lane]) {
    let n = d_theta.len();
    for a in 0..n {
        let (sin, cos, h) = (trig[a], trig[n + a], chain.h[a]);
        for i in 0..LANES {
            dq[a][i] += h * ax[i].mul_add(sin[i], -(ay[i] * cos[i])) * d_theta[a][i];
        }
    }
}

/// The derivative of [`add_losses`]' forces along `d_omega`, into `dq` (overwritten):
/// [`Chain::add_loss_tangent`] in lanes.
#[inline(always)]
pub fn add_loss_tangent(chain: &Chain, omega: &[Lane], d_omega: &[Lane], dq: &mut [Lane]) {
    let n = omega.len();
    let j = &chain.joints;
    let (mut prev, mut d_prev) = ([0.0; LANES], [0.0; LANES]);
    let mut carry = [0.0; LANES];
    for a in 0..n {
        let (b, f, vs) = (j.damping[a], j.friction[a], j.friction_velocity);
        let mut du = [0.0; LANES];
        for i in 0..LANES {
            let (w, dw) = (omega[a][i] - prev[i], d_omega[a][i] - d_prev[i]);
            let mut slope = b;
            if f != 0.0 {
                let th = saturating_tanh(w / vs);
                slope += f / vs * (1.0 - th * th);
            }
            du[i] = -slope * dw;
        }
        if a > 0 {
            for i in 0..LANES {
                dq[a - 1][i] = carry[i] - du[i];
            }
        }
        carry = du;
        (prev, d_prev) = (omega[a], d_omega[a]);
    }
    dq[n - 1] = carry;
}

/// Kinetic and total energy of every lane: `T = 1/2 sum_a d_a w_a^2 + sum_{b<a} l_b h_a w_a w_b
/// cos(theta_a - theta_b)` (the mass matrix's entries, by prefix sums over the links above, O(N))
/// and `U = -g sum_a h_a cos theta_a`, as [`Chain::kinetic_energy`] and
/// [`Chain::potential_energy`] define them.
#[inline(always)]
pub fn energies(chain: &Chain, theta: &[Lane], omega: &[Lane], kinetic: &mut Lane, energy: &mut Lane) {
    energies_on(chain, theta, omega, None, kinetic, energy)
}

/// [`energies`] with the base moving along x at `cart_v` (a cart's): the lab-frame kinetic
/// energy `T + v r_x + (M + M_c) v^2 / 2`, `r_x = sum_a h_a cos(theta_a) w_a`, as
/// [`Chain::kinetic_energy_moving`] has it.
#[inline(always)]
pub fn energies_on(chain: &Chain, theta: &[Lane], omega: &[Lane], cart_v: Option<&Lane>, kinetic: &mut Lane, energy: &mut Lane) {
    let n = theta.len();
    let (l, h, d, g) = (&chain.lengths[..n], &chain.h[..n], &chain.diag[..n], chain.g);
    let (mut cu, mut su, mut t2, mut u, mut rx) = ([0.0; LANES], [0.0; LANES], [0.0; LANES], [0.0; LANES], [0.0; LANES]);
    for a in 0..n {
        let (s, c) = sin_cos(&theta[a]);
        for i in 0..LANES {
            let w = omega[a][i];
            t2[i] += w * (d[a] * w + 2.0 * h[a] * (c[i] * cu[i] + s[i] * su[i]));
            cu[i] += l[a] * w * c[i];
            su[i] += l[a] * w * s[i];
            u[i] -= g * h[a] * c[i];
            rx[i] += h[a] * w * c[i];
        }
    }
    let mass = chain.total_mass() + chain.cart.map_or(0.0, |c| c.mass);
    for i in 0..LANES {
        kinetic[i] = 0.5 * t2[i];
        if let Some(v) = cart_v {
            kinetic[i] += v[i] * rx[i] + 0.5 * mass * (v[i] * v[i]);
        }
        energy[i] = kinetic[i] + u[i];
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dynamics::Workspace;

    #[test]
    fn lanes_are_the_per_state_accelerations_and_tangents_to_round_off() {
        for chain in [
            Chain::new(&[0.8], &[1.5], None, None, 9.81).unwrap(),
            Chain::new(&[1.0, 0.7], &[1.0, 2.0], None, None, 9.81).unwrap(),
            Chain::rods(&[1.0, 0.5, 0.8], &[1.0, 0.3, 2.0], 9.81).unwrap(),
            Chain::new(&[0.4; 7], &[1.0, 0.5, 2.0, 1.0, 0.1, 3.0, 1.0], Some(&[0.2; 7]), Some(&[0.01; 7]), 9.81).unwrap(),
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
            let mut scratch = LaneScratch::new(n);
            scratch.for_tangent = true;
            accelerations(&chain, &th, &om, &tau, &mut out, &mut scratch, &[1.0; LANES]).unwrap();
            let (mut dth, mut dom) = (vec![[0.0; LANES]; n], vec![[0.0; LANES]; n]);
            for a in 0..n {
                for i in 0..LANES {
                    dth[a][i] = (a as f64 * 0.9 - i as f64 * 0.3).sin();
                    dom[a][i] = (a as f64 * 2.1 + i as f64 * 0.5).cos() * 1.7;
                }
            }
            let mut tan = vec![[0.0; LANES]; n];
            tangent(&chain, &om, &out, &dth, &dom, None, &mut tan, &scratch);
            let (mut kin, mut en) = ([0.0; LANES], [0.0; LANES]);
            energies(&chain, &th, &om, &mut kin, &mut en);
            let mut ws = Workspace::new(n);
            for i in 0..LANES {
                let col = |v: &[Lane]| v.iter().map(|l| l[i]).collect::<Vec<f64>>();
                let mut want = vec![0.0; n];
                chain.accelerations_into(&col(&th), &col(&om), &col(&tau), &mut want, &mut ws).unwrap();
                for a in 0..n {
                    assert!((out[a][i] - want[a]).abs() <= 1e-12 * (1.0 + want[a].abs()), "N = {n}, lane {i}, link {a}");
                }
                let (mut want_tan, mut sc) = (vec![0.0; n], vec![0.0; 6 * n]);
                chain.tangent_accelerations_into(&col(&th), &col(&om), &want, &col(&dth), &col(&dom), &mut want_tan, &mut sc, &mut ws).unwrap();
                for a in 0..n {
                    assert!(
                        (tan[a][i] - want_tan[a]).abs() <= 1e-12 * (1.0 + want_tan[a].abs()),
                        "N = {n}, lane {i}, link {a}: tangent {} vs {}",
                        tan[a][i],
                        want_tan[a]
                    );
                }
                let t = chain.kinetic_energy(&col(&th), &col(&om), &mut vec![0.0; n], &mut ws);
                let e = t + chain.potential_energy(&col(&th));
                assert!((kin[i] - t).abs() <= 1e-12 * (1.0 + t.abs()), "N = {n}, lane {i}: T");
                assert!((en[i] - e).abs() <= 1e-12 * (1.0 + e.abs()), "N = {n}, lane {i}: E");
            }
        }
    }

    #[test]
    fn the_triple_pendulums_pivot_tests_fail_where_and_as_the_recursions() {
        // A nearly massless link carrying mass: the mass matrix is nearly singular where it lines
        // up with the link below (the middle one: its own pivot fails; the top one: the first
        // link's). Lane 0 lined up, lane 1 not, lane 2 lined up but inactive.
        for (masses, angles, link) in [([1.0, 1e-18, 1.0], [0.3, 0.5, 0.5], 1), ([1e-18, 1.0, 1.0], [0.4, 0.4, 0.1], 0)] {
            let chain = Chain::new(&[1.0; 3], &masses, None, None, 9.81).unwrap();
            let apart = [-0.2, 0.1, 0.4];
            let (mut th, om, tau) = (apart.map(|a| [a; LANES]).to_vec(), vec![[0.5; LANES]; 3], vec![[0.0; LANES]; 3]);
            for a in 0..3 {
                (th[a][0], th[a][2]) = (angles[a], angles[a]);
            }
            let mut active = [1.0; LANES];
            active[2] = 0.0;
            let (mut out, mut scratch) = (vec![[0.0; LANES]; 3], LaneScratch::new(3));
            let e = accelerations(&chain, &th, &om, &tau, &mut out, &mut scratch, &active).unwrap_err();
            let mut ws = Workspace::new(3);
            let want = chain.accelerations_into(&angles, &[0.5; 3], &[0.0; 3], &mut [0.0; 3], &mut ws).unwrap_err();
            assert_eq!((e.link, want), (Singular(link), Singular(link)), "masses {masses:?}");
            assert_eq!(e.lanes, std::array::from_fn(|i| i == 0));
            // Apart from the line-up, the same chain passes.
            chain.accelerations_into(&apart, &[0.5; 3], &[0.0; 3], &mut [0.0; 3], &mut ws).unwrap();
        }
    }

    #[test]
    fn lossy_lanes_are_the_general_models_accelerations_and_tangents_to_round_off() {
        use crate::dynamics::general::Load;
        for n in [1usize, 2, 3, 6] {
            let lengths: Vec<f64> = (0..n).map(|a| 0.5 + 0.1 * a as f64).collect();
            let masses: Vec<f64> = (0..n).map(|a| 1.0 + 0.3 * a as f64).collect();
            let chain = Chain::new(&lengths, &masses, None, None, 9.81).unwrap();
            let damping: Vec<f64> = (0..n).map(|a| 0.05 * (a + 1) as f64).collect();
            // Friction on every other joint, with rates in its linear and saturated ranges.
            let friction: Vec<f64> = (0..n).map(|a| if a % 2 == 0 { 0.2 } else { 0.0 }).collect();
            let chain = chain.with_losses(&damping, &friction, 0.5).unwrap();
            let mut th = vec![[0.0; LANES]; n];
            let mut om = vec![[0.0; LANES]; n];
            let (mut dth, mut dom) = (vec![[0.0; LANES]; n], vec![[0.0; LANES]; n]);
            for a in 0..n {
                for i in 0..LANES {
                    th[a][i] = (a as f64 * 1.3 + i as f64 * 0.7).sin() * 3.0;
                    om[a][i] = (a as f64 * 0.4 - i as f64 * 1.1).cos() * (0.1 + i as f64);
                    dth[a][i] = (a as f64 * 0.9 - i as f64 * 0.3).sin();
                    dom[a][i] = (a as f64 * 2.1 + i as f64 * 0.5).cos() * 1.7;
                }
            }
            let (mut q, mut power) = (vec![[0.0; LANES]; n], [0.0; LANES]);
            add_losses(&chain, &om, &mut q, &mut power);
            let (mut acc, mut scratch) = (vec![[0.0; LANES]; n], LaneScratch::new(n));
            scratch.for_tangent = true;
            accelerations(&chain, &th, &om, &q, &mut acc, &mut scratch, &[1.0; LANES]).unwrap();
            let mut dq = vec![[0.0; LANES]; n];
            add_loss_tangent(&chain, &om, &dom, &mut dq);
            let mut tan = vec![[0.0; LANES]; n];
            tangent(&chain, &om, &acc, &dth, &dom, Some(&dq), &mut tan, &scratch);
            let mut ws = Workspace::new(n);
            let still = Load::still(&chain);
            for i in 0..LANES {
                let col = |v: &[Lane]| v.iter().map(|l| l[i]).collect::<Vec<f64>>();
                let mut want = vec![0.0; n];
                let rates = chain.accelerations_general(&col(&th), &col(&om), 0.0, &vec![0.0; n], &still, &mut want, &mut ws).unwrap();
                let (mut want_tan, mut sc) = (vec![0.0; n], vec![0.0; 8 * n]);
                chain.tangent_general(&col(&th), &col(&om), (&want, 0.0), &still, (&col(&dth), &col(&dom), 0.0), &mut want_tan, &mut sc, &mut ws).unwrap();
                let close = |a: f64, b: f64| (a - b).abs() <= 1e-12 * (1.0 + b.abs());
                assert!(close(power[i], rates.losses), "N = {n}, lane {i}: power {} vs {}", power[i], rates.losses);
                for a in 0..n {
                    assert!(close(acc[a][i], want[a]), "N = {n}, lane {i}, link {a}: {} vs {}", acc[a][i], want[a]);
                    assert!(close(tan[a][i], want_tan[a]), "N = {n}, lane {i}, link {a}: tangent {} vs {}", tan[a][i], want_tan[a]);
                }
            }
        }
    }

    #[test]
    fn a_cart_in_lanes_is_the_general_models_cart_to_round_off() {
        use crate::dynamics::general::Load;
        use crate::model::Cart;
        for n in [1usize, 2, 3, 5] {
            let lengths: Vec<f64> = (0..n).map(|a| 0.5 + 0.1 * a as f64).collect();
            let masses: Vec<f64> = (0..n).map(|a| 0.3 + 0.2 * a as f64).collect();
            let chain = Chain::rods(&lengths, &masses, 9.81)
                .unwrap()
                .with_losses(&vec![0.05; n], &vec![0.0; n], 1e-3)
                .unwrap()
                .with_cart(Some(Cart::new(1.5, 0.2).unwrap()))
                .unwrap();
            let mut th = vec![[0.0; LANES]; n];
            let mut om = vec![[0.0; LANES]; n];
            let (mut v, mut f) = ([0.0; LANES], [0.0; LANES]);
            for i in 0..LANES {
                for a in 0..n {
                    th[a][i] = (a as f64 * 1.3 + i as f64 * 0.7).sin() * 3.0;
                    om[a][i] = (a as f64 * 0.4 - i as f64 * 1.1).cos() * 2.0;
                }
                v[i] = 0.3 * i as f64 - 1.0;
                f[i] = 2.0 - 0.5 * i as f64;
            }
            let (mut q, mut power) = (vec![[0.0; LANES]; n], [0.0; LANES]);
            add_losses(&chain, &om, &mut q, &mut power);
            let force: Lane = std::array::from_fn(|i| f[i] - 0.2 * v[i]);
            let (mut acc, mut xdd, mut scratch) = (vec![[0.0; LANES]; n], [0.0; LANES], LaneScratch::new(n));
            accelerations_on(&chain, &th, &om, &q, &mut acc, &mut scratch, &[1.0; LANES], Some(CartLanes { force: &force, x_ddot: &mut xdd })).unwrap();
            let (mut kin, mut en) = ([0.0; LANES], [0.0; LANES]);
            energies_on(&chain, &th, &om, Some(&v), &mut kin, &mut en);
            let mut ws = Workspace::new(n);
            for i in 0..LANES {
                let col = |x: &[Lane]| x.iter().map(|l| l[i]).collect::<Vec<f64>>();
                let mut load = Load::still(&chain);
                load.cart_force = f[i];
                let mut want = vec![0.0; n];
                let rates = chain.accelerations_general(&col(&th), &col(&om), v[i], &vec![0.0; n], &load, &mut want, &mut ws).unwrap();
                let close = |a: f64, b: f64| (a - b).abs() <= 1e-12 * (1.0 + b.abs());
                assert!(close(xdd[i], rates.cart), "N = {n}, lane {i}: x_ddot {} vs {}", xdd[i], rates.cart);
                for a in 0..n {
                    assert!(close(acc[a][i], want[a]), "N = {n}, lane {i}, link {a}: {} vs {}", acc[a][i], want[a]);
                }
                let t = chain.kinetic_energy_moving(&col(&th), &col(&om), [v[i], 0.0], &mut vec![0.0; n], &mut ws);
                assert!(close(kin[i], t), "N = {n}, lane {i}: T {} vs {t}", kin[i]);
                assert!(close(en[i], t + chain.potential_energy(&col(&th))), "N = {n}, lane {i}: E");
            }
        }
    }
}
