//! Driving torques. A [`TorqueSource`] writes generalized torques `tau_i(t)` conjugate to the
//! absolute angles (seed 000's convention). [`Joint`] wraps a source of joint-motor torques `u_i`
//! (acting between link i-1 and link i, the robotics convention) and maps them to
//! `tau_i = u_i - u_{i+1}`.
use crate::error::{check_finite, Error, Result, Shown};
use crate::trig::lanes::{each, sin_cos, Lane, LANES};

pub trait TorqueSource {
    /// `false` for the undriven chain: the integrators then skip the call and the work integral.
    fn active(&self) -> bool {
        true
    }
    /// Whether the torques depend on the state (feedback), not on time alone: the variational
    /// equations take torques as functions of time, so such a run has no sensitivities.
    fn uses_state(&self) -> bool {
        false
    }
    /// Write the torques at time `t` in state `(theta, omega)` into `out`.
    fn eval(&mut self, t: f64, theta: &[f64], omega: &[f64], out: &mut [f64]) -> Result<()>;
    /// The same torques as the SIMD lanes take them (a built-in of time, [`Timed`]); `None` for
    /// a source the lanes cannot evaluate (a function of Python, say).
    fn timed(&self) -> Option<Timed> {
        None
    }
}

/// Interpolation between table samples.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Interp {
    Linear,
    /// Natural cubic spline (zero second derivative at both ends).
    Cubic,
}

/// The torques that are evaluated in Rust with no call back into Python.
#[derive(Debug, Clone, PartialEq)]
pub enum Builtin {
    None,
    Constant(Vec<f64>),
    /// `offset_i + amplitude_i sin(frequency_i t + phase_i)`, frequency in rad/s.
    Sinusoid {
        amplitude: Vec<f64>,
        frequency: Vec<f64>,
        phase: Vec<f64>,
        offset: Vec<f64>,
    },
    /// Samples `values` (row-major, `times.len()` x N), held at the end values outside the range.
    Table {
        times: Vec<f64>,
        values: Vec<f64>,
        interp: Interp,
        second: Vec<f64>,
    },
}

impl Builtin {
    pub fn constant(n: usize, values: Vec<f64>) -> Result<Self> {
        check_arr("torque", &values, n)?;
        Ok(Builtin::Constant(values))
    }

    pub fn sinusoid(n: usize, amplitude: Vec<f64>, frequency: Vec<f64>, phase: Vec<f64>, offset: Vec<f64>) -> Result<Self> {
        check_arr("amplitude", &amplitude, n)?;
        check_arr("frequency", &frequency, n)?;
        check_arr("phase", &phase, n)?;
        check_arr("offset", &offset, n)?;
        Ok(Builtin::Sinusoid { amplitude, frequency, phase, offset })
    }

    pub fn table(n: usize, times: Vec<f64>, values: Vec<f64>, interp: Interp) -> Result<Self> {
        let k = times.len();
        if k < 2 {
            return Err(Error::input(format!("a torque table needs at least 2 samples, got {k}")));
        }
        check_finite("t", &times)?;
        if let Some(i) = (1..k).find(|&i| !(times[i] > times[i - 1])) {
            return Err(Error::input(format!("t[{i}] must be > t[{}] (strictly increasing), got {} after {}", i - 1, Shown(times[i]), Shown(times[i - 1]))));
        }
        if values.len() != k * n {
            return Err(Error::input(format!("values must have shape ({k}, {n}) (one row per sample, one column per link), got {} numbers", values.len())));
        }
        check_finite("values", &values)?;
        let second = if interp == Interp::Cubic { natural_spline(&times, &values, n) } else { Vec::new() };
        Ok(Builtin::Table { times, values, interp, second })
    }
}

fn check_arr(name: &str, v: &[f64], n: usize) -> Result<()> {
    crate::error::check_len(name, v, n)?;
    check_finite(name, v)
}

/// Second derivatives of the natural cubic spline through each column (Thomas algorithm).
fn natural_spline(t: &[f64], y: &[f64], n: usize) -> Vec<f64> {
    let k = t.len();
    let mut m = vec![0.0; k * n];
    let (mut c, mut d) = (vec![0.0; k], vec![0.0; k]);
    for col in 0..n {
        for i in 1..k - 1 {
            let (h0, h1) = (t[i] - t[i - 1], t[i + 1] - t[i]);
            let rhs = 6.0 * ((y[(i + 1) * n + col] - y[i * n + col]) / h1 - (y[i * n + col] - y[(i - 1) * n + col]) / h0);
            let diag = 2.0 * (h0 + h1) - h0 * c[i - 1];
            c[i] = h1 / diag;
            d[i] = (rhs - h0 * d[i - 1]) / diag;
        }
        for i in (1..k - 1).rev() {
            m[i * n + col] = d[i] - c[i] * m[(i + 1) * n + col];
        }
    }
    m
}

