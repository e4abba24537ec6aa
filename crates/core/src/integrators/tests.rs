//! Per integrator, through the run driver: the fitted convergence order against the declared
//! one, and save/restore of the memory giving a bit-identical continuation.
use super::*;
use crate::dynamics::system::{ChainSystem, Form};
use crate::dynamics::torque::Builtin;
use crate::model::Chain;
use crate::run::driver::{Config, Run, State};

/// A manufactured problem with the exact solution `Y(t) = (2 + sin t, cos 2t)`: time-dependent
/// and nonlinear off the solution, so neither stage times nor linearity hide an order.
struct Manufactured;

fn exact(t: f64) -> [f64; 2] {
    [2.0 + t.sin(), (2.0 * t).cos()]
}

impl OdeSystem for Manufactured {
    fn dim(&self) -> usize {
        2
    }
    fn rhs(&mut self, t: f64, y: &[f64], dy: &mut [f64]) -> Result<()> {
        let e = exact(t);
        let (u, v) = (y[0] - e[0], y[1] - e[1]);
        dy[0] = t.cos() - u + u * v;
        dy[1] = -2.0 * (2.0 * t).sin() - 0.5 * v - u * u;
        Ok(())
    }
}

fn config(method: Method, dt: f64, t_end: f64) -> Config {
    Config { method, dt: Some(dt), rtol: 1e-10, atol: 1e-12, adaptive: false, t_end: Some(t_end), max_steps: u64::MAX }
}

/// Least-squares slope of log(error) against log(dt).
fn slope(points: &[(f64, f64)]) -> f64 {
    let n = points.len() as f64;
    let (xs, ys): (Vec<f64>, Vec<f64>) = points.iter().map(|&(h, e)| (h.ln(), e.ln())).unzip();
    let (mx, my) = (xs.iter().sum::<f64>() / n, ys.iter().sum::<f64>() / n);
    let sxy: f64 = xs.iter().zip(&ys).map(|(x, y)| (x - mx) * (y - my)).sum();
    let sxx: f64 = xs.iter().map(|x| (x - mx).powi(2)).sum();
    sxy / sxx
}

#[test]
fn the_fitted_order_of_every_method_is_its_declared_order() {
    let t_end = 2.0;
    for method in Method::ALL {
        // Steps where the error is far above round-off and in the asymptotic range.
        let (first, count) = match method.order() {
            4 => (0.1, 5),
            6 => (0.4, 4),
            _ => (1.0, 4),
        };
        let points: Vec<(f64, f64)> = (0..count)
            .map(|k| {
                let dt = first / 2f64.powi(k);
                let mut run = Run::new(Manufactured, exact(0.0).to_vec(), &config(method, dt, t_end)).unwrap();
                while !run.at_end() {
                    run.step(t_end).unwrap();
                }
                assert_eq!(run.t(), t_end, "{}", method.name());
                let e = exact(t_end);
                let err = (run.y()[0] - e[0]).hypot(run.y()[1] - e[1]);
                assert!(err > 1e-14, "{}: error {err} at dt = {dt} is round-off, not truncation", method.name());
                (dt, err)
            })
            .collect();
        let p = slope(&points);
        let order = method.order() as f64;
        assert!((p - order).abs() < 0.25, "{}: fitted order {p:.3}, declared {order} ({points:?})", method.name());
    }
}

fn double_pendulum_run(method: Method) -> Run<ChainSystem<Chain, Builtin>> {
    let chain = Chain::new(&[1.0, 0.8], &[1.0, 1.5], None, None, 9.81).unwrap();
    let torque = Builtin::sinusoid(2, vec![0.3, 0.0], vec![2.0, 1.0], vec![0.0; 2], vec![0.0; 2]).unwrap();
    let form = if method.symplectic() { Form::Hamiltonian } else { Form::Lagrangian };
    let sys = ChainSystem::new(chain, torque, form);
    let config = Config { method, dt: Some(0.01), rtol: 1e-9, atol: 1e-11, adaptive: true, t_end: None, max_steps: u64::MAX };
    Run::new(sys, vec![2.0, 2.5, 0.0, 0.3, 0.0], &config).unwrap()
}

/// Steps with dense output on some of them (so the slope caches are in play).
fn steps(run: &mut Run<ChainSystem<Chain, Builtin>>, from: u64, count: u64) {
    let mut out = vec![0.0; 5];
    for k in from..from + count {
        run.step(f64::INFINITY).unwrap();
        if k % 7 == 0 || k % 7 == 1 {
            run.dense().unwrap();
            run.interpolate(0.5, &mut out);
        }
    }
}

#[test]
fn a_restored_memory_continues_bit_for_bit() {
    for method in Method::ALL {
        let mut whole = double_pendulum_run(method);
        steps(&mut whole, 0, 100);
        let saved = whole.save();
        let bytes = postcard::to_allocvec(&saved).unwrap();
        steps(&mut whole, 100, 200);
        let restored: State = postcard::from_bytes(&bytes).unwrap();
        assert_eq!(postcard::to_allocvec(&restored).unwrap(), bytes);
        let chain = Chain::new(&[1.0, 0.8], &[1.0, 1.5], None, None, 9.81).unwrap();
        let torque = Builtin::sinusoid(2, vec![0.3, 0.0], vec![2.0, 1.0], vec![0.0; 2], vec![0.0; 2]).unwrap();
        let form = if method.symplectic() { Form::Hamiltonian } else { Form::Lagrangian };
        let config = Config { method, dt: Some(0.01), rtol: 1e-9, atol: 1e-11, adaptive: true, t_end: None, max_steps: u64::MAX };
        let mut resumed = Run::resume(ChainSystem::new(chain, torque, form), restored, &config).unwrap();
        steps(&mut resumed, 100, 200);
        // Compared as bytes: bit for bit, and NaN (rk4's unused h) equal to itself.
        let bits = |r: &Run<_>| postcard::to_allocvec(&r.save()).unwrap();
        assert_eq!(bits(&resumed), bits(&whole), "{}: state, counters and memory", method.name());
        assert!(resumed.y().iter().zip(whole.y()).all(|(a, b)| a.to_bits() == b.to_bits()), "{}", method.name());
    }
}

#[test]
fn a_memory_of_another_method_or_size_is_refused() {
    let gauss = double_pendulum_run(Method::Gauss6).save().memory;
    let mut rk = AnyIntegrator::new(Method::Rk4, 5, 1e-10, 1e-12);
    assert!(rk.restore(gauss.clone()).unwrap_err().to_string().contains("not that of this method (rk4)"));
    let mut small = AnyIntegrator::new(Method::Gauss6, 4, 1e-10, 1e-12);
    assert!(small.restore(gauss).unwrap_err().to_string().contains("does not fit gauss6"));
}
