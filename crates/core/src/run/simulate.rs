//! One run from an initial state to `t_end` through the run driver ([`super::Run`]):
//! validation, output at every step or at the requested times (dense output), events,
//! checkpoints, and the derived quantities (momenta or velocities, energy, work, the energy
//! error of [`super::energy`]).
use serde::{Deserialize, Serialize};

use super::driver::{fixed_steps, Config, Run, State};
use super::energy::EnergyBalance;
use super::events::{EventSpec, Hit, Tracker};
use super::sensitivity::{Sensitive, Traced};
use crate::dynamics::base::Drive;
use crate::dynamics::sensitivity::Input;
use crate::dynamics::system::{check_finite_state, ChainSystem, Form, Layout};
use crate::dynamics::torque::TorqueSource;
use crate::dynamics::Workspace;
use crate::error::{Error, Result, Shown};
use crate::integrators::{Dop853, Gauss, Integrator, Method, Rk4};
use crate::model::Chain;
use crate::par::*;
use crate::watch::Watch;

pub use crate::memory::MAX_OUTPUT_BYTES;

#[derive(Debug, Clone)]
pub struct Settings {
    pub method: Method,
    /// `None`: Lagrangian for rk4/dop853, Hamiltonian for the Gauss methods (which require it).
    pub form: Option<Form>,
    /// Step size of the fixed-step methods; the first step of dop853 (and its only step size
    /// when `adaptive` is false).
    pub dt: Option<f64>,
    pub rtol: f64,
    pub atol: f64,
    pub adaptive: bool,
    /// Output times (ascending, within `[0, t_end]`); `None`: every step.
    pub t_eval: Option<Vec<f64>>,
    pub max_steps: u64,
    /// Conditions whose zero crossings are recorded, or stop the run (terminal).
    pub events: Vec<EventSpec>,
    /// What moves the base: a prescribed pivot motion, or the force on the chain's cart.
    pub drive: Drive,
    /// The cart's initial position and velocity (every trajectory of a batch), with a cart.
    pub cart0: [f64; 2],
    /// The inputs the run's forward sensitivities are taken with respect to (none: a plain run).
    pub sensitivities: Vec<Input>,
}

/// The defaults of a run, stated once (Python, the CLI, scenario files and the viewer read them).
pub mod defaults {
    pub const METHOD: super::Method = super::Method::Dop853;
    pub const RTOL: f64 = 1e-10;
    pub const ATOL: f64 = 1e-12;
    /// The smallest rtol the adaptive method accepts (below it round-off dominates the estimate).
    pub const MIN_RTOL: f64 = 1e-15;
    pub const MAX_STEPS: u64 = 100_000_000;
}

impl Default for Settings {
    fn default() -> Self {
        Settings {
            method: defaults::METHOD,
            form: None,
            dt: None,
            rtol: defaults::RTOL,
            atol: defaults::ATOL,
            adaptive: true,
            t_eval: None,
            max_steps: defaults::MAX_STEPS,
            events: Vec::new(),
            drive: Drive::none(),
            cart0: [0.0, 0.0],
            sensitivities: Vec::new(),
        }
    }
}

#[derive(Debug, Clone, Default, PartialEq)]
pub struct Stats {
    pub steps: u64,
    pub rejected: u64,
    pub evaluations: u64,
    /// Fixed-point iterations of the implicit methods.
    pub iterations: u64,
    /// The largest energy error over the outputs ([`super::energy`]).
    pub energy_error: f64,
}

/// An event crossing: `(event index, t, theta, omega, p)`.
pub type Crossing = (usize, f64, Vec<f64>, Vec<f64>, Vec<f64>);

/// A run's output: `T` output times, row-major `(T, N)` arrays.
#[derive(Debug, Clone, PartialEq)]
pub struct Trajectory {
    pub n: usize,
    pub t: Vec<f64>,
    pub theta: Vec<f64>,
    pub omega: Vec<f64>,
    pub p: Vec<f64>,
    /// The lab-frame energy: with the pivot's or the cart's motion.
    pub energy: Vec<f64>,
    /// The work done by the torques since t = 0.
    pub work: Vec<f64>,
    /// The work done by the moving pivot, by the cart force, and the energy dissipated by the
    /// joints and the cart since t = 0 (empty when the run has none).
    pub work_pivot: Vec<f64>,
    pub work_cart: Vec<f64>,
    pub dissipated: Vec<f64>,
    /// The cart's position and velocity (empty without a cart).
    pub cart_x: Vec<f64>,
    pub cart_v: Vec<f64>,
    /// The pivot's position, `(x, y)` per row (empty when it is fixed at the origin).
    pub pivot: Vec<f64>,
    /// The energy error of each output ([`super::energy`]).
    pub energy_error: Vec<f64>,
    pub stats: Stats,
    pub form: Form,
    /// Event crossings in time order.
    pub events: Vec<Crossing>,
    /// The time a terminal event stopped the run, if one did.
    pub stopped_at: Option<f64>,
    /// The forward sensitivities: `(T, S, K)` row-major, the derivative of the state entry
    /// `(theta, omega, (x, v))` (S of them) with respect to each of the K directions of
    /// `Settings::sensitivities` (each input's entries in order). Empty without sensitivities.
    pub sensitivities: Vec<f64>,
    /// The Hamiltonian form's integrated columns, derivatives of `(theta, p, (x, p_x))`, in
    /// the same layout (empty in the Lagrangian form).
    pub canonical: Vec<f64>,
    /// K, the number of sensitivity directions.
    pub directions: usize,
}

impl Settings {
    pub fn resolved_form(&self) -> Result<Form> {
        match (self.method.symplectic(), self.form) {
            (true, Some(Form::Lagrangian)) => {
                Err(Error::input(format!("method {} integrates Hamilton's equations; form must be \"hamiltonian\", got \"lagrangian\"", self.method.name())))
            }
            (true, _) => Ok(Form::Hamiltonian),
            (false, f) => Ok(f.unwrap_or(Form::Lagrangian)),
        }
    }

