//! Chaos indicators of many states in SIMD lanes: undriven chains on a fixed pivot (damping and
//! friction included; no torque, no cart), eight states to a group, each carrying its tangent vectors through rk4 on
//! [`crate::dynamics::lanes`]' accelerations and their tangent ([`Rk4Lanes::step_system`]). The
//! same run as [`super::indicators`]' per-state one (the grid `t_k = k dt`, MEGNO's two integrals
//! integrated with the orbit, the vectors renormalised after every step), so a value agrees with
//! it to round-off (the lanes' `sin`/`cos` and fused product-sums), grown by the orbit's own
//! instability over long chaotic runs. A state's bits depend neither on the other states, nor on
//! the number of threads, nor on the path (AVX-512, AVX2, portable).
//!
//! A group in which any state fails (a singular mass matrix, a non-finite value, a collapsed
//! vector) is run again state by state on the per-state route, which gives its values or the
//! error that route reports.
use super::indicators::{orthonormalise, run, Indicator};
use crate::dynamics::base::Pivot;
use crate::dynamics::lanes::LaneSingular;
use crate::dynamics::lanes::{accelerations, add_loss_tangent, add_losses, add_pivot_forces, add_pivot_tangent, tangent, LaneScratch};
use crate::dynamics::torque::{Builtin, Timed};
use crate::error::Result;
use crate::integrators::lanes::{LaneSystem, Rk4Lanes};
use crate::model::Chain;
use crate::par::*;
use crate::trig::lanes::{copy_lanes, each, on_path, Lane, Path, LANES};
use crate::watch::Watch;

/// Rows per parallel task: eight groups.
const CHUNK: usize = 8 * LANES;

/// Whether a batch of indicators goes through the lanes: a chain without a cart (damping,
/// friction, built-in torques and a moving pivot the lanes can evaluate included), unless
/// `MULTIPENDULUM_LANES` asks for the per-state route. `None`: the per-state route.
pub fn route(chain: &Chain, pivot: Option<&Pivot>) -> Result<Option<Path>> {
    if chain.cart().is_some() || pivot.is_some_and(|p| !p.in_lanes()) {
        return Ok(None);
    }
    crate::run::bank::requested()
}

/// The indicator after `steps` steps of `dt` of every row of `theta0`, `omega0` (flat, `(B, N)`,
/// checked by the caller), from the unit deviation vectors `start` (`k x 2N`); `deviations` as
/// the caller was given them (for the per-state reruns). `watch` counts rows done.
#[allow(clippy::too_many_arguments)]
pub fn indicators(
    chain: &Chain,
    theta0: &[f64],
    omega0: &[f64],
    steps: u64,
    dt: f64,
    which: Indicator,
    driven: (&Builtin, Option<&Pivot>),
    start: &[f64],
    deviations: Option<&[f64]>,
    path: Path,
    watch: &Watch,
) -> Result<Vec<f64>> {
    let n = chain.n();
    let job = Job::new(chain, driven, steps, dt, which, start, deviations, watch);
    let parts: Vec<Vec<f64>> = theta0
        .par_chunks(n * CHUNK)
        .zip(omega0.par_chunks(n * CHUNK))
        .map(|(th, om)| {
            watch.check(0.0)?;
            chunk_on(path, &job, th, om)
        })
        .collect::<Result<_>>()?;
    Ok(parts.concat())
}

/// One state's indicator with `observe(step, value)` after every step (its history), as
/// [`super::indicators::indicator`] keeps it: the state is a batch's row, bit for bit. `None` if
/// the lanes could not finish it (the caller runs it on the per-state route).
#[allow(clippy::too_many_arguments)]
pub fn indicator(
    chain: &Chain,
    theta0: &[f64],
    omega0: &[f64],
    steps: u64,
    dt: f64,
    which: Indicator,
    driven: (&Builtin, Option<&Pivot>),
    start: &[f64],
    path: Path,
    watch: &Watch,
    observe: &mut dyn FnMut(u64, f64),
) -> Result<Option<f64>> {
    let job = Job::new(chain, driven, steps, dt, which, start, None, watch);
    let mut group = Group::new(chain, which);
    let mut history = |step: u64, v: f64| {
        if step % 64 == 0 {
            watch.set_fraction(step as f64 / steps as f64);
        }
        observe(step, v);
    };
    let got = run_observed(path, &mut group, &job, theta0, omega0, &mut history)?;
    Ok(got.map(|values| values[0]))
}

