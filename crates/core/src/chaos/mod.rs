//! Chaos tools: Lyapunov exponents from the variational equations, and first-flip times of
//! ensembles (the flip-time "fractal") with the energy bound that forbids flips.
pub mod ensemble;
pub mod flipkernel;
pub mod indicator_lanes;
pub mod indicators;

use crate::dynamics::base::{Drive, Pivot};
use crate::dynamics::general::{Load, TANGENT_SCRATCH};
use crate::dynamics::system::{singular, ChainSystem, Form, OdeSystem, NON_FINITE};
use crate::dynamics::torque::{Builtin, Timed, TorqueSource};
use crate::dynamics::Workspace;
use crate::error::{Error, Result, Shown};
use crate::integrators::Rk4;
use crate::interp::hermite;
use crate::model::Chain;
use crate::par::*;
use crate::watch::Watch;

/// The Lagrangian form with `k` tangent vectors riding along:
/// `y = [theta, omega, (x, v), (d_theta, d_omega, (d_x, d_v)) x k]` (the cart's entries where
/// there is one), and with `megno` MEGNO's two integrals after them (see [`indicators`]). The
/// base's drive (a moving pivot, a cart force of time) acts at each stage's time.
struct Tangent<'c> {
    chain: &'c Chain,
    torque: Builtin,
    drive: Drive,
    k: usize,
    megno: bool,
    /// The general model's accelerations and tangents (losses, a cart, a moving pivot), else
    /// the ideal chain's.
    general: bool,
    ws: Workspace,
    tau: Vec<f64>,
    scratch: Vec<f64>,
}

impl<'c> Tangent<'c> {
    /// The base's `drive` must fit the chain ([`Drive::check`]) and its cart force be of time
    /// alone (its derivative along the state is not known).
    fn new(chain: &'c Chain, torque: Builtin, drive: Drive, k: usize, megno: bool) -> Self {
        let n = chain.n();
        let general = !chain.is_ideal() || drive.moving_pivot().is_some();
        Tangent { chain, torque, drive, k, megno, general, ws: Workspace::new(n), tau: vec![0.0; n], scratch: vec![0.0; TANGENT_SCRATCH * n] }
    }

    /// MEGNO's integrands (Cincotta & Simo 2000) from the first tangent vector `d` and its rate:
    /// `y' = t (d' . d) / (d . d)` and `w' = 2 y / t`, so that `Y = 2 y / t` and `<Y> = w / t`.
    /// The ratio does not depend on the vector's length, which may be renormalised freely.
    fn megno_rates(&self, t: f64, y: &[f64], dy: &mut [f64]) {
        let m = self.chain.state_len();
        let (v, dv) = (&y[m..2 * m], &dy[m..2 * m]);
        let ratio = dv.iter().zip(v).map(|(a, b)| a * b).sum::<f64>() / v.iter().map(|a| a * a).sum::<f64>();
        let at = m * (1 + self.k);
        dy[at] = t * ratio;
        dy[at + 1] = if t > 0.0 { 2.0 * y[at] / t } else { 0.0 };
    }

    /// The general model's rates and tangents, the base's drive evaluated at `t`.
    fn rhs_general(&mut self, t: f64, y: &[f64], dy: &mut [f64]) -> Result<()> {
        let (n, m) = (self.chain.n(), self.chain.state_len());
        let cart = m > 2 * n;
        let mut load = match self.drive.moving_pivot() {
            Some(p) => Load::pivot(self.chain, p.eval(t)?.acc),
            None => Load::still(self.chain),
        };
        if let Some(f) = self.drive.force.as_mut() {
            load.cart_force = f.eval(t, &[])?;
        }
        let fail = |e| singular(t, y, e);
        let (head, tail) = dy.split_at_mut(m);
        let (theta, omega) = (&y[..n], &y[n..2 * n]);
        let v = if cart { y[2 * n + 1] } else { 0.0 };
        let r = self.chain.accelerations_general(theta, omega, v, &self.tau, &load, &mut head[n..2 * n], &mut self.ws).map_err(fail)?;
        if cart {
            head[2 * n] = v;
            head[2 * n + 1] = r.cart;
        }
        for j in 0..self.k {
            let d = &y[m * (j + 1)..m * (j + 2)];
            let dd = &mut tail[m * j..m * (j + 1)];
            dd[..n].copy_from_slice(&d[n..2 * n]);
            let d_v = if cart { d[2 * n + 1] } else { 0.0 };
            let d_a = self
                .chain
                .tangent_general(
                    theta,
                    omega,
                    (&head[n..2 * n], r.cart),
                    &load,
                    (&d[..n], &d[n..2 * n], d_v),
                    &mut dd[n..2 * n],
                    &mut self.scratch,
                    &mut self.ws,
                )
                .map_err(fail)?;
            if cart {
                dd[2 * n] = d_v;
                dd[2 * n + 1] = d_a;
            }
        }
        Ok(())
    }
}

