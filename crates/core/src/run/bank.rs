//! A bank of chains stepped with rk4 in SIMD lanes, their joint torques (and a cart's force) held
//! over each call: the route [`super::live::Steppers`] takes for a chain on a fixed pivot or on a
//! cart (damping and friction included) on rk4's Lagrangian form. Copies go eight to a group of lanes; the groups run in
//! parallel. The step is [`crate::integrators::lanes::Rk4Lanes`]'s, its product-sums fused as
//! the flip kernel's, so a copy agrees with its per-copy [`super::live::Stepper`] to round-off (the lanes' own `sin`/`cos`, the fused operations); each
//! copy's bits depend neither on the other copies nor on the number of threads, and are the same
//! on the AVX-512, AVX2 and portable builds.
//!
//! The torques' work is `tau . (theta_end - theta_start)` per call: exact for a torque held
//! constant, and what rk4 gives the work integral `int tau . omega dt` in exact arithmetic.
use super::energy::EnergyBalance;
use super::live::observe_on;
use super::simulate::Settings;
use super::task::Task;
use crate::dynamics::lanes::energies_on;
use crate::dynamics::system::NON_FINITE;
use crate::error::{Error, Result};
use crate::integrators::lanes::{failed_at, step_cart_pair, Rk4Lanes, Stepped};
use crate::model::Chain;
use crate::par::each_shared;
use crate::trig::lanes::{on_path, Lane, Path, LANES};

/// The environment variable that picks the route of the steppers: `auto` (the lanes
/// on the best path), `scalar` (one [`super::live::Stepper`] per copy), or a lane path by name.
pub const SWITCH: &str = "MULTIPENDULUM_LANES";

/// The lanes' path the environment asks for; `None` for the per-copy route.
pub fn requested() -> Result<Option<Path>> {
    Path::requested(SWITCH, &[])
}

/// Whether a chain and settings take the lanes: a chain on a fixed pivot or on a cart (damping
/// and friction allowed; the cart's force held by the steppers), rk4, Lagrangian.
pub fn fits(_chain: &Chain, settings: &Settings) -> bool {
    settings.drive.pivot.is_none()
        && settings.drive.force.is_none()
        && settings.method == crate::integrators::Method::Rk4
        && matches!(settings.resolved_form(), Ok(crate::dynamics::system::Form::Lagrangian))
}

/// Eight copies' lanes and the rk4 buffers.
#[derive(Debug, Clone)]
struct Group {
    /// `[theta (N), omega (N)]`, then a cart's `x, v`, then (with a cart or joint losses) the
    /// work of the losses `W = -D`; each a lane.
    y: Vec<Lane>,
    tau: Vec<Lane>,
    /// The cart's force, held.
    force: Lane,
    /// The angles (and the cart's position) at the start of a call, for the inputs' work.
    start: Vec<Lane>,
    rk: Rk4Lanes,
}

/// Where a group's lanes keep what: the state row's length (`theta, omega`, a cart's `x, v`),
/// and the losses' work lane if any.
fn layout(chain: &Chain) -> (usize, Option<usize>) {
    let row = chain.state_len();
    (row, (chain.cart().is_some() || chain.lossy_joints()).then_some(row))
}

/// What a copy keeps besides its lane.
#[derive(Debug, Clone)]
struct Copy {
    steps: u64,
    work: f64,
    balance: EnergyBalance,
    failed: Option<Error>,
}

pub struct Bank {
    chain: Chain,
    dt: f64,
    path: Path,
    count: usize,
    groups: Vec<Group>,
    copies: Vec<Copy>,
}

