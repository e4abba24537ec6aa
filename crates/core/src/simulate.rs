//! One run from an initial state to `t_end`: validation, the integration loop, output at the
//! requested times, and the derived quantities (momenta or velocities, energy, work).
use crate::par::*;

use crate::dynamics::Workspace;
use crate::error::{Error, Result};
use crate::events::{EventSpec, Hit, Tracker};
use crate::integrators::{dop853::Attempt, Carry, Dop853, FixedStep, Gauss, Method, Rk4};
use crate::model::Chain;
use crate::system::{ChainSystem, Form, OdeSystem};
use crate::torque::TorqueSource;

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
}

impl Default for Settings {
    fn default() -> Self {
        Settings {
            method: Method::Dop853,
            form: None,
            dt: None,
            rtol: 1e-10,
            atol: 1e-12,
            adaptive: true,
            t_eval: None,
            max_steps: 100_000_000,
            events: Vec::new(),
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
    /// `max |E(t) - E(0) - W(t)| / |E(0)|` over the outputs (absolute when `E(0) = 0`).
    pub energy_error: f64,
}

/// A run's output: `T` output times, row-major `(T, N)` arrays.
#[derive(Debug, Clone, PartialEq)]
pub struct Trajectory {
    pub n: usize,
    pub t: Vec<f64>,
    pub theta: Vec<f64>,
    pub omega: Vec<f64>,
    pub p: Vec<f64>,
    pub energy: Vec<f64>,
    pub work: Vec<f64>,
    pub stats: Stats,
    pub form: Form,
    /// Event crossings in time order: `(event index, t, theta, omega, p)`.
    pub events: Vec<(usize, f64, Vec<f64>, Vec<f64>, Vec<f64>)>,
    /// The time a terminal event stopped the run, if one did.
    pub stopped_at: Option<f64>,
}

impl Settings {
    pub fn resolved_form(&self) -> Result<Form> {
        match (self.method.symplectic(), self.form) {
            (true, Some(Form::Lagrangian)) => Err(Error::input(format!(
                "method {} integrates Hamilton's equations; form must be \"hamiltonian\", got \"lagrangian\"",
                self.method.name()
            ))),
            (true, _) => Ok(Form::Hamiltonian),
            (false, f) => Ok(f.unwrap_or(Form::Lagrangian)),
        }
    }

    /// Check the settings for a run to `t_end`; returns the number of output rows.
    pub fn validate(&self, t_end: f64) -> Result<usize> {
        if !(t_end.is_finite() && t_end > 0.0) {
            return Err(Error::input(format!("t_end must be > 0 and finite, got {t_end}")));
        }
        if let Some(dt) = self.dt {
            if !(dt.is_finite() && dt > 0.0) {
                return Err(Error::input(format!("dt must be > 0 and finite, got {dt}")));
            }
        } else if !self.method.adaptive() || !self.adaptive {
            return Err(Error::input(format!("method {} takes a fixed step: give dt", self.method.name())));
        }
        if self.method.adaptive() {
            if !(self.rtol.is_finite() && self.rtol >= 1e-15) {
                return Err(Error::input(format!("rtol must be >= 1e-15 and finite, got {}", self.rtol)));
            }
            if !(self.atol.is_finite() && self.atol >= 0.0) {
                return Err(Error::input(format!("atol must be >= 0 and finite, got {}", self.atol)));
            }
        }
        self.resolved_form()?;
        let rows = match &self.t_eval {
            Some(te) => {
                for (i, &v) in te.iter().enumerate() {
                    if !(v.is_finite() && (0.0..=t_end).contains(&v)) {
                        return Err(Error::input(format!("t_eval[{i}] must lie in [0, t_end = {t_end}], got {v}")));
                    }
                    if i > 0 && v < te[i - 1] {
                        return Err(Error::input(format!(
                            "t_eval must be ascending: t_eval[{i}] = {v} < t_eval[{}] = {}",
                            i - 1,
                            te[i - 1]
                        )));
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

/// Number of fixed steps to reach `t_end`; the last one is shortened when `dt` does not divide it.
fn fixed_steps(t_end: f64, dt: f64) -> u64 {
    ((t_end / dt) * (1.0 - 1e-12)).ceil().max(1.0) as u64
}

/// Refuse, before allocating, an output of `rows` rows (all trajectories) that would not fit.
fn check_output_size(rows: f64, n: usize) -> Result<()> {
    crate::memory::check(
        rows * crate::memory::row_bytes(n),
        &format!("storing {rows:.0} output points of {n} links"),
        "ask for fewer with t_eval (e.g. 10^4 points), a larger dt or fewer trajectories",
    )
}

/// A fixed-step run's length is known: refuse one beyond `max_steps` before it starts (with a
/// huge `t_end / dt` and `t_eval` it would otherwise run for ever).
fn check_fixed_steps(settings: &Settings, t_end: f64) -> Result<()> {
    match settings.dt {
        Some(dt) if !settings.method.adaptive() || !settings.adaptive => {
            let steps = fixed_steps(t_end, dt);
            if steps > settings.max_steps {
                return Err(Error::input(format!(
                    "{} with dt = {dt} takes {:.3e} steps to reach t_end = {t_end:e}, more than max_steps = {}; \
                     use a larger dt or a shorter t_end (or raise max_steps)",
                    settings.method.name(),
                    steps as f64,
                    settings.max_steps
                )));
            }
            Ok(())
        }
        _ => Ok(()),
    }
}

/// Collects output rows of the raw ODE state `y`.
struct Recorder {
    t: Vec<f64>,
    y: Vec<f64>,
    stopped_at: Option<f64>,
}

impl Recorder {
    /// A row from an interpolant: a step's ends are checked for blow-up, but its dense output
    /// can still overflow between them, and a NaN must never be returned as a result.
    fn push_interpolated(&mut self, t: f64, y: &[f64]) -> Result<()> {
        check_state_finite(t, y)?;
        self.push(t, y);
        Ok(())
    }

    fn push(&mut self, t: f64, y: &[f64]) {
        self.t.push(t);
        self.y.extend_from_slice(y);
    }
}

/// The complete state of a run between two steps, as plain numbers. [`simulate_from`] started
/// from it takes exactly the floating-point path the uninterrupted run took, so its result is
/// bit-for-bit the same.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Checkpoint {
    /// The time reached.
    pub t: f64,
    /// The raw ODE state at `t`: `[theta, omega or p]` (by the run's form), then the torque's
    /// work when a torque acts.
    pub y: Vec<f64>,
    /// The counters so far (`energy_error` unused). `stats.steps` is the step index: the
    /// fixed-step methods rebuild their grid `t_k = k dt` from it.
    pub stats: Stats,
    /// The integrator's memory.
    pub carry: Carry,
    /// Fixed-step methods with `t_eval`: the slope at `(t, y)` when it is kept for the next
    /// step's interpolation; otherwise empty.
    pub slope: Vec<f64>,
    /// The output rows so far: their times, and their raw states (row-major, `y.len()` each).
    pub out_t: Vec<f64>,
    pub out_y: Vec<f64>,
    /// How many of `t_eval` the rows cover.
    pub next_out: usize,
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

/// What a checkpoint needs from a run loop at the end of an accepted step.
struct Snapshot<'r> {
    t: f64,
    y: &'r [f64],
    stats: &'r Stats,
    evaluations: u64,
    iterations: u64,
    carry: Carry,
    slope: &'r [f64],
    rec: &'r Recorder,
    next_out: usize,
}

impl Snapshot<'_> {
    fn take(&self) -> Checkpoint {
        Checkpoint {
            t: self.t,
            y: self.y.to_vec(),
            stats: Stats { evaluations: self.evaluations, iterations: self.iterations, energy_error: 0.0, ..self.stats.clone() },
            carry: self.carry.clone(),
            slope: self.slope.to_vec(),
            out_t: self.rec.t.clone(),
            out_y: self.rec.y.clone(),
            next_out: self.next_out,
        }
    }
}

/// After each accepted step: a checkpoint when one is due; the monitor every `MONITOR_EVERY`
/// steps, and when it stops the run, a last checkpoint before its error. `snapshot` is only
/// called when a checkpoint is taken (it copies the output rows).
fn after_step(
    steps: u64,
    t: f64,
    monitor: Monitor,
    checkpoints: &mut Option<&mut Checkpoints>,
    snapshot: impl Fn() -> Checkpoint,
) -> Result<()> {
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

/// A checkpoint's rows and output index must fit this run's `t_eval` and state size.
fn check_resume(cp: &Checkpoint, d: usize, t_eval: Option<&[f64]>) -> Result<Recorder> {
    let bad = |what: String| Err(Error::input(format!("the checkpoint does not fit this run: {what}")));
    if cp.out_y.len() != cp.out_t.len() * d {
        return bad(format!("{} output times but {} state values ({d} per row)", cp.out_t.len(), cp.out_y.len()));
    }
    if cp.next_out > t_eval.map_or(0, <[f64]>::len) {
        return bad(format!("next_out = {} beyond the {} output times", cp.next_out, t_eval.map_or(0, <[f64]>::len)));
    }
    if !(cp.slope.is_empty() || cp.slope.len() == d) {
        return bad(format!("{} slope values, expected 0 or {d}", cp.slope.len()));
    }
    Ok(Recorder { t: cp.out_t.clone(), y: cp.out_y.clone(), stopped_at: None })
}

/// Cubic Hermite interpolation between `(y0, f0)` and `(y1, f1)` over a step `h`, at fraction `x`.
pub(crate) fn hermite(y0: &[f64], f0: &[f64], y1: &[f64], f1: &[f64], h: f64, x: f64, out: &mut [f64]) {
    let (x2, x3) = (x * x, x * x * x);
    let (h00, h10, h01, h11) = (2.0 * x3 - 3.0 * x2 + 1.0, x3 - 2.0 * x2 + x, -2.0 * x3 + 3.0 * x2, x3 - x2);
    for m in 0..out.len() {
        out[m] = h00 * y0[m] + h10 * h * f0[m] + h01 * y1[m] + h11 * h * f1[m];
    }
}

/// Called now and then with the current time; an error (e.g. an interrupt) stops the run.
pub type Monitor<'a> = &'a mut dyn FnMut(f64) -> Result<()>;

/// How often (in steps) the monitor is called.
const MONITOR_EVERY: u64 = 64;

fn check_state_finite(t: f64, y: &[f64]) -> Result<()> {
    if y.iter().all(|v| v.is_finite()) {
        Ok(())
    } else {
        Err(Error::integration(t, crate::system::NON_FINITE))
    }
}

#[allow(clippy::too_many_arguments)]
fn run_fixed<T: TorqueSource, I: FixedStep>(
    sys: &mut ChainSystem<T>,
    stepper: &mut I,
    y: &mut [f64],
    t_end: f64,
    dt: f64,
    t_eval: Option<&[f64]>,
    stats: &mut Stats,
    monitor: Monitor,
    events: &mut Tracker,
    resume: Option<&Checkpoint>,
    mut checkpoints: Option<&mut Checkpoints>,
) -> Result<Recorder> {
    let steps = fixed_steps(t_end, dt);
    // The grid is rebuilt from the step index, never accumulated, so a resumed run meets the same times.
    let grid = |k: u64| if k == steps { t_end } else { k as f64 * dt };
    let d = y.len();
    let (mut f0, mut f1, mut y0) = (vec![0.0; d], vec![0.0; d], vec![0.0; d]);
    let mut out = vec![0.0; d];
    let mut f0_valid = false;
    let (mut rec, mut next_out, first) = match resume {
        Some(cp) => {
            if cp.stats.steps > steps || cp.t != grid(cp.stats.steps) {
                return Err(Error::input(format!(
                    "the checkpoint does not fit this run: t = {} after {} steps is not on the grid of dt = {dt} \
                     ({steps} steps to t_end = {t_end})",
                    cp.t, cp.stats.steps
                )));
            }
            let rec = check_resume(cp, d, t_eval)?;
            stepper.restore(&cp.carry)?;
            if !cp.slope.is_empty() {
                f0.copy_from_slice(&cp.slope);
                f0_valid = true;
            }
            (rec, cp.next_out, cp.stats.steps)
        }
        None => {
            let mut rec = match t_eval {
                Some(te) => Recorder { t: Vec::with_capacity(te.len()), y: Vec::with_capacity(te.len() * d), stopped_at: None },
                None => Recorder { t: Vec::with_capacity(steps as usize + 1), y: Vec::with_capacity((steps as usize + 1) * d), stopped_at: None },
            };
            if t_eval.is_none() {
                rec.push(0.0, y);
            }
            events.start(0.0, y)?;
            (rec, 0usize, 0)
        }
    };
    let mut y_start = vec![0.0; d];
    for k in first..steps {
        let t = grid(k);
        let t_next = grid(k + 1);
        let h = t_next - t;
        if let Some(te) = t_eval {
            // Points at the start of this step are taken exactly; interior ones need f at both ends.
            while next_out < te.len() && te[next_out] <= t + 1e-9 * h {
                rec.push(te[next_out], y);
                next_out += 1;
            }
            if next_out < te.len() && te[next_out] < t_next - 1e-9 * h {
                y0.copy_from_slice(y);
                if !f0_valid {
                    sys.rhs(t, y, &mut f0)?;
                }
            }
        }
        let interior = t_eval.is_some_and(|te| next_out < te.len() && te[next_out] < t_next - 1e-9 * h);
        if events.active() {
            y_start.copy_from_slice(y);
        }
        stepper.step(sys, t, y, h)?;
        stats.steps += 1;
        check_state_finite(t_next, y)?;
        if events.active() {
            if events.detect(t_next, y)? {
                let (mut fa, mut fb) = (vec![0.0; d], vec![0.0; d]);
                sys.rhs(t, &y_start, &mut fa)?;
                sys.rhs(t_next, y, &mut fb)?;
                let y_end = y.to_vec();
                let stop = events.locate(t, h, |x, out| {
                    hermite(&y_start, &fa, &y_end, &fb, h, x, out);
                    Ok(())
                }, d)?;
                if let Some((te, ye)) = stop {
                    if let Some(tv) = t_eval {
                        while next_out < tv.len() && tv[next_out] <= te {
                            hermite(&y_start, &fa, &y_end, &fb, h, (tv[next_out] - t) / h, &mut out);
                            rec.push_interpolated(tv[next_out], &out)?;
                            next_out += 1;
                        }
                    }
                    rec.push_interpolated(te, &ye)?;
                    y.copy_from_slice(&ye);
                    rec.stopped_at = Some(te);
                    return Ok(rec);
                }
            } else {
                events.accept();
            }
        }
        f0_valid = false;
        if interior {
            let te = t_eval.unwrap();
            sys.rhs(t_next, y, &mut f1)?;
            while next_out < te.len() && te[next_out] < t_next - 1e-9 * h {
                hermite(&y0, &f0, y, &f1, h, (te[next_out] - t) / h, &mut out);
                rec.push_interpolated(te[next_out], &out)?;
                next_out += 1;
            }
            std::mem::swap(&mut f0, &mut f1);
            f0_valid = true;
        } else if t_eval.is_none() {
            rec.push(t_next, y);
        }
        let (evaluations, y_now) = (sys.evaluations, &*y);
        after_step(stats.steps, t_next, &mut *monitor, &mut checkpoints, || {
            Snapshot {
                t: t_next,
                y: y_now,
                stats,
                evaluations,
                iterations: stepper.iterations(),
                carry: stepper.carry(),
                slope: if f0_valid { &f0 } else { &[] },
                rec: &rec,
                next_out,
            }
            .take()
        })?;
    }
    if let Some(te) = t_eval {
        while next_out < te.len() {
            rec.push(te[next_out], y);
            next_out += 1;
        }
    }
    Ok(rec)
}

#[allow(clippy::too_many_arguments)]
fn run_dop853<T: TorqueSource>(
    sys: &mut ChainSystem<T>,
    settings: &Settings,
    y: &mut [f64],
    t_end: f64,
    stats: &mut Stats,
    monitor: Monitor,
    events: &mut Tracker,
    resume: Option<&Checkpoint>,
    mut checkpoints: Option<&mut Checkpoints>,
) -> Result<Recorder> {
    let d = y.len();
    let mut rk = Dop853::new(d, settings.rtol, settings.atol);
    let t_eval = settings.t_eval.as_deref();
    let fixed = !settings.adaptive;
    let (mut rec, mut next_out, mut t, mut h) = match resume {
        Some(cp) => {
            let rec = check_resume(cp, d, t_eval)?;
            let h = match cp.carry.h {
                Some(h) if h.is_finite() && h > 0.0 && cp.carry.comp.is_empty() => h,
                _ => return Err(Error::input("the checkpoint's integrator state does not fit dop853: it needs a step h > 0")),
            };
            if !(0.0..=t_end).contains(&cp.t) {
                return Err(Error::input(format!("the checkpoint does not fit this run: t = {} outside [0, t_end = {t_end}]", cp.t)));
            }
            rk.resume(&cp.carry.k)?;
            (rec, cp.next_out, cp.t, h)
        }
        None => {
            events.start(0.0, y)?;
            let mut rec = Recorder { t: Vec::new(), y: Vec::new(), stopped_at: None };
            let mut next_out = 0usize;
            rk.start(sys, 0.0, y)?;
            let h = match settings.dt {
                Some(dt) => dt.min(t_end),
                None => rk.initial_step(sys, 0.0, y, t_end)?,
            };
            match t_eval {
                None => rec.push(0.0, y),
                Some(te) => {
                    while next_out < te.len() && te[next_out] <= 0.0 {
                        rec.push(te[next_out], y);
                        next_out += 1;
                    }
                }
            }
            (rec, next_out, 0.0, h)
        }
    };
    let mut y_new = vec![0.0; d];
    let mut out = vec![0.0; d];
    let mut rejected = false;
    while t < t_end {
        if stats.steps + stats.rejected >= settings.max_steps {
            return Err(Error::integration(t, format!("reached max_steps = {} before t_end", settings.max_steps)));
        }
        let min_step = 10.0 * (t.abs() * f64::EPSILON).max(f64::MIN_POSITIVE);
        if h < min_step {
            return Err(Error::integration(t, "the step size underflowed (the motion is singular or blew up)"));
        }
        let last = t + h >= t_end;
        let h_try = if last { t_end - t } else { h };
        match rk.attempt(sys, t, y, h_try, &mut y_new, rejected, fixed)? {
            Attempt::Rejected { h_next } => {
                stats.rejected += 1;
                rejected = true;
                h = h_next;
                continue;
            }
            Attempt::Accepted { h_next } => {
                check_state_finite(t + h_try, &y_new)?;
                let t_new = if last { t_end } else { t + h_try };
                let crossing = events.active() && events.detect(t_new, &y_new)?;
                let dense = crossing || t_eval.is_some_and(|te| next_out < te.len() && te[next_out] < t_new);
                rk.finish_step(sys, t, y, &y_new, h_try, dense)?;
                if crossing {
                    let stop = events.locate(t, h_try, |x, out| {
                        rk.interpolate(y, x, out);
                        Ok(())
                    }, d)?;
                    if let Some((te, ye)) = stop {
                        if let Some(tv) = t_eval {
                            while next_out < tv.len() && tv[next_out] <= te {
                                rk.interpolate(y, (tv[next_out] - t) / h_try, &mut out);
                                rec.push_interpolated(tv[next_out], &out)?;
                                next_out += 1;
                            }
                        }
                        stats.steps += 1;
                        rec.push_interpolated(te, &ye)?;
                        y.copy_from_slice(&ye);
                        rec.stopped_at = Some(te);
                        return Ok(rec);
                    }
                } else if events.active() {
                    events.accept();
                }
                if let Some(te) = t_eval {
                    while next_out < te.len() && te[next_out] < t_new {
                        rk.interpolate(y, (te[next_out] - t) / h_try, &mut out);
                        rec.push_interpolated(te[next_out], &out)?;
                        next_out += 1;
                    }
                }
                y.copy_from_slice(&y_new);
                t = t_new;
                stats.steps += 1;
                if t_eval.is_none() {
                    rec.push(t, y);
                }
                if !fixed {
                    h = h_next;
                }
                rejected = false;
                if t_eval.is_none() && rec.t.len() == rec.t.capacity() {
                    // The next row doubles the buffers: check that they fit before they grow.
                    check_output_size(2.0 * rec.t.len() as f64, d / 2)?;
                }
                let (evaluations, y_now, rk) = (sys.evaluations, &*y, &rk);
                after_step(stats.steps, t, &mut *monitor, &mut checkpoints, || {
                    Snapshot {
                        t,
                        y: y_now,
                        stats,
                        evaluations,
                        iterations: 0,
                        carry: Carry { k: rk.slope().to_vec(), comp: Vec::new(), h: Some(h) },
                        slope: &[],
                        rec: &rec,
                        next_out,
                    }
                    .take()
                })?;
            }
        }
    }
    if let Some(te) = t_eval {
        while next_out < te.len() {
            rec.push(te[next_out], y);
            next_out += 1;
        }
    }
    Ok(rec)
}

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
    let rows = settings.validate(t_end)?;
    check_output_size(rows as f64, chain.n())?;
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
    let mut sys = ChainSystem::new(chain, torque, form);
    let mut ws = Workspace::new(n);
    let mut y = vec![0.0; sys.dim()];
    let mut stats = Stats::default();
    match start {
        Start::Initial { theta0, omega0 } => {
            y[..n].copy_from_slice(theta0);
            match form {
                Form::Lagrangian => y[n..2 * n].copy_from_slice(omega0),
                Form::Hamiltonian => chain.momenta_into(theta0, omega0, &mut y[n..2 * n], &mut ws),
            }
        }
        Start::Resume(cp) => {
            if cp.y.len() != y.len() {
                return Err(Error::input(format!(
                    "the checkpoint does not fit this run: its state has {} values, this run's {} \
                     ({n} links, form {}{})",
                    cp.y.len(),
                    y.len(),
                    form.name(),
                    if sys.tracks_work() { ", with the torque's work" } else { "" }
                )));
            }
            check_state_finite(cp.t, &cp.y).map_err(|_| Error::input("the checkpoint's state is not finite"))?;
            y.copy_from_slice(&cp.y);
            stats = Stats { energy_error: 0.0, ..cp.stats.clone() };
            sys.evaluations = cp.stats.evaluations;
        }
    }
    let t_eval = settings.t_eval.as_deref();
    let mut tracker = Tracker::new(&settings.events, chain, form);
    let dt = settings.dt.unwrap_or(0.0);
    let rec = match settings.method {
        Method::Rk4 => run_fixed(&mut sys, &mut Rk4::new(y.len()), &mut y, t_end, dt, t_eval, &mut stats, monitor, &mut tracker, resume, checkpoints)?,
        Method::Gauss4 | Method::Gauss6 => {
            let mut g = Gauss::new(settings.method.order() as usize / 2, y.len());
            g.iterations = stats.iterations;
            let rec = run_fixed(&mut sys, &mut g, &mut y, t_end, dt, t_eval, &mut stats, monitor, &mut tracker, resume, checkpoints)?;
            stats.iterations = g.iterations;
            rec
        }
        Method::Dop853 => run_dop853(&mut sys, settings, &mut y, t_end, &mut stats, monitor, &mut tracker, resume, checkpoints)?,
    };
    stats.evaluations = sys.evaluations;
    let hits = std::mem::take(&mut tracker.hits);
    Ok(finish(chain, form, sys.tracks_work(), rec, hits, stats, &mut ws))
}

/// `omega` and `p` of a raw ODE state `y = [theta, omega or p, ...]` in the given form.
fn fill_rates(chain: &Chain, form: Form, y: &[f64], omega: &mut [f64], p: &mut [f64], ws: &mut Workspace) {
    let n = chain.n();
    let theta = &y[..n];
    match form {
        Form::Lagrangian => {
            omega.copy_from_slice(&y[n..2 * n]);
            chain.momenta_into(theta, omega, p, ws);
        }
        Form::Hamiltonian => {
            p.copy_from_slice(&y[n..2 * n]);
            // Cannot fail: the same state passed through the right-hand side.
            if chain.velocities_into(theta, p, omega, ws).is_err() {
                omega.fill(f64::NAN);
            }
        }
    }
}

/// Turn raw ODE states into theta, omega, p, energy and work rows.
fn finish(chain: &Chain, form: Form, work: bool, rec: Recorder, hits: Vec<Hit>, mut stats: Stats, ws: &mut Workspace) -> Trajectory {
    let n = chain.n();
    let d = 2 * n + usize::from(work);
    let rows = rec.t.len();
    let mut tr = Trajectory {
        n,
        theta: Vec::with_capacity(rows * n),
        omega: vec![0.0; rows * n],
        p: vec![0.0; rows * n],
        energy: Vec::with_capacity(rows),
        work: Vec::with_capacity(rows),
        t: rec.t,
        stats: Stats::default(),
        form,
        events: Vec::with_capacity(hits.len()),
        stopped_at: rec.stopped_at,
    };
    let mut scratch = vec![0.0; n];
    for r in 0..rows {
        let y = &rec.y[r * d..(r + 1) * d];
        let theta = &y[..n];
        tr.theta.extend_from_slice(theta);
        let (omega, p) = (&mut tr.omega[r * n..(r + 1) * n], &mut tr.p[r * n..(r + 1) * n]);
        fill_rates(chain, form, y, omega, p, ws);
        let energy = chain.kinetic_energy(theta, omega, &mut scratch, ws) + chain.potential_energy(theta);
        tr.energy.push(energy);
        tr.work.push(if work { y[2 * n] } else { 0.0 });
    }
    for hit in hits {
        let theta = hit.y[..n].to_vec();
        let (mut omega, mut p) = (vec![0.0; n], vec![0.0; n]);
        fill_rates(chain, form, &hit.y, &mut omega, &mut p, ws);
        tr.events.push((hit.event, hit.t, theta, omega, p));
    }
    if let Some(&e0) = tr.energy.first() {
        let scale = if e0 != 0.0 { e0.abs() } else { 1.0 };
        stats.energy_error =
            tr.energy.iter().zip(&tr.work).map(|(e, w)| (e - e0 - w).abs()).fold(0.0, f64::max) / scale;
    }
    tr.stats = stats;
    tr
}

/// Run a batch of initial states in parallel (rayon; one after another without the `parallel`
/// feature); results in input order, each identical to its single run whatever the number of
/// threads. Rows of `theta0`/`omega0` are states.
pub fn simulate_batch<T: TorqueSource + Clone + Send + Sync>(
    chain: &Chain,
    theta0: &[f64],
    omega0: &[f64],
    t_end: f64,
    settings: &Settings,
    torque: &T,
) -> Result<Vec<Trajectory>> {
    let n = chain.n();
    if theta0.len() != omega0.len() || theta0.len() % n != 0 {
        return Err(Error::input(format!(
            "theta0 and omega0 must both have shape (B, {n}), got {} and {} numbers",
            theta0.len(),
            omega0.len()
        )));
    }
    if settings.method.adaptive() && settings.adaptive && settings.t_eval.is_none() {
        return Err(Error::input(
            "a batch run of an adaptive method needs t_eval (each trajectory takes its own steps)",
        ));
    }
    let b = theta0.len() / n;
    let rows = settings.validate(t_end)?;
    check_output_size(rows as f64 * b as f64, n)?;
    check_fixed_steps(settings, t_end)?;
    (0..b)
        .into_par_iter()
        .map(|i| {
            let range = i * n..(i + 1) * n;
            simulate(chain, &theta0[range.clone()], &omega0[range], t_end, settings, torque.clone(), &mut |_| Ok(()))
                .map_err(|e| match e {
                    Error::Input(m) => Error::Input(format!("trajectory {i}: {m}")),
                    Error::Integration { t, reason } => Error::Integration { t, reason: format!("trajectory {i}: {reason}") },
                    other => other,
                })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::torque::Builtin;

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
                    let resumed =
                        simulate_from(&chain, Start::Resume(cp), 3.0, &s, drive(), &mut |_| Ok(()), None).unwrap();
                    assert_eq!(resumed, plain, "{method}: resumed at t = {}", cp.t);
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
        assert_eq!(cp.stats.steps % MONITOR_EVERY, 0);
        assert!(cp.t > 1.0 && cp.t < 1.1, "t = {}", cp.t);
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
        let resume = |cp: &Checkpoint, s: &Settings| {
            simulate_from(&chain, Start::Resume(cp), 1.0, s, drive(), &mut |_| Ok(()), None).unwrap_err().to_string()
        };
        let off_grid = Checkpoint { t: cp.t + 1e-3, ..cp.clone() };
        assert!(resume(&off_grid, &s).contains("not on the grid"), "{}", resume(&off_grid, &s));
        let short = Checkpoint { y: cp.y[..4].to_vec(), ..cp.clone() };
        assert!(resume(&short, &s).contains("its state has 4 values, this run's 5"), "{}", resume(&short, &s));
        assert!(resume(cp, &settings("rk4", Some(0.01), None)).contains("not that of this method"));
        assert!(resume(cp, &settings("dop853", None, None)).contains("dop853"));
        let rows = Checkpoint { out_t: cp.out_t[1..].to_vec(), ..cp.clone() };
        assert!(resume(&rows, &s).contains("output times but"), "{}", resume(&rows, &s));
        let nan = Checkpoint { y: vec![f64::NAN; 5], ..cp.clone() };
        assert!(resume(&nan, &s).contains("not finite"));
        let with_events = Settings { events: vec![EventSpec { condition: crate::events::Condition::Flip(None), direction: 1, terminal: true }], ..s.clone() };
        assert!(resume(cp, &with_events).contains("cannot be combined with events"));
    }
}
