//! Errors of the core. Bindings map each variant to one exception class.
use std::fmt;

#[derive(Debug, Clone, PartialEq)]
pub enum Error {
    /// Bad input: a field, an index, the value and what was expected, already in the message
    /// (`lengths[2] must be > 0, got 0`).
    Input(String),
    /// The integration could not continue at time `t` (blow-up, singular mass matrix,
    /// step size underflow, non-convergent implicit stages).
    Integration { t: f64, reason: String },
    /// A user-supplied function (torque, event, progress, checkpoint writer) failed at time
    /// `t`; the binding keeps the original error.
    Torque { t: f64 },
    /// Stopped from outside (Ctrl-C) at time `t` ([`crate::watch::Watch`]).
    Interrupted { t: f64 },
}

impl Error {
    pub fn input(msg: impl Into<String>) -> Self {
        Error::Input(msg.into())
    }
    pub fn integration(t: f64, reason: impl Into<String>) -> Self {
        Error::Integration { t, reason: reason.into() }
    }

    /// This error of row `i` of a batch, named in its message (`trajectory 7: ...`); an
    /// interruption or a failed user function stays as it is.
    pub fn of_trajectory(self, i: usize) -> Self {
        match self {
            Error::Input(m) => Error::Input(format!("trajectory {i}: {m}")),
            Error::Integration { t, reason } => Error::Integration { t, reason: format!("trajectory {i}: {reason}") },
            other => other,
        }
    }
}

impl fmt::Display for Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Error::Input(m) => f.write_str(m),
            Error::Integration { t, reason } => write!(f, "integration failed at t = {t}: {reason}"),
            Error::Torque { t } => write!(f, "the torque function failed at t = {t}"),
            Error::Interrupted { t } => write!(f, "interrupted at t = {t}"),
        }
    }
}

impl std::error::Error for Error {}

/// A number as a message shows it: as Rust writes it (`0.25`, `3`, `NaN`, `inf`), but in
/// exponent form, as Python's `repr` (`1e+300`, `-2.5e-07`), from 1e16 up and under 1e-4, where
/// Rust writes every digit (a refused `1e300` as 301 of them).
pub struct Shown(pub f64);

impl fmt::Display for Shown {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let x = self.0;
        let a = x.abs();
        if !x.is_finite() || a == 0.0 || (1e-4..1e16).contains(&a) {
            return write!(f, "{x}");
        }
        // Rust's shortest round-trip digits, its exponent signed and of two digits at least.
        let e = format!("{x:e}");
        let (mantissa, exponent) = e.split_once('e').expect("{:e} writes an exponent");
        let exponent: i32 = exponent.parse().expect("{:e} writes an integer exponent");
        write!(f, "{mantissa}e{}{:02}", if exponent < 0 { '-' } else { '+' }, exponent.abs())
    }
}

pub type Result<T> = std::result::Result<T, Error>;

/// Refuse a state or array that holds NaN or inf, naming the field and index.
pub fn check_finite(name: &str, values: &[f64]) -> Result<()> {
    match values.iter().position(|v| !v.is_finite()) {
        Some(i) => Err(Error::input(format!("{name}[{i}] must be finite, got {}", Shown(values[i])))),
        None => Ok(()),
    }
}

/// Refuse an array whose length is not `n`.
pub fn check_len(name: &str, values: &[f64], n: usize) -> Result<()> {
    if values.len() != n {
        return Err(Error::input(format!("{name} must have {n} entries (one per link), got {}", values.len())));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::Shown;

    #[test]
    fn numbers_in_messages_are_short_at_every_scale() {
        let shown = |x: f64| Shown(x).to_string();
        // Rust's shortest digits in the middle range, as before.
        assert_eq!(shown(0.25), "0.25");
        assert_eq!(shown(-3.0), "-3");
        assert_eq!(shown(0.0), "0");
        assert_eq!(shown(1e-4), "0.0001");
        assert_eq!(shown(1e15), "1000000000000000");
        assert_eq!((shown(f64::NAN), shown(f64::INFINITY), shown(f64::NEG_INFINITY)), ("NaN".into(), "inf".into(), "-inf".into()));
        // Exponent form (Python's repr) at the ends, where Rust writes every digit.
        assert_eq!(shown(1e16), "1e+16");
        assert_eq!(shown(1e300), "1e+300");
        assert_eq!(shown(-2.5e-7), "-2.5e-07");
        assert_eq!(shown(f64::MAX), "1.7976931348623157e+308");
        assert_eq!(shown(5e-324), "5e-324");
        // The digits round-trip.
        for x in [1.2345678901234567e200, -9.87654321e-150, 3e-5] {
            assert_eq!(shown(x).parse::<f64>().unwrap(), x);
        }
    }
}
