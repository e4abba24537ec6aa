//! WebAssembly exports of `multipendulum-core` for the browser viewer: conversion and error
//! reporting only, no physics. Plain `extern "C"` functions over linear memory, so the page needs
//! no generated glue (its wrapper is `python/multipendulum/web/engine.js`):
//!
//! - buffers: `mp_alloc(bytes)` returns 8-byte aligned memory, `mp_free(ptr, bytes)` releases
//!   it; arrays are `f64`, strings UTF-8.
//! - what goes beyond the ideal chain on a fixed pivot: `mp_setup_new()` returns a [`Setup`]
//!   (joint losses, a cart, a pivot motion, a torque, a cart force), filled by the
//!   `mp_setup_*` functions and read by `mp_sim_new`; `mp_setup_free` releases it. It only holds
//!   the numbers: the core checks them when the simulation is built.
//! - a simulation: `mp_sim_new(..)` returns a handle (null on bad input), the other `mp_sim_*`
//!   functions take it, `mp_sim_free` releases it. It wraps a core [`Stepper`].
//! - the dragged base: a setup made with `mp_setup_draggable` lets `mp_sim_follow` pull the
//!   pivot (or the cart) towards the pointer while the run goes on, with bounded acceleration;
//!   `mp_sim_release` lets go; `mp_sim_base_motion` reports the base's motion.
//! - flip maps: `mp_first_flips` runs the core's lane kernel over many double pendulums.
//! - errors: a call that fails returns null or a negative status, and `mp_error_ptr` /
//!   `mp_error_len` give the core's message (`lengths[1] must be > 0 and finite, got -1`).
//!
//! Pointers and lengths come from the wrapper, which allocates every buffer it passes.
// The crate's documentation is for its developers (`cargo doc --document-private-items`, as
// `make lint` builds it): its links to private items are meant, and resolve there.
#![allow(rustdoc::private_intra_doc_links)]
use std::alloc::{alloc_zeroed, dealloc, Layout};
use std::cell::RefCell;
use std::sync::Arc;

use multipendulum_core::model::FRICTION_VELOCITY;
use multipendulum_core::{Axis, Builtin, Cart, Chain, Drive, Error, Force, Interp, Joint, Method, Pivot, Settings, Stepper, TorqueSource};

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
                m.name,
                m.order,
                m.symplectic,
                m.implicit,
                m.adaptive,
                m.needs_dt,
                list(m.forms.clone())
            )
        })
        .collect();
    let numbers = |v: Vec<facts::Fact>| v.iter().map(|(k, x, _)| format!("\"{k}\":{x:e}")).collect::<Vec<_>>().join(",");
    format!(
        "{{\"methods\":{{{}}},\"method_order\":[{}],\"defaults\":{{{},\"friction_velocity\":{:e},\"method\":\"{}\"}},\"limits\":{{{}}}}}",
        methods.join(","),
        list(facts::methods().iter().map(|m| m.name).collect()),
        numbers(facts::defaults()),
        FRICTION_VELOCITY,
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

// ---- Setup: losses, the base, the drive -----------------------------------------------------

/// The forms of a signal (a torque, a pivot axis, the cart force) passed to the `mp_setup_*`
/// functions, with the layout of its `data`:
/// - `SIGNAL_CONSTANT`: the values (one per link; one for an axis or the force);
/// - `SIGNAL_SINUSOID`: amplitudes, frequencies (rad/s), phases (rad), offsets, one block each
///   of `len / 4` values (`offset + amplitude sin(frequency t + phase)`);
/// - `SIGNAL_LINEAR`, `SIGNAL_CUBIC`: a table, `rows` sample times then their values row by
///   row (`rows` x N; one column for an axis or the force), interpolated linearly or by the
///   natural cubic spline. A pivot axis takes only the cubic table (it needs two derivatives).
pub const SIGNAL_CONSTANT: i32 = 0;
pub const SIGNAL_SINUSOID: i32 = 1;
pub const SIGNAL_LINEAR: i32 = 2;
pub const SIGNAL_CUBIC: i32 = 3;

#[derive(Debug, Clone)]
struct Signal {
    kind: i32,
    rows: usize,
    data: Vec<f64>,
}

impl Signal {
    unsafe fn read(kind: i32, rows: usize, data: *const f64, len: usize, what: &str) -> Result<Self, Error> {
        if !(SIGNAL_CONSTANT..=SIGNAL_CUBIC).contains(&kind) {
            return Err(Error::input(format!("{what}: unknown signal kind {kind}")));
        }
        let data = slice(data, len).to_vec();
        if kind == SIGNAL_SINUSOID && data.len() % 4 != 0 {
            return Err(Error::input(format!("{what}: a sinusoid takes amplitude, frequency, phase and offset, got {} numbers", data.len())));
        }
        if kind >= SIGNAL_LINEAR && rows > data.len() {
            return Err(Error::input(format!("{what}: a table of {rows} times needs at least {rows} numbers, got {}", data.len())));
        }
        Ok(Signal { kind, rows, data })
    }

    /// The core's built-in signal of `n` columns (a torque, or the cart force with `n = 1`).
    fn builtin(&self, n: usize) -> Result<Builtin, Error> {
        let d = &self.data;
        match self.kind {
            SIGNAL_CONSTANT => Builtin::constant(n, d.clone()),
            SIGNAL_SINUSOID => {
                let m = d.len() / 4;
                let part = |k: usize| d[k * m..(k + 1) * m].to_vec();
                Builtin::sinusoid(n, part(0), part(1), part(2), part(3))
            }
            kind => {
                let interp = if kind == SIGNAL_CUBIC { Interp::Cubic } else { Interp::Linear };
                Builtin::table(n, d[..self.rows].to_vec(), d[self.rows..].to_vec(), interp)
            }
        }
    }

    /// The core's pivot axis (`name`: x or y).
    fn axis(&self, name: &str) -> Result<Axis, Error> {
        let d = &self.data;
        match self.kind {
            SIGNAL_CONSTANT if d.len() == 1 => Axis::fixed(name, d[0]),
            SIGNAL_SINUSOID if d.len() == 4 => Axis::sinusoid(name, d[0], d[1], d[2], d[3]),
            SIGNAL_CONSTANT | SIGNAL_SINUSOID => Err(Error::input(format!("pivot {name}: expected one value per parameter, got {} numbers", d.len()))),
            SIGNAL_LINEAR => Err(Error::input(format!("pivot {name}: a table must be cubic (the pivot's motion needs two derivatives)"))),
            _ => Axis::spline(name, d[..self.rows].to_vec(), d[self.rows..].to_vec()),
        }
    }
}

/// Everything a simulation has beyond the ideal chain on a fixed pivot; unset parts are
/// absent (no losses, no cart, a fixed pivot at the origin, no torque, no cart force).
#[derive(Debug, Clone)]
pub struct Setup {
    damping: Option<Vec<f64>>,
    friction: Option<Vec<f64>>,
    friction_velocity: f64,
    cart: Option<(f64, f64)>,
    cart0: [f64; 2],
    pivot: [Option<Signal>; 2],
    torque: Option<(bool, Signal)>,
    force: Option<Signal>,
    /// Whether the base can be dragged (`mp_sim_follow`) during the run.
    draggable: bool,
}

impl Default for Setup {
    fn default() -> Self {
        Setup {
            damping: None,
            friction: None,
            friction_velocity: FRICTION_VELOCITY,
            cart: None,
            cart0: [0.0, 0.0],
            pivot: [None, None],
            torque: None,
            force: None,
            draggable: false,
        }
    }
}

/// The torque of a simulation: generalized (conjugate to the absolute angles) or joint-motor
/// torques, both the core's built-in forms.
enum Torque {
    Generalized(Builtin),
    Joint(Joint<Builtin>),
}

impl TorqueSource for Torque {
    fn active(&self) -> bool {
        match self {
            Torque::Generalized(b) => b.active(),
            Torque::Joint(b) => b.active(),
        }
    }
    fn eval(&mut self, t: f64, theta: &[f64], omega: &[f64], out: &mut [f64]) -> multipendulum_core::Result<()> {
        match self {
            Torque::Generalized(b) => b.eval(t, theta, omega, out),
            Torque::Joint(b) => b.eval(t, theta, omega, out),
        }
    }
}

/// A message of the core about part of the setup, said with the part's name.
fn about(what: &str) -> impl Fn(Error) -> Error + '_ {
    move |e| match e {
        Error::Input(m) if !m.starts_with(what) => Error::input(format!("{what}: {m}")),
        e => e,
    }
}