impl OdeSystem for Tangent<'_> {
    fn dim(&self) -> usize {
        self.chain.state_len() * (1 + self.k) + 2 * usize::from(self.megno)
    }

    fn rhs(&mut self, t: f64, y: &[f64], dy: &mut [f64]) -> Result<()> {
        let n = self.chain.n();
        if self.torque.active() {
            self.torque.eval(t, &y[..n], &y[n..2 * n], &mut self.tau)?;
        }
        dy[..n].copy_from_slice(&y[n..2 * n]);
        if self.general {
            self.rhs_general(t, y, dy)?;
        } else {
            let fail = |e| singular(t, y, e);
            let (head, tail) = dy.split_at_mut(2 * n);
            let (theta, omega) = (&y[..n], &y[n..2 * n]);
            self.chain.accelerations_into(theta, omega, &self.tau, &mut head[n..], &mut self.ws).map_err(fail)?;
            for j in 0..self.k {
                let v = &y[2 * n * (j + 1)..2 * n * (j + 2)];
                let dv = &mut tail[2 * n * j..2 * n * (j + 1)];
                dv[..n].copy_from_slice(&v[n..]);
                self.chain
                    .tangent_accelerations_into(theta, omega, &head[n..], &v[..n], &v[n..], &mut dv[n..], &mut self.scratch, &mut self.ws)
                    .map_err(fail)?;
            }
        }
        if self.megno {
            self.megno_rates(t, y, dy);
        }
        Ok(())
    }
}

/// Lyapunov exponents of a run: the final estimates (largest first) and their history.
#[derive(Debug, Clone, PartialEq)]
pub struct Lyapunov {
    pub exponents: Vec<f64>,
    /// Times of the re-orthonormalisations.
    pub times: Vec<f64>,
    /// Running estimates at those times, row-major `(times.len(), k)`.
    pub history: Vec<f64>,
}

