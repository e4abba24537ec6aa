//! The validated, immutable chain: constant parameters only (work buffers live in `Workspace`).
use crate::error::{check_finite, check_len, Error, Result, Shown};

/// The largest angle (rad) a state may hold: beyond it an angle has
/// no digits left below a turn, and differences of angles (`cos(theta_a - theta_b)`) overflow
/// to NaN near 1e308.
pub const MAX_STATE: f64 = 1e15;

/// A planar chain of `n` rigid links hanging from a fixed pivot at the origin.
///
/// Link `i` has length `l_i` (pivot to the next joint), mass `m_i`, centre of mass at `c_i` from
/// its own pivot along the link, and moment of inertia `I_i` about its centre of mass. Angles are
/// absolute, from the downward vertical, counter-clockwise positive; gravity `g` along -y. SI units.
#[derive(Debug, Clone, PartialEq)]
pub struct Chain {
    pub(crate) lengths: Vec<f64>,
    pub(crate) masses: Vec<f64>,
    pub(crate) com: Vec<f64>,
    pub(crate) inertia: Vec<f64>,
    pub(crate) g: f64,
    /// `h_i = m_i c_i + l_i * sum_{k>i} m_k`: couples link i to the links above it; also
    /// the gravity moment `U = -g sum h_i cos(theta_i)`.
    pub(crate) h: Vec<f64>,
    /// `A_ii = I_i + m_i c_i^2 + l_i^2 sum_{k>i} m_k`.
    pub(crate) diag: Vec<f64>,
    /// `1 / A_{N-1,N-1}`, the bottom link's pivot inverted: the lanes' recursion starts from it
    /// on every evaluation, where a division of its own would stall the start of each one.
    pub(crate) bottom_inv: f64,
    /// Losses at the joints: viscous damping and regularised Coulomb friction
    /// ([`Chain::add_losses`]); all zero for the seeds' ideal chain.
    pub(crate) joints: Joints,
    /// The base slides along x as a degree of freedom when there is a cart.
    pub(crate) cart: Option<Cart>,
}

/// The joints' losses. Joint `i` connects link `i-1` to link `i` (joint 0: the base to link 0)
/// and turns at the relative rate `w_i = omega_i - omega_{i-1}` (`omega_{-1} = 0`); its torque
/// `u_i = -damping_i w_i - friction_i tanh(w_i / friction_velocity)` acts `+u_i` on link `i` and
/// `-u_i` on link `i-1`.
#[derive(Debug, Clone, PartialEq)]
pub struct Joints {
    pub damping: Vec<f64>,
    pub friction: Vec<f64>,
    /// The regularisation rate `v_s` (rad/s) of the Coulomb friction: below it the friction
    /// torque grows linearly with the rate, as a steep viscous damping `f / v_s`.
    pub friction_velocity: f64,
    /// Whether any joint has a loss (so the ideal chain skips them).
    pub(crate) any: bool,
    /// `1 / friction_velocity`.
    pub(crate) inv_velocity: f64,
}

/// The default regularisation rate of the Coulomb friction (rad/s).
pub const FRICTION_VELOCITY: f64 = 1e-3;

/// A cart on a horizontal rail carrying the chain's pivot: its mass and viscous damping
/// (force `-damping * v`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Cart {
    pub mass: f64,
    pub damping: f64,
}

impl Cart {
    pub fn new(mass: f64, damping: f64) -> Result<Self> {
        if !(mass.is_finite() && mass > 0.0) {
            return Err(Error::input(format!("cart mass must be > 0 and finite, got {}", Shown(mass))));
        }
        if !(damping.is_finite() && damping >= 0.0) {
            return Err(Error::input(format!("cart damping must be >= 0 and finite, got {}", Shown(damping))));
        }
        Ok(Cart { mass, damping })
    }
}