impl Bank {
    /// `count` copies hanging at rest; `dt` the rk4 step (checked by the caller).
    pub fn new(chain: &Chain, count: usize, dt: f64, path: Path) -> Self {
        let n = chain.n();
        let lanes = |k| vec![[0.0; LANES]; k];
        let (row, work) = layout(chain);
        let m = row + usize::from(work.is_some());
        let group = Group { y: lanes(m), tau: lanes(n), force: [0.0; LANES], start: lanes(n + 1), rk: Rk4Lanes::with_dim(n, m) };
        let groups = vec![group; count.div_ceil(LANES)];
        let mut bank = Bank { chain: chain.clone(), dt, path, count, groups, copies: Vec::with_capacity(count) };
        let rest = vec![0.0; n];
        for i in 0..count {
            bank.copies.push(Copy { steps: 0, work: 0.0, balance: EnergyBalance::from_energy(chain, 0.0, 0.0), failed: None });
            bank.reset(i, &rest, &rest, [0.0; 2]);
        }
        bank
    }

    pub fn chain(&self) -> &Chain {
        &self.chain
    }

    pub fn path(&self) -> Path {
        self.path
    }

    /// Copy `i` anew at t = 0 from `(theta0, omega0)` and a cart's `(x, v)` (checked by the
    /// caller).
    pub fn reset(&mut self, i: usize, theta0: &[f64], omega0: &[f64], cart0: [f64; 2]) {
        let n = self.chain.n();
        let (row, work) = layout(&self.chain);
        let (g, lane) = (&mut self.groups[i / LANES], i % LANES);
        for a in 0..n {
            g.y[a][lane] = theta0[a];
            g.y[n + a][lane] = omega0[a];
        }
        if row > 2 * n {
            (g.y[2 * n][lane], g.y[2 * n + 1][lane]) = (cart0[0], cart0[1]);
        }
        if let Some(w) = work {
            g.y[w][lane] = 0.0;
        }
        // The energies as the reports compute them (in lanes), so a copy's balance starts at 0.
        let (mut kinetic, mut energy) = ([0.0; LANES], [0.0; LANES]);
        energies_on(&self.chain, &g.y[..n], &g.y[n..2 * n], (row > 2 * n).then(|| &g.y[2 * n + 1]), &mut kinetic, &mut energy);
        let (kinetic, energy) = (kinetic[lane], energy[lane]);
        self.copies[i] = Copy { steps: 0, work: 0.0, balance: EnergyBalance::from_energy(&self.chain, kinetic, energy), failed: None };
    }