    /// The driver's configuration of a run to `t_end` (`None`: a run without an end).
    pub fn config(&self, t_end: Option<f64>) -> Config {
        Config { method: self.method, dt: self.dt, rtol: self.rtol, atol: self.atol, adaptive: self.adaptive, t_end, max_steps: self.max_steps }
    }

    /// Whether `trajectories` runs to `t_end` are surely short (a fixed-step run of a few
    /// thousand steps in all): short enough to run where they are called, without a watcher
    /// thread for Ctrl-C (which costs tens of microseconds to start).
    pub fn is_short(&self, t_end: f64, trajectories: usize) -> bool {
        match self.dt {
            Some(dt) if !self.method.adaptive() || !self.adaptive => (t_end / dt).ceil() * trajectories as f64 <= SHORT_STEPS && self.events.is_empty(),
            _ => false,
        }
    }

    /// Check the settings for a run to `t_end`; returns the number of output rows.
    pub fn validate(&self, t_end: f64) -> Result<usize> {
        if !(t_end.is_finite() && t_end > 0.0) {
            return Err(Error::input(format!("t_end must be > 0 and finite, got {}", Shown(t_end))));
        }
        if let Some(dt) = self.dt {
            if !(dt.is_finite() && dt > 0.0) {
                return Err(Error::input(format!("dt must be > 0 and finite, got {}", Shown(dt))));
            }
        } else if !self.method.adaptive() || !self.adaptive {
            return Err(Error::input(format!("method {} takes a fixed step: give dt", self.method.name())));
        }
        if self.method.adaptive() {
            if !(self.rtol.is_finite() && self.rtol >= defaults::MIN_RTOL) {
                return Err(Error::input(format!("rtol must be >= {:e} and finite, got {}", defaults::MIN_RTOL, Shown(self.rtol))));
            }
            if !(self.atol.is_finite() && self.atol >= 0.0) {
                return Err(Error::input(format!("atol must be >= 0 and finite, got {}", Shown(self.atol))));
            }
        }
        self.resolved_form()?;
        let rows = match &self.t_eval {
            Some(te) => {
                for (i, &v) in te.iter().enumerate() {
                    if !(v.is_finite() && (0.0..=t_end).contains(&v)) {
                        return Err(Error::input(format!("t_eval[{i}] must lie in [0, t_end = {}], got {}", Shown(t_end), Shown(v))));
                    }
                    if i > 0 && v < te[i - 1] {
                        return Err(Error::input(format!("t_eval must be ascending: t_eval[{i}] = {} < t_eval[{}] = {}", Shown(v), i - 1, Shown(te[i - 1]))));
                    }
                }
                te.len() as f64
            }
            None if !self.method.adaptive() || !self.adaptive => fixed_steps(t_end, self.dt.unwrap()) as f64 + 1.0,
            None => 0.0, // unknown in advance; bounded by max_steps
        };
        Ok(rows as usize)
    }
}

/// Steps (all trajectories together) below which a fixed-step run counts as short.
const SHORT_STEPS: f64 = 4096.0;

/// Bytes per output row of a run of `chain` with `settings`: [`crate::memory::row_bytes`], and
/// with sensitivities their columns, held three times at once (the recorded rows, their copy
/// while the run is finished, the output) and four in the Hamiltonian form (its own columns too).
fn output_row_bytes(chain: &Chain, settings: &Settings) -> f64 {
    let n = chain.n();
    let k: usize = settings.sensitivities.iter().map(|i| i.len(n)).sum();
    let mech = 2 * n + if chain.cart().is_some() { 2 } else { 0 };
    let copies = if settings.resolved_form().ok() == Some(Form::Hamiltonian) { 4.0 } else { 3.0 };
    crate::memory::row_bytes(n) + (k * mech) as f64 * 8.0 * copies
}

/// Refuse, before allocating, an output of `rows` rows (all trajectories) of `row` bytes each
/// ([`output_row_bytes`]) that would not fit.
fn check_output_size(rows: f64, n: usize, row: f64) -> Result<()> {
    crate::memory::check(
        rows * row,
        &format!("storing {rows:.0} output points of {n} links"),
        "ask for fewer with t_eval (e.g. 10^4 points), a larger dt or fewer trajectories",
    )
}

/// A fixed-step run's length is known: refuse one beyond `max_steps` before it starts (with a
/// huge `t_end / dt` and `t_eval` it would otherwise run for ever).
pub(crate) fn check_fixed_steps(settings: &Settings, t_end: f64) -> Result<()> {
    match settings.dt {
        Some(dt) if !settings.method.adaptive() || !settings.adaptive => {
            let steps = fixed_steps(t_end, dt);
            if steps > settings.max_steps {
                return Err(Error::input(format!(
                    "{} with dt = {} takes {:.3e} steps to reach t_end = {t_end:e}, more than max_steps = {}; \
                     use a larger dt or a shorter t_end (or raise max_steps)",
                    settings.method.name(),
                    Shown(dt),
                    steps as f64,
                    settings.max_steps
                )));
            }
            Ok(())
        }
        _ => Ok(()),
    }
}

/// An adaptive run's length is known only as it goes: at its pace so far (checked at 64, 128,
/// 256, ... steps), refuse at once a run that clearly cannot reach `t_end` within `max_steps`, or
/// whose every-step output clearly would not fit, instead of after minutes of work. "Clearly":
/// four times over, as the pace of the first steps can differ from the rest.
#[allow(clippy::too_many_arguments)]
fn check_pace(settings: &Settings, attempts: u64, t: f64, t_end: f64, every_step: bool, n: usize, row: f64) -> Result<()> {
    if !(t > 0.0) {
        return Ok(());
    }
    let total = attempts as f64 * t_end / t;
    if total > 4.0 * settings.max_steps as f64 {
        return Err(Error::input(format!(
            "{} needs about {total:.1e} steps to reach t_end = {t_end:e} at its pace so far ({attempts} steps \
             to t = {t:.3e}), more than max_steps = {}; use a shorter t_end or looser rtol/atol (or raise max_steps)",
            settings.method.name(),
            settings.max_steps
        )));
    }
    if every_step {
        let rows = total / 4.0;
        crate::memory::check(
            rows * row,
            &format!("storing every step, about {rows:.1e} output points of {n} links to t_end = {t_end:e} at the pace so far"),
            "ask for fewer with t_eval (e.g. 10^4 points), or a shorter t_end",
        )?;
    }
    Ok(())
}

