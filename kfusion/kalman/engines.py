"""Engine names (light: no numba import). ``compiled``: the numba kernels of
:mod:`kfusion.kalman.compiled`; ``filterpy``: :class:`kfusion.kalman.KalmanFusion` on filterpy,
the readable reference."""

from __future__ import annotations

from typing import Final

ENGINES: Final = ("compiled", "filterpy")
DEFAULT_ENGINE: Final = "compiled"
