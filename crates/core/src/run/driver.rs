//! The run driver: one type ([`Run`]) that owns a system's state, its integrator and its
//! counters, and advances them. Every caller goes through it: [`super::simulate`](fn@super::simulate) (and so
//! batches, `t_eval` output, events and checkpoints) step by step, the viewer and the
//! environments frame by frame ([`Run::advance_to`]), with new inputs between steps.
//!
//! **The time grid.** The fixed-step methods (`rk4`, `gauss4`, `gauss6`) step on `t_k = k dt`
//! (computed from the step index, never accumulated, so a run cut into pieces or resumed meets
//! the same times), each step of size `t_{k+1} - t_k`; a run with an end `t_end` shortens its
//! last step to land on it. `dop853` controls its own steps and shortens the one that would
//! pass the end or the target (keeping its proposal for the step after); with `adaptive =
//! false` it takes steps of `dt` from where it is.
//!
//! A checkpoint is the driver's [`State`] written out (serde): whatever an integrator must
//! remember is in its typed memory, so none of it can be left out.
use serde::{Deserialize, Serialize};

use crate::dynamics::system::{check_finite_state, OdeSystem, NON_FINITE};
use crate::error::{Error, Result};
use crate::integrators::{AnyIntegrator, AnyMemory, Controller, Decision, Integrator, Method};

/// How a run steps.
#[derive(Debug, Clone, PartialEq)]
pub struct Config {
    pub method: Method,
    /// The fixed-step methods' step; the first step of dop853 (and its only one when
    /// `adaptive` is false); `None`: dop853 chooses its first step.
    pub dt: Option<f64>,
    pub rtol: f64,
    pub atol: f64,
    /// dop853: control the step (else steps of `dt`).
    pub adaptive: bool,
    /// The run's end: the fixed grid's last step lands on it, and no step passes it.
    pub t_end: Option<f64>,
    /// dop853: accepted plus rejected steps at most, an error beyond.
    pub max_steps: u64,
}

/// Everything a run remembers between two steps, as plain numbers: a checkpoint's core.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct State {
    pub t: f64,
    /// The raw ODE state.
    pub y: Vec<f64>,
    /// Accepted steps: the fixed grid's index.
    pub steps: u64,
    pub rejected: u64,
    pub evaluations: u64,
    pub iterations: u64,
    /// dop853: the next step to try, and whether the last attempt was rejected.
    pub h: f64,
    pub after_rejection: bool,
    pub memory: AnyMemory,
}

/// A system with its right-hand side evaluations counted.
struct Counted<S> {
    sys: S,
    n: u64,
}

impl<S: OdeSystem> OdeSystem for Counted<S> {
    fn dim(&self) -> usize {
        self.sys.dim()
    }

    #[inline(always)]
    fn rhs(&mut self, t: f64, y: &[f64], dy: &mut [f64]) -> Result<()> {
        self.n += 1;
        self.sys.rhs(t, y, dy)
    }

    fn jacobian(&mut self, t: f64, y: &[f64], out: &mut [f64]) -> Result<bool> {
        self.sys.jacobian(t, y, out)
    }

    fn scales(&self, y: &[f64], out: &mut [f64]) {
        self.sys.scales(y, out)
    }
}

/// Number of fixed steps to reach `t_end`; the last one is shortened when `dt` does not divide it.
pub fn fixed_steps(t_end: f64, dt: f64) -> u64 {
    ((t_end / dt) * (1.0 - 1e-12)).ceil().max(1.0) as u64
}

/// Why dop853 stopped when its step became too small to move on.
pub(crate) const UNDERFLOW: &str = "the step size underflowed (the motion is singular or blew up)";

/// Why dop853 stopped when it ran out of steps.
pub(crate) fn max_steps_reached(max_steps: u64) -> String {
    format!("reached max_steps = {max_steps} before t_end")
}

/// The smallest step dop853 may take at time `t` before the step size counts as underflowed.
pub(crate) fn min_step(t: f64) -> f64 {
    10.0 * (t.abs() * f64::EPSILON).max(f64::MIN_POSITIVE)
}

