//! [`Rk4`](super::Rk4) in SIMD lanes: eight states of one chain (losses, a cart and a built-in
//! torque included: [`ChainLanes`]; or any other [`LaneSystem`], such as the tangent equations)
//! stepped at once on [`crate::dynamics::lanes`]' accelerations, the step's product-sums fused by
//! explicit `mul_add` as the flip kernel's (one correctly rounded operation on every path, so the
//! AVX-512, AVX2 and portable builds give the same bits, and a lane's bits never depend on the
//! other lanes). Used by the steppers' bank (`run::bank`), the flip times of chains other than the
//! double pendulum (`chaos::flipkernel`), ensembles and chaos indicators; each compiles it inside
//! its `#[target_feature]` wrappers.
use crate::dynamics::base::Pivot;
use crate::dynamics::lanes::{accelerations, accelerations_on, add_losses, add_pivot_forces_from, CartLanes, LaneScratch, LaneSingular};
use crate::dynamics::torque::Timed;
use crate::model::Chain;
use crate::trig::lanes::{copy_lanes, each, Lane, LANES};
use std::ops::Index;

/// A system of lanes built on a chain's accelerations. A trait rather than a closure: its
/// `#[inline(always)]` method is compiled inside the caller's `#[target_feature]` wrapper, where
/// a closure's body would be a function of its own on the baseline target (no FMA: `mul_add`
/// becomes a call to `fma()`).
pub trait LaneSystem {
    /// The rates at the stage's state `y` and times `at` (one per lane) into `dy`, with `scratch`
    /// for the accelerations. Every lane is computed; only the `active` ones (`> 0`) are checked
    /// (an inactive lane's rates may be anything, and stay in its own lane).
    fn rates(&mut self, at: &Lane, y: &[Lane], dy: &mut [Lane], scratch: &mut LaneScratch, active: &Lane) -> std::result::Result<(), LaneSingular>;

    /// Whether the rates read the stage's times `at` (the steppers compute them only then; a
    /// system that does not may get any times).
    fn timed(&self) -> bool {
        true
    }
}

/// A chain's own equations in lanes under generalized torques `tau` held over the step, or
/// `drive`'s torques of time at each stage's times instead: `y = [theta (N), omega (N)]`, then the
/// cart's `[x, v]` under `force` (less its damping) on a chain with a cart, then the drive's work
/// (`int tau . omega dt`) with a drive, then the pivot's work with `pivot_work`, then, if `y` has
/// room for it, the work `W` of the joints' losses and the cart's damping (`W' = -P`, the power
/// they take), which a lossy chain feels at every stage.
pub struct ChainLanes<'a> {
    pub chain: &'a Chain,
    pub tau: &'a [Lane],
    /// Torques of time, in place of `tau`.
    pub drive: Option<&'a Timed>,
    /// The force on the cart (unused without one).
    pub force: &'a Lane,
    /// A moving pivot (one the lanes can evaluate: [`Pivot::in_lanes`]), its acceleration at
    /// each stage's times: the generalized forces `-h_a (a_x cos theta_a + a_y sin theta_a)`.
    pub pivot: Option<&'a Pivot>,
    /// Whether `y` carries the work of the pivot's forces, `-int a_p . R_dot dt` (the run
    /// driver's pivot slot, [`crate::dynamics::system::Layout::pivot_work`]), after the drive's.
    pub pivot_work: bool,
    /// The generalized forces with the losses (`N` lanes of scratch).
    pub q: &'a mut [Lane],
}

