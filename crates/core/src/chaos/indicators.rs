//! Chaos indicators from the variational equations, for single states and batches:
//!
//! - **MEGNO** `<Y>` (Cincotta & Simo 2000): `Y(t) = (2/t) int_0^t s (d' . d)/(d . d) ds`, time
//!   averaged; tends to 2 on regular (non-isochronous) orbits, to 0 on stable isochronous ones,
//!   and grows like `lambda t / 2` on chaotic ones. Integrated with the orbit (two more states).
//! - **FLI** (Froeschle, Lega & Gonczi 1997): `sup_{s <= t} ln |d(s)|` from `|d(0)| = 1`; its
//!   orthogonal variant **OFLI** (Fouchard et al. 2002) takes the part of `d` orthogonal to the
//!   flow, which removes the linear growth along a regular orbit.
//! - **SALI** (Skokos 2001): `min(|u + v|, |u - v|)` of two unit deviation vectors; tends to 0
//!   (exponentially, at `lambda_1 - lambda_2`) on chaotic orbits, stays positive on regular ones.
//! - **The largest Lyapunov exponent** (Benettin et al. 1980): `ln |d(t)| / t` of one renormalised
//!   vector, the finite-time estimate (what [`super::lyapunov`] gives with `k = 1`, for maps).
//! - **GALI_k** (Skokos, Bountis & Antonopoulos 2007): the volume of the parallelepiped of `k`
//!   unit deviation vectors; on chaotic orbits it decays like
//!   `exp(-sum_{i=2..k} (lambda_1 - lambda_i) t)`, on regular orbits of an N-degree-of-freedom
//!   chain it stays constant for `k <= N` and decays like `t^{-2(k-N)}` for `k > N`.
//!
//! Every indicator steps rk4 at a fixed `dt` on the grid `t_k = k dt`, on the Lagrangian form of
//! [`super::Tangent`] (damping and friction included, as for the Lyapunov exponents). The
//! deviation vectors start from a fixed pseudo-random orthonormal set (the same in every call, so
//! results are reproducible) unless given, and are renormalised after every step (their
//! directions, all the indicators see, are unchanged by it).
use super::{check_steps, Tangent};
use crate::dynamics::base::{Drive, Pivot};
use crate::dynamics::system::{OdeSystem, NON_FINITE};
use crate::dynamics::torque::Builtin;
use crate::error::{check_finite, Error, Result, Shown};
use crate::integrators::Rk4;
use crate::model::Chain;
use crate::par::*;
use crate::watch::Watch;

/// Which indicator.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Indicator {
    Megno,
    Fli,
    /// The orthogonal FLI.
    Ofli,
    Sali,
    /// GALI_k, `2 <= k <= 2N`.
    Gali(usize),
    /// The largest Lyapunov exponent's finite-time estimate.
    Lyapunov,
}

impl Indicator {
    /// The names [`Indicator::parse`] takes, stated once.
    pub const NAMES: [&'static str; 6] = ["megno", "fli", "ofli", "sali", "gali", "lyapunov"];

    /// The indicator called `name`; `k` is GALI's order (ignored by the others).
    pub fn parse(name: &str, k: Option<usize>) -> Result<Self> {
        match name {
            "megno" => Ok(Indicator::Megno),
            "fli" => Ok(Indicator::Fli),
            "ofli" => Ok(Indicator::Ofli),
            "sali" => Ok(Indicator::Sali),
            "lyapunov" => Ok(Indicator::Lyapunov),
            "gali" => k.map(Indicator::Gali).ok_or_else(|| Error::input("gali needs its order k (2 <= k <= 2N)")),
            other => Err(Error::input(format!("indicator must be one of {}, got {other:?}", Self::NAMES.join(", ")))),
        }
    }

    /// The rule of thumb that calls a value chaotic, where the field has one: `(above,
    /// threshold)`, chaotic when the value is above (`true`) or below the threshold. MEGNO above
    /// 4 (regular orbits tend to 2 and reach it slowly on short runs), SALI and GALI below 1e-8
    /// (Skokos 2001; Skokos et al. 2007). The other indicators' levels depend on the time and the
    /// system: `None`, chaotic above a threshold the caller states.
    pub fn chaos_rule(self) -> (bool, Option<f64>) {
        match self {
            Indicator::Megno => (true, Some(4.0)),
            Indicator::Sali | Indicator::Gali(_) => (false, Some(1e-8)),
            Indicator::Fli | Indicator::Ofli | Indicator::Lyapunov => (true, None),
        }
    }

    /// The indicator's name, as [`Indicator::parse`] takes it.
    pub fn name(self) -> &'static str {
        match self {
            Indicator::Megno => "megno",
            Indicator::Fli => "fli",
            Indicator::Ofli => "ofli",
            Indicator::Sali => "sali",
            Indicator::Gali(_) => "gali",
            Indicator::Lyapunov => "lyapunov",
        }
    }

