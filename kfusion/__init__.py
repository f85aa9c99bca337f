"""kfusion: fuse optical motion capture with a limb-mounted IMU through occlusions."""

__version__ = "0.1.0"

# Public API for in-process use (imported on first access, so that ``import kfusion`` stays light).
_EXPORTS = {
    "Tracker": "kfusion.tracker",
    "Estimate": "kfusion.tracker",
    "Health": "kfusion.tracker",
    "PushOutcome": "kfusion.tracker",
    "TrackerOptions": "kfusion.tracker",
    "protective_separation_distance": "kfusion.safety",
    "SeparationDistance": "kfusion.safety",
}
__all__ = ["__version__", *_EXPORTS]


def __getattr__(name: str) -> object:
    if name in _EXPORTS:
        import importlib

        return getattr(importlib.import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'kfusion' has no attribute {name!r}")