on_path! {
    fn chunk_on(job: &Job, th: &[f64], om: &[f64]) -> Result<Vec<f64>> {
        job.chunk(th, om)
    }
}

on_path! {
    fn run_observed(group: &mut Group, job: &Job, th: &[f64], om: &[f64], observe: &mut dyn FnMut(u64, f64)) -> Result<Option<Lane>> {
        group.run(job, th, om, Some(observe))
    }
}

/// What every group shares.
struct Job<'a> {
    chain: &'a Chain,
    /// A built-in generalized torque of time (none: undriven).
    drive: Option<Timed>,
    torque: &'a Builtin,
    /// A moving pivot the lanes evaluate.
    pivot: Option<&'a Pivot>,
    steps: u64,
    dt: f64,
    which: Indicator,
    start: &'a [f64],
    deviations: Option<&'a [f64]>,
    watch: &'a Watch,
}

impl<'a> Job<'a> {
    #[allow(clippy::too_many_arguments)]
    fn new(
        chain: &'a Chain,
        (torque, pivot): (&'a Builtin, Option<&'a Pivot>),
        steps: u64,
        dt: f64,
        which: Indicator,
        start: &'a [f64],
        deviations: Option<&'a [f64]>,
        watch: &'a Watch,
    ) -> Self {
        let drive = Timed::generalized(torque);
        Job { chain, drive, torque, pivot, steps, dt, which, start, deviations, watch }
    }

    /// A chunk's rows, a group of eight lanes at a time.
    #[inline(always)]
    fn chunk(&self, th: &[f64], om: &[f64]) -> Result<Vec<f64>> {
        let n = self.chain.n();
        let rows = th.len() / n;
        let mut out = Vec::with_capacity(rows);
        let mut group = Group::new(self.chain, self.which);
        for lo in (0..rows).step_by(LANES) {
            let count = LANES.min(rows - lo);
            let (th, om) = (&th[n * lo..n * (lo + count)], &om[n * lo..n * (lo + count)]);
            match group.run(self, th, om, None)? {
                Some(values) => out.extend_from_slice(&values[..count]),
                None => {
                    // Some state failed: the per-state route gives the values or its error.
                    for j in 0..count {
                        let row = (&th[n * j..n * (j + 1)], &om[n * j..n * (j + 1)]);
                        let value = run(
                            self.chain,
                            row.0,
                            row.1,
                            self.steps,
                            self.dt,
                            self.which,
                            (self.torque, self.pivot),
                            self.deviations,
                            self.watch,
                            false,
                            &mut |_, _| {},
                        )?;
                        out.push(value);
                    }
                }
            }
            self.watch.add_units(count as u64);
        }
        Ok(out)
    }
}

/// The Lagrangian form with `k` tangent vectors and MEGNO's integrals in lanes: the lanes'
/// [`super::Tangent`], the step from `t` of `h`.
struct TangentLanes<'a> {
    chain: &'a Chain,
    k: usize,
    megno: bool,
    tau: &'a [Lane],
    /// Torques of time, in place of `tau` (a time-only torque has no tangent of its own).
    drive: Option<&'a Timed>,
    /// A moving pivot: its forces ([`add_pivot_forces`]) and their tangent along `d_theta`.
    pivot: Option<&'a Pivot>,
    /// A lossy or shaken chain's forces and their tangent; the angles' trig for the pivot's.
    q: &'a mut [Lane],
    dq: &'a mut [Lane],
    trig: &'a mut [Lane],
}

