//! The chain as a first-order ODE `y' = f(t, y)` in either of the seeds' forms. The state is
//! `[theta, omega]` (Lagrangian, seed 000) or `[theta, p]` (Hamiltonian, seed 001), then the
//! cart's `[x, v or p_x]` when there is one, then the energy terms that the run tracks
//! ([`Layout`]): the work of the torque, of the moving pivot, of the cart force, and the energy
//! dissipated, so that the energy balance can be checked.
use std::borrow::Borrow;

use serde::{Deserialize, Serialize};

use super::base::{Drive, Force, Motion};
use super::general::{Load, TANGENT_SCRATCH};
use super::torque::{Builtin, TorqueSource};
use super::Workspace;
use crate::error::{Error, Result};
use crate::model::Chain;

/// An ODE right-hand side; the integrators are generic over it so the hot loop is monomorphised.
pub trait OdeSystem {
    fn dim(&self) -> usize;
    fn rhs(&mut self, t: f64, y: &[f64], dy: &mut [f64]) -> Result<()>;
    /// The Jacobian `d f / d y` at `(t, y)`, row-major `dim x dim` into `out`, if the system
    /// has one (`false`: it has none).
    fn jacobian(&mut self, _t: f64, _y: &[f64], _out: &mut [f64]) -> Result<bool> {
        Ok(false)
    }
    /// The size each component of `y` is measured against when an implicit method's iteration
    /// decides it has converged: `max(|y_m|, 1)`, unless the system knows better.
    fn scales(&self, y: &[f64], out: &mut [f64]) {
        for (o, v) in out.iter_mut().zip(y) {
            *o = v.abs().max(1.0);
        }
    }
}

/// Where each part of a run's ODE state sits: `[theta, omega or p]`, then the cart's
/// `[x, v or p_x]`, then the tracked energy terms, each only when present.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Layout {
    pub n: usize,
    pub cart: bool,
    /// The torque's work `int tau . theta_dot dt`.
    pub torque: bool,
    /// The pivot's generalized (fictitious) force's work `-int a_p . R_dot dt`, of which the
    /// pivot's work follows ([`crate::run::energy`]).
    pub pivot: bool,
    /// The cart force's work `int F v dt`.
    pub force: bool,
    /// The energy dissipated by the joints' losses and the cart's damping.
    pub losses: bool,
}

impl Layout {
    pub fn dim(&self) -> usize {
        2 * self.n + 2 * usize::from(self.cart) + [self.torque, self.pivot, self.force, self.losses].iter().filter(|&&b| b).count()
    }

    /// The mechanical state's size: angles and their rates, and the cart's.
    pub fn mechanical(&self) -> usize {
        2 * self.n + 2 * usize::from(self.cart)
    }

    fn slot(&self, k: usize, present: bool) -> Option<usize> {
        let before = [self.torque, self.pivot, self.force, self.losses][..k].iter().filter(|&&b| b).count();
        present.then(|| self.mechanical() + before)
    }

    /// The cart's position's index (its rate follows).
    pub fn cart(&self) -> Option<usize> {
        self.cart.then_some(2 * self.n)
    }
    pub fn torque_work(&self) -> Option<usize> {
        self.slot(0, self.torque)
    }
    pub fn pivot_work(&self) -> Option<usize> {
        self.slot(1, self.pivot)
    }
    pub fn force_work(&self) -> Option<usize> {
        self.slot(2, self.force)
    }
    pub fn dissipated(&self) -> Option<usize> {
        self.slot(3, self.losses)
    }
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
        Self::ALL.into_iter().find(|f| f.name() == name).ok_or_else(|| Error::input(format!("form must be \"lagrangian\" or \"hamiltonian\", got {name:?}")))
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
    drive: Drive,
    layout: Layout,
    /// Whether the model goes beyond the seeds' (losses, a cart or a moving pivot): the
    /// general dynamics, else the ideal chain's fast paths.
    general: bool,
    /// `(x, theta, v, omega)` for a feedback cart force; scratch for the tangents.
    state: Vec<f64>,
    scratch: Vec<f64>,
    /// The layout's indices, looked up once.
    slots: Slots,
    /// The gravity (with the pivot's acceleration) and cart force of the last evaluation, for
    /// what rides along it (the sensitivity columns) without evaluating the pivot again.
    last_load: Load,
}