impl Chain {
    /// Build and validate a chain. `com` defaults to `lengths` (point masses at the link ends,
    /// seed 000) and `inertia` to zeros.
    pub fn new(lengths: &[f64], masses: &[f64], com: Option<&[f64]>, inertia: Option<&[f64]>, g: f64) -> Result<Self> {
        let n = lengths.len();
        if n == 0 {
            return Err(Error::input("lengths must have at least one entry, got 0"));
        }
        check_len("masses", masses, n)?;
        let com = com.map_or_else(|| lengths.to_vec(), <[f64]>::to_vec);
        let inertia = inertia.map_or_else(|| vec![0.0; n], <[f64]>::to_vec);
        check_len("com", &com, n)?;
        check_len("inertia", &inertia, n)?;
        for (i, &l) in lengths.iter().enumerate() {
            if !(l.is_finite() && l > 0.0) {
                return Err(Error::input(format!("lengths[{i}] must be > 0 and finite, got {}", Shown(l))));
            }
        }
        for (name, values) in [("masses", masses), ("inertia", &inertia[..])] {
            for (i, &v) in values.iter().enumerate() {
                if !(v.is_finite() && v >= 0.0) {
                    return Err(Error::input(format!("{name}[{i}] must be >= 0 and finite, got {}", Shown(v))));
                }
            }
        }
        check_finite("com", &com)?;
        if !g.is_finite() {
            return Err(Error::input(format!("g must be finite, got {}", Shown(g))));
        }
        let total: f64 = masses.iter().sum();
        if !total.is_finite() {
            return Err(Error::input("the sum of masses overflows"));
        }

        let mut h = vec![0.0; n];
        let mut diag = vec![0.0; n];
        let mut below = 0.0; // sum of the masses of the links below link i
        for i in (0..n).rev() {
            h[i] = masses[i] * com[i] + lengths[i] * below;
            diag[i] = inertia[i] + masses[i] * com[i] * com[i] + lengths[i] * lengths[i] * below;
            below += masses[i];
        }
        check_finite("mass matrix diagonal", &diag)?;
        // Gravity torques g h_i, and their sum in the recursion, must stay finite.
        let moment: f64 = h.iter().sum();
        if !(g * moment * n as f64).is_finite() {
            return Err(Error::input(format!(
                "g = {} with these masses and lengths overflows the gravity torques (g * sum of m c + l m_below = {:e})",
                Shown(g),
                g * moment
            )));
        }
        // The O(N) solve forms products of two diagonal entries (the 2x2 articulated inertias):
        // parameters so small or so large in scale that those products leave the normal range make
        // the mass matrix numerically singular in every configuration. Refuse them here, as bad
        // input, rather than at t = 0 as a failed integration.
        let joints =
            Joints { damping: vec![0.0; n], friction: vec![0.0; n], friction_velocity: FRICTION_VELOCITY, any: false, inv_velocity: 1.0 / FRICTION_VELOCITY };
        let bottom_inv = 1.0 / diag[n - 1];
        let chain = Chain { lengths: lengths.to_vec(), masses: masses.to_vec(), com, inertia, g, h, diag, bottom_inv, joints, cart: None };
        chain.check_nonsingular()?;
        // (A chain that passes the structural check has every diagonal entry > 0 in exact
        // arithmetic: a zero here is an underflow.)
        for (i, &d) in chain.diag.iter().enumerate() {
            let square = d * d;
            if !(d > 0.0 && square.is_finite() && square * 1e-16 >= f64::MIN_POSITIVE) {
                return Err(Error::input(format!(
                    "the chain's scale is out of float64's range: link {i}'s moment of inertia about its \
                     pivot is {d:e} kg m^2, whose square {} (masses and lengths too {}); express them in \
                     other units",
                    if square.is_finite() { "underflows" } else { "overflows" },
                    if square.is_finite() { "small" } else { "large" }
                )));
            }
        }
        Ok(chain)
    }

    /// Uniform rods (seed 001): centre of mass mid-link, `I = m l^2 / 12`.
    pub fn rods(lengths: &[f64], masses: &[f64], g: f64) -> Result<Self> {
        check_len("masses", masses, lengths.len())?;
        let com: Vec<f64> = lengths.iter().map(|l| 0.5 * l).collect();
        let inertia: Vec<f64> = lengths.iter().zip(masses).map(|(l, m)| m * l * l / 12.0).collect();
        Self::new(lengths, masses, Some(&com), Some(&inertia), g)
    }