/// The `k` largest Lyapunov exponents (1/s) by integrating the variational equations with rk4 at
/// step `dt` and re-orthonormalising the tangent vectors (modified Gram–Schmidt, Benettin et al.
/// 1980) every `renorm_every` steps. `k = None` gives the full spectrum: `2N` exponents, and on a
/// cart `2N + 2` (the state `(theta, omega, x, v)`; the cart's position is a neutral direction,
/// an exponent of zero). Torques, a moving pivot and a cart force may depend on time, not on the
/// state. `start` is `(theta0, omega0, [x0, v0])` (the cart's, ignored without one).
/// A specialised kernel (the tangent vectors are renormalised between steps), so it steps the
/// integrator itself on the driver's grid `t_k = k dt`; `watch` stops it and shows its progress.
#[allow(clippy::too_many_arguments)]
pub fn lyapunov(
    chain: &Chain,
    (theta0, omega0, cart0): (&[f64], &[f64], [f64; 2]),
    t_end: f64,
    dt: f64,
    k: Option<usize>,
    renorm_every: u64,
    torque: Builtin,
    drive: Drive,
    watch: &Watch,
) -> Result<Lyapunov> {
    let n = chain.n();
    chain.check_state("theta0", theta0)?;
    chain.check_state("omega0", omega0)?;
    if !(t_end.is_finite() && t_end > 0.0) {
        return Err(Error::input(format!("t_end must be > 0 and finite, got {}", Shown(t_end))));
    }
    if !(dt.is_finite() && dt > 0.0 && dt <= t_end) {
        return Err(Error::input(format!("dt must be > 0, finite and <= t_end, got {}", Shown(dt))));
    }
    let m = chain.state_len();
    let k = k.unwrap_or(m);
    if k == 0 || k > m {
        let size = if m > 2 * n { format!("2N + 2 = {m} (the angles, their rates and the cart's)") } else { format!("2N = {m}") };
        return Err(Error::input(format!("k must be between 1 and {size}, got {k}")));
    }
    if renorm_every == 0 {
        return Err(Error::input("renorm_every must be >= 1 step, got 0"));
    }
    drive.check(chain)?;
    if drive.force.as_ref().is_some_and(|f| f.is_feedback()) {
        return Err(Error::input(
            "Lyapunov exponents take a cart force of time alone (a number, Sinusoid or Table), not a function of the state (its derivative along the state is not known)",
        ));
    }
    if !cart0.iter().all(|v| v.is_finite()) {
        return Err(Error::input(format!("the cart's initial position and velocity must be finite, got {cart0:?}")));
    }
    let mut sys = Tangent::new(chain, torque, drive, k, false);
    let d = sys.dim();
    let mut y = vec![0.0; d];
    y[..n].copy_from_slice(theta0);
    y[n..2 * n].copy_from_slice(omega0);
    if m > 2 * n {
        y[2 * n..m].copy_from_slice(&cart0);
    }
    for j in 0..k {
        y[m * (j + 1) + j] = 1.0; // unit vectors: an orthonormal start
    }
    let steps = (t_end / dt).round().max(1.0);
    check_steps(steps, "t_end / dt")?;
    // The history keeps k running estimates per re-orthonormalisation.
    let renorms = (steps / renorm_every as f64).ceil();
    crate::memory::check(
        renorms * (k + 1) as f64 * 8.0,
        &format!("a history of {renorms:.0} re-orthonormalisations of {k} exponents"),
        "use a larger renorm_every or dt, or a shorter t_end",
    )?;
    let steps = steps as u64;
    let mut rk = Rk4::new(d);
    let mut y_new = vec![0.0; d];
    let mut sums = vec![0.0; k];
    let mut out = Lyapunov { exponents: vec![0.0; k], times: Vec::new(), history: Vec::new() };
    for step in 1..=steps {
        let (t, t_next) = ((step - 1) as f64 * dt, step as f64 * dt);
        if step % 64 == 0 {
            watch.check(t)?;
            watch.set_fraction(step as f64 / steps as f64);
        }
        rk.step(&mut sys, t, &y, dt, &mut y_new)?;
        std::mem::swap(&mut y, &mut y_new);
        if step % renorm_every == 0 || step == steps {
            if !y.iter().all(|v| v.is_finite()) {
                return Err(Error::integration(t_next, NON_FINITE));
            }
            let (_, vs) = y.split_at_mut(m);
            for j in 0..k {
                let (done, rest) = vs.split_at_mut(m * j);
                let v = &mut rest[..m];
                for i in 0..j {
                    let u = &done[m * i..m * (i + 1)];
                    let dot: f64 = u.iter().zip(v.iter()).map(|(a, b)| a * b).sum();
                    v.iter_mut().zip(u).for_each(|(b, a)| *b -= dot * a);
                }
                let norm = v.iter().map(|x| x * x).sum::<f64>().sqrt();
                if !(norm > 0.0) {
                    return Err(Error::integration(t_next, "a tangent vector collapsed; renormalise more often"));
                }
                sums[j] += norm.ln();
                v.iter_mut().for_each(|x| *x /= norm);
            }
            out.times.push(t_next);
            out.history.extend(sums.iter().map(|s| s / t_next));
        }
    }
    out.exponents = sums.iter().map(|s| s / (steps as f64 * dt)).collect();
    Ok(out)
}

/// The least energy a chain needs before link `link` (or, with `None`, any link) can go over the
/// top: with `theta_k = pi` the potential is at least `g h_k - g sum_{i != k} |h_i|` (the
/// potential separates in the absolute angles), and kinetic energy is never negative. A chain
/// released with less energy can never flip that link.
pub fn flip_energy_threshold(chain: &Chain, link: Option<usize>) -> Result<f64> {
    let n = chain.n();
    let g = chain.g;
    let total: f64 = chain.h.iter().map(|h| h.abs()).sum();
    let bound = |k: usize| g * chain.h[k] - g * (total - chain.h[k].abs());
    match link {
        Some(k) if k >= n => Err(Error::input(format!("link must be < N = {n}, got {k}"))),
        Some(k) => Ok(bound(k)),
        None => Ok((0..n).map(bound).fold(f64::INFINITY, f64::min)),
    }
}

