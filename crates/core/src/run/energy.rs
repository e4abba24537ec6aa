//! The energy error, defined once for every report (stats, the CLI summary, plots, animation
//! frames, the viewer):
//!
//! `error(t) = |E(t) - E(0) - W(t)| / S(t)`, with `S(t) = g sum_i |h_i| + max T`,
//!
//! always against the initial state `E(0)` (not the first output row), with `W` the work done
//! on the chain since t = 0 and `T` the kinetic energy, its maximum over the initial state and
//! every output up to `t`. `g sum |h_i|` is the depth of the potential well (`U` ranges over
//! `+-g sum h_i`), so the scale never vanishes for a chain under gravity, whatever its energy;
//! without gravity it is the kinetic energy the run has had. (A relative error against `|E(0)|`
//! explodes for a chain released horizontally from rest, where `E(0)` is zero up to round-off.)
//! Where the scale is zero (no gravity and no motion so far) the error is the absolute residual.
use crate::model::Chain;

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EnergyBalance {
    e0: f64,
    well: f64,
    kinetic_max: f64,
}

impl EnergyBalance {
    /// From the initial state's kinetic and potential energies.
    pub fn new(chain: &Chain, kinetic0: f64, potential0: f64) -> Self {
        EnergyBalance { e0: kinetic0 + potential0, well: chain.potential_depth(), kinetic_max: kinetic0 }
    }

    /// From the initial state's kinetic and total energies.
    pub fn from_energy(chain: &Chain, kinetic0: f64, energy0: f64) -> Self {
        EnergyBalance { e0: energy0, well: chain.potential_depth(), kinetic_max: kinetic0 }
    }

    pub fn initial_energy(&self) -> f64 {
        self.e0
    }

    /// The scale so far.
    pub fn scale(&self) -> f64 {
        self.well + self.kinetic_max
    }

    /// The error of an output with kinetic energy `kinetic`, total `energy` and work `work`
    /// (which then counts for the scale of this and later outputs).
    pub fn observe(&mut self, kinetic: f64, energy: f64, work: f64) -> f64 {
        if kinetic > self.kinetic_max {
            self.kinetic_max = kinetic;
        }
        let residual = (energy - self.e0 - work).abs();
        let scale = self.scale();
        if scale > 0.0 {
            residual / scale
        } else {
            residual
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_chain_released_horizontally_from_rest_has_a_scale_of_the_well() {
        // E(0) = 0 for three rods at 90 degrees at rest: the scale is g (h1 + h2 + h3).
        let c = Chain::rods(&[1.0, 1.0, 1.0], &[1.0, 1.0, 1.0], 9.81).unwrap();
        let theta = [std::f64::consts::FRAC_PI_2; 3];
        let u0 = c.potential_energy(&theta);
        assert!(u0.abs() < 1e-14);
        let mut b = EnergyBalance::new(&c, 0.0, u0);
        // h = (0.5 + 2, 0.5 + 1, 0.5) = (2.5, 1.5, 0.5): the well is 4.5 g.
        assert!((b.scale() - 4.5 * 9.81).abs() < 1e-12);
        // |E - E0| = 5e-11 J after the chain gained 1 J of kinetic energy (and lost it in U).
        let err = b.observe(1.0, u0 + 5e-11, 0.0);
        assert!((err - 5e-11 / (4.5 * 9.81 + 1.0)).abs() < 1e-22, "{err}");
    }

    #[test]
    fn without_gravity_the_scale_is_the_largest_kinetic_energy_so_far() {
        let c = Chain::new(&[1.0], &[2.0], None, None, 0.0).unwrap();
        let mut b = EnergyBalance::new(&c, 0.0, 0.0);
        assert_eq!(b.observe(0.0, 1e-20, 0.0), 1e-20, "absolute while nothing moves");
        // A torque did 4 J of work: E = T = 4 J, residual 2e-10 J against T_max = 4 J.
        assert_eq!(b.observe(4.0, 4.0 + 2e-10, 4.0), (4.0f64 + 2e-10 - 4.0) / 4.0);
        assert_eq!(b.observe(1.0, 1.0 + 2e-10, 1.0), (1.0f64 + 2e-10 - 1.0) / 4.0, "the largest so far");
        assert_eq!(b.observe(1.0, 3.0, 3.0), 0.0, "work counts");
    }
}