impl LaneSystem for ChainLanes<'_> {
    #[inline(always)]
    fn timed(&self) -> bool {
        self.drive.is_some() || self.pivot.is_some()
    }

    #[inline(always)]
    fn rates(&mut self, at: &Lane, y: &[Lane], dy: &mut [Lane], scratch: &mut LaneScratch, active: &Lane) -> std::result::Result<(), LaneSingular> {
        let chain = self.chain;
        let n = chain.n();
        let (theta, omega) = (&y[..n], &y[n..2 * n]);
        let (cart, lossy) = (chain.cart(), chain.lossy_joints());
        let (head, tail) = dy.split_at_mut(n);
        copy_lanes(head, omega);
        if self.drive.is_none() && !lossy && cart.is_none() && self.pivot.is_none() {
            return accelerations(chain, theta, omega, self.tau, tail, scratch, active);
        }
        let mut drive_power = None;
        match self.drive {
            Some(drive) => {
                drive.lanes(at, self.q);
                let mut p = [0.0; LANES];
                for (q, w) in self.q.iter().zip(omega) {
                    for i in 0..LANES {
                        p[i] += q[i] * w[i];
                    }
                }
                drive_power = Some(p);
            }
            None => copy_lanes(self.q, self.tau),
        }
        let mut pivot_power = None;
        if let Some(pivot) = self.pivot {
            let (ax, ay) = pivot.acc_lanes(at);
            // The angles' trig once, for these forces and the accelerations below.
            let trig = scratch.trig_of(theta);
            add_pivot_forces_from(chain, (&ax, &ay), trig, self.q);
            if self.pivot_work {
                pivot_power = Some(pivot_power_of(chain, (&ax, &ay), omega, trig));
            }
        }
        let mut power = [0.0; LANES];
        if lossy {
            add_losses(chain, omega, self.q, &mut power);
        }
        let mut slot = 2 * n;
        match cart {
            None => accelerations(chain, theta, omega, self.q, &mut tail[..n], scratch, active)?,
            Some(cart) => {
                let v = y[2 * n + 1];
                let mut force = [0.0; LANES];
                for i in 0..LANES {
                    force[i] = self.force[i] - cart.damping * v[i];
                    power[i] += cart.damping * v[i] * v[i];
                }
                let (acc, rest) = tail.split_at_mut(n);
                let mut x_ddot = [0.0; LANES];
                accelerations_on(chain, theta, omega, self.q, acc, scratch, active, Some(CartLanes { force: &force, x_ddot: &mut x_ddot }))?;
                rest[0] = v;
                rest[1] = x_ddot;
                slot += 2;
            }
        }
        for p in [drive_power, pivot_power].into_iter().flatten() {
            dy[slot] = p;
            slot += 1;
        }
        if let Some(work) = dy.get_mut(slot) {
            *work = power.map(|p| -p);
        }
        Ok(())
    }
}

/// The power of a moving pivot's forces, `-a_p . R_dot` with `R_dot = sum_a h_a omega_a (cos,
/// sin)(theta_a)` (the driver's pivot slot's rate), from the angles' `sin` and `cos`.
#[inline(always)]
fn pivot_power_of(chain: &Chain, (ax, ay): (&Lane, &Lane), omega: &[Lane], (sin, cos): (&[Lane], &[Lane])) -> Lane {
    let (mut rx, mut ry) = ([0.0; LANES], [0.0; LANES]);
    for (a, w) in omega.iter().enumerate() {
        let (sin, cos, h) = (sin[a], cos[a], chain.h[a]);
        for i in 0..LANES {
            let hw = h * w[i];
            rx[i] += hw * cos[i];
            ry[i] += hw * sin[i];
        }
    }
    // A loop, not `each`'s closure, which LLVM outlined here: on the baseline target, its
    // `mul_add` a call to `fma()`.
    let mut p = [0.0; LANES];
    for i in 0..LANES {
        p[i] = -ax[i].mul_add(rx[i], ay[i] * ry[i]);
    }
    p
}

/// When rk4's `stage` of lane `i` failed in the step of size `h` from `t`, as the scalar route
/// reports it: a blow-up (a non-finite stage state) at the step's end, where the driver's check
/// of the new state finds it; a singular configuration at the stage's own time.
pub fn failed_at(bad: &LaneSingular, i: usize, stage: usize, t: f64, h: f64) -> f64 {
    if bad.nonfinite[i] {
        t + h
    } else {
        t + [0.0, 0.5, 0.5, 1.0][stage] * h
    }
}

