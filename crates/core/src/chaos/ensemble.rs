//! Ensembles in SIMD lanes: many undriven chains (damping, friction and a cart included: the
//! cart's state and the losses' work ride along as more lanes, for the energy balance; the cart
//! starts at rest at the origin, as a run's does by default; no torque) run by rk4
//! to `t_end` on the driver's grid (`t_k = k dt`, the last step shortened to land on `t_end`),
//! eight to a group of lanes ([`Rk4Lanes`]), keeping only what `mp.ensemble` reports: the final
//! states and momenta, the energy error at `t_end`, the number of steps, and the first time any
//! link went over the top (the first upward crossing of `max_i |theta_i| = pi`, the non-terminal
//! `Flip` event of the per-trajectory route, located on the step's cubic Hermite interpolant).
//! A row agrees with the per-trajectory route (a batch `simulate` with that event) to round-off:
//! the lanes' own `sin`/`cos` and fused product-sums; its bits depend neither on the other rows
//! nor on the number of threads, and are the same on the AVX-512, AVX2 and portable paths.
use std::f64::consts::PI;

use super::flip_time;
use crate::dynamics::system::NON_FINITE;
use crate::dynamics::Workspace;
use crate::error::{Error, Result};
use crate::integrators::lanes::Rk4Lanes;
use crate::integrators::Method;
use crate::model::Chain;
use crate::par::*;
use crate::run::driver::fixed_steps;
use crate::run::energy::EnergyBalance;
use crate::run::Settings;
use crate::trig::lanes::{Path, LANES};
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
    /// Steps of every row (the grid's: the same for all).
    pub steps: u64,
    /// The first flip of each row (+inf: none by `t_end`).
    pub first_flip: Vec<f64>,
}

/// Whether an ensemble of `chain` run with `method` goes through the lanes: an undriven chain
/// (the caller passes no torque; losses and a cart allowed) on rk4's Lagrangian form, unless `MULTIPENDULUM_LANES`
/// asks for the per-trajectory route. `None`: the per-trajectory route.
pub fn route(chain: &Chain, method: Method) -> Result<Option<Path>> {
    if method != Method::Rk4 {
        return Ok(None);
    }
    crate::run::bank::requested()
}

/// The ensemble of the rows of `theta0`, `omega0` (flat, `(B, N)`) by rk4 at step `dt` to
/// `t_end` in lanes on `path` (see [`route`]); inputs are checked as a batch `simulate` checks
/// them, with the same messages. `watch` counts rows done and stops the work between steps.
pub fn ensemble(chain: &Chain, theta0: &[f64], omega0: &[f64], t_end: f64, dt: f64, path: Path, watch: &Watch) -> Result<Ensemble> {
    let n = chain.n();
    let settings = Settings { method: Method::Rk4, dt: Some(dt), t_eval: Some(vec![t_end]), ..Settings::default() };
    let b = crate::run::simulate::batch_size(chain, theta0, omega0)?;
    settings.validate(t_end)?;
    crate::run::simulate::check_fixed_steps(&settings, t_end)?;
    for i in 0..b {
        let rows = (&theta0[n * i..n * (i + 1)], &omega0[n * i..n * (i + 1)]);
        chain.check_state("theta0", rows.0).and_then(|_| chain.check_state("omega0", rows.1)).map_err(|e| match e {
            Error::Input(m) => Error::Input(format!("trajectory {i}: {m}")),
            other => other,
        })?;
    }
    let steps = fixed_steps(t_end, dt);
    let parts: Vec<Ensemble> = theta0
        .par_chunks(n * CHUNK)
        .zip(omega0.par_chunks(n * CHUNK))
        .enumerate()
        .map(|(c, (th, om))| {
            watch.check(0.0)?;
            let out = run_chunk_on(path, chain, th, om, t_end, dt, steps, c * CHUNK, watch)?;
            watch.add_units((th.len() / n) as u64);
            Ok(out)
        })
        .collect::<Result<_>>()?;
    let mut all = Ensemble { theta: Vec::new(), omega: Vec::new(), p: Vec::new(), energy_error: Vec::new(), steps, first_flip: Vec::new() };
    for part in parts {
        all.theta.extend(part.theta);
        all.omega.extend(part.omega);
        all.p.extend(part.p);
        all.energy_error.extend(part.energy_error);
        all.first_flip.extend(part.first_flip);
    }
    Ok(all)
}