/// For each initial state (rows of `theta0`, `omega0`), the first time at which `|theta_link|`
/// reaches pi (`link = None`: any link), integrating with rk4 at step `dt` up to `t_max`; the
/// crossing is located by bisection on the cubic Hermite interpolant of the step. Never: +inf;
/// a row that starts beyond pi: 0. Runs in parallel; each result is independent of the number
/// of threads. An integration error (a blow-up, a singular configuration) names its row
/// (`trajectory 7: ...`) on every path.
///
/// Undriven ideal chains go through the SIMD kernels of [`flipkernel`] (the same steps, with
/// their own `sin`/`cos`, so they agree with the per-trajectory path to round-off): the double
/// pendulum's closed form, any other N (and a chain on a moving `pivot`; a pivot held anywhere
/// is the fixed one) in lanes. A pivot given as a function, or `MULTIPENDULUM_FLIP_KERNEL=scalar`,
/// goes through [`first_flips_scalar`].
/// `watch` counts trajectories done and stops the work between chunks of steps.
#[allow(clippy::too_many_arguments)]
pub fn first_flips(
    chain: &Chain,
    theta0: &[f64],
    omega0: &[f64],
    t_max: f64,
    dt: f64,
    link: Option<usize>,
    torque: &Builtin,
    pivot: Option<&Pivot>,
    watch: &Watch,
) -> Result<Vec<f64>> {
    let steps = check_flips(chain, theta0, omega0, t_max, dt, link)?;
    Drive { pivot: pivot.cloned(), force: None }.check(chain)?;
    // A pivot held anywhere moves nothing: the angles' motion is the fixed pivot's.
    let pivot = pivot.filter(|p| !p.is_fixed());
    // The kernels: the ideal undriven double pendulum's own, any other chain in lanes (damping,
    // friction, a cart, a built-in torque and a pivot motion of time included).
    if let Some(path) = flipkernel::requested()?.filter(|_| pivot.map_or(true, Pivot::in_lanes)) {
        let drive = Timed::generalized(torque);
        return match (chain.n(), chain.is_ideal()) {
            (2, true) if drive.is_none() && pivot.is_none() && !flipkernel::generic() => {
                flipkernel::first_flips_double(chain, theta0, omega0, steps, dt, link, path, watch)
            }
            _ => flipkernel::first_flips_chain(chain, theta0, omega0, steps, dt, link, (drive.as_ref(), pivot), path, watch),
        };
    }
    first_flips_scalar(chain, theta0, omega0, t_max, dt, link, torque, pivot, watch)
}

/// A certified flip computation: [`first_flips`] at `dt` (the times reported) and again at
/// `dt / 2`; a row is uncertain where the two disagree on whether it flips by `t_max`, or on
/// when by more than `tolerance` (seconds; `None`: one step `dt`), so that its time or its very
/// decision depends on the step. The energy bound is not consulted: a row that cannot flip never
/// does at either step. `watch` counts each row twice.
#[allow(clippy::too_many_arguments)]
pub fn certified_flips(
    chain: &Chain,
    theta0: &[f64],
    omega0: &[f64],
    t_max: f64,
    dt: f64,
    link: Option<usize>,
    torque: &Builtin,
    pivot: Option<&Pivot>,
    tolerance: Option<f64>,
    watch: &Watch,
) -> Result<Certified> {
    let tolerance = tolerance.unwrap_or(dt);
    if !(tolerance.is_finite() && tolerance >= 0.0) {
        return Err(Error::input(format!("time_tolerance must be >= 0 and finite, got {}", Shown(tolerance))));
    }
    let coarse = first_flips(chain, theta0, omega0, t_max, dt, link, torque, pivot, watch)?;
    let fine = first_flips(chain, theta0, omega0, t_max, 0.5 * dt, link, torque, pivot, watch)?;
    let uncertain = coarse.iter().zip(&fine).map(|(&a, &b)| a.is_finite() != b.is_finite() || (a.is_finite() && (a - b).abs() > tolerance)).collect();
    Ok(Certified { times: coarse, uncertain, tolerance })
}

/// What [`certified_flips`] finds: the times at `dt`, the uncertain rows, and the time
/// tolerance they were judged with.
#[derive(Debug, Clone, PartialEq)]
pub struct Certified {
    pub times: Vec<f64>,
    pub uncertain: Vec<bool>,
    pub tolerance: f64,
}