/// `I`: the integrator, its own type in hot loops (monomorphised), or [`AnyIntegrator`] chosen
/// at run time.
pub struct Run<S, I = AnyIntegrator> {
    sys: Counted<S>,
    method: Method,
    integ: I,
    /// Step-size control (dop853 with `adaptive`).
    control: Option<Controller>,
    dt: f64,
    t_end: Option<f64>,
    /// The fixed grid's index of `t_end`.
    last_index: Option<u64>,
    max_steps: u64,
    state: State,
    /// The start of the last accepted step, `(t, h)`, and its state: the dense output's ends.
    last: Option<(f64, f64)>,
    y_prev: Vec<f64>,
    y_new: Vec<f64>,
    /// The first error; once failed, the run stays at its last good state and repeats it.
    failed: Option<Error>,
    /// Iterations counted before a resume (the integrator counts its own since).
    iterations_before: u64,
}

impl<S: OdeSystem> Run<S, AnyIntegrator> {
    /// Start at `t = 0` from the raw state `y0`, with the config's method chosen at run time.
    pub fn new(sys: S, y0: Vec<f64>, config: &Config) -> Result<Self> {
        let integ = AnyIntegrator::new(config.method, y0.len(), config.rtol, config.atol);
        Self::start_with(sys, y0, config, integ)
    }

    /// Continue from a saved [`State`] of the same run (same system and config).
    pub fn resume(sys: S, state: State, config: &Config) -> Result<Self> {
        let integ = AnyIntegrator::new(config.method, state.y.len(), config.rtol, config.atol);
        Self::resume_with(sys, state, config, integ)
    }
}

impl<S: OdeSystem, I: Integrator> Run<S, I> {
    /// Start at `t = 0` from the raw state `y0` with `integ`, the integrator of `config.method`.
    pub fn start_with(sys: S, y0: Vec<f64>, config: &Config, integ: I) -> Result<Self> {
        let mut run = Self::build(sys, y0, config, integ)?;
        let Run { sys, integ, state, .. } = &mut run;
        integ.start(sys, 0.0, &state.y)?;
        if config.method.adaptive() {
            state.h = match config.dt {
                Some(dt) => config.t_end.map_or(dt, |e| dt.min(e)),
                None => integ.initial_step(sys, 0.0, &state.y, config.t_end.unwrap_or(f64::INFINITY))?.unwrap_or(f64::NAN),
            };
        }
        run.state.memory = run.integ.save_any();
        Ok(run)
    }

    /// Continue from a saved [`State`] of the same run (same system and config) with `integ`.
    pub fn resume_with(sys: S, state: State, config: &Config, integ: I) -> Result<Self> {
        let bad = |what: String| Err(Error::input(format!("the checkpoint does not fit this run: {what}")));
        if state.y.len() != sys.dim() {
            return bad(format!("its state has {} values, this run's {}", state.y.len(), sys.dim()));
        }
        if !(state.y.iter().all(|v| v.is_finite()) && state.t.is_finite()) {
            return Err(Error::input("the checkpoint's state is not finite"));
        }
        let mut run = Self::build(sys, state.y.clone(), config, integ)?;
        run.integ.restore_any(state.memory.clone())?;
        match run.method {
            Method::Dop853 => {
                if !(state.h.is_finite() && state.h > 0.0) {
                    return Err(Error::input("the checkpoint's integrator state does not fit dop853: it needs a step h > 0"));
                }
                if let Some(e) = config.t_end {
                    if !(0.0..=e).contains(&state.t) {
                        return bad(format!("t = {} outside [0, t_end = {e}]", state.t));
                    }
                }
            }
            _ => {
                if run.last_index.is_some_and(|last| state.steps > last) || state.t != run.grid(state.steps) {
                    return bad(format!(
                        "t = {} after {} steps is not on the grid of dt = {}{}",
                        state.t,
                        state.steps,
                        run.dt,
                        match (run.last_index, config.t_end) {
                            (Some(k), Some(e)) => format!(" ({k} steps to t_end = {e})"),
                            _ => String::new(),
                        }
                    ));
                }
            }
        }
        run.sys.n = state.evaluations;
        run.iterations_before = state.iterations;
        run.state = state;
        Ok(run)
    }