/// Output rows of the raw ODE state `y`.
#[derive(Debug, Clone, Default)]
pub(crate) struct Recorder {
    t: Vec<f64>,
    y: Vec<f64>,
    /// How many of `t_eval` the rows cover.
    next_out: usize,
    stopped_at: Option<f64>,
}

impl Recorder {
    /// A row from an interpolant: a step's ends are checked for blow-up, but its dense output
    /// can still overflow between them, and a NaN must never be returned as a result.
    fn push_interpolated(&mut self, t: f64, y: &[f64]) -> Result<()> {
        check_finite_state(t, y)?;
        self.push(t, y);
        Ok(())
    }

    pub(crate) fn push(&mut self, t: f64, y: &[f64]) {
        self.t.push(t);
        self.y.extend_from_slice(y);
    }
}

/// The complete state of a run between two steps: the driver's [`State`], the initial state
/// (for the energy error) and the output so far. [`simulate_from`] started from it takes exactly
/// the floating-point path the uninterrupted run took, so its result is bit-for-bit the same.
/// Serialised whole ([`Checkpoint::to_bytes`]), so no part of it can be left out.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Checkpoint {
    pub run: State,
    /// The raw ODE state at t = 0.
    pub initial: Vec<f64>,
    /// The output rows so far: their times, and their raw states (row-major, `y.len()` each).
    pub out_t: Vec<f64>,
    pub out_y: Vec<f64>,
    /// How many of `t_eval` the rows cover.
    pub next_out: usize,
}

/// Leads every serialised checkpoint: a format name and its version.
const CHECKPOINT_MAGIC: &[u8; 8] = b"mpckpt\x00\x02";

impl Checkpoint {
    /// The time reached.
    pub fn t(&self) -> f64 {
        self.run.t
    }

    pub fn to_bytes(&self) -> Vec<u8> {
        let mut out = CHECKPOINT_MAGIC.to_vec();
        // Serialising plain numbers and vectors into memory cannot fail.
        out.extend(postcard::to_allocvec(self).unwrap_or_default());
        out
    }

    pub fn from_bytes(bytes: &[u8]) -> Result<Self> {
        let body = bytes
            .strip_prefix(CHECKPOINT_MAGIC.as_slice())
            .ok_or_else(|| Error::input("the checkpoint's run state is not of this format (another version, or damaged)"))?;
        postcard::from_bytes(body).map_err(|e| Error::input(format!("the checkpoint's run state cannot be read (damaged?): {e}")))
    }
}

/// When a run takes checkpoints, and where they go. Checkpoints with events are refused (the
/// event tracker's state is not part of a [`Checkpoint`]).
pub struct Checkpoints<'a> {
    /// Take one every this many steps (0: not by count).
    pub every_steps: u64,
    /// Asked every `MONITOR_EVERY` (64) steps: true to take one now (a wall clock, say).
    pub due: &'a mut dyn FnMut() -> bool,
    /// Receives each checkpoint, and a last one when the monitor stops the run (an interrupt).
    /// An error stops the run.
    pub save: &'a mut dyn FnMut(&Checkpoint) -> Result<()>,
}

/// Where a run starts: an initial state at t = 0, or a [`Checkpoint`] of the same run.
#[derive(Debug, Clone, Copy)]
pub enum Start<'a> {
    Initial { theta0: &'a [f64], omega0: &'a [f64] },
    Resume(&'a Checkpoint),
}

/// After each accepted step: a checkpoint when one is due; the monitor every `MONITOR_EVERY`
/// steps, and when it stops the run, a last checkpoint before its error. `snapshot` is only
/// called when a checkpoint is taken (it copies the output rows).
fn after_step(steps: u64, t: f64, monitor: Monitor, checkpoints: &mut Option<&mut Checkpoints>, snapshot: impl Fn() -> Checkpoint) -> Result<()> {
    let tick = steps % MONITOR_EVERY == 0;
    let mut saved = false;
    if let Some(cp) = checkpoints.as_deref_mut() {
        if (cp.every_steps > 0 && steps % cp.every_steps == 0) || (tick && (cp.due)()) {
            (cp.save)(&snapshot())?;
            saved = true;
        }
    }
    if tick {
        if let Err(e) = monitor(t) {
            if let (Some(cp), false) = (checkpoints.as_deref_mut(), saved) {
                (cp.save)(&snapshot())?;
            }
            return Err(e);
        }
    }
    Ok(())
}

/// Called now and then with the current time; an error (e.g. an interrupt) stops the run.
pub type Monitor<'a> = &'a mut dyn FnMut(f64) -> Result<()>;

/// How often (in steps) the monitor is called.
pub const MONITOR_EVERY: u64 = 64;

/// Integrate `chain` from `(theta0, omega0)` at t = 0 to `t_end`.
pub fn simulate<T: TorqueSource>(
    chain: &Chain,
    theta0: &[f64],
    omega0: &[f64],
    t_end: f64,
    settings: &Settings,
    torque: T,
    monitor: Monitor,
) -> Result<Trajectory> {
    simulate_from(chain, Start::Initial { theta0, omega0 }, t_end, settings, torque, monitor, None)
}

