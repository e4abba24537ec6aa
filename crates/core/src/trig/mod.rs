//! `sin` and `cos` of one angle in one call. glibc's `sincos` shares the argument reduction
//! (what C compilers emit for `sin(x)` beside `cos(x)`; LLVM does so only sometimes), and its
//! results equal `sin` and `cos` bit for bit. Elsewhere (e.g. WebAssembly), Rust's own pair.
//! [`lanes`]: the vectorised pair, eight angles at a time.
pub mod lanes;

#[cfg(all(target_os = "linux", target_env = "gnu"))]
#[inline(always)]
pub fn sin_cos(x: f64) -> (f64, f64) {
    extern "C" {
        fn sincos(x: f64, s: *mut f64, c: *mut f64);
    }
    let (mut s, mut c) = (0.0, 0.0);
    // SAFETY: glibc's sincos writes one f64 through each of two valid, distinct pointers.
    unsafe { sincos(x, &mut s, &mut c) };
    (s, c)
}

#[cfg(not(all(target_os = "linux", target_env = "gnu")))]
#[inline(always)]
pub fn sin_cos(x: f64) -> (f64, f64) {
    x.sin_cos()
}

#[cfg(test)]
mod tests {
    #[test]
    fn equals_separate_calls_bit_for_bit() {
        for i in 0..100_000 {
            let x = (i as f64 - 50_000.0) * 0.00137;
            assert_eq!(super::sin_cos(x), (x.sin(), x.cos()), "x = {x}");
        }
    }
}
