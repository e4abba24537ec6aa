//! The chain as a first-order ODE `y' = f(t, y)` in either of the seeds' forms. The state is
//! `[theta, omega]` (Lagrangian, seed 000) or `[theta, p]` (Hamiltonian, seed 001), followed by
//! the work `W` done by the torque when one acts (so `E(t) - E(0) = W(t)` can be checked).
use std::borrow::Borrow;

use serde::{Deserialize, Serialize};

use super::torque::TorqueSource;
use super::Workspace;
use crate::error::{Error, Result};
use crate::model::Chain;

/// An ODE right-hand side; the integrators are generic over it so the hot loop is monomorphised.
pub trait OdeSystem {
    fn dim(&self) -> usize;
    fn rhs(&mut self, t: f64, y: &[f64], dy: &mut [f64]) -> Result<()>;
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Form {
    /// `(theta, omega)`, `theta_ddot = A^-1 (tau - ...)`.
    Lagrangian,
    /// `(theta, p)`, Hamilton's canonical equations; needed by the symplectic integrators.
    Hamiltonian,
}

impl Form {
    pub fn name(self) -> &'static str {
        match self {
            Form::Lagrangian => "lagrangian",
            Form::Hamiltonian => "hamiltonian",
        }
    }

    pub const ALL: [Form; 2] = [Form::Lagrangian, Form::Hamiltonian];

    pub fn parse(name: &str) -> Result<Self> {
        Self::ALL.into_iter().find(|f| f.name() == name).ok_or_else(|| {
            Error::input(format!("form must be \"lagrangian\" or \"hamiltonian\", got {name:?}"))
        })
    }
}

/// The chain's equations of motion with a torque, in one form. `C` is the chain, borrowed
/// (`&Chain`, a run inside a call) or owned (`Chain`, a run that outlives its caller's borrow,
/// such as the viewer's).
pub struct ChainSystem<C, T> {
    chain: C,
    torque: T,
    form: Form,
    ws: Workspace,
    tau: Vec<f64>,
}

impl<C: Borrow<Chain>, T: TorqueSource> ChainSystem<C, T> {
    pub fn new(chain: C, torque: T, form: Form) -> Self {
        let n = chain.borrow().n();
        ChainSystem { chain, torque, form, ws: Workspace::new(n), tau: vec![0.0; n] }
    }

    pub fn form(&self) -> Form {
        self.form
    }

    pub fn chain(&self) -> &Chain {
        self.chain.borrow()
    }

    /// Whether the state carries the work integral after the 2N mechanical entries.
    pub fn tracks_work(&self) -> bool {
        self.torque.active()
    }
}

/// A failed pivot means either a non-finite state (a blow-up) or a truly singular configuration.
pub(crate) fn singular(t: f64, y: &[f64], s: super::Singular) -> Error {
    if y.iter().all(|v| v.is_finite()) {
        Error::integration(t, s.reason())
    } else {
        Error::integration(t, NON_FINITE)
    }
}

/// A step's state must stay finite: the integration error at `t` otherwise.
pub(crate) fn check_finite_state(t: f64, y: &[f64]) -> Result<()> {
    if y.iter().all(|v| v.is_finite()) {
        Ok(())
    } else {
        Err(Error::integration(t, NON_FINITE))
    }
}

pub(crate) const NON_FINITE: &str = "the state became non-finite (the motion blew up; reduce dt or the tolerances)";

impl<C: Borrow<Chain>, T: TorqueSource> OdeSystem for ChainSystem<C, T> {
    fn dim(&self) -> usize {
        2 * self.chain.borrow().n() + usize::from(self.torque.active())
    }

    #[inline(always)]
    fn rhs(&mut self, t: f64, y: &[f64], dy: &mut [f64]) -> Result<()> {
        let Self { chain, torque, ws, tau, .. } = self;
        let chain: &Chain = (*chain).borrow();
        let n = chain.n();
        let active = torque.active();
        let (theta, second) = (&y[..n], &y[n..2 * n]);
        let (d_theta, rest) = dy.split_at_mut(n);
        let d_second = &mut rest[..n];
        match self.form {
            Form::Lagrangian => {
                if active {
                    torque.eval(t, theta, second, tau)?;
                }
                if n == 2 {
                    // Not a call to memcpy for two numbers.
                    d_theta[0] = second[0];
                    d_theta[1] = second[1];
                } else {
                    d_theta.copy_from_slice(second);
                }
                chain
                    .accelerations_into(theta, second, tau, d_second, ws)
                    .map_err(|s| singular(t, y, s))?;
            }
            Form::Hamiltonian => {
                chain
                    .hamilton_into(theta, second, d_theta, d_second, ws, |omega, out| {
                        if active {
                            torque.eval(t, theta, omega, tau)?;
                        }
                        out.copy_from_slice(tau);
                        Ok(())
                    })
                    .map_err(|s| singular(t, y, s))??;
            }
        }
        if active {
            dy[2 * n] = self.tau.iter().zip(&dy[..n]).map(|(a, b)| a * b).sum();
        }
        Ok(())
    }
}
