//! [`Dop853`](super::Dop853) in SIMD lanes: eight states of one chain, each with its own time
//! and its own step, taken together through the twelve stages (a lane whose trial is rejected,
//! or that has no state, rides along and keeps its values). The stage sums are fused by
//! explicit `mul_add`, as [`super::lanes::Rk4Lanes`]' (the same bits on the AVX-512, AVX2 and
//! portable paths; a lane's bits never depend on the other lanes). The step-size control, the
//! first step, the error norm and the dense output are the scalar method's, per lane (its
//! [`super::Controller`] and helpers), so a lane follows the per-trajectory run's steps to
//! round-off. Used by `chaos::ensemble`, inside its `#[target_feature]` wrappers.
use super::dop853::{combined_error, first_guess, first_step_from, increment, interpolant, rms, STAGES};
use super::dop853_tableau::{A, B, C, E3, E5};
use super::lanes::LaneSystem;
use crate::dynamics::lanes::{LaneScratch, LaneSingular};
use crate::dynamics::Singular;
use crate::trig::lanes::{each, Lane, LANES};

/// Why a lane's first step could not be found: a singular configuration (its link), or rates
/// that are not finite however small the trial.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum StartFailure {
    Singular(Singular),
    NonFinite,
}

/// DOP853's stages, dense output and tolerances for eight states of `dim` lanes each.
#[derive(Debug, Clone)]
pub struct Dop853Lanes {
    dim: usize,
    /// The leading components the error norm and the first step see.
    controlled: usize,
    /// 16 stages: 12 of the step, `f(t + h, y_new)` at 12, 3 for the dense output.
    k: Vec<Vec<Lane>>,
    tmp: Vec<Lane>,
    /// Rates of lanes being started (`f(t, y)` and the first step's trial).
    f: Vec<Lane>,
    /// The interpolant's 7 coefficients of the last step, per component.
    dense: Vec<Lane>,
    scratch: LaneScratch,
    rtol: f64,
    atol: f64,
}

/// Whether any lane is set.
#[inline(always)]
fn any(lanes: &[bool; LANES]) -> bool {
    lanes.iter().any(|&b| b)
}

/// The lanes set as an activity mask (`1` or `0`).
#[inline(always)]
pub fn mask(lanes: &[bool; LANES]) -> Lane {
    lanes.map(|b| if b { 1.0 } else { 0.0 })
}

impl Dop853Lanes {
    /// Buffers for a system of `dim` lanes per state built on an N-link chain, its leading
    /// `controlled` components under the tolerances `rtol`, `atol`.
    pub fn new(n: usize, dim: usize, controlled: usize, rtol: f64, atol: f64) -> Self {
        let lanes = |k| vec![[0.0; LANES]; k];
        Dop853Lanes {
            dim,
            controlled: controlled.min(dim),
            k: (0..16).map(|_| lanes(dim)).collect(),
            tmp: lanes(dim),
            f: lanes(dim),
            dense: lanes(7 * dim),
            scratch: LaneScratch::new(n),
            rtol,
            atol,
        }
    }

