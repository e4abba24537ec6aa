//! Reference routes for the accelerations, kept to cross-check the O(N) recursion in tests and
//! benchmarks: a dense Cholesky solve (O(N^3)) and Cramer's rule as seed 000 writes it (small N).
use crate::dynamics::Singular;
use crate::model::Chain;

/// Dense right-hand side `tau - g h sin(theta) - sum_b K_ab sin(theta_a - theta_b) omega_b^2`. O(N^2).
fn dense_rhs(chain: &Chain, theta: &[f64], omega: &[f64], tau: &[f64]) -> Vec<f64> {
    let n = chain.n();
    (0..n)
        .map(|a| {
            let coriolis: f64 = (0..n).map(|b| chain.coupling(a, b) * (theta[a] - theta[b]).sin() * omega[b] * omega[b]).sum();
            tau[a] - chain.g * chain.h[a] * theta[a].sin() - coriolis
        })
        .collect()
}

/// The routes to the accelerations: the O(N) recursion, and the reference routes it is checked
/// against, each refused beyond the size where it would look like a hang.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Algorithm {
    Recursive,
    /// A dense Cholesky solve, O(N^3).
    Cholesky,
    /// Seed 000's Cramer's rule, O(N^4).
    Cramer,
}

impl Algorithm {
    pub const ALL: [Algorithm; 3] = [Algorithm::Recursive, Algorithm::Cholesky, Algorithm::Cramer];

    pub fn name(self) -> &'static str {
        match self {
            Algorithm::Recursive => "recursive",
            Algorithm::Cholesky => "cholesky",
            Algorithm::Cramer => "cramer",
        }
    }

    /// The most links the route takes (`None`: any).
    pub fn max_links(self) -> Option<usize> {
        match self {
            Algorithm::Recursive => None,
            Algorithm::Cholesky => Some(2000),
            Algorithm::Cramer => Some(12),
        }
    }

    pub fn parse(name: &str) -> crate::error::Result<Self> {
        Self::ALL.into_iter().find(|a| a.name() == name).ok_or_else(|| {
            let valid: Vec<&str> = Self::ALL.iter().map(|a| a.name()).collect();
            crate::error::Error::input(format!("algorithm must be one of {}, got '{name}'", valid.join(", ")))
        })
    }

    /// Refuse a chain too long for the route.
    pub fn check(self, n: usize) -> crate::error::Result<()> {
        match self.max_links() {
            Some(limit) if n > limit => Err(crate::error::Error::input(format!(
                "algorithm '{}' is a reference route for N <= {limit}, got N = {n}; use the default \"recursive\" (O(N))",
                self.name()
            ))),
            _ => Ok(()),
        }
    }
}

/// Accelerations by a dense Cholesky factorisation of the mass matrix.
pub fn accelerations_cholesky(chain: &Chain, theta: &[f64], omega: &[f64], tau: &[f64]) -> Result<Vec<f64>, Singular> {
    let n = chain.n();
    let mut a = vec![0.0; n * n];
    chain.mass_matrix_into(theta, &mut a);
    let mut x = dense_rhs(chain, theta, omega, tau);
    // In-place lower Cholesky factor.
    for j in 0..n {
        let mut d = a[j * n + j];
        for k in 0..j {
            d -= a[j * n + k] * a[j * n + k];
        }
        if !(d > 0.0) {
            return Err(Singular(j));
        }
        let d = d.sqrt();
        a[j * n + j] = d;
        for i in j + 1..n {
            let mut v = a[i * n + j];
            for k in 0..j {
                v -= a[i * n + k] * a[j * n + k];
            }
            a[i * n + j] = v / d;
        }
    }
    for i in 0..n {
        let mut v = x[i];
        for k in 0..i {
            v -= a[i * n + k] * x[k];
        }
        x[i] = v / a[i * n + i];
    }
    for i in (0..n).rev() {
        let mut v = x[i];
        for k in i + 1..n {
            v -= a[k * n + i] * x[k];
        }
        x[i] = v / a[i * n + i];
    }
    Ok(x)
}

/// Determinant by Gaussian elimination with partial pivoting.
fn det(mut m: Vec<f64>, n: usize) -> f64 {
    let mut det = 1.0;
    for col in 0..n {
        let piv = (col..n).max_by(|&i, &j| m[i * n + col].abs().total_cmp(&m[j * n + col].abs())).unwrap();
        if m[piv * n + col] == 0.0 {
            return 0.0;
        }
        if piv != col {
            for k in 0..n {
                m.swap(piv * n + k, col * n + k);
            }
            det = -det;
        }
        let p = m[col * n + col];
        det *= p;
        for i in col + 1..n {
            let f = m[i * n + col] / p;
            for k in col..n {
                m[i * n + k] -= f * m[col * n + k];
            }
        }
    }
    det
}

