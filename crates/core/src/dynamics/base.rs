//! What moves the chain's base: a prescribed pivot motion ([`Pivot`], each axis an [`Axis`]
//! with its position, velocity and acceleration), or the horizontal force on a cart ([`Force`]).
//! Both are plain data or shared callbacks (`Send + Sync`), so a batch can run them on every
//! core.
use std::fmt;
use std::sync::Arc;

use super::torque::{Builtin, Interp, TorqueSource};
use crate::error::{Error, Result, Shown};
use crate::trig::lanes::{each, sin_cos, Lane, LANES};

/// A prescribed coordinate of the pivot as a function of time, with two derivatives.
#[derive(Clone)]
pub enum Axis {
    Fixed(f64),
    /// `offset + amplitude sin(frequency t + phase)`, frequency in rad/s.
    Sinusoid {
        amplitude: f64,
        frequency: f64,
        phase: f64,
        offset: f64,
    },
    /// The natural cubic spline through `(t_k, x_k)` (second derivatives `m_k`), continued by
    /// its end tangents outside the table: twice continuously differentiable everywhere, since a
    /// natural spline has no curvature at its ends.
    Spline {
        t: Vec<f64>,
        x: Vec<f64>,
        m: Vec<f64>,
    },
    /// A callback returning `(position, velocity, acceleration)` at `t`.
    Function(Arc<dyn AxisFn>),
}

/// A user's function of time for a pivot axis.
pub trait AxisFn: Send + Sync {
    fn eval(&self, t: f64) -> Result<[f64; 3]>;
}

impl fmt::Debug for Axis {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Axis::Fixed(x) => write!(f, "Fixed({x})"),
            Axis::Sinusoid { amplitude, frequency, phase, offset } => {
                write!(f, "Sinusoid({amplitude}, {frequency}, {phase}, {offset})")
            }
            Axis::Spline { t, .. } => write!(f, "Spline({} points)", t.len()),
            Axis::Function(_) => write!(f, "Function"),
        }
    }
}

impl Axis {
    pub fn sinusoid(name: &str, amplitude: f64, frequency: f64, phase: f64, offset: f64) -> Result<Self> {
        for (what, v) in [("amplitude", amplitude), ("frequency", frequency), ("phase", phase), ("offset", offset)] {
            if !v.is_finite() {
                return Err(Error::input(format!("pivot {name}: {what} must be finite, got {}", Shown(v))));
            }
        }
        Ok(Axis::Sinusoid { amplitude, frequency, phase, offset })
    }

    pub fn fixed(name: &str, x: f64) -> Result<Self> {
        if !x.is_finite() {
            return Err(Error::input(format!("pivot {name} must be finite, got {}", Shown(x))));
        }
        Ok(Axis::Fixed(x))
    }

    /// The natural cubic spline through the samples (at least 2, times strictly increasing).
    pub fn spline(name: &str, t: Vec<f64>, x: Vec<f64>) -> Result<Self> {
        let k = t.len();
        if k < 2 {
            return Err(Error::input(format!("pivot {name}: a cubic table needs at least 2 samples, got {k}")));
        }
        if x.len() != k {
            return Err(Error::input(format!("pivot {name}: values must have {k} entries (one per time), got {}", x.len())));
        }
        // The same table and spline as the torques': one column.
        match Builtin::table(1, t, x, Interp::Cubic) {
            Ok(Builtin::Table { times, values, second, .. }) => Ok(Axis::Spline { t: times, x: values, m: second }),
            Ok(_) => unreachable!("a table is a table"),
            Err(e) => Err(Error::input(format!("pivot {name}: {e}"))),
        }
    }

    /// Whether the coordinate stays where it is.
    pub fn is_fixed(&self) -> bool {
        matches!(self, Axis::Fixed(_)) || matches!(self, Axis::Sinusoid { amplitude, .. } if *amplitude == 0.0)
    }

