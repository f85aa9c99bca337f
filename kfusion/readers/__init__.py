"""Readers of real data formats, each returning kfusion's typed objects.

* :func:`read_motive_csv`: an OptiTrack Motive CSV export -> :class:`~kfusion.recording.MocapFrames`
  (Motive has no IMU; ``kfusion convert motive`` pairs it with an ``imu.csv``);
* :func:`read_broad`: a BROAD trial (``.mat``) -> :class:`~kfusion.recording.Recording`.

``kfusion convert`` writes either as a recording folder.
"""

from kfusion.readers.broad import read_broad
from kfusion.readers.motive import motive_rigid_bodies, read_motive_csv

__all__ = ["motive_rigid_bodies", "read_broad", "read_motive_csv"]