    /// Hold joint torques `u` (count x N) and a cart's forces `forces` (count values; empty
    /// without a cart) and advance every active copy by the whole steps of its grid
    /// `t_k = k dt` up to `t + span` (as [`super::driver::Run`] counts them); then every copy
    /// writes its state `(theta, omega, [x, v])` and `(t, energy, energy_error)`. The first copy
    /// (by index) that fails names itself; it stays failed until reset.
    /// `task`: with it, every copy also writes its observation, reward and end ([`Task`]'s, into
    /// the three slices), each group's in the same parallel pass as its steps.
    #[allow(clippy::too_many_arguments, clippy::type_complexity)]
    pub fn step(
        &mut self,
        u: &[f64],
        forces: &[f64],
        span: f64,
        active: &[bool],
        states: &mut [f64],
        balance: &mut [f64],
        task: Option<(&Task, &mut [f64], &mut [f64], &mut [bool])>,
    ) -> Result<()> {
        let (chain, dt, path) = (&self.chain, self.dt, self.path);
        let (n, (row, _)) = (chain.n(), layout(chain));
        let (task, mut outcomes) = match task {
            Some((task, obs, reward, ended)) => {
                let width = task.columns.len();
                let chunks = obs.chunks_mut(LANES * width).zip(reward.chunks_mut(LANES)).zip(ended.chunks_mut(LANES));
                (Some(task), chunks.map(|((o, r), e)| Some((o, r, e))).collect())
            }
            None => (None, Vec::new()),
        };
        outcomes.resize_with(self.groups.len(), || None);
        let mut shares: Vec<Share> = self
            .groups
            .iter_mut()
            .zip(self.copies.chunks_mut(LANES))
            .zip(u.chunks(LANES * n))
            .zip(states.chunks_mut(LANES * row))
            .zip(balance.chunks_mut(LANES * 3))
            .zip(outcomes)
            .enumerate()
            .map(|(gi, (((((g, copies), u), states), balance), outcome))| {
                let base = gi * LANES;
                for j in 0..copies.len() {
                    g.force[j] = forces.get(base + j).copied().unwrap_or(0.0);
                }
                Share { g, copies, u, states, balance, base, outcome }
            })
            .collect();
        let run = |shares: &mut [Share]| {
            let failed = run_groups(path, chain, dt, shares, span, active);
            for s in shares.iter_mut() {
                report_on(path, chain, dt, s.g, s.copies, s.states, s.balance);
                if let (Some(task), Some((obs, reward, ended))) = (task, &mut s.outcome) {
                    observe_on(path, s.states, row, &task.columns, obs);
                    task.outcome(chain, s.states, reward, ended);
                }
            }
            failed
        };
        // Groups go two at a time side by side ([`step_cart_pair`]) when every thread still
        // gets a pair; one group runs here: the pool's hand-over would cost more than its steps.
        let width = if shares.len() >= 2 * crate::par::threads() { 2 } else { 1 };
        let failed: Option<(usize, Error)> = if shares.len() <= width {
            run(&mut shares)
        } else {
            let items: Vec<&mut [Share]> = shares.chunks_mut(width).collect();
            each_shared(items, run).into_iter().flatten().min_by_key(|(i, _)| *i)
        };
        match failed {
            None => Ok(()),
            Some((i, Error::Integration { t, reason })) => Err(Error::integration(t, format!("copy {i}: {reason}"))),
            Some((_, e)) => Err(e),
        }
    }

    /// Every copy's state (count x (2N, and 2 more with a cart)) and balance (count x 3).
    pub fn report_into(&mut self, states: &mut [f64], balance: &mut [f64]) {
        let (chain, dt, path, (row, _)) = (&self.chain, self.dt, self.path, layout(&self.chain));
        for (((g, copies), s), b) in
            self.groups.iter_mut().zip(self.copies.chunks_mut(LANES)).zip(states.chunks_mut(LANES * row)).zip(balance.chunks_mut(LANES * 3))
        {
            report_on(path, chain, dt, g, copies, s, b);
        }
    }

    pub fn len(&self) -> usize {
        self.count
    }

    pub fn is_empty(&self) -> bool {
        self.count == 0
    }
}

on_path! {
    /// [`report`] on the chosen path: its energies' product-sums are `mul_add`s, a hardware FMA
    /// inside the path's `#[target_feature]` (the same correctly rounded value as the baseline
    /// build's call to `fma()`, which cost this report as much as two of the group's rk4 steps).
    fn report_on(chain: &Chain, dt: f64, g: &mut Group, copies: &mut [Copy], states: &mut [f64], balance: &mut [f64]) {
        report(chain, dt, g, copies, states, balance)
    }
}

/// Each copy of the group: its state row and `(t, energy, energy_error)` (the energies in lanes).
#[inline(always)]
fn report(chain: &Chain, dt: f64, g: &mut Group, copies: &mut [Copy], states: &mut [f64], balance: &mut [f64]) {
    let (n, (len, work)) = (chain.n(), layout(chain));
    let (mut kinetic, mut energy) = ([0.0; LANES], [0.0; LANES]);
    energies_on(chain, &g.y[..n], &g.y[n..2 * n], (len > 2 * n).then(|| &g.y[2 * n + 1]), &mut kinetic, &mut energy);
    for (j, c) in copies.iter_mut().enumerate() {
        let row = &mut states[len * j..len * (j + 1)];
        for (m, v) in row.iter_mut().enumerate() {
            *v = g.y[m][j];
        }
        let b = &mut balance[3 * j..3 * j + 3];
        b[0] = c.steps as f64 * dt;
        b[1] = energy[j];
        // The inputs' work and, with losses, theirs (its lane).
        let losses = work.map_or(0.0, |w| g.y[w][j]);
        b[2] = c.balance.observe(kinetic[j], energy[j], c.work + losses);
    }
}

