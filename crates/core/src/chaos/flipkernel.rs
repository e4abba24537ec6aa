//! The flip-map kernels: first-flip times of many undriven double pendulums at once, and of
//! undriven ideal chains of any other N ([`first_flips_chain`], on
//! [`crate::integrators::lanes::Rk4Lanes`] with the same refilling of lanes).
//!
//! Trajectories advance in lanes (structure of arrays: `theta1[W]`, `theta2[W]`, ...; `W` two groups of
//! [`LANES`] for the double pendulum's own kernel, one for the chains') with
//! plain loops over fixed-size arrays that LLVM vectorises across trajectories. A lane whose
//! trajectory has flipped (or reached `t_max`) is refilled at once with the next trajectory of its
//! chunk, so no lane idles while work remains. The step is [`Rk4::step`](crate::integrators::Rk4)
//! on the Lagrangian form, operation for operation, with the chain's own `diag`, `h`, `lengths`
//! and `g` as in `Chain::accelerations_double`; only `sin`/`cos` differ: a vectorisable Cody–Waite
//! reduction and the fdlibm kernels (within 1 ulp of glibc's), so states agree with the scalar
//! path to round-off (not bit for bit) and flip times to the accuracy of the bisection.
//!
//! The same source is compiled several times (AVX-512, AVX2, portable) and chosen at run time.
//! Every product-sum that is fused is written as an explicit `mul_add` (Rust never contracts
//! `a * b + c` by itself): one correctly rounded operation, a hardware FMA on the AVX paths and
//! glibc's exact `fma()` on the portable one, so every path gives the same bits; each lane is
//! independent of the others, so a result does not depend on the chunking or the number of
//! threads. (Fusing saved a fifth of the time against the unfused kernel.)
//!
//! The vectorised `sin`/`cos` also serves chains of eight or more links (`sin_cos_slice`, called
//! by the O(N) recursion), where it took a third off the cost per link.
#![allow(clippy::excessive_precision)] // fdlibm's constants, digit for digit

use std::f64::consts::PI;

use super::flip_time;
use crate::dynamics::base::Pivot;
use crate::dynamics::system::NON_FINITE;
use crate::dynamics::torque::Timed;
use crate::dynamics::{Singular, PIVOT_TOL};
use crate::error::{Error, Result};
use crate::integrators::lanes::{failed_at, step_system_pair, ChainLanes as Equations, Rk4Lanes, Stepped};
use crate::model::Chain;
use crate::par::*;
use crate::trig::lanes::{copy_lanes, each, max_abs, on_path, sin_cos, Lane, Path, LANES};
use crate::watch::Watch;

/// Trajectories per parallel task (each task refills its lanes from its own chunk).
const CHUNK: usize = 512;

/// The environment variable that picks the flip-map route: `auto` (default), `scalar` (the
/// per-trajectory rk4 of `chaos::first_flips_scalar`), a kernel path by name, or `generic` (the
/// lanes of any chain, also for the ideal double pendulum, whose own kernel `auto` takes). For
/// tests and benchmarks; results never depend on it beyond round-off (and not at all among
/// kernel paths).
pub const SWITCH: &str = "MULTIPENDULUM_FLIP_KERNEL";

/// The route the environment asks for: `None` for the scalar path.
pub fn requested() -> Result<Option<Path>> {
    Path::requested(SWITCH, &["generic"])
}

/// Whether the environment asks for the generic lanes also where a chain has its own kernel.
pub fn generic() -> bool {
    std::env::var(SWITCH).is_ok_and(|v| v == "generic")
}

/// The double pendulum's kernel steps two groups of [`LANES`] trajectories side by side: its
/// step is short, and the second group's independent arithmetic fills the wait on the first's
/// divisions and sin/cos (23-32% more trajectory-steps per second than one group on AVX-512;
/// the same on AVX2).
/// Each lane's arithmetic is its own, so the width changes no value.
const W: usize = 2 * LANES;
type Wide = [f64; W];

/// The double pendulum's constant coefficients, as `Chain::accelerations_double` uses them.
#[derive(Debug, Clone, Copy)]
struct Coef {
    gh1: f64,
    gh2: f64,
    k: f64,
    d1: f64,
    d2: f64,
    d1d2: f64,
    tol: f64,
}

impl Coef {
    fn new(chain: &Chain) -> Self {
        let (d1, d2, h1, h2, g) = (chain.diag[0], chain.diag[1], chain.h[0], chain.h[1], chain.g);
        // The same products, in the same order, as the scalar expressions they replace.
        Coef { gh1: g * h1, gh2: g * h2, k: chain.lengths[0] * h2, d1, d2, d1d2: d1 * d2, tol: PIVOT_TOL * d1 * d2 }
    }
}

