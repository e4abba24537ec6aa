//! Property tests over random valid chains: N from 1 to 50, masses and lengths spanning six
//! orders of magnitude, arbitrary angles and rates.
use multipendulum_core::{reference, simulate, Builtin, Chain, Method, Settings, Workspace};
use proptest::prelude::*;

fn chain_strategy() -> impl Strategy<Value = (Chain, Vec<f64>, Vec<f64>)> {
    chains(3.0)
}

/// Chains whose lengths and masses span `2 * decades` orders of magnitude.
fn chains(decades: f64) -> impl Strategy<Value = (Chain, Vec<f64>, Vec<f64>)> {
    (1usize..=50).prop_flat_map(move |n| {
        (
            prop::collection::vec(-decades..decades, n), // log10 length
            prop::collection::vec(-decades..decades, n), // log10 mass
            prop::collection::vec(0.05f64..1.0, n),      // com / length
            prop::collection::vec(0.0f64..0.2, n),       // inertia / (m l^2)
            any::<bool>(),
            prop::collection::vec(-10.0f64..10.0, n),
            prop::collection::vec(-5.0f64..5.0, n),
        )
            .prop_map(|(ll, lm, cf, inf, point, theta, omega)| {
                let l: Vec<f64> = ll.iter().map(|x| 10f64.powf(*x)).collect();
                let m: Vec<f64> = lm.iter().map(|x| 10f64.powf(*x)).collect();
                let chain = if point {
                    Chain::new(&l, &m, None, None, 9.81).unwrap()
                } else {
                    let c: Vec<f64> = l.iter().zip(&cf).map(|(l, f)| l * f).collect();
                    let i: Vec<f64> = m.iter().zip(&l).zip(&inf).map(|((m, l), f)| f * m * l * l).collect();
                    Chain::new(&l, &m, Some(&c), Some(&i), 9.81).unwrap()
                };
                // Rates scaled to each link's natural frequency, so states are physical.
                let omega = omega.iter().zip(&l).map(|(w, l)| w * (9.81 / l).sqrt()).collect();
                (chain, theta, omega)
            })
    })
}

fn dense(chain: &Chain, theta: &[f64]) -> Vec<f64> {
    let n = chain.n();
    let mut a = vec![0.0; n * n];
    chain.mass_matrix_into(theta, &mut a);
    a
}