/// One group's share of a call: its lanes and copies, their inputs (`u`: the joints' torques,
/// N per copy) and outputs, and the index of its first copy.
struct Share<'a> {
    g: &'a mut Group,
    copies: &'a mut [Copy],
    u: &'a [f64],
    states: &'a mut [f64],
    balance: &'a mut [f64],
    base: usize,
    /// The group's observations, rewards and ends, when a task asks for them.
    outcome: Option<(&'a mut [f64], &'a mut [f64], &'a mut [bool])>,
}

on_path! {
    /// The steps of one group or of two side by side, on the chosen path; the first failed copy
    /// (by index) of any of them.
    fn run_groups(chain: &Chain, dt: f64, shares: &mut [Share], span: f64, active: &[bool]) -> Option<(usize, Error)> {
        run_groups_body(chain, dt, shares, span, active)
    }
}

#[inline(always)]
fn run_groups_body(chain: &Chain, dt: f64, shares: &mut [Share], span: f64, active: &[bool]) -> Option<(usize, Error)> {
    // Loops, not closures: a closure's body would compile outside the target features.
    if let [a, b] = shares {
        let [fa, fb] = run_body::<2>([a, b], chain, dt, span, active);
        return fa.or(fb);
    }
    let mut first = None;
    for s in shares.iter_mut() {
        let [f] = run_body::<1>([s], chain, dt, span, active);
        first = first.or(f);
    }
    first
}

/// Whether copy `i` takes this call's steps (`active` empty: every copy).
fn wanted(active: &[bool], i: usize) -> bool {
    active.get(i).copied().unwrap_or(true)
}

