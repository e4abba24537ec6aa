//! Vectorised `sin`/`cos`: lanes of eight angles through a branch-free Cody–Waite reduction and
//! the fdlibm kernels (within 1 ulp of glibc's), compiled for AVX-512, AVX2 and portable code and
//! chosen at run time ([`Path`]). Every fused product-sum is an explicit `mul_add` (one correctly
//! rounded operation: a hardware FMA on the AVX paths, glibc's exact `fma()` on the portable one),
//! so every path gives the same bits. Where every angle of a call is under pi/4 the reduction is
//! skipped (there it returns the angle itself: the same bits, a third less latency). Used by the
//! flip-map kernel (a lane per trajectory) and by the O(N) recursion for chains of eight or more
//! links ([`sin_cos_slice`]), where it took a third off the cost per link, and by the double
//! pendulum's closed forms ([`sin_cos_pair`]).
#![allow(clippy::excessive_precision)] // fdlibm's constants, digit for digit

/// Values computed together: one AVX-512 register of f64, two AVX2 registers.
pub const LANES: usize = 8;
pub type Lane = [f64; LANES];

/// `[f(0), .., f(7)]`, always compiled into its caller. `std::array::from_fn` need not be: the
/// rk4 lanes' stage times through it were a function of their own on the baseline target (SSE2,
/// outside the caller's `#[target_feature]`), a third of the generic flip lanes' time.
#[inline(always)]
pub fn each(mut f: impl FnMut(usize) -> f64) -> Lane {
    let mut out = [0.0; LANES];
    for (i, o) in out.iter_mut().enumerate() {
        *o = f(i);
    }
    out
}

/// `dst = src`, lanes of equal count. A copy of a length known only at run time is a call to
/// `memcpy` wherever it is (a few percent of the lanes' step when each stage copies its rates'
/// first half); for the small systems the steppers copy every stage or step (up to eight lanes:
/// the double and triple pendulums' states, a cart's), fixed-size copies, which LLVM makes
/// vector moves.
#[inline(always)]
pub fn copy_lanes(dst: &mut [Lane], src: &[Lane]) {
    #[inline(always)]
    fn fixed<const K: usize>(dst: &mut [Lane], src: &[Lane]) {
        let (d, s): (&mut [Lane; K], &[Lane; K]) = (dst.try_into().expect("equal lengths"), src.try_into().expect("equal lengths"));
        *d = *s;
    }
    match src.len() {
        1 => fixed::<1>(dst, src),
        2 => fixed::<2>(dst, src),
        3 => fixed::<3>(dst, src),
        4 => fixed::<4>(dst, src),
        5 => fixed::<5>(dst, src),
        6 => fixed::<6>(dst, src),
        7 => fixed::<7>(dst, src),
        8 => fixed::<8>(dst, src),
        _ => dst.copy_from_slice(src),
    }
}

/// Each lane's largest `|y[k]|` over the entries `which` of `y`, whole lanes at a time (so
/// vectorised: a test per lane and entry was a seventh of the generic double pendulum's flip
/// lanes' time). A NaN entry is passed over: callers reject non-finite states first.
#[inline(always)]
pub fn max_abs(y: &[Lane], which: impl IntoIterator<Item = usize>) -> Lane {
    let mut top = [0.0f64; LANES];
    for k in which {
        let yk = &y[k];
        for i in 0..LANES {
            top[i] = top[i].max(yk[i].abs());
        }
    }
    top
}

/// A compiled copy of the kernel.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Path {
    /// Whatever the target's baseline allows (SSE2 on x86_64, simd128 or scalar on wasm32).
    Portable,
    /// x86_64 with AVX2 and FMA.
    Avx2,
    /// x86_64 with AVX-512F and FMA.
    Avx512,
}

impl Path {
    pub const ALL: [Path; 3] = [Path::Portable, Path::Avx2, Path::Avx512];

