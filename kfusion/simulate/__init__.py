"""Seeded simulator: the paper's forearm scenarios as recordings with ground truth.

Example::

    from kfusion.simulate import OcclusionSpec, simulate
    sim = simulate("arm_lift", seed=1, occlusions=OcclusionSpec(placement="mid_motion"))
    sim.recording  # what an estimator sees: IMU at 200 Hz, mocap at 100 Hz with NaN gaps
    sim.truth      # true position at the mocap times, the occluded mask, dense IMU truth

Modules: :mod:`~kfusion.simulate.trajectories` (smooth curves with exact derivatives),
:mod:`~kfusion.simulate.scenarios` (arm_lift, circle, pick_tool, random_reach),
:mod:`~kfusion.simulate.imu` and :mod:`~kfusion.simulate.mocap` (sensor error models),
:mod:`~kfusion.simulate.occlusions` (gap lengths and placement),
:mod:`~kfusion.simulate.simulation` (:func:`simulate`) and :mod:`~kfusion.simulate.files`
(``truth.csv``).
"""

from kfusion.simulate.files import read_truth, write_simulation
from kfusion.simulate.imu import TYPICAL_UNMODELLED, UnmodelledErrors
from kfusion.simulate.markers import MarkerSpec
from kfusion.simulate.occlusions import PLACEMENTS, OcclusionSpec
from kfusion.simulate.simulation import SCENARIOS, Simulation, Truth, simulate

__all__ = [
    "PLACEMENTS",
    "SCENARIOS",
    "TYPICAL_UNMODELLED",
    "MarkerSpec",
    "OcclusionSpec",
    "Simulation",
    "Truth",
    "UnmodelledErrors",
    "read_truth",
    "simulate",
    "write_simulation",
]
