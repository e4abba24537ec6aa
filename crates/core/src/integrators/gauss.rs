//! Implicit Gauss–Legendre collocation with s = 2 (`gauss4`, order 4) or s = 3 (`gauss6`, order 6)
//! stages (Butcher 1964; Hairer, Lubich & Wanner, Geometric Numerical Integration, sec. II.1.3).
//! Symplectic and time-reversible, so on Hamilton's equations in `(theta, p)` the energy error
//! stays bounded with no secular drift; the pendulum's Hamiltonian is not separable, so no
//! explicit leapfrog would do. Cost per step: s evaluations per fixed-point iteration, typically
//! 5–15 iterations. The stage equations are iterated until the increments stop decreasing at
//! round-off (Hairer, McLachlan & Razakarivony 2008), starting from the previous step's
//! collocation polynomial; the update uses compensated summation so round-off does not drift.
//! Where fixed-point iteration stops contracting (stiff stages: strong damping, ill-scaled
//! chains), the step's stages are solved by simplified Newton iteration with the system's exact
//! Jacobian instead. With losses (damping, friction) the flow itself is not symplectic, nor is
//! any integrator of it: the methods stay of order 2s.
use serde::{Deserialize, Serialize};

use super::dense::{Hermite, Slope};
use super::{misfit, Facts, Integrator};
use crate::dynamics::system::OdeSystem;
use crate::error::{Error, Result, Shown};

/// The facts of the `stages`-stage method (order 2s, A-stable, symplectic and implicit).
pub const fn facts(stages: usize) -> Facts {
    Facts { order: 2 * stages as u32, symplectic: true, implicit: true, adaptive: false }
}

const MAX_ITERATIONS: usize = 100;

/// The largest iteration matrix (bytes) the simplified Newton iteration factors: beyond it (a
/// chain of thousands of links, or a run with many sensitivity directions) the stages are left
/// to the fixed-point iteration, whose failure is reported (reduce dt), rather than a dense
/// matrix allocated past the machine's memory.
const NEWTON_MAX_BYTES: f64 = (1u64 << 30) as f64;

/// LU factorisation with partial pivoting in place (row-major `m x m`); `None` if singular.
fn lu_factor(a: &mut [f64], m: usize) -> Option<Vec<usize>> {
    let mut piv = vec![0; m];
    for k in 0..m {
        let p = (k..m).max_by(|&i, &j| a[i * m + k].abs().total_cmp(&a[j * m + k].abs()))?;
        piv[k] = p;
        if !(a[p * m + k].abs() > 0.0) || !a[p * m + k].is_finite() {
            return None;
        }
        if p != k {
            for j in 0..m {
                a.swap(k * m + j, p * m + j);
            }
        }
        let inv = 1.0 / a[k * m + k];
        for i in k + 1..m {
            let f = a[i * m + k] * inv;
            a[i * m + k] = f;
            if f != 0.0 {
                for j in k + 1..m {
                    a[i * m + j] -= f * a[k * m + j];
                }
            }
        }
    }
    Some(piv)
}

/// Solve with [`lu_factor`]'s result, `b` in place.
fn lu_solve(lu: &[f64], piv: &[usize], b: &mut [f64], m: usize) {
    for k in 0..m {
        b.swap(k, piv[k]);
        let bk = b[k];
        for i in k + 1..m {
            b[i] -= lu[i * m + k] * bk;
        }
    }
    for k in (0..m).rev() {
        let s: f64 = (k + 1..m).map(|j| lu[k * m + j] * b[j]).sum();
        b[k] = (b[k] - s) / lu[k * m + k];
    }
}

#[derive(Debug, Clone)]
pub struct Gauss {
    s: usize,
    a: [[f64; 3]; 3],
    b: [f64; 3],
    c: [f64; 3],
    /// `extrap[i][j] = L_j(1 + c_i)`: the previous step's stage derivatives, extrapolated.
    extrap: [[f64; 3]; 3],
    k: Vec<f64>,
    k_new: Vec<f64>,
    stage: Vec<f64>,
    /// What each component's increments are measured against ([`OdeSystem::scales`]).
    scale: Vec<f64>,
    comp: Vec<f64>,
    /// The step size whose stages `k` hold, if any (the extrapolated start needs the same h).
    last_h: Option<f64>,
    /// Fixed-point iterations so far.
    pub iterations: u64,
    dense: Hermite,
}

/// What later steps depend on: the stage slopes (the next step's starting guess), the
/// compensated-summation residuals, the step size whose stages they are (the guess is
/// extrapolated only for a next step of exactly this size), and the dense output's slope.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Memory {
    pub k: Vec<f64>,
    pub comp: Vec<f64>,
    pub last_h: Option<f64>,
    pub slope: Slope,
}

