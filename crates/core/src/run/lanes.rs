//! A batch [`super::simulate_batch`] in SIMD lanes: eight trajectories of one chain at a time
//! (rk4: [`Rk4Lanes`]; dop853: [`Dop853Lanes`]; on [`ChainLanes`]), each with every output the
//! per-trajectory route gives (the same rows, momenta, energies, work and energy errors: the
//! rows go through the same [`super::simulate::finish`]). Taken for a chain on a fixed or moving
//! pivot (a sinusoid or a table on each axis) or on a cart (damping and friction included),
//! undriven or under a built-in torque, on the Lagrangian form of rk4 or adaptive dop853 without
//! events or sensitivities; anything else runs trajectory by trajectory.
//!
//! rk4 steps on the run driver's grid: `t_k = k dt`, each step of `t_{k+1} - t_k`, the last one
//! landing on `t_end`; an output time within 1e-9 of a step of a grid point is that point's
//! state, any other the step's cubic Hermite interpolant (its slopes evaluated as the driver's,
//! and counted alike). A trajectory agrees with its per-trajectory run to round-off (the lanes'
//! own `sin`/`cos` and fused product-sums). dop853 takes a step per lane as the driver's
//! controlled steps, outputs from the step's 7th-order interpolant, a finished lane refilled
//! with the next row: a trajectory agrees with its per-trajectory run to the tolerance (the
//! error estimate cancels to round-off, so the steps drift apart). Either way its bits depend
//! neither on the other trajectories nor on the number of threads, and are the same on the
//! AVX-512, AVX2 and portable paths.
use super::driver::{fixed_steps, max_steps_reached, min_step, UNDERFLOW};
use super::simulate::{finish, Recorder, Settings, Stats, Trajectory};
use crate::dynamics::base::{Drive, Pivot};
use crate::dynamics::lanes::LaneScratch;
use crate::dynamics::system::{check_finite_state, ChainSystem, Form, Layout, NON_FINITE};
use crate::dynamics::torque::{Builtin, Timed};
use crate::error::{Error, Result};
use crate::integrators::dop853_lanes::{mask, Dop853Lanes, StartFailure};
use crate::integrators::lanes::{failed_at, ChainLanes, LaneSystem, Rk4Lanes};
use crate::integrators::Method;
use crate::integrators::{Controller, Decision};
use crate::interp::hermite;
use crate::model::Chain;
use crate::par::*;
use crate::trig::lanes::{copy_lanes, on_path, Lane, Path, LANES};
use crate::watch::Watch;

/// Whether a batch with `settings` and the torque `drive` (`None`: one the lanes cannot
/// evaluate) runs in lanes, and on which path: rk4, or adaptive dop853 with `t_eval`, in the
/// Lagrangian form; a pivot fixed or moving as the lanes can evaluate it (no axis a function),
/// no cart force, no events and no sensitivities; unless `MULTIPENDULUM_LANES` asks for the
/// per-trajectory route.
pub fn route(settings: &Settings, drive: Option<&Timed>) -> Result<Option<Path>> {
    let fits = drive.is_some()
        && (settings.method == Method::Rk4 || (settings.method == Method::Dop853 && settings.adaptive && settings.t_eval.is_some()))
        && matches!(settings.resolved_form(), Ok(Form::Lagrangian))
        && settings.drive.pivot.as_ref().map_or(true, Pivot::in_lanes)
        && settings.drive.force.is_none()
        && settings.events.is_empty()
        && settings.sensitivities.is_empty();
    if !fits {
        return Ok(None);
    }
    super::bank::requested()
}

/// The batch of the rows of `theta0`, `omega0` (flat, `(B, N)`, checked by the caller as a batch
/// run checks them, but for each row's values) to `t_end` in lanes on `path` (see [`route`]).
/// Each finished trajectory counts a unit of `watch`; a stopped watch stops every group within
/// a step.
#[allow(clippy::too_many_arguments)]
pub fn simulate(
    chain: &Chain,
    theta0: &[f64],
    omega0: &[f64],
    t_end: f64,
    settings: &Settings,
    drive: &Timed,
    path: Path,
    watch: &Watch,
) -> Result<Vec<Trajectory>> {
    let n = chain.n();
    for (i, (th, om)) in theta0.chunks(n).zip(omega0.chunks(n)).enumerate() {
        chain.check_state("theta0", th).and_then(|_| chain.check_state("omega0", om)).map_err(|e| e.of_trajectory(i))?;
    }
    super::simulate::check_cart0(chain, settings)?;
    let layout = layout(chain, drive, &settings.drive)?;
    let drive = Some(drive).filter(|d| !matches!(d.builtin, Builtin::None));
    // rk4's rows share the grid, eight to a group; dop853's take their own steps, a finished
    // lane refilled with the chunk's next row.
    let rows = if settings.method == Method::Dop853 { CHUNK } else { LANES };
    let groups: Vec<Vec<Trajectory>> = theta0
        .par_chunks(n * rows)
        .zip(omega0.par_chunks(n * rows))
        .enumerate()
        .map(|(g, (th, om))| {
            watch.check(0.0)?;
            let pivot = settings.drive.moving_pivot();
            let out = group_on(path, &Group { chain, layout, th, om, first: g * rows, drive, pivot, settings, t_end }, watch)?;
            watch.add_units(out.len() as u64);
            Ok(out)
        })
        .collect::<Result<_>>()?;
    Ok(groups.into_iter().flatten().collect())
}

