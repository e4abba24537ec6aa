//! The memory a request needs, checked before anything is allocated: against a fixed limit and
//! against what the machine has available, with a message that says how to ask for less.
use crate::error::{Error, Result};

const GIB: f64 = 1024.0 * 1024.0 * 1024.0;

/// Refuse outputs that would need more memory than this, whatever the machine has.
pub const MAX_OUTPUT_BYTES: f64 = 8.0 * GIB;

/// Below this a request is never refused (it is not worth reading the machine's state).
const SMALL: f64 = 64.0 * 1024.0 * 1024.0;

/// Bytes per output row of an N-link run, counting everything that holds one at the same time:
/// during the run the recorder's raw state (`2N` values, the work integral and `t`); while the
/// run is finished, that and the output `theta`, `omega`, `p` (`3N`), `energy` and `work`; then
/// the output and what the Python `Solution` derives from it on request: `positions` (`2N`) and
/// the energy error (with its temporaries, 3). A batch of B runs needs B times as much.
pub fn row_bytes(n: usize) -> f64 {
    (5 * n + 6) as f64 * 8.0
}

/// Bytes the operating system can still give this process without swapping (Linux:
/// `MemAvailable` in /proc/meminfo); `None` where that is not known (other systems, wasm).
pub fn available_bytes() -> Option<f64> {
    #[cfg(target_os = "linux")]
    {
        let text = std::fs::read_to_string("/proc/meminfo").ok()?;
        let line = text.lines().find(|l| l.starts_with("MemAvailable:"))?;
        let kib: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
        Some(kib * 1024.0)
    }
    #[cfg(not(target_os = "linux"))]
    {
        None
    }
}

/// Refuse `what` (e.g. "storing 10^9 output points of 2 links") when it needs more than
/// [`MAX_OUTPUT_BYTES`] or than the machine has available; `advice` says how to ask for less.
pub fn check(bytes: f64, what: &str, advice: &str) -> Result<()> {
    if bytes <= SMALL {
        return Ok(());
    }
    let available = available_bytes();
    let limit = available.map_or(MAX_OUTPUT_BYTES, |a| a.min(MAX_OUTPUT_BYTES));
    if bytes > limit {
        let have = match available {
            Some(a) => format!("{:.1} GiB available, limit {:.0} GiB", a / GIB, MAX_OUTPUT_BYTES / GIB),
            None => format!("limit {:.0} GiB", MAX_OUTPUT_BYTES / GIB),
        };
        return Err(Error::input(format!("{what} needs {:.1} GiB ({have}); {advice}", bytes / GIB)));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn small_requests_pass_and_huge_ones_are_refused_with_advice() {
        assert!(check(1e6, "a run", "ask for less").is_ok());
        let e = check(1e12, "storing 10^10 output points of 2 links", "ask for fewer with t_eval").unwrap_err();
        let m = e.to_string();
        assert!(m.starts_with("storing 10^10 output points of 2 links needs 931.3 GiB ("), "{m}");
        assert!(m.ends_with("); ask for fewer with t_eval"), "{m}");
    }

    #[test]
    fn the_machine_reports_some_memory_on_linux() {
        if cfg!(target_os = "linux") {
            assert!(available_bytes().is_some_and(|a| a > 0.0));
        }
    }
}
