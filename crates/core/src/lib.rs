//! multipendulum-core: planar N-link pendulum dynamics in O(N), integrators, ensembles.
//!
//! Layers, each using only those before it (a test keeps it so, `tests/layers.rs`):
//! - [`error`], [`par`], [`watch`], [`memory`], [`trig`] (scalar and vectorised `sin`/`cos`),
//!   [`interp`]: shared helpers;
//! - [`model`]: the validated, constant [`model::Chain`];
//! - [`dynamics`]: the Lagrangian and Hamiltonian forms in O(N) with preallocated
//!   [`dynamics::Workspace`] buffers, the ODE systems and the torques, reference solvers;
//! - [`integrators`]: one trait, four methods, step-size control, dense output;
//! - [`run`]: the run driver and its clients (simulate, batches, events, checkpoints, the
//!   frame-by-frame stepper), the energy error;
//! - [`chaos`]: Lyapunov exponents, flip times and the flip-map kernel;
//! - [`facts`]: what the bindings publish about the core (methods, defaults, limits).
// The crate's documentation is for its developers (`cargo doc --document-private-items`, as
// `make lint` builds it): its links to private items are meant, and resolve there.
#![allow(rustdoc::private_intra_doc_links)]
pub mod chaos;
pub mod dynamics;
pub mod error;
pub mod facts;
pub mod integrators;
pub mod interp;
pub mod memory;
pub mod model;
mod par;
pub mod run;
pub mod trig;
pub mod watch;

pub use dynamics::base::{Axis, AxisFn, Drive, Force, ForceFn, Motion, Pivot};
pub use dynamics::general::Load;
pub use dynamics::reference;
pub use dynamics::sensitivity::Input;
pub use dynamics::system::{ChainSystem, Form, OdeSystem};
pub use dynamics::torque::{Builtin, Interp, Joint, Timed, TorqueSource};
pub use dynamics::{Singular, Workspace};
pub use error::{Error, Result};
pub use integrators::{Facts, Method};
pub use model::{Cart, Chain};
pub use run::events::{Condition, EventFn, EventSpec};
pub use run::live::{Acted, Column, Stepper, Steppers};
pub use run::simulate::Terms;
pub use run::task::{Goal, Target, Task};
pub use run::{simulate, simulate_batch, simulate_each, simulate_from, Checkpoint, Checkpoints, Settings, Start, Stats, Trajectory};
pub use watch::Watch;