impl TorqueSource for Builtin {
    fn active(&self) -> bool {
        !matches!(self, Builtin::None)
    }
    fn timed(&self) -> Option<Timed> {
        Some(Timed { builtin: self.clone(), joint: false })
    }

    fn eval(&mut self, t: f64, _theta: &[f64], _omega: &[f64], out: &mut [f64]) -> Result<()> {
        if let Builtin::None = self {
            out.fill(0.0);
        }
        self.each(t, |i, v| out[i] = v);
        Ok(())
    }
}

impl Builtin {
    /// The torques at time `t`, each handed to `put(link, value)` (none for [`Builtin::None`]).
    #[inline]
    pub fn each(&self, t: f64, mut put: impl FnMut(usize, f64)) {
        match self {
            Builtin::None => {}
            Builtin::Constant(v) => {
                for (i, &x) in v.iter().enumerate() {
                    put(i, x);
                }
            }
            Builtin::Sinusoid { amplitude, frequency, phase, offset } => {
                for i in 0..offset.len() {
                    put(i, offset[i] + amplitude[i] * (frequency[i] * t + phase[i]).sin());
                }
            }
            Builtin::Table { times, values, interp, second } => {
                let n = values.len() / times.len();
                let k = times.len();
                if t <= times[0] || t >= times[k - 1] {
                    let row = if t <= times[0] { 0 } else { k - 1 };
                    for i in 0..n {
                        put(i, values[row * n + i]);
                    }
                    return;
                }
                let j = times.partition_point(|&s| s <= t) - 1; // times[j] <= t < times[j+1]
                let h = times[j + 1] - times[j];
                let (a, b) = ((times[j + 1] - t) / h, (t - times[j]) / h);
                for i in 0..n {
                    let (y0, y1) = (values[j * n + i], values[(j + 1) * n + i]);
                    // Exact on flat segments (a * y0 + b * y1 is not, since a + b rounds).
                    let mut o = y0 + b * (y1 - y0);
                    if *interp == Interp::Cubic {
                        let (m0, m1) = (second[j * n + i], second[(j + 1) * n + i]);
                        o += ((a * a * a - a) * m0 + (b * b * b - b) * m1) * h * h / 6.0;
                    }
                    put(i, o);
                }
            }
        }
    }
}

/// Joint-motor torques `u` (in `out`) to generalized ones, in place: `tau_i = u_i - u_{i+1}`.
#[inline]
fn joint_to_generalized(out: &mut [f64]) {
    for i in 0..out.len().saturating_sub(1) {
        out[i] -= out[i + 1];
    }
}

/// A torque of time alone evaluated in Rust: a built-in, generalized or in the joint-motor
/// convention (`joint`). What the SIMD lanes take ([`Timed::lanes`]), as runs do (it is a
/// [`TorqueSource`]).
#[derive(Debug, Clone, PartialEq)]
pub struct Timed {
    pub builtin: Builtin,
    pub joint: bool,
}

impl Timed {
    /// A built-in generalized torque as a drive; `None` where there is no torque.
    pub fn generalized(torque: &Builtin) -> Option<Timed> {
        torque.active().then(|| Timed { builtin: torque.clone(), joint: false })
    }

    /// The generalized torques of every lane at its time `at[i]` into `out` (`out[link][i]`):
    /// a sinusoid through the lanes' own `sin` (the lanes' round-off, as their dynamics').
    #[inline(always)]
    pub fn lanes(&self, at: &Lane, out: &mut [Lane]) {
        match &self.builtin {
            Builtin::Sinusoid { amplitude, frequency, phase, offset } => {
                for (a, o) in out.iter_mut().enumerate() {
                    let arg: Lane = each(|i| frequency[a] * at[i] + phase[a]);
                    let (sin, _) = sin_cos(&arg);
                    for i in 0..LANES {
                        o[i] = offset[a] + amplitude[a] * sin[i];
                    }
                }
            }
            Builtin::None => out.fill([0.0; LANES]),
            builtin => {
                for i in 0..LANES {
                    // Lanes at the same time (rk4's) share one evaluation.
                    if i > 0 && at[i] == at[0] {
                        for o in out.iter_mut() {
                            o[i] = o[0];
                        }
                    } else {
                        builtin.each(at[i], |a, v| out[a][i] = v);
                    }
                }
            }
        }
        if self.joint {
            for a in 0..out.len().saturating_sub(1) {
                for i in 0..LANES {
                    out[a][i] -= out[a + 1][i];
                }
            }
        }
    }
}