/// The spectral radius of the Jacobian of `(theta, omega)' ` at a state, by power iteration
/// through the core's tangent equations.
fn spectral_radius(chain: &Chain, theta: &[f64], omega: &[f64]) -> f64 {
    let n = chain.n();
    let mut ws = Workspace::new(n);
    let mut acc = vec![0.0; n];
    chain.accelerations_into(theta, omega, &vec![0.0; n], &mut acc, &mut ws).unwrap();
    let (mut v, mut jv, mut scratch) = (vec![1.0; 2 * n], vec![0.0; 2 * n], vec![0.0; 6 * n]);
    let mut rho = 0.0f64;
    for _ in 0..40 {
        let norm = v.iter().map(|x| x * x).sum::<f64>().sqrt();
        v.iter_mut().for_each(|x| *x /= norm);
        jv[..n].copy_from_slice(&v[n..]);
        let (_, tail) = jv.split_at_mut(n);
        chain.tangent_accelerations_into(theta, omega, &acc, &v[..n], &v[n..], tail, &mut scratch, &mut ws).unwrap();
        rho = rho.max(jv.iter().map(|x| x * x).sum::<f64>().sqrt());
        v.copy_from_slice(&jv);
    }
    rho
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 200, ..ProptestConfig::default() })]

    #[test]
    fn mass_matrix_is_symmetric_positive_definite((chain, theta, omega) in chain_strategy()) {
        let n = chain.n();
        let a = dense(&chain, &theta);
        for i in 0..n {
            for j in 0..n {
                prop_assert_eq!(a[i * n + j], a[j * n + i]);
            }
        }
        // omega . A omega = 2 T > 0 for omega != 0, computed by the O(N) route.
        let mut ws = Workspace::new(n);
        let t = chain.kinetic_energy(&theta, &omega, &mut vec![0.0; n], &mut ws);
        prop_assert!(t > 0.0 || omega.iter().all(|w| *w == 0.0));
        prop_assert!(reference::accelerations_cholesky(&chain, &theta, &omega, &vec![0.0; n]).is_ok());
    }

    #[test]
    fn recursion_solves_the_same_system_as_the_dense_route((chain, theta, omega) in chain_strategy()) {
        let n = chain.n();
        let tau = vec![0.0; n];
        let mut fast = vec![0.0; n];
        chain.accelerations_into(&theta, &omega, &tau, &mut fast, &mut Workspace::new(n)).unwrap();
        let chol = reference::accelerations_cholesky(&chain, &theta, &omega, &tau).unwrap();
        // Backward error: A (x_fast - x_chol) is at round-off relative to |A| |x|, whatever cond(A).
        let a = dense(&chain, &theta);
        let scale_a = a.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        let scale_x = chol.iter().fold(0.0f64, |m, v| m.max(v.abs())).max(1e-300);
        let worst = (0..n)
            .map(|i| (0..n).map(|j| a[i * n + j] * (fast[j] - chol[j])).sum::<f64>().abs())
            .fold(0.0f64, f64::max);
        prop_assert!(worst <= 1e-12 * n as f64 * scale_a * scale_x, "backward error {}", worst / (scale_a * scale_x));
        prop_assert!(fast.iter().all(|v| v.is_finite()));
    }

    // Two decades: across six, a short light link between long heavy ones makes the stage
    // equations so badly scaled in (theta, p) that fixed-point iteration diverges at any practical
    // step (it then reports "did not converge", checked below); that needs a Newton iteration.
    #[test]
    fn gauss6_keeps_energy_to_its_bound((chain, theta, omega) in chains(1.0)) {
        // A step resolving the fastest motion: the spectral radius of the Jacobian.
        let rho = spectral_radius(&chain, &theta, &omega);
        let dt = 0.05 / rho.max(1e-6);
        let t_end = 50.0 * dt;
        // The energy error against the initial state (not the one output row), at dt and dt/2:
        // an order-6 method's error shrinks by 2^6 = 64 in the asymptotic range, above
        // round-off; allow the pre-asymptotic range a factor of 4 (still at least order 4).
        // Outputs along the run, to check that the step stays resolving (below).
        let t_eval: Vec<f64> = (0..=10).map(|i| (t_end * i as f64 / 10.0).min(t_end)).collect();
        let run = |dt: f64| {
            let settings = Settings { method: Method::Gauss6, dt: Some(dt), t_eval: Some(t_eval.clone()), ..Settings::default() };
            simulate(&chain, &theta, &omega, t_end, &settings, Builtin::None, &mut |_| Ok(()))
        };
        match (run(dt), run(dt / 2.0)) {
            (Ok(coarse), Ok(fine)) => {
                prop_assert!(coarse.theta.iter().chain(&coarse.omega).all(|v| v.is_finite()));
                // The step resolves the motion only if it does not speed up much anywhere along the
                // run (a chain that whips round): such cases say nothing about the bound.
                let n = chain.n();
                let fastest = (0..t_eval.len())
                    .map(|r| spectral_radius(&chain, &coarse.theta[r * n..(r + 1) * n], &coarse.omega[r * n..(r + 1) * n]))
                    .fold(0.0, f64::max);
                prop_assume!(fastest < 2.0 * rho);
                let (e1, e2) = (coarse.stats.energy_error, fine.stats.energy_error);
                prop_assert!(e1 < 1e-3, "energy error {e1} at a step of a twentieth of the fastest time scale");
                if e1 > 1e-11 {
                    prop_assert!(e1 / e2 > 16.0, "energy error {e1} at dt, {e2} at dt/2: not order 6");
                }
            }
            // Never a panic or a NaN result: at worst the documented integration error.
            (Err(e), _) | (_, Err(e)) => {
                prop_assert!(matches!(e, multipendulum_core::Error::Integration { .. }), "{e}")
            }
        }
    }

    #[test]
    fn invalid_parameters_are_errors_never_panics(
        l in prop::collection::vec(prop_oneof![Just(0.0), Just(-1.0), Just(f64::NAN), Just(f64::INFINITY), 0.1f64..10.0], 1..8),
        m in prop::collection::vec(prop_oneof![Just(0.0), Just(-1.0), Just(f64::NAN), 0.1f64..10.0], 1..8),
    ) {
        let result = Chain::new(&l, &m, None, None, 9.81);
        let valid = l.len() == m.len() && l.iter().all(|x| x.is_finite() && *x > 0.0)
            && m.iter().all(|x| x.is_finite() && *x >= 0.0) && m.last().is_some_and(|x| *x > 0.0)
            && m.iter().all(|x| *x > 0.0);
        if valid {
            prop_assert!(result.is_ok());
        } else {
            // Invalid input is refused, as an input error that says what is wrong.
            match result {
                Err(multipendulum_core::Error::Input(m)) => prop_assert!(!m.is_empty()),
                other => prop_assert!(false, "invalid lengths {l:?} / masses {m:?} gave {other:?}"),
            }
        }
    }
}
