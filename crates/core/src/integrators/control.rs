//! Step-size control for an adaptive method: from the error norm of a trial step (1 = exactly
//! at the tolerance) to accepting or rejecting it, and the next step size to try. The standard
//! controller of Hairer, Norsett & Wanner (Solving ODEs I, II.4, eq. 4.13) with DOP853's
//! constants; a trial whose error is not finite (a state that blew up) is rejected with the
//! largest decrease.
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Controller {
    /// Fraction of the optimal step taken (0.9).
    pub safety: f64,
    /// Bounds on the factor from one step to the next (0.2 and 10).
    pub min_factor: f64,
    pub max_factor: f64,
    /// `-1 / (q + 1)` for an error estimate of order q: -1/8 for DOP853.
    pub exponent: f64,
}

/// The controller's verdict on a trial step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Decision {
    Accept { h_next: f64 },
    Reject { h_next: f64 },
}

impl Controller {
    /// DOP853's constants.
    pub const DOP853: Controller = Controller { safety: 0.9, min_factor: 0.2, max_factor: 10.0, exponent: -1.0 / 8.0 };

    /// The verdict on a step `h` with error norm `err`; after a rejection the step may not grow.
    pub fn decide(&self, err: f64, h: f64, rejected_before: bool) -> Decision {
        if err < 1.0 {
            let mut factor = if err == 0.0 { self.max_factor } else { self.max_factor.min(self.safety * err.powf(self.exponent)) };
            if rejected_before {
                factor = factor.min(1.0);
            }
            Decision::Accept { h_next: h * factor }
        } else if err.is_finite() {
            Decision::Reject { h_next: h * self.min_factor.max(self.safety * err.powf(self.exponent)) }
        } else {
            Decision::Reject { h_next: h * self.min_factor }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn accepts_below_one_rejects_above_and_shrinks_most_on_a_blow_up() {
        let c = Controller::DOP853;
        let Decision::Accept { h_next } = c.decide(0.5, 1.0, false) else { panic!() };
        assert!((h_next - 0.9 * 0.5f64.powf(-0.125)).abs() < 1e-15);
        assert_eq!(c.decide(0.0, 1.0, false), Decision::Accept { h_next: 10.0 });
        assert_eq!(c.decide(1e-30, 2.0, true), Decision::Accept { h_next: 2.0 }, "no growth after a rejection");
        let Decision::Reject { h_next } = c.decide(4.0, 1.0, false) else { panic!() };
        assert!((h_next - 0.9 * 4.0f64.powf(-0.125)).abs() < 1e-15);
        assert_eq!(c.decide(1e300, 1.0, false), Decision::Reject { h_next: 0.2 });
        assert_eq!(c.decide(f64::INFINITY, 1.0, false), Decision::Reject { h_next: 0.2 });
        assert_eq!(c.decide(f64::NAN, 1.0, false), Decision::Reject { h_next: 0.2 });
    }
}
