//! Integrators, each a small type behind one trait ([`Integrator`]) with its declared facts
//! ([`Facts`]: order, symplectic, implicit, adaptive) and a typed memory that a checkpoint saves
//! and restores. Names are shared by Python, the CLI and the viewer: `rk4`, `dop853`, `gauss4`,
//! `gauss6`; [`Method`] is the enum at the boundary, and its facts come from the integrators.
//!
//! Every integrator maps `(t, y)` and a step `h` to a trial state `y_new` without touching `y`
//! ([`Integrator::attempt`]); the run driver keeps or drops it (and swaps buffers instead of
//! copying). Dense output over the last accepted step is the integrator's own
//! ([`Integrator::dense`], [`Integrator::interpolate`]): DOP853's 7th-order interpolant, or the
//! cubic Hermite interpolant of the fixed-step methods ([`dense::Hermite`]). Step-size control
//! is a small type of its own ([`control::Controller`]).
pub mod control;
pub mod dense;
pub mod dop853;
pub mod dop853_lanes;
mod dop853_tableau;
pub mod gauss;
pub mod lanes;
pub mod rk4;

use serde::{Deserialize, Serialize};

use crate::dynamics::system::OdeSystem;
use crate::error::{Error, Result};

pub use control::{Controller, Decision};
pub use dop853::Dop853;
pub use gauss::Gauss;
pub use rk4::Rk4;

/// What an integrator is, as stated facts (the tests measure the order).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Facts {
    /// Classical order of accuracy (global error ~ dt^order).
    pub order: u32,
    /// Whether the one-step map is symplectic on Hamilton's equations (of a conservative chain).
    pub symplectic: bool,
    /// Whether each step solves implicit stage equations.
    pub implicit: bool,
    /// Whether it estimates its local error, so that a controller can choose the step.
    pub adaptive: bool,
}

/// A one-step method. Generic over the system so the hot loop is monomorphised.
pub trait Integrator {
    /// What a checkpoint must keep so that a restarted run continues bit for bit.
    type Memory: Clone + std::fmt::Debug + PartialEq + Serialize + for<'de> Deserialize<'de>;

    fn facts(&self) -> Facts;

    /// Called before the first step from `(t, y)` and whenever the state was changed from
    /// outside: forget what depended on the previous state.
    fn start<S: OdeSystem>(&mut self, sys: &mut S, t: f64, y: &[f64]) -> Result<()>;

    /// A trial step of size `h` from `(t, y)` into `y_new`. Returns the error norm of the step
    /// against the tolerances for adaptive methods (`inf` for a trial that left the finite
    /// states: the controller shrinks the step), `None` for fixed-step ones.
    fn attempt<S: OdeSystem>(&mut self, sys: &mut S, t: f64, y: &[f64], h: f64, y_new: &mut [f64]) -> Result<Option<f64>>;

    /// The last attempt became the new state.
    fn accept(&mut self) {}

    /// Make the dense output of the last accepted step, of size `h` from `(t, y)` to
    /// `(t_new, y_new)` (`t_new` is `t + h` but for rounding, and the end of the time grid).
    /// Idempotent: a second call costs nothing.
    fn dense<S: OdeSystem>(&mut self, sys: &mut S, t: f64, y: &[f64], h: f64, t_new: f64, y_new: &[f64]) -> Result<()>;

    /// The state at `t + x h` of the last accepted step, after [`Integrator::dense`].
    fn interpolate(&self, y: &[f64], y_new: &[f64], h: f64, x: f64, out: &mut [f64]);

    /// Fixed-point or Newton iterations so far (implicit methods).
    fn iterations(&self) -> u64 {
        0
    }

    fn save(&self) -> Self::Memory;

    /// Continue from a saved memory; refuses one of another size.
    fn restore(&mut self, memory: Self::Memory) -> Result<()>;

    /// The memory as a checkpoint holds it, whatever the method.
    fn save_any(&self) -> AnyMemory;

    /// [`Integrator::restore`] from a checkpoint's memory; refuses another method's.
    fn restore_any(&mut self, memory: AnyMemory) -> Result<()>;

    /// The method's name (for messages).
    fn name(&self) -> &'static str;

    /// The first step to try from `(t, y)` towards a span of `span`, after
    /// [`Integrator::start`], for methods that choose their own steps (`None` for the others).
    fn initial_step<S: OdeSystem>(&mut self, _sys: &mut S, _t: f64, _y: &[f64], _span: f64) -> Result<Option<f64>> {
        Ok(None)
    }
}

/// A checkpoint's memory of another method than the run's.
pub(crate) fn other_method(name: &str) -> Error {
    Error::input(format!("the checkpoint's integrator state is not that of this method ({name})"))
}

