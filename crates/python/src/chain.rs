//! The `Chain` class: construction, and the dynamics of rows of states (each row a state; the
//! Python layer reshapes).
use std::cell::RefCell;

use multipendulum_core as core;
use numpy::{PyArray1, PyReadonlyArray1};
use pyo3::prelude::*;

use core::reference::{self, Algorithm};
use core::{Chain as CoreChain, Error, TorqueSource, Workspace};

use crate::torque::{torque_error, PyTorque};
use crate::{slice, to_py, vec_out, InputError};

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyChain>()
}

#[pyclass(module = "multipendulum._core", frozen, name = "Chain")]
pub(crate) struct PyChain {
    pub(crate) inner: CoreChain,
}

fn rows(name: &str, len: usize, n: usize) -> PyResult<usize> {
    if len % n != 0 || len == 0 {
        return Err(InputError::new_err(format!("{name} must have shape (..., {n}), got {len} numbers")));
    }
    Ok(len / n)
}

#[pymethods]
impl PyChain {
    #[new]
    #[pyo3(signature = (lengths, masses, com=None, inertia=None, g=9.81))]
    fn new(
        py: Python<'_>,
        lengths: Vec<f64>,
        masses: Vec<f64>,
        com: Option<Vec<f64>>,
        inertia: Option<Vec<f64>>,
        g: f64,
    ) -> PyResult<Self> {
        CoreChain::new(&lengths, &masses, com.as_deref(), inertia.as_deref(), g)
            .map(|inner| PyChain { inner })
            .map_err(|e| to_py(py, e))
    }

    #[staticmethod]
    #[pyo3(signature = (lengths, masses, g=9.81))]
    fn rods(py: Python<'_>, lengths: Vec<f64>, masses: Vec<f64>, g: f64) -> PyResult<Self> {
        CoreChain::rods(&lengths, &masses, g).map(|inner| PyChain { inner }).map_err(|e| to_py(py, e))
    }