/// `theta_ddot` of every lane, as `Chain::accelerations_double` with no torque; `det` receives
/// the 2x2 determinant for the pivot test.
#[inline(always)]
fn accelerations(c: &Coef, y: &[Wide; 4], a1: &mut Wide, a2: &mut Wide, det: &mut Wide) {
    let [th1, th2, w1, w2] = y;
    let (s1, c1) = sin_cos(th1);
    let (s2, c2) = sin_cos(th2);
    for i in 0..W {
        let (s12, c12) = (s1[i].mul_add(c2[i], -(c1[i] * s2[i])), c1[i].mul_add(c2[i], s1[i] * s2[i]));
        let r1 = (-c.gh1).mul_add(s1[i], -(c.k * s12 * w2[i] * w2[i]));
        let r2 = (-c.gh2).mul_add(s2[i], c.k * s12 * w1[i] * w1[i]);
        let kc = c.k * c12;
        let d = (-kc).mul_add(kc, c.d1d2);
        let inv = 1.0 / d;
        a1[i] = c.d2.mul_add(r1, -(kc * r2)) * inv;
        a2[i] = c.d1.mul_add(r2, -(kc * r1)) * inv;
        det[i] = d;
    }
}

/// Whether an active lane failed the pivot test.
#[inline(always)]
fn any_singular(c: &Coef, det: &Wide, active: &[bool; W]) -> bool {
    let mut bad = false;
    for i in 0..W {
        bad |= active[i] & !(det[i] > c.tol);
    }
    bad
}

/// One rk4 step of every lane, operation for operation as `Rk4::step`. `Err(stage)` (0..4) when
/// an active lane's mass matrix failed the pivot test at that stage; `det` then holds its values.
#[inline(always)]
fn rk4_step(c: &Coef, y: &mut [Wide; 4], dt: f64, active: &[bool; W], det: &mut Wide) -> std::result::Result<(), usize> {
    let half = 0.5 * dt;
    let mut k = [[[0.0; W]; 4]; 4];
    let mut tmp = *y;
    for stage in 0..4 {
        let [_, _, a1, a2] = &mut k[stage];
        accelerations(c, &tmp, a1, a2, det);
        k[stage][0] = tmp[2];
        k[stage][1] = tmp[3];
        if any_singular(c, det, active) {
            return Err(stage);
        }
        if stage < 3 {
            let h = if stage < 2 { half } else { dt };
            for m in 0..4 {
                for i in 0..W {
                    tmp[m][i] = h.mul_add(k[stage][m][i], y[m][i]);
                }
            }
        }
    }
    let sixth = dt / 6.0;
    for m in 0..4 {
        for i in 0..W {
            y[m][i] = sixth.mul_add(2.0f64.mul_add(k[1][m][i] + k[2][m][i], k[0][m][i]) + k[3][m][i], y[m][i]);
        }
    }
    Ok(())
}

/// The lanes of one chunk and the next row of the chunk to load.
struct Lanes {
    y: [Wide; 4],
    step: [u64; W],
    id: [usize; W],
    active: [bool; W],
    next: usize,
}

impl Lanes {
    /// Put the next row that has not already flipped (`out = 0` for those) into `lane`; when none
    /// is left the lane goes idle at rest, where it stays finite.
    #[inline(always)]
    fn load(&mut self, lane: usize, theta0: &[f64], omega0: &[f64], links: [bool; 2], out: &mut [f64]) {
        while self.next < out.len() {
            let j = self.next;
            self.next += 1;
            let (th, om) = (&theta0[2 * j..2 * j + 2], &omega0[2 * j..2 * j + 2]);
            if (links[0] && th[0].abs() >= PI) || (links[1] && th[1].abs() >= PI) {
                out[j] = 0.0;
                continue;
            }
            (self.y[0][lane], self.y[1][lane], self.y[2][lane], self.y[3][lane]) = (th[0], th[1], om[0], om[1]);
            (self.step[lane], self.id[lane], self.active[lane]) = (0, j, true);
            return;
        }
        for m in self.y.iter_mut() {
            m[lane] = 0.0;
        }
        self.active[lane] = false;
    }
}

/// The run of one chunk: `out[j]` for the rows `theta0[2j..2j+2]`, `omega0[2j..2j+2]`.
/// `links[k]`: whether link `k` counts as a flip; `first`: the chunk's first row in the batch
/// (an error names its row as the per-trajectory route does).
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn run_chunk(c: &Coef, theta0: &[f64], omega0: &[f64], steps: u64, dt: f64, links: [bool; 2], (stop, first): (&Watch, usize), out: &mut [f64]) -> Result<()> {
    let mut lanes = Lanes { y: [[0.0; W]; 4], step: [0; W], id: [0; W], active: [false; W], next: 0 };
    let mut det = [0.0; W];
    let mut live = 0;
    for lane in 0..W {
        lanes.load(lane, theta0, omega0, links, out);
        live += usize::from(lanes.active[lane]);
    }
    let mut rounds = 0u64;
    while live > 0 {
        rounds += 1;
        if rounds % 1024 == 0 {
            stop.check(lanes.step[0] as f64 * dt)?;
        }
        let y0 = lanes.y;
        if let Err(stage) = rk4_step(c, &mut lanes.y, dt, &lanes.active, &mut det) {
            let i = (0..W).find(|&i| lanes.active[i] && !(det[i] > c.tol)).unwrap_or(0);
            let t = lanes.step[i] as f64 * dt;
            let t = [t, t + 0.5 * dt, t + 0.5 * dt, t + dt][stage];
            let reason = if det[i].is_nan() { NON_FINITE.to_string() } else { Singular(0).reason() };
            return Err(Error::integration(t, reason).of_trajectory(first + lanes.id[i]));
        }
        let mut event = false;
        for i in 0..W {
            lanes.step[i] += 1;
            let flip = (links[0] & (lanes.y[0][i].abs() >= PI)) | (links[1] & (lanes.y[1][i].abs() >= PI));
            event |= lanes.active[i] & (flip | (lanes.step[i] >= steps));
        }
        if !event {
            continue;
        }
        for i in 0..W {
            if !lanes.active[i] {
                continue;
            }
            let t = (lanes.step[i] - 1) as f64 * dt;
            let k = if links[0] && lanes.y[0][i].abs() >= PI { 0 } else { 1 };
            if links[k] && lanes.y[k][i].abs() >= PI {
                // On the step's cubic Hermite interpolant (theta' = omega), as the scalar path.
                out[lanes.id[i]] = flip_time(t, dt, (y0[k][i], y0[2 + k][i]), (lanes.y[k][i], lanes.y[2 + k][i]));
            } else if lanes.step[i] >= steps {
                if !(0..4).all(|m| lanes.y[m][i].is_finite()) {
                    return Err(Error::integration(t + dt, NON_FINITE).of_trajectory(first + lanes.id[i]));
                }
                out[lanes.id[i]] = f64::INFINITY;
            } else {
                continue;
            }
            lanes.load(i, theta0, omega0, links, out);
            live -= usize::from(!lanes.active[i]);
        }
    }
    Ok(())
}

