//! A run shown as it happens (the browser viewer advances one frame at a time; an environment
//! one action at a time): a [`Run`] of an owned chain, with the energy balance of its frames.
//! It keeps no history. The time grid is the driver's (see [`super::driver`]): the fixed-step
//! methods take whole steps of the grid `t_k = k dt`, so the run is the same however it is cut
//! into pieces, and a target between grid points is reached to within one step; `dop853` lands
//! on each target exactly.
use super::bank::{self, Bank};
use super::driver::Run;
use super::energy::EnergyBalance;
use super::simulate::{fill_rates, initial_state, Books, Settings, Terms};
use super::task::Task;
use crate::dynamics::base::Force;
use crate::dynamics::system::{ChainSystem, Form};
use crate::dynamics::torque::{Builtin, Joint, TorqueSource};
use crate::dynamics::Workspace;
use crate::error::{check_finite, Error, Result, Shown};
use crate::integrators::Method;
use crate::model::Chain;
use crate::par::*;
use crate::trig::lanes::{each, on_path, sin_cos, Lane, Path, LANES};

/// One column of an observation ([`Steppers::observe_into`]): entry `i` of a state row, or its
/// cosine or sine.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Column {
    Value(usize),
    Cos(usize),
    Sin(usize),
}

impl Column {
    pub(crate) fn index(self) -> usize {
        match self {
            Column::Value(i) | Column::Cos(i) | Column::Sin(i) => i,
        }
    }
}

#[inline(always)]
fn observe(states: &[f64], k: usize, columns: &[Column], out: &mut [f64]) {
    let width = columns.len();
    // Each entry's sin and cos once per chunk, for a cosine and a sine of the same angle.
    let mut trig: Vec<Option<(Lane, Lane)>> = vec![None; k];
    for (rows, obs) in states.chunks(LANES * k).zip(out.chunks_mut(LANES * width)) {
        let copies = rows.len() / k;
        trig.iter_mut().for_each(|t| *t = None);
        for (j, &col) in columns.iter().enumerate() {
            let lane = each(|c| if c < copies { rows[c * k + col.index()] } else { 0.0 });
            // No closure (`get_or_insert_with`): its body would compile on the baseline target,
            // outside the callers' target features, and every `mul_add` of `sin_cos` become a
            // call to libm's `fma` (22 us for 256 double pendulums' observations, not 2).
            let value = match col {
                Column::Value(_) => lane,
                Column::Cos(i) | Column::Sin(i) => {
                    if trig[i].is_none() {
                        trig[i] = Some(sin_cos(&lane));
                    }
                    let (sin, cos) = trig[i].unwrap_or_default();
                    if matches!(col, Column::Cos(_)) {
                        cos
                    } else {
                        sin
                    }
                }
            };
            for c in 0..copies {
                obs[c * width + j] = value[c];
            }
        }
    }
}

on_path! {
    /// The observation of state rows of `k` values (checked by the caller), on `path`.
    pub(crate) fn observe_on(states: &[f64], k: usize, columns: &[Column], out: &mut [f64]) {
        observe(states, k, columns, out)
    }
}

/// Where [`Steppers::act`] writes, each count rows: the state rows and balances (as
/// [`Steppers::step`]), the observations, rewards, ends and truncations.
pub struct Acted<'a> {
    pub states: &'a mut [f64],
    pub balance: &'a mut [f64],
    pub obs: &'a mut [f64],
    pub reward: &'a mut [f64],
    pub terminated: &'a mut [bool],
    pub truncated: &'a mut [bool],
}

/// A chain, its current state and its integrator, advanced on request.
pub struct Stepper<T> {
    run: Run<ChainSystem<Chain, T>>,
    form: Form,
    balance: EnergyBalance,
    books: Books,
    ws: Workspace,
    omega: Vec<f64>,
    p: Vec<f64>,
}

impl<T: TorqueSource> Stepper<T> {
    /// Start at t = 0 from `(theta0, omega0)`. `settings.t_eval` and `max_steps` are not used;
    /// `dt` is required by the fixed-step methods and is the first step of `dop853` if given.
    pub fn new(chain: Chain, theta0: &[f64], omega0: &[f64], settings: &Settings, torque: T) -> Result<Self> {
        chain.check_state("theta0", theta0)?;
        chain.check_state("omega0", omega0)?;
        super::simulate::check_cart0(&chain, settings)?;
        // The run has no end; any t_end checks the step and tolerance settings the same way.
        let mut checked = settings.clone();
        checked.t_eval = None;
        checked.validate(f64::MAX)?;
        let form = settings.resolved_form()?;
        let n = chain.n();
        let sys = ChainSystem::new(chain, torque, form).with_drive(settings.drive.clone())?;
        let y = initial_state(sys.chain(), form, sys.layout(), theta0, omega0, settings.cart0);
        let mut books = Books::new(sys.chain(), form, sys.layout());
        let first = books.terms(sys.chain(), sys.drive(), 0.0, &y)?;
        let balance = EnergyBalance::from_energy(sys.chain(), first.kinetic, first.energy);
        let config = crate::run::driver::Config { max_steps: u64::MAX, ..settings.config(None) };
        let run = Run::new(sys, y, &config)?;
        Ok(Stepper { run, form, balance, books, ws: Workspace::new(n), omega: omega0.to_vec(), p: vec![0.0; n] })
    }

    /// Advance towards `t_target`, taking at most `max_steps` accepted steps. Returns `true` once
    /// the target is reached (for fixed-step methods: when one more step would pass it),
    /// `false` if the step budget ran out first. After an error the state is the last good one and
    /// every later call returns the same error.
    pub fn advance(&mut self, t_target: f64, max_steps: u64) -> Result<bool> {
        self.run.advance_to(t_target, max_steps)
    }

