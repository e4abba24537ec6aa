//! What an environment asks of its copies besides their physics ([`Task`]): how an action
//! becomes joint torques or a cart's force, the observation, the reward and the end of an
//! episode. [`super::live::Steppers::act`] applies it around a step, so a vector environment's
//! step is one call into the core: its Python layer (clipping, scaling, the outcome's sums)
//! cost as much as the physics of 256 double pendulums.
use super::live::Column;
use crate::error::{Error, Result, Shown};
use crate::model::Chain;
use crate::trig::lanes::{each, on_path, sin_cos, Lane, Path, LANES};

/// Where an action's component goes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Target {
    /// The torque on joint `j` (from link `j - 1`, or the pivot, onto link `j`).
    Joint(usize),
    /// The horizontal force on the cart.
    Cart,
}

/// The reward and the end of an episode.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Goal {
    /// Swing the chain's tip up: terminated once it rises above the pivot by more than
    /// `above` (m); reward -1 per step, 0 on the step that ends the episode (gymnasium's Acrobot).
    Height { above: f64 },
    /// Keep every link within `angle_limit` (rad) of upright and the cart within
    /// `|x| <= x_limit`; reward 1 per step (gymnasium's CartPole).
    Balance { x_limit: f64, angle_limit: f64 },
    /// Reward `mean_i (1 - cos theta_i) / 2` per step (1 upright, 0 hanging); terminated only
    /// when the cart leaves `|x| <= x_limit`.
    SwingUp { x_limit: f64 },
}

/// An environment's actions, observation and outcome over copies of one chain.
#[derive(Debug, Clone, PartialEq)]
pub struct Task {
    /// Actions are 0, 1, 2 (the inputs `-scale`, 0, `+scale`); else numbers clipped to
    /// `[-1, 1]` and scaled.
    pub discrete: bool,
    /// Each action component's input.
    pub targets: Vec<Target>,
    /// Each component's largest input (N m or N).
    pub scale: Vec<f64>,
    pub columns: Vec<Column>,
    pub goal: Goal,
}

/// `x` as Python writes it (`nan`, `inf`, `1e+300`), so the environments' messages read alike.
fn number(x: f64) -> String {
    if x.is_nan() {
        "nan".into()
    } else {
        Shown(x).to_string()
    }
}

impl Task {
    /// The values a discrete action takes, `0..LEVELS` (the inputs `-scale`, 0, `+scale`).
    pub const LEVELS: usize = 3;

    /// The range of a continuous action's components; beyond it they are clipped.
    pub const BOUNDS: (f64, f64) = (-1.0, 1.0);

    /// A task for copies of `chain`, checked against it.
    pub fn new(chain: &Chain, discrete: bool, targets: Vec<Target>, scale: Vec<f64>, columns: Vec<Column>, goal: Goal) -> Result<Task> {
        if targets.is_empty() || targets.len() != scale.len() {
            return Err(Error::input(format!("a task needs one scale per action component, got {} targets and {} scales", targets.len(), scale.len())));
        }
        if let Some(s) = scale.iter().find(|s| !(s.is_finite() && **s > 0.0)) {
            return Err(Error::input(format!("each action scale must be > 0 and finite, got {}", Shown(*s))));
        }
        let limits: &[f64] = match &goal {
            Goal::Height { above } => std::slice::from_ref(above),
            Goal::Balance { x_limit, angle_limit } => &[*x_limit, *angle_limit],
            Goal::SwingUp { x_limit } => std::slice::from_ref(x_limit),
        };
        if limits.iter().any(|v| !(v.is_finite() && *v > 0.0)) {
            return Err(Error::input(format!("the goal's limits must be > 0 and finite, got {goal:?}")));
        }
        let task = Task { discrete, targets, scale, columns, goal };
        task.check(chain)?;
        Ok(task)
    }