on_path! {
    fn run_chunk_on(c: &Coef, th: &[f64], om: &[f64], steps: u64, dt: f64, links: [bool; 2], watch: (&Watch, usize), out: &mut [f64]) -> Result<()> {
        run_chunk(c, th, om, steps, dt, links, watch, out)
    }
}

/// First-flip times of the undriven double pendulum `chain` (N = 2) for the rows of `theta0`,
/// `omega0` (flat, `(B, 2)`), with `steps` rk4 steps of `dt` (`t = step * dt`) and the same rules
/// as `chaos::first_flips`, which validates the input and calls this. `link`: `None` for either.
#[allow(clippy::too_many_arguments)]
pub(crate) fn first_flips_double(
    chain: &Chain,
    theta0: &[f64],
    omega0: &[f64],
    steps: u64,
    dt: f64,
    link: Option<usize>,
    path: Path,
    stop: &Watch,
) -> Result<Vec<f64>> {
    debug_assert_eq!(chain.n(), 2);
    let c = Coef::new(chain);
    let links = [link != Some(1), link != Some(0)];
    let parts: Vec<Vec<f64>> = theta0
        .par_chunks(2 * CHUNK)
        .zip(omega0.par_chunks(2 * CHUNK))
        .enumerate()
        .map(|(k, (th, om))| {
            let mut out = vec![0.0; th.len() / 2];
            stop.check(0.0)?;
            run_chunk_on(path, &c, th, om, steps, dt, links, (stop, k * CHUNK), &mut out)?;
            stop.add_units(out.len() as u64);
            Ok(out)
        })
        .collect::<Result<_>>()?;
    Ok(parts.concat())
}

/// One group of lanes of a chunk of an N-link chain's rows: `y = [theta (N), omega (N)]`, each a
/// lane.
struct ChainLanes {
    y: Vec<Lane>,
    y0: Vec<Lane>,
    tau: Vec<Lane>,
    q: Vec<Lane>,
    rk: Rk4Lanes,
    step: [u64; LANES],
    id: [usize; LANES],
    active: Lane,
    /// Lanes holding a row.
    live: usize,
}

impl ChainLanes {
    fn new(chain: &Chain, m: usize) -> Self {
        let (n, lanes) = (chain.n(), |k| vec![[0.0; LANES]; k]);
        ChainLanes {
            y: lanes(m),
            y0: lanes(m),
            tau: lanes(n),
            q: lanes(n),
            rk: Rk4Lanes::with_dim(n, m),
            step: [0; LANES],
            id: [0; LANES],
            active: [0.0; LANES],
            live: 0,
        }
    }

    /// As [`Lanes::load`], for N links: the chunk's `next` row not already flipped into `lane`,
    /// or the lane idle at rest.
    #[inline(always)]
    fn load(&mut self, lane: usize, next: &mut usize, theta0: &[f64], omega0: &[f64], links: &[usize], out: &mut [f64]) {
        let n = self.tau.len();
        let was = self.active[lane] > 0.0;
        while *next < out.len() {
            let j = *next;
            *next += 1;
            let (th, om) = (&theta0[n * j..n * (j + 1)], &omega0[n * j..n * (j + 1)]);
            if links.iter().any(|&k| th[k].abs() >= PI) {
                out[j] = 0.0;
                continue;
            }
            for a in 0..n {
                (self.y[a][lane], self.y[n + a][lane]) = (th[a], om[a]);
            }
            // A cart starts at rest at the origin.
            for m in self.y[2 * n..].iter_mut() {
                m[lane] = 0.0;
            }
            (self.step[lane], self.id[lane], self.active[lane]) = (0, j, 1.0);
            self.live += usize::from(!was);
            return;
        }
        for m in self.y.iter_mut() {
            m[lane] = 0.0;
        }
        self.active[lane] = 0.0;
        self.live -= usize::from(was);
    }

