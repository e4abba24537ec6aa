//! Runs: the driver ([`driver::Run`]) that every integration goes through, and its clients:
//! [`simulate`](fn@simulate) (outputs, events, checkpoints, batches) and [`live::Stepper`] (frame by frame).
//! [`energy`] defines the energy error every report uses.
pub mod bank;
pub mod driver;
pub mod energy;
pub mod events;
pub mod lanes;
pub mod live;
pub mod sensitivity;
pub mod simulate;
pub mod task;

pub use driver::{Config, Run, State};
pub use simulate::{defaults, simulate, simulate_batch, simulate_each, simulate_from, Checkpoint, Checkpoints, Monitor, Settings, Start, Stats, Trajectory};
