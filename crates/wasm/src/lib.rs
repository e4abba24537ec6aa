//! WebAssembly exports of `multipendulum-core` for the browser viewer: conversion and error
//! reporting only, no physics. Plain `extern "C"` functions over linear memory, so the page needs
//! no generated glue (its wrapper is `python/multipendulum/web/engine.js`):
//!
//! - buffers: `mp_alloc(bytes)` returns 8-byte aligned memory, `mp_free(ptr, bytes)` releases
//!   it; arrays are `f64`, strings UTF-8.
//! - a simulation: `mp_sim_new(..)` returns a handle (null on bad input), the other `mp_sim_*`
//!   functions take it, `mp_sim_free` releases it. It wraps a core [`Stepper`].
//! - errors: a call that fails returns null or a negative status, and `mp_error_ptr` /
//!   `mp_error_len` give the core's message (`lengths[1] must be > 0 and finite, got -1`).
//!
//! Pointers and lengths come from the wrapper, which allocates every buffer it passes.
use std::alloc::{alloc_zeroed, dealloc, Layout};
use std::cell::RefCell;

use multipendulum_core::{Builtin, Chain, Error, Method, Settings, Stepper};

thread_local! {
    static LAST_ERROR: RefCell<String> = const { RefCell::new(String::new()) };
}

/// Status codes of the calls that can fail.
pub const DONE: i32 = 0;
pub const BUDGET: i32 = 1;
pub const INPUT_ERROR: i32 = -1;
pub const INTEGRATION_ERROR: i32 = -2;

fn fail(e: &Error) -> i32 {
    LAST_ERROR.with(|m| *m.borrow_mut() = e.to_string());
    match e {
        Error::Input(_) => INPUT_ERROR,
        _ => INTEGRATION_ERROR,
    }
}

fn layout(bytes: usize) -> Option<Layout> {
    Layout::from_size_align(bytes.max(8), 8).ok()
}

/// `bytes` of zeroed memory aligned for `f64`; null if the request is impossible.
#[no_mangle]
pub extern "C" fn mp_alloc(bytes: usize) -> *mut u8 {
    match layout(bytes) {
        // SAFETY: the layout has a non-zero size.
        Some(l) => unsafe { alloc_zeroed(l) },
        None => std::ptr::null_mut(),
    }
}

/// Release memory from `mp_alloc(bytes)`.
///
/// # Safety
/// `ptr` came from `mp_alloc` with the same `bytes` and is not used again.
#[no_mangle]
pub unsafe extern "C" fn mp_free(ptr: *mut u8, bytes: usize) {
    if let (false, Some(l)) = (ptr.is_null(), layout(bytes)) {
        dealloc(ptr, l);
    }
}

/// The message of the last failed call (UTF-8, `mp_error_len` bytes).
#[no_mangle]
pub extern "C" fn mp_error_ptr() -> *const u8 {
    LAST_ERROR.with(|m| m.borrow().as_ptr())
}

#[no_mangle]
pub extern "C" fn mp_error_len() -> usize {
    LAST_ERROR.with(|m| m.borrow().len())
}

thread_local! {
    static FACTS: String = facts_json();
}

/// The core's facts as JSON (methods with their order, kind and forms; defaults; limits), so
/// the page restates none of them.
fn facts_json() -> String {
    use multipendulum_core::facts;
    let list = |v: Vec<&str>| v.iter().map(|s| format!("\"{s}\"")).collect::<Vec<_>>().join(",");
    let methods: Vec<String> = facts::methods()
        .iter()
        .map(|m| {
            format!(
                "\"{}\":{{\"order\":{},\"symplectic\":{},\"implicit\":{},\"adaptive\":{},\"needs_dt\":{},\"forms\":[{}]}}",
                m.name, m.order, m.symplectic, m.implicit, m.adaptive, m.needs_dt, list(m.forms.clone())
            )
        })
        .collect();
    let numbers = |v: Vec<facts::Fact>| v.iter().map(|(k, x, _)| format!("\"{k}\":{x:e}")).collect::<Vec<_>>().join(",");
    format!(
        "{{\"methods\":{{{}}},\"method_order\":[{}],\"defaults\":{{{},\"method\":\"{}\"}},\"limits\":{{{}}}}}",
        methods.join(","),
        list(facts::methods().iter().map(|m| m.name).collect()),
        numbers(facts::defaults()),
        facts::default_method(),
        numbers(facts::limits())
    )
}

/// The core's facts as JSON (UTF-8, `mp_facts_len` bytes).
#[no_mangle]
pub extern "C" fn mp_facts_ptr() -> *const u8 {
    FACTS.with(|f| f.as_ptr())
}

#[no_mangle]
pub extern "C" fn mp_facts_len() -> usize {
    FACTS.with(|f| f.len())
}

/// A simulation: the core's stepper for an undriven chain.
pub struct Sim {
    stepper: Stepper<Builtin>,
}