impl LaneSystem for TangentLanes<'_> {
    #[inline(always)]
    fn rates(&mut self, at: &Lane, src: &[Lane], dst: &mut [Lane], scratch: &mut LaneScratch, active: &Lane) -> std::result::Result<(), LaneSingular> {
        let (chain, n, k) = (self.chain, self.chain.n(), self.k);
        let d = 2 * n;
        let (head, tail) = dst.split_at_mut(d);
        copy_lanes(&mut head[..n], &src[n..d]);
        let lossy = chain.lossy_joints();
        let acc = self.pivot.map(|p| p.acc_lanes(at));
        let forces: &[Lane] = if lossy || self.drive.is_some() || acc.is_some() {
            match self.drive {
                Some(drive) => drive.lanes(at, self.q),
                None => self.q.copy_from_slice(self.tau),
            }
            if let Some((ax, ay)) = &acc {
                add_pivot_forces(chain, (ax, ay), &src[..n], self.q, self.trig);
            }
            if lossy {
                // The joints' losses as generalized forces, and their own tangent per vector.
                add_losses(chain, &src[n..d], self.q, &mut [0.0; LANES]);
            }
            self.q
        } else {
            self.tau
        };
        // The tangents below read the accelerations' trig (and a triple pendulum's adjugate).
        scratch.for_tangent = true;
        accelerations(chain, &src[..n], &src[n..d], forces, &mut head[n..], scratch, active)?;
        for j in 0..k {
            let v = &src[d * (j + 1)..d * (j + 2)];
            let dv = &mut tail[d * j..d * (j + 1)];
            copy_lanes(&mut dv[..n], &v[n..]);
            let extra = if lossy || acc.is_some() {
                if lossy {
                    add_loss_tangent(chain, &src[n..d], &v[n..], self.dq);
                } else {
                    self.dq.fill([0.0; LANES]);
                }
                if let Some((ax, ay)) = &acc {
                    add_pivot_tangent(chain, (ax, ay), self.trig, &v[..n], self.dq);
                }
                Some(&*self.dq)
            } else {
                None
            };
            tangent(chain, &src[n..d], &head[n..], &v[..n], &v[n..], extra, &mut dv[n..], scratch);
        }
        if self.megno {
            // y' = t (d' . d) / (d . d), w' = 2 y / t (see `Tangent::megno_rates`), at the
            // stage's time (the same in every lane).
            let ts = at[0];
            let (v, dv) = (&src[d..2 * d], &tail[..d]);
            let (mut num, mut den) = ([0.0; LANES], [0.0; LANES]);
            for c in 0..d {
                for i in 0..LANES {
                    num[i] += dv[c][i] * v[c][i];
                    den[i] += v[c][i] * v[c][i];
                }
            }
            let m = d * (1 + k);
            let (ym, rest) = tail[d * k..].split_at_mut(1);
            for i in 0..LANES {
                ym[0][i] = ts * (num[i] / den[i]);
                rest[0][i] = if ts > 0.0 { 2.0 * src[m][i] / ts } else { 0.0 };
            }
        }
        Ok(())
    }
}

/// One group's lanes and buffers: `y = [theta, omega, (d_theta, d_omega) x k, MEGNO's two]`.
struct Group {
    n: usize,
    k: usize,
    megno: bool,
    y: Vec<Lane>,
    rk: Rk4Lanes,
    tau: Vec<Lane>,
    /// OFLI's flow at the step's end.
    flow: Vec<Lane>,
    scratch: LaneScratch,
    q: Vec<Lane>,
    dq: Vec<Lane>,
    trig: Vec<Lane>,
}

impl Group {
    fn new(chain: &Chain, which: Indicator) -> Self {
        let (n, k, megno) = (chain.n(), which.vectors(), which == Indicator::Megno);
        let dim = 2 * n * (1 + k) + 2 * usize::from(megno);
        let lanes = |m| vec![[0.0; LANES]; m];
        Group {
            n,
            k,
            megno,
            y: lanes(dim),
            rk: Rk4Lanes::with_dim(n, dim),
            tau: lanes(n),
            flow: lanes(n),
            scratch: LaneScratch::new(n),
            q: lanes(n),
            dq: lanes(n),
            trig: lanes(2 * n),
        }
    }