/// Validate a flip computation's input; the number of steps.
fn check_flips(chain: &Chain, theta0: &[f64], omega0: &[f64], t_max: f64, dt: f64, link: Option<usize>) -> Result<u64> {
    let n = chain.n();
    if theta0.len() != omega0.len() || theta0.len() % n != 0 {
        return Err(Error::input(format!("theta0 and omega0 must both have shape (B, {n})")));
    }
    crate::error::check_finite("theta0", theta0)?;
    crate::error::check_finite("omega0", omega0)?;
    if !(t_max.is_finite() && t_max > 0.0) {
        return Err(Error::input(format!("t_max must be > 0 and finite, got {}", Shown(t_max))));
    }
    if !(dt.is_finite() && dt > 0.0) {
        return Err(Error::input(format!("dt must be > 0 and finite, got {}", Shown(dt))));
    }
    if let Some(k) = link {
        if k >= n {
            return Err(Error::input(format!("link must be < N = {n}, got {k}")));
        }
    }
    let steps = (t_max / dt).ceil();
    check_steps(steps, "t_max / dt")?;
    Ok(steps as u64)
}

/// The most rk4 steps per trajectory the chaos kernels take (about 10^3 s of one double
/// pendulum): beyond it a request would look like a hang.
pub const MAX_STEPS: f64 = 1e9;

pub(crate) fn check_steps(steps: f64, what: &str) -> Result<()> {
    if steps > MAX_STEPS {
        return Err(Error::input(format!("{what} = {steps:.3e} steps per trajectory, more than {MAX_STEPS:.0e}; use a larger dt or a shorter time")));
    }
    Ok(())
}

/// The time in `[t, t + dt]` at which `|theta|` reaches pi on the step's cubic Hermite
/// interpolant, from `(theta, theta')` at both ends (the end one has `|theta| >= pi`); by
/// bisection to the last bit of the step fraction.
pub(crate) fn flip_time(t: f64, dt: f64, start: (f64, f64), end: (f64, f64)) -> f64 {
    let target = std::f64::consts::PI.copysign(end.0);
    let theta_at = |x: f64| {
        let mut at = [0.0];
        hermite(&[start.0], &[start.1], &[end.0], &[end.1], dt, x, &mut at);
        at[0]
    };
    let (mut lo, mut hi) = (0.0f64, 1.0f64);
    for _ in 0..60 {
        let mid = 0.5 * (lo + hi);
        if (theta_at(mid) - target) * target.signum() >= 0.0 {
            hi = mid;
        } else {
            lo = mid;
        }
    }
    (t + hi * dt).min(t + dt)
}