    /// The same chain with losses at its joints: `damping` (N m s/rad) and `friction` (N m), one
    /// value per joint, and the friction's regularisation rate (rad/s).
    pub fn with_losses(mut self, damping: &[f64], friction: &[f64], friction_velocity: f64) -> Result<Self> {
        let n = self.n();
        check_len("damping", damping, n)?;
        check_len("friction", friction, n)?;
        for (name, values) in [("damping", damping), ("friction", friction)] {
            for (i, &v) in values.iter().enumerate() {
                if !(v.is_finite() && v >= 0.0) {
                    return Err(Error::input(format!("{name}[{i}] must be >= 0 and finite, got {}", Shown(v))));
                }
            }
        }
        if !(friction_velocity.is_finite() && friction_velocity > 0.0) {
            return Err(Error::input(format!("friction_velocity must be > 0 and finite, got {}", Shown(friction_velocity))));
        }
        let any = damping.iter().chain(friction).any(|&v| v > 0.0);
        let inv_velocity = 1.0 / friction_velocity;
        self.joints = Joints { damping: damping.to_vec(), friction: friction.to_vec(), friction_velocity, any, inv_velocity };
        Ok(self)
    }

    /// The same chain on a cart (or on a fixed pivot, `None`).
    pub fn with_cart(mut self, cart: Option<Cart>) -> Result<Self> {
        if let Some(c) = cart {
            Cart::new(c.mass, c.damping)?;
            let total = c.mass + self.masses.iter().sum::<f64>();
            if !(total * total).is_finite() {
                return Err(Error::input(format!("the cart's and chain's mass {total:e} overflows")));
            }
        }
        self.cart = cart;
        Ok(self)
    }

    pub fn joints(&self) -> &Joints {
        &self.joints
    }

    pub fn cart(&self) -> Option<Cart> {
        self.cart
    }

    /// The mechanical state's length: `theta` and `omega` (N each), then a cart's `x` and `v`.
    pub fn state_len(&self) -> usize {
        2 * self.n() + 2 * usize::from(self.cart.is_some())
    }

    /// Whether any joint has damping or friction.
    #[inline]
    pub fn lossy_joints(&self) -> bool {
        self.joints.any
    }

    /// Whether the chain loses energy by itself (joint damping or friction, cart damping).
    pub fn dissipative(&self) -> bool {
        self.lossy_joints() || self.cart.is_some_and(|c| c.damping > 0.0)
    }

    /// The seeds' ideal chain: no losses, no cart (the fast paths of the dynamics).
    pub fn is_ideal(&self) -> bool {
        !self.lossy_joints() && self.cart.is_none()
    }

    /// The total mass of the links.
    pub fn total_mass(&self) -> f64 {
        self.masses.iter().sum()
    }

    /// Refuse a chain whose mass matrix is singular in some configuration.
    ///
    /// Kinetic energy zero with the pivot still forces every angular velocity to zero unless some
    /// link is "unpinned" (no inertia and no mass off its pivot) while the links below it can
    /// still let its far end move at zero kinetic energy ("free"), e.g. a massless last link, or a
    /// massless link carrying a point mass (singular when the two are aligned). Walking up the
    /// chain: the empty tail is free; a link with mass at its pivot or with both mass and inertia
    /// holds its pivot still; a point mass exactly at the far end always lets the pivot swing.
    fn check_nonsingular(&self) -> Result<()> {
        let mut free = true; // can joint i+1 move with zero kinetic energy below it?
        for i in (0..self.n()).rev() {
            let (m, c, inertia) = (self.masses[i], self.com[i], self.inertia[i]);
            let pinned = inertia > 0.0 || (m > 0.0 && c != 0.0);
            if !pinned && free {
                return Err(Error::input(format!(
                    "link {i} leaves the mass matrix singular: masses[{i}] = {m}, com[{i}] = {c}, \
                     inertia[{i}] = {inertia}, and the links below it cannot hold its end \
                     (give it mass away from its pivot or inertia)"
                )));
            }
            free = if inertia > 0.0 {
                m == 0.0 && free
            } else if m > 0.0 && c != 0.0 {
                c == self.lengths[i] || free
            } else {
                m == 0.0
            };
        }
        Ok(())
    }