    pub fn t(&self) -> f64 {
        self.run.t()
    }
    pub fn n(&self) -> usize {
        self.chain().n()
    }
    pub fn chain(&self) -> &Chain {
        self.run.system().chain()
    }
    pub fn method(&self) -> Method {
        self.run.method()
    }
    pub fn form(&self) -> Form {
        self.form
    }
    /// Accepted steps, rejected attempts (dop853) and right-hand side evaluations so far.
    pub fn counts(&self) -> (u64, u64, u64) {
        let (steps, rejected, evaluations, _) = self.run.counters();
        (steps, rejected, evaluations)
    }
    pub fn theta(&self) -> &[f64] {
        &self.run.y()[..self.n()]
    }

    /// Angular velocities of the current state (solved from `p` in the Hamiltonian form).
    pub fn omega(&mut self) -> &[f64] {
        let Stepper { run, form, ws, omega, p, .. } = self;
        fill_rates(run.system().chain(), *form, run.y(), omega, p, ws);
        &self.omega
    }

    /// The energy terms of the current state: lab-frame kinetic and total energy, the work of
    /// the torques, the pivot and the cart force, the energy dissipated, since t = 0. (The
    /// pivot's own motion is a function of time and cannot fail but through a user function.)
    pub fn terms(&mut self) -> Result<Terms> {
        let Stepper { run, books, .. } = self;
        let (t, sys) = (run.t(), run.system());
        books.terms(sys.chain(), sys.drive(), t, run.y())
    }

    /// Energy (lab frame) of the current state; NaN if a user's pivot function fails.
    pub fn energy(&mut self) -> f64 {
        self.terms().map_or(f64::NAN, |t| t.energy)
    }

    pub fn initial_energy(&self) -> f64 {
        self.balance.initial_energy()
    }

    /// Work done by the torque since t = 0 (zero without one).
    pub fn work(&self) -> f64 {
        self.run.system().layout().torque_work().map_or(0.0, |i| self.run.y()[i])
    }

    /// The cart's position and velocity (zeros without a cart).
    pub fn cart(&mut self) -> (f64, f64) {
        let Some(i) = self.run.system().layout().cart() else { return (0.0, 0.0) };
        let x = self.run.y()[i];
        (x, self.terms().map_or(f64::NAN, |t| t.cart_v))
    }

    /// The pivot's position now (the origin when it is fixed).
    pub fn pivot(&self) -> [f64; 2] {
        self.run.system().pivot_motion(self.t()).map_or([f64::NAN; 2], |m| m.pos)
    }

    /// The pivot's position, velocity and acceleration now (zeros when it is fixed).
    pub fn pivot_motion(&self) -> Result<crate::dynamics::base::Motion> {
        self.run.system().pivot_motion(self.t())
    }

    /// The drive the run has now (to restore after a [`Stepper::set_drive`]).
    pub fn drive(&self) -> &crate::dynamics::base::Drive {
        self.run.system().drive()
    }

    /// Replace the base's drive between steps (the viewer's dragged pivot, an environment's
    /// cart force); the integrator restarts from the current state.
    /// The energy balance stays exact when the new drive continues the old one's position and
    /// velocity at the switch.
    pub fn set_drive(&mut self, drive: crate::dynamics::base::Drive) -> Result<()> {
        self.run.system_mut().replace_drive(drive)?;
        let y = self.run.y().to_vec();
        self.run.set_state(&y)
    }

    /// The energy error of the current state as [`super::energy`] defines it, this state
    /// counting as an output (its kinetic energy joins the scale).
    pub fn energy_error(&mut self) -> f64 {
        match self.terms() {
            Ok(t) => self.balance.observe(t.kinetic, t.energy, t.torque + t.pivot + t.cart - t.dissipated),
            Err(_) => f64::NAN,
        }
    }

    /// Joint positions of the current state, `2N` values (x then y of each link's far end).
    pub fn positions_into(&self, out: &mut [f64]) {
        self.chain().positions_into(self.theta(), out);
    }

    /// The error that stopped the run, if any.
    pub fn failure(&self) -> Option<&Error> {
        self.run.failure()
    }

    /// The torque source, to change between steps; call [`Stepper::restart`] after.
    pub fn torque_mut(&mut self) -> &mut T {
        self.run.system_mut().torque_mut()
    }

    /// Hold the cart force at `f` (a run started with a constant cart force); call
    /// [`Stepper::restart`] after.
    pub fn hold_force(&mut self, f: f64) -> Result<()> {
        self.run.system_mut().hold_force(f)
    }

    /// Write the state `(theta, omega, [x, v])` into `row` and `(t, energy, energy_error)` into
    /// `balance` (the energy terms computed once; NaN if a user's pivot function fails).
    pub fn report(&mut self, row: &mut [f64], balance: &mut [f64]) {
        let n = self.n();
        row[..n].copy_from_slice(self.theta());
        let Stepper { run, form, ws, omega, p, books, balance: books_balance, .. } = self;
        fill_rates(run.system().chain(), *form, run.y(), omega, p, ws);
        row[n..2 * n].copy_from_slice(omega);
        let (t, sys) = (run.t(), run.system());
        let terms = books.terms(sys.chain(), sys.drive(), t, run.y());
        if let Some(i) = sys.layout().cart() {
            row[2 * n] = run.y()[i];
            row[2 * n + 1] = terms.as_ref().map_or(f64::NAN, |t| t.cart_v);
        }
        balance[0] = t;
        match terms {
            Ok(t) => {
                balance[1] = t.energy;
                balance[2] = books_balance.observe(t.kinetic, t.energy, t.torque + t.pivot + t.cart - t.dissipated);
            }
            Err(_) => balance[1..3].fill(f64::NAN),
        }
    }

    /// Restart the integrator from the current state after its inputs changed (what it carried
    /// from the last step, such as dop853's last derivative, belonged to the old inputs). A run
    /// that failed stays failed: its error is returned (a new start is a new stepper).
    pub fn restart(&mut self) -> Result<()> {
        if let Some(e) = self.run.failure() {
            return Err(e.clone());
        }
        let y = self.run.y().to_vec();
        self.run.set_state(&y)
    }
}