/// [`simulate`] from an initial state or from a [`Checkpoint`] of the same run (same chain,
/// settings, torque and `t_end`), handing `checkpoints` the run's complete state now and then.
/// A resumed run's trajectory is bit-for-bit the uninterrupted run's, stats included (but the
/// wall time). Checkpoints and resuming are refused with events.
#[allow(clippy::too_many_arguments)]
pub fn simulate_from<T: TorqueSource>(
    chain: &Chain,
    start: Start,
    t_end: f64,
    settings: &Settings,
    torque: T,
    monitor: Monitor,
    checkpoints: Option<&mut Checkpoints>,
) -> Result<Trajectory> {
    if let Start::Initial { theta0, omega0 } = start {
        chain.check_state("theta0", theta0)?;
        chain.check_state("omega0", omega0)?;
    }
    check_cart0(chain, settings)?;
    let rows = settings.validate(t_end)?;
    check_output_size(rows as f64, chain.n(), output_row_bytes(chain, settings))?;
    check_fixed_steps(settings, t_end)?;
    let form = settings.resolved_form()?;
    let n = chain.n();
    for e in &settings.events {
        e.validate(n)?;
    }
    let resume = match start {
        Start::Resume(cp) => Some(cp),
        Start::Initial { .. } => None,
    };
    if !settings.events.is_empty() && (resume.is_some() || checkpoints.is_some()) {
        return Err(Error::input("checkpoints cannot be combined with events (the event tracker's state is not saved)"));
    }
    let sys = ChainSystem::new(chain, torque, form).with_drive(settings.drive.clone())?;
    if settings.sensitivities.is_empty() {
        return by_method(chain, start, t_end, settings, sys, monitor, checkpoints, rows);
    }
    if resume.is_some() || checkpoints.is_some() {
        return Err(Error::input("checkpoints cannot be combined with sensitivities (resume the run without them)"));
    }
    let sys = Sensitive::new(chain, sys, &settings.sensitivities, &settings.drive)?;
    by_method(chain, start, t_end, settings, sys, monitor, checkpoints, rows)
}

/// [`drive`] with the method's own integrator type: one monomorphised loop per method, not a
/// dispatch per step. dop853 controls the error of the chain's state only.
#[allow(clippy::too_many_arguments)]
fn by_method<S: Traced>(
    chain: &Chain,
    start: Start,
    t_end: f64,
    settings: &Settings,
    sys: S,
    monitor: Monitor,
    checkpoints: Option<&mut Checkpoints>,
    rows: usize,
) -> Result<Trajectory> {
    let (d, config) = (sys.dim(), settings.config(Some(t_end)));
    match settings.method {
        Method::Rk4 => drive(chain, start, t_end, settings, sys, Rk4::new(d), monitor, checkpoints, rows),
        Method::Gauss4 => drive(chain, start, t_end, settings, sys, Gauss::new(2, d), monitor, checkpoints, rows),
        Method::Gauss6 => drive(chain, start, t_end, settings, sys, Gauss::new(3, d), monitor, checkpoints, rows),
        Method::Dop853 => {
            let integ = Dop853::new(d, config.rtol, config.atol).controlling(sys.layout().dim());
            drive(chain, start, t_end, settings, sys, integ, monitor, checkpoints, rows)
        }
    }
}