#[allow(clippy::too_many_arguments)]
fn run_chunk_on(path: Path, chain: &Chain, th: &[f64], om: &[f64], t_end: f64, dt: f64, steps: u64, first: usize, watch: &Watch) -> Result<Ensemble> {
    match path {
        // SAFETY: the path was checked available when chosen (`bank::requested`).
        #[cfg(target_arch = "x86_64")]
        Path::Avx512 => unsafe { run_chunk_avx512(chain, th, om, t_end, dt, steps, first, watch) },
        #[cfg(target_arch = "x86_64")]
        Path::Avx2 => unsafe { run_chunk_avx2(chain, th, om, t_end, dt, steps, first, watch) },
        _ => run_chunk(chain, th, om, t_end, dt, steps, first, watch),
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,fma")]
#[allow(clippy::too_many_arguments)]
unsafe fn run_chunk_avx512(chain: &Chain, th: &[f64], om: &[f64], t_end: f64, dt: f64, steps: u64, first: usize, watch: &Watch) -> Result<Ensemble> {
    run_chunk(chain, th, om, t_end, dt, steps, first, watch)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
#[allow(clippy::too_many_arguments)]
unsafe fn run_chunk_avx2(chain: &Chain, th: &[f64], om: &[f64], t_end: f64, dt: f64, steps: u64, first: usize, watch: &Watch) -> Result<Ensemble> {
    run_chunk(chain, th, om, t_end, dt, steps, first, watch)
}

/// The rows of one chunk (`first`: the index of its first row in the batch, for messages), a
/// group of eight lanes at a time.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn run_chunk(chain: &Chain, th: &[f64], om: &[f64], t_end: f64, dt: f64, steps: u64, first: usize, watch: &Watch) -> Result<Ensemble> {
    let n = chain.n();
    let rows = th.len() / n;
    let lanes = |k| vec![[0.0; LANES]; k];
    // A chain on a cart carries the cart's x and v (from rest at the origin) after its angles
    // and rates; a lossy chain, or one on a cart, the losses' work (-D) as one more lane, for its
    // energy balance.
    let cart = chain.cart().is_some();
    let row = 2 * n + 2 * usize::from(cart);
    let m = row + usize::from(cart || chain.lossy_joints());
    let (mut y, mut y0, tau) = (lanes(m), lanes(m), lanes(n));
    let mut rk = Rk4Lanes::with_dim(n, m);
    let (mut ws, mut scratch) = (Workspace::new(n), vec![0.0; n]);
    let mut out = Ensemble {
        theta: vec![0.0; rows * n],
        omega: vec![0.0; rows * n],
        p: vec![0.0; rows * n],
        energy_error: vec![0.0; rows],
        steps,
        first_flip: vec![f64::INFINITY; rows],
    };
    for g in 0..rows.div_ceil(LANES) {
        let (lo, count) = (g * LANES, LANES.min(rows - g * LANES));
        let mut active = [0.0; LANES];
        // Unused lanes stay at rest (finite) and inactive.
        for m in y.iter_mut() {
            *m = [0.0; LANES];
        }
        for j in 0..count {
            for a in 0..n {
                y[a][j] = th[n * (lo + j) + a];
                y[n + a][j] = om[n * (lo + j) + a];
            }
            active[j] = 1.0;
        }
        // Whether the lane's max |theta| was below pi at the start of the step (the event's
        // sign), and whether its first flip is found.
        let mut below = [false; LANES];
        let mut found = [false; LANES];
        for j in 0..count {
            below[j] = (0..n).all(|a| y[a][j].abs() < PI);
        }
        for k in 0..steps {
            // Every step: a relaxed load against eight lanes' step of N links (long chains take
            // seconds per group, and Ctrl-C must be heard within a fraction of one).
            watch.check(k as f64 * dt)?;
            let t = k as f64 * dt;
            let h = if k + 1 == steps { t_end - t } else { dt };
            y0.copy_from_slice(&y);
            let stepped = if cart {
                rk.step_cart(chain, &mut y, &tau, &[0.0; LANES], h, &active)
            } else {
                rk.step(chain, &mut y, &tau, h, &active)
            };
            let nonfinite = stepped.map_err(|(stage, bad)| {
                let j = (0..LANES).find(|&j| bad.lanes[j]).unwrap_or(0);
                let at = t + [0.0, 0.5, 0.5, 1.0][stage] * h;
                Error::integration(at, format!("trajectory {}: {}", first + lo + j, bad.link.reason()))
            })?;
            if let Some(j) = (0..count).find(|&j| nonfinite[j]) {
                return Err(Error::integration(t + h, format!("trajectory {}: {NON_FINITE}", first + lo + j)));
            }
            for j in 0..count {
                let now_below = (0..n).all(|a| y[a][j].abs() < PI);
                if below[j] && !now_below && !found[j] {
                    // The earliest crossing among the links that went over in this step.
                    let at = (0..n)
                        .filter(|&a| y[a][j].abs() >= PI)
                        .map(|a| flip_time(t, h, (y0[a][j], y0[n + a][j]), (y[a][j], y[n + a][j])))
                        .fold(f64::INFINITY, f64::min);
                    out.first_flip[lo + j] = at;
                    found[j] = true;
                }
                below[j] = now_below;
            }
        }
        for j in 0..count {
            let r = lo + j;
            let (th0, om0) = (&th[n * r..n * (r + 1)], &om[n * r..n * (r + 1)]);
            let kinetic0 = chain.kinetic_energy(th0, om0, &mut scratch, &mut ws);
            let mut balance = EnergyBalance::new(chain, kinetic0, chain.potential_energy(th0));
            let (theta, omega) = (&mut out.theta[n * r..n * (r + 1)], &mut out.omega[n * r..n * (r + 1)]);
            for a in 0..n {
                theta[a] = y[a][j];
                omega[a] = y[n + a][j];
            }
            // The lab frame's kinetic energy and the momenta with the cart's velocity.
            let v = if cart { y[2 * n + 1][j] } else { 0.0 };
            let kinetic = chain.kinetic_energy_moving(theta, omega, [v, 0.0], &mut scratch, &mut ws);
            let work = y.get(row).map_or(0.0, |w| w[j]);
            out.energy_error[r] = balance.observe(kinetic, kinetic + chain.potential_energy(theta), work);
            chain.momenta_general(theta, omega, v, &mut out.p[n * r..n * (r + 1)], &mut ws);
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dynamics::torque::Builtin;
    use crate::run::events::{Condition, EventSpec};
    use crate::run::simulate_batch;

    fn chains() -> Vec<Chain> {
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

    fn rows(n: usize, b: usize) -> (Vec<f64>, Vec<f64>) {
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
            let got = ensemble(&chain, &th, &om, t_end, dt, Path::best(), &Watch::new()).unwrap();
            let settings = Settings {
                method: Method::Rk4,
                dt: Some(dt),
                t_eval: Some(vec![t_end]),
                events: vec![EventSpec { condition: Condition::Flip(None), direction: 1, terminal: false }],
                ..Settings::default()
            };
            let want = simulate_batch(&chain, &th, &om, t_end, &settings, &Builtin::None, &Watch::new()).unwrap();
            assert_eq!(got.steps, 84);
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
                assert_eq!(tr.stats.steps, got.steps);
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
        let reference = ensemble(chain, &th, &om, 3.0, 0.01, Path::Portable, &Watch::new()).unwrap();
        for path in Path::ALL.into_iter().filter(|p| p.available()) {
            assert_eq!(ensemble(chain, &th, &om, 3.0, 0.01, path, &Watch::new()).unwrap(), reference, "{path:?}");
        }
        let one = ensemble(chain, &th[3 * 261..3 * 262], &om[3 * 261..3 * 262], 3.0, 0.01, Path::best(), &Watch::new()).unwrap();
        assert_eq!(one.theta, reference.theta[3 * 261..3 * 262].to_vec());
        assert_eq!(one.first_flip[0].to_bits(), reference.first_flip[261].to_bits());
    }

    #[test]
    fn bad_rows_and_blow_ups_name_their_trajectory() {
        let chain = &chains()[0];
        let e = ensemble(chain, &[0.1, 0.2, 0.3, f64::NAN], &[0.0; 4], 1.0, 0.01, Path::best(), &Watch::new()).unwrap_err();
        assert_eq!(e.to_string(), "trajectory 1: theta0[1] must be finite, got NaN");
        let e = ensemble(chain, &[0.1; 4], &[0.0, 0.0, 1e200, 0.0], 1.0, 0.01, Path::best(), &Watch::new()).unwrap_err();
        assert!(matches!(e, Error::Integration { .. }) && e.to_string().contains("trajectory 1:"), "{e}");
        let e = ensemble(chain, &[0.1; 4], &[0.0; 4], 1.0, -0.01, Path::best(), &Watch::new()).unwrap_err();
        assert_eq!(e.to_string(), "dt must be > 0 and finite, got -0.01");
    }
}