    pub fn n(&self) -> usize {
        self.lengths.len()
    }
    pub fn lengths(&self) -> &[f64] {
        &self.lengths
    }
    pub fn masses(&self) -> &[f64] {
        &self.masses
    }
    pub fn com(&self) -> &[f64] {
        &self.com
    }
    pub fn inertia(&self) -> &[f64] {
        &self.inertia
    }
    /// The depth of the potential well, `g sum_i |h_i|`: the potential ranges over `+-` it
    /// (the scale of the energy error, [`crate::run::energy`]).
    pub fn potential_depth(&self) -> f64 {
        self.g.abs() * self.h.iter().map(|h| h.abs()).sum::<f64>()
    }

    pub fn g(&self) -> f64 {
        self.g
    }

    /// Refuse a state of the wrong size or with NaN/inf, naming it; angles (`theta...`) also
    /// beyond [`MAX_STATE`].
    pub fn check_state(&self, name: &str, values: &[f64]) -> Result<()> {
        check_len(name, values, self.n())?;
        check_finite(name, values)?;
        if !name.starts_with("theta") {
            return Ok(());
        }
        match values.iter().position(|v| v.abs() > MAX_STATE) {
            Some(i) => Err(Error::input(format!("{name}[{i}] must be within +-{MAX_STATE:e} rad, got {}", Shown(values[i])))),
            None => Ok(()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn refuses_bad_lengths_with_field_and_index() {
        let e = Chain::new(&[1.0, 1.0, 0.0], &[1.0; 3], None, None, 9.81).unwrap_err();
        assert_eq!(e, Error::input("lengths[2] must be > 0 and finite, got 0"));
        let e = Chain::new(&[1.0, f64::NAN], &[1.0; 2], None, None, 9.81).unwrap_err();
        assert!(e.to_string().starts_with("lengths[1] must be > 0"), "{e}");
        // Huge values in exponent form, not as 301 digits.
        let e = Chain::new(&[1.0, -1e300], &[1.0; 2], None, None, 9.81).unwrap_err();
        assert_eq!(e, Error::input("lengths[1] must be > 0 and finite, got -1e+300"));
        let chain = Chain::new(&[1.0, 1.0], &[1.0; 2], None, None, 9.81).unwrap();
        assert_eq!(chain.check_state("theta0", &[0.5, 1e300]).unwrap_err(), Error::input("theta0[1] must be within +-1e15 rad, got 1e+300"));
        let e = Chain::new(&[1.0], &[10.0], None, None, 1e308).unwrap_err();
        assert!(e.to_string().starts_with("g = 1e+308 with these masses and lengths overflows"), "{e}");
    }

    #[test]
    fn refuses_negative_mass_and_inertia() {
        let e = Chain::new(&[1.0, 1.0], &[1.0, -1.0], None, None, 9.81).unwrap_err();
        assert!(e.to_string().starts_with("masses[1] must be >= 0"), "{e}");
        let e = Chain::new(&[1.0], &[1.0], None, Some(&[-0.1]), 9.81).unwrap_err();
        assert!(e.to_string().starts_with("inertia[0] must be >= 0"), "{e}");
    }

    #[test]
    fn singular_chains_are_refused_and_regular_ones_accepted() {
        // A massless last point mass: the last link swings freely.
        assert!(Chain::new(&[1.0, 1.0], &[1.0, 0.0], None, None, 9.81).is_err());
        // A massless link carrying a point mass: singular when aligned.
        assert!(Chain::new(&[1.0, 1.0], &[0.0, 1.0], None, None, 9.81).is_err());
        // A massless link carrying a rod with inertia: regular everywhere.
        assert!(Chain::new(&[1.0, 1.0], &[0.0, 1.0], Some(&[1.0, 0.5]), Some(&[0.0, 0.1]), 9.81).is_ok());
        // Mass at the pivot only, then a point mass: the first link is unpinned but held.
        assert!(Chain::new(&[1.0, 1.0], &[1.0, 1.0], Some(&[0.0, 1.0]), None, 9.81).is_err());
        assert!(Chain::rods(&[1.0, 0.7], &[1.0, 2.0], 9.81).is_ok());
    }

    #[test]
    fn mismatched_sizes_are_refused() {
        let e = Chain::new(&[1.0, 1.0], &[1.0], None, None, 9.81).unwrap_err();
        assert_eq!(e, Error::input("masses must have 2 entries (one per link), got 1"));
    }
}