/// The run loop of [`simulate_from`] for one integrator type.
#[allow(clippy::too_many_arguments)]
fn drive<S: Traced, I: Integrator>(
    chain: &Chain,
    start: Start,
    t_end: f64,
    settings: &Settings,
    mut sys: S,
    integ: I,
    monitor: Monitor,
    mut checkpoints: Option<&mut Checkpoints>,
    rows: usize,
) -> Result<Trajectory> {
    let (n, form, layout) = (chain.n(), sys.form(), sys.layout());
    let resume = matches!(start, Start::Resume(_));
    let d = sys.dim();
    let config = settings.config(Some(t_end));
    let t_eval = settings.t_eval.as_deref();
    let mut tracker = Tracker::new(&settings.events, chain, form);
    let (mut run, initial, mut rec) = match start {
        Start::Initial { theta0, omega0 } => {
            let y = sys.start(initial_state(chain, form, layout, theta0, omega0, settings.cart0))?;
            tracker.start(0.0, &y)?;
            let rows = t_eval.map_or(if settings.method.adaptive() { 0 } else { rows }, <[f64]>::len);
            let rec = Recorder { t: Vec::with_capacity(rows), y: Vec::with_capacity(rows * d), ..Recorder::default() };
            (Run::start_with(sys, y.clone(), &config, integ)?, y, rec)
        }
        Start::Resume(cp) => {
            if cp.run.y.len() != d {
                return Err(Error::input(format!(
                    "the checkpoint does not fit this run: its state has {} values, this run's {d} \
                     ({n} links, form {}{})",
                    cp.run.y.len(),
                    form.name(),
                    describe(layout)
                )));
            }
            let bad = |what: String| Err(Error::input(format!("the checkpoint does not fit this run: {what}")));
            if cp.out_y.len() != cp.out_t.len() * d || cp.initial.len() != d {
                return bad(format!("{} output times but {} state values ({d} per row)", cp.out_t.len(), cp.out_y.len()));
            }
            if cp.next_out > t_eval.map_or(0, <[f64]>::len) {
                return bad(format!("next_out = {} beyond the {} output times", cp.next_out, t_eval.map_or(0, <[f64]>::len)));
            }
            let rec = Recorder { t: cp.out_t.clone(), y: cp.out_y.clone(), next_out: cp.next_out, stopped_at: None };
            (Run::resume_with(sys, cp.run.clone(), &config, integ)?, cp.initial.clone(), rec)
        }
    };
    if !resume && t_eval.is_none() {
        rec.push(0.0, run.y());
    }
    // Fixed-step methods take an output time within 1e-9 of a step of a grid point as that
    // point's state; dop853 interpolates every time inside a step.
    let snap = if settings.method.adaptive() { 0.0 } else { 1e-9 };
    while !run.at_end() {
        if let Some(te) = t_eval {
            let (t, h) = (run.t(), run.next_grid_step().unwrap_or(0.0));
            while rec.next_out < te.len() && te[rec.next_out] <= t + snap * h {
                rec.push(te[rec.next_out], run.y());
                rec.next_out += 1;
            }
        }
        run.step(t_end)?;
        let ((t0, h), t1) = (run.last_step().unwrap_or_default(), run.t());
        if tracker.active() {
            if tracker.detect(t1, run.y())? {
                run.dense()?;
                let stop = tracker.locate(
                    t0,
                    h,
                    |x, out| {
                        run.interpolate(x, out);
                        Ok(())
                    },
                    d,
                )?;
                if let Some((ts, ys)) = stop {
                    let mut out = vec![0.0; d];
                    if let Some(te) = t_eval {
                        while rec.next_out < te.len() && te[rec.next_out] <= ts {
                            run.interpolate((te[rec.next_out] - t0) / h, &mut out);
                            rec.push_interpolated(te[rec.next_out], &out)?;
                            rec.next_out += 1;
                        }
                    }
                    rec.push_interpolated(ts, &ys)?;
                    rec.stopped_at = Some(ts);
                    break;
                }
            } else {
                tracker.accept();
            }
        }
        match t_eval {
            Some(te) => {
                let edge = t1 - snap * h;
                if rec.next_out < te.len() && te[rec.next_out] < edge {
                    run.dense()?;
                    let mut out = vec![0.0; d];
                    while rec.next_out < te.len() && te[rec.next_out] < edge {
                        run.interpolate((te[rec.next_out] - t0) / h, &mut out);
                        rec.push_interpolated(te[rec.next_out], &out)?;
                        rec.next_out += 1;
                    }
                }
            }
            None => {
                rec.push(t1, run.y());
                if rec.t.len() == rec.t.capacity() {
                    // The next row doubles the buffers: check that they fit before they grow.
                    check_output_size(2.0 * rec.t.len() as f64, n, output_row_bytes(chain, settings))?;
                }
            }
        }
        let steps = run.state().steps;
        if settings.method.adaptive() && steps.is_power_of_two() && steps >= MONITOR_EVERY {
            check_pace(settings, steps + run.state().rejected, t1, t_end, t_eval.is_none(), n, output_row_bytes(chain, settings))?;
        }
        after_step(steps, t1, &mut *monitor, &mut checkpoints, || Checkpoint {
            run: run.save(),
            initial: initial.clone(),
            out_t: rec.t.clone(),
            out_y: rec.y.clone(),
            next_out: rec.next_out,
        })?;
    }
    if let (Some(te), None) = (t_eval, rec.stopped_at) {
        while rec.next_out < te.len() {
            rec.push(te[rec.next_out], run.y());
            rec.next_out += 1;
        }
    }
    let (steps, rejected, evaluations, iterations) = run.counters();
    let stats = Stats { steps, rejected, evaluations, iterations, energy_error: 0.0 };
    let hits = std::mem::take(&mut tracker.hits);
    let base = layout.dim();
    if d == base {
        return finish(chain, form, layout, &settings.drive, &initial, rec, hits, stats);
    }
    // The chain's state leads each row; the sensitivity columns follow it.
    let rows_y = std::mem::take(&mut rec.y);
    let y = rows_y.chunks(d).flat_map(|r| &r[..base]).copied().collect();
    let mut tr = finish(chain, form, layout, &settings.drive, &initial[..base], Recorder { y, ..rec }, hits, stats)?;
    let out = run.system_mut().sensitivities(&rows_y, &tr.t)?;
    (tr.sensitivities, tr.canonical, tr.directions) = (out.derivatives, out.canonical, out.directions);
    Ok(tr)
}

/// What a state holds besides the angles and their rates (for messages).
fn describe(layout: Layout) -> String {
    let parts: Vec<&str> = [
        (layout.cart, "a cart"),
        (layout.torque, "the torque's work"),
        (layout.pivot, "the pivot's work"),
        (layout.force, "the cart force's work"),
        (layout.losses, "the energy dissipated"),
    ]
    .iter()
    .filter(|(on, _)| *on)
    .map(|(_, what)| *what)
    .collect();
    if parts.is_empty() {
        String::new()
    } else {
        format!(", with {}", parts.join(", "))
    }
}

/// The cart's initial state must be finite (and is only meaningful with a cart).
pub(crate) fn check_cart0(chain: &Chain, settings: &Settings) -> Result<()> {
    crate::error::check_finite("cart state (cart_x0, cart_v0)", &settings.cart0)?;
    if chain.cart().is_none() && settings.cart0 != [0.0, 0.0] {
        return Err(Error::input("cart_x0 and cart_v0 need a chain with a cart (Chain(..., cart=Cart(mass)))"));
    }
    Ok(())
}

/// The raw ODE state at t = 0 (the tracked energy terms start at zero).
pub(crate) fn initial_state(chain: &Chain, form: Form, layout: Layout, theta0: &[f64], omega0: &[f64], cart0: [f64; 2]) -> Vec<f64> {
    let n = chain.n();
    let mut y = vec![0.0; layout.dim()];
    y[..n].copy_from_slice(theta0);
    let mut ws = Workspace::new(n);
    match form {
        Form::Lagrangian => y[n..2 * n].copy_from_slice(omega0),
        Form::Hamiltonian => {
            let px = chain.momenta_general(theta0, omega0, cart0[1], &mut y[n..2 * n], &mut ws);
            if let Some(i) = layout.cart() {
                y[i + 1] = px;
            }
        }
    }
    if let Some(i) = layout.cart() {
        y[i] = cart0[0];
        if form == Form::Lagrangian {
            y[i + 1] = cart0[1];
        }
    }
    y
}

