//! The `Chain` class: construction, and the dynamics of rows of states (each row a state; the
//! Python layer reshapes).
use std::cell::RefCell;

use multipendulum_core as core;
use numpy::PyReadonlyArray1;
use pyo3::prelude::*;

use core::dynamics::rows;
use core::reference::Algorithm;
use core::Chain as CoreChain;

use crate::base::{self as base, Errors, PyAxis, PyCartForce};
use crate::torque::{torque_error, PyTorque};
use crate::{slice, to_py, vec_out, Array};

/// A pivot as two axes `(x, y)`.
type Axes<'py> = Option<(PyRef<'py, PyAxis>, PyRef<'py, PyAxis>)>;

/// A callback's kept exception first, then a torque function's, then the core's error.
fn fail(py: Python<'_>, e: core::Error, slot: &RefCell<Option<PyErr>>, errors: &Errors) -> PyErr {
    match base::take(errors) {
        Some(err) => err,
        None => torque_error(py, e, slot),
    }
}

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyChain>()
}

#[pyclass(module = "multipendulum._core", frozen, name = "Chain")]
pub(crate) struct PyChain {
    pub(crate) inner: CoreChain,
}

#[pymethods]
impl PyChain {
    /// `damping`/`friction`: one value per joint (None: zeros); `cart`: `(mass, damping)`.
    #[new]
    #[pyo3(signature = (lengths, masses, com=None, inertia=None, g=9.81, *, damping=None, friction=None, friction_velocity=core::model::FRICTION_VELOCITY, cart=None))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        py: Python<'_>,
        lengths: Vec<f64>,
        masses: Vec<f64>,
        com: Option<Vec<f64>>,
        inertia: Option<Vec<f64>>,
        g: f64,
        damping: Option<Vec<f64>>,
        friction: Option<Vec<f64>>,
        friction_velocity: f64,
        cart: Option<(f64, f64)>,
    ) -> PyResult<Self> {
        let chain = CoreChain::new(&lengths, &masses, com.as_deref(), inertia.as_deref(), g).map_err(|e| to_py(py, e))?;
        extend(py, chain, damping, friction, friction_velocity, cart)
    }

    #[staticmethod]
    #[pyo3(signature = (lengths, masses, g=9.81, *, damping=None, friction=None, friction_velocity=core::model::FRICTION_VELOCITY, cart=None))]
    #[allow(clippy::too_many_arguments)]
    fn rods(
        py: Python<'_>,
        lengths: Vec<f64>,
        masses: Vec<f64>,
        g: f64,
        damping: Option<Vec<f64>>,
        friction: Option<Vec<f64>>,
        friction_velocity: f64,
        cart: Option<(f64, f64)>,
    ) -> PyResult<Self> {
        let chain = CoreChain::rods(&lengths, &masses, g).map_err(|e| to_py(py, e))?;
        extend(py, chain, damping, friction, friction_velocity, cart)
    }

    #[getter]
    fn damping<'py>(&self, py: Python<'py>) -> Array<'py> {
        vec_out(py, self.inner.joints().damping.clone())
    }
    #[getter]
    fn friction<'py>(&self, py: Python<'py>) -> Array<'py> {
        vec_out(py, self.inner.joints().friction.clone())
    }
    #[getter]
    fn friction_velocity(&self) -> f64 {
        self.inner.joints().friction_velocity
    }
    /// `(mass, damping)` of the cart, or None.
    #[getter]
    fn cart(&self) -> Option<(f64, f64)> {
        self.inner.cart().map(|c| (c.mass, c.damping))
    }
    /// Whether the chain loses energy by itself (joint damping or friction, cart damping).
    #[getter]
    fn dissipative(&self) -> bool {
        self.inner.dissipative()
    }

    #[getter]
    fn n(&self) -> usize {
        self.inner.n()
    }
    #[getter]
    fn lengths<'py>(&self, py: Python<'py>) -> Array<'py> {
        vec_out(py, self.inner.lengths().to_vec())
    }
    #[getter]
    fn masses<'py>(&self, py: Python<'py>) -> Array<'py> {
        vec_out(py, self.inner.masses().to_vec())
    }
    #[getter]
    fn com<'py>(&self, py: Python<'py>) -> Array<'py> {
        vec_out(py, self.inner.com().to_vec())
    }
    #[getter]
    fn inertia<'py>(&self, py: Python<'py>) -> Array<'py> {
        vec_out(py, self.inner.inertia().to_vec())
    }
    #[getter]
    fn g(&self) -> f64 {
        self.inner.g()
    }

    /// Rows of flat `theta` -> rows of row-major N x N mass matrices.
    fn mass_matrix<'py>(&self, py: Python<'py>, theta: PyReadonlyArray1<'py, f64>) -> PyResult<Array<'py>> {
        let out = rows::mass_matrices(&self.inner, slice("theta", &theta)?).map_err(|e| to_py(py, e))?;
        Ok(vec_out(py, out))
    }

    /// Accelerations of each row; `algorithm` is "recursive" (O(N)), "cholesky" or "cramer"
    /// (the reference routes: the seeds' ideal chain only). With losses, a pivot (at `t`) or a
    /// cart: the general model, `N + 1` per row with the cart's `x_ddot` first.
    #[pyo3(signature = (theta, omega, *, t=0.0, torque=None, algorithm="recursive", pivot=None, cart_v=None, cart_force=None))]
    #[allow(clippy::too_many_arguments)]
    fn accelerations<'py>(
        &self,
        py: Python<'py>,
        theta: PyReadonlyArray1<'py, f64>,
        omega: PyReadonlyArray1<'py, f64>,
        t: f64,
        torque: Option<PyRef<'py, PyTorque>>,
        algorithm: &str,
        pivot: Axes<'py>,
        cart_v: Option<Vec<f64>>,
        cart_force: Option<PyRef<'py, PyCartForce>>,
    ) -> PyResult<Array<'py>> {
        let (theta, omega) = (slice("theta", &theta)?, slice("omega", &omega)?);
        let algorithm = Algorithm::parse(algorithm).map_err(|e| to_py(py, e))?;
        let slot = RefCell::new(None);
        let errors = Errors::default();
        let mut src = crate::torque::torque(py, self.inner.n(), torque.as_deref(), &slot)?;
        let pivot = base::pivot(py, pivot, &errors)?;
        let mut force = base::force(py, cart_force, &errors)?;
        let cart_v = cart_v.unwrap_or_default();
        let mut b = rows::Base { pivot: pivot.as_ref(), cart_v: &cart_v, force: force.as_mut() };
        let out = if self.inner.is_ideal() && b.still() {
            rows::accelerations(&self.inner, theta, omega, t, &mut src, algorithm)
        } else if algorithm != Algorithm::Recursive {
            Err(core::Error::input(format!(
                "algorithm {:?} solves the seeds' ideal chain only (no damping, friction, pivot motion or cart); use \"recursive\"",
                algorithm.name()
            )))
        } else {
            rows::accelerations_general(&self.inner, theta, omega, t, &mut src, &mut b)
        };
        Ok(vec_out(py, out.map_err(|e| fail(py, e, &slot, &errors))?))
    }

    /// The exact Jacobian of the Lagrangian right-hand side `(omega, theta_ddot)` with respect to
    /// `(theta, omega)` (row-major 2N x 2N), from the variational equations; torques are taken as
    /// depending on time only.
    /// With losses, a pivot or a cart: the general model's, in the ordering
    /// `(x, theta, v, omega)` (`2N + 2` square with a cart).
    #[pyo3(signature = (theta, omega, *, t=0.0, torque=None, pivot=None, cart_v=0.0, cart_force=None))]
    #[allow(clippy::too_many_arguments)]
    fn jacobian<'py>(
        &self,
        py: Python<'py>,
        theta: Vec<f64>,
        omega: Vec<f64>,
        t: f64,
        torque: Option<PyRef<'py, PyTorque>>,
        pivot: Axes<'py>,
        cart_v: f64,
        cart_force: Option<PyRef<'py, PyCartForce>>,
    ) -> PyResult<Array<'py>> {
        let slot = RefCell::new(None);
        let errors = Errors::default();
        let mut src = crate::torque::torque(py, self.inner.n(), torque.as_deref(), &slot)?;
        let pivot = base::pivot(py, pivot, &errors)?;
        let mut force = base::force(py, cart_force, &errors)?;
        let v = [cart_v];
        let mut b = rows::Base { pivot: pivot.as_ref(), cart_v: &v, force: force.as_mut() };
        let out = if self.inner.is_ideal() && b.still() {
            rows::jacobian(&self.inner, &theta, &omega, t, &mut src)
        } else {
            rows::jacobian_general(&self.inner, &theta, &omega, t, &mut src, &mut b)
        };
        Ok(vec_out(py, out.map_err(|e| fail(py, e, &slot, &errors))?))
    }

    /// `(theta_dot, p_dot)` of Hamilton's equations for each row.
    #[pyo3(signature = (theta, p, *, t=0.0, torque=None, pivot=None))]
    fn hamilton<'py>(
        &self,
        py: Python<'py>,
        theta: PyReadonlyArray1<'py, f64>,
        p: PyReadonlyArray1<'py, f64>,
        t: f64,
        torque: Option<PyRef<'py, PyTorque>>,
        pivot: Axes<'py>,
    ) -> PyResult<(Array<'py>, Array<'py>)> {
        let slot = RefCell::new(None);
        let errors = Errors::default();
        let mut src = crate::torque::torque(py, self.inner.n(), torque.as_deref(), &slot)?;
        let pivot = base::pivot(py, pivot, &errors)?;
        let (td, pd) =
            rows::hamilton(&self.inner, slice("theta", &theta)?, slice("p", &p)?, t, &mut src, pivot.as_ref()).map_err(|e| fail(py, e, &slot, &errors))?;
        Ok((vec_out(py, td), vec_out(py, pd)))
    }

    /// The momenta of each row; with a cart `N + 1` per row, `p_x` first (`cart_v`: the cart's
    /// velocity, one value or one per row).
    #[pyo3(signature = (theta, omega, *, cart_v=None))]
    fn momenta<'py>(
        &self,
        py: Python<'py>,
        theta: PyReadonlyArray1<'py, f64>,
        omega: PyReadonlyArray1<'py, f64>,
        cart_v: Option<Vec<f64>>,
    ) -> PyResult<Array<'py>> {
        let (theta, omega) = (slice("theta", &theta)?, slice("omega", &omega)?);
        let out = match cart_v {
            None if self.inner.cart().is_none() => rows::momenta(&self.inner, theta, omega),
            v => {
                let v = v.unwrap_or_default();
                rows::momenta_general(&self.inner, theta, omega, &rows::Base { pivot: None, cart_v: &v, force: None })
            }
        };
        Ok(vec_out(py, out.map_err(|e| to_py(py, e))?))
    }

    /// The velocities of each row; with a cart, `p` and the result have `N + 1` per row, the
    /// cart's first.
    fn velocities<'py>(&self, py: Python<'py>, theta: PyReadonlyArray1<'py, f64>, p: PyReadonlyArray1<'py, f64>) -> PyResult<Array<'py>> {
        let (theta, p) = (slice("theta", &theta)?, slice("p", &p)?);
        let out = if self.inner.cart().is_none() { rows::velocities(&self.inner, theta, p) } else { rows::velocities_general(&self.inner, theta, p) };
        Ok(vec_out(py, out.map_err(|e| to_py(py, e))?))
    }

    /// Lab-frame `(kinetic, potential)` energies of each row: with the pivot's motion at `t`,
    /// or the cart at `cart_v` (its own kinetic energy included).
    #[pyo3(signature = (theta, omega, *, t=0.0, pivot=None, cart_v=None))]
    fn energies<'py>(
        &self,
        py: Python<'py>,
        theta: PyReadonlyArray1<'py, f64>,
        omega: PyReadonlyArray1<'py, f64>,
        t: f64,
        pivot: Axes<'py>,
        cart_v: Option<Vec<f64>>,
    ) -> PyResult<(Array<'py>, Array<'py>)> {
        let (theta, omega) = (slice("theta", &theta)?, slice("omega", &omega)?);
        let errors = Errors::default();
        let pivot = base::pivot(py, pivot, &errors)?;
        let r = if pivot.is_none() && cart_v.is_none() {
            rows::energies(&self.inner, theta, omega)
        } else {
            let v = cart_v.unwrap_or_default();
            rows::energies_general(&self.inner, theta, omega, t, &rows::Base { pivot: pivot.as_ref(), cart_v: &v, force: None })
        };
        let (kin, pot) = r.map_err(|e| base::take(&errors).unwrap_or_else(|| to_py(py, e)))?;
        Ok((vec_out(py, kin), vec_out(py, pot)))
    }

    /// Joint positions (`com=False`) or centres of mass (`com=True`), 2N numbers per row.
    #[pyo3(signature = (theta, *, com=false))]
    fn positions<'py>(&self, py: Python<'py>, theta: PyReadonlyArray1<'py, f64>, com: bool) -> PyResult<Array<'py>> {
        let out = rows::positions(&self.inner, slice("theta", &theta)?, com).map_err(|e| to_py(py, e))?;
        Ok(vec_out(py, out))
    }

    fn __repr__(&self) -> String {
        let c = &self.inner;
        let mut s = format!("Chain(lengths={:?}, masses={:?}, com={:?}, inertia={:?}, g={}", c.lengths(), c.masses(), c.com(), c.inertia(), c.g());
        let j = c.joints();
        if c.lossy_joints() {
            s += &format!(", damping={:?}, friction={:?}, friction_velocity={}", j.damping, j.friction, j.friction_velocity);
        } else if j.friction_velocity != core::model::FRICTION_VELOCITY {
            s += &format!(", friction_velocity={}", j.friction_velocity);
        }
        if let Some(cart) = c.cart() {
            s += &format!(", cart=Cart(mass={}, damping={})", cart.mass, cart.damping);
        }
        s + ")"
    }
}

/// The chain with its joints' losses and its cart.
fn extend(
    py: Python<'_>,
    chain: CoreChain,
    damping: Option<Vec<f64>>,
    friction: Option<Vec<f64>>,
    friction_velocity: f64,
    cart: Option<(f64, f64)>,
) -> PyResult<PyChain> {
    let n = chain.n();
    let (damping, friction) = (damping.unwrap_or_else(|| vec![0.0; n]), friction.unwrap_or_else(|| vec![0.0; n]));
    let cart = cart.map(|(m, d)| core::Cart::new(m, d)).transpose().map_err(|e| to_py(py, e))?;
    chain.with_losses(&damping, &friction, friction_velocity).and_then(|c| c.with_cart(cart)).map(|inner| PyChain { inner }).map_err(|e| to_py(py, e))
}