/// The per-trajectory run's layout of its raw state under the torque `drive` and the base's
/// `motion`: the lanes keep theirs alike ([`ChainLanes`]' work slots come in its order), so
/// that a lane is a raw state ([`raw_row`]).
pub(crate) fn layout(chain: &Chain, drive: &Timed, motion: &Drive) -> Result<Layout> {
    Ok(ChainSystem::new(chain, drive.clone(), Form::Lagrangian).with_drive(motion.clone())?.layout())
}

/// Lane `j` of `y` into `out`.
#[inline]
pub(crate) fn lane_of(y: &[Lane], j: usize, out: &mut [f64]) {
    for (o, v) in out.iter_mut().zip(y) {
        *o = v[j];
    }
}

/// Lane `j` of `y` as the run driver's raw state ([`to_raw`]).
#[inline]
pub(crate) fn raw_row(layout: Layout, y: &[Lane], j: usize, row: &mut [f64]) {
    lane_of(y, j, row);
    to_raw(layout, row);
}

/// A lane's state (or its interpolant's) as the run driver's raw state: the losses' slot holds
/// the energy dissipated, `D`, where the lanes integrate its work, `-D`.
#[inline]
fn to_raw(layout: Layout, row: &mut [f64]) {
    if let Some(m) = layout.dissipated() {
        row[m] = -row[m];
    }
}

/// Rows per parallel task of dop853 (whose lanes take the next row as they finish).
const CHUNK: usize = 64;

/// The rows of a task and what they run with.
struct Group<'a> {
    chain: &'a Chain,
    layout: Layout,
    th: &'a [f64],
    om: &'a [f64],
    /// The batch index of the first row (for messages).
    first: usize,
    drive: Option<&'a Timed>,
    pivot: Option<&'a Pivot>,
    settings: &'a Settings,
    t_end: f64,
}

impl Group<'_> {
    /// Row `r`'s initial raw state into `start` and lane `j` of `y`: its angles and rates, the
    /// cart's `cart0`, no work yet.
    fn load(&self, r: usize, start: &mut [f64], y: &mut [Lane], j: usize) {
        let n = self.chain.n();
        start.fill(0.0);
        start[..n].copy_from_slice(&self.th[n * r..n * (r + 1)]);
        start[n..2 * n].copy_from_slice(&self.om[n * r..n * (r + 1)]);
        if let Some(c) = self.layout.cart() {
            start[c..c + 2].copy_from_slice(&self.settings.cart0);
        }
        for (m, v) in start.iter().enumerate() {
            y[m][j] = *v;
        }
    }
}

on_path! {
    fn group_on(g: &Group, watch: &Watch) -> Result<Vec<Trajectory>> {
        run_group(g, watch)
    }
}

/// No force on a cart (a batch in lanes has none).
const NO_FORCE: Lane = [0.0; LANES];

/// The group's equations in lanes, with the per-trajectory run's work slots; `zero` the held
/// torques (none: a drive's torques of time ride along instead), `q` scratch (`N` lanes).
#[inline(always)]
fn equations<'a>(g: &'a Group, zero: &'a [Lane], q: &'a mut [Lane]) -> ChainLanes<'a> {
    ChainLanes { chain: g.chain, tau: zero, drive: g.drive, force: &NO_FORCE, pivot: g.pivot, pivot_work: g.layout.pivot, q }
}

