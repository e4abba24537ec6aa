//! One run from an initial state to `t_end`: validation, the integration loop, output at the
//! requested times, and the derived quantities (momenta or velocities, energy, work).
use crate::par::*;

use crate::dynamics::Workspace;
use crate::error::{Error, Result};
use crate::events::{EventSpec, Hit, Tracker};
use crate::integrators::{dop853::Attempt, Dop853, FixedStep, Gauss, Method, Rk4};
use crate::model::Chain;
use crate::system::{ChainSystem, Form, OdeSystem};
use crate::torque::TorqueSource;

/// Refuse outputs that would need more memory than this; the message says how to ask for less.
pub const MAX_OUTPUT_BYTES: f64 = 8.0 * 1024.0 * 1024.0 * 1024.0;

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

fn check_output_size(rows: f64, n: usize) -> Result<()> {
    let bytes = rows * (3 * n + 2) as f64 * 8.0;
    if bytes > MAX_OUTPUT_BYTES {
        return Err(Error::input(format!(
            "storing {rows:.0} output points of {n} links needs {:.1} GiB (limit {:.0} GiB); \
             ask for fewer with t_eval (e.g. 10^4 points) or a larger dt",
            bytes / 1073741824.0,
            MAX_OUTPUT_BYTES / 1073741824.0
        )));
    }
    Ok(())
}

/// Collects output rows of the raw ODE state `y`.
struct Recorder {
    t: Vec<f64>,
    y: Vec<f64>,
    stopped_at: Option<f64>,
}

impl Recorder {
    fn push(&mut self, t: f64, y: &[f64]) {
        self.t.push(t);
        self.y.extend_from_slice(y);
    }
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

fn run_fixed<S: OdeSystem, I: FixedStep>(
    sys: &mut S,
    stepper: &mut I,
    y: &mut [f64],
    t_end: f64,
    dt: f64,
    t_eval: Option<&[f64]>,
    stats: &mut Stats,
    monitor: Monitor,
    events: &mut Tracker,
) -> Result<Recorder> {
    let steps = fixed_steps(t_end, dt);
    let d = y.len();
    let mut rec = match t_eval {
        Some(te) => Recorder { t: Vec::with_capacity(te.len()), y: Vec::with_capacity(te.len() * d), stopped_at: None },
        None => Recorder { t: Vec::with_capacity(steps as usize + 1), y: Vec::with_capacity((steps as usize + 1) * d), stopped_at: None },
    };
    let mut next_out = 0usize; // index into t_eval
    let (mut f0, mut f1, mut y0) = (vec![0.0; d], vec![0.0; d], vec![0.0; d]);
    let mut out = vec![0.0; d];
    let mut f0_valid = false;
    if t_eval.is_none() {
        rec.push(0.0, y);
    }
    let mut y_start = vec![0.0; d];
    events.start(0.0, y)?;
    for k in 0..steps {
        let t = k as f64 * dt;
        let t_next = if k + 1 == steps { t_end } else { (k + 1) as f64 * dt };
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
                            rec.push(tv[next_out], &out);
                            next_out += 1;
                        }
                    }
                    rec.push(te, &ye);
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
                rec.push(te[next_out], &out);
                next_out += 1;
            }
            std::mem::swap(&mut f0, &mut f1);
            f0_valid = true;
        } else if t_eval.is_none() {
            rec.push(t_next, y);
        }
        if stats.steps % MONITOR_EVERY == 0 {
            monitor(t_next)?;
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

#[allow(clippy::too_many_arguments)]
fn run_dop853<S: OdeSystem>(
    sys: &mut S,
    settings: &Settings,
    y: &mut [f64],
    t_end: f64,
    stats: &mut Stats,
    monitor: Monitor,
    events: &mut Tracker,
) -> Result<Recorder> {
    let d = y.len();
    let mut rk = Dop853::new(d, settings.rtol, settings.atol);
    events.start(0.0, y)?;
    let t_eval = settings.t_eval.as_deref();
    let mut rec = Recorder { t: Vec::new(), y: Vec::new(), stopped_at: None };
    let mut next_out = 0usize;
    rk.start(sys, 0.0, y)?;
    let fixed = !settings.adaptive;
    let mut h = match settings.dt {
        Some(dt) => dt.min(t_end),
        None => rk.initial_step(sys, 0.0, y, t_end)?,
    };
    let mut t = 0.0;
    let mut y_new = vec![0.0; d];
    let mut out = vec![0.0; d];
    match t_eval {
        None => rec.push(0.0, y),
        Some(te) => {
            while next_out < te.len() && te[next_out] <= 0.0 {
                rec.push(te[next_out], y);
                next_out += 1;
            }
        }
    }
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
                                rec.push(tv[next_out], &out);
                                next_out += 1;
                            }
                        }
                        stats.steps += 1;
                        rec.push(te, &ye);
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
                        rec.push(te[next_out], &out);
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
                if stats.steps % MONITOR_EVERY == 0 {
                    if t_eval.is_none() {
                        check_output_size(rec.t.len() as f64, d / 2)?;
                    }
                    monitor(t)?;
                }
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
    chain.check_state("theta0", theta0)?;
    chain.check_state("omega0", omega0)?;
    let rows = settings.validate(t_end)?;
    check_output_size(rows as f64, chain.n())?;
    let form = settings.resolved_form()?;
    let n = chain.n();
    for e in &settings.events {
        e.validate(n)?;
    }
    let mut sys = ChainSystem::new(chain, torque, form);
    let mut ws = Workspace::new(n);
    let mut y = vec![0.0; sys.dim()];
    y[..n].copy_from_slice(theta0);
    match form {
        Form::Lagrangian => y[n..2 * n].copy_from_slice(omega0),
        Form::Hamiltonian => chain.momenta_into(theta0, omega0, &mut y[n..2 * n], &mut ws),
    }
    let mut stats = Stats::default();
    let t_eval = settings.t_eval.as_deref();
    let mut tracker = Tracker::new(&settings.events, chain, form);
    let dt = settings.dt.unwrap_or(0.0);
    let rec = match settings.method {
        Method::Rk4 => run_fixed(&mut sys, &mut Rk4::new(y.len()), &mut y, t_end, dt, t_eval, &mut stats, monitor, &mut tracker)?,
        Method::Gauss4 | Method::Gauss6 => {
            let mut g = Gauss::new(settings.method.order() as usize / 2, y.len());
            let rec = run_fixed(&mut sys, &mut g, &mut y, t_end, dt, t_eval, &mut stats, monitor, &mut tracker)?;
            stats.iterations = g.iterations;
            rec
        }
        Method::Dop853 => run_dop853(&mut sys, settings, &mut y, t_end, &mut stats, monitor, &mut tracker)?,
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