/// `omega` and `p` of a raw ODE state `y = [theta, omega or p, (x, v or p_x), ...]` in the
/// given form; returns the cart's `(v, p_x)` (zeros without a cart).
pub(crate) fn fill_rates(chain: &Chain, form: Form, y: &[f64], omega: &mut [f64], p: &mut [f64], ws: &mut Workspace) -> (f64, f64) {
    let n = chain.n();
    let theta = &y[..n];
    let cart = chain.cart().is_some();
    match form {
        Form::Lagrangian => {
            omega.copy_from_slice(&y[n..2 * n]);
            if !cart {
                chain.momenta_into(theta, omega, p, ws);
                return (0.0, 0.0);
            }
            let v = y[2 * n + 1];
            (v, chain.momenta_general(theta, omega, v, p, ws))
        }
        Form::Hamiltonian => {
            p.copy_from_slice(&y[n..2 * n]);
            let px = if cart { y[2 * n + 1] } else { 0.0 };
            // Cannot fail: the same state passed through the right-hand side.
            match chain.velocities_general(theta, p, px, omega, ws) {
                Ok(v) => (v, px),
                Err(_) => {
                    omega.fill(f64::NAN);
                    (f64::NAN, px)
                }
            }
        }
    }
}

/// Turn raw ODE states into theta, omega, p, energy, work and energy-error rows.
#[allow(clippy::too_many_arguments)]
pub(crate) fn finish(
    chain: &Chain,
    form: Form,
    layout: Layout,
    drive: &Drive,
    initial: &[f64],
    rec: Recorder,
    hits: Vec<Hit>,
    mut stats: Stats,
) -> Result<Trajectory> {
    let n = chain.n();
    let d = layout.dim();
    let rows = rec.t.len();
    let some = |on: bool| if on { Vec::with_capacity(rows) } else { Vec::new() };
    let mut tr = Trajectory {
        n,
        theta: Vec::with_capacity(rows * n),
        omega: vec![0.0; rows * n],
        p: vec![0.0; rows * n],
        energy: Vec::with_capacity(rows),
        work: Vec::with_capacity(rows),
        work_pivot: some(layout.pivot),
        work_cart: some(layout.force),
        dissipated: some(layout.losses),
        cart_x: some(layout.cart),
        cart_v: some(layout.cart),
        pivot: if layout.pivot { Vec::with_capacity(2 * rows) } else { Vec::new() },
        energy_error: Vec::with_capacity(rows),
        t: Vec::new(),
        stats: Stats::default(),
        form,
        events: Vec::with_capacity(hits.len()),
        stopped_at: rec.stopped_at,
        sensitivities: Vec::new(),
        canonical: Vec::new(),
        directions: 0,
    };
    let mut books = Books::new(chain, form, layout);
    let first = books.terms(chain, drive, 0.0, initial)?;
    let mut balance = EnergyBalance::from_energy(chain, first.kinetic, first.energy);
    for r in 0..rows {
        let y = &rec.y[r * d..(r + 1) * d];
        tr.theta.extend_from_slice(&y[..n]);
        let terms = books.terms(chain, drive, rec.t[r], y)?;
        tr.omega[r * n..(r + 1) * n].copy_from_slice(&books.omega);
        tr.p[r * n..(r + 1) * n].copy_from_slice(&books.p);
        tr.energy.push(terms.energy);
        tr.work.push(terms.torque);
        if layout.pivot {
            tr.work_pivot.push(terms.pivot);
            tr.pivot.extend_from_slice(&terms.pivot_pos);
        }
        if layout.force {
            tr.work_cart.push(terms.cart);
        }
        if layout.losses {
            tr.dissipated.push(terms.dissipated);
        }
        if let Some(i) = layout.cart() {
            tr.cart_x.push(y[i]);
            tr.cart_v.push(terms.cart_v);
        }
        tr.energy_error.push(balance.observe(terms.kinetic, terms.energy, terms.torque + terms.pivot + terms.cart - terms.dissipated));
    }
    tr.t = rec.t;
    let mut ws = Workspace::new(n);
    for hit in hits {
        let theta = hit.y[..n].to_vec();
        let (mut omega, mut p) = (vec![0.0; n], vec![0.0; n]);
        fill_rates(chain, form, &hit.y, &mut omega, &mut p, &mut ws);
        tr.events.push((hit.event, hit.t, theta, omega, p));
    }
    stats.energy_error = tr.energy_error.iter().copied().fold(0.0, f64::max);
    tr.stats = stats;
    Ok(tr)
}

/// The energy terms of one output: the lab-frame kinetic and total energies, the work of the
/// torques, the pivot and the cart force, and the energy dissipated since t = 0; with the cart's
/// velocity and the pivot's position.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Terms {
    pub kinetic: f64,
    pub energy: f64,
    pub torque: f64,
    pub pivot: f64,
    pub cart: f64,
    pub dissipated: f64,
    pub cart_v: f64,
    pub pivot_pos: [f64; 2],
}

/// Reads the energy terms off raw ODE states: the lab-frame kinetic and total energy and the
/// work terms of [`super::energy`]. The pivot's work is
/// `W_pivot = [v_p . R_dot + M |v_p|^2 / 2 + g M y_p]_0^t - int a_p . R_dot dt`
/// (the integral is in the state; `R_dot = sum_b h_b omega_b (cos, sin)(theta_b)` is the links'
/// momentum relative to the pivot), which makes `E(t) - E(0) = W_torque + W_pivot + W_cart - D`
/// exact.
pub(crate) struct Books {
    form: Form,
    layout: Layout,
    ws: Workspace,
    scratch: Vec<f64>,
    pub omega: Vec<f64>,
    pub p: Vec<f64>,
    /// The pivot's boundary term at t = 0.
    boundary0: Option<f64>,
}

impl Books {
    pub fn new(chain: &Chain, form: Form, layout: Layout) -> Self {
        let n = chain.n();
        Books { form, layout, ws: Workspace::new(n), scratch: vec![0.0; n], omega: vec![0.0; n], p: vec![0.0; n], boundary0: None }
    }