    /// The rates at `(t + c h, src)` into `dst`; the active lanes whose accelerations failed.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    fn eval(sys: &mut impl LaneSystem, t: &Lane, c: f64, h: &Lane, src: &[Lane], dst: &mut [Lane], scratch: &mut LaneScratch, active: &Lane) -> [bool; LANES] {
        let at: Lane = each(|i| t[i] + c * h[i]);
        match sys.rates(&at, src, dst, scratch, active) {
            Ok(()) => [false; LANES],
            Err(s) => s.lanes,
        }
    }

    /// Start the lanes `fresh` at `(t, y)`: their first stage `f(t, y)` and their first step
    /// towards a span of `span` (Hairer's guess, as [`super::Dop853::first_step`]; `dt`: that
    /// step instead, cut to the span). The other lanes keep what they had. `Err((lane, why))`:
    /// the first lane that cannot start.
    #[inline(always)]
    pub fn start(
        &mut self,
        sys: &mut impl LaneSystem,
        t: &Lane,
        y: &[Lane],
        fresh: &[bool; LANES],
        span: &Lane,
        dt: Option<f64>,
    ) -> Result<Lane, (usize, StartFailure)> {
        let (d, e) = (self.dim, self.controlled);
        let active = mask(fresh);
        let zero = [0.0; LANES];
        let bad = Self::eval(sys, t, 0.0, &zero, y, &mut self.f, &mut self.scratch, &active);
        if let Some(j) = (0..LANES).find(|&j| bad[j]) {
            return Err((j, self.singular(sys, t, y, j)));
        }
        for (k0, f) in self.k[0].iter_mut().zip(&self.f) {
            for i in 0..LANES {
                k0[i] = if fresh[i] { f[i] } else { k0[i] };
            }
        }
        let mut h = [0.0; LANES];
        if let Some(dt) = dt {
            for i in 0..LANES {
                h[i] = if fresh[i] { dt.min(span[i]) } else { 0.0 };
            }
            return Ok(h);
        }
        // Per lane, as the scalar method: the scaled sizes, then explicit Euler trials shrunk
        // until their rates are finite and regular.
        let (atol, rtol) = (self.atol, self.rtol);
        let rms = |v: &dyn Fn(usize) -> f64| rms(e, v);
        let mut h0 = [0.0; LANES];
        let mut d1s = [0.0; LANES];
        for i in (0..LANES).filter(|&i| fresh[i]) {
            let scale = |m: usize| atol + y[m][i].abs() * rtol;
            let d0 = rms(&|m| y[m][i] / scale(m));
            d1s[i] = rms(&|m| self.k[0][m][i] / scale(m));
            h0[i] = first_guess(d0, d1s[i], span[i]);
        }
        let mut pending = *fresh;
        while any(&pending) {
            for ((t, yv), f) in self.tmp.iter_mut().zip(y).zip(&self.k[0]) {
                for i in 0..LANES {
                    t[i] = yv[i] + h0[i] * f[i];
                }
            }
            let singular = Self::eval(sys, t, 1.0, &h0, &self.tmp, &mut self.f, &mut self.scratch, &mask(&pending));
            let trying = pending;
            for i in (0..LANES).filter(|&i| trying[i]) {
                let finite = self.f[..d].iter().all(|f| f[i].is_finite());
                if finite && !singular[i] {
                    let scale = |m: usize| atol + y[m][i].abs() * rtol;
                    let d2 = rms(&|m| (self.f[m][i] - self.k[0][m][i]) / scale(m)) / h0[i];
                    h[i] = first_step_from(h0[i], d1s[i], d2, span[i]);
                    pending[i] = false;
                } else if h0[i] > 1e-300 {
                    h0[i] *= 0.01;
                } else if singular[i] {
                    let at: Lane = each(|l| t[l] + h0[l]);
                    let tmp = std::mem::take(&mut self.tmp);
                    return Err((i, self.singular(sys, &at, &tmp, i)));
                } else {
                    return Err((i, StartFailure::NonFinite));
                }
            }
        }
        Ok(h)
    }

    /// Why lane `i`'s accelerations at `(t, y)` failed: its own first failing link.
    #[inline(always)]
    fn singular(&mut self, sys: &mut impl LaneSystem, t: &Lane, y: &[Lane], i: usize) -> StartFailure {
        let alone = mask(&std::array::from_fn(|l| l == i));
        match sys.rates(t, y, &mut self.f, &mut self.scratch, &alone) {
            Err(s) => StartFailure::Singular(s.link),
            Ok(()) => StartFailure::NonFinite,
        }
    }

    /// A trial step of size `h` (per lane) of the `active` lanes from `(t, y)` into `y_new`: the
    /// combined error norm of each, `inf` where a stage's accelerations failed (the controller
    /// then shrinks the step, as the scalar method's). The lanes' last stage is kept for
    /// [`Dop853Lanes::accept`] and [`Dop853Lanes::dense`].
    #[inline(always)]
    pub fn trial(&mut self, sys: &mut impl LaneSystem, t: &Lane, y: &[Lane], h: &Lane, y_new: &mut [Lane], active: &Lane) -> Lane {
        let Dop853Lanes { controlled: e, k, tmp, scratch, rtol, atol, .. } = self;
        let e = *e;
        let mut bad = [false; LANES];
        for s in 1..STAGES {
            let (done, rest) = k.split_at_mut(s);
            combine(&A[s][..s], done, y, h, tmp);
            let failed = Self::eval(sys, t, C[s], h, tmp, &mut rest[0], scratch, active);
            for i in 0..LANES {
                bad[i] |= failed[i];
            }
        }
        combine(&B[..STAGES], &k[..STAGES], y, h, y_new);
        let at: Lane = each(|i| t[i] + h[i]);
        if let Err(s) = sys.rates(&at, y_new, &mut k[STAGES], scratch, active) {
            for i in 0..LANES {
                bad[i] |= s.lanes[i];
            }
        }
        let (mut e5, mut e3) = ([0.0; LANES], [0.0; LANES]);
        for m in 0..e {
            let (mut a5, mut a3) = ([0.0; LANES], [0.0; LANES]);
            for (j, kj) in k.iter().enumerate().take(STAGES + 1) {
                let (c5, c3) = (E5[j], E3[j]);
                for i in 0..LANES {
                    a5[i] += c5 * kj[m][i];
                    a3[i] += c3 * kj[m][i];
                }
            }
            for i in 0..LANES {
                let scale = *atol + y[m][i].abs().max(y_new[m][i].abs()) * *rtol;
                e5[i] += (a5[i] / scale).powi(2);
                e3[i] += (a3[i] / scale).powi(2);
            }
        }
        each(|i| if bad[i] { f64::INFINITY } else { combined_error(h[i], e5[i], e3[i], e) })
    }

    /// The last trials of the lanes `accepted` became their states: their next step starts from
    /// the trial's last stage (first same as last).
    #[inline(always)]
    pub fn accept(&mut self, accepted: &[bool; LANES]) {
        let (first, rest) = self.k.split_at_mut(1);
        for (k0, k12) in first[0].iter_mut().zip(&rest[STAGES - 1]) {
            for i in 0..LANES {
                k0[i] = if accepted[i] { k12[i] } else { k0[i] };
            }
        }
    }

    /// The interpolant of the last trial of the lanes `lanes` (before [`Dop853Lanes::accept`]):
    /// three more stages, then its coefficients. `Err` if a stage's accelerations failed.
    #[inline(always)]
    pub fn dense(&mut self, sys: &mut impl LaneSystem, t: &Lane, y: &[Lane], y_new: &[Lane], h: &Lane, lanes: &[bool; LANES]) -> Result<(), LaneSingular> {
        let active = mask(lanes);
        let Dop853Lanes { dim: d, k, tmp, scratch, dense, .. } = self;
        for s in STAGES + 1..16 {
            let (done, rest) = k.split_at_mut(s);
            combine(&A[s][..s], done, y, h, tmp);
            let at: Lane = each(|i| t[i] + C[s] * h[i]);
            sys.rates(&at, tmp, &mut rest[0], scratch, &active).map_err(|s| s.seen_in(tmp))?;
        }
        for m in 0..*d {
            for i in (0..LANES).filter(|&i| lanes[i]) {
                let rows = interpolant(y[m][i], y_new[m][i], h[i], |j| k[j][m][i]);
                for (r, v) in rows.into_iter().enumerate() {
                    dense[r * *d + m][i] = v;
                }
            }
        }
        Ok(())
    }

    /// Lane `i`'s state at fraction `x` of its last step from `y_old` (after [`Dop853Lanes::dense`]).
    pub fn interpolate(&self, i: usize, y_old: &[Lane], x: f64, out: &mut [f64]) {
        let d = self.dim;
        for (m, o) in out.iter_mut().enumerate().take(d) {
            *o = y_old[m][i] + increment(|r| self.dense[r * d + m][i], x);
        }
    }
}

/// `out = y + h (sum_j a_j k_j)` over the lanes, the sum fused and its zero terms skipped.
#[inline(always)]
fn combine(a: &[f64], k: &[Vec<Lane>], y: &[Lane], h: &Lane, out: &mut [Lane]) {
    for (m, (o, yv)) in out.iter_mut().zip(y).enumerate() {
        let mut acc = [0.0; LANES];
        for (&c, kj) in a.iter().zip(k) {
            if c == 0.0 {
                continue;
            }
            let kv = &kj[m];
            for i in 0..LANES {
                acc[i] = c.mul_add(kv[i], acc[i]);
            }
        }
        for i in 0..LANES {
            o[i] = h[i].mul_add(acc[i], yv[i]);
        }
    }
}