    /// After a step of this group (`stepped`, from `y0` to `y`): its failure as an error naming
    /// the row (`first`: the chunk's first row in the batch), and each lane whose row flipped or
    /// ran its `steps` out written to `out` and loaded anew.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    fn settle(
        &mut self,
        stepped: Stepped,
        (steps, dt): (u64, f64),
        links: &[usize],
        (next, first): (&mut usize, usize),
        theta0: &[f64],
        omega0: &[f64],
        out: &mut [f64],
    ) -> Result<()> {
        let n = self.tau.len();
        let nonfinite = match stepped {
            Ok(nonfinite) => nonfinite,
            Err((stage, bad)) => {
                let i = (0..LANES).find(|&i| bad.lanes[i]).unwrap_or(0);
                let t = failed_at(&bad, i, stage, self.step[i] as f64 * dt, dt);
                return Err(Error::integration(t, bad.reason(i)).of_trajectory(first + self.id[i]));
            }
        };
        if let Some(i) = (0..LANES).find(|&i| nonfinite[i]) {
            return Err(Error::integration((self.step[i] + 1) as f64 * dt, NON_FINITE).of_trajectory(first + self.id[i]));
        }
        // The largest |theta| of the watched links.
        let top = max_abs(&self.y, links.iter().copied());
        // Whether any lane has an event, as bits (an `any |=` compiles to a branch per lane).
        let mut event = 0u32;
        for i in 0..LANES {
            self.step[i] += 1;
            event |= u32::from((self.active[i] > 0.0) & ((top[i] >= PI) | (self.step[i] >= steps))) << i;
        }
        if event == 0 {
            return Ok(());
        }
        for i in 0..LANES {
            if !(self.active[i] > 0.0) {
                continue;
            }
            let t = (self.step[i] - 1) as f64 * dt;
            if let Some(&k) = links.iter().find(|&&k| self.y[k][i].abs() >= PI) {
                // On the step's cubic Hermite interpolant (theta' = omega), as the scalar path.
                out[self.id[i]] = flip_time(t, dt, (self.y0[k][i], self.y0[n + k][i]), (self.y[k][i], self.y[n + k][i]));
            } else if self.step[i] >= steps {
                out[self.id[i]] = f64::INFINITY;
            } else {
                continue;
            }
            self.load(i, next, theta0, omega0, links, out);
        }
        Ok(())
    }
}

/// [`run_chunk`] for a chain of any N (losses and a cart included), undriven or under `drive`'s
/// torques of time (each lane at its own trajectory's time), stepped by [`Rk4Lanes`]: `out[j]` for the
/// rows `theta0[N j..N (j + 1)]`, `omega0[..]`; `links` the links whose flip counts, in order
/// (the first one over the top is the one timed, as on the scalar path). Two groups of lanes
/// take the chunk's rows in turn and step side by side ([`step_system_pair`]: for the double and
/// triple pendulum, the one group's arithmetic fills the wait on the other's divisions and
/// `sin`/`cos`); each row's lane takes the same operations in either group, so the same bits.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn run_chunk_chain(
    chain: &Chain,
    theta0: &[f64],
    omega0: &[f64],
    steps: u64,
    dt: f64,
    links: &[usize],
    (drive, pivot): (Option<&Timed>, Option<&Pivot>),
    (stop, first): (&Watch, usize),
    out: &mut [f64],
) -> Result<()> {
    // A chain on a cart carries the cart's x and v after its angles and rates; a driven one, its
    // torques' work (for the lanes' layout; not reported).
    let m = chain.state_len() + usize::from(drive.is_some());
    let mut g = [ChainLanes::new(chain, m), ChainLanes::new(chain, m)];
    let mut next = 0;
    for lane in 0..LANES {
        for s in g.iter_mut() {
            s.load(lane, &mut next, theta0, omega0, links, out);
        }
    }
    while g[0].live + g[1].live > 0 {
        // Every round: a relaxed load against sixteen lanes' step of N links (so Ctrl-C is heard
        // at once on chains of thousands of links too).
        stop.check(g[0].step[0].max(g[1].step[0]) as f64 * dt)?;
        let [a, b] = &mut g;
        for s in [&mut *a, &mut *b] {
            copy_lanes(&mut s.y0, &s.y);
        }
        // Each lane at its own trajectory's time (for a drive).
        let (ta, tb) = (each(|i| a.step[i] as f64 * dt), each(|i| b.step[i] as f64 * dt));
        let stepped = {
            let sys = |tau, q| Equations { chain, tau, drive, force: &[0.0; LANES], pivot, pivot_work: false, q };
            let (mut sa, mut sb) = (sys(&a.tau, &mut a.q), sys(&b.tau, &mut b.q));
            match (a.live > 0, b.live > 0) {
                (true, true) => {
                    step_system_pair([&mut a.rk, &mut b.rk], [&mut a.y, &mut b.y], [&ta, &tb], dt, [&a.active, &b.active], [&mut sa, &mut sb]).map(Some)
                }
                (true, false) => [Some(a.rk.step_system_at(&mut a.y, &ta, dt, &a.active, &mut sa)), None],
                _ => [None, Some(b.rk.step_system_at(&mut b.y, &tb, dt, &b.active, &mut sb))],
            }
        };
        for (s, stepped) in [a, b].into_iter().zip(stepped) {
            if let Some(stepped) = stepped {
                s.settle(stepped, (steps, dt), links, (&mut next, first), theta0, omega0, out)?;
            }
        }
    }
    Ok(())
}