    /// Deviation vectors it follows.
    pub fn vectors(self) -> usize {
        match self {
            Indicator::Megno | Indicator::Fli | Indicator::Ofli | Indicator::Lyapunov => 1,
            Indicator::Sali => 2,
            Indicator::Gali(k) => k,
        }
    }
}

/// An indicator's value at the end of a run, and its history.
#[derive(Debug, Clone, PartialEq)]
pub struct Series {
    pub value: f64,
    pub times: Vec<f64>,
    pub values: Vec<f64>,
}

/// `k` orthonormal vectors of dimension `d` (row-major `k x d`), the same in every call: a fixed
/// SplitMix64 sequence mapped to (-1, 1), orthonormalised by modified Gram-Schmidt (a generic
/// start: no special direction of the phase space).
pub fn initial_deviations(d: usize, k: usize) -> Vec<f64> {
    let mut state: u64 = 0x9E37_79B9_7F4A_7C15;
    let mut next = || {
        state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = state;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
        (z >> 11) as f64 / (1u64 << 52) as f64 - 1.0
    };
    let mut v: Vec<f64> = (0..k * d).map(|_| next()).collect();
    orthonormalise(&mut v, d, k).expect("a generic set is independent");
    v
}

/// Modified Gram-Schmidt on the rows of `v` (`k x d`), in place; the product of the norms
/// before normalisation (the rows' volume). Err if a row collapses.
pub(super) fn orthonormalise(v: &mut [f64], d: usize, k: usize) -> Result<f64> {
    let mut volume = 1.0;
    for j in 0..k {
        let (done, rest) = v.split_at_mut(d * j);
        let row = &mut rest[..d];
        for i in 0..j {
            let u = &done[d * i..d * (i + 1)];
            let dot: f64 = u.iter().zip(row.iter()).map(|(a, b)| a * b).sum();
            row.iter_mut().zip(u).for_each(|(b, a)| *b -= dot * a);
        }
        let norm = norm(row);
        if !(norm > 0.0) {
            return Err(Error::input("the deviation vectors must be linearly independent"));
        }
        volume *= norm;
        row.iter_mut().for_each(|x| *x /= norm);
    }
    Ok(volume)
}

/// The `k` unit deviation vectors a run starts from: `deviations` (`k x d`) normalised (their
/// directions as given; they must span k dimensions), or [`initial_deviations`].
fn start_vectors(d: usize, k: usize, deviations: Option<&[f64]>) -> Result<Vec<f64>> {
    let Some(dev) = deviations else {
        return Ok(initial_deviations(d, k));
    };
    orthonormalise(&mut dev.to_vec(), d, k)?;
    let mut v = dev.to_vec();
    for row in v.chunks_mut(d) {
        let r = norm(row);
        row.iter_mut().for_each(|x| *x /= r);
    }
    Ok(v)
}

fn norm(v: &[f64]) -> f64 {
    v.iter().map(|x| x * x).sum::<f64>().sqrt()
}

/// A pivot that moves (one held anywhere is the fixed one: `None`).
fn moving(pivot: Option<&Pivot>) -> Option<&Pivot> {
    pivot.filter(|p| !p.is_fixed())
}

