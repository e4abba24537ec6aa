//! A run advanced piece by piece, for callers that show the motion as it happens (the browser
//! viewer advances one frame at a time). Unlike [`crate::simulate`] it keeps no history: it holds
//! the chain, the state and the integrator's own state between calls.
//!
//! Fixed-step methods (`rk4`, `gauss4`, `gauss6`) take whole steps of `dt` only, so the time is
//! always `k dt` and the run is the same however it is cut into pieces; a target that is not a
//! multiple of `dt` is reached to within one step. `dop853` adapts its step and shortens the one
//! that would pass the target, so it lands on the target exactly.
use crate::dynamics::Workspace;
use crate::error::{Error, Result};
use crate::integrators::{dop853::Attempt, Dop853, FixedStep, Gauss, Method, Rk4};
use crate::model::Chain;
use crate::simulate::Settings;
use crate::system::{ChainSystem, Form, OdeSystem, NON_FINITE};
use crate::torque::TorqueSource;

// One per stepper, so the size of the largest variant costs nothing worth a box.
#[allow(clippy::large_enum_variant)]
enum Integrator {
    Rk4(Rk4),
    Gauss(Gauss),
    Dop853 { rk: Dop853, h: f64, rejected: bool },
}

/// A chain, its current state and its integrator, advanced on request.
pub struct Stepper<T> {
    chain: Chain,
    torque: T,
    form: Form,
    method: Method,
    dt: f64,
    integrator: Integrator,
    /// The ODE state: `[theta, omega or p]`, then the torque's work when one acts.
    y: Vec<f64>,
    y_new: Vec<f64>,
    t: f64,
    steps: u64,
    rejected: u64,
    evaluations: u64,
    e0: f64,
    /// The first error; once failed, the stepper stays at the last good state and repeats it.
    failed: Option<Error>,
    ws: Workspace,
    omega: Vec<f64>,
    scratch: Vec<f64>,
}

impl<T: TorqueSource> Stepper<T> {
    /// Start at t = 0 from `(theta0, omega0)`. `settings.t_eval` and `max_steps` are not used;
    /// `dt` is required by the fixed-step methods and is the first step of `dop853` if given.
    pub fn new(chain: Chain, theta0: &[f64], omega0: &[f64], settings: &Settings, torque: T) -> Result<Self> {
        chain.check_state("theta0", theta0)?;
        chain.check_state("omega0", omega0)?;
        // The run has no end; any t_end checks the step and tolerance settings the same way.
        let mut checked = settings.clone();
        checked.t_eval = None;
        checked.validate(f64::MAX)?;
        let form = settings.resolved_form()?;
        let n = chain.n();
        let mut ws = Workspace::new(n);
        let dim = 2 * n + usize::from(torque.active());
        let mut y = vec![0.0; dim];
        y[..n].copy_from_slice(theta0);
        match form {
            Form::Lagrangian => y[n..2 * n].copy_from_slice(omega0),
            Form::Hamiltonian => chain.momenta_into(theta0, omega0, &mut y[n..2 * n], &mut ws),
        }
        let mut scratch = vec![0.0; n];
        let e0 = chain.kinetic_energy(theta0, omega0, &mut scratch, &mut ws) + chain.potential_energy(theta0);
        let mut stepper = Stepper {
            integrator: Integrator::Rk4(Rk4::new(0)),
            chain,
            torque,
            form,
            method: settings.method,
            dt: settings.dt.unwrap_or(f64::NAN),
            y_new: vec![0.0; dim],
            y,
            t: 0.0,
            steps: 0,
            rejected: 0,
            evaluations: 0,
            e0,
            failed: None,
            ws,
            omega: omega0.to_vec(),
            scratch,
        };
        stepper.integrator = match settings.method {
            Method::Rk4 => Integrator::Rk4(Rk4::new(dim)),
            Method::Gauss4 | Method::Gauss6 => Integrator::Gauss(Gauss::new(settings.method.order() as usize / 2, dim)),
            Method::Dop853 => {
                let mut rk = Dop853::new(dim, settings.rtol, settings.atol);
                let Stepper { chain, torque, y, .. } = &mut stepper;
                let mut sys = ChainSystem::new(&*chain, &mut *torque, form);
                rk.start(&mut sys, 0.0, y)?;
                let h = match settings.dt {
                    Some(dt) => dt,
                    None => rk.initial_step(&mut sys, 0.0, y, f64::INFINITY)?,
                };
                stepper.evaluations += sys.evaluations;
                Integrator::Dop853 { rk, h, rejected: false }
            }
        };
        Ok(stepper)
    }