/// Cramer's rule. For point masses (`com = lengths`, no inertia) this is seed 000 verbatim:
/// `M*_ab = cos(theta_a - theta_b) sum_{i>=max(a,b)} m_i`,
/// `S_a = tau_a / l_a - sum_{i>=a} m_i [g sin theta_a + sum_{j<=i} l_j omega_j^2 sin(theta_a - theta_j)]`,
/// `theta_ddot_n = det(M*_n) / (l_n det M*)`. Other links use the general mass matrix. O(N^4).
pub fn accelerations_cramer(chain: &Chain, theta: &[f64], omega: &[f64], tau: &[f64]) -> Result<Vec<f64>, Singular> {
    let n = chain.n();
    let point_masses = chain.com == chain.lengths && chain.inertia.iter().all(|&i| i == 0.0);
    let (m, s, scale): (Vec<f64>, Vec<f64>, Vec<f64>) = if point_masses {
        let (ms, l, g) = (&chain.masses, &chain.lengths, chain.g);
        let tail = |k: usize| ms[k..].iter().sum::<f64>();
        let m = (0..n * n).map(|ab| (theta[ab / n] - theta[ab % n]).cos() * tail((ab / n).max(ab % n))).collect();
        let s = (0..n)
            .map(|a| {
                let pull: f64 = (a..n)
                    .map(|i| {
                        let centripetal: f64 = (0..=i).map(|j| l[j] * omega[j] * omega[j] * (theta[a] - theta[j]).sin()).sum();
                        ms[i] * (g * theta[a].sin() + centripetal)
                    })
                    .sum();
                tau[a] / l[a] - pull
            })
            .collect();
        (m, s, l.clone())
    } else {
        let mut m = vec![0.0; n * n];
        chain.mass_matrix_into(theta, &mut m);
        (m, dense_rhs(chain, theta, omega, tau), vec![1.0; n])
    };
    let d = det(m.clone(), n);
    if !(d.abs() > 0.0) {
        return Err(Singular(0));
    }
    Ok((0..n)
        .map(|col| {
            let mut mc = m.clone();
            for row in 0..n {
                mc[row * n + col] = s[row];
            }
            det(mc, n) / (scale[col] * d)
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dynamics::Workspace;

    fn lcg(seed: &mut u64) -> f64 {
        *seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        ((*seed >> 11) as f64) / ((1u64 << 53) as f64)
    }

    fn random_chain(n: usize, seed: &mut u64, point: bool) -> Chain {
        let l: Vec<f64> = (0..n).map(|_| 0.2 + lcg(seed)).collect();
        let m: Vec<f64> = (0..n).map(|_| 10f64.powf(2.0 * lcg(seed) - 1.0)).collect();
        if point {
            return Chain::new(&l, &m, None, None, 9.81).unwrap();
        }
        let c: Vec<f64> = l.iter().map(|l| l * lcg(seed)).collect();
        let i: Vec<f64> = m.iter().map(|m| 0.1 * m * lcg(seed)).collect();
        Chain::new(&l, &m, Some(&c), Some(&i), 9.81).unwrap()
    }

    fn max_rel(a: &[f64], b: &[f64]) -> f64 {
        let scale = b.iter().fold(1.0f64, |s, v| s.max(v.abs()));
        a.iter().zip(b).fold(0.0f64, |e, (x, y)| e.max((x - y).abs())) / scale
    }

    #[test]
    fn recursion_matches_cramer_and_cholesky() {
        let mut seed = 7;
        for &(n, point) in &[(1, true), (2, true), (3, false), (5, true), (6, false), (40, false), (300, true)] {
            let chain = random_chain(n, &mut seed, point);
            let theta: Vec<f64> = (0..n).map(|_| 6.0 * lcg(&mut seed) - 3.0).collect();
            let omega: Vec<f64> = (0..n).map(|_| 4.0 * lcg(&mut seed) - 2.0).collect();
            let tau: Vec<f64> = (0..n).map(|_| lcg(&mut seed) - 0.5).collect();
            let mut fast = vec![0.0; n];
            chain.accelerations_into(&theta, &omega, &tau, &mut fast, &mut Workspace::new(n)).unwrap();
            let chol = accelerations_cholesky(&chain, &theta, &omega, &tau).unwrap();
            assert!(max_rel(&fast, &chol) < 1e-11, "n={n}: cholesky differs by {}", max_rel(&fast, &chol));
            if n <= 6 {
                let cramer = accelerations_cramer(&chain, &theta, &omega, &tau).unwrap();
                assert!(max_rel(&fast, &cramer) < 1e-11, "n={n}: cramer differs by {}", max_rel(&fast, &cramer));
            }
        }
    }

    #[test]
    fn double_pendulum_closed_form_equals_the_recursion() {
        let mut seed = 11;
        for k in 0..200 {
            let chain = random_chain(2, &mut seed, k % 2 == 0);
            let theta: Vec<f64> = (0..2).map(|_| 12.0 * lcg(&mut seed) - 6.0).collect();
            let omega: Vec<f64> = (0..2).map(|_| 8.0 * lcg(&mut seed) - 4.0).collect();
            let tau: Vec<f64> = (0..2).map(|_| lcg(&mut seed) - 0.5).collect();
            let (mut closed, mut general) = ([0.0; 2], vec![0.0; 2]);
            chain.accelerations_into(&theta, &omega, &tau, &mut closed, &mut Workspace::new(2)).unwrap();
            chain.accelerations_impl(&theta, &omega, &tau, &mut general, &mut Workspace::new(2)).unwrap();
            assert!(max_rel(&closed, &general) < 1e-13, "{closed:?} vs {general:?}");
        }
    }

    #[test]
    fn tangent_equations_match_central_differences() {
        let mut seed = 21;
        for &(n, point) in &[(1, true), (2, true), (3, false), (7, false), (30, true)] {
            let chain = random_chain(n, &mut seed, point);
            let theta: Vec<f64> = (0..n).map(|_| 6.0 * lcg(&mut seed) - 3.0).collect();
            let omega: Vec<f64> = (0..n).map(|_| 4.0 * lcg(&mut seed) - 2.0).collect();
            let dth: Vec<f64> = (0..n).map(|_| lcg(&mut seed) - 0.5).collect();
            let dom: Vec<f64> = (0..n).map(|_| lcg(&mut seed) - 0.5).collect();
            let tau = vec![0.0; n];
            let mut ws = Workspace::new(n);
            let accel_at = |th: &[f64], om: &[f64], ws: &mut Workspace| {
                let mut a = vec![0.0; n];
                chain.accelerations_impl(th, om, &tau, &mut a, ws).unwrap();
                a
            };
            let acc = accel_at(&theta, &omega, &mut ws);
            let (mut tangent, mut scratch) = (vec![0.0; n], vec![0.0; 6 * n]);
            chain.tangent_accelerations_into(&theta, &omega, &acc, &dth, &dom, &mut tangent, &mut scratch, &mut ws).unwrap();
            let e = 1e-5;
            let shift = |sign: f64| -> (Vec<f64>, Vec<f64>) {
                (theta.iter().zip(&dth).map(|(t, d)| t + sign * e * d).collect(), omega.iter().zip(&dom).map(|(w, d)| w + sign * e * d).collect())
            };
            let (tp, wp) = shift(1.0);
            let (tm, wm) = shift(-1.0);
            let (ap, am) = (accel_at(&tp, &wp, &mut ws), accel_at(&tm, &wm, &mut ws));
            let fd: Vec<f64> = ap.iter().zip(&am).map(|(p, m)| (p - m) / (2.0 * e)).collect();
            assert!(max_rel(&tangent, &fd) < 1e-7, "n={n}: {}", max_rel(&tangent, &fd));
        }
    }

    #[test]
    fn momenta_and_velocities_invert_each_other() {
        let mut seed = 3;
        let n = 25;
        let chain = random_chain(n, &mut seed, false);
        let theta: Vec<f64> = (0..n).map(|_| 6.0 * lcg(&mut seed)).collect();
        let omega: Vec<f64> = (0..n).map(|_| lcg(&mut seed) - 0.5).collect();
        let mut ws = Workspace::new(n);
        let (mut p, mut back) = (vec![0.0; n], vec![0.0; n]);
        chain.momenta_into(&theta, &omega, &mut p, &mut ws);
        let mut dense = vec![0.0; n * n];
        chain.mass_matrix_into(&theta, &mut dense);
        let pd: Vec<f64> = (0..n).map(|a| (0..n).map(|b| dense[a * n + b] * omega[b]).sum()).collect();
        assert!(max_rel(&p, &pd) < 1e-13);
        chain.velocities_into(&theta, &p, &mut back, &mut ws).unwrap();
        assert!(max_rel(&back, &omega) < 1e-11);
    }
}