#[inline(always)]
fn run_group(g: &Group, watch: &Watch) -> Result<Vec<Trajectory>> {
    if g.settings.method == Method::Dop853 {
        return dop853_rows(g, watch);
    }
    let (chain, layout, settings, t_end) = (g.chain, g.layout, g.settings, g.t_end);
    let n = chain.n();
    let count = g.th.len() / n;
    let d = layout.dim();
    let lanes = |k| vec![[0.0; LANES]; k];
    let (mut y, mut y0, mut f0, mut f1, mut q, zero) = (lanes(d), lanes(d), lanes(d), lanes(d), lanes(n), lanes(n));
    let mut scratch = LaneScratch::new(n);
    let mut rk = Rk4Lanes::with_dim(n, d);
    let mut active = [0.0; LANES];
    let mut initial = vec![vec![0.0; d]; count];
    for (j, start) in initial.iter_mut().enumerate() {
        g.load(j, start, &mut y, j);
        active[j] = 1.0;
    }
    let error = |j: usize, t: f64, reason: &str| Error::integration(t, reason).of_trajectory(g.first + j);
    // A row of every lane into its recorder: the driver's raw state (the losses' slot holds the
    // energy dissipated, D; the lanes integrate their work, -D).
    let mut recs: Vec<Recorder> = (0..count).map(|_| Recorder::default()).collect();
    let mut row = vec![0.0; d];
    let mut record = |recs: &mut [Recorder], t: f64, y: &[Lane]| {
        for (j, rec) in recs.iter_mut().enumerate() {
            raw_row(layout, y, j, &mut row);
            rec.push(t, &row);
        }
    };
    let t_eval = settings.t_eval.as_deref();
    let dt = settings.dt.unwrap_or(f64::NAN);
    let steps = fixed_steps(t_end, dt);
    let grid = |k: u64| if k == steps { t_end } else { k as f64 * dt };
    if t_eval.is_none() {
        record(&mut recs, 0.0, &y);
    }
    let (mut next, mut evaluations) = (0, 0u64);
    // Whether the slope at the current state is known (the last step's end slope, kept).
    let mut end_known = false;
    let snap = 1e-9;
    // A step's ends and slopes in one lane, and its interpolant's value there.
    let (mut ends, mut point) = ([vec![0.0; d], vec![0.0; d], vec![0.0; d], vec![0.0; d]], vec![0.0; d]);
    for k in 0..steps {
        let (t, t1) = (grid(k), grid(k + 1));
        let h = t1 - t;
        // Every step: a relaxed load against eight rows' step.
        watch.check(t)?;
        if let Some(te) = t_eval {
            while next < te.len() && te[next] <= t + snap * h {
                record(&mut recs, te[next], &y);
                next += 1;
            }
        }
        copy_lanes(&mut y0, &y);
        let nonfinite = rk.step_system(&mut y, t, h, &active, &mut equations(g, &zero, &mut q)).map_err(|(stage, bad)| {
            let j = (0..LANES).find(|&j| bad.lanes[j]).unwrap_or(0);
            error(j, failed_at(&bad, j, stage, t, h), &bad.reason(j))
        })?;
        if let Some(j) = (0..count).find(|&j| nonfinite[j]) {
            return Err(error(j, t1, NON_FINITE));
        }
        evaluations += 4;
        // The start slope is the last step's end slope when that was evaluated.
        let start_known = std::mem::take(&mut end_known);
        if start_known {
            std::mem::swap(&mut f0, &mut f1);
        }
        if let Some(te) = t_eval {
            let edge = t1 - snap * h;
            if next < te.len() && te[next] < edge {
                let failed = |t: f64| {
                    move |s: crate::dynamics::lanes::LaneSingular| {
                        let j = (0..LANES).find(|&j| s.lanes[j]).unwrap_or(0);
                        error(j, t, &s.reason(j))
                    }
                };
                // The slopes in place, not through a closure: its body would compile outside the
                // path's target features, each `mul_add` a call to `fma()`.
                if !start_known {
                    equations(g, &zero, &mut q).rates(&[t; LANES], &y0, &mut f0, &mut scratch, &active).map_err(|s| failed(t)(s.seen_in(&y0)))?;
                    evaluations += 1;
                }
                equations(g, &zero, &mut q).rates(&[t1; LANES], &y, &mut f1, &mut scratch, &active).map_err(|s| failed(t1)(s.seen_in(&y)))?;
                evaluations += 1;
                end_known = true;
                while next < te.len() && te[next] < edge {
                    let (at, x) = (te[next], (te[next] - t) / h);
                    for (j, rec) in recs.iter_mut().enumerate() {
                        for (buf, v) in ends.iter_mut().zip([&y0, &f0, &y, &f1]) {
                            lane_of(v, j, buf);
                        }
                        hermite(&ends[0], &ends[1], &ends[2], &ends[3], h, x, &mut point);
                        to_raw(layout, &mut point);
                        check_finite_state(at, &point).map_err(|_| error(j, at, NON_FINITE))?;
                        rec.push(at, &point);
                    }
                    next += 1;
                }
            }
        } else {
            record(&mut recs, t1, &y);
        }
    }
    if let Some(te) = t_eval {
        while next < te.len() {
            record(&mut recs, te[next], &y);
            next += 1;
        }
    }
    let stats = Stats { steps, rejected: 0, evaluations, iterations: 0, energy_error: 0.0 };
    recs.into_iter().zip(initial).map(|(rec, start)| finish(chain, Form::Lagrangian, layout, &settings.drive, &start, rec, Vec::new(), stats.clone())).collect()
}

