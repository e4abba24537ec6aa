//! Long work watched from outside: a stop flag its workers poll (Ctrl-C), and how much of it is
//! done (progress). The caller keeps the [`Watch`]; [`supervise`] runs the work on another thread
//! while the calling thread polls, so an interrupt is noticed within a fraction of a second even
//! when every worker is busy in a parallel loop.
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::Duration;

use crate::error::{Error, Result};

#[derive(Debug, Default)]
pub struct Watch {
    stop: AtomicBool,
    /// The fraction done, as the bits of an f64 in [0, 1].
    fraction: AtomicU64,
    /// Units done, for work counted in units (trajectories, rows).
    units: AtomicU64,
    total_units: u64,
}

impl Watch {
    /// A watch of work measured as a fraction (one run: its time over its span).
    pub fn new() -> Self {
        Watch::default()
    }

    /// A watch of `total` units of work (a batch of trajectories).
    pub fn units(total: u64) -> Self {
        Watch { total_units: total, ..Watch::default() }
    }

    pub fn stop(&self) {
        self.stop.store(true, Ordering::Relaxed);
    }

    pub fn stopped(&self) -> bool {
        self.stop.load(Ordering::Relaxed)
    }

    /// `Err(Interrupted)` once stopped; `t` is where the caller is, for the message.
    #[inline]
    pub fn check(&self, t: f64) -> Result<()> {
        if self.stopped() {
            Err(Error::Interrupted { t })
        } else {
            Ok(())
        }
    }

    pub fn set_fraction(&self, f: f64) {
        self.fraction.store(f.clamp(0.0, 1.0).to_bits(), Ordering::Relaxed);
    }

    pub fn add_units(&self, n: u64) {
        self.units.fetch_add(n, Ordering::Relaxed);
    }

    /// The fraction done: units over their total when counted so, else the fraction set.
    pub fn fraction(&self) -> f64 {
        if self.total_units > 0 {
            (self.units.load(Ordering::Relaxed) as f64 / self.total_units as f64).min(1.0)
        } else {
            f64::from_bits(self.fraction.load(Ordering::Relaxed))
        }
    }
}

/// Run `work` on a scoped thread while the calling thread calls `poll(fraction)` every `every`;
/// when `poll` returns true the watch is stopped (the work's polls then return
/// [`Error::Interrupted`]) and this waits for the work to wind down. Without threads (the
/// `parallel` feature off, e.g. WebAssembly) the work runs here and `poll` is not called.
pub fn supervise<R: Send>(watch: &Watch, every: Duration, work: impl FnOnce() -> R + Send, mut poll: impl FnMut(f64) -> bool) -> R {
    #[cfg(feature = "parallel")]
    {
        use std::sync::mpsc::{channel, RecvTimeoutError};
        std::thread::scope(|s| {
            let (done, result) = channel();
            let handle = s.spawn(move || {
                // The receiver is gone only if the caller panicked; nothing to tell then.
                let _ = done.send(work());
            });
            loop {
                match result.recv_timeout(every) {
                    Ok(r) => return r,
                    Err(RecvTimeoutError::Timeout) => {
                        if !watch.stopped() && poll(watch.fraction()) {
                            watch.stop();
                        }
                    }
                    // The work panicked: pass its panic on.
                    Err(RecvTimeoutError::Disconnected) => match handle.join() {
                        Err(panic) => std::panic::resume_unwind(panic),
                        Ok(()) => unreachable!("the work ended without a result or a panic"),
                    },
                }
            }
        })
    }
    #[cfg(not(feature = "parallel"))]
    {
        let _ = (watch, every, &mut poll);
        work()
    }
}

#[cfg(all(test, feature = "parallel"))]
mod tests {
    use super::*;

    #[test]
    fn a_poll_that_asks_stops_busy_work_promptly() {
        let watch = Watch::units(10);
        let start = std::time::Instant::now();
        let mut polls = 0;
        let r = supervise(
            &watch,
            Duration::from_millis(10),
            || {
                loop {
                    watch.check(1.5)?;
                    std::hint::spin_loop();
                }
                #[allow(unreachable_code)]
                Ok(())
            },
            |_| {
                polls += 1;
                polls >= 3
            },
        );
        assert_eq!(r, Err(Error::Interrupted { t: 1.5 }));
        assert!(start.elapsed() < Duration::from_secs(2), "took {:?}", start.elapsed());
        assert_eq!(polls, 3);
    }

    #[test]
    fn short_work_returns_at_once_not_after_a_poll_interval() {
        let watch = Watch::new();
        let start = std::time::Instant::now();
        for _ in 0..20 {
            assert_eq!(supervise(&watch, Duration::from_secs(1), || 7, |_| false), 7);
        }
        assert!(start.elapsed() < Duration::from_millis(500), "took {:?}", start.elapsed());
    }

    #[test]
    fn fractions_come_from_units_or_the_fraction_set() {
        let w = Watch::units(4);
        w.add_units(1);
        assert_eq!(w.fraction(), 0.25);
        let f = Watch::new();
        f.set_fraction(2.0);
        assert_eq!(f.fraction(), 1.0);
    }
}
