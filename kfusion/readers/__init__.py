"""Readers of real data formats, each returning kfusion's typed objects.

* :func:`read_motive_csv`: an OptiTrack Motive CSV export -> :class:`~kfusion.recording.MocapFrames`
  (Motive has no IMU; ``kfusion convert motive`` pairs it with an ``imu.csv``), and
  :func:`read_motive_markers`: its ``Marker`` columns -> :class:`~kfusion.recording.MarkerFrames`;
* :func:`read_c3d_markers`: named markers of a C3D file (needs ezc3d: ``kfusion[c3d]``), and
  :func:`write_c3d_markers`, its inverse;
* :func:`read_broad`: a BROAD trial (``.mat``) -> :class:`~kfusion.recording.Recording`.

``kfusion convert`` writes any of them as a recording folder.
"""

from kfusion.readers.broad import read_broad
from kfusion.readers.c3d import read_c3d_markers, write_c3d_markers
from kfusion.readers.motive import motive_rigid_bodies, read_motive_csv, read_motive_markers

__all__ = ["motive_rigid_bodies", "read_broad", "read_c3d_markers", "read_motive_csv",
           "read_motive_markers", "write_c3d_markers"]