impl Gauss {
    pub fn new(stages: usize, dim: usize) -> Self {
        assert!(stages == 2 || stages == 3, "Gauss–Legendre is implemented for 2 and 3 stages");
        let (a, b, c) = if stages == 2 {
            let r = 3f64.sqrt() / 6.0;
            ([[0.25, 0.25 - r, 0.0], [0.25 + r, 0.25, 0.0], [0.0; 3]], [0.5, 0.5, 0.0], [0.5 - r, 0.5 + r, 0.0])
        } else {
            let r = 15f64.sqrt();
            (
                [
                    [5.0 / 36.0, 2.0 / 9.0 - r / 15.0, 5.0 / 36.0 - r / 30.0],
                    [5.0 / 36.0 + r / 24.0, 2.0 / 9.0, 5.0 / 36.0 - r / 24.0],
                    [5.0 / 36.0 + r / 30.0, 2.0 / 9.0 + r / 15.0, 5.0 / 36.0],
                ],
                [5.0 / 18.0, 4.0 / 9.0, 5.0 / 18.0],
                [0.5 - r / 10.0, 0.5, 0.5 + r / 10.0],
            )
        };
        let mut extrap = [[0.0; 3]; 3];
        for i in 0..stages {
            for j in 0..stages {
                extrap[i][j] = (0..stages).filter(|&m| m != j).map(|m| (1.0 + c[i] - c[m]) / (c[j] - c[m])).product();
            }
        }
        Gauss {
            s: stages,
            a,
            b,
            c,
            extrap,
            k: vec![0.0; stages * dim],
            k_new: vec![0.0; stages * dim],
            stage: vec![0.0; dim],
            scale: vec![0.0; dim],
            comp: vec![0.0; dim],
            last_h: None,
            iterations: 0,
            dense: Hermite::new(dim),
        }
    }

    /// The stage slopes `k` by fixed-point iteration from their guess: converged (`true`), or
    /// not contracting (the increments grew three times in a row above round-off, left the
    /// finite numbers, or a stage left the chain's domain).
    fn fixed_point<S: OdeSystem>(&mut self, sys: &mut S, t: f64, y: &[f64], h: f64) -> Result<bool> {
        let (s, d) = (self.s, y.len());
        sys.scales(y, &mut self.scale);
        let (mut prev, mut growing) = (f64::INFINITY, 0);
        for _ in 0..MAX_ITERATIONS {
            self.iterations += 1;
            for i in 0..s {
                for m in 0..d {
                    let z: f64 = (0..s).map(|j| self.a[i][j] * self.k[j * d + m]).sum();
                    self.stage[m] = y[m] + h * z;
                }
                match sys.rhs(t + self.c[i] * h, &self.stage, &mut self.k_new[i * d..(i + 1) * d]) {
                    Err(Error::Integration { .. }) => return Ok(false),
                    other => other?,
                }
            }
            let mut delta = 0.0f64;
            for i in 0..s {
                for m in 0..d {
                    let change = h * (self.k_new[i * d + m] - self.k[i * d + m]);
                    delta = delta.max(change.abs() / self.scale[m]);
                }
            }
            std::mem::swap(&mut self.k, &mut self.k_new);
            if !delta.is_finite() {
                return Ok(false);
            }
            // Converged once the increments vanish or stop shrinking at round-off level.
            if delta == 0.0 || (delta >= prev && delta < 1e-13) {
                return Ok(true);
            }
            growing = if delta > prev { growing + 1 } else { 0 };
            if growing >= 3 {
                return Ok(false);
            }
            prev = delta;
        }
        Ok(false)
    }

    /// The stage slopes by simplified Newton iteration with the system's exact Jacobian at the
    /// step's start (Hairer & Wanner, Solving ODEs II, sec. IV.8): the iteration matrix
    /// `I - h A (x) J` of the `s d` stage unknowns is factored once per step. For stiff stages
    /// (strong damping, ill-scaled chains) where fixed-point iteration diverges. `false` when the
    /// system has no Jacobian or the iteration does not converge either.
    fn newton<S: OdeSystem>(&mut self, sys: &mut S, t: f64, y: &[f64], h: f64) -> Result<bool> {
        let (s, d) = (self.s, y.len());
        if ((s * d) as f64).powi(2) * 8.0 > NEWTON_MAX_BYTES {
            return Ok(false);
        }
        let mut jac = vec![0.0; d * d];
        if !sys.jacobian(t, y, &mut jac)? {
            return Ok(false);
        }
        let m = s * d;
        let mut lu = vec![0.0; m * m];
        for i in 0..s {
            for j in 0..s {
                let a = h * self.a[i][j];
                for r in 0..d {
                    for c in 0..d {
                        lu[(i * d + r) * m + j * d + c] = -a * jac[r * d + c];
                    }
                }
            }
        }
        for k in 0..m {
            lu[k * m + k] += 1.0;
        }
        let Some(pivots) = lu_factor(&mut lu, m) else { return Ok(false) };
        let (first, rest) = self.k.split_at_mut(d);
        sys.rhs(t, y, first)?;
        for i in 1..s {
            rest[(i - 1) * d..i * d].copy_from_slice(first);
        }
        let mut prev = f64::INFINITY;
        for _ in 0..MAX_ITERATIONS {
            self.iterations += 1;
            for i in 0..s {
                for m in 0..d {
                    let z: f64 = (0..s).map(|j| self.a[i][j] * self.k[j * d + m]).sum();
                    self.stage[m] = y[m] + h * z;
                }
                let out = &mut self.k_new[i * d..(i + 1) * d];
                match sys.rhs(t + self.c[i] * h, &self.stage, out) {
                    Err(Error::Integration { .. }) => return Ok(false),
                    other => other?,
                }
                for (o, k) in out.iter_mut().zip(&self.k[i * d..(i + 1) * d]) {
                    *o -= k;
                }
            }
            lu_solve(&lu, &pivots, &mut self.k_new, m);
            let mut delta = 0.0f64;
            for i in 0..s {
                for m in 0..d {
                    let change = self.k_new[i * d + m];
                    if !change.is_finite() {
                        return Ok(false);
                    }
                    self.k[i * d + m] += change;
                    delta = delta.max((h * change).abs() / self.scale[m]);
                }
            }
            if delta == 0.0 || (delta >= prev && delta < 1e-13) {
                return Ok(true);
            }
            prev = delta;
        }
        Ok(false)
    }