    /// Whether the task fits copies of `chain`: its targets are distinct joints of the chain (or
    /// its cart), its columns within a state row, its goal one the chain has (a cart for the
    /// cart-pole's goals).
    pub fn check(&self, chain: &Chain) -> Result<()> {
        let (n, row, targets, goal) = (chain.n(), chain.state_len(), &self.targets, self.goal);
        for (a, t) in targets.iter().enumerate() {
            let ok = match *t {
                Target::Joint(j) => j < n,
                Target::Cart => chain.cart().is_some(),
            };
            if !ok || targets[..a].contains(t) {
                return Err(Error::input(format!(
                    "action component {a}: {t:?} is not a distinct input of this chain ({n} joints{})",
                    if chain.cart().is_some() { ", a cart" } else { "" }
                )));
            }
        }
        if let Some(c) = self.columns.iter().find(|c| c.index() >= row) {
            return Err(Error::input(format!("observation column {c:?} is outside a state row of {row} values")));
        }
        if !matches!(goal, Goal::Height { .. }) && chain.cart().is_none() {
            return Err(Error::input(format!("{goal:?} needs a chain on a cart")));
        }
        Ok(())
    }

    /// Components of one action.
    pub fn width(&self) -> usize {
        self.targets.len()
    }

    /// One action's shape as gymnasium's spaces see it: `[]` for a discrete task of one
    /// component (one number per copy, gymnasium's `Discrete(3)`), else `[width]`
    /// (`MultiDiscrete` or a `Box`).
    pub fn action_shape(&self) -> Vec<usize> {
        if self.one_number() {
            Vec::new()
        } else {
            vec![self.width()]
        }
    }

    /// The values a discrete action takes, as a message names them (`0, 1 or 2`).
    fn levels() -> String {
        let all: Vec<String> = (0..Self::LEVELS).map(|v| v.to_string()).collect();
        match all.split_last() {
            Some((last, rest)) if !rest.is_empty() => format!("{} or {last}", rest.join(", ")),
            _ => all.join(""),
        }
    }

    /// Whether one action is one number (a discrete task of one component), not an array.
    fn one_number(&self) -> bool {
        self.discrete && self.width() == 1
    }

    /// Actions (count x [`Task::width`], row-major) as joint torques (count x N) and cart
    /// forces (count; empty without a cart). Continuous actions out of `[-1, 1]` are clipped
    /// (gymnasium's Pendulum), not finite ones refused; discrete ones must be 0, 1 or 2. A
    /// refused action names its index in the actions' array: `(copy, component)` when `batched`,
    /// else `(component,)`; a discrete task of one component takes one number per copy
    /// (gymnasium's `Discrete(3)`), so there `(copy,)`, and a single action has no index.
    pub fn inputs(&self, chain: &Chain, actions: &[f64], batched: bool, torques: &mut [f64], forces: &mut [f64]) -> Result<()> {
        let (k, n) = (self.width(), chain.n());
        let count = actions.len() / k;
        if actions.len() != count * k || torques.len() != count * n || forces.len() != if chain.cart().is_some() { count } else { 0 } {
            return Err(Error::input(format!("{} action values do not make whole actions of {k} for {} copies", actions.len(), torques.len() / n.max(1))));
        }
        let scalar = self.one_number();
        let at = |i: usize| match (batched, scalar) {
            (true, false) => format!(" at index ({}, {})", i / k, i % k),
            (true, true) => format!(" at index ({i},)"),
            (false, false) => format!(" at index ({},)", i % k),
            (false, true) => String::new(),
        };
        for (i, &a) in actions.iter().enumerate() {
            if self.discrete {
                if !(a.fract() == 0.0 && (0.0..Self::LEVELS as f64).contains(&a)) {
                    return Err(Error::input(format!("a discrete action must be {}, got {}{}", Self::levels(), number(a), at(i))));
                }
            } else if !a.is_finite() {
                return Err(Error::input(format!("action must be finite, got {}{}", number(a), at(i))));
            }
        }
        torques.fill(0.0);
        for (c, action) in actions.chunks(k).enumerate() {
            for ((&a, &s), t) in action.iter().zip(&self.scale).zip(&self.targets) {
                let level = if self.discrete { a - 1.0 } else { a.clamp(Self::BOUNDS.0, Self::BOUNDS.1) };
                match *t {
                    Target::Joint(j) => torques[c * n + j] = level * s,
                    Target::Cart => forces[c] = level * s,
                }
            }
        }
        Ok(())
    }

    /// Each copy's reward and whether its episode ended, from its state row (count x
    /// `state_len`, as the steppers report them).
    pub fn outcome(&self, chain: &Chain, states: &[f64], reward: &mut [f64], terminated: &mut [bool]) {
        outcome_on(Path::best(), self, chain, states, reward, terminated)
    }
}

