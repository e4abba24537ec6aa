//! Ensembles in SIMD lanes: many chains (damping, friction, a cart, a built-in torque and a
//! pivot moved by sinusoids or tables included: the cart's state and the work of the torque, the
//! pivot and the losses ride along as more lanes, laid out as the per-trajectory run's raw state,
//! for the energy balance; the cart starts at rest at the origin, as a run's does by default),
//! eight to a group of lanes, keeping only what `mp.ensemble` reports: the final states and
//! momenta, the energy error at `t_end` (read off as a run's outputs are), each row's number of
//! steps, and the first time any link went over the top (the first upward crossing of
//! `max_i |theta_i| = pi`, the non-terminal `Flip` event of the per-trajectory route).
//!
//! - rk4 ([`Rk4Lanes`]) on the driver's grid (`t_k = k dt`, the last step shortened to land on
//!   `t_end`), the flip located on the step's cubic Hermite interpolant. A row agrees with the
//!   per-trajectory route (a batch `simulate` with that event) to round-off: the lanes' own
//!   `sin`/`cos` and fused product-sums.
//! - dop853 ([`Dop853Lanes`]), each lane with its own time and step as the run driver's
//!   controlled steps, a finished lane refilled with the next row; the flip located on the
//!   7th-order interpolant by the events' own root finder. A row agrees with the per-trajectory
//!   route to the tolerance: the error estimate cancels to round-off, so the steps drift apart.
//!
//! A row's bits depend neither on the other rows nor on the number of threads, and are the same
//! on the AVX-512, AVX2 and portable paths.
use std::f64::consts::PI;

use super::flip_time;
use crate::dynamics::base::Drive;
use crate::dynamics::system::NON_FINITE;
use crate::dynamics::system::{Form, Layout};
use crate::dynamics::torque::{Builtin, Timed};
use crate::error::{Error, Result};
use crate::integrators::dop853_lanes::{mask, Dop853Lanes, StartFailure};
use crate::integrators::lanes::{failed_at, ChainLanes, Rk4Lanes};
use crate::integrators::Method;
use crate::model::Chain;
use crate::par::*;
use crate::run::driver::fixed_steps;
use crate::run::energy::EnergyBalance;
use crate::run::events::{Condition, EventSpec, Tracker};
use crate::run::lanes::{lane_of, raw_row, LaneControl};
use crate::run::simulate::Books;
use crate::run::Settings;
use crate::trig::lanes::{copy_lanes, max_abs, on_path, Lane, Path, LANES};
use crate::watch::Watch;

/// Rows per parallel task.
const CHUNK: usize = 256;

/// What an ensemble keeps of each row (row-major `(B, N)` arrays).
#[derive(Debug, Clone, PartialEq)]
pub struct Ensemble {
    pub theta: Vec<f64>,
    pub omega: Vec<f64>,
    pub p: Vec<f64>,
    pub energy_error: Vec<f64>,
    /// Accepted steps of each row (rk4: the grid's, the same for all).
    pub steps: Vec<u64>,
    /// The first flip of each row (+inf: none by `t_end`).
    pub first_flip: Vec<f64>,
}

/// Whether an ensemble run with `method` goes through the lanes: rk4's or dop853's Lagrangian
/// form (the caller sends a torque or a pivot axis that is a Python function the
/// per-trajectory way), unless `MULTIPENDULUM_LANES` asks for the per-trajectory route. `None`:
/// the per-trajectory route.
pub fn route(method: Method) -> Result<Option<Path>> {
    if !matches!(method, Method::Rk4 | Method::Dop853) {
        return Ok(None);
    }
    crate::run::bank::requested()
}

/// The ensemble of the rows of `theta0`, `omega0` (flat, `(B, N)`) to `t_end` in lanes on `path`
/// (see [`route`]) with `settings`' method, `dt` (rk4's step; dop853's first step, or `None`
/// for its own guess), tolerances, `max_steps` and pivot (`drive.pivot`; no cart force), under
/// the torque `drive`; inputs are checked as a batch `simulate` checks them, with the same
/// messages. `watch` counts rows done and stops the work between
/// steps.
#[allow(clippy::too_many_arguments)]
pub fn ensemble(
    chain: &Chain,
    theta0: &[f64],
    omega0: &[f64],
    t_end: f64,
    settings: &Settings,
    drive: Option<&Timed>,
    path: Path,
    watch: &Watch,
) -> Result<Ensemble> {
    let n = chain.n();
    let drive = drive.filter(|d| !matches!(d.builtin, Builtin::None));
    if !matches!(settings.method, Method::Rk4 | Method::Dop853) || !settings.adaptive {
        return Err(Error::input(format!("an ensemble in lanes runs rk4 or adaptive dop853, not {}", settings.method.name())));
    }
    if settings.drive.force.is_some() || settings.drive.pivot.as_ref().is_some_and(|p| !p.in_lanes()) {
        return Err(Error::input("an ensemble in lanes takes no cart force and no pivot given as a function (the per-trajectory route does)"));
    }
    let settings = Settings { t_eval: Some(vec![t_end]), ..settings.clone() };
    let b = crate::run::simulate::batch_size(chain, theta0, omega0)?;
    settings.validate(t_end)?;
    crate::run::simulate::check_fixed_steps(&settings, t_end)?;
    for i in 0..b {
        let rows = (&theta0[n * i..n * (i + 1)], &omega0[n * i..n * (i + 1)]);
        chain.check_state("theta0", rows.0).and_then(|_| chain.check_state("omega0", rows.1)).map_err(|e| e.of_trajectory(i))?;
    }
    let parts: Vec<Ensemble> = theta0
        .par_chunks(n * CHUNK)
        .zip(omega0.par_chunks(n * CHUNK))
        .enumerate()
        .map(|(c, (th, om))| {
            watch.check(0.0)?;
            let out = run_chunk_on(path, chain, th, om, t_end, &settings, drive, c * CHUNK, watch)?;
            watch.add_units((th.len() / n) as u64);
            Ok(out)
        })
        .collect::<Result<_>>()?;
    let mut all = Ensemble { theta: Vec::new(), omega: Vec::new(), p: Vec::new(), energy_error: Vec::new(), steps: Vec::new(), first_flip: Vec::new() };
    for part in parts {
        all.theta.extend(part.theta);
        all.omega.extend(part.omega);
        all.p.extend(part.p);
        all.energy_error.extend(part.energy_error);
        all.steps.extend(part.steps);
        all.first_flip.extend(part.first_flip);
    }
    Ok(all)
}