    /// The terms of state `y` at `t` (the first call must be the run's initial state).
    pub fn terms(&mut self, chain: &Chain, drive: &Drive, t: f64, y: &[f64]) -> Result<Terms> {
        let (n, lay) = (chain.n(), self.layout);
        let theta = &y[..n];
        let (v, _) = fill_rates(chain, self.form, y, &mut self.omega, &mut self.p, &mut self.ws);
        let at = |i: Option<usize>| i.map_or(0.0, |i| y[i]);
        let mut out = Terms { torque: at(lay.torque_work()), cart: at(lay.force_work()), dissipated: at(lay.dissipated()), cart_v: v, ..Terms::default() };
        if lay.pivot {
            let motion = drive.moving_pivot().map_or(Ok(Default::default()), |p| p.eval(t))?;
            let kinetic = chain.kinetic_energy_moving(theta, &self.omega, motion.vel, &mut self.scratch, &mut self.ws);
            let r = chain.momentum_relative_cached(&self.omega, &self.ws);
            let m = chain.total_mass();
            let (vp, yp) = (motion.vel, motion.pos[1]);
            let boundary = vp[0] * r[0] + vp[1] * r[1] + 0.5 * m * (vp[0] * vp[0] + vp[1] * vp[1]) + chain.g() * m * yp;
            let b0 = *self.boundary0.get_or_insert(boundary);
            out.kinetic = kinetic;
            out.energy = kinetic + chain.potential_energy_moving(theta, yp);
            out.pivot = boundary - b0 + at(lay.pivot_work());
            out.pivot_pos = motion.pos;
        } else {
            let base_v = if lay.cart { [v, 0.0] } else { [0.0, 0.0] };
            out.kinetic = chain.kinetic_energy_moving(theta, &self.omega, base_v, &mut self.scratch, &mut self.ws);
            out.energy = out.kinetic + chain.potential_energy(theta);
        }
        Ok(out)
    }
}

/// The number of trajectories in rows of `theta0` and `omega0` (B x N each).
pub(crate) fn batch_size(chain: &Chain, theta0: &[f64], omega0: &[f64]) -> Result<usize> {
    let n = chain.n();
    if theta0.len() != omega0.len() || theta0.len() % n != 0 {
        return Err(Error::input(format!("theta0 and omega0 must both have shape (B, {n}), got {} and {} numbers", theta0.len(), omega0.len())));
    }
    Ok(theta0.len() / n)
}

/// Run a batch of initial states one after another with one torque source (a torque that
/// cannot cross threads, such as a Python function): results in input order, each identical to
/// its single run. `monitor(fraction, t)` is called as in [`simulate`], with the fraction of the
/// whole batch done; its error stops the batch.
pub fn simulate_each<T: TorqueSource>(
    chain: &Chain,
    theta0: &[f64],
    omega0: &[f64],
    t_end: f64,
    settings: &Settings,
    torque: &mut T,
    monitor: &mut dyn FnMut(f64, f64) -> Result<()>,
) -> Result<Vec<Trajectory>> {
    let (n, b) = (chain.n(), batch_size(chain, theta0, omega0)?);
    (0..b)
        .map(|i| {
            let range = i * n..(i + 1) * n;
            let mut row_monitor = |t: f64| monitor((i as f64 + t / t_end) / b as f64, t);
            simulate(chain, &theta0[range.clone()], &omega0[range], t_end, settings, &mut *torque, &mut row_monitor)
        })
        .collect()
}

