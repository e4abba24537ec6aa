//! [`Rk4`](super::Rk4) in SIMD lanes: eight states of one ideal chain stepped at once on
//! [`crate::dynamics::lanes`]' accelerations, the step's product-sums fused by explicit `mul_add`
//! as the flip kernel's (one correctly rounded operation on every path, so the AVX-512, AVX2 and
//! portable builds give the same bits, and a lane's bits never depend on the other lanes). Used
//! by the steppers' bank (`run::bank`) and by the flip times of chains other than the double
//! pendulum (`chaos::flipkernel`); both compile it inside their `#[target_feature]` wrappers.
use crate::dynamics::lanes::{accelerations, LaneScratch, LaneSingular};
use crate::model::Chain;
use crate::trig::lanes::{Lane, LANES};

/// rk4's stage buffers for eight states of an N-link chain, each a lane.
#[derive(Debug, Clone)]
pub struct Rk4Lanes {
    k: [Vec<Lane>; 4],
    tmp: Vec<Lane>,
    scratch: LaneScratch,
}

impl Rk4Lanes {
    pub fn new(n: usize) -> Self {
        let lanes = |k| vec![[0.0; LANES]; k];
        Rk4Lanes { k: std::array::from_fn(|_| lanes(2 * n)), tmp: lanes(2 * n), scratch: LaneScratch::new(n) }
    }

    /// One rk4 step of every active lane (`active[i] > 0`) of `y = [theta (N), omega (N)]` under
    /// generalized torques `tau` (held over the step), as `Rk4::step` (stages, then the weighted
    /// sum); the inactive lanes stay as they were. `Err((stage, _))` if an active lane's pivot
    /// failed (then no lane moves); else the active lanes whose new state is not finite (they do
    /// not move either).
    #[inline(always)]
    pub fn step(
        &mut self,
        chain: &Chain,
        y: &mut [Lane],
        tau: &[Lane],
        dt: f64,
        active: &Lane,
    ) -> std::result::Result<[bool; LANES], (usize, LaneSingular)> {
        let n = chain.n();
        let half = 0.5 * dt;
        let Rk4Lanes { k, tmp, scratch } = self;
        // Loops over whole lanes by iterators (no bounds checks), so they vectorise.
        for stage in 0..4 {
            {
                let src: &[Lane] = if stage == 0 { &y[..] } else { &tmp[..] };
                let (head, tail) = k[stage].split_at_mut(n);
                head.copy_from_slice(&src[n..2 * n]);
                accelerations(chain, &src[..n], &src[n..2 * n], tau, tail, scratch, active).map_err(|s| (stage, s))?;
            }
            if stage < 3 {
                let h = if stage < 2 { half } else { dt };
                for ((t, yv), kv) in tmp.iter_mut().zip(y.iter()).zip(k[stage].iter()) {
                    for i in 0..LANES {
                        t[i] = h.mul_add(kv[i], yv[i]);
                    }
                }
            }
        }
        let sixth = dt / 6.0;
        // `x * 0` is 0 for a finite x and NaN otherwise: the lanes' finiteness without branches.
        let mut poison = [0.0; LANES];
        let [k1, k2, k3, k4] = &*k;
        for (((((t, yv), a), b), c), d) in tmp.iter_mut().zip(y.iter()).zip(k1.iter()).zip(k2.iter()).zip(k3.iter()).zip(k4.iter()) {
            for i in 0..LANES {
                t[i] = sixth.mul_add(2.0f64.mul_add(b[i] + c[i], a[i]) + d[i], yv[i]);
                poison[i] += t[i] * 0.0;
            }
        }
        let (mut keep, mut nonfinite) = ([false; LANES], [false; LANES]);
        for i in 0..LANES {
            let finite = poison[i] == 0.0;
            keep[i] = active[i] > 0.0 && finite;
            nonfinite[i] = active[i] > 0.0 && !finite;
        }
        for (yv, t) in y.iter_mut().zip(tmp.iter()) {
            for i in 0..LANES {
                yv[i] = if keep[i] { t[i] } else { yv[i] };
            }
        }
        Ok(nonfinite)
    }
}