/// The steps of `P` groups; each one's first failed copy (its index).
#[inline(always)]
fn run_body<const P: usize>(mut shares: [&mut Share; P], chain: &Chain, dt: f64, span: f64, active: &[bool]) -> [Option<(usize, Error)>; P] {
    let n = chain.n();
    let cart = chain.cart().is_some();
    let mut todo = [[0u64; LANES]; P];
    let mut first_failure: [Option<(usize, Error)>; P] = std::array::from_fn(|_| None);
    for (p, s) in shares.iter_mut().enumerate() {
        let on = |j: usize| wanted(active, s.base + j);
        let (g, u) = (&mut *s.g, s.u);
        // Each copy's number of grid steps this call, and its generalized torques (joint motors).
        for (j, c) in s.copies.iter().enumerate() {
            if !on(j) || c.failed.is_some() {
                continue;
            }
            let target = c.steps as f64 * dt + span;
            let mut k = c.steps;
            while ((k + 1) as f64 * dt) <= target + 1e-9 * dt {
                k += 1;
            }
            todo[p][j] = k - c.steps;
            for a in 0..n {
                let next = if a + 1 < n { u[n * j + a + 1] } else { 0.0 };
                g.tau[a][j] = u[n * j + a] - next;
            }
        }
        for a in 0..n {
            g.start[a] = g.y[a];
        }
        if cart {
            g.start[n] = g.y[2 * n];
        }
    }
    let rounds = todo.iter().flatten().copied().max().unwrap_or(0);
    let fail = |j: usize, t: f64, reason: String, first: &mut Option<(usize, Error)>, copies: &mut [Copy]| {
        let e = Error::integration(t, reason);
        copies[j].failed = Some(e.clone());
        if first.as_ref().map_or(true, |(k, _)| j < *k) {
            *first = Some((j, e));
        }
    };
    // The lanes still stepping (`r < todo`), worked out again only at the rounds where a copy's
    // steps run out or after a failure: the rounds between take them as they are.
    let mut going = [[0.0; LANES]; P];
    let mut fresh_until = 0;
    for r in 0..rounds {
        // A lane whose mass matrix fails stops at its last good state; the step is then taken
        // again by the others (a group that has taken it sits out, all its lanes inactive).
        let mut pending = [true; P];
        loop {
            if r >= fresh_until {
                fresh_until = u64::MAX;
                for p in 0..P {
                    for j in 0..shares[p].copies.len() {
                        let on = r < todo[p][j];
                        going[p][j] = if on { 1.0 } else { 0.0 };
                        if on {
                            fresh_until = fresh_until.min(todo[p][j]);
                        }
                    }
                }
            }
            let mut on = [[0.0; LANES]; P];
            for p in 0..P {
                if pending[p] {
                    on[p] = going[p];
                    pending[p] = going[p].iter().any(|&a| a > 0.0);
                }
            }
            if !pending.iter().any(|&p| p) {
                break;
            }
            // Loops, not `array::from_fn`: a closure's body would compile outside the callers'
            // target features, each `mul_add` a call to `fma()`.
            let mut stepped: [Stepped; P] = [Ok([false; LANES]); P];
            match &mut shares[..] {
                [a, b] => {
                    let (a, b) = (&mut *a.g, &mut *b.g);
                    let two = step_cart_pair([&mut a.rk, &mut b.rk], chain, [&mut a.y, &mut b.y], [&a.tau, &b.tau], [&a.force, &b.force], dt, [&on[0], &on[1]]);
                    stepped[..2].copy_from_slice(&two);
                }
                _ => {
                    for p in 0..P {
                        let g = &mut *shares[p].g;
                        if pending[p] {
                            stepped[p] = g.rk.step_cart(chain, &mut g.y, &g.tau, &g.force, dt, &on[p]);
                        }
                    }
                }
            }
            for (p, stepped) in stepped.into_iter().enumerate() {
                if !pending[p] {
                    continue;
                }
                let copies = &mut *shares[p].copies;
                match stepped {
                    Ok(nonfinite) => {
                        if nonfinite.iter().any(|&b| b) {
                            for j in 0..copies.len() {
                                if nonfinite[j] {
                                    fail(j, (copies[j].steps + r + 1) as f64 * dt, NON_FINITE.to_string(), &mut first_failure[p], copies);
                                    todo[p][j] = r;
                                }
                            }
                            fresh_until = 0;
                        }
                        pending[p] = false;
                    }
                    Err((stage, bad)) => {
                        for j in 0..copies.len() {
                            if bad.lanes[j] {
                                let t = failed_at(&bad, j, stage, (copies[j].steps + r) as f64 * dt, dt);
                                fail(j, t, bad.reason(j), &mut first_failure[p], copies);
                                todo[p][j] = r;
                            }
                        }
                        fresh_until = 0;
                    }
                }
            }
        }
    }
    for (p, s) in shares.iter_mut().enumerate() {
        let on = |j: usize| wanted(active, s.base + j);
        let g = &mut *s.g;
        for (j, c) in s.copies.iter_mut().enumerate() {
            if todo[p][j] == 0 {
                if let Some(e) = &c.failed {
                    if on(j) {
                        first_failure[p].get_or_insert((j, e.clone()));
                    }
                }
                continue;
            }
            c.steps += todo[p][j];
            c.work += (0..n).map(|a| g.tau[a][j] * (g.y[a][j] - g.start[a][j])).sum::<f64>();
            if cart {
                // The held force's work, F (x_end - x_start): what rk4 gives its integral.
                c.work += g.force[j] * (g.y[2 * n][j] - g.start[n][j]);
            }
        }
    }
    std::array::from_fn(|p| first_failure[p].take().map(|(j, e)| (shares[p].base + j, e)))
}
