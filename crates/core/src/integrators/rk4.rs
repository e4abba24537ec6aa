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
        // The double pendulum (without and with the work integral) on the stack, where the
        // constant lengths let the loops unroll; the same body, so the same bits.
        match y.len() {
            4 => return stages(sys, t, y, h, &mut [[0.0; 4]; 5]),
            5 => return stages(sys, t, y, h, &mut [[0.0; 5]; 5]),
            _ => {}
        }
        let [k1, k2, k3, k4] = &mut self.k;
        stages(sys, t, y, h, &mut [k1, k2, k3, k4, &mut self.tmp])
    }
}

/// The four stages and the weighted sum, in buffers `[k1, k2, k3, k4, tmp]` of `y`'s length.
#[inline(always)]
fn stages<S: OdeSystem, B: AsMut<[f64]>>(sys: &mut S, t: f64, y: &mut [f64], h: f64, buf: &mut [B; 5]) -> Result<()> {
    let [k1, k2, k3, k4, tmp] = buf.each_mut().map(|b| &mut b.as_mut()[..y.len()]);
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