/// Run a batch of initial states in parallel (rayon; one after another without the `parallel`
/// feature); results in input order, whatever the number of threads. Where the lanes take the
/// batch ([`super::lanes::route`]: rk4 or dop853 with a built-in torque, no events...), in SIMD
/// lanes, each row agreeing with its single run to round-off (rk4) or to the tolerance
/// (dop853); else each row is its single run, bit for bit. Rows of `theta0`/`omega0` are states. Each finished trajectory counts a unit of
/// `watch`; once it is stopped the running trajectories stop within `MONITOR_EVERY` steps.
pub fn simulate_batch<T: TorqueSource + Clone + Send + Sync>(
    chain: &Chain,
    theta0: &[f64],
    omega0: &[f64],
    t_end: f64,
    settings: &Settings,
    torque: &T,
    watch: &Watch,
) -> Result<Vec<Trajectory>> {
    let (n, b) = (chain.n(), batch_size(chain, theta0, omega0)?);
    if settings.method.adaptive() && settings.adaptive && settings.t_eval.is_none() {
        return Err(Error::input("a batch run of an adaptive method needs t_eval (each trajectory takes its own steps)"));
    }
    let rows = settings.validate(t_end)?;
    check_output_size(rows as f64 * b as f64, n, output_row_bytes(chain, settings))?;
    check_fixed_steps(settings, t_end)?;
    let timed = torque.timed();
    if let Some(path) = super::lanes::route(settings, timed.as_ref())? {
        if let Some(drive) = &timed {
            return super::lanes::simulate(chain, theta0, omega0, t_end, settings, drive, path, watch);
        }
    }
    (0..b)
        .into_par_iter()
        .map(|i| {
            watch.check(0.0)?;
            let range = i * n..(i + 1) * n;
            let tr = simulate(chain, &theta0[range.clone()], &omega0[range], t_end, settings, torque.clone(), &mut |t| watch.check(t))
                .map_err(|e| e.of_trajectory(i))?;
            watch.add_units(1);
            Ok(tr)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dynamics::torque::Builtin;

    fn settings(method: &str, dt: Option<f64>, t_eval: Option<Vec<f64>>) -> Settings {
        Settings { method: Method::parse(method).unwrap(), dt, t_eval, rtol: 1e-9, atol: 1e-11, ..Settings::default() }
    }

    fn drive() -> Builtin {
        Builtin::sinusoid(2, vec![0.3, 0.0], vec![2.0, 1.0], vec![0.0; 2], vec![0.0; 2]).unwrap()
    }

    /// Every checkpoint of a run, taken every `every` steps.
    fn checkpoints_of(chain: &Chain, s: &Settings, t_end: f64, every: u64) -> (Trajectory, Vec<Checkpoint>) {
        let mut saved = Vec::new();
        let mut save = |cp: &Checkpoint| {
            saved.push(cp.clone());
            Ok(())
        };
        let mut cps = Checkpoints { every_steps: every, due: &mut || false, save: &mut save };
        let start = Start::Initial { theta0: &[2.0, 2.5], omega0: &[0.0, 0.3] };
        let tr = simulate_from(chain, start, t_end, s, drive(), &mut |_| Ok(()), Some(&mut cps)).unwrap();
        (tr, saved)
    }

    #[test]
    fn a_resumed_run_equals_the_uninterrupted_one_bit_for_bit() {
        let chain = Chain::new(&[1.0, 0.8], &[1.0, 1.5], None, None, 9.81).unwrap();
        let t_eval: Vec<f64> = (0..=300).map(|i| i as f64 * 0.01).collect();
        for (method, dt) in [("rk4", Some(0.003)), ("gauss6", Some(0.007)), ("gauss4", Some(0.01)), ("dop853", None)] {
            for te in [None, Some(t_eval.clone())] {
                let s = settings(method, dt, te);
                let plain = simulate(&chain, &[2.0, 2.5], &[0.0, 0.3], 3.0, &s, drive(), &mut |_| Ok(())).unwrap();
                let (with, saved) = checkpoints_of(&chain, &s, 3.0, if method == "dop853" { 7 } else { 37 });
                assert_eq!(with, plain, "{method}: taking checkpoints changed the run");
                assert!(saved.len() >= 3, "{method}: {} checkpoints", saved.len());
                for cp in [&saved[0], &saved[saved.len() / 2], saved.last().unwrap()] {
                    // Through the bytes a checkpoint file holds.
                    let cp = Checkpoint::from_bytes(&cp.to_bytes()).unwrap();
                    let resumed = simulate_from(&chain, Start::Resume(&cp), 3.0, &s, drive(), &mut |_| Ok(()), None).unwrap();
                    assert_eq!(resumed, plain, "{method}: resumed at t = {}", cp.t());
                }
            }
        }
    }

    #[test]
    fn an_interrupting_monitor_leaves_a_last_checkpoint() {
        let chain = Chain::new(&[1.0, 1.0], &[1.0, 1.0], None, None, 9.81).unwrap();
        let s = settings("rk4", Some(0.001), None);
        let mut last = None;
        let mut save = |cp: &Checkpoint| {
            last = Some(cp.clone());
            Ok(())
        };
        let mut cps = Checkpoints { every_steps: 0, due: &mut || false, save: &mut save };
        let start = Start::Initial { theta0: &[2.0, 2.5], omega0: &[0.0, 0.3] };
        let mut monitor = |t: f64| if t > 1.0 { Err(Error::input("interrupted")) } else { Ok(()) };
        let err = simulate_from(&chain, start, 3.0, &s, drive(), &mut monitor, Some(&mut cps)).unwrap_err();
        assert!(err.to_string().contains("interrupted"));
        let cp = last.expect("no checkpoint on interrupt");
        assert_eq!(cp.run.steps % MONITOR_EVERY, 0);
        assert!(cp.t() > 1.0 && cp.t() < 1.1, "t = {}", cp.t());
        let plain = simulate(&chain, &[2.0, 2.5], &[0.0, 0.3], 3.0, &s, drive(), &mut |_| Ok(())).unwrap();
        let resumed = simulate_from(&chain, Start::Resume(&cp), 3.0, &s, drive(), &mut |_| Ok(()), None).unwrap();
        assert_eq!(resumed, plain);
    }

    #[test]
    fn checkpoints_that_do_not_fit_are_refused() {
        let chain = Chain::new(&[1.0, 1.0], &[1.0, 1.0], None, None, 9.81).unwrap();
        let s = settings("gauss6", Some(0.01), None);
        let (_, saved) = checkpoints_of(&chain, &s, 1.0, 20);
        let cp = &saved[1];
        let resume = |cp: &Checkpoint, s: &Settings| simulate_from(&chain, Start::Resume(cp), 1.0, s, drive(), &mut |_| Ok(()), None).unwrap_err().to_string();
        let with = |run: State| Checkpoint { run, ..cp.clone() };
        let off_grid = with(State { t: cp.t() + 1e-3, ..cp.run.clone() });
        assert!(resume(&off_grid, &s).contains("not on the grid"), "{}", resume(&off_grid, &s));
        let short = with(State { y: cp.run.y[..4].to_vec(), ..cp.run.clone() });
        assert!(resume(&short, &s).contains("its state has 4 values, this run's 5"), "{}", resume(&short, &s));
        assert!(resume(cp, &settings("rk4", Some(0.01), None)).contains("not that of this method"));
        assert!(resume(cp, &settings("dop853", None, None)).contains("dop853"));
        let rows = Checkpoint { out_t: cp.out_t[1..].to_vec(), ..cp.clone() };
        assert!(resume(&rows, &s).contains("output times but"), "{}", resume(&rows, &s));
        let nan = with(State { y: vec![f64::NAN; 5], ..cp.run.clone() });
        assert!(resume(&nan, &s).contains("not finite"));
        let with_events =
            Settings { events: vec![EventSpec { condition: crate::run::events::Condition::Flip(None), direction: 1, terminal: true }], ..s.clone() };
        assert!(resume(cp, &with_events).contains("cannot be combined with events"));
    }

    #[test]
    fn damaged_checkpoint_bytes_are_input_errors() {
        let chain = Chain::new(&[1.0, 1.0], &[1.0, 1.0], None, None, 9.81).unwrap();
        let (_, saved) = checkpoints_of(&chain, &settings("dop853", None, None), 1.0, 5);
        let bytes = saved[0].to_bytes();
        for cut in [0, 4, 8, 9, bytes.len() / 2, bytes.len() - 1] {
            let e = Checkpoint::from_bytes(&bytes[..cut]).unwrap_err();
            assert!(matches!(e, Error::Input(_)), "{e}");
            assert!(e.to_string().contains("checkpoint's run state"), "{e}");
        }
        let mut other = bytes.clone();
        other[7] = 1; // another format version
        assert!(Checkpoint::from_bytes(&other).unwrap_err().to_string().contains("not of this format"));
    }
}
