"""Motion-capture files in: C3D and CSV readers, marker maps, labelling of point clouds.

A recording (:class:`~identification.data.mocap.recording.MarkerRecording`) is what a
file holds: frame times and marker positions in metres, NaN where a marker was not
seen, with labels or as an unlabelled point cloud per frame. The importer
(:mod:`identification.data.mocap.importer`) turns recordings into end caps of a robot
and writes the public dataset format.
"""

from identification.data.mocap.formats import read_recording
from identification.data.mocap.recording import MarkerRecording

__all__ = ["MarkerRecording", "read_recording"]