unsafe fn slice<'a>(ptr: *const f64, n: usize) -> &'a [f64] {
    if n == 0 || ptr.is_null() {
        &[]
    } else {
        std::slice::from_raw_parts(ptr, n)
    }
}

unsafe fn optional<'a>(ptr: *const f64, n: usize) -> Option<&'a [f64]> {
    (!ptr.is_null()).then(|| slice(ptr, n))
}

/// Build a chain and start a simulation at t = 0; null on bad input (see `mp_error_ptr`).
///
/// `rods != 0`: uniform rods (com and inertia must be null); otherwise `com` and `inertia` may
/// be null (point masses). `method` names an integrator (`rk4`, `dop853`, `gauss4`, `gauss6`);
/// `dt` is the fixed step, or for `dop853` the first step when > 0 (0: chosen automatically).
///
/// # Safety
/// Every non-null array pointer holds `n` f64; `method` holds `method_len` bytes.
#[no_mangle]
pub unsafe extern "C" fn mp_sim_new(
    n: usize,
    rods: i32,
    lengths: *const f64,
    masses: *const f64,
    com: *const f64,
    inertia: *const f64,
    g: f64,
    method: *const u8,
    method_len: usize,
    dt: f64,
    rtol: f64,
    atol: f64,
    theta0: *const f64,
    omega0: *const f64,
) -> *mut Sim {
    let build = || -> Result<Sim, Error> {
        let name = if method.is_null() { &[][..] } else { std::slice::from_raw_parts(method, method_len) };
        let name = std::str::from_utf8(name).map_err(|_| Error::input("method must be UTF-8 text"))?;
        let method = Method::parse(name)?;
        let (lengths, masses) = (slice(lengths, n), slice(masses, n));
        let (com, inertia) = (optional(com, n), optional(inertia, n));
        let chain = if rods != 0 {
            if com.is_some() || inertia.is_some() {
                return Err(Error::input("com and inertia cannot be given for uniform rods (com = l/2, inertia = m l^2/12)"));
            }
            Chain::rods(lengths, masses, g)?
        } else {
            Chain::new(lengths, masses, com, inertia, g)?
        };
        let dt = if method.adaptive() && dt == 0.0 { None } else { Some(dt) };
        let settings = Settings { method, dt, rtol, atol, ..Settings::default() };
        let stepper = Stepper::new(chain, slice(theta0, n), slice(omega0, n), &settings, Builtin::None)?;
        Ok(Sim { stepper })
    };
    match build() {
        Ok(sim) => Box::into_raw(Box::new(sim)),
        Err(e) => {
            fail(&e);
            std::ptr::null_mut()
        }
    }
}

/// # Safety
/// `sim` came from `mp_sim_new` and is not used again.
#[no_mangle]
pub unsafe extern "C" fn mp_sim_free(sim: *mut Sim) {
    if !sim.is_null() {
        drop(Box::from_raw(sim));
    }
}

/// Advance towards `t_target` with at most `max_steps` steps: `DONE` (0) when reached, `BUDGET`
/// (1) when the steps ran out first, a negative status on failure (the state stays at the last
/// good one).
///
/// # Safety
/// `sim` is a live handle from `mp_sim_new`.
#[no_mangle]
pub unsafe extern "C" fn mp_sim_advance(sim: *mut Sim, t_target: f64, max_steps: u32) -> i32 {
    match (*sim).stepper.advance(t_target, u64::from(max_steps)) {
        Ok(true) => DONE,
        Ok(false) => BUDGET,
        Err(e) => fail(&e),
    }
}

/// # Safety
/// `sim` is a live handle from `mp_sim_new`.
#[no_mangle]
pub unsafe extern "C" fn mp_sim_t(sim: *const Sim) -> f64 {
    (*sim).stepper.t()
}

/// # Safety
/// `sim` is a live handle from `mp_sim_new`.
#[no_mangle]
pub unsafe extern "C" fn mp_sim_n(sim: *const Sim) -> usize {
    (*sim).stepper.n()
}

/// Energy `T + U` of the current state (J).
///
/// # Safety
/// `sim` is a live handle from `mp_sim_new`.
#[no_mangle]
pub unsafe extern "C" fn mp_sim_energy(sim: *mut Sim) -> f64 {
    (*sim).stepper.energy()
}

/// # Safety
/// `sim` is a live handle from `mp_sim_new`.
#[no_mangle]
pub unsafe extern "C" fn mp_sim_initial_energy(sim: *const Sim) -> f64 {
    (*sim).stepper.initial_energy()
}

/// The energy error of the current state, as the core defines it for every report:
/// `|E - E0 - W| / (g sum |h_i| + max T)` (`multipendulum_core::run::energy`).
///
/// # Safety
/// `sim` is a live handle from `mp_sim_new`.
#[no_mangle]
pub unsafe extern "C" fn mp_sim_energy_error(sim: *mut Sim) -> f64 {
    (*sim).stepper.energy_error()
}

/// Accepted steps so far (as f64: JavaScript numbers).
///
/// # Safety
/// `sim` is a live handle from `mp_sim_new`.
#[no_mangle]
pub unsafe extern "C" fn mp_sim_steps(sim: *const Sim) -> f64 {
    (*sim).stepper.counts().0 as f64
}

