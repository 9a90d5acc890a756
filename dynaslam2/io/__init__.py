"""File formats: our KITTI-compatible sequences, real KITTI odometry/tracking/MOTS, results."""

from dynaslam2.io.sequence import Sequence, SequenceWriter, open_sequence
from dynaslam2.io.types import FrameData, ObjectState

__all__ = ["FrameData", "ObjectState", "Sequence", "SequenceWriter", "open_sequence"]