on_path! {
    fn run_chunk_on(
        chain: &Chain,
        th: &[f64],
        om: &[f64],
        t_end: f64,
        settings: &Settings,
        drive: Option<&Timed>,
        first: usize,
        watch: &Watch,
    ) -> Result<Ensemble> {
        run_chunk(chain, th, om, t_end, settings, drive, first, watch)
    }
}

/// The rows of one chunk (`first`: the index of its first row in the batch, for messages).
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn run_chunk(chain: &Chain, th: &[f64], om: &[f64], t_end: f64, settings: &Settings, drive: Option<&Timed>, first: usize, watch: &Watch) -> Result<Ensemble> {
    let (n, rows) = (chain.n(), th.len() / chain.n());
    let mut out = Ensemble {
        theta: vec![0.0; rows * n],
        omega: vec![0.0; rows * n],
        p: vec![0.0; rows * n],
        energy_error: vec![0.0; rows],
        steps: vec![0; rows],
        first_flip: vec![f64::INFINITY; rows],
    };
    let none = Timed { builtin: Builtin::None, joint: false };
    let layout = crate::run::lanes::layout(chain, drive.unwrap_or(&none), &settings.drive)?;
    let mut rows = Rows { chain, drive, base: &settings.drive, layout, th, om, first, out: &mut out };
    match settings.method {
        Method::Dop853 => dop853_rows(&mut rows, t_end, settings, watch)?,
        _ => rk4_rows(&mut rows, t_end, settings.dt.unwrap_or(f64::NAN), watch)?,
    }
    Ok(out)
}

/// A chunk's rows and what the ensemble keeps of them.
struct Rows<'a> {
    chain: &'a Chain,
    drive: Option<&'a Timed>,
    /// The base's motion: a moving pivot's (none on a cart).
    base: &'a Drive,
    /// The per-trajectory run's raw state, which the lanes keep alike.
    layout: Layout,
    th: &'a [f64],
    om: &'a [f64],
    /// The index of the chunk's first row in the batch (for messages).
    first: usize,
    out: &'a mut Ensemble,
}

impl Rows<'_> {
    /// Row `r`'s initial state into lane `j` of `y` (the cart at rest at the origin, no work).
    #[inline(always)]
    fn load(&self, r: usize, y: &mut [Lane], j: usize) {
        let n = self.chain.n();
        for lane in y.iter_mut() {
            lane[j] = 0.0;
        }
        for a in 0..n {
            y[a][j] = self.th[n * r + a];
            y[n + a][j] = self.om[n * r + a];
        }
    }

    /// An integration error of row `r` (its index in the batch named).
    fn error(&self, r: usize, t: f64, reason: &str) -> Error {
        Error::integration(t, reason).of_trajectory(self.first + r)
    }

    /// Row `r`'s final state at `t_end` (lane `j` of `y`) and its reductions: the momenta and
    /// the energy error, read off the raw states as a run's outputs are ([`Books`]: the lab
    /// frame's energy, the work of the drive, the pivot and the losses).
    fn finish(&mut self, r: usize, y: &[Lane], j: usize, t_end: f64, steps: u64) -> Result<()> {
        let (chain, layout) = (self.chain, self.layout);
        let n = chain.n();
        let mut start = vec![0.0; layout.dim()];
        start[..n].copy_from_slice(&self.th[n * r..n * (r + 1)]);
        start[n..2 * n].copy_from_slice(&self.om[n * r..n * (r + 1)]);
        let mut end = vec![0.0; layout.dim()];
        raw_row(layout, y, j, &mut end);
        let mut books = Books::new(chain, Form::Lagrangian, layout);
        let first = books.terms(chain, self.base, 0.0, &start)?;
        let mut balance = EnergyBalance::from_energy(chain, first.kinetic, first.energy);
        let last = books.terms(chain, self.base, t_end, &end)?;
        let out = &mut *self.out;
        out.theta[n * r..n * (r + 1)].copy_from_slice(&end[..n]);
        out.omega[n * r..n * (r + 1)].copy_from_slice(&end[n..2 * n]);
        out.p[n * r..n * (r + 1)].copy_from_slice(&books.p);
        out.energy_error[r] = balance.observe(last.kinetic, last.energy, last.torque + last.pivot + last.cart - last.dissipated);
        out.steps[r] = steps;
        Ok(())
    }
}

