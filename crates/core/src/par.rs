//! Data parallelism written once: rayon with the `parallel` feature (on by default); without it
//! (WebAssembly has no threads) the same calls run one after another on the calling thread.
//! Modules import `crate::par::*` instead of `rayon::prelude::*`.
#[cfg(feature = "parallel")]
pub(crate) use rayon::prelude::*;

#[cfg(not(feature = "parallel"))]
pub(crate) use sequential::*;

/// The number of threads parallel work runs on (1 without the `parallel` feature).
pub(crate) fn threads() -> usize {
    #[cfg(feature = "parallel")]
    {
        rayon::current_num_threads()
    }
    #[cfg(not(feature = "parallel"))]
    {
        1
    }
}

/// `f` of every item, the calling thread taking part: it starts on the items at once while the
/// pool's threads wake and join in (a short call, such as a vector environment's step between
/// a policy's evaluations, would otherwise wait for a sleeping pool to wake and then for its own
/// wake-up at the end). Items are taken in any order by any thread; each result stays with its
/// index, so the results are the same whichever thread computed them.
pub(crate) fn each_shared<T: Send, R: Send>(items: Vec<T>, f: impl Fn(T) -> R + Sync) -> Vec<R> {
    #[cfg(feature = "parallel")]
    {
        use std::sync::atomic::{AtomicUsize, Ordering};
        use std::sync::Mutex;
        let count = items.len();
        let queue = Mutex::new(items.into_iter().enumerate());
        let results = Mutex::new((0..count).map(|_| None).collect::<Vec<Option<R>>>());
        let done = AtomicUsize::new(0);
        let drain = || loop {
            let Some((i, item)) = queue.lock().unwrap_or_else(|e| e.into_inner()).next() else { break };
            let r = f(item);
            results.lock().unwrap_or_else(|e| e.into_inner())[i] = Some(r);
            done.fetch_add(1, Ordering::Release);
        };
        let helpers = rayon::current_num_threads().min(count).saturating_sub(1);
        let epoch = linger::begin();
        rayon::in_place_scope(|s| {
            for _ in 0..helpers {
                s.spawn(|_| drain());
            }
            drain();
            // The others' last items are at most one item's time away: waited for here rather
            // than asleep (the scope's own wait), which a pool thread would have to wake from.
            while done.load(Ordering::Acquire) < count {
                std::hint::spin_loop();
            }
        });
        linger::after(epoch, helpers);
        results.into_inner().unwrap_or_else(|e| e.into_inner()).into_iter().map(|r| r.expect("every item is taken once")).collect()
    }
    #[cfg(not(feature = "parallel"))]
    {
        items.into_iter().map(f).collect()
    }
}

/// The pool's threads kept awake a moment after an [`each_shared`] call. A vector environment
/// calls again after its Python layer (tens of microseconds); a pool thread that went to sleep
/// in between takes about as long to wake (more in a virtual machine, where its idle CPU halts),
/// so the call's first items would run on the calling thread alone. Each call ends by giving
/// `helpers` pool threads a job that waits (a `spin_loop`, light on a hyperthread's sibling)
/// until the next call begins or [`LINGER`](linger::LINGER) has passed, whichever comes first; the next call's
/// items then find those threads awake. Nothing is computed there, so results are unchanged.
#[cfg(feature = "parallel")]
mod linger {
    use std::sync::atomic::{AtomicU64, Ordering};
    use std::time::{Duration, Instant};

    /// How long a pool thread waits for the next call before it may sleep.
    pub(super) const LINGER: Duration = Duration::from_micros(300);

    /// Calls begun so far: a waiting thread stops when it changes.
    static EPOCH: AtomicU64 = AtomicU64::new(0);

    /// A call begins: the threads waiting since the last one stop waiting. -> this call's epoch.
    pub(super) fn begin() -> u64 {
        EPOCH.fetch_add(1, Ordering::AcqRel) + 1
    }

    /// A call ended: `helpers` pool threads wait for the next one.
    pub(super) fn after(epoch: u64, helpers: usize) {
        for _ in 0..helpers {
            rayon::spawn(move || {
                let until = Instant::now() + LINGER;
                let mut spins = 0u32;
                while EPOCH.load(Ordering::Acquire) == epoch {
                    std::hint::spin_loop();
                    spins = spins.wrapping_add(1);
                    if spins % 64 == 0 && Instant::now() >= until {
                        break;
                    }
                }
            });
        }
    }
}

#[cfg(not(feature = "parallel"))]
mod sequential {
    /// `into_par_iter()`: the plain iterator.
    pub(crate) trait IntoParallelIterator: IntoIterator + Sized {
        fn into_par_iter(self) -> Self::IntoIter {
            self.into_iter()
        }
    }
    impl<I: IntoIterator> IntoParallelIterator for I {}

    /// `par_chunks(n)`: `chunks(n)`.
    pub(crate) trait ParallelSlice<T> {
        fn par_chunks(&self, size: usize) -> std::slice::Chunks<'_, T>;
    }
    impl<T> ParallelSlice<T> for [T] {
        fn par_chunks(&self, size: usize) -> std::slice::Chunks<'_, T> {
            self.chunks(size)
        }
    }

    /// `par_iter_mut()`, `par_chunks_mut(n)`: `iter_mut()`, `chunks_mut(n)`.
    pub(crate) trait ParallelSliceMut<T> {
        fn par_iter_mut(&mut self) -> std::slice::IterMut<'_, T>;
        fn par_chunks_mut(&mut self, size: usize) -> std::slice::ChunksMut<'_, T>;
    }
    impl<T> ParallelSliceMut<T> for [T] {
        fn par_iter_mut(&mut self) -> std::slice::IterMut<'_, T> {
            self.iter_mut()
        }
        fn par_chunks_mut(&mut self, size: usize) -> std::slice::ChunksMut<'_, T> {
            self.chunks_mut(size)
        }
    }

    /// `map_init(init, f)`: one state, made once, for the whole sequence.
    pub(crate) trait MapInit: Iterator + Sized {
        fn map_init<S, R>(self, init: impl FnOnce() -> S, mut f: impl FnMut(&mut S, Self::Item) -> R) -> impl Iterator<Item = R> {
            let mut state = init();
            self.map(move |item| f(&mut state, item))
        }
    }
    impl<I: Iterator> MapInit for I {}
}