/// The run driver's step control of dop853 in eight lanes: each lane's time, next step and
/// counters under the driver's rules (`max_steps`, an underflowed step, the last step cut to
/// land on `t_end`, keeping the proposal it was cut from). Shared by the batch runs and the
/// ensembles in lanes.
#[derive(Debug, Clone, Default)]
pub(crate) struct LaneControl {
    pub t: Lane,
    /// The next step to try.
    pub h: Lane,
    pub steps: [u64; LANES],
    pub rejected: [u64; LANES],
    after_rejection: [bool; LANES],
    /// The trial's: whether it lands on `t_end`, and its size.
    pub last: [bool; LANES],
    pub h_try: Lane,
}

impl LaneControl {
    /// Lane `j` starts a new row at t = 0 with the first step `h`.
    pub fn restart(&mut self, j: usize, h: f64) {
        (self.t[j], self.h[j], self.steps[j], self.rejected[j], self.after_rejection[j]) = (0.0, h, 0, 0, false);
    }

    /// Lane `j`'s next trial towards `t_end`; `Err(reason)` when it may not take one.
    pub fn propose(&mut self, j: usize, t_end: f64, max_steps: u64) -> std::result::Result<(), String> {
        if self.steps[j] + self.rejected[j] >= max_steps {
            return Err(max_steps_reached(max_steps));
        }
        if self.h[j] < min_step(self.t[j]) {
            return Err(UNDERFLOW.to_string());
        }
        self.last[j] = self.t[j] + self.h[j] >= t_end;
        self.h_try[j] = if self.last[j] { t_end - self.t[j] } else { self.h[j] };
        Ok(())
    }

    /// The controller's decisions on the `running` lanes' trials (error norms `err`, new states
    /// `y_new`): the accepted lanes and the times they reach; `Err(j)` when lane `j`'s accepted
    /// state is not finite.
    pub fn decide(&mut self, err: &Lane, running: &[bool; LANES], y_new: &[Lane], t_end: f64) -> std::result::Result<([bool; LANES], Lane), usize> {
        let (mut accepted, mut t_new) = ([false; LANES], self.t);
        for j in (0..LANES).filter(|&j| running[j]) {
            match Controller::DOP853.decide(err[j], self.h_try[j], self.after_rejection[j]) {
                Decision::Reject { h_next } => {
                    self.rejected[j] += 1;
                    self.after_rejection[j] = true;
                    self.h[j] = h_next;
                }
                Decision::Accept { h_next } => {
                    if !y_new.iter().all(|v| v[j].is_finite()) {
                        return Err(j);
                    }
                    // A step shortened to land on the end keeps the proposal it was cut from.
                    if !self.last[j] {
                        self.h[j] = h_next;
                    }
                    self.after_rejection[j] = false;
                    accepted[j] = true;
                    self.steps[j] += 1;
                    t_new[j] = if self.last[j] { t_end } else { self.t[j] + self.h_try[j] };
                }
            }
        }
        Ok((accepted, t_new))
    }

    /// The `accepted` lanes move to their new states and times (after their interpolants are used).
    pub fn advance(&mut self, y: &mut [Lane], y_new: &[Lane], accepted: &[bool; LANES], t_new: Lane) {
        for (yv, nv) in y.iter_mut().zip(y_new) {
            for i in 0..LANES {
                yv[i] = if accepted[i] { nv[i] } else { yv[i] };
            }
        }
        self.t = t_new;
    }

    /// The earliest time of the `running` lanes.
    pub fn earliest(&self, running: &[bool; LANES]) -> f64 {
        (0..LANES).filter(|&j| running[j]).map(|j| self.t[j]).fold(f64::INFINITY, f64::min)
    }
}