    fn build(sys: S, y: Vec<f64>, config: &Config, integ: I) -> Result<Self> {
        let method = config.method;
        let dim = y.len();
        if dim != sys.dim() {
            return Err(Error::input(format!("the state has {dim} values, the system {}", sys.dim())));
        }
        let dt = config.dt.unwrap_or(f64::NAN);
        let grid = !method.adaptive();
        if grid && !(dt.is_finite() && dt > 0.0) {
            return Err(Error::input(format!("method {} takes a fixed step: give dt", method.name())));
        }
        let memory = integ.save_any();
        Ok(Run {
            sys: Counted { sys, n: 0 },
            method,
            integ,
            control: (method.adaptive() && config.adaptive).then_some(Controller::DOP853),
            dt,
            t_end: config.t_end,
            last_index: config.t_end.filter(|_| grid).map(|e| fixed_steps(e, dt)),
            max_steps: config.max_steps,
            state: State { t: 0.0, y, steps: 0, rejected: 0, evaluations: 0, iterations: 0, h: f64::NAN, after_rejection: false, memory },
            last: None,
            y_prev: vec![0.0; dim],
            y_new: vec![0.0; dim],
            failed: None,
            iterations_before: 0,
        })
    }

    /// The fixed grid: `t_k = k dt`, and `t_end` at its last index.
    #[inline]
    fn grid(&self, k: u64) -> f64 {
        if Some(k) == self.last_index {
            self.t_end.unwrap_or(f64::NAN)
        } else {
            k as f64 * self.dt
        }
    }

    /// Whether the run is at its end (never, without one).
    pub fn at_end(&self) -> bool {
        match (self.last_index, self.t_end) {
            (Some(k), _) => self.state.steps >= k,
            (None, Some(e)) => self.state.t >= e,
            (None, None) => false,
        }
    }

    /// One accepted step (dop853: after as many rejected attempts as it takes), never past
    /// `until` nor the run's end. After an error the run stays at its last good state and
    /// every later step returns the same error.
    pub fn step(&mut self, until: f64) -> Result<()> {
        if let Some(e) = &self.failed {
            return Err(e.clone());
        }
        let r = if self.method.adaptive() { self.controlled_step(until) } else { self.grid_step() };
        if let Err(e) = &r {
            self.failed = Some(e.clone());
        }
        r
    }

    #[inline]
    fn grid_step(&mut self) -> Result<()> {
        let k = self.state.steps;
        let (t, t_next) = (self.state.t, self.grid(k + 1));
        let h = t_next - t;
        self.integ.attempt(&mut self.sys, t, &self.state.y, h, &mut self.y_new)?;
        check_finite_state(t_next, &self.y_new)?;
        self.commit(t, h, t_next);
        Ok(())
    }

    fn controlled_step(&mut self, until: f64) -> Result<()> {
        let until = self.t_end.map_or(until, |e| until.min(e));
        loop {
            let State { t, h, steps, rejected, .. } = self.state;
            if steps + rejected >= self.max_steps {
                return Err(Error::integration(t, max_steps_reached(self.max_steps)));
            }
            if h < min_step(t) {
                return Err(Error::integration(t, UNDERFLOW));
            }
            let last = t + h >= until;
            let h_try = if last { until - t } else { h };
            let err = self.integ.attempt(&mut self.sys, t, &self.state.y, h_try, &mut self.y_new)?.unwrap_or(0.0);
            let h_next = match self.control.map(|c| c.decide(err, h_try, self.state.after_rejection)) {
                Some(Decision::Reject { h_next }) => {
                    self.state.rejected += 1;
                    self.state.after_rejection = true;
                    self.state.h = h_next;
                    continue;
                }
                Some(Decision::Accept { h_next }) => h_next,
                // Steps of dt, whatever their error; a stage that left the finite states ends it.
                None if !err.is_finite() => return Err(Error::integration(t + h_try, NON_FINITE)),
                None => h,
            };
            check_finite_state(t + h_try, &self.y_new)?;
            // A step shortened to land on the end or a target says little about the next one:
            // keep the proposal it was cut from.
            if !last {
                self.state.h = h_next;
            }
            self.state.after_rejection = false;
            self.commit(t, h_try, if last { until } else { t + h_try });
            return Ok(());
        }
    }

    /// The trial state becomes the state; the old one the start of the last step.
    #[inline]
    fn commit(&mut self, t: f64, h: f64, t_new: f64) {
        self.integ.accept();
        std::mem::swap(&mut self.y_prev, &mut self.state.y);
        std::mem::swap(&mut self.state.y, &mut self.y_new);
        self.last = Some((t, h));
        self.state.t = t_new;
        self.state.steps += 1;
    }