    /// The values of up to eight rows (`th`, `om`: `count x N`); `None` if any failed.
    /// `observe(step, value)` sees the first row's value after every step.
    #[inline(always)]
    fn run(&mut self, job: &Job, th: &[f64], om: &[f64], mut observe: Option<&mut dyn FnMut(u64, f64)>) -> Result<Option<Lane>> {
        let (chain, n, k, d) = (job.chain, self.n, self.k, 2 * self.n);
        let count = th.len() / n;
        let mut active = [0.0; LANES];
        // Unused lanes stay at rest (finite) and inactive.
        for m in self.y.iter_mut() {
            *m = [0.0; LANES];
        }
        for j in 0..count {
            for a in 0..n {
                self.y[a][j] = th[n * j + a];
                self.y[n + a][j] = om[n * j + a];
            }
            active[j] = 1.0;
        }
        for (c, &v) in job.start.iter().enumerate() {
            self.y[d + c] = [v; LANES];
        }
        let (mut log_growth, mut fli) = ([0.0f64; LANES], [0.0f64; LANES]);
        let mut gali = vec![0.0; k * d];
        let Group { y, rk, tau, flow, megno, scratch: flow_scratch, q, dq, trig, .. } = self;
        let megno = *megno;
        for step in 1..=job.steps {
            let t = (step - 1) as f64 * job.dt;
            // Every step: a relaxed load against eight states' step (long chains take long).
            job.watch.check(t)?;
            let h = job.dt;
            let mut sys =
                TangentLanes { chain, k, megno, tau, drive: job.drive.as_ref(), pivot: job.pivot, q: &mut q[..], dq: &mut dq[..], trig: &mut trig[..] };
            let stepped = rk.step_system(y, t, h, &active, &mut sys);
            match stepped {
                Ok(nonfinite) if !nonfinite.iter().any(|&b| b) => {}
                _ => return Ok(None),
            }
            // Renormalise; the first vector's growth feeds FLI and the Lyapunov estimate.
            let mut first = [0.0; LANES];
            for j in 0..k {
                let v = &mut y[d * (j + 1)..d * (j + 2)];
                let mut sq = [0.0; LANES];
                for row in v.iter() {
                    for i in 0..LANES {
                        sq[i] += row[i] * row[i];
                    }
                }
                let r: Lane = each(|i| sq[i].sqrt());
                if (0..LANES).any(|i| active[i] > 0.0 && !(r[i] > 0.0)) {
                    return Ok(None);
                }
                for row in v.iter_mut() {
                    for i in 0..LANES {
                        row[i] = if r[i] > 0.0 { row[i] / r[i] } else { row[i] };
                    }
                }
                if j == 0 {
                    first = r;
                }
            }
            match job.which {
                Indicator::Fli | Indicator::Lyapunov => {
                    for i in 0..LANES {
                        log_growth[i] += first[i].ln();
                        fli[i] = fli[i].max(log_growth[i]);
                    }
                }
                Indicator::Ofli => {
                    // The flow at the new state (the torque and the pivot at its time, as the
                    // per-state route's), and the part of the vector orthogonal to it.
                    let at = [step as f64 * job.dt; LANES];
                    match job.drive.as_ref() {
                        Some(drive) => drive.lanes(&at, q),
                        None => q.copy_from_slice(tau),
                    }
                    if let Some(pivot) = job.pivot {
                        let (ax, ay) = pivot.acc_lanes(&at);
                        add_pivot_forces(chain, (&ax, &ay), &y[..n], q, trig);
                    }
                    if chain.lossy_joints() {
                        add_losses(chain, &y[n..d], q, &mut [0.0; LANES]);
                    }
                    if accelerations(chain, &y[..n], &y[n..d], q, flow, flow_scratch, &active).is_err() {
                        return Ok(None);
                    }
                    for i in 0..LANES {
                        log_growth[i] += first[i].ln();
                        let f = |c: usize| if c < n { y[n + c][i] } else { flow[c - n][i] };
                        let fn_ = (0..d).map(|c| f(c) * f(c)).sum::<f64>().sqrt();
                        let perp = if fn_ > 0.0 {
                            let cdot = (0..d).map(|c| y[d + c][i] * f(c)).sum::<f64>() / (fn_ * fn_);
                            (0..d).map(|c| (y[d + c][i] - cdot * f(c)) * (y[d + c][i] - cdot * f(c))).sum::<f64>().sqrt()
                        } else {
                            1.0
                        };
                        fli[i] = fli[i].max(log_growth[i] + perp.ln());
                    }
                }
                _ => {}
            }
            if let Some(observe) = observe.as_mut() {
                observe(step, value(job.which, 0, step as f64 * job.dt, y, (d, k), (&fli, &log_growth), &mut gali));
            }
        }
        let t_end = job.steps as f64 * job.dt;
        let mut values = [0.0; LANES];
        for (i, v) in values.iter_mut().enumerate().take(count) {
            *v = value(job.which, i, t_end, y, (d, k), (&fli, &log_growth), &mut gali);
        }
        Ok(Some(values))
    }
}

