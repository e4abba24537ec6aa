//! Integrators, each a small type with a declared order. Names are shared by Python, the CLI and
//! the viewer: `rk4`, `dop853`, `gauss4`, `gauss6`.
pub mod dop853;
mod dop853_tableau;
pub mod gauss;
pub mod rk4;

use crate::error::{Error, Result};
use crate::system::OdeSystem;

pub use dop853::Dop853;
pub use gauss::Gauss;
pub use rk4::Rk4;

/// A one-step method with a fixed step size.
pub trait FixedStep {
    /// Classical order of accuracy (global error ~ dt^order).
    fn order(&self) -> u32;
    /// Whether the one-step map is symplectic on Hamilton's equations.
    fn symplectic(&self) -> bool;
    /// Advance `y` from `t` to `t + h` in place.
    fn step<S: OdeSystem>(&mut self, sys: &mut S, t: f64, y: &mut [f64], h: f64) -> Result<()>;
    /// Fixed-point iterations so far (implicit methods).
    fn iterations(&self) -> u64 {
        0
    }
    /// What later steps depend on, for a checkpoint (nothing for a method without memory).
    fn carry(&self) -> Carry {
        Carry::default()
    }
    /// Continue from a [`FixedStep::carry`]; refuses one of another method or size.
    fn restore(&mut self, carry: &Carry) -> Result<()> {
        if carry == &Carry::default() {
            Ok(())
        } else {
            Err(Error::input("the checkpoint's integrator state is not that of this method"))
        }
    }
}

/// An integrator's state carried from one step to the next, as plain numbers (checkpoints).
/// dop853: `k` the slope at the current state (first-same-as-last), `h` the next step to try;
/// gauss4/gauss6: `k` the stage slopes (stages x dim, the next step's starting guess), `comp`
/// the compensated-summation residuals, `h` the last step (the guess is extrapolated only when
/// the next step has exactly this size); rk4: nothing.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Carry {
    pub k: Vec<f64>,
    pub comp: Vec<f64>,
    pub h: Option<f64>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Method {
    Rk4,
    Dop853,
    Gauss4,
    Gauss6,
}

impl Method {
    pub const ALL: [Method; 4] = [Method::Rk4, Method::Dop853, Method::Gauss4, Method::Gauss6];

    pub fn name(self) -> &'static str {
        match self {
            Method::Rk4 => "rk4",
            Method::Dop853 => "dop853",
            Method::Gauss4 => "gauss4",
            Method::Gauss6 => "gauss6",
        }
    }

    pub fn order(self) -> u32 {
        match self {
            Method::Rk4 | Method::Gauss4 => 4,
            Method::Dop853 => 8,
            Method::Gauss6 => 6,
        }
    }

    pub fn symplectic(self) -> bool {
        matches!(self, Method::Gauss4 | Method::Gauss6)
    }

    pub fn adaptive(self) -> bool {
        self == Method::Dop853
    }

    pub fn parse(name: &str) -> Result<Self> {
        Self::ALL.into_iter().find(|m| m.name() == name).ok_or_else(|| {
            let valid: Vec<&str> = Self::ALL.iter().map(|m| m.name()).collect();
            Error::input(format!("method must be one of {}, got {name:?}", valid.join(", ")))
        })
    }
}
