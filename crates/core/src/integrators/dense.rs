//! Dense output of the fixed-step methods: the cubic Hermite interpolant of a step from the
//! states and slopes at its two ends. The slopes are evaluated only when output inside a step is
//! asked for; the end's slope is the next step's start slope, kept while the state stays.
use serde::{Deserialize, Serialize};

use crate::dynamics::system::OdeSystem;
use crate::error::Result;
use crate::interp::hermite;

#[derive(Debug, Clone)]
pub struct Hermite {
    /// The slope at the start of the last accepted step, when `start_known`.
    start: Vec<f64>,
    /// The slope at the current state (the end of the last step), when `end_known`.
    end: Vec<f64>,
    start_known: bool,
    end_known: bool,
}

/// What a checkpoint keeps of a [`Hermite`]: the slope at the current state, if known (so the
/// resumed run evaluates exactly what the uninterrupted one did).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Slope(pub Option<Vec<f64>>);

impl Hermite {
    pub fn new(dim: usize) -> Self {
        Hermite { start: vec![0.0; dim], end: vec![0.0; dim], start_known: false, end_known: false }
    }

    /// The state changed from outside: nothing known.
    pub fn forget(&mut self) {
        self.start_known = false;
        self.end_known = false;
    }

    /// A step was accepted: the slope at the old state, if known, is the new step's start slope.
    pub fn accept(&mut self) {
        std::mem::swap(&mut self.start, &mut self.end);
        self.start_known = self.end_known;
        self.end_known = false;
    }

    pub fn prepare<S: OdeSystem>(&mut self, sys: &mut S, t: f64, y: &[f64], t_new: f64, y_new: &[f64]) -> Result<()> {
        if !self.start_known {
            sys.rhs(t, y, &mut self.start)?;
            self.start_known = true;
        }
        if !self.end_known {
            sys.rhs(t_new, y_new, &mut self.end)?;
            self.end_known = true;
        }
        Ok(())
    }

    pub fn interpolate(&self, y: &[f64], y_new: &[f64], h: f64, x: f64, out: &mut [f64]) {
        hermite(y, &self.start, y_new, &self.end, h, x, out);
    }

    pub fn save(&self) -> Slope {
        Slope(self.end_known.then(|| self.end.clone()))
    }

    pub fn restore(&mut self, slope: Slope, method: &str) -> Result<()> {
        self.start_known = false;
        match slope.0 {
            None => self.end_known = false,
            Some(v) if v.len() == self.end.len() => {
                self.end.copy_from_slice(&v);
                self.end_known = true;
            }
            Some(v) => return Err(super::misfit(method, format!("{} slope values, expected {}", v.len(), self.end.len()))),
        }
        Ok(())
    }
}
