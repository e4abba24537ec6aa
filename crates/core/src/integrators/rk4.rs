//! Classical fourth-order Runge–Kutta (Kutta 1901), the integrator of seed 001.
//! Explicit, order 4, not symplectic (energy drifts secularly), 4 evaluations per step.
use super::FixedStep;
use crate::error::Result;
use crate::system::OdeSystem;

#[derive(Debug, Clone)]
pub struct Rk4 {
    k: [Vec<f64>; 4],
    tmp: Vec<f64>,
}

impl Rk4 {
    pub fn new(dim: usize) -> Self {
        Rk4 { k: std::array::from_fn(|_| vec![0.0; dim]), tmp: vec![0.0; dim] }
    }
}

impl FixedStep for Rk4 {
    fn order(&self) -> u32 {
        4
    }
    fn symplectic(&self) -> bool {
        false
    }

    #[inline]
    fn step<S: OdeSystem>(&mut self, sys: &mut S, t: f64, y: &mut [f64], h: f64) -> Result<()> {
        let [k1, k2, k3, k4] = &mut self.k;
        let tmp = &mut self.tmp;
        sys.rhs(t, y, k1)?;
        for i in 0..y.len() {
            tmp[i] = y[i] + 0.5 * h * k1[i];
        }
        sys.rhs(t + 0.5 * h, tmp, k2)?;
        for i in 0..y.len() {
            tmp[i] = y[i] + 0.5 * h * k2[i];
        }
        sys.rhs(t + 0.5 * h, tmp, k3)?;
        for i in 0..y.len() {
            tmp[i] = y[i] + h * k3[i];
        }
        sys.rhs(t + h, tmp, k4)?;
        for i in 0..y.len() {
            y[i] += h / 6.0 * (k1[i] + 2.0 * (k2[i] + k3[i]) + k4[i]);
        }
        Ok(())
    }
}