impl Setup {
    /// The chain with its losses and cart, the drive and the torque, as the core builds them.
    fn apply(&self, chain: Chain) -> Result<(Chain, Drive, Torque), Error> {
        let n = chain.n();
        let zeros = vec![0.0; n];
        let chain = chain.with_losses(self.damping.as_deref().unwrap_or(&zeros), self.friction.as_deref().unwrap_or(&zeros), self.friction_velocity)?;
        let cart = self.cart.map(|(m, c)| Cart::new(m, c)).transpose()?;
        let chain = chain.with_cart(cart)?;
        // The core's check of a run's cart state, which its Stepper::new does not call (yet).
        multipendulum_core::error::check_finite("cart state (cart_x0, cart_v0)", &self.cart0)?;
        let pivot = match &self.pivot {
            [None, None] => None,
            [x, y] => {
                let axis = |s: &Option<Signal>, name| s.as_ref().map_or(Ok(Axis::Fixed(0.0)), |s| s.axis(name));
                Some(Pivot { x: axis(x, "x")?, y: axis(y, "y")? })
            }
        };
        let mut force = match &self.force {
            Some(s) => Some(Force::Builtin(s.builtin(1).map_err(about("cart_force"))?)),
            None => None,
        };
        let mut pivot = pivot;
        if self.draggable {
            // What the state holds is fixed when the run starts: a draggable base starts with a
            // pivot that stays at the origin (an approach at rest) or a cart force of zero.
            if chain.cart().is_some() {
                force = force.or_else(|| Some(Force::Builtin(Builtin::Constant(vec![0.0]))));
            } else if pivot.is_none() {
                let rest = Arc::new(Dragged([Approach::towards(0.0, 0.0, 0.0, 0.0); 2]));
                pivot = Some(Pivot { x: Axis::Function(rest.clone()), y: Axis::Function(Arc::new(DraggedY(rest))) });
            }
        }
        let torque = match &self.torque {
            None => Torque::Generalized(Builtin::None),
            Some((false, s)) => Torque::Generalized(s.builtin(n).map_err(about("torque"))?),
            Some((true, s)) => Torque::Joint(Joint(s.builtin(n).map_err(about("joint torque"))?)),
        };
        Ok((chain, Drive { pivot, force }, torque))
    }
}

/// An empty setup (the ideal chain on a fixed pivot).
#[no_mangle]
pub extern "C" fn mp_setup_new() -> *mut Setup {
    Box::into_raw(Box::default())
}

/// # Safety
/// `setup` came from `mp_setup_new` and is not used again.
#[no_mangle]
pub unsafe extern "C" fn mp_setup_free(setup: *mut Setup) {
    if !setup.is_null() {
        drop(Box::from_raw(setup));
    }
}

/// Joint losses: viscous `damping` (N m s/rad) and Coulomb `friction` (N m), `n` values each
/// (null: none), and the friction's regularisation rate (rad/s; the core's default is in the
/// facts, `defaults.friction_velocity`).
///
/// # Safety
/// `setup` is live; non-null arrays hold `n` f64.
#[no_mangle]
pub unsafe extern "C" fn mp_setup_losses(setup: *mut Setup, n: usize, damping: *const f64, friction: *const f64, friction_velocity: f64) {
    let s = &mut *setup;
    s.damping = optional(damping, n).map(<[f64]>::to_vec);
    s.friction = optional(friction, n).map(<[f64]>::to_vec);
    s.friction_velocity = friction_velocity;
}