/// Angles into `[-pi, pi)`.
#[inline(always)]
fn wrap(a: f64) -> f64 {
    (a + std::f64::consts::PI).rem_euclid(2.0 * std::f64::consts::PI) - std::f64::consts::PI
}

/// [`Task::outcome`], eight copies at a time for the cosines (the lanes' `cos`, as the
/// observations'). No closures but `each`'s (inlined): a closure's body would compile outside the
/// callers' target features (see `observe` in `super::live`).
#[inline(always)]
fn outcome(task: &Task, chain: &Chain, states: &[f64], reward: &mut [f64], terminated: &mut [bool]) {
    let (n, k) = (chain.n(), chain.state_len());
    let lengths = chain.lengths();
    for ((rows, reward), ended) in states.chunks(LANES * k).zip(reward.chunks_mut(LANES)).zip(terminated.chunks_mut(LANES)) {
        let copies = rows.len() / k;
        match task.goal {
            Goal::Height { above } => {
                let mut height: Lane = [0.0; LANES];
                for (i, &l) in lengths.iter().enumerate() {
                    let (_, cos) = sin_cos(&each(|c| if c < copies { rows[c * k + i] } else { 0.0 }));
                    for c in 0..LANES {
                        height[c] -= l * cos[c];
                    }
                }
                for c in 0..copies {
                    ended[c] = height[c] > above;
                    reward[c] = if ended[c] { 0.0 } else { -1.0 };
                }
            }
            Goal::Balance { x_limit, angle_limit } => {
                for c in 0..copies {
                    let row = &rows[c * k..(c + 1) * k];
                    let mut out = row[2 * n].abs() > x_limit;
                    for &theta in &row[..n] {
                        out |= wrap(theta - std::f64::consts::PI).abs() > angle_limit;
                    }
                    ended[c] = out;
                    reward[c] = 1.0;
                }
            }
            Goal::SwingUp { x_limit } => {
                let mut sum: Lane = [0.0; LANES];
                for i in 0..n {
                    let (_, cos) = sin_cos(&each(|c| if c < copies { rows[c * k + i] } else { 0.0 }));
                    for c in 0..LANES {
                        sum[c] += 1.0 - cos[c];
                    }
                }
                for c in 0..copies {
                    ended[c] = rows[c * k + 2 * n].abs() > x_limit;
                    reward[c] = sum[c] / n as f64 / 2.0;
                }
            }
        }
    }
}

