//! A run with forward sensitivities: the chain's system with the sensitivity columns riding
//! along ([`crate::dynamics::sensitivity::Columns`]), one augmented ODE that every method
//! integrates as it does the chain alone. Integrating the variational equations with the
//! run's own method gives the derivative of the method's own map (for rk4 and the Gauss
//! methods exactly, up to the implicit stages' convergence), so the Gauss methods'
//! sensitivity to the initial `(theta, p)` is symplectic; dop853 controls the error of the
//! chain's state only, so its columns follow the state's steps.
use crate::dynamics::base::Drive;
use crate::dynamics::general::Load;
use crate::dynamics::sensitivity::{directions, Columns, Input};
use crate::dynamics::system::{singular, ChainSystem, Form, Layout, OdeSystem};
use crate::dynamics::torque::TorqueSource;
use crate::error::{Error, Result};
use crate::model::Chain;

/// What the run loop ([`super::simulate`](fn@super::simulate)) needs of its system besides the right-hand side: the
/// chain's form and layout (its leading `layout.dim()` values are the chain's state), and what
/// rides along.
pub(crate) trait Traced: OdeSystem {
    fn form(&self) -> Form;
    fn layout(&self) -> Layout;
    /// The whole initial state from the chain's own `y` at t = 0.
    fn start(&mut self, y: Vec<f64>) -> Result<Vec<f64>> {
        Ok(y)
    }
    /// The sensitivities of the recorded rows (of `self.dim()` values) at times `t`.
    fn sensitivities(&mut self, _rec: &[f64], _t: &[f64]) -> Result<Derivatives> {
        Ok(Derivatives::default())
    }
}

impl<T: TorqueSource> Traced for ChainSystem<&Chain, T> {
    fn form(&self) -> Form {
        ChainSystem::form(self)
    }
    fn layout(&self) -> Layout {
        ChainSystem::layout(self)
    }
}

/// A run's sensitivities, laid out as [`super::Trajectory::sensitivities`] says.
#[derive(Debug, Clone, Default)]
pub(crate) struct Derivatives {
    pub derivatives: Vec<f64>,
    pub canonical: Vec<f64>,
    pub directions: usize,
}

pub(crate) struct Sensitive<'c, T> {
    chain: &'c Chain,
    sys: ChainSystem<&'c Chain, T>,
    cols: Columns,
    /// The chain's state's length, where the columns start.
    base: usize,
}

impl<'c, T: TorqueSource> Sensitive<'c, T> {
    pub fn new(chain: &'c Chain, sys: ChainSystem<&'c Chain, T>, inputs: &[Input], drive: &Drive) -> Result<Self> {
        if sys.torque_uses_state() {
            return Err(Error::input(
                "sensitivities need torques that depend on time only (a constant, Sinusoid, Table or f(t)), \
                 not a feedback f(t, theta, omega)",
            ));
        }
        if drive.force.as_ref().is_some_and(|f| f.is_feedback()) {
            return Err(Error::input("sensitivities need a cart force that depends on time only, not a feedback f(t, state)"));
        }
        let cols = Columns::new(chain, sys.form(), directions(inputs, chain.n())?);
        Ok(Sensitive { chain, base: sys.layout().dim(), cols, sys })
    }

    fn load(&self, t: f64) -> Result<Load> {
        let chain = self.chain;
        Ok(if self.sys.layout().pivot { Load::pivot(chain, self.sys.pivot_motion(t)?.acc) } else { Load::still(chain) })
    }
}