/// rk4 on the driver's grid, a group of eight rows at a time.
#[inline(always)]
fn rk4_rows(rows: &mut Rows, t_end: f64, dt: f64, watch: &Watch) -> Result<()> {
    let chain = rows.chain;
    let n = chain.n();
    let count_all = rows.th.len() / n;
    let lanes = |k| vec![[0.0; LANES]; k];
    // The per-trajectory run's raw state: on a cart, its x and v (from rest at the origin)
    // after the angles and rates; then the work of the drive, of a moving pivot and of the
    // losses (-D), for the energy balance.
    let m = rows.layout.dim();
    let pivot = rows.base.moving_pivot();
    let (mut y, mut y0, tau, mut q) = (lanes(m), lanes(m), lanes(n), lanes(n));
    let mut rk = Rk4Lanes::with_dim(n, m);
    let steps = fixed_steps(t_end, dt);
    for g in 0..count_all.div_ceil(LANES) {
        let (lo, count) = (g * LANES, LANES.min(count_all - g * LANES));
        let mut active = [0.0; LANES];
        // Unused lanes stay at rest (finite) and inactive.
        for m in y.iter_mut() {
            *m = [0.0; LANES];
        }
        for j in 0..count {
            rows.load(lo + j, &mut y, j);
            active[j] = 1.0;
        }
        // Whether the lane's max |theta| was below pi at the start of the step (the event's
        // sign), and whether its first flip is found.
        let mut below = under_pi(&max_abs(&y, 0..n));
        let mut found = 0u32;
        for k in 0..steps {
            // Every step: a relaxed load against eight lanes' step of N links (long chains take
            // seconds per group, and Ctrl-C must be heard within a fraction of one).
            watch.check(k as f64 * dt)?;
            let t = k as f64 * dt;
            let h = if k + 1 == steps { t_end - t } else { dt };
            copy_lanes(&mut y0, &y);
            let mut sys = ChainLanes { chain, tau: &tau, drive: rows.drive, force: &[0.0; LANES], pivot, pivot_work: pivot.is_some(), q: &mut q };
            let stepped = rk.step_system(&mut y, t, h, &active, &mut sys);
            let nonfinite = stepped.map_err(|(stage, bad)| {
                let j = (0..LANES).find(|&j| bad.lanes[j]).unwrap_or(0);
                rows.error(lo + j, failed_at(&bad, j, stage, t, h), &bad.reason(j))
            })?;
            if let Some(j) = (0..count).find(|&j| nonfinite[j]) {
                return Err(rows.error(lo + j, t + h, NON_FINITE));
            }
            // Each lane's largest |theta|, and a lane by lane look only when one of them has gone
            // over the top for the first time (bit masks: arrays of bool cost byte conversions).
            let now = under_pi(&max_abs(&y, 0..n));
            let news = below & !now & !found;
            if news != 0 {
                for j in (0..count).filter(|&j| news >> j & 1 == 1) {
                    // The earliest crossing among the links that went over in this step.
                    let at = (0..n)
                        .filter(|&a| y[a][j].abs() >= PI)
                        .map(|a| flip_time(t, h, (y0[a][j], y0[n + a][j]), (y[a][j], y[n + a][j])))
                        .fold(f64::INFINITY, f64::min);
                    rows.out.first_flip[lo + j] = at;
                }
                found |= news;
            }
            below = now;
        }
        for j in 0..count {
            rows.finish(lo + j, &y, j, t_end, steps)?;
        }
    }
    Ok(())
}

/// The lanes whose `top` is under pi, as bits (lane `i`, bit `i`).
#[inline(always)]
fn under_pi(top: &Lane) -> u32 {
    let mut bits = 0u32;
    for (i, v) in top.iter().enumerate() {
        bits |= u32::from(*v < PI) << i;
    }
    bits
}