/// Let the base be dragged during the run (`mp_sim_follow`): without a prescribed motion the
/// pivot then stays at the origin through the moving-pivot equations (and a cart gets a cart
/// force of zero), so that pulling it later changes no part of the run's state.
///
/// # Safety
/// `setup` is live.
#[no_mangle]
pub unsafe extern "C" fn mp_setup_draggable(setup: *mut Setup) {
    (*setup).draggable = true;
}

/// A cart carrying the pivot: its mass (kg), viscous damping (N s/m), initial position (m) and
/// velocity (m/s).
///
/// # Safety
/// `setup` is live.
#[no_mangle]
pub unsafe extern "C" fn mp_setup_cart(setup: *mut Setup, mass: f64, damping: f64, x0: f64, v0: f64) {
    let s = &mut *setup;
    s.cart = Some((mass, damping));
    s.cart0 = [x0, v0];
}

unsafe fn set_signal(slot: &mut Option<Signal>, kind: i32, rows: usize, data: *const f64, len: usize, what: &str) -> i32 {
    match Signal::read(kind, rows, data, len, what) {
        Ok(sig) => {
            *slot = Some(sig);
            DONE
        }
        Err(e) => fail(&e),
    }
}

/// One axis of a prescribed pivot motion (`axis` 0: x, 1: y; m), a signal (`SIGNAL_*`; the
/// other axis stays at 0 unless set). `INPUT_ERROR` for an unknown axis or kind.
///
/// # Safety
/// `setup` is live; `data` holds `len` f64.
#[no_mangle]
pub unsafe extern "C" fn mp_setup_pivot(setup: *mut Setup, axis: i32, kind: i32, rows: usize, data: *const f64, len: usize) -> i32 {
    let s = &mut *setup;
    match axis {
        0 | 1 => set_signal(&mut s.pivot[axis as usize], kind, rows, data, len, ["pivot x", "pivot y"][axis as usize]),
        _ => fail(&Error::input(format!("pivot axis must be 0 (x) or 1 (y), got {axis}"))),
    }
}

/// The driving torque (N m), a signal of one column per link: generalized torques conjugate
/// to the absolute angles (`joint == 0`), or joint-motor torques between link i-1 and link i.
///
/// # Safety
/// `setup` is live; `data` holds `len` f64.
#[no_mangle]
pub unsafe extern "C" fn mp_setup_torque(setup: *mut Setup, joint: i32, kind: i32, rows: usize, data: *const f64, len: usize) -> i32 {
    let s = &mut *setup;
    let mut slot = None;
    let status = set_signal(&mut slot, kind, rows, data, len, "torque");
    s.torque = slot.map(|sig| (joint != 0, sig));
    status
}

/// The horizontal force on the cart (N), a signal of one column.
///
/// # Safety
/// `setup` is live; `data` holds `len` f64.
#[no_mangle]
pub unsafe extern "C" fn mp_setup_cart_force(setup: *mut Setup, kind: i32, rows: usize, data: *const f64, len: usize) -> i32 {
    set_signal(&mut (*setup).force, kind, rows, data, len, "cart_force")
}

// ---- Simulation --------------------------------------------------------------------------------

