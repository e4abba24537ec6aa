//! Dormand–Prince 8(5,3) (Hairer, Norsett & Wanner, Solving ODEs I, sec. II.10; the DOP853 code).
//! Explicit, order 8, adaptive: the step is controlled by a combined 5th/3rd-order error estimate
//! against `atol + rtol |y|`; 12 evaluations per step (the last reused as the next step's first),
//! 3 more for the 7th-order dense output used at `t_eval`. Not symplectic.
use super::dop853_tableau::{A, B, C, D, E3, E5};
use crate::error::{Error, Result};
use crate::system::OdeSystem;

const STAGES: usize = 12;
const SAFETY: f64 = 0.9;
const MIN_FACTOR: f64 = 0.2;
const MAX_FACTOR: f64 = 10.0;

#[derive(Debug, Clone)]
pub struct Dop853 {
    dim: usize,
    /// 16 stage derivatives: 12 of the step, `f(t+h, y_new)` at 12, 3 for dense output.
    k: Vec<f64>,
    tmp: Vec<f64>,
    /// Dense output coefficients of the last accepted step (7 rows).
    dense: Vec<f64>,
    pub rtol: f64,
    pub atol: f64,
}

/// Outcome of one attempted step.
pub enum Attempt {
    /// Accepted; the proposal for the next step size.
    Accepted { h_next: f64 },
    /// Rejected; try again with this step size.
    Rejected { h_next: f64 },
}

impl Dop853 {
    pub fn new(dim: usize, rtol: f64, atol: f64) -> Self {
        Dop853 { dim, k: vec![0.0; 16 * dim], tmp: vec![0.0; dim], dense: vec![0.0; 7 * dim], rtol, atol }
    }

    pub fn order(&self) -> u32 {
        8
    }

    /// `f(t, y)` for the first step (later steps reuse the last stage).
    pub fn start<S: OdeSystem>(&mut self, sys: &mut S, t: f64, y: &[f64]) -> Result<()> {
        let d = self.dim;
        sys.rhs(t, y, &mut self.k[..d])
    }

    /// The slope at the current state that the next step starts from (for a checkpoint).
    pub fn slope(&self) -> &[f64] {
        &self.k[..self.dim]
    }

    /// Start from a saved [`Dop853::slope`] instead of evaluating it, as the run it came from did.
    pub fn resume(&mut self, slope: &[f64]) -> Result<()> {
        if slope.len() != self.dim {
            return Err(Error::input(format!(
                "the checkpoint's integrator state does not fit dop853: {} slopes expected, got {}",
                self.dim,
                slope.len()
            )));
        }
        self.k[..self.dim].copy_from_slice(slope);
        Ok(())
    }

    /// Hairer's initial step size guess (Solving ODEs I, II.4), after `start`.
    pub fn initial_step<S: OdeSystem>(&mut self, sys: &mut S, t: f64, y: &[f64], span: f64) -> Result<f64> {
        let d = self.dim;
        let scale = |m: usize| self.atol + y[m].abs() * self.rtol;
        let rms = |v: &dyn Fn(usize) -> f64| ((0..d).map(|m| v(m).powi(2)).sum::<f64>() / d as f64).sqrt();
        let f0 = self.k[..d].to_vec();
        let d0 = rms(&|m| y[m] / scale(m));
        let d1 = rms(&|m| f0[m] / scale(m));
        let h0 = if d0 < 1e-5 || d1 < 1e-5 { 1e-6 } else { 0.01 * d0 / d1 }.min(span);
        for m in 0..d {
            self.tmp[m] = y[m] + h0 * f0[m];
        }
        let mut f1 = vec![0.0; d];
        sys.rhs(t + h0, &self.tmp, &mut f1)?;
        let d2 = rms(&|m| (f1[m] - f0[m]) / scale(m)) / h0;
        let h1 = if d1 <= 1e-15 && d2 <= 1e-15 {
            (h0 * 1e-3).max(1e-6)
        } else {
            (0.01 / d1.max(d2)).powf(1.0 / 8.0)
        };
        Ok((100.0 * h0).min(h1).min(span))
    }

    /// Try one step of size `h` from `(t, y)`; on acceptance `y_new` holds the new state and the
    /// stages are kept for `prepare_dense`. With `fixed` the step is accepted whatever its error.
    pub fn attempt<S: OdeSystem>(
        &mut self,
        sys: &mut S,
        t: f64,
        y: &[f64],
        h: f64,
        y_new: &mut [f64],
        rejected_before: bool,
        fixed: bool,
    ) -> Result<Attempt> {
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
            sys.rhs(t + C[s] * h, &self.tmp, &mut rest[..d])?;
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
            sys.rhs(t + h, y_new, &mut rest[..d])?;
        }
        if fixed {
            return Ok(Attempt::Accepted { h_next: h });
        }
        // Combined error norm of DOP853 (scipy's `_estimate_error_norm`).
        let (mut e5, mut e3) = (0.0, 0.0);
        for m in 0..d {
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
        let err = if e5 == 0.0 && e3 == 0.0 { 0.0 } else { h.abs() * e5 / ((e5 + 0.01 * e3) * d as f64).sqrt() };
        let exponent = -1.0 / 8.0;
        if err < 1.0 {
            let mut factor = if err == 0.0 { MAX_FACTOR } else { MAX_FACTOR.min(SAFETY * err.powf(exponent)) };
            if rejected_before {
                factor = factor.min(1.0);
            }
            Ok(Attempt::Accepted { h_next: h * factor })
        } else if err.is_finite() {
            Ok(Attempt::Rejected { h_next: h * MIN_FACTOR.max(SAFETY * err.powf(exponent)) })
        } else {
            Ok(Attempt::Rejected { h_next: h * MIN_FACTOR })
        }
    }

    /// After an accepted step, make the first stage of the next step and (if `dense`) the 7th
    /// order interpolant between `(t, y)` and `(t + h, y_new)`: 3 more evaluations.
    pub fn finish_step<S: OdeSystem>(
        &mut self,
        sys: &mut S,
        t: f64,
        y: &[f64],
        y_new: &[f64],
        h: f64,
        dense: bool,
    ) -> Result<()> {
        let d = self.dim;
        if dense {
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
                let dy = y_new[m] - y[m];
                let (f_old, f_new) = (self.k[m], self.k[STAGES * d + m]);
                self.dense[m] = dy;
                self.dense[d + m] = h * f_old - dy;
                self.dense[2 * d + m] = 2.0 * dy - h * (f_new + f_old);
                for r in 0..4 {
                    let mut acc = 0.0;
                    for j in 0..16 {
                        acc += D[r][j] * self.k[j * d + m];
                    }
                    self.dense[(3 + r) * d + m] = h * acc;
                }
            }
        }
        // FSAL: the last stage is the next step's first.
        self.k.copy_within(STAGES * d..(STAGES + 1) * d, 0);
        Ok(())
    }

    /// The dense output at fraction `x` of the last step (after `finish_step(.., dense = true)`).
    pub fn interpolate(&self, y_old: &[f64], x: f64, out: &mut [f64]) {
        let d = self.dim;
        for m in 0..d {
            let mut acc = 0.0;
            for (i, r) in (0..7).rev().enumerate() {
                acc += self.dense[r * d + m];
                acc *= if i % 2 == 0 { x } else { 1.0 - x };
            }
            out[m] = y_old[m] + acc;
        }
    }
}
