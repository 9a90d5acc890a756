"""Rigid-body geometry (SO3/SE3) and the stereo camera model."""

from dynaslam2.geometry.camera import StereoCamera

__all__ = ["StereoCamera"]