#[derive(Debug, Clone, Copy, Default)]
struct Slots {
    cart: Option<usize>,
    torque: Option<usize>,
    pivot: Option<usize>,
    force: Option<usize>,
    dissipated: Option<usize>,
}

impl<C: Borrow<Chain>, T: TorqueSource> ChainSystem<C, T> {
    pub fn new(chain: C, torque: T, form: Form) -> Self {
        let (n, still) = (chain.borrow().n(), Load::still(chain.borrow()));
        let mut sys = ChainSystem {
            chain,
            torque,
            form,
            ws: Workspace::new(n),
            tau: vec![0.0; n],
            drive: Drive::none(),
            layout: Layout { n, cart: false, torque: false, pivot: false, force: false, losses: false },
            general: false,
            state: Vec::new(),
            scratch: Vec::new(),
            slots: Slots::default(),
            last_load: still,
        };
        sys.arrange();
        sys
    }

    /// The same system with the base driven: a moving pivot or a cart force.
    pub fn with_drive(mut self, drive: Drive) -> Result<Self> {
        drive.check(self.chain.borrow())?;
        self.drive = drive;
        self.arrange();
        Ok(self)
    }

    /// Replace the drive between steps; refused if it changes what the state holds (a pivot
    /// that starts or stops moving, a cart force that appears or goes).
    pub fn replace_drive(&mut self, drive: Drive) -> Result<()> {
        drive.check(self.chain.borrow())?;
        let before = self.layout;
        let old = std::mem::replace(&mut self.drive, drive);
        self.arrange();
        if self.layout != before {
            self.drive = old;
            self.arrange();
            return Err(Error::input(
                "the new drive changes what the run's state holds (a moving pivot or a cart force that appears or goes): start a new run",
            ));
        }
        Ok(())
    }

    /// The torque source, to change between steps (then restart the integrator: a changed
    /// input invalidates what it carried over, as [`crate::run::Run::set_state`] does).
    pub fn torque_mut(&mut self) -> &mut T {
        &mut self.torque
    }

    /// Hold the cart force at `f` from now on, in place (an environment's action over one
    /// step); the drive must already be a constant force. Restart the integrator after it.
    pub fn hold_force(&mut self, f: f64) -> Result<()> {
        match &mut self.drive.force {
            Some(Force::Builtin(Builtin::Constant(v))) if v.len() == 1 => {
                v[0] = f;
                Ok(())
            }
            _ => Err(Error::input("hold_force needs a run started with a constant cart force")),
        }
    }

    fn arrange(&mut self) {
        let chain: &Chain = self.chain.borrow();
        let n = chain.n();
        let pivot = self.drive.moving_pivot().is_some();
        self.layout =
            Layout { n, cart: chain.cart().is_some(), torque: self.torque.active(), pivot, force: self.drive.force.is_some(), losses: chain.dissipative() };
        self.general = !chain.is_ideal() || pivot;
        let l = self.layout;
        self.slots = Slots { cart: l.cart(), torque: l.torque_work(), pivot: l.pivot_work(), force: l.force_work(), dissipated: l.dissipated() };
        self.state = vec![0.0; 2 * n + 2];
        self.scratch = vec![0.0; TANGENT_SCRATCH * n + 4 * n];
    }

    pub fn form(&self) -> Form {
        self.form
    }

    pub fn chain(&self) -> &Chain {
        self.chain.borrow()
    }

    /// What acted on the chain in the last evaluation of the right-hand side besides its
    /// torques (a fixed pivot's gravity before any).
    pub fn last_load(&self) -> Load {
        self.last_load
    }

    /// What the last evaluation of the right-hand side left in its workspace for what rides
    /// along the state (the sensitivity columns): every path leaves the angles' trig, and every
    /// path but the Lagrangian double pendulum's closed forms (which solve 2 x 2) the mass
    /// matrix's factorisation too.
    pub fn evaluated(&self) -> Evaluated<'_> {
        if self.form == Form::Hamiltonian || self.chain.borrow().n() != 2 {
            Evaluated::Factored(&self.ws)
        } else {
            Evaluated::Trig(&self.ws)
        }
    }

    /// Whether the torque is a feedback of the state.
    pub fn torque_uses_state(&self) -> bool {
        self.torque.uses_state()
    }

    pub fn drive(&self) -> &Drive {
        &self.drive
    }

    pub fn layout(&self) -> Layout {
        self.layout
    }

    /// Whether the state carries the torque's work after the mechanical entries.
    pub fn tracks_work(&self) -> bool {
        self.layout.torque
    }

    /// The pivot's motion at `t` (at rest at the origin when it has none).
    pub fn pivot_motion(&self, t: f64) -> Result<Motion> {
        match self.drive.moving_pivot() {
            Some(p) => p.eval(t),
            None => Ok(Motion::default()),
        }
    }
}