/// rk4's stage buffers for eight states of an N-link chain, each a lane.
#[derive(Debug, Clone)]
pub struct Rk4Lanes {
    k: [Vec<Lane>; 4],
    tmp: Vec<Lane>,
    scratch: LaneScratch,
    /// The generalized forces with the losses (a lossy chain's).
    q: Vec<Lane>,
}

impl Rk4Lanes {
    pub fn new(n: usize) -> Self {
        Self::with_dim(n, 2 * n)
    }

    /// Buffers for a system of `m` lanes per state built on an N-link chain's accelerations (the
    /// tangent equations: `m = 2N (1 + k)` and more).
    pub fn with_dim(n: usize, m: usize) -> Self {
        let lanes = |k| vec![[0.0; LANES]; k];
        Rk4Lanes { k: std::array::from_fn(|_| lanes(m)), tmp: lanes(m), scratch: LaneScratch::new(n), q: lanes(n) }
    }

    /// One rk4 step of every active lane (`active[i] > 0`) of `y = [theta (N), omega (N)]` under
    /// generalized torques `tau` (held over the step), as `Rk4::step` (stages, then the weighted
    /// sum); the inactive lanes stay as they were. A chain with joint losses feels them at every
    /// stage, and `y` may then carry one more lane, the work the losses have done (`-D`, the
    /// energy dissipated), integrated with the state. `Err((stage, _))` if an active lane's pivot
    /// failed (then no lane moves); else the active lanes whose new state is not finite (they do
    /// not move either).
    #[inline(always)]
    pub fn step(&mut self, chain: &Chain, y: &mut [Lane], tau: &[Lane], dt: f64, active: &Lane) -> Stepped {
        self.step_cart(chain, y, tau, &[0.0; LANES], dt, active)
    }

    /// [`Rk4Lanes::step`] of a chain on a cart: `y = [theta (N), omega (N), x, v, W]` under
    /// joint torques `tau` and the cart force `force` (both held over the step); `W` the work of
    /// the joints' losses and the cart's damping (`-D`).
    #[inline(always)]
    pub fn step_cart(&mut self, chain: &Chain, y: &mut [Lane], tau: &[Lane], force: &Lane, dt: f64, active: &Lane) -> Stepped {
        let mut q = std::mem::take(&mut self.q);
        // The chain's equations do not depend on time: the steps' times are immaterial.
        let out = self.step_system(y, 0.0, dt, active, &mut ChainLanes { chain, tau, drive: None, force, pivot: None, pivot_work: false, q: &mut q });
        self.q = q;
        out
    }

    /// [`Rk4Lanes::step`] of any system built on the chain (see [`LaneSystem`]) from time `t`.
    #[inline(always)]
    pub fn step_system(&mut self, y: &mut [Lane], t: f64, dt: f64, active: &Lane, sys: &mut impl LaneSystem) -> Stepped {
        self.step_system_at(y, &[t; LANES], dt, active, sys)
    }