/// A simulation: the core's stepper, with its chain's cart if it has one.
pub struct Sim {
    stepper: Stepper<Torque>,
    cart: bool,
    /// The drive the run was built with (a dragged cart gets its force back from it).
    drive: Drive,
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
/// `setup` (null: none) adds the losses, the cart, the pivot motion and the drive.
///
/// # Safety
/// Every non-null array pointer holds `n` f64; `method` holds `method_len` bytes; a non-null
/// `setup` is live.
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
    setup: *const Setup,
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
        let extra = if setup.is_null() { Setup::default() } else { (*setup).clone() };
        let (chain, drive, torque) = extra.apply(chain)?;
        let cart = chain.cart().is_some();
        let dt = if method.adaptive() && dt == 0.0 { None } else { Some(dt) };
        let settings = Settings { method, dt, rtol, atol, drive, cart0: extra.cart0, ..Settings::default() };
        let stepper = Stepper::new(chain, slice(theta0, n), slice(omega0, n), &settings, torque)?;
        let drive = stepper.drive().clone();
        Ok(Sim { stepper, cart, drive })
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

/// Energy `T + U` of the current state (J), in the lab frame (with the pivot's or the cart's
/// motion).
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

/// The energy error of the current state, as the core defines it for every report: the
/// residual of the balance `|E - E0 - W_torque - W_pivot - W_cart + D| / (g sum |h_i| + max T)`
/// (`multipendulum_core::run::energy`).
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

/// Joint positions into `out` (2N values: x, y of each link's far end), relative to the pivot
/// (add `mp_sim_base` for the lab frame).
///
/// # Safety
/// `sim` is a live handle; `out` holds 2N f64.
#[no_mangle]
pub unsafe extern "C" fn mp_sim_positions(sim: *const Sim, out: *mut f64) {
    let s = &(*sim).stepper;
    s.positions_into(std::slice::from_raw_parts_mut(out, 2 * s.n()));
}

/// The number of values `mp_sim_terms` writes.
pub const TERMS: usize = 12;

/// The energy terms and the base of the current state into `out` (`TERMS` values): kinetic,
/// potential and total energy (J, lab frame); the work done since t = 0 by the torque, the
/// pivot and the cart force; the energy dissipated (joint losses and cart damping); the
/// balance's residual (`mp_sim_energy_error`); the base's position (x, y: the pivot, or the
/// cart at y = 0); the cart's position and velocity (zeros without a cart). A negative status
/// if the core cannot evaluate them.
///
/// # Safety
/// `sim` is a live handle; `out` holds `TERMS` f64.
#[no_mangle]
pub unsafe extern "C" fn mp_sim_terms(sim: *mut Sim, out: *mut f64) -> i32 {
    let sim = &mut *sim;
    let terms = match sim.stepper.terms() {
        Ok(t) => t,
        Err(e) => return fail(&e),
    };
    let residual = sim.stepper.energy_error();
    let (x, v) = sim.stepper.cart();
    let base = if sim.cart { [x, 0.0] } else { terms.pivot_pos };
    let values =
        [terms.kinetic, terms.energy - terms.kinetic, terms.energy, terms.torque, terms.pivot, terms.cart, terms.dissipated, residual, base[0], base[1], x, v];
    std::slice::from_raw_parts_mut(out, TERMS).copy_from_slice(&values);
    DONE
}

/// The base's position into `out` (2 values, m): the pivot's (the origin when fixed), or the
/// cart's at y = 0.
///
/// # Safety
/// `sim` is a live handle; `out` holds 2 f64.
#[no_mangle]
pub unsafe extern "C" fn mp_sim_base(sim: *mut Sim, out: *mut f64) {
    let sim = &mut *sim;
    let base = if sim.cart { [sim.stepper.cart().0, 0.0] } else { sim.stepper.pivot() };
    std::slice::from_raw_parts_mut(out, 2).copy_from_slice(&base);
}

// ---- The dragged base ----------------------------------------------------------------------

/// How the base follows the pointer: a critically damped spring of this natural rate (rad/s),
/// from the base's position and velocity when the pointer moves.
pub const FOLLOW_RATE: f64 = 12.0;
/// The most acceleration (m/s^2) of a dragged base: the spring's target is brought no further
/// from the base than keeps the whole approach within it (see [`Approach::towards`]).
pub const FOLLOW_ACCELERATION: f64 = 40.0;

/// One axis of the dragged pivot: from `(x0, v0)` at `t0` towards `target`, critically damped,
/// `x'' = w^2 (target - x) - 2 w x'`, in closed form: `x = target + (c1 + c2 s) e^{-w s}`,
/// `s = t - t0`, `c1 = x0 - target`, `c2 = v0 + w c1`. Position, velocity and acceleration are
/// exact derivatives of one another (the core's moving pivot needs all three).
#[derive(Debug, Clone, Copy)]
struct Approach {
    t0: f64,
    x0: f64,
    v0: f64,
    target: f64,
    rate: f64,
}

/// The largest |acceleration| of the approach from `(x0, v0)` towards `target` over all later
/// times. With `u = w s` the acceleration is `e^{-u} (a0 - b u)`, `a0 = w^2 (target - x0) -
/// 2 w v0`, `b = a0 + w v0`: its extremes are at `u = 0` and, when positive, at
/// `u* = 1 + a0 / b`, where it is `-b e^{-u*}`.
fn peak(w: f64, x0: f64, v0: f64, target: f64) -> f64 {
    let a0 = w * w * (target - x0) - 2.0 * w * v0;
    let b = a0 + w * v0;
    let u = 1.0 + a0 / b;
    if b != 0.0 && u > 0.0 {
        a0.abs().max(b.abs() * (-u).exp())
    } else {
        a0.abs()
    }
}

impl Approach {
    /// From `(x0, v0)` towards `target`, the target brought towards the coasting one (where
    /// the spring starts without acceleration, `x0 + 2 v0 / w`, whose peak is `w |v0| / e`)
    /// until the whole approach stays within [`FOLLOW_ACCELERATION`]. Only a base already
    /// faster than `e A / w` (about 9 m/s) cannot be held to it: it coasts.
    fn towards(t0: f64, x0: f64, v0: f64, target: f64) -> Self {
        let (w, limit) = (FOLLOW_RATE, FOLLOW_ACCELERATION);
        let coast = x0 + 2.0 * v0 / w;
        let within = |r: f64| peak(w, x0, v0, r) <= limit;
        let target = if within(target) || !within(coast) {
            if within(target) {
                target
            } else {
                coast
            }
        } else {
            // Bisection between an acceptable target and one that is not.
            let (mut ok, mut bad) = (coast, target);
            for _ in 0..64 {
                let mid = 0.5 * (ok + bad);
                if within(mid) {
                    ok = mid
                } else {
                    bad = mid
                }
            }
            ok
        };
        Approach { t0, x0, v0, target, rate: w }
    }