    pub fn name(self) -> &'static str {
        match self {
            Path::Portable => "portable",
            Path::Avx2 => "avx2",
            Path::Avx512 => "avx512",
        }
    }

    /// Whether this CPU can run the path.
    pub fn available(self) -> bool {
        match self {
            Path::Portable => true,
            #[cfg(target_arch = "x86_64")]
            Path::Avx2 => std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma"),
            #[cfg(target_arch = "x86_64")]
            Path::Avx512 => std::arch::is_x86_feature_detected!("avx512f") && std::arch::is_x86_feature_detected!("fma"),
            #[cfg(not(target_arch = "x86_64"))]
            _ => false,
        }
    }

    /// The widest path this CPU runs.
    pub fn best() -> Path {
        Path::ALL.into_iter().rev().find(|p| p.available()).unwrap_or(Path::Portable)
    }

    /// The route the environment variable `var` asks for (for tests and benchmarks): `auto` or
    /// unset, the best path; `scalar`, `None` (the per-trajectory route); a path by name; or one
    /// of the caller's `more` values, which mean the best path too.
    pub fn requested(var: &str, more: &[&str]) -> crate::error::Result<Option<Path>> {
        use crate::error::Error;
        let value = std::env::var(var).unwrap_or_default();
        match value.as_str() {
            "" | "auto" => Ok(Some(Path::best())),
            "scalar" => Ok(None),
            v if more.contains(&v) => Ok(Some(Path::best())),
            name => match Path::ALL.into_iter().find(|p| p.name() == name) {
                Some(p) if p.available() => Ok(Some(p)),
                Some(p) => Err(Error::input(format!("{var} = {} is not supported by this CPU", p.name()))),
                None => {
                    let names: Vec<&str> = ["auto", "scalar"].into_iter().chain(Path::ALL.map(Path::name)).chain(more.iter().copied()).collect();
                    Err(Error::input(format!("{var} must be one of {}, got {name:?}", names.join(", "))))
                }
            },
        }
    }
}

