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
        // The double pendulum (without and with the work integral) on the stack, its loops
        // unrolled: the same operations in the same order, so the same bits.
        match y.len() {
            4 => return step_on_stack::<S, 4>(sys, t, y.try_into().unwrap(), h),
            5 => return step_on_stack::<S, 5>(sys, t, y.try_into().unwrap(), h),
            _ => {}
        }
        let [k1, k2, k3, k4] = &mut self.k;
        let tmp = &mut self.tmp[..y.len()];
        let half = 0.5 * h;
        sys.rhs(t, y, k1)?;
        for ((o, y), k) in tmp.iter_mut().zip(y.iter()).zip(k1.iter()) {
            *o = y + half * k;
        }
        sys.rhs(t + half, tmp, k2)?;
        for ((o, y), k) in tmp.iter_mut().zip(y.iter()).zip(k2.iter()) {
            *o = y + half * k;
        }
        sys.rhs(t + half, tmp, k3)?;
        for ((o, y), k) in tmp.iter_mut().zip(y.iter()).zip(k3.iter()) {
            *o = y + h * k;
        }
        sys.rhs(t + h, tmp, k4)?;
        let sixth = h / 6.0;
        for ((((y, a), b), c), d) in y.iter_mut().zip(k1.iter()).zip(k2.iter()).zip(k3.iter()).zip(k4.iter()) {
            *y += sixth * (a + 2.0 * (b + c) + d);
        }
        Ok(())
    }
}

#[inline(always)]
fn step_on_stack<S: OdeSystem, const D: usize>(sys: &mut S, t: f64, y: &mut [f64; D], h: f64) -> Result<()> {
    let (mut k1, mut k2, mut k3, mut k4, mut tmp) = ([0.0; D], [0.0; D], [0.0; D], [0.0; D], [0.0; D]);
    let half = 0.5 * h;
    sys.rhs(t, y, &mut k1)?;
    for i in 0..D {
        tmp[i] = y[i] + half * k1[i];
    }
    sys.rhs(t + half, &tmp, &mut k2)?;
    for i in 0..D {
        tmp[i] = y[i] + half * k2[i];
    }
    sys.rhs(t + half, &tmp, &mut k3)?;
    for i in 0..D {
        tmp[i] = y[i] + h * k3[i];
    }
    sys.rhs(t + h, &tmp, &mut k4)?;
    let sixth = h / 6.0;
    for i in 0..D {
        y[i] += sixth * (k1[i] + 2.0 * (k2[i] + k3[i]) + k4[i]);
    }
    Ok(())
}