/// Copies of one chain advanced together, each with its inputs held constant over a call (an
/// environment's zero-order hold): joint-motor torques `u` (the motor at joint i turns link i
/// and pushes back on link i-1, see [`Joint`]) and, with a cart, the force on the cart. Each
/// copy has its own energy balance; the copies run in parallel, and each one's arithmetic is the
/// same whatever the number of threads and the other copies.
///
/// Two routes: an ideal chain on rk4 (Lagrangian) goes eight copies to a group of SIMD lanes
/// ([`super::bank`]); everything else, or `MULTIPENDULUM_LANES=scalar`, one [`Stepper`] per copy.
/// The two agree to round-off (the lanes' own `sin`/`cos`).
pub struct Steppers {
    route: Route,
    chain: Chain,
    settings: Settings,
}

// One per `Steppers`, made once and never moved while stepping: the size of the lanes' bank
// beside a `Vec` costs nothing, where a `Box` would add a pointer to follow on every step.
#[allow(clippy::large_enum_variant)]
enum Route {
    Each(Vec<Stepper<Joint<Builtin>>>),
    Lanes(Bank),
}

/// One copy's part of a step, as [`Steppers::step`] hands it out: its index, its stepper, its
/// held torques, its state's row and its balance's.
type Part<'a> = (usize, (((&'a mut Stepper<Joint<Builtin>>, &'a [f64]), &'a mut [f64]), &'a mut [f64]));

impl Steppers {
    /// `count` copies of `chain`, hanging at rest until [`Steppers::reset`]. `settings` as for
    /// [`Stepper::new`]; its drive must be empty (the cart force is the one held here).
    pub fn new(chain: &Chain, count: usize, settings: &Settings) -> Result<Self> {
        if count == 0 {
            return Err(Error::input("count must be >= 1, got 0"));
        }
        if settings.drive.pivot.is_some() || settings.drive.force.is_some() {
            return Err(Error::input("steppers hold their own cart force and take no pivot motion"));
        }
        // Refused before anything is allocated: a copy holds its chain, its state and the
        // integrator's stages (a generous kilobyte plus some hundreds of bytes per link).
        crate::memory::check(count as f64 * (1024.0 + 512.0 * chain.n() as f64), &format!("{count} copies of the chain"), "use fewer copies")?;
        let lanes = if bank::fits(chain, settings) { bank::requested()? } else { None };
        Self::with_route(chain, count, settings, lanes)
    }

    /// [`Steppers::new`] on the lanes' `path`, or a stepper per copy (`None`): for the tests,
    /// which hold the two routes to each other.
    pub(crate) fn with_route(chain: &Chain, count: usize, settings: &Settings, lanes: Option<crate::trig::lanes::Path>) -> Result<Self> {
        let mut settings = settings.clone();
        if chain.cart().is_some() {
            settings.drive.force = Some(Force::Builtin(Builtin::Constant(vec![0.0])));
        }
        settings.cart0 = [0.0; 2];
        let rest = vec![0.0; chain.n()];
        let make = || Stepper::new(chain.clone(), &rest, &rest, &settings, Joint(Builtin::Constant(rest.clone())));
        // The settings are checked as a stepper checks them, whichever route runs.
        let first = make()?;
        let route = match lanes {
            Some(path) => Route::Lanes(Bank::new(chain, count, settings.dt.unwrap_or(f64::NAN), path)),
            None => Route::Each(std::iter::once(Ok(first)).chain((1..count).map(|_| make())).collect::<Result<Vec<_>>>()?),
        };
        Ok(Steppers { route, chain: chain.clone(), settings })
    }