/// The checks every call makes; the number of steps.
fn check(chain: &Chain, t_end: f64, dt: f64, which: Indicator, deviations: Option<&[f64]>) -> Result<u64> {
    let d = 2 * chain.n();
    if !(t_end.is_finite() && t_end > 0.0) {
        return Err(Error::input(format!("t_end must be > 0 and finite, got {}", Shown(t_end))));
    }
    if !(dt.is_finite() && dt > 0.0 && dt <= t_end) {
        return Err(Error::input(format!("dt must be > 0, finite and <= t_end, got {}", Shown(dt))));
    }
    if let Indicator::Gali(k) = which {
        if !(2..=d).contains(&k) {
            return Err(Error::input(format!("GALI's order k must be between 2 and 2N = {d}, got {k}")));
        }
    }
    if chain.cart().is_some() {
        return Err(Error::input(
            "chaos indicators are computed for chains on a pivot (fixed or moving), not on a cart (the cart's position is a neutral direction; mp.lyapunov takes a cart)",
        ));
    }
    if let Some(dev) = deviations {
        let k = which.vectors();
        if dev.len() != k * d {
            return Err(Error::input(format!("deviations must have shape ({k}, 2N = {d}), got {} values", dev.len())));
        }
        check_finite("deviations", dev)?;
    }
    let steps = (t_end / dt).round().max(1.0);
    check_steps(steps, "t_end / dt")?;
    Ok(steps as u64)
}

/// One run's indicator with its history every `record_every` steps (and at the end).
#[allow(clippy::too_many_arguments)]
pub fn indicator(
    chain: &Chain,
    theta0: &[f64],
    omega0: &[f64],
    t_end: f64,
    dt: f64,
    which: Indicator,
    (torque, pivot): (&Builtin, Option<&Pivot>),
    deviations: Option<&[f64]>,
    record_every: u64,
    watch: &Watch,
) -> Result<Series> {
    let steps = check(chain, t_end, dt, which, deviations)?;
    let pivot = moving(pivot);
    if record_every == 0 {
        return Err(Error::input("record_every must be >= 1 step, got 0"));
    }
    let samples = (steps / record_every + 1) as f64;
    crate::memory::check(samples * 16.0, &format!("a history of {samples:.0} samples"), "use a larger record_every")?;
    let mut series = Series { value: f64::NAN, times: Vec::new(), values: Vec::new() };
    let keep = |series: &mut Series, step: u64, v: f64| {
        if step % record_every == 0 || step == steps {
            series.times.push(step as f64 * dt);
            series.values.push(v);
        }
    };
    // In lanes where a batch would be, so that a state's value is its value in any batch.
    let mut value = None;
    if let Some(path) = super::indicator_lanes::route(chain, pivot)? {
        chain.check_state("theta0", theta0)?;
        chain.check_state("omega0", omega0)?;
        let start = start_vectors(2 * chain.n(), which.vectors(), deviations)?;
        value = super::indicator_lanes::indicator(chain, theta0, omega0, steps, dt, which, (torque, pivot), &start, path, watch, &mut |step, v| {
            keep(&mut series, step, v)
        })?;
    }
    let value = match value {
        Some(v) => v,
        None => {
            // (what the lanes recorded of a run they could not finish is dropped)
            series.times.clear();
            series.values.clear();
            run(chain, theta0, omega0, steps, dt, which, (torque, pivot), deviations, watch, true, &mut |step, v| keep(&mut series, step, v))?
        }
    };
    series.value = value;
    Ok(series)
}

/// The indicator at `t_end` of every row of `theta0`, `omega0` (B x N), in parallel; each value
/// independent of the batch and the number of threads. `watch` counts rows done.
#[allow(clippy::too_many_arguments)]
pub fn indicators(
    chain: &Chain,
    theta0: &[f64],
    omega0: &[f64],
    t_end: f64,
    dt: f64,
    which: Indicator,
    (torque, pivot): (&Builtin, Option<&Pivot>),
    deviations: Option<&[f64]>,
    watch: &Watch,
) -> Result<Vec<f64>> {
    let n = chain.n();
    let steps = check(chain, t_end, dt, which, deviations)?;
    let pivot = moving(pivot);
    let b = crate::dynamics::rows::count("theta0", theta0.len(), n)?;
    if omega0.len() != theta0.len() {
        return Err(Error::input(format!("theta0 and omega0 must both have shape (B, {n})")));
    }
    if let Some(path) = super::indicator_lanes::route(chain, pivot)? {
        for i in 0..b {
            chain.check_state("theta0", &theta0[i * n..(i + 1) * n])?;
            chain.check_state("omega0", &omega0[i * n..(i + 1) * n])?;
        }
        let start = start_vectors(2 * n, which.vectors(), deviations)?;
        return super::indicator_lanes::indicators(chain, theta0, omega0, steps, dt, which, (torque, pivot), &start, deviations, path, watch);
    }
    let rows: Vec<Result<f64>> = (0..b)
        .into_par_iter()
        .map(|i| {
            // A stopped batch skips its remaining rows at once (a row's run looks only every
            // 64 steps, which with a pivot function take a while each).
            watch.check(0.0)?;
            let r = run(
                chain,
                &theta0[i * n..(i + 1) * n],
                &omega0[i * n..(i + 1) * n],
                steps,
                dt,
                which,
                (torque, pivot),
                deviations,
                watch,
                false,
                &mut |_, _| {},
            );
            watch.add_units(1);
            r
        })
        .collect();
    rows.into_iter().collect()
}