    /// Whether `until` counts as reached: the fixed grid's next point lies beyond it; dop853 is
    /// on it, or short of it by less than a step it could take.
    pub fn reached(&self, until: f64) -> bool {
        if self.at_end() {
            return true;
        }
        if self.method.adaptive() {
            let span = until - self.state.t;
            span <= 0.0 || (span < min_step(self.state.t) && Some(until) != self.t_end)
        } else {
            self.grid(self.state.steps + 1) > until + 1e-9 * self.dt
        }
    }

    /// Advance towards `target`, taking at most `budget` accepted steps. Returns `true` once
    /// the target (or the run's end) is reached ([`Run::reached`]), `false` if the budget ran
    /// out first.
    pub fn advance_to(&mut self, target: f64, budget: u64) -> Result<bool> {
        if let Some(e) = &self.failed {
            return Err(e.clone());
        }
        if target.is_nan() {
            return Err(Error::input("t_target must not be NaN"));
        }
        let mut taken = 0u64;
        loop {
            if self.reached(target) {
                return Ok(true);
            }
            if taken >= budget {
                return Ok(false);
            }
            self.step(target)?;
            taken += 1;
        }
    }

    /// Make the dense output of the last accepted step (lazily; idempotent).
    pub fn dense(&mut self) -> Result<()> {
        let Some((t, h)) = self.last else { return Err(Error::input("no step taken yet")) };
        self.integ.dense(&mut self.sys, t, &self.y_prev, h, self.state.t, &self.state.y)
    }

    /// The state at fraction `x` of the last accepted step, after [`Run::dense`].
    pub fn interpolate(&self, x: f64, out: &mut [f64]) {
        let (_, h) = self.last.unwrap_or((0.0, 0.0));
        self.integ.interpolate(&self.y_prev, &self.state.y, h, x, out)
    }

    /// The last accepted step `(t, h)`, if any.
    pub fn last_step(&self) -> Option<(f64, f64)> {
        self.last
    }

    /// The next step of the fixed grid (for output taken at the start of a step).
    pub fn next_grid_step(&self) -> Option<f64> {
        (!self.method.adaptive()).then(|| self.grid(self.state.steps + 1) - self.state.t)
    }

    /// Change the state from outside (new initial values between steps): the integrator forgets
    /// what depended on the old one.
    pub fn set_state(&mut self, y: &[f64]) -> Result<()> {
        if y.len() != self.state.y.len() {
            return Err(Error::input(format!("the state must have {} values, got {}", self.state.y.len(), y.len())));
        }
        self.state.y.copy_from_slice(y);
        self.last = None;
        self.failed = None;
        self.integ.start(&mut self.sys, self.state.t, &self.state.y)
    }

    /// The driver's complete state (a checkpoint's core).
    pub fn save(&self) -> State {
        State { memory: self.integ.save_any(), ..self.counted() }
    }

    /// The state with its counters brought up to date (they are not kept per step, which would
    /// cost the double pendulum's hot loop a few percent).
    fn counted(&self) -> State {
        State { evaluations: self.sys.n, iterations: self.iterations_before + self.integ.iterations(), ..self.state.clone() }
    }

    /// Accepted steps, rejected attempts, right-hand side evaluations and implicit iterations.
    pub fn counters(&self) -> (u64, u64, u64, u64) {
        (self.state.steps, self.state.rejected, self.sys.n, self.iterations_before + self.integ.iterations())
    }

    pub fn t(&self) -> f64 {
        self.state.t
    }
    pub fn y(&self) -> &[f64] {
        &self.state.y
    }
    /// The state (its counters as of the last [`Run::save`]; [`Run::counters`] for the current ones).
    pub fn state(&self) -> &State {
        &self.state
    }
    pub fn method(&self) -> Method {
        self.method
    }
    pub fn system(&self) -> &S {
        &self.sys.sys
    }
    /// The system, for changing its inputs between steps (a torque, say).
    pub fn system_mut(&mut self) -> &mut S {
        &mut self.sys.sys
    }
    /// The error that stopped the run, if any.
    pub fn failure(&self) -> Option<&Error> {
        self.failed.as_ref()
    }
}