/// Right-hand side evaluations so far.
///
/// # Safety
/// `sim` is a live handle from `mp_sim_new`.
#[no_mangle]
pub unsafe extern "C" fn mp_sim_evaluations(sim: *const Sim) -> f64 {
    (*sim).stepper.counts().2 as f64
}

/// Angles into `out` (N values).
///
/// # Safety
/// `sim` is a live handle; `out` holds N f64.
#[no_mangle]
pub unsafe extern "C" fn mp_sim_theta(sim: *const Sim, out: *mut f64) {
    let s = &(*sim).stepper;
    std::slice::from_raw_parts_mut(out, s.n()).copy_from_slice(s.theta());
}

/// Angular velocities into `out` (N values).
///
/// # Safety
/// `sim` is a live handle; `out` holds N f64.
#[no_mangle]
pub unsafe extern "C" fn mp_sim_omega(sim: *mut Sim, out: *mut f64) {
    let s = &mut (*sim).stepper;
    let n = s.n();
    std::slice::from_raw_parts_mut(out, n).copy_from_slice(s.omega());
}

/// Joint positions into `out` (2N values: x, y of each link's far end; the pivot is the origin).
///
/// # Safety
/// `sim` is a live handle; `out` holds 2N f64.
#[no_mangle]
pub unsafe extern "C" fn mp_sim_positions(sim: *const Sim, out: *mut f64) {
    let s = &(*sim).stepper;
    s.positions_into(std::slice::from_raw_parts_mut(out, 2 * s.n()));
}

#[cfg(test)]
mod facts_tests {
    #[test]
    fn the_facts_are_json_naming_every_method() {
        let json = super::facts_json();
        for m in multipendulum_core::Method::ALL {
            assert!(json.contains(&format!("\"{}\":{{\"order\":{}", m.name(), m.order())), "{json}");
        }
        assert!(json.contains("\"rtol\":1e-10"), "{json}");
        assert_eq!(json.matches('{').count(), json.matches('}').count());

    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn message() -> String {
        let bytes = unsafe { std::slice::from_raw_parts(mp_error_ptr(), mp_error_len()) };
        String::from_utf8(bytes.to_vec()).unwrap()
    }

    unsafe fn new(lengths: &[f64], method: &str, dt: f64, theta0: &[f64]) -> *mut Sim {
        let n = lengths.len();
        let masses = vec![1.0; n];
        let omega0 = vec![0.0; n];
        mp_sim_new(
            n, 0, lengths.as_ptr(), masses.as_ptr(), std::ptr::null(), std::ptr::null(), 9.81,
            method.as_ptr(), method.len(), dt, 1e-10, 1e-12, theta0.as_ptr(), omega0.as_ptr(),
        )
    }

    #[test]
    fn bad_input_returns_null_and_the_core_message() {
        unsafe {
            assert!(new(&[1.0, -1.0], "rk4", 0.01, &[0.0, 0.0]).is_null());
            assert_eq!(message(), "lengths[1] must be > 0 and finite, got -1");
            assert!(new(&[1.0], "euler", 0.01, &[0.0]).is_null());
            assert_eq!(message(), "method must be one of rk4, dop853, gauss4, gauss6, got \"euler\"");
            assert!(new(&[1.0], "rk4", 0.01, &[f64::NAN]).is_null());
            assert_eq!(message(), "theta0[0] must be finite, got NaN");
            assert!(new(&[], "rk4", 0.01, &[]).is_null());
            assert_eq!(message(), "lengths must have at least one entry, got 0");
        }
    }

    #[test]
    fn a_simulation_advances_and_reports() {
        unsafe {
            let sim = new(&[1.0, 1.0], "dop853", 0.0, &[1.0, 0.5]);
            assert!(!sim.is_null());
            assert_eq!(mp_sim_advance(sim, 0.5, 1), BUDGET);
            assert_eq!(mp_sim_advance(sim, 0.5, 100_000), DONE);
            assert_eq!(mp_sim_t(sim), 0.5);
            assert!(mp_sim_energy_error(sim) < 1e-9);
            let mut pos = [0.0; 4];
            mp_sim_positions(sim, pos.as_mut_ptr());
            let mut theta = [0.0; 2];
            mp_sim_theta(sim, theta.as_mut_ptr());
            assert!((pos[0] - theta[0].sin()).abs() < 1e-15);
            assert!(mp_sim_evaluations(sim) > 12.0 * mp_sim_steps(sim));
            assert_eq!(mp_sim_advance(sim, f64::NAN, 1), INPUT_ERROR);
            mp_sim_free(sim);
        }
    }

    #[test]
    fn buffers_are_aligned_for_f64() {
        unsafe {
            let p = mp_alloc(24);
            assert_eq!(p as usize % 8, 0);
            mp_free(p, 24);
            mp_free(std::ptr::null_mut(), 0);
        }
    }
}