/// A certified batch: [`indicators`] at `dt` (the values reported) and again at `dt / 2`; a row
/// is uncertain where the two runs fall on different sides of `threshold` (the indicator's
/// [`Indicator::chaos_rule`] unless given), so that whether it looks chaotic depends on the step.
/// `watch` counts each row twice.
#[allow(clippy::too_many_arguments)]
pub fn certified_indicators(
    chain: &Chain,
    theta0: &[f64],
    omega0: &[f64],
    t_end: f64,
    dt: f64,
    which: Indicator,
    driven: (&Builtin, Option<&Pivot>),
    deviations: Option<&[f64]>,
    threshold: Option<f64>,
    watch: &Watch,
) -> Result<CertifiedValues> {
    let (above, rule) = which.chaos_rule();
    let threshold = match threshold.or(rule) {
        Some(t) if t.is_finite() => t,
        Some(t) => return Err(Error::input(format!("threshold must be finite, got {}", Shown(t)))),
        None => {
            return Err(Error::input(format!(
                "a certified {} map needs a threshold: the value above which a cell counts as chaotic (megno, sali and gali have their own)",
                which.name()
            )))
        }
    };
    let values = indicators(chain, theta0, omega0, t_end, dt, which, driven, deviations, watch)?;
    let fine = indicators(chain, theta0, omega0, t_end, 0.5 * dt, which, driven, deviations, watch)?;
    let chaotic = |v: f64| if above { v > threshold } else { v < threshold };
    let uncertain = values.iter().zip(&fine).map(|(&a, &b)| chaotic(a) != chaotic(b)).collect();
    Ok(CertifiedValues { values, uncertain, threshold, above })
}

/// What [`certified_indicators`] finds: the values at `dt`, the uncertain rows, and the rule they
/// were judged by (chaotic `above` or below `threshold`).
#[derive(Debug, Clone, PartialEq)]
pub struct CertifiedValues {
    pub values: Vec<f64>,
    pub uncertain: Vec<bool>,
    pub threshold: f64,
    pub above: bool,
}