/// Lane `i`'s indicator at `t1` from the state `y` (its vectors just renormalised) and the
/// running FLI and log-growth; `gali` holds `k x d` values.
#[inline(always)]
fn value(which: Indicator, i: usize, t1: f64, y: &[Lane], (d, k): (usize, usize), (fli, log_growth): (&Lane, &Lane), gali: &mut [f64]) -> f64 {
    match which {
        Indicator::Megno => y[d * (1 + k) + 1][i] / t1,
        Indicator::Fli | Indicator::Ofli => fli[i],
        Indicator::Lyapunov => log_growth[i] / t1,
        Indicator::Sali => {
            let (u, v) = (|c: usize| y[d + c][i], |c: usize| y[2 * d + c][i]);
            let plus = (0..d).map(|c| (u(c) + v(c)) * (u(c) + v(c))).sum::<f64>().sqrt();
            let minus = (0..d).map(|c| (u(c) - v(c)) * (u(c) - v(c))).sum::<f64>().sqrt();
            plus.min(minus)
        }
        Indicator::Gali(_) => {
            for (c, s) in gali.iter_mut().enumerate() {
                *s = y[d + c][i];
            }
            // A volume that has collapsed to round-off is 0, not an error.
            orthonormalise(gali, d, k).unwrap_or(0.0)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::error::Error;

    fn chains() -> Vec<Chain> {
        vec![
            Chain::new(&[0.8], &[1.5], None, None, 9.81).unwrap(),
            Chain::new(&[1.0, 1.0], &[1.0, 1.0], None, None, 9.81).unwrap(),
            Chain::rods(&[1.0, 0.5, 0.8], &[1.0, 0.3, 2.0], 9.81).unwrap(),
            Chain::new(&[0.4; 5], &[1.0, 0.5, 2.0, 1.0, 0.1], Some(&[0.2; 5]), Some(&[0.01; 5]), 3.7).unwrap(),
            // Damping and friction (the general model's route on the per-state side).
            Chain::new(&[1.0, 1.0], &[1.0, 1.0], None, None, 9.81).unwrap().with_losses(&[0.1, 0.3], &[0.2, 0.0], 0.05).unwrap(),
            Chain::rods(&[1.0, 0.5, 0.8], &[1.0, 0.3, 2.0], 9.81).unwrap().with_losses(&[0.0, 0.2, 0.1], &[0.1, 0.1, 0.0], 1e-3).unwrap(),
        ]
    }

    fn rows(n: usize, b: usize) -> (Vec<f64>, Vec<f64>) {
        let th = (0..n * b).map(|k| (k as f64 * 0.77).sin() * 2.6).collect();
        let om = (0..n * b).map(|k| (k as f64 * 1.31).cos() * 2.0).collect();
        (th, om)
    }

    fn every(n: usize) -> Vec<Indicator> {
        let mut all = vec![Indicator::Megno, Indicator::Fli, Indicator::Ofli, Indicator::Sali, Indicator::Lyapunov, Indicator::Gali(2)];
        if 2 * n >= 3 {
            all.push(Indicator::Gali(3));
        }
        all
    }

    /// The per-state route, row by row.
    fn reference(chain: &Chain, th: &[f64], om: &[f64], steps: u64, dt: f64, which: Indicator) -> Vec<f64> {
        reference_driven(chain, th, om, steps, dt, which, &Builtin::None)
    }

    /// The same under a torque.
    fn reference_driven(chain: &Chain, th: &[f64], om: &[f64], steps: u64, dt: f64, which: Indicator, torque: &Builtin) -> Vec<f64> {
        let n = chain.n();
        (0..th.len() / n)
            .map(|i| {
                run(chain, &th[n * i..n * (i + 1)], &om[n * i..n * (i + 1)], steps, dt, which, (torque, None), None, &Watch::new(), false, &mut |_, _| {})
                    .unwrap()
            })
            .collect()
    }

    #[test]
    fn driven_lanes_agree_with_the_per_state_route() {
        let chains = chains();
        for chain in [&chains[1], &chains[2], &chains[4]] {
            let n = chain.n();
            let torque = Builtin::sinusoid(n, vec![3.0; n], (0..n).map(|a| 2.0 + a as f64).collect(), vec![0.2; n], vec![0.5; n]).unwrap();
            let (th, om) = rows(n, 11);
            let (steps, dt) = (150, 0.005);
            for which in [Indicator::Megno, Indicator::Fli, Indicator::Ofli, Indicator::Sali, Indicator::Gali(2)] {
                let start = super::super::indicators::initial_deviations(2 * n, which.vectors());
                let got = indicators(chain, &th, &om, steps, dt, which, (&torque, None), &start, None, Path::best(), &Watch::new()).unwrap();
                let want = reference_driven(chain, &th, &om, steps, dt, which, &torque);
                let undriven = reference(chain, &th, &om, steps, dt, which);
                assert!(want.iter().zip(&undriven).any(|(a, b)| (a - b).abs() > 1e-3 * (1.0 + b.abs())), "the torque matters");
                for (i, (g, w)) in got.iter().zip(&want).enumerate() {
                    assert!((g - w).abs() <= 1e-12 * (1.0 + w.abs()), "N = {n}, {which:?}, row {i}: {g} vs {w}");
                }
            }
        }
    }

    #[test]
    fn lanes_on_a_shaken_pivot_agree_with_the_per_state_route() {
        use crate::dynamics::base::Axis;
        // A sinusoid along x, a cubic table along y: both evaluated in the lanes.
        let t: Vec<f64> = (0..40).map(|k| 0.05 * k as f64).collect();
        let table = Axis::spline("y", t.clone(), t.iter().map(|t| 0.03 * (11.0 * t).sin()).collect()).unwrap();
        let pivot = Pivot { x: Axis::sinusoid("x", 0.05, 7.0, 0.3, 0.0).unwrap(), y: table };
        let chains = chains();
        for chain in [&chains[1], &chains[2], &chains[4]] {
            let n = chain.n();
            let (th, om) = rows(n, 11);
            let (steps, dt) = (150, 0.005);
            for which in [Indicator::Megno, Indicator::Fli, Indicator::Ofli, Indicator::Sali, Indicator::Gali(2)] {
                let start = super::super::indicators::initial_deviations(2 * n, which.vectors());
                let got = indicators(chain, &th, &om, steps, dt, which, (&Builtin::None, Some(&pivot)), &start, None, Path::best(), &Watch::new()).unwrap();
                let want: Vec<f64> = (0..th.len() / n)
                    .map(|i| {
                        let row = (&th[n * i..n * (i + 1)], &om[n * i..n * (i + 1)]);
                        run(chain, row.0, row.1, steps, dt, which, (&Builtin::None, Some(&pivot)), None, &Watch::new(), false, &mut |_, _| {}).unwrap()
                    })
                    .collect();
                let still = reference(chain, &th, &om, steps, dt, which);
                assert!(want.iter().zip(&still).any(|(a, b)| (a - b).abs() > 1e-3 * (1.0 + b.abs())), "the pivot matters");
                for (i, (g, w)) in got.iter().zip(&want).enumerate() {
                    assert!((g - w).abs() <= 1e-12 * (1.0 + w.abs()), "N = {n}, {which:?}, row {i}: {g} vs {w}");
                }
            }
        }
    }

    #[test]
    fn lanes_agree_with_the_per_state_route_for_every_indicator() {
        for chain in chains() {
            let n = chain.n();
            let (th, om) = rows(n, 21); // two full groups and a partial one
            let (steps, dt) = (150, 0.005);
            for which in every(n) {
                let start = super::super::indicators::initial_deviations(2 * n, which.vectors());
                let got = indicators(&chain, &th, &om, steps, dt, which, (&Builtin::None, None), &start, None, Path::best(), &Watch::new()).unwrap();
                let want = reference(&chain, &th, &om, steps, dt, which);
                // Round-off grown over 150 steps by the chaotic rows, which MEGNO sums up: 2.1e-12
                // of the value at worst (the rods, N = 3), the other indicators under 7e-13.
                for (i, (g, w)) in got.iter().zip(&want).enumerate() {
                    assert!((g - w).abs() <= 1e-11 * (1.0 + w.abs()), "N = {n}, {which:?}, row {i}: {g} vs {w}");
                }
            }
        }
    }

    #[test]
    fn a_state_alone_is_its_row_in_a_batch_and_its_history_the_per_state_routes() {
        use super::super::indicators::indicator as one;
        let chain = &chains()[2];
        let (th, om) = rows(3, 11);
        for which in [Indicator::Megno, Indicator::Ofli, Indicator::Gali(3)] {
            let batch = super::super::indicators::indicators(chain, &th, &om, 0.6, 0.005, which, (&Builtin::None, None), None, &Watch::new()).unwrap();
            for i in [0, 9] {
                let alone =
                    one(chain, &th[3 * i..3 * i + 3], &om[3 * i..3 * i + 3], 0.6, 0.005, which, (&Builtin::None, None), None, 7, &Watch::new()).unwrap();
                assert_eq!(alone.value.to_bits(), batch[i].to_bits(), "{which:?}, row {i}");
                let mut want = Vec::new();
                run(chain, &th[3 * i..3 * i + 3], &om[3 * i..3 * i + 3], 120, 0.005, which, (&Builtin::None, None), None, &Watch::new(), true, &mut |s, v| {
                    if s % 7 == 0 || s == 120 {
                        want.push(v);
                    }
                })
                .unwrap();
                assert_eq!(alone.values.len(), want.len());
                for (g, w) in alone.values.iter().zip(&want) {
                    assert!((g - w).abs() <= 1e-12 * (1.0 + w.abs()), "{which:?}, row {i}: {g} vs {w}");
                }
            }
        }
    }

    #[test]
    fn every_path_gives_the_same_bits_and_a_row_its_own_whatever_its_neighbours() {
        let chain = &chains()[2];
        let (th, om) = rows(3, 70);
        let start = super::super::indicators::initial_deviations(6, 1);
        let go = |th: &[f64], om: &[f64], path| {
            indicators(chain, th, om, 100, 0.01, Indicator::Megno, (&Builtin::None, None), &start, None, path, &Watch::new()).unwrap()
        };
        let reference = go(&th, &om, Path::Portable);
        for path in Path::ALL.into_iter().filter(|p| p.available()) {
            assert_eq!(go(&th, &om, path), reference, "{path:?}");
        }
        let one = go(&th[3 * 67..3 * 68], &om[3 * 67..3 * 68], Path::best());
        assert_eq!(one[0].to_bits(), reference[67].to_bits());
    }

    #[test]
    fn a_failing_group_takes_the_per_state_route_its_error_or_its_values() {
        let chain = &chains()[1];
        let (th, mut om) = rows(2, 10);
        let start = super::super::indicators::initial_deviations(4, 1);
        let go =
            |th: &[f64], om: &[f64]| indicators(chain, th, om, 200, 0.01, Indicator::Fli, (&Builtin::None, None), &start, None, Path::best(), &Watch::new());
        om[2 * 3] = 1e155; // row 3 overflows
        let e = go(&th, &om).unwrap_err();
        let scalar =
            run(chain, &th[6..8], &om[6..8], 200, 0.01, Indicator::Fli, (&Builtin::None, None), None, &Watch::new(), false, &mut |_, _| {}).unwrap_err();
        assert!(matches!(e, Error::Integration { .. }), "{e}");
        assert_eq!(e.to_string(), scalar.to_string());
        // A group the lanes cannot finish (here: started from a zero vector, which collapses)
        // takes the per-state route, whose values it returns.
        let dev = [1.0, 0.0, 0.0, 0.0];
        let got = indicators(chain, &th[..4], &om[..4], 10, 0.01, Indicator::Fli, (&Builtin::None, None), &[0.0; 4], Some(&dev), Path::best(), &Watch::new())
            .unwrap();
        for (i, g) in got.iter().enumerate() {
            let want = run(
                chain,
                &th[2 * i..2 * i + 2],
                &om[2 * i..2 * i + 2],
                10,
                0.01,
                Indicator::Fli,
                (&Builtin::None, None),
                Some(&dev),
                &Watch::new(),
                false,
                &mut |_, _| {},
            )
            .unwrap();
            assert_eq!(g.to_bits(), want.to_bits());
        }
    }
}