    /// [`Rk4Lanes::step_system`] from a time of each lane's own.
    #[inline(always)]
    pub fn step_system_at(&mut self, y: &mut [Lane], t: &Lane, dt: f64, active: &Lane, sys: &mut impl LaneSystem) -> Stepped {
        // A system of four or six lanes (the double and triple pendulums, a pendulum on a cart)
        // takes loops of a compile-time length, which LLVM unrolls: the same operations, so the
        // same bits.
        match y.len() {
            4 => return fixed::<4, 1, _>([y], [t], dt, [active], [sys], [self])[0],
            6 => return fixed::<6, 1, _>([y], [t], dt, [active], [sys], [self])[0],
            _ => {}
        }
        let half = 0.5 * dt;
        let Rk4Lanes { k, tmp, scratch, .. } = self;
        // Loops over whole lanes by iterators (no bounds checks), so they vectorise.
        for stage in 0..4 {
            {
                let src: &[Lane] = if stage == 0 { &y[..] } else { &tmp[..] };
                let at = if sys.timed() {
                    each(|i| match stage {
                        0 => t[i],
                        3 => t[i] + dt,
                        _ => t[i] + half,
                    })
                } else {
                    *t
                };
                sys.rates(&at, src, &mut k[stage], scratch, active).map_err(|s| (stage, s.seen_in(src)))?;
            }
            if stage < 3 {
                let h = if stage < 2 { half } else { dt };
                for ((t, yv), kv) in tmp.iter_mut().zip(y.iter()).zip(k[stage].iter()) {
                    for i in 0..LANES {
                        t[i] = h.mul_add(kv[i], yv[i]);
                    }
                }
            }
        }
        let sixth = dt / 6.0;
        // `x * 0` is 0 for a finite x and NaN otherwise: the lanes' finiteness without branches.
        let mut poison = [0.0; LANES];
        let [k1, k2, k3, k4] = &*k;
        for (((((t, yv), a), b), c), d) in tmp.iter_mut().zip(y.iter()).zip(k1.iter()).zip(k2.iter()).zip(k3.iter()).zip(k4.iter()) {
            for i in 0..LANES {
                t[i] = sixth.mul_add(2.0f64.mul_add(b[i] + c[i], a[i]) + d[i], yv[i]);
                poison[i] += t[i] * 0.0;
            }
        }
        let (mut keep, mut nonfinite) = ([false; LANES], [false; LANES]);
        for i in 0..LANES {
            let finite = poison[i] == 0.0;
            keep[i] = active[i] > 0.0 && finite;
            nonfinite[i] = active[i] > 0.0 && !finite;
        }
        for (yv, t) in y.iter_mut().zip(tmp.iter()) {
            for i in 0..LANES {
                yv[i] = if keep[i] { t[i] } else { yv[i] };
            }
        }
        Ok(nonfinite)
    }
}

/// What one rk4 step of a group of lanes gives: the active lanes whose new state is not finite,
/// or the stage at which an active lane's pivot failed (then no lane moved).
pub type Stepped = std::result::Result<[bool; LANES], (usize, LaneSingular)>;

/// [`Rk4Lanes::step_cart`] of two groups of lanes of the same chain side by side: each stage
/// computes the one group's rates and then the other's, whose independent arithmetic fills the
/// wait on the first's divisions and `sin`/`cos` (the double pendulum's flip kernel does the
/// same with its two groups). Each group's lanes take the same operations as alone: the same
/// bits. Systems of more than six lanes step one group after the other.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub fn step_cart_pair(
    rk: [&mut Rk4Lanes; 2],
    chain: &Chain,
    y: [&mut [Lane]; 2],
    tau: [&[Lane]; 2],
    force: [&Lane; 2],
    dt: f64,
    active: [&Lane; 2],
) -> [Stepped; 2] {
    let [a, b] = rk;
    let (mut qa, mut qb) = (std::mem::take(&mut a.q), std::mem::take(&mut b.q));
    let sys = |tau, force, q| ChainLanes { chain, tau, drive: None, force, pivot: None, pivot_work: false, q };
    let (mut sa, mut sb) = (sys(tau[0], force[0], &mut qa), sys(tau[1], force[1], &mut qb));
    let t = &[0.0; LANES];
    let out = step_system_pair([&mut *a, &mut *b], y, [t, t], dt, active, [&mut sa, &mut sb]);
    (a.q, b.q) = (qa, qb);
    out
}

/// [`Rk4Lanes::step_system_at`] of two groups of lanes of one kind of system side by side (as
/// [`step_cart_pair`]): systems of four or six lanes in fixed-size arrays, each group's lanes
/// taking the same operations as alone (the same bits); larger ones one group after the other.
#[inline(always)]
pub fn step_system_pair<S: LaneSystem>(
    rk: [&mut Rk4Lanes; 2],
    y: [&mut [Lane]; 2],
    t: [&Lane; 2],
    dt: f64,
    active: [&Lane; 2],
    sys: [&mut S; 2],
) -> [Stepped; 2] {
    let ([a, b], [ya, yb], [sa, sb]) = (rk, y, sys);
    match ya.len() {
        4 => fixed::<4, 2, _>([ya, yb], t, dt, active, [sa, sb], [a, b]),
        6 => fixed::<6, 2, _>([ya, yb], t, dt, active, [sa, sb], [a, b]),
        _ => [a.step_system_at(ya, t[0], dt, active[0], sa), b.step_system_at(yb, t[1], dt, active[1], sb)],
    }
}