/// `fn NAME(path: Path, ARGS) -> RET { BODY }`: BODY compiled three times, for AVX-512 + FMA,
/// for AVX2 + FMA (each a `#[target_feature]` function, so that the `#[inline(always)]` kernels
/// BODY calls are compiled for the path's registers and their `mul_add`s are hardware FMAs) and
/// for the baseline target, and run on `path`. Panics where the CPU lacks the path's features
/// (callers choose a path through [`Path::best`] or [`Path::requested`], which never give such a
/// path). BODY sees only its arguments and the module's items: it is the body of a nested
/// function, so no generics or `self` of an enclosing item.
macro_rules! on_path {
    ($(#[$meta:meta])* $vis:vis fn $name:ident($($arg:ident: $ty:ty),* $(,)?) $(-> $ret:ty)? $body:block) => {
        $(#[$meta])*
        #[allow(clippy::too_many_arguments)]
        $vis fn $name(path: $crate::trig::lanes::Path, $($arg: $ty),*) $(-> $ret)? {
            #[cfg(target_arch = "x86_64")]
            #[target_feature(enable = "avx512f,fma")]
            #[allow(clippy::too_many_arguments)]
            unsafe fn avx512($($arg: $ty),*) $(-> $ret)? $body
            #[cfg(target_arch = "x86_64")]
            #[target_feature(enable = "avx2,fma")]
            #[allow(clippy::too_many_arguments)]
            unsafe fn avx2($($arg: $ty),*) $(-> $ret)? $body
            assert!(path.available(), "the {} kernel needs a CPU feature this one lacks", path.name());
            match path {
                // SAFETY: the CPU has the path's features (checked just above).
                #[cfg(target_arch = "x86_64")]
                $crate::trig::lanes::Path::Avx512 => unsafe { avx512($($arg),*) },
                #[cfg(target_arch = "x86_64")]
                $crate::trig::lanes::Path::Avx2 => unsafe { avx2($($arg),*) },
                _ => $body,
            }
        }
    };
}
pub(crate) use on_path;

// The constants are fdlibm's, digit for digit.
// Cody–Waite reduction by pi/2 in three parts (fdlibm's __ieee754_rem_pio2, medium case with its
// second iteration): pi/2 = P1 + P2 + P2T, with P1 and P2 of 33 bits so that `n * P1` and
// `n * P2` are exact while |n| < 2^20.
const TWO_OVER_PI: f64 = std::f64::consts::FRAC_2_PI;
const P1: f64 = 1.57079632673412561417e+00;
const P2: f64 = 6.07710050630396597660e-11;
const P2T: f64 = 2.02226624879595063154e-21;
/// Adding 1.5 * 2^52 rounds to the nearest integer (ties to even) and leaves it in the low bits.
const ROUND: f64 = 6755399441055744.0;
/// Beyond this |x| the lane falls back to `crate::trig::sin_cos` (|n| stays far below 2^20).
const REDUCE_LIMIT: f64 = 1.0e5;

// fdlibm's k_sin.c / k_cos.c minimax polynomials on [-pi/4, pi/4].
const S1: f64 = -1.66666666666666324348e-01;
const S2: f64 = 8.33333333332248946124e-03;
const S3: f64 = -1.98412698298579493134e-04;
const S4: f64 = 2.75573137070700676789e-06;
const S5: f64 = -2.50507602534068634195e-08;
const S6: f64 = 1.58969099521155010221e-10;
const C1: f64 = 4.16666666666666019037e-02;
const C2: f64 = -1.38888888888741095749e-03;
const C3: f64 = 2.48015872894767294178e-05;
const C4: f64 = -2.75573143513906633035e-07;
const C5: f64 = 2.08757232129817482790e-09;
const C6: f64 = -1.13596475577881948265e-11;

/// `(sin x, cos x)` for |x| <= REDUCE_LIMIT, branch-free so that a loop over lanes vectorises.
#[inline(always)]
pub(crate) fn sin_cos_reduced(x: f64) -> (f64, f64) {
    let kd = x.mul_add(TWO_OVER_PI, ROUND);
    let q = kd.to_bits();
    let n = kd - ROUND;
    let r = (-n).mul_add(P1, x);
    let w = n * P2;
    let t = r;
    let r = t - w;
    let w = n * P2T - ((t - r) - w);
    let y0 = r - w;
    let y1 = (r - y0) - w;
    let (ks, kc) = kernels(y0, y1);
    // Quadrant n mod 4: sin = (ks, kc, -ks, -kc), cos = (kc, -ks, -kc, ks).
    let odd = q & 1 != 0;
    let (a, b) = if odd { (kc, ks) } else { (ks, kc) };
    let sin = f64::from_bits(a.to_bits() ^ ((q & 2) << 62));
    let cos = f64::from_bits(b.to_bits() ^ (((q + 1) & 2) << 62));
    (sin, cos)
}

/// Below this |x|, `x * 2/pi` rounds to n = 0 (pi/4 = 0.785..), and the reduction above leaves
/// `y0 = x`, `y1 = +0` exactly and the quadrant's signs alone: [`sin_cos_small`] skips it.
pub(crate) const SMALL: f64 = 0.78;

/// [`sin_cos_reduced`] for |x| < [`SMALL`], without the reduction: the same kernels on the same
/// `(y0, y1) = (x, +0)`, so the same bits (tests compare the two), about a third less latency.
#[inline(always)]
pub(crate) fn sin_cos_small(x: f64) -> (f64, f64) {
    kernels(x, 0.0)
}

/// FreeBSD's `__kernel_sin` and `__kernel_cos` on `y0 + y1` in [-pi/4, pi/4].
#[inline(always)]
fn kernels(y0: f64, y1: f64) -> (f64, f64) {
    let z = y0 * y0;
    let zz = z * z;
    let rs = (z * zz).mul_add(z.mul_add(S6, S5), z.mul_add(z.mul_add(S4, S3), S2));
    let v = z * y0;
    let ks = y0 - (-v).mul_add(S1, z.mul_add((-v).mul_add(rs, 0.5 * y1), -y1));
    let rc = (zz * zz).mul_add(z.mul_add(z.mul_add(C6, C5), C4), z * z.mul_add(z.mul_add(C3, C2), C1));
    let hz = 0.5 * z;
    let wc = 1.0 - hz;
    let kc = wc + (((1.0 - wc) - hz) + z.mul_add(rc, -(y0 * y1)));
    (ks, kc)
}

/// `sin` and `cos` of every lane (of a [`Lane`], or of any width `W` a kernel steps at once);
/// lanes outside the reduction's range (or not finite) take the scalar route, and when every lane
/// is small the reduction is skipped ([`sin_cos_small`]). Each lane's value is its own, whatever
/// the width and whatever its neighbours.
#[inline(always)]
pub fn sin_cos<const W: usize>(x: &[f64; W]) -> ([f64; W], [f64; W]) {
    let (mut s, mut c) = ([0.0; W], [0.0; W]);
    let mut small = true;
    for v in x {
        small &= v.abs() < SMALL;
    }
    if small {
        for i in 0..W {
            (s[i], c[i]) = sin_cos_small(x[i]);
        }
        return (s, c);
    }
    for i in 0..W {
        (s[i], c[i]) = sin_cos_reduced(x[i]);
    }
    let mut outside = false;
    for v in x {
        outside |= !(v.abs() <= REDUCE_LIMIT);
    }
    if outside {
        for i in 0..W {
            if !(x[i].abs() <= REDUCE_LIMIT) {
                (s[i], c[i]) = super::sin_cos(x[i]);
            }
        }
    }
    (s, c)
}

/// `sin` and `cos` of every entry of `x` into `s` and `c`, eight at a time on the AVX-512 or
/// AVX2 path, for the O(N) recursion's angles (`Chain::trig`). Returns false, touching nothing,
/// where neither path runs (the caller then takes glibc's scalar `sincos`): the portable path's
/// `mul_add` would be a software FMA there.
pub(crate) fn sin_cos_slice(x: &[f64], s: &mut [f64], c: &mut [f64]) -> bool {
    match Path::best() {
        Path::Portable => false,
        path => {
            sin_cos_slice_on(path, x, s, c);
            true
        }
    }
}

on_path! {
    fn sin_cos_slice_on(x: &[f64], s: &mut [f64], c: &mut [f64]) {
        sin_cos_chunks(x, s, c)
    }
}

/// Whether the CPU has AVX2 and FMA, the features [`sin_cos_pair_within`] is compiled for.
#[inline(always)]
pub fn fma() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// `sin` and `cos` of two angles in one call: the lanes' kernel (its bits, within 1 ulp of
/// glibc's) where the CPU has AVX2 + FMA, glibc's `sincos` twice elsewhere or for |x| beyond the
/// reduction's range. For the double pendulum's closed forms, where glibc's two calls were
/// about 45% of an rk4 step: the two reductions and kernels run side by side, branch-free.
/// The closed forms inline [`sin_cos_pair_within`] into their own AVX2 + FMA copies instead,
/// so that no call spills their registers; this is the same pair as a function.
pub fn sin_cos_pair(a: f64, b: f64) -> [(f64, f64); 2] {
    #[cfg(target_arch = "x86_64")]
    if fma() {
        // SAFETY: the CPU has AVX2 and FMA.
        return unsafe { sin_cos_pair_fma(a, b) };
    }
    [super::sin_cos(a), super::sin_cos(b)]
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn sin_cos_pair_fma(a: f64, b: f64) -> [(f64, f64); 2] {
    sin_cos_pair_within(a, b)
}

/// The body of [`sin_cos_pair`] where [`fma`] holds, for inlining into a caller compiled with
/// `#[target_feature(enable = "avx2,fma")]` (elsewhere its `mul_add` is a call to libm's `fma`:
/// the same bits, slowly).
#[inline(always)]
pub fn sin_cos_pair_within(a: f64, b: f64) -> [(f64, f64); 2] {
    if a.abs() < SMALL && b.abs() < SMALL {
        [sin_cos_small(a), sin_cos_small(b)]
    } else if a.abs() <= REDUCE_LIMIT && b.abs() <= REDUCE_LIMIT {
        [sin_cos_reduced(a), sin_cos_reduced(b)]
    } else {
        [super::sin_cos(a), super::sin_cos(b)]
    }
}

#[inline(always)]
fn sin_cos_chunks(x: &[f64], s: &mut [f64], c: &mut [f64]) {
    let n = x.len();
    let mut i = 0;
    while i < n {
        let m = (n - i).min(LANES);
        let mut lane = [0.0; LANES];
        lane[..m].copy_from_slice(&x[i..i + m]);
        let (ls, lc) = sin_cos(&lane);
        s[i..i + m].copy_from_slice(&ls[..m]);
        c[i..i + m].copy_from_slice(&lc[..m]);
        i += m;
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use std::f64::consts::PI;

    /// Whether the kernel's own CPU description lists every flag (independent of Rust's detection).
    pub(crate) fn cpu_flags_have(flags: &[&str]) -> bool {
        let info = std::fs::read_to_string("/proc/cpuinfo").unwrap_or_default();
        let line = info.lines().find(|l| l.starts_with("flags")).unwrap_or("");
        let have: Vec<&str> = line.split_whitespace().collect();
        flags.iter().all(|f| have.contains(f))
    }

    #[test]
    #[cfg(all(target_os = "linux", target_arch = "x86_64"))]
    fn the_paths_this_cpu_lists_are_detected() {
        assert_eq!(Path::Avx2.available(), cpu_flags_have(&["avx2", "fma"]));
        assert_eq!(Path::Avx512.available(), cpu_flags_have(&["avx512f", "fma"]));
    }

    fn ulps(a: f64, b: f64) -> u64 {
        let key = |x: f64| {
            let i = x.to_bits() as i64;
            if i < 0 {
                i64::MIN - i
            } else {
                i
            }
        };
        key(a).abs_diff(key(b))
    }

    #[test]
    fn the_slice_route_for_long_chains_equals_the_lanes_at_any_length() {
        // Lengths that leave every remainder 0..7 of the eight-wide chunks, with far-out lanes.
        for n in [1usize, 7, 8, 9, 15, 16, 23, 100] {
            let x: Vec<f64> = (0..n).map(|i| (i as f64 * 0.731 - 3.0) * if i % 11 == 5 { 1e6 } else { 1.0 }).collect();
            let (mut s, mut c) = (vec![0.0; n], vec![0.0; n]);
            if !sin_cos_slice(&x, &mut s, &mut c) {
                // No AVX2 + FMA here (Chain::trig takes glibc's route): only where /proc/cpuinfo agrees.
                assert!(!cpu_flags_have(&["avx2", "fma"]), "the CPU has AVX2 and FMA but the slice route did not run");
                return;
            }
            for i in 0..n {
                let mut lane = [0.0; LANES];
                lane[0] = x[i];
                let (ls, lc) = sin_cos(&lane);
                assert_eq!((s[i].to_bits(), c[i].to_bits()), (ls[0].to_bits(), lc[0].to_bits()), "n = {n}, x = {}", x[i]);
                let (gs, gc) = super::super::sin_cos(x[i]);
                assert!(ulps(s[i], gs) <= 1 && ulps(c[i], gc) <= 1, "x = {}", x[i]);
            }
        }
    }

    #[test]
    fn the_small_angles_skip_the_reduction_and_keep_every_bit() {
        // Dense over (-SMALL, SMALL), its ends, signed zeros, subnormals and tiny values.
        let below = f64::from_bits(SMALL.to_bits() - 1);
        let mut xs: Vec<f64> = (0..400_001).map(|i| (i as f64 - 200_000.0) / 200_000.0 * below).collect();
        xs.extend([0.0, -0.0, 5e-324, -5e-324, 1e-300, 1e-160, -1e-8, below, -below, 0.5, 0.3]);
        for x in xs {
            let (s, c) = sin_cos_small(x);
            let (rs, rc) = sin_cos_reduced(x);
            assert_eq!((s.to_bits(), c.to_bits()), (rs.to_bits(), rc.to_bits()), "x = {x:e}");
            // In lanes: all small (no reduction) or beside a large neighbour (reduced), alike.
            let (alone, _) = sin_cos(&[x; LANES]);
            let (beside, _) = sin_cos(&each(|i| if i == 0 { x } else { 2.0 }));
            assert_eq!(alone[0].to_bits(), beside[0].to_bits(), "x = {x:e}");
        }
        // The bound itself lies below pi/4 and rounds to n = 0, so every angle under it does.
        assert!(SMALL < std::f64::consts::FRAC_PI_4 && SMALL.mul_add(TWO_OVER_PI, ROUND) == ROUND);
    }

    #[test]
    fn the_pair_is_the_lanes_kernel_where_the_cpu_has_fma_and_glibc_elsewhere() {
        let fma = cpu_flags_have(&["avx2", "fma"]);
        let xs = [0.0, -0.0, 1e-300, 0.3, -1.2, PI, -PI, 3.0 * PI + 0.1, 2.5e4, -9.9e4, 1.5e5, -1e300, f64::NAN, f64::INFINITY];
        for &a in &xs {
            for &b in &xs {
                let got = sin_cos_pair(a, b);
                for (x, (s, c)) in [(a, got[0]), (b, got[1])] {
                    let (gs, gc) = super::super::sin_cos(x);
                    // Far out (or not finite) in either angle: glibc for both, bit for bit.
                    let want = if fma && a.abs() <= REDUCE_LIMIT && b.abs() <= REDUCE_LIMIT {
                        let mut lane = [0.0; LANES];
                        lane[0] = x;
                        let (ls, lc) = sin_cos(&lane);
                        (ls[0], lc[0])
                    } else {
                        (gs, gc)
                    };
                    assert_eq!((s.to_bits(), c.to_bits()), (want.0.to_bits(), want.1.to_bits()), "x = {x} (pair {a}, {b})");
                    if x.is_finite() {
                        assert!(ulps(s, gs) <= 1 && ulps(c, gc) <= 1, "x = {x}");
                    }
                }
            }
        }
    }

    #[test]
    fn sin_cos_is_within_one_ulp_of_glibc_and_falls_back_far_out() {
        let mut worst = 0;
        let mut xs: Vec<f64> = (0..200_001).map(|i| (i as f64 - 100_000.0) * 1.37e-4).collect();
        xs.extend((0..20_000).map(|i| (i as f64 - 10_000.0) * 9.3)); // |x| up to 9.3e4
        xs.extend([0.0, -0.0, 1e-300, 5e-324, PI, -PI, 0.5 * PI, 1e5, 1.5e5, 1e300, -3e22]);
        for chunk in xs.chunks(LANES) {
            let mut x = [0.0; LANES];
            x[..chunk.len()].copy_from_slice(chunk);
            let (s, c) = sin_cos(&x);
            for i in 0..chunk.len() {
                let (es, ec) = super::super::sin_cos(x[i]);
                worst = worst.max(ulps(s[i], es)).max(ulps(c[i], ec));
            }
        }
        assert!(worst <= 1, "worst error {worst} ulp");
        let (s, c) = sin_cos(&[f64::NAN, f64::INFINITY, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
        assert!(s[0].is_nan() && c[0].is_nan() && s[1].is_nan() && c[1].is_nan());
    }
}
