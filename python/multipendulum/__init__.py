"""multipendulum: fast, verified simulation of planar N-link pendulums.

The physics lives in a Rust core (``multipendulum._core``); this package converts, presents and
orchestrates. Public API::

    chain = Chain(lengths, masses, com=None, inertia=None, g=9.81,  # or Chain.rods(...)
                  damping=None, friction=None, friction_velocity=1e-3, cart=None)
    sol = simulate(chain, theta0, omega0, t_end, method="dop853", ...,
                   pivot=None, cart_x0=0.0, cart_v0=0.0, cart_force=None)
"""

import typing as _typing

from . import _core
from ._base import Cart, Pivot
from ._chain import Chain
from ._dataset import Dataset, load_dataset, make_dataset, read_dataset_config
from ._fit import FitResult, fit
from ._simulate import DEFAULTS, METHOD_INFO, METHODS, SENSITIVITIES, Crossing, Event, EventRecord, Flip, Solution, Stats, Work, resume, simulate
from ._torque import Sinusoid, Table
from .checkpoint import load_checkpoint
from .chaos import EnsembleResult, FlipMap, LyapunovResult, ensemble, PoincareSection, plot_poincare, poincare, flip_energy_threshold, flip_map, flip_times, certified_flip_times, lyapunov, trustworthy_until
from .chaos import FlipVolume, flip_volume
from .chaos import CHAOS_RULES, INDICATORS, IndicatorMap, IndicatorResult, certified_indicator, fli, gali, indicator, indicator_map, megno, sali
from .chaos import ZeroOneResult, zero_one_test
from .errors import InputError, IntegrationError
from .modes import NormalModes, linearize, normal_modes
from .sweeps import open_flip_map, open_flip_volume, open_indicator_map, sweep, sweep_flip_map, sweep_flip_volume, sweep_indicator_map

#: The package's version: the compiled core's (the workspace's, kept equal to pyproject's), right
#: also when the package is imported from a source tree without install metadata (bench/.venv does so).
__version__ = _core.__version__

__all__ = [
    "Chain", "Cart", "Pivot", "Work", "simulate", "resume", "load_checkpoint", "Solution", "Stats", "Flip", "Crossing", "Event", "EventRecord", "METHODS", "METHOD_INFO", "SENSITIVITIES", "fit", "FitResult", "Sinusoid", "Table",
    "InputError", "IntegrationError", "__version__",
    "normal_modes", "NormalModes", "linearize", "animate_mode", "plot_modes",
    "sweep", "sweep_flip_map", "open_flip_map", "plot_flip_map",
    "flip_volume", "FlipVolume", "sweep_flip_volume", "open_flip_volume", "plot_flip_volume",
    "sweep_indicator_map", "open_indicator_map", "plot_indicator_map",
    "ensemble", "EnsembleResult", "poincare", "PoincareSection", "plot_poincare", "lyapunov", "LyapunovResult", "trustworthy_until", "flip_energy_threshold", "flip_times", "certified_flip_times", "flip_map", "FlipMap",
    "INDICATORS", "CHAOS_RULES", "indicator", "certified_indicator", "IndicatorResult", "megno", "fli", "sali", "gali", "indicator_map", "IndicatorMap",
    "zero_one_test", "ZeroOneResult",
    "make_dataset", "load_dataset", "read_dataset_config", "Dataset",
]


def __getattr__(name: str) -> _typing.Any:
    # Presentation layers import Matplotlib; load them only when asked for.
    lazy = {
        "animate": ("animation", "animate"),
        "animate_mode": ("modes", "animate_mode"),
        "plot_modes": ("modes", "plot_modes"),
        "plot_flip_map": ("fractal", "plot_flip_map"),
        "plot_flip_volume": ("fractal", "plot_flip_volume"),
        "plot_indicator_map": ("fractal", "plot_indicator_map"),
        "plot": ("plotting", "plot"),
        "save_results": ("results", "save_results"),
        "load_results": ("results", "load_results"),
        "load_scenario": ("scenario", "load_scenario"),
        "loads_scenario": ("scenario", "loads_scenario"),
        "ScenarioError": ("scenario", "ScenarioError"),
        "Results": ("results", "Results"),
        # Notebook widgets need anywidget (the `widget` extra); without it these raise an
        # ImportError saying how to install it.
        "widget": ("notebook", "widget"),
        "show": ("_notebook", "show"),
    }
    if name in lazy:
        import importlib

        mod, attr = lazy[name]
        return getattr(importlib.import_module(f".{mod}", __name__), attr)
    raise AttributeError(f"module 'multipendulum' has no attribute {name!r}")
