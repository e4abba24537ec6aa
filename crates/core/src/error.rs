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

pub type Result<T> = std::result::Result<T, Error>;

/// Refuse a state or array that holds NaN or inf, naming the field and index.
pub fn check_finite(name: &str, values: &[f64]) -> Result<()> {
    match values.iter().position(|v| !v.is_finite()) {
        Some(i) => Err(Error::input(format!("{name}[{i}] must be finite, got {}", values[i]))),
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