on_path! {
    fn run_chunk_chain_on(
        chain: &Chain,
        th: &[f64],
        om: &[f64],
        steps: u64,
        dt: f64,
        links: &[usize],
        drive: (Option<&Timed>, Option<&Pivot>),
        watch: (&Watch, usize),
        out: &mut [f64],
    ) -> Result<()> {
        run_chunk_chain(chain, th, om, steps, dt, links, drive, watch, out)
    }
}

/// First-flip times of a chain of any N in lanes, undriven or under `drive`'s torques of time and
/// pivot motion (a pivot the lanes can evaluate) ([`Rk4Lanes`]: the recursion
/// of [`crate::dynamics::lanes`], the lanes' `sin`/`cos`, fused product-sums), with the same
/// rules as `chaos::first_flips`, which validates the input and calls this. Agrees with the
/// per-trajectory path to round-off; the same bits on every path and any number of threads.
#[allow(clippy::too_many_arguments)]
pub(crate) fn first_flips_chain(
    chain: &Chain,
    theta0: &[f64],
    omega0: &[f64],
    steps: u64,
    dt: f64,
    link: Option<usize>,
    drive: (Option<&Timed>, Option<&Pivot>),
    path: Path,
    stop: &Watch,
) -> Result<Vec<f64>> {
    let n = chain.n();
    let links: Vec<usize> = link.map_or_else(|| (0..n).collect(), |k| vec![k]);
    // As many rows per task as the double pendulum's: a task's lanes idle only at its end, while
    // its last trajectories finish, so fewer rows would waste more of the lanes.
    let parts: Vec<Vec<f64>> = theta0
        .par_chunks(n * CHUNK)
        .zip(omega0.par_chunks(n * CHUNK))
        .enumerate()
        .map(|(k, (th, om))| {
            let mut out = vec![0.0; th.len() / n];
            stop.check(0.0)?;
            run_chunk_chain_on(path, chain, th, om, steps, dt, &links, drive, (stop, k * CHUNK), &mut out)?;
            stop.add_units(out.len() as u64);
            Ok(out)
        })
        .collect::<Result<_>>()?;
    Ok(parts.concat())
}

/// The states of every row after `steps` rk4 steps of `dt`, flipped or not (for the tests).
#[cfg(test)]
fn advance(chain: &Chain, theta0: &[f64], omega0: &[f64], steps: u64, dt: f64, path: Path) -> Vec<[f64; 4]> {
    let c = Coef::new(chain);
    let mut out = Vec::new();
    for (th, om) in theta0.chunks(2 * W).zip(omega0.chunks(2 * W)) {
        let mut y = [[0.0; W]; 4];
        for j in 0..th.len() / 2 {
            (y[0][j], y[1][j], y[2][j], y[3][j]) = (th[2 * j], th[2 * j + 1], om[2 * j], om[2 * j + 1]);
        }
        let active = [false; W];
        let mut det = [0.0; W];
        let mut go = |y: &mut [Wide; 4]| {
            let _ = rk4_step(&c, y, dt, &active, &mut det);
        };
        for _ in 0..steps {
            match path {
                // SAFETY: the tests only ask for available paths.
                #[cfg(target_arch = "x86_64")]
                Path::Avx512 => unsafe { avx512_call(&mut go, &mut y) },
                _ => go(&mut y),
            }
        }
        out.extend((0..th.len() / 2).map(|j| [y[0][j], y[1][j], y[2][j], y[3][j]]));
    }
    out
}