impl<T: TorqueSource> OdeSystem for Sensitive<'_, T> {
    fn dim(&self) -> usize {
        self.base + self.cols.len()
    }

    /// The chain's Jacobian on every diagonal block (the columns' equations are `J S + f_P`),
    /// leaving out the columns' dependence on the state: an approximate Jacobian, for the
    /// implicit methods' simplified Newton iteration, whose error matrix is then strictly
    /// block-lower-triangular, so the iteration still converges to the exact stages.
    fn jacobian(&mut self, t: f64, y: &[f64], out: &mut [f64]) -> Result<bool> {
        let (b, m, dim) = (self.base, self.cols.mech, self.dim());
        let mut jac = vec![0.0; b * b];
        if !self.sys.jacobian(t, &y[..b], &mut jac)? {
            return Ok(false);
        }
        out[..dim * dim].fill(0.0);
        for r in 0..b {
            out[r * dim..r * dim + b].copy_from_slice(&jac[r * b..(r + 1) * b]);
        }
        for c in 0..self.cols.dirs.len() {
            let o = b + c * m;
            for r in 0..m {
                out[(o + r) * dim + o..(o + r) * dim + o + m].copy_from_slice(&jac[r * b..r * b + m]);
            }
        }
        Ok(true)
    }

    /// The chain's state as usual; a column's entries against the column's 1-norm (at least
    /// 1): the O(N) recursions mix a column's entries, so its round-off scales with their sum,
    /// not with each entry.
    fn scales(&self, y: &[f64], out: &mut [f64]) {
        let (b, m) = (self.base, self.cols.mech);
        self.sys.scales(&y[..b], &mut out[..b]);
        for (o, col) in out[b..].chunks_mut(m).zip(y[b..].chunks(m)) {
            o.fill(col.iter().map(|v| v.abs()).sum::<f64>().max(1.0));
        }
    }

    fn rhs(&mut self, t: f64, y: &[f64], dy: &mut [f64]) -> Result<()> {
        let b = self.base;
        let (dy_state, dy_cols) = dy.split_at_mut(b);
        self.sys.rhs(t, &y[..b], dy_state)?;
        // The gravity and cart force the chain's own evaluation just used (a pivot given as a
        // function is called once per evaluation).
        let load = self.sys.last_load();
        let chain = self.chain;
        let evaluated = self.sys.evaluated();
        self.cols.rates(chain, &load, &y[..b], dy_state, &y[b..], dy_cols, evaluated).map_err(|s| singular(t, y, s))
    }
}

impl<T: TorqueSource> Traced for Sensitive<'_, T> {
    fn form(&self) -> Form {
        self.sys.form()
    }

    fn layout(&self) -> Layout {
        self.sys.layout()
    }

    fn start(&mut self, mut y: Vec<f64>) -> Result<Vec<f64>> {
        let chain = self.chain;
        let n = chain.n();
        let load = self.load(0.0)?;
        // The rates at t = 0: the Lagrangian state holds them, the Hamiltonian one gives them.
        let mut dy = vec![0.0; self.base];
        self.sys.rhs(0.0, &y, &mut dy)?;
        let (omega0, v0) = match self.sys.form() {
            Form::Lagrangian => (y[n..2 * n].to_vec(), if chain.cart().is_some() { y[2 * n + 1] } else { 0.0 }),
            Form::Hamiltonian => (dy[..n].to_vec(), if chain.cart().is_some() { dy[2 * n] } else { 0.0 }),
        };
        let mut cols = vec![0.0; self.cols.len()];
        self.cols.initial(chain, &load, &y[..n], &omega0, v0, &mut cols).map_err(|s| singular(0.0, &y, s))?;
        y.extend_from_slice(&cols);
        Ok(y)
    }

    fn sensitivities(&mut self, rec: &[f64], t: &[f64]) -> Result<Derivatives> {
        let (d, b, k, m) = (self.dim(), self.base, self.cols.dirs.len(), self.cols.mech);
        let hamiltonian = self.sys.form() == Form::Hamiltonian;
        let mut out = Derivatives { derivatives: vec![0.0; t.len() * m * k], canonical: Vec::new(), directions: k };
        if hamiltonian {
            out.canonical = vec![0.0; t.len() * m * k];
        }
        for (r, row) in rec.chunks(d).enumerate() {
            let load = self.load(t[r])?;
            let rates = &mut out.derivatives[r * m * k..(r + 1) * m * k];
            self.cols.output(self.chain, &load, &row[..b], &row[b..], rates).map_err(|s| singular(t[r], row, s))?;
            if hamiltonian {
                let raw = &mut out.canonical[r * m * k..(r + 1) * m * k];
                for c in 0..k {
                    for i in 0..m {
                        raw[i * k + c] = row[b + c * m + i];
                    }
                }
            }
        }
        Ok(out)
    }
}