    /// Advance towards `t_target`, taking at most `max_steps` accepted steps. Returns `true` once
    /// the target is reached (for fixed-step methods: when one more step of `dt` would pass it),
    /// `false` if the step budget ran out first. After an error the state is the last good one and
    /// every later call returns the same error.
    pub fn advance(&mut self, t_target: f64, max_steps: u64) -> Result<bool> {
        if let Some(e) = &self.failed {
            return Err(e.clone());
        }
        if t_target.is_nan() {
            return Err(Error::input("t_target must not be NaN"));
        }
        let Stepper { chain, torque, form, integrator, y, y_new, t, steps, rejected, dt, .. } = self;
        let mut sys = ChainSystem::new(&*chain, &mut *torque, *form);
        let mut taken = 0u64;
        let result = (|| -> Result<bool> {
            match integrator {
                Integrator::Rk4(rk) => fixed(&mut sys, rk, y, y_new, t, steps, *dt, t_target, max_steps, &mut taken),
                Integrator::Gauss(g) => fixed(&mut sys, g, y, y_new, t, steps, *dt, t_target, max_steps, &mut taken),
                Integrator::Dop853 { rk, h, rejected: was_rejected } => loop {
                    let span = t_target - *t;
                    let min_step = 10.0 * (t.abs() * f64::EPSILON).max(f64::MIN_POSITIVE);
                    if span < min_step {
                        return Ok(true);
                    }
                    if taken >= max_steps {
                        return Ok(false);
                    }
                    if *h < min_step {
                        return Err(Error::integration(*t, "the step size underflowed (the motion is singular or blew up)"));
                    }
                    let clamped = *h >= span;
                    let h_try = if clamped { span } else { *h };
                    match rk.attempt(&mut sys, *t, y, h_try, y_new, *was_rejected, false)? {
                        Attempt::Rejected { h_next } => {
                            *rejected += 1;
                            *was_rejected = true;
                            *h = h_next;
                        }
                        Attempt::Accepted { h_next } => {
                            check_finite(*t + h_try, y_new)?;
                            rk.finish_step(&mut sys, *t, y, y_new, h_try, false)?;
                            y.copy_from_slice(y_new);
                            *t = if clamped { t_target } else { *t + h_try };
                            // A step shortened to land on the target says little about the
                            // next one: keep the proposal it was cut from.
                            if !clamped {
                                *h = h_next;
                            }
                            *was_rejected = false;
                            *steps += 1;
                            taken += 1;
                        }
                    }
                },
            }
        })();
        self.evaluations += sys.evaluations;
        if let Err(e) = &result {
            self.failed = Some(e.clone());
        }
        result
    }

    pub fn t(&self) -> f64 {
        self.t
    }
    pub fn n(&self) -> usize {
        self.chain.n()
    }
    pub fn chain(&self) -> &Chain {
        &self.chain
    }
    pub fn method(&self) -> Method {
        self.method
    }
    pub fn form(&self) -> Form {
        self.form
    }
    /// Accepted steps, rejected attempts (dop853) and right-hand side evaluations so far.
    pub fn counts(&self) -> (u64, u64, u64) {
        (self.steps, self.rejected, self.evaluations)
    }
    pub fn theta(&self) -> &[f64] {
        &self.y[..self.chain.n()]
    }