/// The run itself: `observe(step, value)` after every step when `history`.
#[allow(clippy::too_many_arguments)]
pub(super) fn run(
    chain: &Chain,
    theta0: &[f64],
    omega0: &[f64],
    steps: u64,
    dt: f64,
    which: Indicator,
    (torque, pivot): (&Builtin, Option<&Pivot>),
    deviations: Option<&[f64]>,
    watch: &Watch,
    history: bool,
    observe: &mut dyn FnMut(u64, f64),
) -> Result<f64> {
    let n = chain.n();
    let d = 2 * n;
    chain.check_state("theta0", theta0)?;
    chain.check_state("omega0", omega0)?;
    let k = which.vectors();
    let megno = which == Indicator::Megno;
    let mut sys = Tangent::new(chain, torque.clone(), Drive { pivot: pivot.cloned(), force: None }, k, megno);
    let dim = sys.dim();
    let mut y = vec![0.0; dim];
    y[..n].copy_from_slice(theta0);
    y[n..d].copy_from_slice(omega0);
    y[d..d * (1 + k)].copy_from_slice(&start_vectors(d, k, deviations)?);
    let mut rk = Rk4::new(dim);
    let mut y_new = vec![0.0; dim];
    let (mut log_growth, mut fli) = (0.0f64, 0.0f64);
    let mut flow = vec![0.0; if which == Indicator::Ofli { dim } else { 0 }];
    let mut scratch = vec![0.0; k * d];
    let mut value = f64::NAN;
    for step in 1..=steps {
        let t = (step - 1) as f64 * dt;
        if step % 64 == 0 {
            watch.check(t)?;
            if history {
                watch.set_fraction(step as f64 / steps as f64);
            }
        }
        rk.step(&mut sys, t, &y, dt, &mut y_new)?;
        std::mem::swap(&mut y, &mut y_new);
        let t1 = step as f64 * dt;
        if !y.iter().all(|v| v.is_finite()) {
            return Err(Error::integration(t1, NON_FINITE));
        }
        let vs = &mut y[d..d * (1 + k)];
        let mut norms = [0.0f64; 1];
        for (j, row) in vs.chunks_mut(d).enumerate() {
            let r = norm(row);
            if !(r > 0.0) {
                return Err(Error::integration(t1, "a deviation vector collapsed; use a smaller dt"));
            }
            if j == 0 {
                norms[0] = r;
            }
            row.iter_mut().for_each(|x| *x /= r);
        }
        value = match which {
            Indicator::Megno => y[d * (1 + k) + 1] / t1,
            Indicator::Fli => {
                log_growth += norms[0].ln();
                fli = fli.max(log_growth);
                fli
            }
            Indicator::Lyapunov => {
                log_growth += norms[0].ln();
                log_growth / t1
            }
            Indicator::Ofli => {
                log_growth += norms[0].ln();
                sys.rhs(t1, &y, &mut flow)?;
                let f = &flow[..d];
                let (fn_, v) = (norm(f), &y[d..2 * d]);
                let perp = if fn_ > 0.0 {
                    let c = v.iter().zip(f).map(|(a, b)| a * b).sum::<f64>() / (fn_ * fn_);
                    v.iter().zip(f).map(|(a, b)| (a - c * b) * (a - c * b)).sum::<f64>().sqrt()
                } else {
                    1.0
                };
                fli = fli.max(log_growth + perp.ln());
                fli
            }
            Indicator::Sali => {
                let (u, v) = (&y[d..2 * d], &y[2 * d..3 * d]);
                let plus = u.iter().zip(v).map(|(a, b)| (a + b) * (a + b)).sum::<f64>().sqrt();
                let minus = u.iter().zip(v).map(|(a, b)| (a - b) * (a - b)).sum::<f64>().sqrt();
                plus.min(minus)
            }
            Indicator::Gali(_) => {
                scratch.copy_from_slice(&y[d..d * (1 + k)]);
                // A volume that has collapsed to round-off is 0, not an error.
                orthonormalise(&mut scratch, d, k).unwrap_or(0.0)
            }
        };
        if history {
            observe(step, value);
        }
    }
    Ok(value)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_initial_deviations_are_orthonormal_and_fixed() {
        let v = initial_deviations(6, 4);
        for i in 0..4 {
            for j in 0..4 {
                let dot: f64 = (0..6).map(|c| v[6 * i + c] * v[6 * j + c]).sum();
                assert!((dot - f64::from(u8::from(i == j))).abs() < 1e-14);
            }
        }
        assert_eq!(v, initial_deviations(6, 4));
    }

    #[test]
    fn bad_requests_are_refused_by_name() {
        let chain = Chain::new(&[1.0, 1.0], &[1.0, 1.0], None, None, 9.81).unwrap();
        let w = Watch::new();
        let e = |which, dev: Option<&[f64]>| {
            indicator(&chain, &[1.0, 0.0], &[0.0; 2], 1.0, 0.01, which, (&Builtin::None, None), dev, 1, &w).unwrap_err().to_string()
        };
        assert_eq!(e(Indicator::Gali(5), None), "GALI's order k must be between 2 and 2N = 4, got 5");
        assert_eq!(e(Indicator::Gali(1), None), "GALI's order k must be between 2 and 2N = 4, got 1");
        assert_eq!(e(Indicator::Sali, Some(&[1.0; 4])), "deviations must have shape (2, 2N = 4), got 4 values");
        assert_eq!(e(Indicator::Sali, Some(&[1.0, 0.0, 0.0, 0.0, 2.0, 0.0, 0.0, 0.0])), "the deviation vectors must be linearly independent");
        assert_eq!(Indicator::parse("lyap", None).unwrap_err().to_string(), "indicator must be one of megno, fli, ofli, sali, gali, lyapunov, got \"lyap\"");
    }
}