/// What a system's evaluation at a state left for reuse there ([`ChainSystem::evaluated`]).
#[derive(Clone, Copy)]
pub enum Evaluated<'a> {
    /// Nothing: whoever needs the trig or the factorisation computes them.
    Nothing,
    /// The angles' trig.
    Trig(&'a Workspace),
    /// The angles' trig and the mass matrix's factorisation.
    Factored(&'a Workspace),
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

impl<C: Borrow<Chain>, T: TorqueSource> ChainSystem<C, T> {
    /// The right-hand side of the general model (losses, a cart, a moving pivot).
    fn rhs_general(&mut self, t: f64, y: &[f64], dy: &mut [f64]) -> Result<()> {
        let Self { chain, torque, ws, tau, drive, layout, state, form, slots, last_load, .. } = self;
        let chain: &Chain = (*chain).borrow();
        let (n, lay, slots) = (chain.n(), *layout, *slots);
        let active = lay.torque;
        let theta = &y[..n];
        let (x, second_x) = match slots.cart {
            Some(i) => (y[i], y[i + 1]),
            None => (0.0, 0.0),
        };
        let motion = match (lay.pivot, drive.pivot.as_ref()) {
            (true, Some(p)) => p.eval(t)?,
            _ => Motion::default(),
        };
        let mut load = if lay.pivot { Load::pivot(chain, motion.acc) } else { Load::still(chain) };
        let (d_theta, rest) = dy.split_at_mut(n);
        let d_second = &mut rest[..n];
        let (v, force, losses) = match form {
            Form::Lagrangian => {
                let omega = &y[n..2 * n];
                let v = second_x;
                if active {
                    torque.eval(t, theta, omega, tau)?;
                }
                if let Some(f) = drive.force.as_mut() {
                    if f.is_feedback() {
                        fill_state(t, state, x, theta, v, omega)?;
                    }
                    load.cart_force = f.eval(t, state)?;
                }
                d_theta.copy_from_slice(omega);
                let r = chain.accelerations_general(theta, omega, v, tau, &load, d_second, ws).map_err(|s| singular(t, y, s))?;
                if let Some(i) = slots.cart {
                    dy[i] = v;
                    dy[i + 1] = r.cart;
                }
                (v, load.cart_force, r.losses)
            }
            Form::Hamiltonian => {
                let mut force = 0.0;
                let r = chain
                    .hamilton_general(&y[..n], &y[n..2 * n], second_x, d_theta, d_second, load.gravity, ws, |omega, v, out| {
                        if active {
                            torque.eval(t, theta, omega, tau)?;
                        }
                        out.copy_from_slice(tau);
                        if let Some(f) = drive.force.as_mut() {
                            if f.is_feedback() {
                                fill_state(t, state, x, theta, v, omega)?;
                            }
                            force = f.eval(t, state)?;
                        }
                        Ok(force)
                    })
                    .map_err(|s| singular(t, y, s))??;
                if let Some(i) = slots.cart {
                    dy[i] = r.cart;
                    dy[i + 1] = r.cart_momentum_rate;
                }
                (r.cart, force, r.losses)
            }
        };
        if let Some(i) = slots.torque {
            dy[i] = tau.iter().zip(&dy[..n]).map(|(a, b)| a * b).sum();
        }
        if let Some(i) = slots.pivot {
            // The trig of the angles is still in the workspace.
            let r = chain.momentum_relative_cached(&dy[..n], ws);
            dy[i] = -(motion.acc[0] * r[0] + motion.acc[1] * r[1]);
        }
        if let Some(i) = slots.force {
            dy[i] = force * v;
        }
        if let Some(i) = slots.dissipated {
            dy[i] = losses + chain.cart().map_or(0.0, |c| c.damping * v * v);
        }
        *last_load = Load { cart_force: force, ..load };
        Ok(())
    }

    /// The Jacobian of the mechanical part (the tracked energy terms feed nothing back: their
    /// rows and columns are left zero), torques and the cart force taken as functions of time.
    fn jacobian_into(&mut self, t: f64, y: &[f64], out: &mut [f64]) -> Result<()> {
        let Self { chain, torque, ws, tau, drive, layout, scratch, form, .. } = self;
        let chain: &Chain = (*chain).borrow();
        let (n, lay) = (chain.n(), *layout);
        let dim = lay.dim();
        out[..dim * dim].fill(0.0);
        let motion = match drive.moving_pivot() {
            Some(p) => p.eval(t)?,
            None => Motion::default(),
        };
        let load = if lay.pivot { Load::pivot(chain, motion.acc) } else { Load::still(chain) };
        let theta = &y[..n];
        let second_x = lay.cart().map_or(0.0, |i| y[i + 1]);
        let (tangent, rest) = scratch.split_at_mut(TANGENT_SCRATCH * n);
        let (rates, rest) = rest.split_at_mut(n);
        let (dir, rest) = rest.split_at_mut(2 * n);
        let (col, _) = rest.split_at_mut(n);
        let mech = lay.mechanical();
        let fail = |s| singular(t, y, s);
        match form {
            Form::Lagrangian => {
                let omega = &y[n..2 * n];
                if lay.torque {
                    torque.eval(t, theta, omega, tau)?;
                }
                let r = chain.accelerations_general(theta, omega, second_x, tau, &load, rates, ws).map_err(fail)?;
                for j in 0..mech {
                    dir.fill(0.0);
                    let dv = if j < 2 * n {
                        dir[j] = 1.0;
                        0.0
                    } else {
                        f64::from(u8::from(j == 2 * n + 1))
                    };
                    let (dth, dw) = dir.split_at(n);
                    let dx = chain.tangent_general(theta, omega, (rates, r.cart), &load, (dth, dw, dv), col, tangent, ws).map_err(fail)?;
                    for i in 0..n {
                        out[i * dim + j] = dw[i];
                        out[(n + i) * dim + j] = col[i];
                    }
                    if let Some(c) = lay.cart() {
                        out[c * dim + j] = dv;
                        out[(c + 1) * dim + j] = dx;
                    }
                }
            }
            Form::Hamiltonian => {
                let (omega, rest) = rates.split_at_mut(n);
                let _ = rest;
                let v = chain.velocities_general(theta, &y[n..2 * n], second_x, omega, ws).map_err(fail)?;
                let mut d_pdot = vec![0.0; n];
                for j in 0..mech {
                    dir.fill(0.0);
                    let dpx = if j < 2 * n {
                        dir[j] = 1.0;
                        0.0
                    } else {
                        f64::from(u8::from(j == 2 * n + 1))
                    };
                    let (dth, dp) = dir.split_at(n);
                    let (dv, dpxd) = chain.hamilton_tangent(theta, (omega, v), load.gravity, (dth, dp, dpx), col, &mut d_pdot, tangent, ws).map_err(fail)?;
                    for i in 0..n {
                        out[i * dim + j] = col[i];
                        out[(n + i) * dim + j] = d_pdot[i];
                    }
                    if let Some(c) = lay.cart() {
                        out[c * dim + j] = dv;
                        out[(c + 1) * dim + j] = dpxd;
                    }
                }
            }
        }
        Ok(())
    }
}

/// `(x, theta, v, omega)` into `state` (a feedback cart force's argument): a state that blew
/// up is the integration's failure, not the user function's.
fn fill_state(t: f64, state: &mut [f64], x: f64, theta: &[f64], v: f64, omega: &[f64]) -> Result<()> {
    let n = theta.len();
    state[0] = x;
    state[1..=n].copy_from_slice(theta);
    state[n + 1] = v;
    state[n + 2..2 * n + 2].copy_from_slice(omega);
    check_finite_state(t, state)
}

impl<C: Borrow<Chain>, T: TorqueSource> OdeSystem for ChainSystem<C, T> {
    fn dim(&self) -> usize {
        self.layout.dim()
    }

    fn jacobian(&mut self, t: f64, y: &[f64], out: &mut [f64]) -> Result<bool> {
        self.jacobian_into(t, y, out)?;
        Ok(true)
    }

    #[inline(always)]
    fn rhs(&mut self, t: f64, y: &[f64], dy: &mut [f64]) -> Result<()> {
        if self.general {
            return self.rhs_general(t, y, dy);
        }
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
                chain.accelerations_into(theta, second, tau, d_second, ws).map_err(|s| singular(t, y, s))?;
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