on_path! {
    fn outcome_on(task: &Task, chain: &Chain, states: &[f64], reward: &mut [f64], terminated: &mut [bool]) {
        outcome(task, chain, states, reward, terminated)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::Cart;
    use crate::run::live::{Acted, Steppers};
    use crate::run::simulate::Settings;
    use std::f64::consts::PI;

    fn acrobot() -> Chain {
        Chain::rods(&[1.0, 0.7], &[1.0, 0.5], 9.81).unwrap()
    }

    fn cartpole(n: usize) -> Chain {
        Chain::rods(&vec![0.8; n], &vec![0.2; n], 9.81).unwrap().with_cart(Some(Cart::new(1.0, 0.0).unwrap())).unwrap()
    }

    fn observe_all(n: usize) -> Vec<Column> {
        (0..n).map(Column::Cos).collect()
    }

    #[test]
    fn actions_become_the_inputs_of_their_targets() {
        let chain = cartpole(3);
        let task = Task::new(
            &chain,
            false,
            vec![Target::Joint(2), Target::Cart, Target::Joint(0)],
            vec![2.0, 10.0, 0.5],
            observe_all(3),
            Goal::SwingUp { x_limit: 2.4 },
        )
        .unwrap();
        let actions = [0.25, -3.0, 1.0, 1.5, 0.0, -0.75];
        let (mut torques, mut forces) = ([9.0; 6], [9.0; 2]);
        task.inputs(&chain, &actions, true, &mut torques, &mut forces).unwrap();
        // Clipped to [-1, 1], then scaled; joint 1 has no motor.
        assert_eq!(torques, [1.0 * 0.5, 0.0, 0.25 * 2.0, -0.75 * 0.5, 0.0, 1.0 * 2.0]);
        assert_eq!(forces, [-10.0, 0.0]);

        let chain = acrobot();
        let task = Task::new(&chain, true, vec![Target::Joint(1)], vec![1.5], observe_all(2), Goal::Height { above: 0.85 }).unwrap();
        let (mut torques, mut forces) = ([9.0; 6], [0.0; 0]);
        task.inputs(&chain, &[0.0, 1.0, 2.0], true, &mut torques, &mut forces).unwrap();
        assert_eq!(torques, [0.0, -1.5, 0.0, 0.0, 0.0, 1.5]);
    }

    #[test]
    fn a_refused_action_names_its_value_and_index() {
        let chain = acrobot();
        let both = vec![Target::Joint(0), Target::Joint(1)];
        let task = Task::new(&chain, false, both.clone(), vec![1.0, 1.0], observe_all(2), Goal::Height { above: 0.85 }).unwrap();
        let (mut torques, mut forces) = ([0.0; 4], [0.0; 0]);
        let message = |r: Result<()>| match r {
            Err(Error::Input(m)) => m,
            other => panic!("expected an input error, got {other:?}"),
        };
        assert_eq!(message(task.inputs(&chain, &[0.0, 1.0, f64::NAN, 0.0], true, &mut torques, &mut forces)), "action must be finite, got nan at index (1, 0)");
        assert_eq!(
            message(task.inputs(&chain, &[0.0, f64::NEG_INFINITY], false, &mut torques[..2], &mut forces)),
            "action must be finite, got -inf at index (1,)"
        );
        let discrete = Task::new(&chain, true, both, vec![1.0, 1.0], observe_all(2), Goal::Height { above: 0.85 }).unwrap();
        assert_eq!(
            message(discrete.inputs(&chain, &[0.0, 1.0, 2.0, 1.5], true, &mut torques, &mut forces)),
            "a discrete action must be 0, 1 or 2, got 1.5 at index (1, 1)"
        );
        assert_eq!(
            message(discrete.inputs(&chain, &[3.0, 1.0], false, &mut torques[..2], &mut forces)),
            "a discrete action must be 0, 1 or 2, got 3 at index (0,)"
        );
        // One discrete component: one number per copy (gymnasium's Discrete), so one index or none.
        let single = Task::new(&chain, true, vec![Target::Joint(1)], vec![1.0], observe_all(2), Goal::Height { above: 0.85 }).unwrap();
        assert_eq!((single.action_shape(), discrete.action_shape(), task.action_shape()), (vec![], vec![2], vec![2]));
        for (bad, shown) in [(f64::INFINITY, "inf"), (0.5, "0.5"), (2.000000001, "2.000000001"), (1e300, "1e+300")] {
            assert_eq!(
                message(single.inputs(&chain, &[bad], false, &mut torques[..2], &mut forces)),
                format!("a discrete action must be 0, 1 or 2, got {shown}")
            );
        }
        assert_eq!(message(single.inputs(&chain, &[0.0, -1.0], true, &mut torques, &mut forces)), "a discrete action must be 0, 1 or 2, got -1 at index (1,)");
        assert_eq!(message(single.inputs(&chain, &[f64::NAN], false, &mut torques[..2], &mut forces)), "a discrete action must be 0, 1 or 2, got nan");
        // Nothing was written by a refused call.
        assert_eq!(torques, [0.0; 4]);
    }

    #[test]
    fn tasks_that_do_not_fit_their_chain_are_refused() {
        let chain = acrobot();
        let height = Goal::Height { above: 0.85 };
        let bad = [
            Task::new(&chain, false, vec![Target::Joint(2)], vec![1.0], vec![], height),
            Task::new(&chain, false, vec![Target::Cart], vec![1.0], vec![], height),
            Task::new(&chain, false, vec![Target::Joint(1), Target::Joint(1)], vec![1.0, 1.0], vec![], height),
            Task::new(&chain, false, vec![Target::Joint(1)], vec![0.0], vec![], height),
            Task::new(&chain, false, vec![Target::Joint(1)], vec![1.0, 2.0], vec![], height),
            Task::new(&chain, false, vec![Target::Joint(1)], vec![1.0], vec![Column::Sin(4)], height),
            Task::new(&chain, false, vec![Target::Joint(1)], vec![1.0], vec![], Goal::Height { above: f64::NAN }),
            Task::new(&chain, false, vec![Target::Joint(1)], vec![1.0], vec![], Goal::SwingUp { x_limit: 1.0 }),
        ];
        for (i, t) in bad.into_iter().enumerate() {
            assert!(matches!(t, Err(Error::Input(_))), "case {i}: {t:?}");
        }
        // A task made for a longer chain, given to steppers of this one: refused, not a panic.
        let longer = Chain::rods(&[1.0; 3], &[1.0; 3], 9.81).unwrap();
        let task = Task::new(&longer, false, vec![Target::Joint(2)], vec![1.0], vec![Column::Cos(2)], height).unwrap();
        let settings = Settings { method: crate::integrators::Method::Rk4, dt: Some(0.01), ..Settings::default() };
        for route in [None, Some(crate::trig::lanes::Path::best())] {
            let mut st = Steppers::with_route(&chain, 2, &settings, route).unwrap();
            let (mut s, mut b, mut o) = (vec![0.0; 8], vec![0.0; 6], vec![0.0; 2]);
            let (mut r, mut e, mut t) = ([0.0; 2], [false; 2], [false; 2]);
            let out = Acted { states: &mut s, balance: &mut b, obs: &mut o, reward: &mut r, terminated: &mut e, truncated: &mut t };
            let got = st.act(&task, &[0.5, 0.5], true, 0.1, &[], (&mut [0, 0], None), out);
            assert!(matches!(&got, Err(Error::Input(m)) if m.contains("Joint(2) is not a distinct input")), "{got:?}");
        }
    }

    /// The outcome from the chain's Cartesian positions (the tip's height) and the angles' own
    /// distance from upright, written here without the lanes.
    #[test]
    fn outcomes_follow_the_tip_height_and_the_lean() {
        let chain = acrobot();
        let above = 0.5 * 1.7;
        let task = Task::new(&chain, false, vec![Target::Joint(1)], vec![1.0], vec![], Goal::Height { above }).unwrap();
        let rows: Vec<[f64; 4]> = (0..19).map(|i| [0.37 * i as f64 - 3.0, 0.61 * i as f64 + 0.2, 0.1, -0.2]).collect();
        let states: Vec<f64> = rows.iter().flatten().copied().collect();
        let (mut reward, mut ended) = (vec![0.0; rows.len()], vec![false; rows.len()]);
        task.outcome(&chain, &states, &mut reward, &mut ended);
        let mut seen = [false; 2];
        for (c, row) in rows.iter().enumerate() {
            let mut at = [0.0; 4];
            chain.positions_into(&row[..2], &mut at);
            let tip = at[3];
            assert!((tip - above).abs() > 1e-9, "no state on the threshold");
            assert_eq!(ended[c], tip > above, "copy {c}: tip at {tip}");
            assert_eq!(reward[c], if tip > above { 0.0 } else { -1.0 });
            seen[usize::from(ended[c])] = true;
        }
        assert_eq!(seen, [true, true], "both outcomes among the states");

        let chain = cartpole(2);
        let balance = Task::new(&chain, false, vec![Target::Cart], vec![10.0], vec![], Goal::Balance { x_limit: 2.4, angle_limit: 0.2 }).unwrap();
        let swing = Task::new(&chain, false, vec![Target::Cart], vec![10.0], vec![], Goal::SwingUp { x_limit: 2.4 }).unwrap();
        // (theta_1, theta_2, x): upright within the limit (some a full turn away), leaning, off the track.
        let cases = [
            (PI + 0.1, PI - 0.15, 0.0, false),
            (3.0 * PI - 0.1, -PI + 0.05, 1.0, false),
            (PI + 0.25, PI, 0.0, true),
            (PI, PI - 0.3, 0.0, true),
            (PI, PI, -2.5, true),
            (0.3, 0.0, 0.0, true),
        ];
        let states: Vec<f64> = cases.iter().flat_map(|&(a, b, x, _)| [a, b, 0.0, 0.0, x, 0.0]).collect();
        let (mut reward, mut ended) = (vec![0.0; cases.len()], vec![false; cases.len()]);
        balance.outcome(&chain, &states, &mut reward, &mut ended);
        for (c, case) in cases.iter().enumerate() {
            assert_eq!((ended[c], reward[c]), (case.3, 1.0), "balance, case {c}");
        }
        swing.outcome(&chain, &states, &mut reward, &mut ended);
        for (c, &(a, b, x, _)) in cases.iter().enumerate() {
            let want = ((1.0 - a.cos()) + (1.0 - b.cos())) / 2.0 / 2.0;
            assert!((reward[c] - want).abs() < 1e-15, "swing-up, case {c}: {} against {want}", reward[c]);
            assert_eq!(ended[c], x.abs() > 2.4);
        }
    }

    /// `act` is the step with the inputs written out by hand, bit for bit, on each route; a copy
    /// held still earns 0, does not end and does not count a step; truncation at the limit.
    #[test]
    fn acting_is_stepping_with_the_tasks_inputs() {
        let chain = cartpole(2);
        let settings = Settings { method: crate::integrators::Method::Rk4, dt: Some(0.005), ..Settings::default() };
        let columns = vec![Column::Value(4), Column::Cos(0), Column::Sin(1), Column::Value(3)];
        let task =
            Task::new(&chain, false, vec![Target::Cart, Target::Joint(1)], vec![10.0, 2.0], columns.clone(), Goal::Balance { x_limit: 2.4, angle_limit: 0.2 })
                .unwrap();
        let count = 11;
        let actions: Vec<f64> = (0..2 * count).map(|i| ((i * 7) % 5) as f64 * 0.6 - 1.2).collect();
        let mut torques = vec![0.0; 2 * count];
        let mut forces = vec![0.0; count];
        for c in 0..count {
            forces[c] = actions[2 * c].clamp(-1.0, 1.0) * 10.0;
            torques[2 * c + 1] = actions[2 * c + 1].clamp(-1.0, 1.0) * 2.0;
        }
        for route in [None, Some(crate::trig::lanes::Path::best())] {
            let start = |st: &mut Steppers| {
                for c in 0..count {
                    st.reset(c, &[PI + 0.01 * c as f64, PI - 0.02], &[0.0, 0.1], [if c == 7 { 3.0 } else { 0.05 * c as f64 }, 0.0]).unwrap();
                }
            };
            let mut acted = Steppers::with_route(&chain, count, &settings, route).unwrap();
            let mut stepped = Steppers::with_route(&chain, count, &settings, route).unwrap();
            start(&mut acted);
            start(&mut stepped);
            let mut active = vec![true; count];
            active[3] = false;
            let mut steps = vec![0u64; count];
            steps[5] = 6;
            let (mut s1, mut b1, mut obs) = (vec![0.0; count * 6], vec![0.0; count * 3], vec![0.0; count * 4]);
            let (mut reward, mut ended, mut truncated) = (vec![0.0; count], vec![false; count], vec![false; count]);
            let out = Acted { states: &mut s1, balance: &mut b1, obs: &mut obs, reward: &mut reward, terminated: &mut ended, truncated: &mut truncated };
            let n_ended = acted.act(&task, &actions, true, 0.02, &active, (&mut steps, Some(7)), out).unwrap();
            let (mut s2, mut b2) = (vec![0.0; count * 6], vec![0.0; count * 3]);
            stepped.step(&torques, &forces, 0.02, &active, &mut s2, &mut b2).unwrap();
            assert_eq!(s1, s2, "{route:?}: the states, bit for bit");
            assert_eq!(b1, b2, "{route:?}: the balances, bit for bit");
            let mut want_obs = vec![0.0; count * 4];
            stepped.observe_into(&s2, &columns, &mut want_obs).unwrap();
            assert_eq!(obs, want_obs);
            let (mut want_reward, mut want_ended) = (vec![0.0; count], vec![false; count]);
            task.outcome(&chain, &s2, &mut want_reward, &mut want_ended);
            for c in 0..count {
                if c == 3 {
                    assert_eq!((reward[c], ended[c], truncated[c], steps[c]), (0.0, false, false, 0), "the copy held still");
                } else {
                    assert_eq!((reward[c], ended[c]), (want_reward[c], want_ended[c]), "copy {c}");
                    assert_eq!((steps[c], truncated[c]), if c == 5 { (7, true) } else { (1, false) }, "copy {c}");
                }
            }
            let want_n = (0..count).filter(|&c| c != 3 && (want_ended[c] || c == 5)).count();
            assert_eq!(n_ended, want_n);
            assert!(want_ended.iter().any(|&e| e) && want_ended.iter().any(|&e| !e), "both outcomes among the copies");
        }
    }
}