/// [`Rk4Lanes::step_system_at`] of `P` groups of a system of `M` lanes, side by side, in each
/// group's own buffers (its stages and stage state; nothing zeroed per step, each update
/// computed in a local array and stored whole) with
/// loops of the compile-time length `M`: for each group, operation for operation the same step
/// as alone. A group whose rates fail at a stage stops there (its state unchanged); the others
/// go on.
#[inline(always)]
fn fixed<const M: usize, const P: usize, S: LaneSystem>(
    y: [&mut [Lane]; P],
    t: [&Lane; P],
    dt: f64,
    active: [&Lane; P],
    sys: [&mut S; P],
    rk: [&mut Rk4Lanes; P],
) -> [Stepped; P] {
    let half = 0.5 * dt;
    let mut failed: [Option<(usize, LaneSingular)>; P] = [None; P];
    for stage in 0..4 {
        for p in 0..P {
            if failed[p].is_some() {
                continue;
            }
            // The stage's times only for a system that reads them (a loop of scalar additions
            // otherwise spent on nothing).
            let at = if sys[p].timed() {
                each(|i| match stage {
                    0 => t[p][i],
                    3 => t[p][i] + dt,
                    _ => t[p][i] + half,
                })
            } else {
                *t[p]
            };
            let Rk4Lanes { k, tmp, scratch, .. } = &mut *rk[p];
            let src: &[Lane] = if stage == 0 { &y[p][..M] } else { &tmp[..M] };
            if let Err(s) = sys[p].rates(&at, src, &mut k[stage][..M], scratch, active[p]) {
                failed[p] = Some((stage, s.seen_in(src)));
            }
        }
        if stage < 3 {
            let h = if stage < 2 { half } else { dt };
            for p in 0..P {
                let Rk4Lanes { k, tmp, .. } = &mut *rk[p];
                // Into a local, copied out after: LLVM cannot tell the buffers apart, and with
                // stores into one between loads from the others it kept every lane a scalar
                // operation.
                let next = if M <= IN_REGISTERS {
                    stage_state::<M, _>(h, &fixed_of::<M>(&k[stage]), &fixed_of::<M>(y[p]))
                } else {
                    stage_state::<M, _>(h, &k[stage][..M], &y[p][..M])
                };
                tmp[..M].copy_from_slice(&next);
            }
        }
    }
    let sixth = dt / 6.0;
    // Loops, not `array::from_fn`: a closure's body would compile outside the callers' target
    // features, each `mul_add` a call to `fma()`.
    let mut out: [Stepped; P] = [Ok([false; LANES]); P];
    for p in 0..P {
        if let Some(f) = failed[p] {
            out[p] = Err(f);
            continue;
        }
        let k = &rk[p].k;
        let mut poison = [0.0; LANES];
        // Lanes that are inactive or went non-finite keep their state.
        let nonfinite = if M <= IN_REGISTERS {
            let y0 = fixed_of::<M>(y[p]);
            let [k1, k2, k3, k4] = [fixed_of::<M>(&k[0]), fixed_of::<M>(&k[1]), fixed_of::<M>(&k[2]), fixed_of::<M>(&k[3])];
            let mut next = weighted_sum::<M, _>(sixth, [&k1, &k2, &k3, &k4], &y0);
            // A pass of its own: inside the sum, LLVM vectorised it across the state's
            // components (two lanes at a time) instead of the lanes.
            for v in &next {
                for i in 0..LANES {
                    poison[i] += v[i] * 0.0;
                }
            }
            let (keep, nonfinite) = verdicts(active[p], &poison);
            for m in 0..M {
                for i in 0..LANES {
                    next[m][i] = if keep[i] > 0.0 { next[m][i] } else { y0[m][i] };
                }
            }
            y[p][..M].copy_from_slice(&next);
            nonfinite
        } else {
            // Straight from the buffers, the sum of `v * 0` row by row (as a pass of its own it
            // compiled to scalar operations here).
            let (k1, k2, k3, k4, y0) = (&k[0][..M], &k[1][..M], &k[2][..M], &k[3][..M], &y[p][..M]);
            let mut next = [[0.0; LANES]; M];
            for m in 0..M {
                let mut row = [0.0; LANES];
                for i in 0..LANES {
                    row[i] = sixth.mul_add(2.0f64.mul_add(k2[m][i] + k3[m][i], k1[m][i]) + k4[m][i], y0[m][i]);
                }
                for i in 0..LANES {
                    poison[i] += row[i] * 0.0;
                }
                next[m] = row;
            }
            let (keep, nonfinite) = verdicts(active[p], &poison);
            let state = &mut y[p][..M];
            for m in 0..M {
                for i in 0..LANES {
                    state[m][i] = if keep[i] > 0.0 { next[m][i] } else { state[m][i] };
                }
            }
            nonfinite
        };
        out[p] = Ok(nonfinite);
    }
    out
}