    fn eval(&self, t: f64) -> [f64; 3] {
        let (w, s) = (self.rate, t - self.t0);
        let c1 = self.x0 - self.target;
        let c2 = self.v0 + w * c1;
        let e = (-w * s).exp();
        // `target + (c1 + c2 s) e` written from `x0`, so that it starts exactly there.
        let position = self.x0 + c1 * (-w * s).exp_m1() + c2 * s * e;
        [position, (self.v0 - w * c2 * s) * e, (w * w * c2 * s - w * c2 - w * self.v0) * e]
    }
}

#[derive(Debug)]
struct Dragged([Approach; 2]);

impl multipendulum_core::AxisFn for Dragged {
    fn eval(&self, t: f64) -> multipendulum_core::Result<[f64; 3]> {
        Ok(self.0[0].eval(t))
    }
}

/// The y axis of a dragged pivot (the x axis is [`Dragged`] itself).
#[derive(Debug)]
struct DraggedY(Arc<Dragged>);

impl multipendulum_core::AxisFn for DraggedY {
    fn eval(&self, t: f64) -> multipendulum_core::Result<[f64; 3]> {
        Ok(self.0 .0[1].eval(t))
    }
}

/// The dragged cart: a horizontal force pulling it towards `target` as a critically damped
/// spring would pull the whole chain's mass `m` (cart and links),
/// `F = m (w^2 (target - x) - 2 w v)`, held within `m A` ([`FOLLOW_ACCELERATION`]).
#[derive(Debug)]
struct Pull {
    target: f64,
    mass: f64,
}

impl multipendulum_core::ForceFn for Pull {
    fn eval(&self, _t: f64, state: &[f64]) -> multipendulum_core::Result<f64> {
        // The state is (x, theta_1..theta_N, v, omega_1..omega_N).
        let (x, v) = (state[0], state[state.len() / 2]);
        let w = FOLLOW_RATE;
        let a = (w * w * (self.target - x) - 2.0 * w * v).clamp(-FOLLOW_ACCELERATION, FOLLOW_ACCELERATION);
        Ok(self.mass * a)
    }
}

/// Pull the base towards `(x, y)` (m, lab frame) from now on: the pivot follows it through
/// the core's moving-pivot physics as [`Approach`] says (its position and velocity continue,
/// so the energy balance stays exact), or the cart is pulled along the rail by [`Pull`] (`y`
/// unused; the chain's own cart force is set aside until `mp_sim_release`). Called as the
/// pointer moves; a negative status if the run has failed or the target is not finite.
///
/// # Safety
/// `sim` is a live handle.
#[no_mangle]
pub unsafe extern "C" fn mp_sim_follow(sim: *mut Sim, x: f64, y: f64) -> i32 {
    let sim = &mut *sim;
    let mut follow = || -> Result<(), Error> {
        if !(x.is_finite() && y.is_finite()) {
            return Err(Error::input(format!("the pointer's target must be finite, got ({x}, {y})")));
        }
        let drive = if sim.cart {
            let chain = sim.stepper.chain();
            let mass = chain.cart().map_or(0.0, |c| c.mass) + chain.total_mass();
            Drive { pivot: None, force: Some(Force::Function(Arc::new(Pull { target: x, mass }))) }
        } else {
            let (t, m) = (sim.stepper.t(), sim.stepper.pivot_motion()?);
            let axes = [0, 1].map(|k| Approach::towards(t, m.pos[k], m.vel[k], [x, y][k]));
            let dragged = Arc::new(Dragged(axes));
            Drive { pivot: Some(Pivot { x: Axis::Function(dragged.clone()), y: Axis::Function(Arc::new(DraggedY(dragged))) }), force: None }
        };
        sim.stepper.set_drive(drive)
    };
    match follow() {
        Ok(()) => DONE,
        Err(e) => fail(&e),
    }
}

/// The pointer let go: a cart gets its own force back; a dragged pivot settles where it was
/// pulled (its spring keeps its target).
///
/// # Safety
/// `sim` is a live handle.
#[no_mangle]
pub unsafe extern "C" fn mp_sim_release(sim: *mut Sim) -> i32 {
    let sim = &mut *sim;
    if !sim.cart {
        return DONE;
    }
    match sim.stepper.set_drive(sim.drive.clone()) {
        Ok(()) => DONE,
        Err(e) => fail(&e),
    }
}

/// The base's motion into `out` (6 values): position (m), velocity (m/s) and acceleration
/// (m/s^2), x then y of each: the pivot's, or the cart's along the rail (its acceleration 0:
/// the cart's is the integrator's, not a prescribed one).
///
/// # Safety
/// `sim` is a live handle; `out` holds 6 f64.
#[no_mangle]
pub unsafe extern "C" fn mp_sim_base_motion(sim: *mut Sim, out: *mut f64) -> i32 {
    let sim = &mut *sim;
    let values = if sim.cart {
        let (x, v) = sim.stepper.cart();
        [x, 0.0, v, 0.0, 0.0, 0.0]
    } else {
        match sim.stepper.pivot_motion() {
            Ok(m) => [m.pos[0], m.pos[1], m.vel[0], m.vel[1], m.acc[0], m.acc[1]],
            Err(e) => return fail(&e),
        }
    };
    std::slice::from_raw_parts_mut(out, 6).copy_from_slice(&values);
    DONE
}

// ---- Flip maps ---------------------------------------------------------------------------------

/// First-flip times of `b` undriven double pendulums (the core's lane kernel,
/// `chaos::first_flips`): chain as in `mp_sim_new` (2 links; `rods`, `com`/`inertia` may be
/// null), initial states `theta0`, `omega0` (`2 b` values each, row by row), rk4 at `dt` up to
/// `t_max`, the flip of `link` (0 or 1; -1: either). `out` receives `b` times (+inf: none
/// before `t_max`). A negative status on bad input.
///
/// # Safety
/// Arrays hold what is said; `out` holds `b` f64.
#[no_mangle]
pub unsafe extern "C" fn mp_first_flips(
    rods: i32,
    lengths: *const f64,
    masses: *const f64,
    com: *const f64,
    inertia: *const f64,
    g: f64,
    theta0: *const f64,
    omega0: *const f64,
    b: usize,
    t_max: f64,
    dt: f64,
    link: i32,
    out: *mut f64,
) -> i32 {
    let run = || -> Result<Vec<f64>, Error> {
        let n = 2;
        let (lengths, masses) = (slice(lengths, n), slice(masses, n));
        let chain = if rods != 0 { Chain::rods(lengths, masses, g)? } else { Chain::new(lengths, masses, optional(com, n), optional(inertia, n), g)? };
        let link = match link {
            -1 => None,
            k if k >= 0 => Some(k as usize),
            k => return Err(Error::input(format!("link must be -1 (any) or a link index, got {k}"))),
        };
        multipendulum_core::chaos::first_flips(
            &chain,
            slice(theta0, n * b),
            slice(omega0, n * b),
            t_max,
            dt,
            link,
            &Builtin::None,
            None,
            &multipendulum_core::watch::Watch::new(),
        )
    };
    match run() {
        Ok(times) => {
            std::slice::from_raw_parts_mut(out, b).copy_from_slice(&times);
            DONE
        }
        Err(e) => fail(&e),
    }
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
            n,
            0,
            lengths.as_ptr(),
            masses.as_ptr(),
            std::ptr::null(),
            std::ptr::null(),
            9.81,
            method.as_ptr(),
            method.len(),
            dt,
            1e-10,
            1e-12,
            theta0.as_ptr(),
            omega0.as_ptr(),
            std::ptr::null(),
        )
    }

    /// A rod chain of unit links with `setup`, from `theta0` at rest.
    unsafe fn with(setup: *mut Setup, method: &str, dt: f64, theta0: &[f64]) -> *mut Sim {
        let n = theta0.len();
        let ones = vec![1.0; n];
        let omega0 = vec![0.0; n];
        let sim = mp_sim_new(
            n,
            1,
            ones.as_ptr(),
            ones.as_ptr(),
            std::ptr::null(),
            std::ptr::null(),
            9.81,
            method.as_ptr(),
            method.len(),
            dt,
            1e-10,
            1e-12,
            theta0.as_ptr(),
            omega0.as_ptr(),
            setup,
        );
        mp_setup_free(setup);
        sim
    }

    unsafe fn terms(sim: *mut Sim) -> [f64; TERMS] {
        let mut out = [0.0; TERMS];
        assert_eq!(mp_sim_terms(sim, out.as_mut_ptr()), DONE);
        out
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

    #[test]
    fn a_damped_chain_loses_what_it_dissipates() {
        unsafe {
            let setup = mp_setup_new();
            let (damping, friction) = ([0.2, 0.1], [0.0, 0.05]);
            mp_setup_losses(setup, 2, damping.as_ptr(), friction.as_ptr(), FRICTION_VELOCITY);
            let sim = with(setup, "dop853", 0.0, &[1.0, 0.5]);
            assert!(!sim.is_null(), "{}", message());
            let start = terms(sim);
            assert_eq!(mp_sim_advance(sim, 3.0, 100_000), DONE);
            let [kinetic, potential, energy, torque, pivot, cart, dissipated, residual, bx, by, x, v] = terms(sim);
            assert!(energy < start[2] - 0.5 && dissipated > 0.5, "{energy} {dissipated}");
            assert!((kinetic + potential - energy).abs() < 1e-12);
            assert!(((energy - start[2]) + dissipated).abs() < 1e-8, "the balance");
            assert!(residual < 1e-8 && [torque, pivot, cart, bx, by, x, v] == [0.0; 7]);
            mp_sim_free(sim);
        }
    }

    #[test]
    fn a_cart_pushed_by_its_force_moves_and_a_torque_does_work() {
        unsafe {
            let setup = mp_setup_new();
            mp_setup_cart(setup, 2.0, 0.1, 0.5, 0.0);
            let force = [1.0];
            assert_eq!(mp_setup_cart_force(setup, SIGNAL_CONSTANT, 0, force.as_ptr(), 1), DONE);
            // A joint torque table: 3 times, one column.
            let table = [0.0, 1.0, 2.0, 0.5, 0.5, 0.0];
            assert_eq!(mp_setup_torque(setup, 1, SIGNAL_CUBIC, 3, table.as_ptr(), 6), DONE);
            let sim = with(setup, "rk4", 0.001, &[0.3]);
            assert!(!sim.is_null(), "{}", message());
            assert_eq!(mp_sim_advance(sim, 1.0, 100_000), DONE);
            let t = terms(sim);
            let (x, v) = (t[10], t[11]);
            assert!(x > 0.55 && v > 0.0, "{x} {v}");
            assert_eq!([t[8], t[9]], [x, 0.0]);
            assert!(t[3] != 0.0 && t[5] > 0.0 && t[6] > 0.0 && t[7] < 1e-9, "{t:?}");
            let mut base = [0.0; 2];
            mp_sim_base(sim, base.as_mut_ptr());
            assert_eq!(base, [x, 0.0]);
            mp_sim_free(sim);
        }
    }

    #[test]
    fn a_shaken_pivot_moves_and_its_work_balances() {
        unsafe {
            let setup = mp_setup_new();
            let y = [0.02, 300.0, std::f64::consts::FRAC_PI_2, 0.0];
            assert_eq!(mp_setup_pivot(setup, 1, SIGNAL_SINUSOID, 0, y.as_ptr(), 4), DONE);
            let sim = with(setup, "dop853", 0.0, &[3.0]);
            assert!(!sim.is_null(), "{}", message());
            let mut base = [0.0; 2];
            mp_sim_base(sim, base.as_mut_ptr());
            assert_eq!(base, [0.0, 0.02]);
            assert_eq!(mp_sim_advance(sim, 0.01, 100_000), DONE);
            mp_sim_base(sim, base.as_mut_ptr());
            assert!((base[1] - 0.02 * (3.0f64 + std::f64::consts::FRAC_PI_2).sin()).abs() < 1e-15);
            let t = terms(sim);
            assert!(t[4] != 0.0 && t[7] < 1e-9, "{t:?}");
            mp_sim_free(sim);
        }
    }

    #[test]
    fn bad_losses_a_bad_base_and_bad_signals_are_refused_with_the_core_message() {
        unsafe {
            let setup = mp_setup_new();
            let damping = [0.1, -1.0];
            mp_setup_losses(setup, 2, damping.as_ptr(), std::ptr::null(), FRICTION_VELOCITY);
            assert!(with(setup, "rk4", 0.01, &[0.0, 0.0]).is_null());
            assert_eq!(message(), "damping[1] must be >= 0 and finite, got -1");

            let setup = mp_setup_new();
            mp_setup_losses(setup, 1, std::ptr::null(), std::ptr::null(), 0.0);
            assert!(with(setup, "rk4", 0.01, &[0.0]).is_null());
            assert_eq!(message(), "friction_velocity must be > 0 and finite, got 0");
            let setup = mp_setup_new();
            mp_setup_losses(setup, 1, std::ptr::null(), std::ptr::null(), f64::NAN);
            assert!(with(setup, "rk4", 0.01, &[0.0]).is_null());
            assert_eq!(message(), "friction_velocity must be > 0 and finite, got NaN");

            let setup = mp_setup_new();
            mp_setup_cart(setup, 0.0, 0.0, 0.0, 0.0);
            assert!(with(setup, "rk4", 0.01, &[0.0]).is_null());
            assert_eq!(message(), "cart mass must be > 0 and finite, got 0");
            let setup = mp_setup_new();
            mp_setup_cart(setup, 1.0, 0.0, 0.0, f64::INFINITY);
            assert!(with(setup, "rk4", 0.01, &[0.0]).is_null());
            assert_eq!(message(), "cart state (cart_x0, cart_v0)[1] must be finite, got inf");

            let setup = mp_setup_new();
            mp_setup_cart(setup, 1.0, 0.0, 0.0, 0.0);
            let x = [0.1];
            mp_setup_pivot(setup, 0, SIGNAL_CONSTANT, 0, x.as_ptr(), 1);
            assert!(with(setup, "rk4", 0.01, &[0.0]).is_null());
            assert!(message().starts_with("a chain on a cart has no prescribed pivot motion"), "{}", message());

            let setup = mp_setup_new();
            let short = [0.0, 1.0];
            mp_setup_pivot(setup, 1, SIGNAL_CUBIC, 1, short.as_ptr(), 2);
            assert!(with(setup, "rk4", 0.01, &[0.0]).is_null());
            assert_eq!(message(), "pivot y: a cubic table needs at least 2 samples, got 1");

            let setup = mp_setup_new();
            let line = [0.0, 1.0, 0.0, 1.0];
            mp_setup_pivot(setup, 0, SIGNAL_LINEAR, 2, line.as_ptr(), 4);
            assert!(with(setup, "rk4", 0.01, &[0.0]).is_null());
            assert!(message().starts_with("pivot x: a table must be cubic"), "{}", message());

            let setup = mp_setup_new();
            let two = [1.0, 2.0];
            mp_setup_torque(setup, 0, SIGNAL_CONSTANT, 0, two.as_ptr(), 2);
            assert!(with(setup, "rk4", 0.01, &[0.0]).is_null());
            assert_eq!(message(), "torque must have 1 entries (one per link), got 2");

            let setup = mp_setup_new();
            mp_setup_cart_force(setup, SIGNAL_CONSTANT, 0, two.as_ptr(), 1);
            assert!(with(setup, "rk4", 0.01, &[0.0]).is_null());
            assert!(message().starts_with("cart_force needs a chain with a cart"), "{}", message());

            let setup = mp_setup_new();
            assert_eq!(mp_setup_torque(setup, 0, 7, 0, two.as_ptr(), 2), INPUT_ERROR);
            assert_eq!(message(), "torque: unknown signal kind 7");
            assert_eq!(mp_setup_pivot(setup, 2, SIGNAL_CONSTANT, 0, two.as_ptr(), 1), INPUT_ERROR);
            assert_eq!(message(), "pivot axis must be 0 (x) or 1 (y), got 2");
            mp_setup_free(setup);
        }
    }

    #[test]
    fn the_dragged_pivots_approach_solves_its_spring_and_starts_within_the_bound() {
        let w = FOLLOW_RATE;
        for (x0, v0, target) in [(0.0, 0.0, 0.1), (0.3, -1.5, -0.2), (-1.0, 2.0, 50.0), (0.0, 0.0, -1e6)] {
            let a = Approach::towards(1.5, x0, v0, target);
            // Starts where the base is, at its velocity.
            let [p, v, _] = a.eval(1.5);
            assert!(p == x0 && v == v0, "{p} {v}");
            // The target is the pointer's unless that would ask for more than the bound, and
            // the whole approach stays within it (sampled finely, against the closed form).
            let most = (0..4000).map(|k| a.eval(1.5 + k as f64 * 1e-3)[2].abs()).fold(0.0, f64::max);
            assert!(most <= FOLLOW_ACCELERATION * (1.0 + 1e-9), "{most}");
            assert!(most >= 0.99 * peak(w, x0, v0, a.target), "{most}");
            let unclamped = peak(w, x0, v0, target) <= FOLLOW_ACCELERATION;
            assert_eq!(a.target == target, unclamped, "{x0} {v0} {target}");
            if !unclamped {
                assert!(most > 0.999 * FOLLOW_ACCELERATION, "the target is pulled in only as far as needed: {most}");
            }
            for s in [0.0, 0.01, 0.1, 0.4, 2.0] {
                let t = 1.5 + s;
                let [p, v, acc] = a.eval(t);
                // The spring's equation, and velocity and acceleration as the derivatives
                // (central differences) of what comes before them.
                let spring = w * w * (a.target - p) - 2.0 * w * v;
                assert!((acc - spring).abs() <= 1e-9 * (1.0 + spring.abs()), "{acc} {spring}");
                let h = 1e-6;
                let (m, q) = (a.eval(t - h), a.eval(t + h));
                assert!(((q[0] - m[0]) / (2.0 * h) - v).abs() <= 1e-6 * (1.0 + v.abs()), "velocity at {s}");
                assert!(((q[1] - m[1]) / (2.0 * h) - acc).abs() <= 1e-5 * (1.0 + acc.abs()), "acceleration at {s}");
            }
            assert!((a.eval(100.0)[0] - a.target).abs() < 1e-9, "it settles on the target");
        }
    }

    #[test]
    fn a_pointer_jumping_anywhere_every_frame_keeps_the_pivot_within_the_bound() {
        // Targets anywhere within 3 m each frame for 20 s (a tiny LCG: the test is its own).
        let mut seed = 12345u64;
        let mut jump = || {
            seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            6.0 * ((seed >> 11) as f64 / (1u64 << 53) as f64) - 3.0
        };
        let (mut x, mut v, mut t) = (0.0, 0.0, 0.0);
        let (mut most, mut fastest) = (0.0f64, 0.0f64);
        for _ in 0..1200 {
            let a = Approach::towards(t, x, v, jump());
            for k in 1..=20 {
                let [_, q, acc] = a.eval(t + k as f64 / 1200.0);
                most = most.max(acc.abs());
                fastest = fastest.max(q.abs());
            }
            t += 1.0 / 60.0;
            let [p, q, _] = a.eval(t);
            (x, v) = (p, q);
        }
        assert!(most <= FOLLOW_ACCELERATION * (1.0 + 1e-9) && most > 0.99 * FOLLOW_ACCELERATION, "{most}");
        assert!(fastest < std::f64::consts::E * FOLLOW_ACCELERATION / FOLLOW_RATE, "it never has to coast: {fastest}");
    }

    unsafe fn motion(sim: *mut Sim) -> [f64; 6] {
        let mut out = [0.0; 6];
        assert_eq!(mp_sim_base_motion(sim, out.as_mut_ptr()), DONE);
        out
    }

    #[test]
    fn a_dragged_pivot_moves_smoothly_and_its_work_balances() {
        unsafe {
            let setup = mp_setup_new();
            mp_setup_draggable(setup);
            let sim = with(setup, "rk4", 0.001, &[0.2, 0.1]);
            assert_eq!(motion(sim), [0.0; 6]);
            // The pointer jumps far away and wanders, a target per frame of 1/60 s.
            let (mut frame, mut fastest) = (0.0, 0.0f64);
            for k in 0..240 {
                let (x, y) = if k < 10 { (5.0, 5.0) } else { (0.5 * (k as f64 * 0.1).sin(), -0.2) };
                let before = motion(sim);
                assert_eq!(mp_sim_follow(sim, x, y), DONE, "{}", message());
                let after = motion(sim);
                assert_eq!(before[..4], after[..4], "position and velocity continue at a retarget");
                frame += 1.0 / 60.0;
                // The acceleration stays within the bound throughout, not only at retargets.
                while mp_sim_t(sim) < frame - 1e-9 {
                    assert_eq!(mp_sim_advance(sim, mp_sim_t(sim) + 0.002, 100_000), DONE);
                    let m = motion(sim);
                    assert!(m[4].abs().max(m[5].abs()) <= FOLLOW_ACCELERATION * (1.0 + 1e-9), "{m:?}");
                    fastest = fastest.max(m[2].abs().max(m[3].abs()));
                }
            }
            assert!(fastest < std::f64::consts::E * FOLLOW_ACCELERATION / FOLLOW_RATE, "{fastest}");
            let [px, py, ..] = motion(sim);
            assert!(px.abs() < 0.6 && (py + 0.2).abs() < 0.1, "the pivot followed the pointer: {px} {py}");
            let t = terms(sim);
            assert!(t[4].abs() > 1e-3, "the pivot did work: {}", t[4]);
            assert!(t[7] < 1e-6, "the balance holds through the retargets: {}", t[7]);
            assert_eq!([t[8], t[9]], [px, py]);
            assert_eq!(mp_sim_release(sim), DONE);
            assert_eq!(mp_sim_follow(sim, f64::NAN, 0.0), INPUT_ERROR);
            assert_eq!(message(), "the pointer's target must be finite, got (NaN, 0)");
            mp_sim_free(sim);
        }
    }

    #[test]
    fn a_dragged_cart_is_pulled_along_its_rail_and_gets_its_force_back() {
        unsafe {
            // Without a draggable setup the run's state has no room for a pull.
            let setup = mp_setup_new();
            mp_setup_cart(setup, 1.0, 0.0, 0.0, 0.0);
            let sim = with(setup, "rk4", 0.001, &[0.0]);
            assert_eq!(mp_sim_follow(sim, -1.0, 0.0), INPUT_ERROR);
            assert!(message().starts_with("the new drive changes what the run's state holds"), "{}", message());
            mp_sim_free(sim);

            let setup = mp_setup_new();
            mp_setup_cart(setup, 1.0, 0.0, 0.0, 0.0);
            let force = [2.0];
            assert_eq!(mp_setup_cart_force(setup, SIGNAL_CONSTANT, 0, force.as_ptr(), 1), DONE);
            mp_setup_draggable(setup);
            let sim = with(setup, "rk4", 0.001, &[0.0]);
            assert_eq!(mp_sim_follow(sim, -1.0, 3.0), DONE, "{}", message());
            let mut left = 0.0f64;
            for k in 1..=180 {
                assert_eq!(mp_sim_advance(sim, k as f64 / 60.0, 100_000), DONE);
                left = left.min(terms(sim)[10]);
            }
            let t = terms(sim);
            // Pulled to the pointer's x (against its own push of 2 N, set aside while dragged).
            assert!(left < -0.8 && t[10] < -0.5 && t[9] == 0.0, "{left} {t:?}");
            assert!(t[5] != 0.0 && t[7] < 1e-6, "the pull's work balances: {t:?}");
            assert_eq!(mp_sim_release(sim), DONE);
            // Its own force pushes it back to the right (the chain's mass is 2 kg: 1 m/s^2).
            let v = t[11];
            assert_eq!(mp_sim_advance(sim, 4.0, 100_000), DONE);
            let later = terms(sim);
            assert!(later[11] - v > 0.3, "{v} {later:?}");
            mp_sim_free(sim);
        }
    }

    #[test]
    fn the_flip_map_call_is_the_cores_kernel_and_refuses_what_it_refuses() {
        unsafe {
            let (lengths, masses) = ([1.0, 1.0], [1.0, 1.0]);
            let theta: Vec<f64> = (0..16).map(|k| 1.0 + 0.13 * k as f64).collect();
            let omega = vec![0.0; 16];
            let mut out = [0.0; 8];
            let call = |link: i32, t_max: f64, out: &mut [f64; 8]| {
                mp_first_flips(
                    0,
                    lengths.as_ptr(),
                    masses.as_ptr(),
                    std::ptr::null(),
                    std::ptr::null(),
                    9.81,
                    theta.as_ptr(),
                    omega.as_ptr(),
                    8,
                    t_max,
                    0.01,
                    link,
                    out.as_mut_ptr(),
                )
            };
            assert_eq!(call(-1, 10.0, &mut out), DONE, "{}", message());
            let chain = Chain::new(&lengths, &masses, None, None, 9.81).unwrap();
            let core = multipendulum_core::chaos::first_flips(
                &chain,
                &theta,
                &omega,
                10.0,
                0.01,
                None,
                &Builtin::None,
                None,
                &multipendulum_core::watch::Watch::new(),
            )
            .unwrap();
            assert_eq!(out.to_vec(), core);
            assert!(out.iter().any(|t| t.is_finite()) && out.iter().any(|t| t.is_infinite()), "{out:?}");
            assert_eq!(call(2, 10.0, &mut out), INPUT_ERROR);
            assert_eq!(message(), "link must be < N = 2, got 2");
            assert_eq!(call(-1, -1.0, &mut out), INPUT_ERROR);
            assert_eq!(message(), "t_max must be > 0 and finite, got -1");
        }
    }
}