    /// Angular velocities of the current state (solved from `p` in the Hamiltonian form).
    pub fn omega(&mut self) -> &[f64] {
        let n = self.chain.n();
        let (theta, second) = (&self.y[..n], &self.y[n..2 * n]);
        match self.form {
            Form::Lagrangian => self.omega.copy_from_slice(second),
            Form::Hamiltonian => {
                // Cannot fail: the state passed through the right-hand side (or is the start).
                if self.chain.velocities_into(theta, second, &mut self.omega, &mut self.ws).is_err() {
                    self.omega.fill(f64::NAN);
                }
            }
        }
        &self.omega
    }

    /// Energy `T + U` of the current state.
    pub fn energy(&mut self) -> f64 {
        self.omega();
        let theta = &self.y[..self.chain.n()];
        self.chain.kinetic_energy(theta, &self.omega, &mut self.scratch, &mut self.ws) + self.chain.potential_energy(theta)
    }

    pub fn initial_energy(&self) -> f64 {
        self.e0
    }

    /// Work done by the torque since t = 0 (zero without one).
    pub fn work(&self) -> f64 {
        self.y.get(2 * self.chain.n()).copied().unwrap_or(0.0)
    }

    /// `|E - E0 - W| / |E0|` (absolute when `E0 = 0`), as in [`crate::Stats::energy_error`].
    pub fn energy_error(&mut self) -> f64 {
        let scale = if self.e0 != 0.0 { self.e0.abs() } else { 1.0 };
        (self.energy() - self.e0 - self.work()).abs() / scale
    }

    /// Joint positions of the current state, `2N` values (x then y of each link's far end).
    pub fn positions_into(&self, out: &mut [f64]) {
        self.chain.positions_into(self.theta(), out);
    }

    /// The error that stopped the run, if any.
    pub fn failure(&self) -> Option<&Error> {
        self.failed.as_ref()
    }
}

fn check_finite(t: f64, y: &[f64]) -> Result<()> {
    if y.iter().all(|v| v.is_finite()) {
        Ok(())
    } else {
        Err(Error::integration(t, NON_FINITE))
    }
}

/// Whole steps of `dt` while they do not pass `t_target`; `y_new` keeps the state before each
/// step so a failed step leaves `y` at the last good state.
#[allow(clippy::too_many_arguments)]
fn fixed<S: OdeSystem, I: FixedStep>(
    sys: &mut S,
    stepper: &mut I,
    y: &mut [f64],
    before: &mut [f64],
    t: &mut f64,
    steps: &mut u64,
    dt: f64,
    t_target: f64,
    max_steps: u64,
    taken: &mut u64,
) -> Result<bool> {
    loop {
        let t_next = (*steps + 1) as f64 * dt;
        if t_next > t_target + 1e-9 * dt {
            return Ok(true);
        }
        if *taken >= max_steps {
            return Ok(false);
        }
        before.copy_from_slice(y);
        let outcome = stepper.step(sys, *t, y, dt).and_then(|()| check_finite(t_next, y));
        if let Err(e) = outcome {
            y.copy_from_slice(before);
            return Err(e);
        }
        *steps += 1;
        *taken += 1;
        *t = t_next;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::simulate::simulate;
    use crate::torque::Builtin;

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
            let t_end = whole.t();
            let reference = simulate(&double(), &theta0, &[0.0; 2], t_end, &s, Builtin::None, &mut |_| Ok(())).unwrap();
            let last = reference.theta.len() - 2;
            for i in 0..2 {
                // simulate's last step is t_end - 99 dt, which differs from dt by rounding.
                let d = (whole.theta()[i] - reference.theta[last + i]).abs();
                assert!(d < 1e-12, "{method}: theta[{i}] differs by {d}");
            }
            let e0 = reference.energy[0];
            let last = (reference.energy[reference.energy.len() - 1] - e0).abs() / e0.abs();
            assert!((whole.energy_error() - last).abs() < 1e-9, "{method}: {} vs {last}", whole.energy_error());
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
