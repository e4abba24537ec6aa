//! Events: a condition `g(theta, omega)` crossing zero during a run, located by root finding on
//! the integrator's dense output (DOP853's 7th-order interpolant, or the cubic Hermite of a
//! fixed step) rather than "the step where it changed sign". An event records the state there,
//! or stops the run (terminal).
use crate::dynamics::system::Form;
use crate::dynamics::Workspace;
use crate::error::{Error, Result, Shown};
use crate::model::Chain;
use std::sync::Arc;

/// A user's event function `g(t, theta, omega)` (e.g. written in Python by the bindings).
pub trait EventFn: Send + Sync {
    fn value(&self, t: f64, theta: &[f64], omega: &[f64]) -> Result<f64>;
}

#[derive(Clone)]
pub enum Condition {
    /// `|theta_k| - pi` (link `k` goes over the top); `None`: the largest over all links.
    Flip(Option<usize>),
    /// `theta . a + omega . b + c`, e.g. `theta_1` for a Poincaré section.
    Linear { theta: Vec<f64>, omega: Vec<f64>, constant: f64 },
    /// Any function of the state; evaluated at each step's end and during root finding.
    Custom(Arc<dyn EventFn>),
}

impl std::fmt::Debug for Condition {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Condition::Flip(k) => write!(f, "Flip({k:?})"),
            Condition::Linear { theta, omega, constant } => write!(f, "Linear({theta:?}, {omega:?}, {constant})"),
            Condition::Custom(_) => f.write_str("Custom(..)"),
        }
    }
}

impl PartialEq for Condition {
    fn eq(&self, other: &Self) -> bool {
        match (self, other) {
            (Condition::Flip(a), Condition::Flip(b)) => a == b,
            (Condition::Linear { theta: a, omega: b, constant: c }, Condition::Linear { theta: x, omega: y, constant: z }) => a == x && b == y && c == z,
            (Condition::Custom(a), Condition::Custom(b)) => Arc::ptr_eq(a, b),
            _ => false,
        }
    }
}

#[derive(Debug, Clone, PartialEq)]
pub struct EventSpec {
    pub condition: Condition,
    /// +1: only increasing through zero; -1: only decreasing; 0: both.
    pub direction: i8,
    /// Stop the run at the first such crossing.
    pub terminal: bool,
}

impl EventSpec {
    pub fn validate(&self, n: usize) -> Result<()> {
        if !(-1..=1).contains(&self.direction) {
            return Err(Error::input(format!("direction must be -1, 0 or +1, got {}", self.direction)));
        }
        match &self.condition {
            Condition::Flip(Some(k)) if *k >= n => Err(Error::input(format!("link must be < N = {n}, got {k}"))),
            Condition::Linear { theta, omega, constant } => {
                crate::error::check_len("event theta coefficients", theta, n)?;
                crate::error::check_len("event omega coefficients", omega, n)?;
                crate::error::check_finite("event theta coefficients", theta)?;
                crate::error::check_finite("event omega coefficients", omega)?;
                if !constant.is_finite() {
                    return Err(Error::input(format!("event constant must be finite, got {}", Shown(*constant))));
                }
                Ok(())
            }
            _ => Ok(()),
        }
    }
}

/// One recorded crossing: which event, when, and the raw ODE state there.
#[derive(Debug, Clone, PartialEq)]
pub struct Hit {
    pub event: usize,
    pub t: f64,
    pub y: Vec<f64>,
}

/// Tracks the event functions along a run.
pub(crate) struct Tracker<'a> {
    specs: &'a [EventSpec],
    chain: &'a Chain,
    form: Form,
    ws: Workspace,
    omega: Vec<f64>,
    prev: Vec<f64>,
    next: Vec<f64>,
    pub hits: Vec<Hit>,
}

impl<'a> Tracker<'a> {
    pub fn new(specs: &'a [EventSpec], chain: &'a Chain, form: Form) -> Self {
        let n = chain.n();
        Tracker { specs, chain, form, ws: Workspace::new(n), omega: vec![0.0; n], prev: vec![0.0; specs.len()], next: vec![0.0; specs.len()], hits: Vec::new() }
    }

    pub fn active(&self) -> bool {
        !self.specs.is_empty()
    }