impl TorqueSource for Timed {
    fn active(&self) -> bool {
        self.builtin.active()
    }
    fn timed(&self) -> Option<Timed> {
        Some(self.clone())
    }

    fn eval(&mut self, t: f64, theta: &[f64], omega: &[f64], out: &mut [f64]) -> Result<()> {
        self.builtin.eval(t, theta, omega, out)?;
        if self.joint {
            joint_to_generalized(out);
        }
        Ok(())
    }
}

/// Joint-motor torques `u` mapped to generalized torques `tau_i = u_i - u_{i+1}`: the motor at
/// joint i turns link i forwards and pushes back on link i-1.
#[derive(Debug, Clone)]
pub struct Joint<T>(pub T);

impl<T: TorqueSource> TorqueSource for Joint<T> {
    fn active(&self) -> bool {
        self.0.active()
    }
    fn uses_state(&self) -> bool {
        self.0.uses_state()
    }
    fn eval(&mut self, t: f64, theta: &[f64], omega: &[f64], out: &mut [f64]) -> Result<()> {
        self.0.eval(t, theta, omega, out)?;
        joint_to_generalized(out);
        Ok(())
    }
    fn timed(&self) -> Option<Timed> {
        self.0.timed().filter(|t| !t.joint).map(|t| Timed { joint: true, ..t })
    }
}

impl<T: TorqueSource + ?Sized> TorqueSource for &mut T {
    fn active(&self) -> bool {
        (**self).active()
    }
    fn uses_state(&self) -> bool {
        (**self).uses_state()
    }
    fn eval(&mut self, t: f64, theta: &[f64], omega: &[f64], out: &mut [f64]) -> Result<()> {
        (**self).eval(t, theta, omega, out)
    }
    fn timed(&self) -> Option<Timed> {
        (**self).timed()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn joint_torques_map_to_differences() {
        let mut j = Joint(Builtin::Constant(vec![3.0, 2.0, 0.5]));
        let mut out = [0.0; 3];
        j.eval(0.0, &[0.0; 3], &[0.0; 3], &mut out).unwrap();
        assert_eq!(out, [1.0, 1.5, 0.5]);
    }

    #[test]
    fn tables_reproduce_lines_and_the_natural_spline_keeps_its_error_bound() {
        let times: Vec<f64> = (0..40).map(|i| i as f64 * 0.25).collect();
        let line: Vec<f64> = times.iter().map(|t| 2.0 * t - 1.0).collect();
        let mut out = [0.0];
        // Both kinds reproduce a straight line to round-off (a natural spline's end conditions,
        // zero curvature, hold for a line).
        for interp in [Interp::Linear, Interp::Cubic] {
            let mut table = Builtin::table(1, times.clone(), line.clone(), interp).unwrap();
            for t in [0.1, 3.3, 7.77, 9.7] {
                table.eval(t, &[], &[], &mut out).unwrap();
                assert!((out[0] - (2.0 * t - 1.0)).abs() <= 160.0 * f64::EPSILON, "{interp:?} at {t}");
            }
        }
        // Away from the ends (whose influence decays by about 0.27 a knot), a natural cubic
        // spline of a smooth function keeps the complete spline's bound (5/384) h^4 max |f^(4)|
        // (Hall & Meyer 1976): here h = 0.25 and |sin^(4)| <= 1.
        let sine: Vec<f64> = times.iter().map(|t| t.sin()).collect();
        let mut cub = Builtin::table(1, times, sine, Interp::Cubic).unwrap();
        let bound = 5.0 / 384.0 * 0.25f64.powi(4);
        for k in 0..200 {
            let t = 3.0 + k as f64 * 0.02;
            cub.eval(t, &[], &[], &mut out).unwrap();
            assert!((out[0] - t.sin()).abs() <= bound, "t = {t}: {} > {bound}", (out[0] - t.sin()).abs());
        }
        // Beyond the table, the end value is held.
        cub.eval(100.0, &[], &[], &mut out).unwrap();
        assert_eq!(out[0], 9.75f64.sin());
    }

    #[test]
    fn tables_must_increase() {
        let e = Builtin::table(1, vec![0.0, 1.0, 1.0], vec![0.0; 3], Interp::Linear).unwrap_err();
        assert_eq!(e.to_string(), "t[2] must be > t[1] (strictly increasing), got 1 after 1");
    }
}