    pub fn len(&self) -> usize {
        match &self.route {
            Route::Each(items) => items.len(),
            Route::Lanes(bank) => bank.len(),
        }
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    pub fn chain(&self) -> &Chain {
        &self.chain
    }

    /// The route the copies take: `"each"`, or `"lanes:<path>"` (`portable`, `avx2`, `avx512`).
    pub fn route(&self) -> String {
        match &self.route {
            Route::Each(_) => "each".to_string(),
            Route::Lanes(bank) => format!("lanes:{}", bank.path().name()),
        }
    }

    /// Values per copy in a state row ([`Steppers::report_into`]): `theta`, `omega`, then the
    /// cart's `x, v`.
    pub fn state_len(&self) -> usize {
        self.chain.state_len()
    }

    /// An observation of every copy from its state row (as [`Steppers::report_into`] writes
    /// them, `count x state_len`): `out[c * columns.len() + j]` the `j`-th column of copy `c`,
    /// a value of the row, or the cosine or sine of one (the lanes' `sin`/`cos`, 8 copies at a
    /// time: what an environment's observation costs in NumPy's strided trig is most of its
    /// Python).
    pub fn observe_into(&self, states: &[f64], columns: &[Column], out: &mut [f64]) -> Result<()> {
        let (count, k) = (self.len(), self.state_len());
        if states.len() != count * k {
            return Err(Error::input(format!("states must have count x {k} = {} values, got {}", count * k, states.len())));
        }
        if out.len() != count * columns.len() {
            return Err(Error::input(format!("the observation must have count x {} values", columns.len())));
        }
        if let Some(c) = columns.iter().find(|c| c.index() >= k) {
            return Err(Error::input(format!("observation column {c:?} is outside a state row of {k} values")));
        }
        observe_on(Path::best(), states, k, columns, out);
        Ok(())
    }

    /// Start copy `i` anew at t = 0 from `(theta0, omega0)` and the cart's `(x, v)`: a new
    /// episode, its energy balance and works from zero.
    pub fn reset(&mut self, i: usize, theta0: &[f64], omega0: &[f64], cart0: [f64; 2]) -> Result<()> {
        let count = self.len();
        if i >= count {
            return Err(Error::input(format!("index {i} out of range for {count} copies")));
        }
        let mut settings = self.settings.clone();
        settings.cart0 = cart0;
        match &mut self.route {
            Route::Each(items) => {
                let zero = vec![0.0; self.chain.n()];
                items[i] = Stepper::new(self.chain.clone(), theta0, omega0, &settings, Joint(Builtin::Constant(zero)))?;
            }
            Route::Lanes(bank) => {
                self.chain.check_state("theta0", theta0)?;
                self.chain.check_state("omega0", omega0)?;
                super::simulate::check_cart0(&self.chain, &settings)?;
                bank.reset(i, theta0, omega0, cart0);
            }
        }
        Ok(())
    }

    /// Hold joint torques `torques` (count x N, row-major; zero on joints without a motor) and,
    /// with a cart, forces `forces` (count values; empty without one), then advance every copy
    /// by `span` (the fixed-step methods: the whole steps of their grid up to `t + span`, so
    /// `span = k dt` is exactly k steps; dop853 lands on `t + span`). An input that is not
    /// finite is refused before any copy moves. `active`: which copies move (one flag per copy;
    /// empty: all), the others keep their state and ignore their inputs. Then every copy
    /// writes its row of `states` and `balance` as [`Steppers::report_into`] does (in the same
    /// parallel pass). The first copy (by index) that
    /// fails names itself in the error; it stays failed until reset, the others have taken
    /// their steps.
    pub fn step(&mut self, torques: &[f64], forces: &[f64], span: f64, active: &[bool], states: &mut [f64], balance: &mut [f64]) -> Result<()> {
        self.checked_step(torques, forces, span, active, states, balance)?;
        let items = match &mut self.route {
            Route::Lanes(bank) => return bank.step(torques, forces, span, active, states, balance, None),
            Route::Each(items) => items,
        };
        let n = self.chain.n();
        let k = self.chain.state_len();
        let count = items.len();
        let one = |(i, (((st, u), row), bal)): Part<'_>| -> Option<(usize, Error)> {
            if active.get(i) == Some(&false) {
                st.report(row, bal);
                return None;
            }
            let r = (|| {
                if let Builtin::Constant(held) = &mut st.torque_mut().0 {
                    held.copy_from_slice(u);
                }
                if let Some(&f) = forces.get(i) {
                    st.hold_force(f)?;
                }
                st.restart()?;
                let target = st.t() + span;
                st.advance(target, u64::MAX).map(drop)
            })();
            st.report(row, bal);
            r.err().map(|e| (i, e))
        };
        // One copy runs here: a pool's hand-over would cost more than its step.
        let failed = if count == 1 {
            one((0, (((&mut items[0], torques), states), balance)))
        } else {
            items
                .par_iter_mut()
                .zip(torques.par_chunks(n))
                .zip(states.par_chunks_mut(k))
                .zip(balance.par_chunks_mut(3))
                .enumerate()
                .filter_map(one)
                .min_by_key(|(i, _)| *i)
        };
        match failed {
            None => Ok(()),
            Some((i, Error::Integration { t, reason })) => Err(Error::integration(t, format!("copy {i}: {reason}"))),
            Some((i, Error::Input(m))) => Err(Error::input(format!("copy {i}: {m}"))),
            Some((_, e)) => Err(e),
        }
    }

    /// [`Steppers::step`]'s checks of its inputs and outputs.
    fn checked_step(&self, torques: &[f64], forces: &[f64], span: f64, active: &[bool], states: &[f64], balance: &[f64]) -> Result<()> {
        if !(span.is_finite() && span > 0.0) {
            return Err(Error::input(format!("span must be > 0 and finite, got {}", Shown(span))));
        }
        let (count, n) = (self.len(), self.chain.n());
        let want_forces = if self.chain.cart().is_some() { count } else { 0 };
        if torques.len() != count * n {
            return Err(Error::input(format!("torques must have count x N = {} values, got {}", count * n, torques.len())));
        }
        if forces.len() != want_forces {
            return Err(Error::input(format!("forces must have {want_forces} values (one per copy with a cart), got {}", forces.len())));
        }
        if !active.is_empty() && active.len() != count {
            return Err(Error::input(format!("active must have {count} flags (one per copy) or none, got {}", active.len())));
        }
        let k = self.state_len();
        if states.len() != count * k || balance.len() != count * 3 {
            return Err(Error::input(format!("the outputs must have count x {k} and count x 3 values")));
        }
        check_finite("torques", torques)?;
        check_finite("forces", forces)
    }

    /// One environment step of every copy under `task`: `actions` (count x the task's width,
    /// row-major) become the inputs held over `span` ([`Task::inputs`]: refused before any copy
    /// moves), the active copies step ([`Steppers::step`]), and every copy writes its state
    /// row, balance, observation (count x the task's columns), reward and end
    /// ([`Task::outcome`]); a copy that does not move (one starting anew) earns 0 and does not
    /// end. `episode`: each copy's steps in its episode, counted here, and the count at which
    /// an episode is truncated. `batched`: name a refused action by `(copy, component)`.
    /// Returns how many copies ended (terminated or truncated).
    #[allow(clippy::too_many_arguments)]
    pub fn act(
        &mut self,
        task: &Task,
        actions: &[f64],
        batched: bool,
        span: f64,
        active: &[bool],
        episode: (&mut [u64], Option<u64>),
        out: Acted<'_>,
    ) -> Result<usize> {
        task.check(&self.chain)?;
        let (count, n) = (self.len(), self.chain.n());
        if actions.len() != count * task.width() {
            return Err(Error::input(format!("actions must have count x {} = {} values, got {}", task.width(), count * task.width(), actions.len())));
        }
        let (steps, limit) = episode;
        if out.obs.len() != count * task.columns.len() || [out.reward.len(), out.terminated.len(), out.truncated.len(), steps.len()] != [count; 4] {
            return Err(Error::input(format!(
                "the observations, rewards, ends and episode steps must have count x {}, count, count and count values",
                task.columns.len()
            )));
        }
        let mut torques = vec![0.0; count * n];
        let mut forces = vec![0.0; if self.chain.cart().is_some() { count } else { 0 }];
        task.inputs(&self.chain, actions, batched, &mut torques, &mut forces)?;
        self.checked_step(&torques, &forces, span, active, out.states, out.balance)?;
        if let Route::Lanes(bank) = &mut self.route {
            // The observations and outcomes in the same parallel pass, each group's after its steps.
            bank.step(&torques, &forces, span, active, out.states, out.balance, Some((task, &mut *out.obs, &mut *out.reward, &mut *out.terminated)))?;
        } else {
            self.step(&torques, &forces, span, active, out.states, out.balance)?;
            self.observe_into(out.states, &task.columns, out.obs)?;
            task.outcome(&self.chain, out.states, out.reward, out.terminated);
        }
        let mut ended = 0;
        for i in 0..count {
            if active.get(i) == Some(&false) {
                (out.reward[i], out.terminated[i], out.truncated[i]) = (0.0, false, false);
                continue;
            }
            steps[i] += 1;
            out.truncated[i] = limit.is_some_and(|l| steps[i] >= l);
            ended += usize::from(out.terminated[i] || out.truncated[i]);
        }
        Ok(ended)
    }

