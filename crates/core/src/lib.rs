//! multipendulum-core: planar N-link pendulum dynamics in O(N), integrators, ensembles.
//!
//! Layers: [`model::Chain`] holds validated constant parameters; [`dynamics`] evaluates the
//! Lagrangian and Hamiltonian forms with preallocated [`dynamics::Workspace`] buffers;
//! [`integrators`] advance a state; [`simulate`] drives a run and collects its output.
pub mod chaos;
pub mod dynamics;
pub mod error;
pub mod events;
pub mod flipkernel;
pub mod memory;
pub mod model;
mod par;
pub mod reference;

pub use dynamics::{Singular, Workspace};
pub use error::{Error, Result};
pub use events::{Condition, EventFn, EventSpec};
pub use model::Chain;
pub mod integrators;
pub mod simulate;
pub mod stepper;
pub mod system;
pub mod torque;
mod trig;

pub use integrators::{Carry, Method};
pub use simulate::{simulate, simulate_batch, simulate_from, Checkpoint, Checkpoints, Settings, Start, Stats, Trajectory};
pub use stepper::Stepper;
pub use system::{ChainSystem, Form, OdeSystem};
pub use torque::{Builtin, Interp, Joint, TorqueSource};