/// The largest state (components of [`Lane`]) whose rk4 sums take their operands by value,
/// copied out of the buffers: LLVM then keeps them in registers and interleaves two groups'
/// sums (the double pendulum's four components; measured). Larger states take them straight
/// from the buffers: their copies went through the stack (the triple pendulum's six: thirty
/// vector loads and stores a step).
const IN_REGISTERS: usize = 4;

/// The first `M` lanes of `v` by value (a plain function: `array::map`'s closures were a call
/// per step, `try_map`, outside the callers' target features).
#[inline(always)]
fn fixed_of<const M: usize>(v: &[Lane]) -> [Lane; M] {
    v[..M].try_into().expect("M lanes")
}

/// A stage's state `y0 + h k` into a local (LLVM cannot tell the buffers apart: with stores into
/// one between loads from the others it kept every lane a scalar operation).
#[inline(always)]
fn stage_state<const M: usize, A: Index<usize, Output = Lane> + ?Sized>(h: f64, k: &A, y0: &A) -> [Lane; M] {
    let mut next = [[0.0; LANES]; M];
    for m in 0..M {
        for i in 0..LANES {
            next[m][i] = h.mul_add(k[m][i], y0[m][i]);
        }
    }
    next
}

/// rk4's new state `y0 + h/6 (k1 + 2 (k2 + k3) + k4)` (`sixth` = h/6) into a local.
#[inline(always)]
fn weighted_sum<const M: usize, A: Index<usize, Output = Lane> + ?Sized>(sixth: f64, [k1, k2, k3, k4]: [&A; 4], y0: &A) -> [Lane; M] {
    let mut next = [[0.0; LANES]; M];
    for m in 0..M {
        for i in 0..LANES {
            next[m][i] = sixth.mul_add(2.0f64.mul_add(k2[m][i] + k3[m][i], k1[m][i]) + k4[m][i], y0[m][i]);
        }
    }
    next
}

/// Which lanes take their new state (active and finite: `poison`, the sum of `v * 0` over the
/// state, is 0 exactly where every `v` is finite) as 1.0 or 0.0, and which active lanes went
/// non-finite.
#[inline(always)]
fn verdicts(active: &Lane, poison: &Lane) -> (Lane, [bool; LANES]) {
    let (mut keep, mut nonfinite) = ([0.0; LANES], [false; LANES]);
    for i in 0..LANES {
        let (on, finite) = (active[i] > 0.0, poison[i] == 0.0);
        keep[i] = if on & finite { 1.0 } else { 0.0 };
        nonfinite[i] = on & !finite;
    }
    (keep, nonfinite)
}