    #[getter]
    fn n(&self) -> usize {
        self.inner.n()
    }
    #[getter]
    fn lengths<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        vec_out(py, self.inner.lengths().to_vec())
    }
    #[getter]
    fn masses<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        vec_out(py, self.inner.masses().to_vec())
    }
    #[getter]
    fn com<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        vec_out(py, self.inner.com().to_vec())
    }
    #[getter]
    fn inertia<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        vec_out(py, self.inner.inertia().to_vec())
    }
    #[getter]
    fn g(&self) -> f64 {
        self.inner.g()
    }

    /// Rows of flat `theta` -> rows of row-major N x N mass matrices.
    fn mass_matrix<'py>(&self, py: Python<'py>, theta: PyReadonlyArray1<'py, f64>) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let (c, theta) = (&self.inner, slice("theta", &theta)?);
        let n = c.n();
        let b = rows("theta", theta.len(), n)?;
        let mut out = vec![0.0; b * n * n];
        for (row, o) in theta.chunks(n).zip(out.chunks_mut(n * n)) {
            c.mass_matrix_into(row, o);
        }
        Ok(vec_out(py, out))
    }

    /// Accelerations of each row; `algorithm` is "recursive" (O(N)), "cholesky" or "cramer".
    #[pyo3(signature = (theta, omega, *, t=0.0, torque=None, algorithm="recursive"))]
    fn accelerations<'py>(
        &self,
        py: Python<'py>,
        theta: PyReadonlyArray1<'py, f64>,
        omega: PyReadonlyArray1<'py, f64>,
        t: f64,
        torque: Option<PyRef<'py, PyTorque>>,
        algorithm: &str,
    ) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let c = &self.inner;
        let n = c.n();
        let (theta, omega) = (slice("theta", &theta)?, slice("omega", &omega)?);
        core::error::check_finite("theta", theta).map_err(|e| to_py(py, e))?;
        core::error::check_finite("omega", omega).map_err(|e| to_py(py, e))?;
        let b = rows("theta", theta.len(), n)?;
        let algorithm = Algorithm::parse(algorithm).map_err(|e| to_py(py, e))?;
        algorithm.check(n).map_err(|e| to_py(py, e))?;
        let slot = RefCell::new(None);
        let mut src = crate::torque::torque(py, n, torque.as_deref(), &slot)?;
        let mut ws = Workspace::new(n);
        let (mut tau, mut out) = (vec![0.0; n], vec![0.0; b * n]);
        for i in 0..b {
            let (th, om) = (&theta[i * n..(i + 1) * n], &omega[i * n..(i + 1) * n]);
            if src.active() {
                src.eval(t, th, om, &mut tau).map_err(|e| torque_error(py, e, &slot))?;
            }
            let o = &mut out[i * n..(i + 1) * n];
            let singular = |s: core::Singular| to_py(py, Error::integration(t, s.reason()));
            match algorithm {
                Algorithm::Recursive => c.accelerations_into(th, om, &tau, o, &mut ws).map_err(singular)?,
                Algorithm::Cholesky => o.copy_from_slice(&reference::accelerations_cholesky(c, th, om, &tau).map_err(singular)?),
                Algorithm::Cramer => o.copy_from_slice(&reference::accelerations_cramer(c, th, om, &tau).map_err(singular)?),
            }
        }
        Ok(vec_out(py, out))
    }

    /// The exact Jacobian of the Lagrangian right-hand side `(omega, theta_ddot)` with respect to
    /// `(theta, omega)` (row-major 2N x 2N), from the variational equations; torques are taken as
    /// depending on time only.
    #[pyo3(signature = (theta, omega, *, t=0.0, torque=None))]
    fn jacobian<'py>(
        &self,
        py: Python<'py>,
        theta: Vec<f64>,
        omega: Vec<f64>,
        t: f64,
        torque: Option<PyRef<'py, PyTorque>>,
    ) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let c = &self.inner;
        let n = c.n();
        let err = |e| to_py(py, e);
        c.check_state("theta", &theta).map_err(err)?;
        c.check_state("omega", &omega).map_err(err)?;
        let slot = RefCell::new(None);
        let mut src = crate::torque::torque(py, n, torque.as_deref(), &slot)?;
        let mut ws = Workspace::new(n);
        let mut tau = vec![0.0; n];
        if src.active() {
            src.eval(t, &theta, &omega, &mut tau).map_err(|e| torque_error(py, e, &slot))?;
        }
        let singular = |s: core::Singular| to_py(py, Error::integration(t, s.reason()));
        let mut jac = vec![0.0; 4 * n * n];
        c.jacobian_into(&theta, &omega, &tau, &mut jac, &mut ws).map_err(singular)?;
        Ok(vec_out(py, jac))
    }

    /// `(theta_dot, p_dot)` of Hamilton's equations for each row.
    #[pyo3(signature = (theta, p, *, t=0.0, torque=None))]
    fn hamilton<'py>(
        &self,
        py: Python<'py>,
        theta: PyReadonlyArray1<'py, f64>,
        p: PyReadonlyArray1<'py, f64>,
        t: f64,
        torque: Option<PyRef<'py, PyTorque>>,
    ) -> PyResult<(Bound<'py, PyArray1<f64>>, Bound<'py, PyArray1<f64>>)> {
        let c = &self.inner;
        let n = c.n();
        let (theta, p) = (slice("theta", &theta)?, slice("p", &p)?);
        let b = rows("theta", theta.len(), n)?;
        let slot = RefCell::new(None);
        let mut src = crate::torque::torque(py, n, torque.as_deref(), &slot)?;
        let mut ws = Workspace::new(n);
        let (mut td, mut pd) = (vec![0.0; b * n], vec![0.0; b * n]);
        for i in 0..b {
            let r = i * n..(i + 1) * n;
            let th = &theta[r.clone()];
            let active = src.active();
            c.hamilton_into(th, &p[r.clone()], &mut td[r.clone()], &mut pd[r], &mut ws, |om, out| {
                if active {
                    src.eval(t, th, om, out)
                } else {
                    out.fill(0.0);
                    Ok(())
                }
            })
            .map_err(|s| to_py(py, Error::integration(t, s.reason())))?
            .map_err(|e| torque_error(py, e, &slot))?;
        }
        Ok((vec_out(py, td), vec_out(py, pd)))
    }

    fn momenta<'py>(&self, py: Python<'py>, theta: PyReadonlyArray1<'py, f64>, omega: PyReadonlyArray1<'py, f64>) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let c = &self.inner;
        let n = c.n();
        let (theta, omega) = (slice("theta", &theta)?, slice("omega", &omega)?);
        rows("theta", theta.len(), n)?;
        let mut ws = Workspace::new(n);
        let mut out = vec![0.0; theta.len()];
        for ((th, om), o) in theta.chunks(n).zip(omega.chunks(n)).zip(out.chunks_mut(n)) {
            c.momenta_into(th, om, o, &mut ws);
        }
        Ok(vec_out(py, out))
    }

    fn velocities<'py>(&self, py: Python<'py>, theta: PyReadonlyArray1<'py, f64>, p: PyReadonlyArray1<'py, f64>) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let c = &self.inner;
        let n = c.n();
        let (theta, p) = (slice("theta", &theta)?, slice("p", &p)?);
        rows("theta", theta.len(), n)?;
        let mut ws = Workspace::new(n);
        let mut out = vec![0.0; theta.len()];
        for ((th, pp), o) in theta.chunks(n).zip(p.chunks(n)).zip(out.chunks_mut(n)) {
            c.velocities_into(th, pp, o, &mut ws).map_err(|s| to_py(py, Error::integration(0.0, s.reason())))?;
        }
        Ok(vec_out(py, out))
    }

    /// `(kinetic, potential)` energies of each row.
    fn energies<'py>(&self, py: Python<'py>, theta: PyReadonlyArray1<'py, f64>, omega: PyReadonlyArray1<'py, f64>) -> PyResult<(Bound<'py, PyArray1<f64>>, Bound<'py, PyArray1<f64>>)> {
        let c = &self.inner;
        let n = c.n();
        let (theta, omega) = (slice("theta", &theta)?, slice("omega", &omega)?);
        let b = rows("theta", theta.len(), n)?;
        let mut ws = Workspace::new(n);
        let mut scratch = vec![0.0; n];
        let (mut kin, mut pot) = (Vec::with_capacity(b), Vec::with_capacity(b));
        for (th, om) in theta.chunks(n).zip(omega.chunks(n)) {
            kin.push(c.kinetic_energy(th, om, &mut scratch, &mut ws));
            pot.push(c.potential_energy(th));
        }
        Ok((vec_out(py, kin), vec_out(py, pot)))
    }

    /// Joint positions (`com=False`) or centres of mass (`com=True`), 2N numbers per row.
    #[pyo3(signature = (theta, *, com=false))]
    fn positions<'py>(&self, py: Python<'py>, theta: PyReadonlyArray1<'py, f64>, com: bool) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let c = &self.inner;
        let n = c.n();
        let theta = slice("theta", &theta)?;
        rows("theta", theta.len(), n)?;
        let mut out = vec![0.0; 2 * theta.len()];
        for (th, o) in theta.chunks(n).zip(out.chunks_mut(2 * n)) {
            if com {
                c.com_positions_into(th, o);
            } else {
                c.positions_into(th, o);
            }
        }
        Ok(vec_out(py, out))
    }

    fn __repr__(&self) -> String {
        let c = &self.inner;
        format!(
            "Chain(lengths={:?}, masses={:?}, com={:?}, inertia={:?}, g={})",
            c.lengths(),
            c.masses(),
            c.com(),
            c.inertia(),
            c.g()
        )
    }
}