    pub fn name(&self) -> &'static str {
        if self.s == 2 {
            "gauss4"
        } else {
            "gauss6"
        }
    }
}

impl Integrator for Gauss {
    type Memory = Memory;

    fn facts(&self) -> Facts {
        facts(self.s)
    }

    fn iterations(&self) -> u64 {
        self.iterations
    }

    /// Forget the previous step: no extrapolated guess, no compensation residual.
    fn start<S: OdeSystem>(&mut self, _sys: &mut S, _t: f64, _y: &[f64]) -> Result<()> {
        self.last_h = None;
        self.comp.fill(0.0);
        self.dense.forget();
        Ok(())
    }

    fn accept(&mut self) {
        self.dense.accept();
    }

    fn dense<S: OdeSystem>(&mut self, sys: &mut S, t: f64, y: &[f64], _h: f64, t_new: f64, y_new: &[f64]) -> Result<()> {
        self.dense.prepare(sys, t, y, t_new, y_new)
    }

    fn interpolate(&self, y: &[f64], y_new: &[f64], h: f64, x: f64, out: &mut [f64]) {
        self.dense.interpolate(y, y_new, h, x, out)
    }

    fn save(&self) -> Memory {
        Memory { k: self.k.clone(), comp: self.comp.clone(), last_h: self.last_h, slope: self.dense.save() }
    }

    fn restore(&mut self, m: Memory) -> Result<()> {
        if m.k.len() != self.k.len() || m.comp.len() != self.comp.len() || m.last_h.is_some_and(|h| !(h.is_finite() && h > 0.0)) {
            return Err(misfit(
                self.name(),
                format!("{} stage slopes and {} residuals expected, got {} and {}", self.k.len(), self.comp.len(), m.k.len(), m.comp.len()),
            ));
        }
        self.dense.restore(m.slope, self.name())?;
        self.k.copy_from_slice(&m.k);
        self.comp.copy_from_slice(&m.comp);
        self.last_h = m.last_h;
        Ok(())
    }

    fn attempt<S: OdeSystem>(&mut self, sys: &mut S, t: f64, y: &[f64], h: f64, y_new: &mut [f64]) -> Result<Option<f64>> {
        let (s, d) = (self.s, y.len());
        if self.last_h == Some(h) {
            self.k_new.copy_from_slice(&self.k);
            for i in 0..s {
                for m in 0..d {
                    self.k[i * d + m] = (0..s).map(|j| self.extrap[i][j] * self.k_new[j * d + m]).sum();
                }
            }
        } else {
            let (first, rest) = self.k.split_at_mut(d);
            sys.rhs(t, y, first)?;
            for i in 1..s {
                rest[(i - 1) * d..i * d].copy_from_slice(first);
            }
        }
        let mut converged = self.fixed_point(sys, t, y, h)?;
        if !converged {
            converged = self.newton(sys, t, y, h)?;
        }
        if !converged {
            self.last_h = None;
            return Err(Error::integration(t, format!("the implicit stage equations of gauss{} did not converge; reduce dt (now {})", 2 * s, Shown(h))));
        }
        for m in 0..d {
            let inc: f64 = (0..s).map(|i| self.b[i] * self.k[i * d + m]).sum::<f64>() * h + self.comp[m];
            let new = y[m] + inc;
            self.comp[m] = inc - (new - y[m]);
            y_new[m] = new;
        }
        self.last_h = Some(h);
        Ok(None)
    }

    fn save_any(&self) -> super::AnyMemory {
        super::AnyMemory::Gauss(self.save())
    }

    fn restore_any(&mut self, memory: super::AnyMemory) -> Result<()> {
        match memory {
            super::AnyMemory::Gauss(m) => self.restore(m),
            _ => Err(super::other_method(Gauss::name(self))),
        }
    }

    fn name(&self) -> &'static str {
        Gauss::name(self)
    }
}