    fn values(&mut self, t: f64, y: &[f64], out: &mut [f64]) -> Result<()> {
        let n = self.chain.n();
        let theta = &y[..n];
        let omega: &[f64] = match self.form {
            Form::Lagrangian => &y[n..2 * n],
            Form::Hamiltonian => {
                let p_x = if self.chain.cart().is_some() { y[2 * n + 1] } else { 0.0 };
                if self.chain.velocities_general(theta, &y[n..2 * n], p_x, &mut self.omega, &mut self.ws).is_err() {
                    self.omega.fill(f64::NAN);
                }
                &self.omega
            }
        };
        for (spec, o) in self.specs.iter().zip(out.iter_mut()) {
            *o = match &spec.condition {
                Condition::Flip(Some(k)) => theta[*k].abs() - std::f64::consts::PI,
                Condition::Flip(None) => theta.iter().fold(f64::NEG_INFINITY, |m, t| m.max(t.abs())) - std::f64::consts::PI,
                Condition::Linear { theta: a, omega: b, constant } => {
                    theta.iter().zip(a).map(|(x, c)| x * c).sum::<f64>() + omega.iter().zip(b).map(|(x, c)| x * c).sum::<f64>() + constant
                }
                Condition::Custom(f) => {
                    let v = f.value(t, theta, omega)?;
                    if !v.is_finite() {
                        return Err(Error::input(format!("the event function returned {v} at t = {t}")));
                    }
                    v
                }
            };
        }
        Ok(())
    }

    pub fn start(&mut self, t: f64, y: &[f64]) -> Result<()> {
        let mut v = std::mem::take(&mut self.prev);
        let r = self.values(t, y, &mut v);
        self.prev = v;
        r
    }

    fn crosses(&self, i: usize, a: f64, b: f64) -> bool {
        let up = a < 0.0 && b >= 0.0;
        let down = a > 0.0 && b <= 0.0;
        match self.specs[i].direction {
            1 => up,
            -1 => down,
            _ => up || down,
        }
    }

    /// After a step to `(t_new, y_new)`: does any event cross zero within it?
    pub fn detect(&mut self, t_new: f64, y_new: &[f64]) -> Result<bool> {
        let mut v = std::mem::take(&mut self.next);
        let r = self.values(t_new, y_new, &mut v);
        self.next = v;
        r?;
        Ok((0..self.specs.len()).any(|i| self.crosses(i, self.prev[i], self.next[i])))
    }

    /// Locate the crossings of the step `[t, t + h]` on `interp(x, out)` (the state at `t + x h`)
    /// by the Illinois method; record them in time order, up to the first terminal one, whose
    /// time and state are returned.
    pub fn locate(&mut self, t: f64, h: f64, mut interp: impl FnMut(f64, &mut [f64]) -> Result<()>, dim: usize) -> Result<Option<(f64, Vec<f64>)>> {
        let mut found: Vec<(f64, usize, Vec<f64>)> = Vec::new();
        let mut y = vec![0.0; dim];
        let mut vals = vec![0.0; self.specs.len()];
        for i in 0..self.specs.len() {
            if !self.crosses(i, self.prev[i], self.next[i]) {
                continue;
            }
            let (mut a, mut b, mut ga, mut gb) = (0.0f64, 1.0f64, self.prev[i], self.next[i]);
            let mut side = 0i8;
            for _ in 0..100 {
                if (b - a) <= 4.0 * f64::EPSILON {
                    break;
                }
                let mut x = (a * gb - b * ga) / (gb - ga);
                if !(x > a && x < b) {
                    x = 0.5 * (a + b);
                }
                interp(x, &mut y)?;
                self.values(t + x * h, &y, &mut vals)?;
                let gx = vals[i];
                if gx == 0.0 {
                    b = x;
                    break;
                }
                if (gx < 0.0) == (ga < 0.0) {
                    a = x;
                    ga = gx;
                    if side == -1 {
                        gb *= 0.5;
                    }
                    side = -1;
                } else {
                    b = x;
                    gb = gx;
                    if side == 1 {
                        ga *= 0.5;
                    }
                    side = 1;
                }
            }
            // The end at or past the crossing, so a terminal stop lands on the far side of zero.
            interp(b, &mut y)?;
            found.push((t + b * h, i, y.clone()));
        }
        found.sort_by(|p, q| p.0.total_cmp(&q.0));
        let mut terminal = None;
        for (te, i, ye) in found {
            self.hits.push(Hit { event: i, t: te, y: ye.clone() });
            if self.specs[i].terminal {
                terminal = Some((te, ye));
                break;
            }
        }
        std::mem::swap(&mut self.prev, &mut self.next);
        Ok(terminal)
    }

    /// The step had no crossing: move on.
    pub fn accept(&mut self) {
        std::mem::swap(&mut self.prev, &mut self.next);
    }
}
