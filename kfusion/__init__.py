"""kfusion: fuse optical motion capture with a limb-mounted IMU through occlusions."""

__version__ = "0.1.0"