/// An integrator's memory refused on restore.
pub(crate) fn misfit(method: &str, what: String) -> Error {
    Error::input(format!("the checkpoint's integrator state does not fit {method}: {what}"))
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
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

    /// The facts of the integrator that implements the method.
    pub fn facts(self) -> Facts {
        match self {
            Method::Rk4 => rk4::FACTS,
            Method::Dop853 => dop853::FACTS,
            Method::Gauss4 => gauss::facts(2),
            Method::Gauss6 => gauss::facts(3),
        }
    }

    pub fn order(self) -> u32 {
        self.facts().order
    }

    pub fn symplectic(self) -> bool {
        self.facts().symplectic
    }

    pub fn implicit(self) -> bool {
        self.facts().implicit
    }

    pub fn adaptive(self) -> bool {
        self.facts().adaptive
    }

    /// Whether a run needs a step `dt` (the fixed-step methods; for an adaptive one it is the
    /// first step, optional).
    pub fn needs_dt(self) -> bool {
        !self.adaptive()
    }

    /// The forms the method integrates: the symplectic methods need Hamilton's equations (their
    /// symplecticity is a property of the canonical coordinates).
    pub fn forms(self) -> &'static [crate::dynamics::system::Form] {
        use crate::dynamics::system::Form;
        if self.symplectic() {
            &[Form::Hamiltonian]
        } else {
            &[Form::Lagrangian, Form::Hamiltonian]
        }
    }

    pub fn parse(name: &str) -> Result<Self> {
        Self::ALL.into_iter().find(|m| m.name() == name).ok_or_else(|| {
            let valid: Vec<&str> = Self::ALL.iter().map(|m| m.name()).collect();
            Error::input(format!("method must be one of {}, got {name:?}", valid.join(", ")))
        })
    }
}

/// The integrator of a [`Method`], chosen at run time; each arm calls a monomorphised integrator.
// One per run, so the size of the largest variant costs nothing worth a box.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone)]
pub enum AnyIntegrator {
    Rk4(Rk4),
    Gauss(Gauss),
    Dop853(Dop853),
}

/// The memory of an [`AnyIntegrator`]: a checkpoint's integrator part.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum AnyMemory {
    Rk4(<Rk4 as Integrator>::Memory),
    Gauss(<Gauss as Integrator>::Memory),
    Dop853(<Dop853 as Integrator>::Memory),
}

macro_rules! each {
    ($self:expr, $i:ident => $body:expr) => {
        match $self {
            AnyIntegrator::Rk4($i) => $body,
            AnyIntegrator::Gauss($i) => $body,
            AnyIntegrator::Dop853($i) => $body,
        }
    };
}

impl AnyIntegrator {
    pub fn new(method: Method, dim: usize, rtol: f64, atol: f64) -> Self {
        match method {
            Method::Rk4 => AnyIntegrator::Rk4(Rk4::new(dim)),
            Method::Gauss4 => AnyIntegrator::Gauss(Gauss::new(2, dim)),
            Method::Gauss6 => AnyIntegrator::Gauss(Gauss::new(3, dim)),
            Method::Dop853 => AnyIntegrator::Dop853(Dop853::new(dim, rtol, atol)),
        }
    }
}

/// The method chosen at run time: each call dispatches to the monomorphised integrator. Hot
/// loops take the integrator's own type instead ([`crate::run::simulate`](fn@crate::run::simulate) does).
impl Integrator for AnyIntegrator {
    type Memory = AnyMemory;

    fn facts(&self) -> Facts {
        each!(self, i => i.facts())
    }

    fn start<S: OdeSystem>(&mut self, sys: &mut S, t: f64, y: &[f64]) -> Result<()> {
        each!(self, i => i.start(sys, t, y))
    }

    #[inline(always)]
    fn attempt<S: OdeSystem>(&mut self, sys: &mut S, t: f64, y: &[f64], h: f64, y_new: &mut [f64]) -> Result<Option<f64>> {
        each!(self, i => i.attempt(sys, t, y, h, y_new))
    }

    fn accept(&mut self) {
        each!(self, i => i.accept())
    }

    fn dense<S: OdeSystem>(&mut self, sys: &mut S, t: f64, y: &[f64], h: f64, t_new: f64, y_new: &[f64]) -> Result<()> {
        each!(self, i => i.dense(sys, t, y, h, t_new, y_new))
    }

    fn interpolate(&self, y: &[f64], y_new: &[f64], h: f64, x: f64, out: &mut [f64]) {
        each!(self, i => i.interpolate(y, y_new, h, x, out))
    }

    fn iterations(&self) -> u64 {
        each!(self, i => i.iterations())
    }

    fn save(&self) -> AnyMemory {
        self.save_any()
    }

    fn restore(&mut self, memory: AnyMemory) -> Result<()> {
        self.restore_any(memory)
    }

    fn save_any(&self) -> AnyMemory {
        each!(self, i => i.save_any())
    }

    fn restore_any(&mut self, memory: AnyMemory) -> Result<()> {
        each!(self, i => i.restore_any(memory))
    }

    fn name(&self) -> &'static str {
        each!(self, i => i.name())
    }

    fn initial_step<S: OdeSystem>(&mut self, sys: &mut S, t: f64, y: &[f64], span: f64) -> Result<Option<f64>> {
        each!(self, i => i.initial_step(sys, t, y, span))
    }
}

#[cfg(test)]
mod tests;
