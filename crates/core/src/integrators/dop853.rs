//! Dormand–Prince 8(5,3) (Hairer, Norsett & Wanner, Solving ODEs I, sec. II.10; the DOP853 code).
//! Explicit, order 8, adaptive: the step is controlled by a combined 5th/3rd-order error estimate
//! against `atol + rtol |y|`; 12 evaluations per step (the last reused as the next step's first),
//! 3 more for the 7th-order dense output used at `t_eval`. Not symplectic. A trial stage that
//! leaves the finite states (a step far too large) is an error norm of `inf`, so the controller
//! shrinks the step instead of giving up (as Hairer's code and SciPy do).
use serde::{Deserialize, Serialize};

use super::dop853_tableau::{A, B, C, D, E3, E5};
use super::{misfit, Facts, Integrator};
use crate::dynamics::system::OdeSystem;
use crate::error::{Error, Result};

pub const FACTS: Facts = Facts { order: 8, symplectic: false, implicit: false, adaptive: true };

pub(super) const STAGES: usize = 12;

#[derive(Debug, Clone)]
pub struct Dop853 {
    dim: usize,
    /// The leading components the error estimate and the first step see (all by default; a run
    /// with sensitivities controls its state only).
    controlled: usize,
    /// 16 stage derivatives: 12 of the step, `f(t+h, y_new)` at 12, 3 for dense output.
    k: Vec<f64>,
    tmp: Vec<f64>,
    /// Dense output coefficients of the last accepted step (7 rows).
    dense: Vec<f64>,
    pub rtol: f64,
    pub atol: f64,
    /// The last step was accepted and its last stage (`f(t + h, y_new)`, first same as last) is
    /// not yet moved to the first: the dense output still needs the old first stage.
    fsal_pending: bool,
    /// `dense` holds the interpolant of the last accepted step.
    dense_ready: bool,
}

/// What a checkpoint keeps: the slope at the current state that the next step starts from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Memory {
    pub slope: Vec<f64>,
}

impl Dop853 {
    pub fn new(dim: usize, rtol: f64, atol: f64) -> Self {
        Dop853 {
            dim,
            controlled: dim,
            k: vec![0.0; 16 * dim],
            tmp: vec![0.0; dim],
            dense: vec![0.0; 7 * dim],
            rtol,
            atol,
            fsal_pending: false,
            dense_ready: false,
        }
    }

    /// Control the error of the first `m` components only (the others ride along).
    pub fn controlling(mut self, m: usize) -> Self {
        self.controlled = m.min(self.dim);
        self
    }

    /// The slope at the current state that the next step starts from.
    pub fn slope(&self) -> &[f64] {
        let d = self.dim;
        if self.fsal_pending {
            &self.k[STAGES * d..(STAGES + 1) * d]
        } else {
            &self.k[..d]
        }
    }

    fn apply_fsal(&mut self) {
        if self.fsal_pending {
            let d = self.dim;
            self.k.copy_within(STAGES * d..(STAGES + 1) * d, 0);
            self.fsal_pending = false;
        }
    }

    /// Hairer's initial step size guess (Solving ODEs I, II.4), after `start`.
    pub fn first_step<S: OdeSystem>(&mut self, sys: &mut S, t: f64, y: &[f64], span: f64) -> Result<f64> {
        let (d, e) = (self.dim, self.controlled);
        let scale = |m: usize| self.atol + y[m].abs() * self.rtol;
        let rms = |v: &dyn Fn(usize) -> f64| rms(e, v);
        let f0 = self.k[..d].to_vec();
        let d0 = rms(&|m| y[m] / scale(m));
        let d1 = rms(&|m| f0[m] / scale(m));
        let mut h0 = first_guess(d0, d1, span);
        let mut f1 = vec![0.0; d];
        // An explicit Euler trial that leaves the finite (or non-singular) states says the
        // guess is far too large: shrink it, as a rejected step would be.
        loop {
            for m in 0..d {
                self.tmp[m] = y[m] + h0 * f0[m];
            }
            match sys.rhs(t + h0, &self.tmp, &mut f1) {
                Ok(()) if f1.iter().all(|v| v.is_finite()) => break,
                Ok(()) | Err(Error::Integration { .. }) if h0 > 1e-300 => h0 *= 0.01,
                Ok(()) => return Err(Error::integration(t, crate::dynamics::system::NON_FINITE)),
                Err(e) => return Err(e),
            }
        }
        let d2 = rms(&|m| (f1[m] - f0[m]) / scale(m)) / h0;
        Ok(first_step_from(h0, d1, d2, span))
    }