    /// `(position, velocity, acceleration)` at `t`.
    #[inline]
    pub fn eval(&self, t: f64) -> Result<[f64; 3]> {
        Ok(match self {
            Axis::Fixed(x) => [*x, 0.0, 0.0],
            Axis::Sinusoid { amplitude, frequency, phase, offset } => {
                let (s, c) = (frequency * t + phase).sin_cos();
                [offset + amplitude * s, amplitude * frequency * c, -amplitude * frequency * frequency * s]
            }
            Axis::Spline { t: times, x, m } => {
                let k = times.len();
                if t <= times[0] || t >= times[k - 1] {
                    // The end tangent (the second derivative is zero there).
                    let (j, end) = if t <= times[0] { (0, 0) } else { (k - 2, k - 1) };
                    let h = times[j + 1] - times[j];
                    let slope = (x[j + 1] - x[j]) / h + if end == 0 { -(2.0 * m[j] + m[j + 1]) * h / 6.0 } else { (m[j] + 2.0 * m[j + 1]) * h / 6.0 };
                    return Ok([x[end] + slope * (t - times[end]), slope, 0.0]);
                }
                let j = times.partition_point(|&s| s <= t) - 1;
                let h = times[j + 1] - times[j];
                let (a, b) = ((times[j + 1] - t) / h, (t - times[j]) / h);
                let (m0, m1) = (m[j], m[j + 1]);
                let pos = x[j] + b * (x[j + 1] - x[j]) + ((a * a * a - a) * m0 + (b * b * b - b) * m1) * h * h / 6.0;
                let vel = (x[j + 1] - x[j]) / h + ((1.0 - 3.0 * a * a) * m0 + (3.0 * b * b - 1.0) * m1) * h / 6.0;
                [pos, vel, a * m0 + b * m1]
            }
            Axis::Function(f) => f.eval(t)?,
        })
    }
}

impl Axis {
    /// The acceleration at each lane's time `at`, for the SIMD lanes: a sinusoid's through the
    /// lanes' own `sin` (their round-off, as their dynamics'), a table's as [`Axis::eval`];
    /// NaN for a function, which the lanes cannot call (never asked: [`Pivot::in_lanes`]).
    #[inline(always)]
    pub fn acc_lanes(&self, at: &Lane) -> Lane {
        match self {
            Axis::Fixed(_) => [0.0; LANES],
            Axis::Sinusoid { amplitude, frequency, phase, .. } => {
                let arg: Lane = each(|i| frequency * at[i] + phase);
                let (sin, _) = sin_cos(&arg);
                let k = -amplitude * frequency * frequency;
                sin.map(|s| k * s)
            }
            Axis::Spline { .. } => each(|i| self.eval(at[i]).map_or(f64::NAN, |m| m[2])),
            Axis::Function(_) => [f64::NAN; LANES],
        }
    }
}

/// The pivot's prescribed motion `(x_p(t), y_p(t))`.
#[derive(Debug, Clone)]
pub struct Pivot {
    pub x: Axis,
    pub y: Axis,
}

/// The pivot's position, velocity and acceleration at one instant.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Motion {
    pub pos: [f64; 2],
    pub vel: [f64; 2],
    pub acc: [f64; 2],
}

impl Pivot {
    pub fn fixed() -> Self {
        Pivot { x: Axis::Fixed(0.0), y: Axis::Fixed(0.0) }
    }

    /// Whether it is held at the origin: no pivot motion at all.
    pub fn is_origin(&self) -> bool {
        let origin = |a: &Axis| matches!(a, Axis::Fixed(x) if *x == 0.0);
        origin(&self.x) && origin(&self.y)
    }

    /// Whether the pivot stays where it is.
    pub fn is_fixed(&self) -> bool {
        self.x.is_fixed() && self.y.is_fixed()
    }

    /// Whether the SIMD lanes can evaluate it (no axis is a function).
    pub fn in_lanes(&self) -> bool {
        ![&self.x, &self.y].iter().any(|a| matches!(a, Axis::Function(_)))
    }

    /// The acceleration `(a_x, a_y)` at each lane's time ([`Axis::acc_lanes`]).
    #[inline(always)]
    pub fn acc_lanes(&self, at: &Lane) -> (Lane, Lane) {
        (self.x.acc_lanes(at), self.y.acc_lanes(at))
    }

    #[inline]
    pub fn eval(&self, t: f64) -> Result<Motion> {
        let (x, y) = (self.x.eval(t)?, self.y.eval(t)?);
        Ok(Motion { pos: [x[0], y[0]], vel: [x[1], y[1]], acc: [x[2], y[2]] })
    }
}

/// A user's cart force `F(t, state)`, `state = (x, theta_1..theta_N, v, omega_1..omega_N)`.
pub trait ForceFn: Send + Sync {
    fn eval(&self, t: f64, state: &[f64]) -> Result<f64>;
}

/// The horizontal force applied to a cart (besides its damping).
#[derive(Clone)]
pub enum Force {
    /// A constant, a sinusoid or a table of time, evaluated in Rust (one column).
    Builtin(Builtin),
    Function(Arc<dyn ForceFn>),
}