/// dop853 with a step per lane, as the run driver's controlled steps (its first step,
/// controller, `max_steps`, landing on `t_end`), each row's outputs at `t_eval` from its state
/// or its step's 7th-order interpolant as the driver takes them; a lane whose row is done takes
/// the task's next row. Evaluations are counted as the driver counts them (12 per attempt, the
/// first step's guess, 3 for an interpolant).
#[inline(always)]
fn dop853_rows(g: &Group, watch: &Watch) -> Result<Vec<Trajectory>> {
    let (chain, layout, settings, t_end) = (g.chain, g.layout, g.settings, g.t_end);
    let n = chain.n();
    let count = g.th.len() / n;
    let d = layout.dim();
    let te = settings.t_eval.as_deref().unwrap_or(&[]);
    let lanes = |k| vec![[0.0; LANES]; k];
    let (mut y, mut y_new, mut q, zero) = (lanes(d), lanes(d), lanes(n), lanes(n));
    let mut dp = Dop853Lanes::new(n, d, d, settings.rtol, settings.atol);
    let error = |r: usize, t: f64, reason: &str| Error::integration(t, reason).of_trajectory(g.first + r);
    let mut done: Vec<Option<Trajectory>> = (0..count).map(|_| None).collect();
    let mut recs: Vec<Recorder> = (0..LANES).map(|_| Recorder::default()).collect();
    // Per lane: its row, its step control, output index and evaluations.
    let mut slot: [Option<usize>; LANES] = [None; LANES];
    let mut ctl = LaneControl::default();
    let (mut evaluations, mut next_out) = ([0u64; LANES], [0usize; LANES]);
    let (mut row, mut initial) = (vec![0.0; d], vec![vec![0.0; d]; LANES]);
    let mut next = 0;
    loop {
        let mut fresh = [false; LANES];
        for j in 0..LANES {
            if slot[j].is_none() && next < count {
                g.load(next, &mut initial[j], &mut y, j);
                (slot[j], fresh[j], next) = (Some(next), true, next + 1);
                ctl.restart(j, 0.0);
                next_out[j] = 0;
                evaluations[j] = if settings.dt.is_some() { 1 } else { 2 };
                recs[j] = Recorder::default();
            }
        }
        let mut sys = equations(g, &zero, &mut q);
        if fresh.iter().any(|&f| f) {
            let first = dp.start(&mut sys, &ctl.t, &y, &fresh, &[t_end; LANES], settings.dt).map_err(|(j, why)| {
                let r = slot[j].unwrap_or(0);
                match why {
                    StartFailure::Singular(link) => error(r, 0.0, &link.reason()),
                    StartFailure::NonFinite => error(r, 0.0, NON_FINITE),
                }
            })?;
            for j in (0..LANES).filter(|&j| fresh[j]) {
                ctl.h[j] = first[j];
            }
        }
        let running = slot.map(|s| s.is_some());
        if !running.iter().any(|&r| r) {
            break;
        }
        // Every step: a relaxed load against eight lanes' step.
        watch.check(ctl.earliest(&running))?;
        for j in (0..LANES).filter(|&j| running[j]) {
            // Output times at the state the step starts from, as the driver takes them.
            while next_out[j] < te.len() && te[next_out[j]] <= ctl.t[j] {
                raw_row(layout, &y, j, &mut row);
                recs[j].push(te[next_out[j]], &row);
                next_out[j] += 1;
            }
            ctl.propose(j, t_end, settings.max_steps).map_err(|why| error(slot[j].unwrap_or(0), ctl.t[j], &why))?;
            evaluations[j] += 12;
        }
        let (t, h_try) = (ctl.t, ctl.h_try);
        let err = dp.trial(&mut sys, &t, &y, &h_try, &mut y_new, &mask(&running));
        let (accepted, t_new) = ctl.decide(&err, &running, &y_new, t_end).map_err(|j| error(slot[j].unwrap_or(0), t[j] + h_try[j], NON_FINITE))?;
        // Output times inside an accepted step: from its interpolant.
        let inside: [bool; LANES] = std::array::from_fn(|j| accepted[j] && next_out[j] < te.len() && te[next_out[j]] < t_new[j]);
        if inside.iter().any(|&b| b) {
            dp.dense(&mut sys, &t, &y, &y_new, &h_try, &inside).map_err(|s| {
                let j = (0..LANES).find(|&j| s.lanes[j]).unwrap_or(0);
                error(slot[j].unwrap_or(0), t[j], &s.reason(j))
            })?;
            for j in (0..LANES).filter(|&j| inside[j]) {
                evaluations[j] += 3;
                while next_out[j] < te.len() && te[next_out[j]] < t_new[j] {
                    let at = te[next_out[j]];
                    dp.interpolate(j, &y, (at - t[j]) / h_try[j], &mut row);
                    to_raw(layout, &mut row);
                    check_finite_state(at, &row).map_err(|_| error(slot[j].unwrap_or(0), at, NON_FINITE))?;
                    recs[j].push(at, &row);
                    next_out[j] += 1;
                }
            }
        }
        dp.accept(&accepted);
        ctl.advance(&mut y, &y_new, &accepted, t_new);
        for j in (0..LANES).filter(|&j| accepted[j] && ctl.last[j]) {
            let Some(r) = slot[j].take() else { continue };
            raw_row(layout, &y, j, &mut row);
            while next_out[j] < te.len() {
                recs[j].push(te[next_out[j]], &row);
                next_out[j] += 1;
            }
            let stats = Stats { steps: ctl.steps[j], rejected: ctl.rejected[j], evaluations: evaluations[j], iterations: 0, energy_error: 0.0 };
            let rec = std::mem::take(&mut recs[j]);
            done[r] = Some(finish(chain, Form::Lagrangian, layout, &settings.drive, &initial[j], rec, Vec::new(), stats)?);
        }
    }
    Ok(done.into_iter().flatten().collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::chaos::ensemble::tests::{chains, rows};

    fn rk4(dt: f64, t_eval: Option<Vec<f64>>) -> Settings {
        Settings { method: Method::Rk4, dt: Some(dt), t_eval, ..Settings::default() }
    }

    /// The per-trajectory route: each row's own run.
    fn each(chain: &Chain, th: &[f64], om: &[f64], t_end: f64, settings: &Settings, drive: &Timed) -> Vec<Trajectory> {
        let n = chain.n();
        th.chunks(n).zip(om.chunks(n)).map(|(a, b)| super::super::simulate(chain, a, b, t_end, settings, drive.clone(), &mut |_| Ok(())).unwrap()).collect()
    }

    fn close(what: &str, got: &[f64], want: &[f64], tol: f64) {
        assert_eq!(got.len(), want.len(), "{what}");
        for (k, (x, y)) in got.iter().zip(want).enumerate() {
            assert!((x - y).abs() <= tol * (1.0 + y.abs()), "{what}[{k}]: {x} vs {y}");
        }
    }

    #[test]
    fn a_batch_in_lanes_gives_every_output_of_the_per_trajectory_route() {
        let undriven = Timed { builtin: Builtin::None, joint: false };
        let sinusoid = Timed { builtin: Builtin::sinusoid(2, vec![1.5, -0.7], vec![3.0, 5.5], vec![0.1, 0.0], vec![0.2, 0.0]).unwrap(), joint: false };
        let table = Timed {
            builtin: Builtin::table(3, vec![0.0, 0.3, 0.9], vec![0.0, 1.0, -2.0, 1.0, 0.5, 0.0, 2.0, -1.0, 0.3], crate::Interp::Cubic).unwrap(),
            joint: true,
        };
        let (t_end, dt) = (0.834, 0.01); // the last step is shortened
                                         // Output at every step, on the grid (snapped) and between grid points (interpolated,
                                         // some steps with several outputs, some with none).
        let outputs = [None, Some((0..=8).map(|k| 0.1 * k as f64).collect()), Some(vec![0.0, 0.013, 0.0171, 0.02, 0.3333, 0.5, 0.75, 0.8, t_end])];
        let chains = chains();
        for (c, chain) in chains.iter().enumerate() {
            let n = chain.n();
            let drive = match (c, n) {
                (0 | 3 | 5, 2) => &sinusoid,
                (1 | 6, 3) => &table,
                _ => &undriven,
            };
            let (th, om) = rows(n, 11);
            for t_eval in outputs.clone() {
                let mut settings = rk4(dt, t_eval);
                if chain.cart().is_some() {
                    settings.cart0 = [0.3, -0.2];
                }
                assert!(route(&settings, Some(drive)).unwrap().is_some() || std::env::var(super::super::bank::SWITCH).as_deref() == Ok("scalar"));
                let got = simulate(chain, &th, &om, t_end, &settings, drive, Path::best(), &Watch::new()).unwrap();
                let want = each(chain, &th, &om, t_end, &settings, drive);
                for (i, (g, w)) in got.iter().zip(&want).enumerate() {
                    let what = |f: &str| format!("chain {c}, row {i}, {f}");
                    assert_eq!(g.t, w.t, "{}", what("t"));
                    assert_eq!(
                        (g.stats.steps, g.stats.evaluations, g.stats.rejected),
                        (w.stats.steps, w.stats.evaluations, w.stats.rejected),
                        "{}",
                        what("stats")
                    );
                    // Round-off grown by the chaotic rows over 83 steps: a change of one ulp in row 1's
                    // initial angles moves the rods' final rates under the joint table by 1.9e-11
                    // (the routes differ by 1.2e-11 there, by under 1e-12 in most rows).
                    let tol = 1e-10;
                    close(&what("theta"), &g.theta, &w.theta, tol);
                    close(&what("omega"), &g.omega, &w.omega, tol);
                    close(&what("p"), &g.p, &w.p, tol);
                    close(&what("energy"), &g.energy, &w.energy, tol);
                    close(&what("work"), &g.work, &w.work, tol);
                    close(&what("dissipated"), &g.dissipated, &w.dissipated, tol);
                    close(&what("cart_x"), &g.cart_x, &w.cart_x, tol);
                    close(&what("cart_v"), &g.cart_v, &w.cart_v, tol);
                    close(&what("energy_error"), &g.energy_error, &w.energy_error, 1e-12);
                    assert_eq!((g.work_pivot.len(), g.work_cart.len(), g.pivot.len()), (0, 0, 0));
                }
                if matches!(drive.builtin, Builtin::None) {
                    continue;
                }
                // The drive did work, and the balance with it closes as the scalar route's.
                assert!(got.iter().all(|g| g.work.iter().any(|w| w.abs() > 1e-2)), "chain {c}");
            }
        }
    }

    #[test]
    fn a_batch_on_a_moving_pivot_in_lanes_gives_the_per_trajectory_routes_work_and_pivot() {
        use crate::dynamics::base::{Axis, Drive, Pivot};
        let shaken = Pivot {
            x: Axis::sinusoid("x", 0.05, 20.0, 0.3, 0.1).unwrap(),
            y: Axis::spline("y", vec![0.0, 0.2, 0.5, 1.0], vec![0.0, 0.03, -0.02, 0.01]).unwrap(),
        };
        let held = Pivot { x: Axis::Fixed(0.2), y: Axis::Fixed(-0.1) }; // fixed, off the origin
        let drive = Timed { builtin: Builtin::sinusoid(2, vec![1.5, -0.7], vec![3.0, 5.5], vec![0.1, 0.0], vec![0.2, 0.0]).unwrap(), joint: false };
        let chains = chains();
        for (c, pivot) in [(0, &shaken), (3, &shaken), (1, &held), (4, &shaken)] {
            let chain = &chains[c];
            let n = chain.n();
            let (th, om) = rows(n, 13);
            let torque = if n == 2 { drive.clone() } else { Timed { builtin: Builtin::None, joint: false } };
            let settings = Settings { drive: Drive { pivot: Some(pivot.clone()), force: None }, ..rk4(0.01, Some(vec![0.0, 0.0171, 0.3, 0.5, 0.834])) };
            assert!(route(&settings, Some(&torque)).unwrap().is_some() || std::env::var(super::super::bank::SWITCH).as_deref() == Ok("scalar"));
            let got = simulate(chain, &th, &om, 0.834, &settings, &torque, Path::best(), &Watch::new()).unwrap();
            let want = each(chain, &th, &om, 0.834, &settings, &torque);
            for (i, (g, w)) in got.iter().zip(&want).enumerate() {
                let what = |f: &str| format!("chain {c}, row {i}, {f}");
                assert_eq!(g.pivot, w.pivot, "{}", what("pivot"));
                assert_eq!(g.stats.evaluations, w.stats.evaluations);
                close(&what("theta"), &g.theta, &w.theta, 1e-11);
                close(&what("energy"), &g.energy, &w.energy, 1e-11);
                close(&what("work_pivot"), &g.work_pivot, &w.work_pivot, 1e-11);
                close(&what("energy_error"), &g.energy_error, &w.energy_error, 1e-12);
                if std::ptr::eq(pivot, &shaken) {
                    assert!(w.work_pivot.iter().any(|x| x.abs() > 1e-3), "{}: the pivot did work", what("work_pivot"));
                }
            }
        }
        // A pivot given as a function stays per trajectory.
        struct Still;
        impl crate::dynamics::base::AxisFn for Still {
            fn eval(&self, _t: f64) -> Result<[f64; 3]> {
                Ok([0.0; 3])
            }
        }
        let function = Pivot { x: Axis::Function(std::sync::Arc::new(Still)), y: Axis::Fixed(0.0) };
        let settings = Settings { drive: Drive { pivot: Some(function), force: None }, ..rk4(0.01, None) };
        assert!(route(&settings, Some(&drive)).unwrap().is_none());
    }

    #[test]
    fn a_dop853_batch_in_lanes_agrees_with_the_per_trajectory_route_to_its_tolerance() {
        use crate::dynamics::base::{Axis, Drive, Pivot};
        let shaken = Pivot { x: Axis::sinusoid("x", 0.05, 20.0, 0.3, 0.1).unwrap(), y: Axis::Fixed(0.0) };
        let sinusoid = Timed { builtin: Builtin::sinusoid(2, vec![1.5, -0.7], vec![3.0, 5.5], vec![0.1, 0.0], vec![0.2, 0.0]).unwrap(), joint: false };
        let none = Timed { builtin: Builtin::None, joint: false };
        let t_eval = vec![0.0, 0.013, 0.0171, 0.3333, 0.75, 0.834, 2.0];
        let chains = chains();
        // Ideal, general links, damped (a torque; a shaken pivot), rods on a damped cart.
        for (c, drive, pivot) in [(0, &sinusoid, None), (2, &none, None), (3, &sinusoid, Some(&shaken)), (6, &none, None)] {
            let chain = &chains[c];
            let n = chain.n();
            let (th, om) = rows(n, 70); // more rows than lanes: finished lanes take new rows
            let (th, om): (Vec<f64>, Vec<f64>) = (th.iter().map(|x| 0.4 * x).collect(), om.iter().map(|x| 0.2 * x).collect());
            let base = Drive { pivot: pivot.cloned(), force: None };
            let settings = Settings { t_eval: Some(t_eval.clone()), drive: base.clone(), ..Settings::default() };
            assert!(route(&settings, Some(drive)).unwrap().is_some() || std::env::var(super::super::bank::SWITCH).as_deref() == Ok("scalar"));
            let got = simulate(chain, &th, &om, 2.0, &settings, drive, Path::best(), &Watch::new()).unwrap();
            let want = each(chain, &th, &om, 2.0, &settings, drive);
            let exact = each(chain, &th, &om, 2.0, &Settings { rtol: 1e-13, atol: 1e-15, ..settings.clone() }, drive);
            for (i, ((g, w), e)) in got.iter().zip(&want).zip(&exact).enumerate() {
                let what = format!("chain {c}, row {i}");
                assert_eq!(g.t, w.t, "{what}");
                let off = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max);
                // As near the exact motion as the per-trajectory run (each takes its own steps).
                assert!(
                    off(&g.theta, &e.theta) <= 10.0 * off(&w.theta, &e.theta) + 1e-10,
                    "{what}: {} vs {}",
                    off(&g.theta, &e.theta),
                    off(&w.theta, &e.theta)
                );
                assert!(off(&g.energy_error, &w.energy_error) < 1e-9, "{what}");
                // The same steps give or take one (chain 3's regularised friction is stiff where
                // a joint stops: there the controller's choices follow round-off, a few more).
                let slack = if c == 3 { 1 + w.stats.steps / 20 } else { 1 };
                assert!(g.stats.steps.abs_diff(w.stats.steps) <= slack, "{what}: {} vs {} steps", g.stats.steps, w.stats.steps);
                if (g.stats.steps, g.stats.rejected) == (w.stats.steps, w.stats.rejected) {
                    assert_eq!(g.stats.evaluations, w.stats.evaluations, "{what}: evaluations counted as the driver counts them");
                }
            }
        }
    }

    #[test]
    fn every_path_gives_the_same_bits_and_a_row_its_own_whatever_its_neighbours() {
        let chains = chains();
        let drive = Timed { builtin: Builtin::Constant(vec![0.3, -0.2, 0.1]), joint: true };
        let chain = &chains[6]; // rods on a damped cart, with joint losses
        let (th, om) = rows(3, 29);
        let t_eval = Some(vec![0.05, 0.5, 1.0]);
        for settings in [rk4(0.01, t_eval.clone()), Settings { t_eval, ..Settings::default() }] {
            let reference = simulate(chain, &th, &om, 1.0, &settings, &drive, Path::Portable, &Watch::new()).unwrap();
            for path in Path::ALL.into_iter().filter(|p| p.available()) {
                assert_eq!(simulate(chain, &th, &om, 1.0, &settings, &drive, path, &Watch::new()).unwrap(), reference, "{path:?}");
            }
            let one = simulate(chain, &th[3 * 21..3 * 22], &om[3 * 21..3 * 22], 1.0, &settings, &drive, Path::best(), &Watch::new()).unwrap();
            assert_eq!(one[0], reference[21], "{:?}", settings.method);
        }
    }

    #[test]
    fn bad_rows_and_blow_ups_name_their_trajectory_as_the_per_trajectory_route() {
        let chain = &chains()[0];
        let none = Timed { builtin: Builtin::None, joint: false };
        let settings = rk4(0.01, None);
        let e = simulate(chain, &[0.1, 0.2, 0.3, f64::NAN], &[0.0; 4], 1.0, &settings, &none, Path::best(), &Watch::new()).unwrap_err();
        assert_eq!(e.to_string(), "trajectory 1: theta0[1] must be finite, got NaN");
        let th = [0.1; 20];
        let mut om = [0.0; 20];
        om[2 * 9] = 1e200; // row 9: the second group's second row
        let e = simulate(chain, &th, &om, 1.0, &settings, &none, Path::best(), &Watch::new()).unwrap_err();
        let want = super::super::simulate(chain, &th[18..], &om[18..], 1.0, &settings, none.clone(), &mut |_| Ok(())).unwrap_err();
        match (&e, &want) {
            (Error::Integration { t, reason }, Error::Integration { t: t0, reason: r0 }) => {
                assert_eq!((*t, reason.as_str()), (*t0, format!("trajectory 9: {r0}").as_str()));
                assert!(r0.contains(NON_FINITE));
            }
            _ => panic!("{e} / {want}"),
        }
        // A stopped watch stops the batch.
        let watch = Watch::new();
        watch.stop();
        assert!(matches!(simulate(chain, &[0.1; 4], &[0.0; 4], 1.0, &settings, &none, Path::best(), &watch), Err(Error::Interrupted { .. })));
    }
}
