"""DynaSLAM II: stereo / RGB-D SLAM with tightly-coupled multi-object tracking."""

__version__ = "0.1.0"