/// dop853 with a step per lane, as the run driver's controlled steps (the same first step,
/// controller, `max_steps` and landing on `t_end`); a lane whose row is done takes the chunk's
/// next row. The first flip is the per-trajectory route's `Flip` event, located on the step's
/// 7th-order interpolant by the same root finder ([`Tracker`]).
#[inline(always)]
fn dop853_rows(rows: &mut Rows, t_end: f64, settings: &Settings, watch: &Watch) -> Result<()> {
    let chain = rows.chain;
    let n = chain.n();
    let count = rows.th.len() / n;
    let lanes = |k| vec![[0.0; LANES]; k];
    // The per-trajectory run's state: the cart's x and v after the angles and rates, then the
    // work of the drive, of a moving pivot and of the losses (-D here, D there; the error norm
    // sees only its size), all controlled.
    let m = rows.layout.dim();
    let pivot = rows.base.moving_pivot();
    let mut dp = Dop853Lanes::new(n, m, m, settings.rtol, settings.atol);
    let (mut y, mut y_new, tau, mut q) = (lanes(m), lanes(m), lanes(n), lanes(n));
    let zero = [0.0; LANES];
    let specs = [EventSpec { condition: Condition::Flip(None), direction: 1, terminal: false }];
    let tracker = || Tracker::new(&specs, chain, Form::Lagrangian);
    let mut trackers: Vec<Tracker> = (0..LANES).map(|_| tracker()).collect();
    // Per lane: its row, time, next step, and the driver's counters.
    let mut slot: [Option<usize>; LANES] = [None; LANES];
    let mut ctl = LaneControl::default();
    let mut found = [false; LANES];
    let mut next = 0;
    let mut state = vec![0.0; m];
    loop {
        let mut fresh = [false; LANES];
        for j in 0..LANES {
            if slot[j].is_none() && next < count {
                rows.load(next, &mut y, j);
                (slot[j], fresh[j], next) = (Some(next), true, next + 1);
                ctl.restart(j, 0.0);
                found[j] = false;
                trackers[j] = tracker();
                lane_of(&y, j, &mut state);
                trackers[j].start(0.0, &state)?;
            }
        }
        let mut sys = ChainLanes { chain, tau: &tau, drive: rows.drive, force: &zero, pivot, pivot_work: pivot.is_some(), q: &mut q };
        if fresh.iter().any(|&f| f) {
            let first = dp.start(&mut sys, &ctl.t, &y, &fresh, &[t_end; LANES], settings.dt).map_err(|(j, why)| {
                let r = slot[j].unwrap_or(0);
                match why {
                    StartFailure::Singular(link) => rows.error(r, 0.0, &link.reason()),
                    StartFailure::NonFinite => rows.error(r, 0.0, NON_FINITE),
                }
            })?;
            for j in (0..LANES).filter(|&j| fresh[j]) {
                ctl.h[j] = first[j];
            }
        }
        let running = slot.map(|s| s.is_some());
        if !running.iter().any(|&r| r) {
            return Ok(());
        }
        // Every step: a relaxed load against eight lanes' step.
        watch.check(ctl.earliest(&running))?;
        for j in (0..LANES).filter(|&j| running[j]) {
            ctl.propose(j, t_end, settings.max_steps).map_err(|why| rows.error(slot[j].unwrap_or(0), ctl.t[j], &why))?;
        }
        let (t, h_try) = (ctl.t, ctl.h_try);
        let err = dp.trial(&mut sys, &t, &y, &h_try, &mut y_new, &mask(&running));
        let (accepted, t_new) = ctl.decide(&err, &running, &y_new, t_end).map_err(|j| rows.error(slot[j].unwrap_or(0), t[j] + h_try[j], NON_FINITE))?;
        // The rows' first flips: a crossing in the step is located on its interpolant.
        let mut crossed = [false; LANES];
        for j in (0..LANES).filter(|&j| accepted[j] && !found[j]) {
            lane_of(&y_new, j, &mut state);
            crossed[j] = trackers[j].detect(t_new[j], &state)?;
            if !crossed[j] {
                trackers[j].accept();
            }
        }
        if crossed.iter().any(|&c| c) {
            dp.dense(&mut sys, &t, &y, &y_new, &h_try, &crossed).map_err(|s| {
                let j = (0..LANES).find(|&j| s.lanes[j]).unwrap_or(0);
                rows.error(slot[j].unwrap_or(0), t[j], &s.reason(j))
            })?;
            for j in (0..LANES).filter(|&j| crossed[j]) {
                trackers[j].locate(
                    t[j],
                    h_try[j],
                    |x, out| {
                        dp.interpolate(j, &y, x, out);
                        Ok(())
                    },
                    m,
                )?;
                let r = slot[j].unwrap_or(0);
                rows.out.first_flip[r] = trackers[j].hits.first().map_or(f64::INFINITY, |hit| hit.t);
                found[j] = true;
            }
        }
        dp.accept(&accepted);
        ctl.advance(&mut y, &y_new, &accepted, t_new);
        for j in (0..LANES).filter(|&j| accepted[j] && ctl.last[j]) {
            if let Some(r) = slot[j].take() {
                rows.finish(r, &y, j, t_end, ctl.steps[j])?;
            }
        }
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::dynamics::torque::Builtin;
    use crate::run::events::{Condition, EventSpec};
    use crate::run::simulate_batch;

    /// Chains of every kind the lanes take: point masses, rods, general links, joint losses and
    /// carts (also the batch runs' in lanes, `run::lanes`).
    pub(crate) fn chains() -> Vec<Chain> {
        vec![
            Chain::new(&[1.0, 1.0], &[1.0, 1.0], None, None, 9.81).unwrap(),
            Chain::rods(&[1.0, 0.5, 0.8], &[1.0, 0.3, 2.0], 9.81).unwrap(),
            Chain::new(&[0.4; 5], &[1.0, 0.5, 2.0, 1.0, 0.1], Some(&[0.2; 5]), Some(&[0.01; 5]), 3.7).unwrap(),
            Chain::new(&[1.0, 1.0], &[1.0, 1.0], None, None, 9.81).unwrap().with_losses(&[0.1, 0.3], &[0.2, 0.0], 0.05).unwrap(),
            Chain::rods(&[1.0, 0.5, 0.8], &[1.0, 0.3, 2.0], 9.81).unwrap().with_losses(&[0.0, 0.2, 0.1], &[0.1, 0.1, 0.0], 1e-3).unwrap(),
            // On carts: free (its horizontal momentum kept), and damped with joint losses.
            Chain::new(&[1.0, 1.0], &[1.0, 1.0], None, None, 9.81).unwrap().with_cart(Some(crate::model::Cart::new(2.0, 0.0).unwrap())).unwrap(),
            Chain::rods(&[1.0, 0.5, 0.8], &[1.0, 0.3, 2.0], 9.81)
                .unwrap()
                .with_losses(&[0.05; 3], &[0.0; 3], 1e-3)
                .unwrap()
                .with_cart(Some(crate::model::Cart::new(1.0, 0.3).unwrap()))
                .unwrap(),
        ]
    }

    fn rk4(dt: f64) -> Settings {
        Settings { method: Method::Rk4, dt: Some(dt), ..Settings::default() }
    }

    pub(crate) fn rows(n: usize, b: usize) -> (Vec<f64>, Vec<f64>) {
        let th = (0..n * b).map(|k| (k as f64 * 0.77).sin() * 2.6).collect();
        let om = (0..n * b).map(|k| (k as f64 * 1.31).cos() * 5.0).collect();
        (th, om)
    }

    #[test]
    fn lanes_agree_with_the_per_trajectory_batch_and_its_flip_event() {
        for chain in chains() {
            let n = chain.n();
            let (th, om) = rows(n, 37);
            let (t_end, dt) = (0.834, 0.01); // the last step is shortened
            let got = ensemble(&chain, &th, &om, t_end, &rk4(dt), None, Path::best(), &Watch::new()).unwrap();
            let settings = Settings {
                method: Method::Rk4,
                dt: Some(dt),
                t_eval: Some(vec![t_end]),
                events: vec![EventSpec { condition: Condition::Flip(None), direction: 1, terminal: false }],
                ..Settings::default()
            };
            let want = simulate_batch(&chain, &th, &om, t_end, &settings, &Builtin::None, &Watch::new()).unwrap();
            assert_eq!(got.steps, vec![84; 37]);
            let mut flips = 0;
            for (i, tr) in want.iter().enumerate() {
                assert_eq!(tr.t, vec![t_end]);
                // Round-off only (the lanes' sin/cos, fused operations), grown a little by chaos
                // (these rows whirl: over 1.2 s it reaches 1e-11).
                let close = |a: f64, b: f64| (a - b).abs() <= 1e-12 * (1.0 + b.abs());
                for a in 0..n {
                    assert!(close(got.theta[n * i + a], tr.theta[a]), "row {i}: {} vs {}", got.theta[n * i + a], tr.theta[a]);
                    assert!(close(got.omega[n * i + a], tr.omega[a]), "row {i}: {} vs {}", got.omega[n * i + a], tr.omega[a]);
                    assert!(close(got.p[n * i + a], tr.p[a]), "row {i}");
                }
                assert_eq!(tr.stats.steps, got.steps[i]);
                let first = tr.events.first().map_or(f64::INFINITY, |h| h.1);
                assert_eq!(first.is_finite(), got.first_flip[i].is_finite(), "row {i}");
                if first.is_finite() {
                    flips += 1;
                    assert!((first - got.first_flip[i]).abs() < 1e-12, "row {i}: {first} vs {}", got.first_flip[i]);
                }
                assert!((got.energy_error[i] - tr.stats.energy_error).abs() < 1e-12, "row {i}");
            }
            assert!(flips > 3, "{flips}");
        }
    }

    #[test]
    fn every_path_gives_the_same_bits_and_a_row_its_own_whatever_its_neighbours() {
        let chain = &chains()[1];
        let (th, om) = rows(3, 300);
        let reference = ensemble(chain, &th, &om, 3.0, &rk4(0.01), None, Path::Portable, &Watch::new()).unwrap();
        for path in Path::ALL.into_iter().filter(|p| p.available()) {
            assert_eq!(ensemble(chain, &th, &om, 3.0, &rk4(0.01), None, path, &Watch::new()).unwrap(), reference, "{path:?}");
        }
        let one = ensemble(chain, &th[3 * 261..3 * 262], &om[3 * 261..3 * 262], 3.0, &rk4(0.01), None, Path::best(), &Watch::new()).unwrap();
        assert_eq!(one.theta, reference.theta[3 * 261..3 * 262].to_vec());
        assert_eq!(one.first_flip[0].to_bits(), reference.first_flip[261].to_bits());
    }

    #[test]
    fn bad_rows_and_blow_ups_name_their_trajectory() {
        let chain = &chains()[0];
        let e = ensemble(chain, &[0.1, 0.2, 0.3, f64::NAN], &[0.0; 4], 1.0, &rk4(0.01), None, Path::best(), &Watch::new()).unwrap_err();
        assert_eq!(e.to_string(), "trajectory 1: theta0[1] must be finite, got NaN");
        let e = ensemble(chain, &[0.1; 4], &[0.0, 0.0, 1e200, 0.0], 1.0, &rk4(0.01), None, Path::best(), &Watch::new()).unwrap_err();
        // A blow-up is named as the per-trajectory route names it (not a singular mass matrix).
        assert!(matches!(e, Error::Integration { .. }) && e.to_string().contains(&format!("trajectory 1: {NON_FINITE}")), "{e}");
        let scalar = crate::run::simulate_batch(chain, &[0.1; 4], &[0.0, 0.0, 1e200, 0.0], 1.0, &rk4(0.01), &Builtin::None, &Watch::new()).unwrap_err();
        assert!(scalar.to_string().contains(NON_FINITE), "{scalar}");
        let dop = Settings { t_eval: Some(vec![1.0]), ..Settings::default() };
        let e = ensemble(chain, &[0.1; 4], &[0.0, 0.0, 1e200, 0.0], 1.0, &dop, None, Path::best(), &Watch::new()).unwrap_err();
        assert!(e.to_string().contains(NON_FINITE) || e.to_string().contains("underflowed"), "{e}");
        let e = ensemble(chain, &[0.1; 4], &[0.0; 4], 1.0, &rk4(-0.01), None, Path::best(), &Watch::new()).unwrap_err();
        assert_eq!(e.to_string(), "dt must be > 0 and finite, got -0.01");
    }

    #[test]
    fn the_first_failing_row_is_named_though_a_later_one_fails_sooner() {
        // Row 0 (the first group) whirls until it blows up some steps in; row 9 (the second
        // group, stepped beside the first) at once. Row by row, row 0 fails first.
        let chain = &chains()[0];
        let mut om = vec![0.0; 2 * 16];
        (om[1], om[2 * 9]) = (1e3, 1e200);
        let ens = |th: &[f64], om: &[f64]| ensemble(chain, th, om, 1.0, &rk4(0.01), None, Path::best(), &Watch::new()).unwrap_err();
        let (both, first, ninth) = (ens(&[0.1; 32], &om), ens(&[0.1; 2], &om[..2]), ens(&[0.1; 2], &om[18..20]));
        let time = |e: &Error| match e {
            Error::Integration { t, .. } => *t,
            other => panic!("{other}"),
        };
        assert!(time(&ninth) < time(&first), "{ninth} / {first}");
        assert!(first.to_string().contains("trajectory 0: "), "{first}");
        assert_eq!(both.to_string(), first.to_string());
        // Row 9 alone in its pair is still found.
        let mut om = vec![0.0; 2 * 16];
        om[2 * 9] = 1e200;
        assert_eq!(ens(&[0.1; 32], &om).to_string(), ninth.to_string().replace("trajectory 0", "trajectory 9"));
    }

    /// The per-trajectory route of dop853: a batch `simulate` with the ensemble's output and
    /// its flip event.
    fn per_trajectory(chain: &Chain, th: &[f64], om: &[f64], t_end: f64, settings: &Settings) -> Vec<crate::run::Trajectory> {
        let settings = Settings {
            t_eval: Some(vec![t_end]),
            events: vec![EventSpec { condition: Condition::Flip(None), direction: 1, terminal: false }],
            ..settings.clone()
        };
        simulate_batch(chain, th, om, t_end, &settings, &Builtin::None, &Watch::new()).unwrap()
    }

    #[test]
    fn dop853_lanes_take_the_per_trajectory_steps_and_agree_with_it() {
        let settings = Settings::default();
        assert_eq!(settings.method, Method::Dop853);
        let tight = Settings { rtol: 1e-13, atol: 1e-15, ..Settings::default() };
        for (c, chain) in chains().into_iter().enumerate() {
            // Chain 4's friction is regularised over 1e-3 rad/s: stiff where a joint stops,
            // where the controller's choices are sensitive to round-off.
            let stiff = c == 4;
            let n = chain.n();
            let (th, om) = rows(n, 29);
            let t_end = 0.834;
            let got = ensemble(&chain, &th, &om, t_end, &settings, None, Path::best(), &Watch::new()).unwrap();
            let want = per_trajectory(&chain, &th, &om, t_end, &settings);
            let exact = per_trajectory(&chain, &th, &om, t_end, &tight);
            let (mut flips, mut steps, mut log_ratio) = (0, (0, 0), 0.0);
            for (i, (tr, ex)) in want.iter().zip(&exact).enumerate() {
                // As accurate as the run alone, against a run 1000 times tighter: each row to
                // the tolerance's scale, and as accurate on (geometric) average.
                let off = |row: &[f64], o: usize| (0..n).map(|a| (row[o + a] - ex.theta[a]).abs()).fold(0.0, f64::max);
                let (lanes_off, alone_off) = (off(&got.theta, n * i), off(&tr.theta, 0));
                assert!(lanes_off < 1e-7, "row {i} of chain {c}: {lanes_off:e} vs {alone_off:e}");
                log_ratio += (lanes_off.max(1e-15) / alone_off.max(1e-15)).ln() / want.len() as f64;
                // Each lane takes its own steps as the run alone does, but their sizes are not
                // the same bits: the error estimate is a sum of stages that cancel to round-off
                // (its relative round-off reaches 1e-6), so the two routes' steps drift apart by
                // round-off amplified, and may land on t_end with a step more or less. They
                // agree to the tolerance's scale, not to round-off.
                steps.0 += got.steps[i];
                steps.1 += tr.stats.steps;
                let first = tr.events.first().map_or(f64::INFINITY, |h| h.1);
                assert_eq!(first.is_finite(), got.first_flip[i].is_finite(), "row {i}");
                flips += usize::from(first.is_finite());
                assert!(got.energy_error[i] < 1e-8, "row {i}: {}", got.energy_error[i]);
                if stiff {
                    continue;
                }
                assert!(got.steps[i].abs_diff(tr.stats.steps) <= 1, "row {i} of chain {c}: {} vs {}", got.steps[i], tr.stats.steps);
                let close = |a: f64, b: f64| (a - b).abs() <= 1e-9 * (1.0 + b.abs());
                for a in 0..n {
                    assert!(close(got.theta[n * i + a], tr.theta[a]), "row {i}: {} vs {}", got.theta[n * i + a], tr.theta[a]);
                    assert!(close(got.omega[n * i + a], tr.omega[a]), "row {i}: {} vs {}", got.omega[n * i + a], tr.omega[a]);
                    assert!(close(got.p[n * i + a], tr.p[a]), "row {i}");
                }
                if first.is_finite() {
                    assert!((first - got.first_flip[i]).abs() < 1e-9, "row {i}: {first} vs {}", got.first_flip[i]);
                }
                assert!((got.energy_error[i] - tr.stats.energy_error).abs() < 1e-10, "row {i}");
            }
            assert!(flips > 3, "{flips}");
            assert!(log_ratio.exp() < 2.0, "chain {c}: lanes' errors {} times the run's", log_ratio.exp());
            let slack = if stiff { steps.1 / 20 } else { 3 };
            assert!(steps.0.abs_diff(steps.1) <= slack, "chain {c}: {steps:?}");
        }
    }

    #[test]
    fn dop853_lanes_give_every_path_and_neighbourhood_the_same_bits_and_honour_dt_and_max_steps() {
        let chain = &chains()[4];
        let (th, om) = rows(3, 301);
        let settings = Settings { rtol: 1e-8, atol: 1e-10, ..Settings::default() };
        let reference = ensemble(chain, &th, &om, 2.0, &settings, None, Path::Portable, &Watch::new()).unwrap();
        assert!(reference.steps.iter().min() < reference.steps.iter().max(), "rows take their own steps");
        for path in Path::ALL.into_iter().filter(|p| p.available()) {
            assert_eq!(ensemble(chain, &th, &om, 2.0, &settings, None, path, &Watch::new()).unwrap(), reference, "{path:?}");
        }
        // Alone, a row meets another lane's history (and is no longer refilled mid-group).
        let one = ensemble(chain, &th[3 * 261..3 * 262], &om[3 * 261..3 * 262], 2.0, &settings, None, Path::best(), &Watch::new()).unwrap();
        assert_eq!(one.theta, reference.theta[3 * 261..3 * 262].to_vec());
        assert_eq!(one.steps[0], reference.steps[261]);
        // A first step of dt, and max_steps, as the per-trajectory run takes them.
        let short = Settings { dt: Some(1e-4), max_steps: 40, ..settings.clone() };
        let e = ensemble(chain, &th[..9], &om[..9], 2.0, &short, None, Path::best(), &Watch::new()).unwrap_err();
        let Error::Integration { t, reason } = &e else { panic!("{e}") };
        let (row, rest) = reason.strip_prefix("trajectory ").and_then(|r| r.split_once(": ")).unwrap();
        assert_eq!(rest, "reached max_steps = 40 before t_end");
        let row: usize = row.parse().unwrap();
        let alone = Settings { t_eval: Some(vec![2.0]), ..short.clone() };
        let Error::Integration { t: at, .. } =
            crate::run::simulate(chain, &th[3 * row..3 * row + 3], &om[3 * row..3 * row + 3], 2.0, &alone, Builtin::None, &mut |_| Ok(())).unwrap_err()
        else {
            panic!()
        };
        assert!((t - at).abs() < 1e-6, "{t} vs {at}");
        // (On a chain without the friction's stiffness, where the routes' steps agree.)
        let (chain, small) = (&chains()[1], Settings { dt: Some(1e-4), ..settings.clone() });
        let got = ensemble(chain, &th[..9], &om[..9], 0.5, &small, None, Path::best(), &Watch::new()).unwrap();
        let want = per_trajectory(chain, &th[..9], &om[..9], 0.5, &small);
        for (i, tr) in want.iter().enumerate() {
            assert!(got.steps[i].abs_diff(tr.stats.steps) <= 1, "row {i}");
            assert!((got.theta[3 * i] - tr.theta[0]).abs() < 1e-9, "row {i}");
        }
    }

    /// The lanes' rows against the per-trajectory route's runs: angles and momenta to `tol`
    /// (relative to 1 + the value), the same flip decisions, energy errors to 1e-10.
    fn agree(got: &Ensemble, want: &[crate::run::Trajectory], tol: f64, what: &str) {
        for (i, tr) in want.iter().enumerate() {
            let n = tr.n;
            for (name, x, y) in [("theta", &got.theta, &tr.theta), ("p", &got.p, &tr.p)] {
                for a in 0..n {
                    let (x, y) = (x[n * i + a], y[a]);
                    assert!((x - y).abs() <= tol * (1.0 + y.abs()), "{what}, row {i}: {name} {x} vs {y}");
                }
            }
            let first = tr.events.first().map_or(f64::INFINITY, |h| h.1);
            assert_eq!(first.is_finite(), got.first_flip[i].is_finite(), "{what}, row {i}");
            assert!((got.energy_error[i] - tr.stats.energy_error).abs() < 1e-10, "{what}, row {i}: {} vs {}", got.energy_error[i], tr.stats.energy_error);
        }
    }

    #[test]
    fn lanes_on_a_moving_pivot_agree_with_the_per_trajectory_route_and_close_the_energy_balance() {
        use crate::dynamics::base::{Axis, Pivot};
        let shaken = Pivot {
            x: Axis::sinusoid("x", 0.05, 20.0, 0.3, 0.1).unwrap(),
            y: Axis::spline("y", vec![0.0, 0.2, 0.5, 1.0], vec![0.0, 0.03, -0.02, 0.01]).unwrap(),
        };
        let chains = chains();
        // Ideal, damped with friction, general links.
        for c in [0, 3, 2] {
            let chain = &chains[c];
            let n = chain.n();
            let (th, om) = rows(n, 21);
            let t_end = 0.834;
            for method in [rk4(0.01), Settings::default()] {
                let settings = Settings { drive: Drive { pivot: Some(shaken.clone()), force: None }, ..method };
                let got = ensemble(chain, &th, &om, t_end, &settings, None, Path::best(), &Watch::new()).unwrap();
                let full = Settings {
                    t_eval: Some(vec![t_end]),
                    events: vec![EventSpec { condition: Condition::Flip(None), direction: 1, terminal: false }],
                    ..settings.clone()
                };
                let want = simulate_batch(chain, &th, &om, t_end, &full, &Builtin::None, &Watch::new()).unwrap();
                // rk4: round-off; dop853: its tolerance, each route with its own steps (the
                // shaken five links' fast motion grows their difference to a few 1e-8).
                let tol = if settings.method == Method::Rk4 { 1e-11 } else { 1e-7 };
                // The balance with the pivot's work (which is joules) closes as the
                // per-trajectory route's.
                agree(&got, &want, tol, &format!("chain {c}, {:?}", settings.method));
                for (i, tr) in want.iter().enumerate() {
                    assert!(tr.work_pivot[0].abs() > 1e-3, "chain {c}, row {i}: the pivot did work {}", tr.work_pivot[0]);
                }
            }
        }
    }

    #[test]
    fn driven_lanes_agree_with_the_per_trajectory_route_and_close_the_energy_balance() {
        let chains = chains();
        let drives = [
            Timed { builtin: Builtin::sinusoid(2, vec![1.5, -0.7], vec![3.0, 5.5], vec![0.1, 0.0], vec![0.2, 0.0]).unwrap(), joint: false },
            Timed {
                builtin: Builtin::table(3, vec![0.0, 0.3, 0.9], vec![0.0, 1.0, -2.0, 1.0, 0.5, 0.0, 2.0, -1.0, 0.3], crate::Interp::Cubic).unwrap(),
                joint: true,
            },
        ];
        // The double pendulum ideal, damped and on a free cart; the rods ideal and damped on a
        // damped cart.
        for (c, drive) in [(0, &drives[0]), (3, &drives[0]), (5, &drives[0]), (1, &drives[1]), (6, &drives[1])] {
            let chain = &chains[c];
            let n = chain.n();
            let (th, om) = rows(n, 21);
            let t_end = 0.834;
            for settings in [rk4(0.01), Settings::default()] {
                let got = ensemble(chain, &th, &om, t_end, &settings, Some(drive), Path::best(), &Watch::new()).unwrap();
                let full = Settings {
                    t_eval: Some(vec![t_end]),
                    events: vec![EventSpec { condition: Condition::Flip(None), direction: 1, terminal: false }],
                    ..settings.clone()
                };
                let want = simulate_batch(chain, &th, &om, t_end, &full, drive, &Watch::new()).unwrap();
                // rk4: round-off grown by chaos (the drive pumps energy in: these rows whirl
                // faster than the undriven ones); dop853: its tolerance (see the undriven test).
                let tol = if settings.method == Method::Rk4 { 1e-11 } else { 1e-8 };
                agree(&got, &want, tol, &format!("chain {c}, {:?}", settings.method));
                for (i, tr) in want.iter().enumerate() {
                    // The balance with the drive's work closes (the drive does joules of work):
                    // to dop853's tolerance.
                    if settings.method == Method::Dop853 {
                        assert!(got.energy_error[i] < 1e-8, "chain {c}, row {i}: {}", got.energy_error[i]);
                    }
                    assert!(tr.work[0].abs() > 1e-2, "chain {c}, row {i}: the drive did work {}", tr.work[0]);
                }
            }
        }
    }
}