    /// Try one step of size `h` from `(t, y)` into `y_new`; the combined error norm (`inf` when a
    /// stage left the finite or non-singular states).
    fn trial<S: OdeSystem>(&mut self, sys: &mut S, t: f64, y: &[f64], h: f64, y_new: &mut [f64]) -> Result<f64> {
        self.apply_fsal();
        self.dense_ready = false;
        let d = self.dim;
        for s in 1..STAGES {
            for m in 0..d {
                let mut acc = 0.0;
                for j in 0..s {
                    acc += A[s][j] * self.k[j * d + m];
                }
                self.tmp[m] = y[m] + h * acc;
            }
            let (_, rest) = self.k.split_at_mut(s * d);
            match sys.rhs(t + C[s] * h, &self.tmp, &mut rest[..d]) {
                Err(Error::Integration { .. }) => return Ok(f64::INFINITY),
                other => other?,
            }
        }
        for m in 0..d {
            let mut acc = 0.0;
            for j in 0..STAGES {
                acc += B[j] * self.k[j * d + m];
            }
            y_new[m] = y[m] + h * acc;
        }
        {
            let (_, rest) = self.k.split_at_mut(STAGES * d);
            match sys.rhs(t + h, y_new, &mut rest[..d]) {
                Err(Error::Integration { .. }) => return Ok(f64::INFINITY),
                other => other?,
            }
        }
        // Combined error norm of DOP853 (scipy's `_estimate_error_norm`).
        let (mut e5, mut e3) = (0.0, 0.0);
        let e = self.controlled;
        for m in 0..e {
            let scale = self.atol + y[m].abs().max(y_new[m].abs()) * self.rtol;
            let (mut a5, mut a3) = (0.0, 0.0);
            for j in 0..=STAGES {
                let kj = self.k[j * d + m];
                a5 += E5[j] * kj;
                a3 += E3[j] * kj;
            }
            e5 += (a5 / scale).powi(2);
            e3 += (a3 / scale).powi(2);
        }
        Ok(combined_error(h, e5, e3, e))
    }

    /// The 7th-order interpolant between `(t, y)` and `(t + h, y_new)` of the last accepted
    /// step: 3 more evaluations, from its stages (so before they are reused).
    fn make_dense<S: OdeSystem>(&mut self, sys: &mut S, t: f64, y: &[f64], y_new: &[f64], h: f64) -> Result<()> {
        debug_assert!(self.fsal_pending, "dense output is made from the stages of the last accepted step");
        let d = self.dim;
        {
            for s in 13..16 {
                for m in 0..d {
                    let mut acc = 0.0;
                    for j in 0..s {
                        acc += A[s][j] * self.k[j * d + m];
                    }
                    self.tmp[m] = y[m] + h * acc;
                }
                let (_, rest) = self.k.split_at_mut(s * d);
                sys.rhs(t + C[s] * h, &self.tmp, &mut rest[..d])?;
            }
            for m in 0..d {
                let rows = interpolant(y[m], y_new[m], h, |j| self.k[j * d + m]);
                for (r, v) in rows.into_iter().enumerate() {
                    self.dense[r * d + m] = v;
                }
            }
        }
        Ok(())
    }

    /// The dense output at fraction `x` of the last step (after `make_dense`).
    fn interpolate_at(&self, y_old: &[f64], x: f64, out: &mut [f64]) {
        let d = self.dim;
        for m in 0..d {
            out[m] = y_old[m] + increment(|r| self.dense[r * d + m], x);
        }
    }
}

/// DOP853's combined error norm of a step `h` from the sums of the squared scaled 5th- and
/// 3rd-order estimates over its `count` controlled components (SciPy's `_estimate_error_norm`).
#[inline]
pub(super) fn combined_error(h: f64, e5: f64, e3: f64, count: usize) -> f64 {
    if e5 == 0.0 && e3 == 0.0 {
        0.0
    } else {
        h.abs() * e5 / ((e5 + 0.01 * e3) * count as f64).sqrt()
    }
}

/// The root mean square of `v(m)` over the first `count` components (the first step's scaled
/// sizes).
#[inline]
pub(super) fn rms(count: usize, v: impl Fn(usize) -> f64) -> f64 {
    let mut sum = 0.0;
    for m in 0..count {
        sum += v(m).powi(2);
    }
    (sum / count as f64).sqrt()
}

