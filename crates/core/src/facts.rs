//! What the core states about itself, for the bindings to publish as they are (Python's
//! `METHOD_INFO`, scenario validation, the viewer, the fuzz targets): no other layer restates a
//! method list, a default or a limit.
use crate::dynamics::system::Form;
use crate::integrators::Method;
use crate::run::simulate::defaults;

/// One method's facts, as the bindings publish them.
#[derive(Debug, Clone, PartialEq)]
pub struct MethodFacts {
    pub name: &'static str,
    pub order: u32,
    pub symplectic: bool,
    /// When the symplecticity holds (empty for the other methods): losses make the flow itself
    /// contract phase space, and no one-step map of it is symplectic.
    pub symplectic_when: &'static str,
    pub implicit: bool,
    pub adaptive: bool,
    /// Whether a run needs `dt` (else it is the optional first step).
    pub needs_dt: bool,
    /// The forms it integrates; the first is its default.
    pub forms: Vec<&'static str>,
}

/// The condition of the symplectic methods' symplecticity.
pub const SYMPLECTIC_WHEN: &str =
    "on conservative chains (no damping or friction; torques and a moving pivot are allowed): with losses they stay of their order but are no longer symplectic";

pub fn methods() -> Vec<MethodFacts> {
    Method::ALL
        .into_iter()
        .map(|m| {
            let f = m.facts();
            MethodFacts {
                name: m.name(),
                order: f.order,
                symplectic: f.symplectic,
                symplectic_when: if f.symplectic { SYMPLECTIC_WHEN } else { "" },
                implicit: f.implicit,
                adaptive: f.adaptive,
                needs_dt: m.needs_dt(),
                forms: m.forms().iter().map(|f| f.name()).collect(),
            }
        })
        .collect()
}

/// A default or a limit: a name, its value, what it is.
pub type Fact = (&'static str, f64, &'static str);

/// The defaults of a run.
pub fn defaults() -> Vec<Fact> {
    vec![
        ("rtol", defaults::RTOL, "relative tolerance of the adaptive method"),
        ("atol", defaults::ATOL, "absolute tolerance of the adaptive method"),
        ("max_steps", defaults::MAX_STEPS as f64, "steps (accepted and rejected) a run may take"),
    ]
}

/// The default method's name.
pub fn default_method() -> &'static str {
    defaults::METHOD.name()
}

/// The most links the browser's viewer draws and runs at an interactive rate (the page, the
/// notebook widget and its playback of a solution refuse longer chains and say so).
pub const VIEWER_MAX_LINKS: usize = 100;

/// The limits on input: the core enforces them, and every layer reads them from here (the
/// viewer's too).
pub fn limits() -> Vec<Fact> {
    vec![
        ("min_rtol", defaults::MIN_RTOL, "the smallest rtol accepted"),
        ("min_atol", 0.0, "the smallest atol accepted"),
        ("max_angle", crate::model::MAX_STATE, "the largest |angle| (rad) a state may hold"),
        ("max_output_bytes", crate::memory::MAX_OUTPUT_BYTES, "the most memory an output may take"),
        ("max_chaos_steps", crate::chaos::MAX_STEPS, "the most steps per trajectory of the chaos kernels"),
        ("viewer_max_links", VIEWER_MAX_LINKS as f64, "the most links the browser viewer and the notebook widget show"),
    ]
}

/// The routes to the accelerations and the most links each takes (`None`: any).
pub fn algorithms() -> Vec<(&'static str, Option<usize>)> {
    crate::dynamics::reference::Algorithm::ALL.iter().map(|a| (a.name(), a.max_links())).collect()
}

/// The forms' names, in order.
pub fn forms() -> Vec<&'static str> {
    Form::ALL.iter().map(|f| f.name()).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::integrators::{AnyIntegrator, Integrator};

    #[test]
    fn each_methods_facts_are_its_integrators() {
        for m in Method::ALL {
            assert_eq!(AnyIntegrator::new(m, 4, 1e-10, 1e-12).facts(), m.facts(), "{}", m.name());
        }
        let by_name: Vec<_> = methods().into_iter().map(|f| (f.name, f.implicit, f.symplectic, f.needs_dt)).collect();
        assert_eq!(by_name, vec![("rk4", false, false, true), ("dop853", false, false, false), ("gauss4", true, true, true), ("gauss6", true, true, true)]);
    }
}
