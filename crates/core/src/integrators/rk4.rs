//! Classical fourth-order Runge–Kutta (Kutta 1901), the integrator of seed 001.
//! Explicit, order 4, not symplectic (energy drifts secularly), 4 evaluations per step; dense
//! output by cubic Hermite interpolation (2 more evaluations per step that has output inside).
use super::dense::{Hermite, Slope};
use super::{Facts, Integrator};
use crate::dynamics::system::OdeSystem;
use crate::error::Result;

pub const FACTS: Facts = Facts { order: 4, symplectic: false, implicit: false, adaptive: false };

#[derive(Debug, Clone)]
pub struct Rk4 {
    k: [Vec<f64>; 4],
    tmp: Vec<f64>,
    dense: Hermite,
}

impl Rk4 {
    pub fn new(dim: usize) -> Self {
        Rk4 { k: std::array::from_fn(|_| vec![0.0; dim]), tmp: vec![0.0; dim], dense: Hermite::new(dim) }
    }

    /// One step of `h` from `(t, y)` into `y_new`, for kernels that drive the method themselves.
    #[inline]
    pub fn step<S: OdeSystem>(&mut self, sys: &mut S, t: f64, y: &[f64], h: f64, y_new: &mut [f64]) -> Result<()> {
        // The double pendulum (without and with the work integral) on the stack, where the
        // constant lengths let the loops unroll; the same body, so the same bits.
        match y.len() {
            4 => return stages(sys, t, y, h, y_new, &mut [[0.0; 4]; 5]),
            5 => return stages(sys, t, y, h, y_new, &mut [[0.0; 5]; 5]),
            _ => {}
        }
        let [k1, k2, k3, k4] = &mut self.k;
        stages(sys, t, y, h, y_new, &mut [k1, k2, k3, k4, &mut self.tmp])
    }
}

impl Integrator for Rk4 {
    type Memory = Slope;

    fn facts(&self) -> Facts {
        FACTS
    }

    fn start<S: OdeSystem>(&mut self, _sys: &mut S, _t: f64, _y: &[f64]) -> Result<()> {
        self.dense.forget();
        Ok(())
    }

    #[inline]
    fn attempt<S: OdeSystem>(&mut self, sys: &mut S, t: f64, y: &[f64], h: f64, y_new: &mut [f64]) -> Result<Option<f64>> {
        self.step(sys, t, y, h, y_new)?;
        Ok(None)
    }

    fn accept(&mut self) {
        self.dense.accept();
    }

    fn dense<S: OdeSystem>(&mut self, sys: &mut S, t: f64, y: &[f64], _h: f64, t_new: f64, y_new: &[f64]) -> Result<()> {
        self.dense.prepare(sys, t, y, t_new, y_new)
    }

    fn interpolate(&self, y: &[f64], y_new: &[f64], h: f64, x: f64, out: &mut [f64]) {
        self.dense.interpolate(y, y_new, h, x, out)
    }

    fn save(&self) -> Slope {
        self.dense.save()
    }

    fn restore(&mut self, memory: Slope) -> Result<()> {
        self.dense.restore(memory, "rk4")
    }

    fn save_any(&self) -> super::AnyMemory {
        super::AnyMemory::Rk4(self.save())
    }

    fn restore_any(&mut self, memory: super::AnyMemory) -> Result<()> {
        match memory {
            super::AnyMemory::Rk4(m) => self.restore(m),
            _ => Err(super::other_method("rk4")),
        }
    }

    fn name(&self) -> &'static str {
        "rk4"
    }
}

/// The four stages and the weighted sum, in buffers `[k1, k2, k3, k4, tmp]` of `y`'s length.
#[inline(always)]
fn stages<S: OdeSystem, B: AsMut<[f64]>>(sys: &mut S, t: f64, y: &[f64], h: f64, y_new: &mut [f64], buf: &mut [B; 5]) -> Result<()> {
    let [k1, k2, k3, k4, tmp] = buf.each_mut().map(|b| &mut b.as_mut()[..y.len()]);
    // Of y's length too, so the loops below see one length (constant for the double pendulum).
    let y_new = &mut y_new[..y.len()];
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
    for (((((o, y), a), b), c), d) in y_new.iter_mut().zip(y.iter()).zip(k1.iter()).zip(k2.iter()).zip(k3.iter()).zip(k4.iter()) {
        *o = y + sixth * (a + 2.0 * (b + c) + d);
    }
    Ok(())
}
