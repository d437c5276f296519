"""Time stepping: sources, sensors (what is recorded inside the loop), the stateless stepper, the
scanned loop with `simulate` as its one entry point, and the adjoint-wave-equation reverse mode."""

from .loop import (
    INSTABILITY_MESSAGE,
    SPEED_MESSAGE,
    SPEED_MESSAGE_3D,
    Result,
    check_finite,
    check_result,
    check_speed,
    run,
    run_pieces,
    simulate,
)
from .scan import Joiner, grid_sharding
from .sensors import Sensors, received_signal
from .sources import (
    ContinuousWave,
    PointSources,
    ToneBurst,
    disc_housing,
    disc_transducer,
    disc_transducer_3d,
    line_transducer,
    ring_fractions,
    ring_radii_m,
    rings_from_fit_report,
)
from .stepper import LayerFields, LeapfrogState, StaggeredState, State, Stepper

__all__ = [
    "INSTABILITY_MESSAGE",
    "SPEED_MESSAGE",
    "SPEED_MESSAGE_3D",
    "ContinuousWave",
    "Joiner",
    "LayerFields",
    "LeapfrogState",
    "PointSources",
    "Result",
    "Sensors",
    "StaggeredState",
    "State",
    "Stepper",
    "ToneBurst",
    "check_finite",
    "check_result",
    "check_speed",
    "disc_housing",
    "disc_transducer",
    "disc_transducer_3d",
    "grid_sharding",
    "line_transducer",
    "received_signal",
    "ring_fractions",
    "ring_radii_m",
    "rings_from_fit_report",
    "run",
    "run_pieces",
    "simulate",
]