#[cfg(all(test, target_arch = "x86_64"))]
#[target_feature(enable = "avx512f,fma")]
unsafe fn avx512_call(f: &mut impl FnMut(&mut [Wide; 4]), y: &mut [Wide; 4]) {
    f(y)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::chaos::first_flips_scalar;
    use crate::dynamics::system::{ChainSystem, Form};
    use crate::dynamics::torque::Builtin;
    use crate::integrators::Rk4;
    use crate::trig::lanes::tests::cpu_flags_have;

    /// The lanes' flip times against the scalar path's where the motion is regular: the same
    /// decision (a flip or none) for at least 99% of the rows, and the same time to 1e-9 for
    /// every row that flips before `before` on both (more than `early` of them).
    fn agree(fast: &[f64], slow: &[f64], before: f64, early: usize, what: &str) {
        let same = fast.iter().zip(slow).filter(|(a, b)| a.is_finite() == b.is_finite()).count();
        assert!(same as f64 >= 0.99 * fast.len() as f64, "{what}: {same} of {}", fast.len());
        let both: Vec<_> = fast.iter().zip(slow).filter(|(a, b)| **a < before && **b < before).collect();
        assert!(both.len() > early, "{what}: {}", both.len());
        for (a, b) in both {
            assert!((a - b).abs() < 1e-9, "{what}: {a} vs {b}");
        }
    }

    fn go() -> Watch {
        Watch::new()
    }

    fn chains() -> Vec<Chain> {
        vec![
            Chain::new(&[1.0, 1.0], &[1.0, 1.0], None, None, 9.81).unwrap(),
            Chain::rods(&[1.0, 0.7], &[1.0, 2.0], 9.81).unwrap(),
            Chain::new(&[1.0, 0.7], &[1.0, 2.0], Some(&[0.6, 0.3]), Some(&[0.05, 0.1]), 3.7).unwrap(),
        ]
    }

    fn inputs(b: usize, seed: u64) -> (Vec<f64>, Vec<f64>) {
        // A small LCG: reproducible without a dependency.
        let mut s = seed;
        let mut u = || {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (s >> 11) as f64 / (1u64 << 53) as f64
        };
        let th = (0..2 * b).map(|_| 6.0 * u() - 3.0).collect();
        let om = (0..2 * b).map(|_| 4.0 * u() - 2.0).collect();
        (th, om)
    }

    #[test]
    fn lanes_follow_the_scalar_rk4_to_round_off() {
        let (steps, dt) = (300, 0.01);
        for chain in chains() {
            // Mild motion, so that round-off is not amplified by chaos over the run.
            let (th, om) = inputs(21, 5);
            let (th, om): (Vec<f64>, Vec<f64>) = (th.iter().map(|x| 0.3 * x).collect(), om.iter().map(|x| 0.3 * x).collect());
            let lanes = advance(&chain, &th, &om, steps, dt, Path::Portable);
            let mut sys = ChainSystem::new(&chain, Builtin::None, Form::Lagrangian);
            let mut rk = Rk4::new(4);
            for (j, got) in lanes.iter().enumerate() {
                let mut y = [th[2 * j], th[2 * j + 1], om[2 * j], om[2 * j + 1]];
                for s in 0..steps {
                    let before = y;
                    rk.step(&mut sys, s as f64 * dt, &before, dt, &mut y).unwrap();
                }
                for m in 0..4 {
                    assert!((got[m] - y[m]).abs() < 1e-12, "row {j}, entry {m}: {} vs {}", got[m], y[m]);
                }
            }
        }
    }

    #[test]
    fn every_path_gives_the_same_bits() {
        let (th, om) = inputs(100, 9);
        for chain in chains() {
            let reference = first_flips_double(&chain, &th, &om, 800, 0.01, None, Path::Portable, &go()).unwrap();
            let states = advance(&chain, &th, &om, 500, 0.01, Path::Portable);
            let mut ran = Vec::new();
            for path in Path::ALL.into_iter().filter(|p| p.available() && *p != Path::Portable) {
                ran.push(path);
                let got = first_flips_double(&chain, &th, &om, 800, 0.01, None, path, &go()).unwrap();
                assert!(got.iter().zip(&reference).all(|(a, b)| a.to_bits() == b.to_bits()), "{path:?}");
                if path == Path::Avx512 {
                    let s = advance(&chain, &th, &om, 500, 0.01, path);
                    assert!(s.iter().flatten().zip(states.iter().flatten()).all(|(a, b)| a.to_bits() == b.to_bits()));
                }
            }
            assert!(reference.iter().any(|t| t.is_finite()) && reference.iter().any(|t| t.is_infinite()));
            // Not the portable path compared with itself where the CPU has a wider one.
            assert_eq!(ran.contains(&Path::Avx2), cpu_flags_have(&["avx2", "fma"]), "paths compared: {ran:?}");
            assert_eq!(ran.contains(&Path::Avx512), cpu_flags_have(&["avx512f", "fma"]), "paths compared: {ran:?}");
        }
    }

    #[test]
    fn flip_times_match_the_scalar_path_where_the_motion_is_regular() {
        for chain in chains() {
            for link in [None, Some(0), Some(1)] {
                // Released from rest over a grid; a flip soon after release is regular motion.
                let (mut th, mut om) = (Vec::new(), Vec::new());
                for i in 0..41 {
                    for j in 0..41 {
                        th.extend([-PI + 2.0 * PI * i as f64 / 40.0, -PI + 2.0 * PI * j as f64 / 40.0]);
                        om.extend([0.0, 0.0]);
                    }
                }
                let steps = 400;
                let fast = first_flips_double(&chain, &th, &om, steps, 0.01, link, Path::best(), &go()).unwrap();
                let slow = first_flips_scalar(&chain, &th, &om, 4.0, 0.01, link, &Builtin::None, None, &go()).unwrap();
                agree(&fast, &slow, 2.0, 50, "the double pendulum");
                // The rows starting beyond pi (the grid's edges) flip at 0 on both paths.
                assert_eq!(fast[0], 0.0);
                assert_eq!(slow[0], 0.0);
            }
        }
    }

    fn chains_of(n: usize) -> Vec<Chain> {
        let l: Vec<f64> = (0..n).map(|a| 1.0 - 0.05 * a as f64).collect();
        let m: Vec<f64> = (0..n).map(|a| 1.0 + 0.3 * (a % 3) as f64).collect();
        let c: Vec<f64> = l.iter().map(|x| 0.4 * x).collect();
        let i: Vec<f64> = l.iter().map(|x| 0.02 * x).collect();
        vec![
            Chain::new(&l, &m, None, None, 9.81).unwrap(),
            Chain::rods(&l, &m, 9.81).unwrap(),
            Chain::new(&l, &m, Some(&c), Some(&i), 3.7).unwrap(),
            // Damping on every joint, friction on every other one (the general model's route on
            // the scalar side).
            Chain::rods(&l, &m, 9.81)
                .unwrap()
                .with_losses(&vec![0.05; n], &(0..n).map(|a| if a % 2 == 0 { 0.1 } else { 0.0 }).collect::<Vec<_>>(), 0.01)
                .unwrap(),
            // On a cart (free, damped), starting at rest.
            Chain::new(&l, &m, None, None, 9.81).unwrap().with_cart(Some(crate::model::Cart::new(2.0, 0.1).unwrap())).unwrap(),
        ]
    }

    /// Rows of a grid of `theta_0` and `theta_last` from rest (the others at 0.3 rad).
    fn released(n: usize, side: usize) -> (Vec<f64>, Vec<f64>) {
        let (mut th, mut om) = (Vec::new(), Vec::new());
        for i in 0..side {
            for j in 0..side {
                let mut row = vec![0.3; n];
                row[0] = -PI + 2.0 * PI * i as f64 / (side - 1) as f64;
                row[n - 1] = -PI + 2.0 * PI * j as f64 / (side - 1) as f64;
                th.extend(row);
                om.extend(vec![0.0; n]);
            }
        }
        (th, om)
    }

    #[test]
    fn chains_of_any_n_flip_as_on_the_scalar_path_where_the_motion_is_regular() {
        for n in [1, 2, 3, 5] {
            for chain in chains_of(n) {
                for link in [None, Some(0), Some(n - 1)] {
                    let (th, om) = released(n, 31);
                    let fast = first_flips_chain(&chain, &th, &om, 300, 0.01, link, (None, None), Path::best(), &go()).unwrap();
                    let slow = first_flips_scalar(&chain, &th, &om, 3.0, 0.01, link, &Builtin::None, None, &go()).unwrap();
                    agree(&fast, &slow, 1.5, 30, &format!("N = {n}"));
                    assert_eq!((fast[0], slow[0]), (0.0, 0.0)); // starting beyond pi
                    assert!(fast.iter().any(|t| t.is_infinite()) || n == 1 || link.is_some());
                }
            }
        }
    }

    #[test]
    fn chains_of_any_n_give_the_same_bits_on_every_path_and_any_chunking() {
        let n = 4;
        let (th, om) = released(n, 23);
        for chain in chains_of(n) {
            let reference = first_flips_chain(&chain, &th, &om, 400, 0.01, None, (None, None), Path::Portable, &go()).unwrap();
            assert!(reference.iter().any(|t| t.is_finite() && *t > 0.0) && reference.iter().any(|t| t.is_infinite()));
            for path in Path::ALL.into_iter().filter(|p| p.available()) {
                let got = first_flips_chain(&chain, &th, &om, 400, 0.01, None, (None, None), path, &go()).unwrap();
                assert!(got.iter().zip(&reference).all(|(a, b)| a.to_bits() == b.to_bits()), "{path:?}");
            }
            // A row's time does not depend on its neighbours: each row alone, from its middle on.
            for j in [0, 7, 100, 300] {
                let one =
                    first_flips_chain(&chain, &th[n * j..n * (j + 1)], &om[n * j..n * (j + 1)], 400, 0.01, None, (None, None), Path::best(), &go()).unwrap();
                assert_eq!(one[0].to_bits(), reference[j].to_bits(), "row {j}");
            }
        }
    }

    #[test]
    fn driven_chains_flip_in_lanes_as_on_the_scalar_path_each_row_at_its_own_time() {
        for n in [2, 3] {
            let drive = Builtin::sinusoid(n, vec![4.0; n], (0..n).map(|a| 2.0 + a as f64).collect(), vec![0.3; n], vec![0.5; n]).unwrap();
            let timed = Timed { builtin: drive.clone(), joint: false };
            for chain in chains_of(n) {
                let (th, om) = released(n, 23);
                let fast = first_flips_chain(&chain, &th, &om, 300, 0.01, None, (Some(&timed), None), Path::best(), &go()).unwrap();
                let slow = first_flips_scalar(&chain, &th, &om, 3.0, 0.01, None, &drive, None, &go()).unwrap();
                let undriven = first_flips_chain(&chain, &th, &om, 300, 0.01, None, (None, None), Path::best(), &go()).unwrap();
                assert!(fast.iter().zip(&undriven).filter(|(a, b)| a != b).count() > 100, "the drive changes the flips");
                agree(&fast, &slow, 1.0, 30, &format!("N = {n}, driven"));
                // Lanes are refilled at different times: a row alone is the same bits.
                for path in Path::ALL.into_iter().filter(|p| p.available()) {
                    let got = first_flips_chain(&chain, &th, &om, 300, 0.01, None, (Some(&timed), None), path, &go()).unwrap();
                    assert!(got.iter().zip(&fast).all(|(a, b)| a.to_bits() == b.to_bits()), "{path:?}");
                }
                for j in [3, 200, 528] {
                    let one =
                        first_flips_chain(&chain, &th[n * j..n * (j + 1)], &om[n * j..n * (j + 1)], 300, 0.01, None, (Some(&timed), None), Path::best(), &go())
                            .unwrap();
                    assert_eq!(one[0].to_bits(), fast[j].to_bits(), "row {j}");
                }
            }
        }
    }

    #[test]
    fn a_shaken_pivot_flips_chains_in_lanes_as_on_the_scalar_path_each_row_at_its_own_time() {
        use crate::dynamics::base::Axis;
        // A sinusoid and a cubic table: both evaluated in the lanes.
        let t: Vec<f64> = (0..40).map(|k| 0.1 * k as f64).collect();
        let table = Axis::spline("y", t.clone(), t.iter().map(|t| 0.04 * (9.0 * t).cos()).collect()).unwrap();
        let pivot = Pivot { x: Axis::sinusoid("x", 0.08, 7.0, 0.2, 0.0).unwrap(), y: table };
        for n in [2, 3] {
            // (A chain on a cart has no prescribed pivot motion: `first_flips` refuses it.)
            for chain in chains_of(n).into_iter().filter(|c| c.cart().is_none()) {
                let (th, om) = released(n, 23);
                let fast = first_flips_chain(&chain, &th, &om, 300, 0.01, None, (None, Some(&pivot)), Path::best(), &go()).unwrap();
                let slow = first_flips_scalar(&chain, &th, &om, 3.0, 0.01, None, &Builtin::None, Some(&pivot), &go()).unwrap();
                let still = first_flips_chain(&chain, &th, &om, 300, 0.01, None, (None, None), Path::best(), &go()).unwrap();
                assert!(fast.iter().zip(&still).filter(|(a, b)| a != b).count() > 100, "the pivot changes the flips");
                agree(&fast, &slow, 1.0, 30, &format!("N = {n}, shaken"));
                for path in Path::ALL.into_iter().filter(|p| p.available()) {
                    let got = first_flips_chain(&chain, &th, &om, 300, 0.01, None, (None, Some(&pivot)), path, &go()).unwrap();
                    assert!(got.iter().zip(&fast).all(|(a, b)| a.to_bits() == b.to_bits()), "{path:?}");
                }
                for j in [3, 200, 528] {
                    let one =
                        first_flips_chain(&chain, &th[n * j..n * (j + 1)], &om[n * j..n * (j + 1)], 300, 0.01, None, (None, Some(&pivot)), Path::best(), &go())
                            .unwrap();
                    assert_eq!(one[0].to_bits(), fast[j].to_bits(), "row {j}");
                }
            }
        }
    }

    #[test]
    fn a_chain_that_blows_up_is_an_integration_error_with_its_time() {
        let chain = &chains_of(3)[0];
        let e = first_flips_chain(chain, &[0.1; 6], &[0.0, 0.0, 0.0, 1e200, 0.0, 0.0], 100, 0.01, None, (None, None), Path::best(), &go()).unwrap_err();
        // Named as the scalar route names a blow-up, not as a singular mass matrix.
        assert!(matches!(&e, Error::Integration { reason, .. } if reason == &format!("trajectory 1: {NON_FINITE}")), "{e}");
    }

    /// The reason of an integration error.
    fn reason(e: Error) -> String {
        match e {
            Error::Integration { reason, .. } => reason,
            other => panic!("{other}"),
        }
    }

    #[test]
    fn a_blow_up_is_an_integration_error_not_a_silent_value() {
        let chain = Chain::new(&[1.0, 1.0], &[1.0, 1.0], None, None, 9.81).unwrap();
        let e = first_flips_double(&chain, &[0.1, 0.1, 0.2, 0.2], &[0.0, 0.0, 1e200, 0.0], 100, 0.01, None, Path::best(), &go()).unwrap_err();
        assert_eq!(reason(e), format!("trajectory 1: {NON_FINITE}"));
    }

    #[test]
    fn a_blow_up_names_its_row_in_any_chunk_on_every_path_and_as_the_scalar_route() {
        // The row that blows up sits in the second chunk of rows (each path splits the rows
        // into chunks for the threads and names the row by its index in the whole batch).
        let row = CHUNK + 3;
        for n in [2, 3] {
            let chain = &chains_of(n)[0];
            let rows = CHUNK + 8;
            let th = vec![0.1; n * rows];
            let mut om = vec![0.0; n * rows];
            om[n * row] = 1e200;
            let want = format!("trajectory {row}: {NON_FINITE}");
            let scalar = first_flips_scalar(chain, &th, &om, 1.0, 0.01, None, &Builtin::None, None, &go()).unwrap_err();
            assert_eq!(reason(scalar), want, "N = {n}, scalar");
            for path in Path::ALL.into_iter().filter(|p| p.available()) {
                let lanes = first_flips_chain(chain, &th, &om, 100, 0.01, None, (None, None), path, &go()).unwrap_err();
                assert_eq!(reason(lanes), want, "N = {n}, lanes on {}", path.name());
                if n == 2 {
                    let kernel = first_flips_double(chain, &th, &om, 100, 0.01, None, path, &go()).unwrap_err();
                    assert_eq!(reason(kernel), want, "the kernel on {}", path.name());
                }
            }
        }
    }
}