/// Hairer's first trial step from the scaled sizes of the state (`d0`) and its rate (`d1`).
pub(super) fn first_guess(d0: f64, d1: f64, span: f64) -> f64 {
    if d0 < 1e-5 || d1 < 1e-5 { 1e-6 } else { 0.01 * d0 / d1 }.min(span)
}

/// Hairer's first step from the trial `h0` and the scaled sizes of the rate (`d1`) and of its
/// change over the trial (`d2`).
pub(super) fn first_step_from(h0: f64, d1: f64, d2: f64, span: f64) -> f64 {
    let h1 = if d1 <= 1e-15 && d2 <= 1e-15 { (h0 * 1e-3).max(1e-6) } else { (0.01 / d1.max(d2)).powf(1.0 / 8.0) };
    (100.0 * h0).min(h1).min(span)
}

/// The 7th-order interpolant's seven coefficients of one component over a step `h` from `y` to
/// `y_new`, from its 16 stages `k(j)` (12 of the step, the last at `y_new`, 3 more).
#[inline]
pub(super) fn interpolant(y: f64, y_new: f64, h: f64, k: impl Fn(usize) -> f64) -> [f64; 7] {
    let dy = y_new - y;
    let (f_old, f_new) = (k(0), k(STAGES));
    let mut rows = [dy, h * f_old - dy, 2.0 * dy - h * (f_new + f_old), 0.0, 0.0, 0.0, 0.0];
    for r in 0..4 {
        let mut acc = 0.0;
        for j in 0..16 {
            acc += D[r][j] * k(j);
        }
        rows[3 + r] = h * acc;
    }
    rows
}

/// The interpolant's increment over the step's start at fraction `x`, from its seven
/// coefficients `row(r)` of one component.
#[inline]
pub(super) fn increment(row: impl Fn(usize) -> f64, x: f64) -> f64 {
    let mut acc = 0.0;
    for (i, r) in (0..7).rev().enumerate() {
        acc += row(r);
        acc *= if i % 2 == 0 { x } else { 1.0 - x };
    }
    acc
}

impl Integrator for Dop853 {
    type Memory = Memory;

    fn facts(&self) -> Facts {
        FACTS
    }

    /// `f(t, y)` for the first step (later steps reuse the last stage).
    fn start<S: OdeSystem>(&mut self, sys: &mut S, t: f64, y: &[f64]) -> Result<()> {
        let d = self.dim;
        self.fsal_pending = false;
        self.dense_ready = false;
        sys.rhs(t, y, &mut self.k[..d])
    }

    #[inline]
    fn attempt<S: OdeSystem>(&mut self, sys: &mut S, t: f64, y: &[f64], h: f64, y_new: &mut [f64]) -> Result<Option<f64>> {
        self.trial(sys, t, y, h, y_new).map(Some)
    }

    fn accept(&mut self) {
        self.fsal_pending = true;
    }

    fn dense<S: OdeSystem>(&mut self, sys: &mut S, t: f64, y: &[f64], h: f64, _t_new: f64, y_new: &[f64]) -> Result<()> {
        if !self.dense_ready {
            self.make_dense(sys, t, y, y_new, h)?;
            self.dense_ready = true;
        }
        Ok(())
    }

    fn interpolate(&self, y: &[f64], _y_new: &[f64], _h: f64, x: f64, out: &mut [f64]) {
        self.interpolate_at(y, x, out)
    }

    fn save(&self) -> Memory {
        Memory { slope: self.slope().to_vec() }
    }

    /// Start from a saved slope instead of evaluating it, as the run it came from did.
    fn restore(&mut self, m: Memory) -> Result<()> {
        if m.slope.len() != self.dim {
            return Err(misfit("dop853", format!("{} slopes expected, got {}", self.dim, m.slope.len())));
        }
        self.k[..self.dim].copy_from_slice(&m.slope);
        self.fsal_pending = false;
        self.dense_ready = false;
        Ok(())
    }

    fn save_any(&self) -> super::AnyMemory {
        super::AnyMemory::Dop853(self.save())
    }

    fn restore_any(&mut self, memory: super::AnyMemory) -> Result<()> {
        match memory {
            super::AnyMemory::Dop853(m) => self.restore(m),
            _ => Err(super::other_method("dop853")),
        }
    }

    fn name(&self) -> &'static str {
        "dop853"
    }

    fn initial_step<S: OdeSystem>(&mut self, sys: &mut S, t: f64, y: &[f64], span: f64) -> Result<Option<f64>> {
        self.first_step(sys, t, y, span).map(Some)
    }
}