/// [`first_flips`] one trajectory at a time with the generic [`Rk4`] over a
/// [`ChainSystem`]: any N, any built-in torque, a moving pivot (a pivot function is called from
/// the workers). Kept callable for comparisons with the kernel.
#[allow(clippy::too_many_arguments)]
pub fn first_flips_scalar(
    chain: &Chain,
    theta0: &[f64],
    omega0: &[f64],
    t_max: f64,
    dt: f64,
    link: Option<usize>,
    torque: &Builtin,
    pivot: Option<&Pivot>,
    watch: &Watch,
) -> Result<Vec<f64>> {
    let n = chain.n();
    let steps = check_flips(chain, theta0, omega0, t_max, dt, link)?;
    let links: Vec<usize> = link.map_or_else(|| (0..n).collect(), |k| vec![k]);
    let base = Drive { pivot: pivot.cloned(), force: None };
    base.check(chain)?;
    theta0
        .par_chunks(n)
        .zip(omega0.par_chunks(n))
        .enumerate()
        .map_init(
            || {
                let sys = ChainSystem::new(chain, torque.clone(), Form::Lagrangian).with_drive(base.clone()).expect("checked above");
                let d = sys.dim();
                (sys, Rk4::new(d))
            },
            |(sys, rk), (i, (th, om))| {
                watch.check(0.0)?;
                let pi = std::f64::consts::PI;
                if links.iter().any(|&k| th[k].abs() >= pi) {
                    return Ok(0.0);
                }
                let d = sys.dim();
                let mut y = vec![0.0; d];
                y[..n].copy_from_slice(th);
                y[n..2 * n].copy_from_slice(om);
                let mut y0 = y.clone();
                let flip = (|| {
                    for step in 0..steps {
                        let t = step as f64 * dt;
                        std::mem::swap(&mut y0, &mut y);
                        rk.step(sys, t, &y0, dt, &mut y)?;
                        if let Some(&k) = links.iter().find(|&&k| y[k].abs() >= pi) {
                            let (mut f0, mut f1) = (vec![0.0; d], vec![0.0; d]);
                            sys.rhs(t, &y0, &mut f0)?;
                            sys.rhs(t + dt, &y, &mut f1)?;
                            return Ok(flip_time(t, dt, (y0[k], f0[k]), (y[k], f1[k])));
                        }
                        if step % 64 == 0 {
                            if !y.iter().all(|v| v.is_finite()) {
                                return Err(Error::integration(t + dt, NON_FINITE));
                            }
                            watch.check(t)?;
                        }
                    }
                    Ok(f64::INFINITY)
                })();
                watch.add_units(1);
                flip.map_err(|e| e.of_trajectory(i))
            },
        )
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn energy_thresholds_give_the_known_flip_bounds() {
        let g = 9.81;
        // Equal point masses: no flip where 2 cos th1 + cos th2 > 1, i.e. E < -g.
        let point = Chain::new(&[1.0, 1.0], &[1.0, 1.0], None, None, g).unwrap();
        assert!((flip_energy_threshold(&point, None).unwrap() + g).abs() < 1e-12);
        // Equal uniform rods: no flip where 3 cos th1 + cos th2 > 2, i.e. E < -g (in units of m l).
        let rods = Chain::rods(&[1.0, 1.0], &[1.0, 1.0], g).unwrap();
        assert!((flip_energy_threshold(&rods, None).unwrap() + g).abs() < 1e-12);
        assert!((flip_energy_threshold(&point, Some(0)).unwrap() - g).abs() < 1e-12);
    }

    #[test]
    fn certified_flips_mark_the_rows_whose_decision_or_time_moves_with_the_step() {
        let chain = Chain::new(&[1.0, 1.0, 1.0], &[1.0, 1.0, 1.0], None, None, 9.81).unwrap();
        let (mut th, mut om) = (Vec::new(), Vec::new());
        for i in 0..40 {
            th.extend([-3.0 + 0.15 * i as f64, 2.5, 0.3]);
            om.extend([0.0; 3]);
        }
        let go = Watch::new();
        let Certified { times, uncertain, tolerance } = certified_flips(&chain, &th, &om, 20.0, 0.02, None, &Builtin::None, None, None, &go).unwrap();
        assert_eq!(tolerance, 0.02, "one step by default");
        let coarse = first_flips(&chain, &th, &om, 20.0, 0.02, None, &Builtin::None, None, &go).unwrap();
        let fine = first_flips(&chain, &th, &om, 20.0, 0.01, None, &Builtin::None, None, &go).unwrap();
        assert!(times.iter().zip(&coarse).all(|(a, b)| a.to_bits() == b.to_bits()), "the times are the run at dt");
        for j in 0..40 {
            let differ = coarse[j].is_finite() != fine[j].is_finite() || (coarse[j] - fine[j]).abs() > 0.02;
            assert_eq!(uncertain[j], differ, "row {j}: {} vs {}", coarse[j], fine[j]);
        }
        // Released high, over 20 s the triple pendulum's chaos moves some flips with the step, and
        // a quick first flip is resolved.
        assert!(uncertain.iter().any(|&u| u) && uncertain.iter().any(|&u| !u), "{uncertain:?}");
        let tight = certified_flips(&chain, &th, &om, 20.0, 0.02, None, &Builtin::None, None, Some(0.0), &go).unwrap().uncertain;
        assert!(tight.iter().zip(&uncertain).all(|(t, u)| *t || !*u));
        let e = certified_flips(&chain, &th, &om, 20.0, 0.02, None, &Builtin::None, None, Some(f64::NAN), &go).unwrap_err();
        assert_eq!(e.to_string(), "time_tolerance must be >= 0 and finite, got NaN");
    }

    #[test]
    fn small_oscillations_have_near_zero_exponents_and_the_spectrum_sums_to_zero() {
        let chain = Chain::new(&[1.0, 1.0], &[1.0, 1.0], None, None, 9.81).unwrap();
        let small = lyapunov(&chain, (&[0.01, 0.0], &[0.0, 0.0], [0.0; 2]), 200.0, 0.01, None, 10, Builtin::None, Drive::none(), &Watch::new()).unwrap();
        assert!(small.exponents.iter().all(|l| l.abs() < 0.05), "{:?}", small.exponents);
        let chaotic = lyapunov(&chain, (&[2.0, 2.5], &[0.0, 0.0], [0.0; 2]), 200.0, 0.005, Some(4), 10, Builtin::None, Drive::none(), &Watch::new()).unwrap();
        let sum: f64 = chaotic.exponents.iter().sum();
        assert!(chaotic.exponents[0] > 0.5, "{:?}", chaotic.exponents);
        assert!(sum.abs() < 0.02 * chaotic.exponents[0], "{:?}", chaotic.exponents);
    }
}