    /// Every copy's state (count x [`Steppers::state_len`] values) and its time, energy (lab
    /// frame) and energy-balance residual ([`Stepper::energy_error`]; count x 3), as
    /// [`Steppers::step`] writes them.
    pub fn report_into(&mut self, states: &mut [f64], balance: &mut [f64]) {
        let k = self.state_len();
        match &mut self.route {
            Route::Each(items) => {
                for ((st, row), bal) in items.iter_mut().zip(states.chunks_mut(k)).zip(balance.chunks_mut(3)) {
                    st.report(row, bal);
                }
            }
            Route::Lanes(bank) => bank.report_into(states, balance),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dynamics::torque::Builtin;
    use crate::run::bank::Bank;
    use crate::run::simulate::simulate;

    fn settings(method: &str, dt: Option<f64>) -> Settings {
        Settings { method: Method::parse(method).unwrap(), dt, ..Settings::default() }
    }

    fn double() -> Chain {
        Chain::new(&[1.0, 1.0], &[1.0, 1.0], None, None, 9.81).unwrap()
    }

    #[test]
    fn fixed_steps_match_simulate_and_do_not_depend_on_the_pieces() {
        let theta0 = [2.0, 2.5];
        for method in ["rk4", "gauss6"] {
            let s = settings(method, Some(0.01));
            let mut whole = Stepper::new(double(), &theta0, &[0.0; 2], &s, Builtin::None).unwrap();
            assert!(whole.advance(1.0, u64::MAX).unwrap());
            let mut pieces = Stepper::new(double(), &theta0, &[0.0; 2], &s, Builtin::None).unwrap();
            let mut target = 0.0f64;
            while target < 1.0 {
                target += 1.0 / 60.0;
                pieces.advance(target.min(1.0), u64::MAX).unwrap();
            }
            assert_eq!(whole.t(), 100.0 * 0.01);
            assert_eq!(pieces.t(), whole.t());
            assert_eq!(pieces.theta(), whole.theta(), "{method}: bit for bit whatever the pieces");
            // One time grid: the frame-by-frame run is simulate's to t_end, bit for bit.
            let reference = simulate(&double(), &theta0, &[0.0; 2], 1.0, &s, Builtin::None, &mut |_| Ok(())).unwrap();
            let last = reference.theta.len() - 2;
            assert_eq!(whole.theta(), &reference.theta[last..], "{method}");
            assert_eq!(whole.energy(), reference.energy[reference.energy.len() - 1]);
            assert_eq!(whole.initial_energy(), reference.energy[0]);
        }
    }

    #[test]
    fn one_rk4_step_equals_simulate_bit_for_bit() {
        let chain = Chain::rods(&[1.0, 0.7, 0.5], &[1.0, 2.0, 0.5], 9.81).unwrap();
        let (theta0, omega0) = ([0.3, -1.2, 2.0], [0.5, 0.0, -1.0]);
        let s = Settings { t_eval: Some(vec![0.01]), ..settings("rk4", Some(0.01)) };
        let mut st = Stepper::new(chain.clone(), &theta0, &omega0, &s, Builtin::None).unwrap();
        st.advance(0.01, 1).unwrap();
        let r = simulate(&chain, &theta0, &omega0, 0.01, &s, Builtin::None, &mut |_| Ok(())).unwrap();
        assert_eq!(st.theta(), &r.theta[..]);
        assert_eq!(st.omega(), &r.omega[..]);
        assert_eq!(st.energy(), r.energy[0]);
    }

    #[test]
    fn dop853_lands_on_each_target_and_keeps_its_tolerance() {
        let s = Settings { rtol: 1e-11, atol: 1e-13, ..settings("dop853", None) };
        // A regular (not chaotic) start, so the tolerance bounds the difference at the end.
        let theta0 = [1.0, 0.5];
        let mut st = Stepper::new(double(), &theta0, &[0.0; 2], &s, Builtin::None).unwrap();
        for frame in 1..=600 {
            let target = frame as f64 / 60.0;
            assert!(st.advance(target, u64::MAX).unwrap());
            assert_eq!(st.t(), target);
        }
        let reference = Settings { rtol: 1e-13, atol: 1e-15, t_eval: Some(vec![st.t()]), ..settings("dop853", None) };
        let r = simulate(&double(), &theta0, &[0.0; 2], st.t(), &reference, Builtin::None, &mut |_| Ok(())).unwrap();
        for i in 0..2 {
            let d = (st.theta()[i] - r.theta[i]).abs();
            assert!(d < 1e-8, "theta[{i}] differs by {d} after 10 s");
        }
        assert!(st.energy_error() < 1e-9, "{}", st.energy_error());
    }

    #[test]
    fn the_step_budget_stops_early_and_resumes() {
        let s = settings("rk4", Some(0.01));
        let mut st = Stepper::new(double(), &[1.0, 0.0], &[0.0; 2], &s, Builtin::None).unwrap();
        assert!(!st.advance(1.0, 10).unwrap());
        assert_eq!(st.counts().0, 10);
        assert!((st.t() - 0.1).abs() < 1e-15);
        assert!(st.advance(f64::INFINITY, 1).is_ok_and(|done| !done));
        assert!(st.advance(0.005, 5).unwrap(), "a target already passed is reached");
        assert_eq!(st.counts().0, 11);
    }

    #[test]
    fn bad_settings_and_states_are_refused() {
        let e = Stepper::new(double(), &[1.0, 0.0], &[0.0; 2], &settings("rk4", None), Builtin::None).err().unwrap();
        assert_eq!(e.to_string(), "method rk4 takes a fixed step: give dt");
        let e = Stepper::new(double(), &[1.0, 0.0], &[0.0; 2], &settings("rk4", Some(-1.0)), Builtin::None).err().unwrap();
        assert_eq!(e.to_string(), "dt must be > 0 and finite, got -1");
        let e = Stepper::new(double(), &[f64::NAN, 0.0], &[0.0; 2], &settings("rk4", Some(0.01)), Builtin::None).err().unwrap();
        assert_eq!(e.to_string(), "theta0[0] must be finite, got NaN");
        let mut st = Stepper::new(double(), &[1.0, 0.0], &[0.0; 2], &settings("rk4", Some(0.01)), Builtin::None).unwrap();
        assert!(st.advance(f64::NAN, 1).is_err());
    }

    #[test]
    fn steppers_are_steppers_held_constant_and_independent_of_the_batch() {
        // Each copy of a batch is the single stepper with the same constant joint torque (to
        // round-off on the lanes, the same route for every copy), whatever the other copies do,
        // and bit for bit the copy alone; a masked copy does not move.
        for chain in [Chain::rods(&[1.0, 0.7], &[1.0, 0.5], 9.81).unwrap(), Chain::rods(&[1.0, 0.7, 0.4], &[1.0, 0.5, 0.2], 9.81).unwrap()] {
            let n = chain.n();
            let s = settings("rk4", Some(0.01));
            let mut batch = Steppers::new(&chain, 11, &s).unwrap();
            assert!(batch.route().starts_with("lanes:") || std::env::var(super::bank::SWITCH).as_deref() == Ok("scalar"), "{}", batch.route());
            let start = |i: usize| -> (Vec<f64>, Vec<f64>) {
                ((0..n).map(|a| 0.3 * (i + a) as f64 - 1.0).collect(), (0..n).map(|a| 0.1 * (i as f64 - a as f64)).collect())
            };
            for i in 0..11 {
                let (th, om) = start(i);
                batch.reset(i, &th, &om, [0.0; 2]).unwrap();
            }
            let u: Vec<f64> = (0..11 * n).map(|j| 0.1 * (j % 7) as f64 - 0.3).collect();
            let k = batch.state_len();
            let (mut out, mut bal) = (vec![0.0; 11 * k], vec![0.0; 33]);
            batch.step(&u, &[], 0.2, &[], &mut out, &mut bal).unwrap();
            let mask: Vec<bool> = (0..11).map(|i| i != 1).collect();
            batch.step(&u, &[], 0.2, &mask, &mut out, &mut bal).unwrap();
            let (mut again, mut bal_again) = (vec![0.0; out.len()], vec![0.0; bal.len()]);
            batch.report_into(&mut again, &mut bal_again);
            assert_eq!(again, out, "the step's report is the state's");
            for i in 0..11 {
                let (th, om) = start(i);
                let torque = Joint(Builtin::Constant(u[n * i..n * (i + 1)].to_vec()));
                let mut one = Stepper::new(chain.clone(), &th, &om, &s, torque).unwrap();
                let span = if i == 1 { 0.2 } else { 0.4 };
                one.advance(span, u64::MAX).unwrap();
                assert_eq!(one.counts().0, (span / 0.01).round() as u64, "whole steps of the grid");
                for a in 0..n {
                    assert!((out[k * i + a] - one.theta()[a]).abs() < 1e-12, "copy {i}");
                    assert!((out[k * i + n + a] - one.omega()[a]).abs() < 1e-12, "copy {i}");
                }
                let mut alone = Steppers::new(&chain, 1, &s).unwrap();
                alone.reset(0, &th, &om, [0.0; 2]).unwrap();
                let (mut o1, mut b1) = (vec![0.0; k], vec![0.0; 3]);
                for _ in 0..if i == 1 { 1 } else { 2 } {
                    alone.step(&u[n * i..n * (i + 1)], &[], 0.2, &[], &mut o1, &mut b1).unwrap();
                }
                assert_eq!(&o1[..], &out[k * i..k * (i + 1)], "copy {i} bit for bit alone");
            }
            assert_eq!(bal[3], 0.2, "the masked copy stayed at t = 0.2");
            assert!(bal.chunks(3).all(|b| b[2] < 1e-7), "the torque's work closes the balance: {bal:?}");
        }
    }

    #[test]
    fn a_copy_that_blows_up_in_the_lanes_stops_alone_at_its_last_good_state() {
        let chain = Chain::rods(&[1.0, 0.7], &[1.0, 0.5], 9.81).unwrap();
        let mut batch = Steppers::new(&chain, 3, &settings("rk4", Some(0.01))).unwrap();
        assert!(batch.route().starts_with("lanes:") || std::env::var(super::bank::SWITCH).as_deref() == Ok("scalar"));
        for i in 0..3 {
            batch.reset(i, &[0.5, 0.2], &[0.0, 0.0], [0.0; 2]).unwrap();
        }
        let u = [0.0, 0.1, 1e200, -1e200, 0.0, 0.0]; // copy 1 driven to overflow
        let (mut out, mut bal) = (vec![0.0; 12], vec![0.0; 9]);
        let e = batch.step(&u, &[], 0.2, &[], &mut out, &mut bal).unwrap_err();
        let blew_up = format!("copy 1: {}", crate::dynamics::system::NON_FINITE);
        assert!(matches!(&e, Error::Integration { reason, .. } if *reason == blew_up), "{e}");
        assert!(out.iter().all(|v| v.is_finite()), "the failed copy kept a finite state: {out:?}");
        assert_eq!((bal[0], bal[6]), (0.2, 0.2), "the other copies took their steps");
        assert!(bal[3] < 0.2, "the failed copy stopped early");
        assert_eq!(batch.step(&[0.0; 6], &[], 0.2, &[], &mut out, &mut bal).unwrap_err(), e, "it stays failed");
        batch.reset(1, &[0.5, 0.2], &[0.0, 0.0], [0.0; 2]).unwrap();
        batch.step(&[0.0; 6], &[], 0.2, &[], &mut out, &mut bal).unwrap();
        assert_eq!(bal[3], 0.2);
    }

    #[test]
    fn groups_stepped_side_by_side_give_each_copy_its_bits_alone() {
        use crate::trig::lanes::Path;
        // 40 copies: five groups, stepped two by two (and the fifth alone); copy 19 (the last
        // lane of the third group, whose pair is the fourth) driven to overflow.
        for path in Path::ALL.into_iter().filter(|p| p.available()) {
            for chain in [Chain::rods(&[1.0, 0.7], &[1.0, 0.5], 9.81).unwrap(), Chain::rods(&[1.0, 0.7, 0.4], &[1.0, 0.5, 0.2], 9.81).unwrap()] {
                let n = chain.n();
                let start = |i: usize| -> Vec<f64> { (0..n).map(|a| 0.3 + 0.05 * (i + a) as f64).collect() };
                let torque = |i: usize| -> Vec<f64> { (0..n).map(|a| if i == 19 { 1e200 } else { 0.1 * ((i * 7 + a) % 5) as f64 - 0.2 }).collect() };
                let mut bank = Bank::new(&chain, 40, 0.01, path);
                for i in 0..40 {
                    bank.reset(i, &start(i), &vec![0.0; n], [0.0; 2]);
                }
                let u: Vec<f64> = (0..40).flat_map(torque).collect();
                let (mut out, mut bal) = (vec![0.0; 40 * 2 * n], vec![0.0; 40 * 3]);
                let e = bank.step(&u, &[], 0.2, &[], &mut out, &mut bal, None).unwrap_err();
                assert!(matches!(&e, Error::Integration { reason, .. } if reason.starts_with("copy 19: ")), "{e}");
                for i in (0..40).filter(|&i| i != 19) {
                    let mut alone = Bank::new(&chain, 1, 0.01, path);
                    alone.reset(0, &start(i), &vec![0.0; n], [0.0; 2]);
                    let (mut o, mut b) = (vec![0.0; 2 * n], vec![0.0; 3]);
                    alone.step(&torque(i), &[], 0.2, &[], &mut o, &mut b, None).unwrap();
                    assert_eq!(&out[2 * n * i..2 * n * (i + 1)], &o[..], "copy {i} of {n} links on {}", path.name());
                    assert_eq!(&bal[3 * i..3 * i + 3], &b[..], "copy {i}'s balance");
                }
                assert!(bal[3 * 19] < 0.2, "the failed copy stopped early");
            }
        }
    }

    #[test]
    fn a_lossy_chains_copies_in_lanes_agree_with_a_stepper_each() {
        use crate::trig::lanes::Path;
        let chain = Chain::new(&[1.0, 0.5, 0.8], &[1.0, 2.0, 0.5], None, None, 9.81).unwrap().with_losses(&[0.1, 0.2, 0.05], &[0.1, 0.0, 0.2], 0.5).unwrap();
        let s = settings("rk4", Some(0.005));
        let mut lanes = Steppers::with_route(&chain, 9, &s, Some(Path::best())).unwrap();
        let mut each = Steppers::with_route(&chain, 9, &s, None).unwrap();
        assert!(lanes.route().starts_with("lanes:") && each.route() == "each");
        for i in 0..9 {
            let (th, om) = ([2.0, 2.5 - 0.1 * i as f64, -1.0], [0.0, 1.0 + 0.2 * i as f64, 0.0]);
            lanes.reset(i, &th, &om, [0.0; 2]).unwrap();
            each.reset(i, &th, &om, [0.0; 2]).unwrap();
        }
        let (mut a, mut ab, mut b, mut bb) = (vec![0.0; 54], vec![0.0; 27], vec![0.0; 54], vec![0.0; 27]);
        for k in 0..30 {
            let u: Vec<f64> = (0..27).map(|m| 0.3 * ((m + k) as f64).sin()).collect();
            lanes.step(&u, &[], 0.05, &[], &mut a, &mut ab).unwrap();
            each.step(&u, &[], 0.05, &[], &mut b, &mut bb).unwrap();
        }
        for (x, y) in a.iter().zip(&b) {
            assert!((x - y).abs() <= 1e-10 * (1.0 + y.abs()), "{x} vs {y}");
        }
        for c in 0..9 {
            // Time, energy and the energy balance (torque work and dissipation in it): the
            // residual is rk4's, far below the energy the losses took.
            assert_eq!(ab[3 * c], bb[3 * c]);
            assert!((ab[3 * c + 1] - bb[3 * c + 1]).abs() < 1e-10, "copy {c}");
            assert!((ab[3 * c + 2] - bb[3 * c + 2]).abs() < 1e-12 && ab[3 * c + 2] < 1e-5, "copy {c}: {} vs {}", ab[3 * c + 2], bb[3 * c + 2]);
        }
    }

    #[test]
    fn copies_on_a_cart_in_lanes_agree_with_a_stepper_each() {
        use crate::model::Cart;
        use crate::trig::lanes::Path;
        for (n, losses) in [(1usize, false), (2, true), (3, false), (3, true)] {
            let mut chain = Chain::rods(&vec![0.6; n], &vec![0.2; n], 9.81).unwrap();
            if losses {
                chain = chain.with_losses(&vec![0.05; n], &vec![0.02; n], 0.5).unwrap();
            }
            let chain = chain.with_cart(Some(Cart::new(1.0, if losses { 0.3 } else { 0.0 }).unwrap())).unwrap();
            let s = settings("rk4", Some(0.005));
            let mut lanes = Steppers::with_route(&chain, 10, &s, Some(Path::best())).unwrap();
            let mut each = Steppers::with_route(&chain, 10, &s, None).unwrap();
            assert!(lanes.route().starts_with("lanes:") && each.route() == "each");
            for i in 0..10 {
                let th: Vec<f64> = (0..n).map(|a| 3.0 - 0.2 * (i + a) as f64).collect();
                let om: Vec<f64> = (0..n).map(|a| 0.5 * a as f64 - 0.1 * i as f64).collect();
                let cart0 = [0.1 * i as f64, -0.2];
                lanes.reset(i, &th, &om, cart0).unwrap();
                each.reset(i, &th, &om, cart0).unwrap();
            }
            let k = 2 * n + 2;
            let (mut a, mut ab, mut b, mut bb) = (vec![0.0; 10 * k], vec![0.0; 30], vec![0.0; 10 * k], vec![0.0; 30]);
            for step in 0..30 {
                let u: Vec<f64> = (0..10 * n).map(|m| 0.2 * ((m + step) as f64).cos()).collect();
                let f: Vec<f64> = (0..10).map(|m| 3.0 * ((m * 7 + step) as f64).sin()).collect();
                lanes.step(&u, &f, 0.05, &[], &mut a, &mut ab).unwrap();
                each.step(&u, &f, 0.05, &[], &mut b, &mut bb).unwrap();
            }
            for (x, y) in a.iter().zip(&b) {
                assert!((x - y).abs() <= 1e-9 * (1.0 + y.abs()), "N = {n}, losses {losses}: {x} vs {y}");
            }
            for c in 0..10 {
                assert_eq!(ab[3 * c], bb[3 * c]);
                assert!((ab[3 * c + 1] - bb[3 * c + 1]).abs() < 1e-9, "N = {n}: copy {c}");
                // The balance with the force's work and the losses: rk4's residual, on both routes.
                assert!((ab[3 * c + 2] - bb[3 * c + 2]).abs() < 1e-11 && ab[3 * c + 2] < 1e-3, "N = {n}, copy {c}: {} vs {}", ab[3 * c + 2], bb[3 * c + 2]);
            }
        }
    }

    #[test]
    fn the_lane_paths_give_the_same_bits() {
        use crate::trig::lanes::Path;
        let chain = Chain::new(&[1.0, 0.5, 0.8, 0.3], &[1.0, 2.0, 0.5, 1.0], None, None, 9.81).unwrap();
        let mut results = Vec::new();
        for path in Path::ALL.into_iter().filter(|p| p.available()) {
            let mut bank = Bank::new(&chain, 9, 0.005, path);
            for i in 0..9 {
                bank.reset(i, &[2.0, 2.5 - 0.1 * i as f64, -1.0, 0.5], &[0.0, 1.0, 0.0, -2.0], [0.0; 2]);
            }
            let (mut out, mut bal) = (vec![0.0; 72], vec![0.0; 27]);
            for _ in 0..50 {
                bank.step(&[0.1; 36], &[], 0.05, &[], &mut out, &mut bal, None).unwrap();
            }
            results.push((path.name(), out));
        }
        for (name, out) in &results[1..] {
            assert_eq!(out, &results[0].1, "{name} against {}", results[0].0);
        }
    }

    #[test]
    fn steppers_hold_the_cart_force_and_refuse_bad_inputs() {
        let chain = Chain::rods(&[1.0], &[0.1], 9.8).unwrap().with_cart(Some(crate::model::Cart::new(1.0, 0.0).unwrap())).unwrap();
        let s = settings("rk4", Some(0.005));
        let mut batch = Steppers::new(&chain, 2, &s).unwrap();
        assert_eq!(batch.state_len(), 4);
        batch.reset(1, &[3.0], &[0.0], [0.5, 0.0]).unwrap();
        let (mut out, mut bal) = (vec![0.0; 8], vec![0.0; 6]);
        batch.step(&[0.0, 0.0], &[2.0, -1.0], 0.1, &[], &mut out, &mut bal).unwrap();
        // A rod hanging at rest, its cart pushed by F: at first x_ddot = F / (M + m / 4) (the
        // rod turns about its centre of percussion), so x = F t^2 / (2 (M + m / 4)) over 0.1 s.
        assert!((out[2] - 2.0 * 0.01 / 2.0 / 1.025).abs() < 2e-5, "{out:?}");
        assert!(out[6] < 0.5, "the second cart pushed back: {out:?}");
        assert!(bal[2] < 1e-9 && bal[5] < 1e-9, "{bal:?}");
        let e = batch.step(&[0.0, f64::NAN], &[0.0, 0.0], 0.1, &[], &mut out, &mut bal).unwrap_err();
        assert_eq!(e.to_string(), "torques[1] must be finite, got NaN");
        let e = batch.step(&[0.0, 0.0], &[], 0.1, &[], &mut out, &mut bal).unwrap_err();
        assert_eq!(e.to_string(), "forces must have 2 values (one per copy with a cart), got 0");
        let e = batch.step(&[0.0, 0.0], &[0.0, 0.0], 0.0, &[], &mut out, &mut bal).unwrap_err();
        assert_eq!(e.to_string(), "span must be > 0 and finite, got 0");
        let e = batch.reset(2, &[0.0], &[0.0], [0.0; 2]).unwrap_err();
        assert_eq!(e.to_string(), "index 2 out of range for 2 copies");
        assert_eq!(Steppers::new(&chain, 0, &s).err().unwrap().to_string(), "count must be >= 1, got 0");
    }

    #[test]
    fn a_failed_run_keeps_its_last_good_state() {
        // gauss6 with a huge step on a fast chain: the stage equations do not converge.
        let s = settings("gauss6", Some(2.0));
        let mut st = Stepper::new(double(), &[2.0, 2.5], &[10.0, -10.0], &s, Builtin::None).unwrap();
        let e = st.advance(100.0, u64::MAX).unwrap_err();
        assert!(matches!(e, Error::Integration { .. }), "{e}");
        assert!(st.theta().iter().all(|v| v.is_finite()));
        assert!(st.energy().is_finite());
        assert_eq!(st.advance(200.0, 1).unwrap_err(), e);
        assert_eq!(st.failure(), Some(&e));
    }
}