impl fmt::Debug for Force {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Force::Builtin(b) => write!(f, "Builtin({b:?})"),
            Force::Function(_) => write!(f, "Function"),
        }
    }
}

impl Force {
    /// Whether it needs the state (a feedback law).
    pub fn is_feedback(&self) -> bool {
        matches!(self, Force::Function(_))
    }

    #[inline]
    pub fn eval(&mut self, t: f64, state: &[f64]) -> Result<f64> {
        match self {
            Force::Builtin(b) => {
                let mut out = [0.0];
                b.eval(t, &[], &[], &mut out)?;
                Ok(out[0])
            }
            Force::Function(f) => {
                let v = f.eval(t, state)?;
                if !v.is_finite() {
                    return Err(Error::input(format!("the cart force function returned {v} at t = {t}")));
                }
                Ok(v)
            }
        }
    }
}

/// A run's base inputs: the pivot's motion (none: fixed at the origin) and the cart's force
/// (none: no applied force).
#[derive(Debug, Clone, Default)]
pub struct Drive {
    pub pivot: Option<Pivot>,
    pub force: Option<Force>,
}

impl Drive {
    pub fn none() -> Self {
        Drive::default()
    }

    /// Refuse what does not fit the chain: a cart force without a cart, a moving pivot with one.
    pub fn check(&self, chain: &crate::model::Chain) -> Result<()> {
        if self.force.is_some() && chain.cart().is_none() {
            return Err(Error::input("cart_force needs a chain with a cart (Chain(..., cart=Cart(mass)))"));
        }
        if chain.cart().is_some() && self.moving_pivot().is_some() {
            return Err(Error::input("a chain on a cart has no prescribed pivot motion: the cart moves the base (drive it with cart_force)"));
        }
        Ok(())
    }

    /// The pivot unless it is fixed at the origin (which is no pivot motion at all).
    pub fn moving_pivot(&self) -> Option<&Pivot> {
        self.pivot.as_ref().filter(|p| !p.is_origin())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_spline_axis_has_continuous_derivatives_and_matches_a_cubic() {
        // A natural spline reproduces a straight line, and continues it outside.
        let t: Vec<f64> = (0..6).map(|i| i as f64 * 0.5).collect();
        let x: Vec<f64> = t.iter().map(|t| 3.0 * t - 1.0).collect();
        let a = Axis::spline("x", t, x).unwrap();
        for s in [-1.0, 0.3, 1.7, 2.5, 4.0] {
            let [p, v, acc] = a.eval(s).unwrap();
            assert!((p - (3.0 * s - 1.0)).abs() < 1e-13 && (v - 3.0).abs() < 1e-13 && acc.abs() < 1e-12, "{s}: {p} {v} {acc}");
        }
        // Velocity and acceleration are the derivatives of the position (central differences).
        let t: Vec<f64> = (0..12).map(|i| i as f64 * 0.3).collect();
        let x: Vec<f64> = t.iter().map(|t| (1.3 * t).sin()).collect();
        let a = Axis::spline("x", t, x).unwrap();
        for s in [-0.5, 0.0, 0.01, 0.77, 1.2, 3.3, 3.5] {
            let e = 1e-5;
            let (p0, p1) = (a.eval(s - e).unwrap(), a.eval(s + e).unwrap());
            let c = a.eval(s).unwrap();
            assert!(((p1[0] - p0[0]) / (2.0 * e) - c[1]).abs() < 1e-8, "velocity at {s}");
            // (At a knot or an end the third derivative jumps: the difference is off by ~e |m|.)
            assert!(((p1[1] - p0[1]) / (2.0 * e) - c[2]).abs() < 1e-4, "acceleration at {s}");
        }
    }

    #[test]
    fn a_sinusoid_axis_has_its_derivatives() {
        let a = Axis::sinusoid("y", 0.1, 30.0, 0.2, 0.5).unwrap();
        let [p, v, acc] = a.eval(0.4).unwrap();
        let arg = 30.0 * 0.4 + 0.2f64;
        assert_eq!(p, 0.5 + 0.1 * arg.sin());
        assert_eq!(v, 0.1 * 30.0 * arg.cos());
        assert_eq!(acc, -0.1 * 900.0 * arg.sin());
    }

    #[test]
    fn short_tables_are_refused() {
        let e = Axis::spline("x", vec![0.0], vec![1.0]).unwrap_err();
        assert_eq!(e.to_string(), "pivot x: a cubic table needs at least 2 samples, got 1");
    }
}
