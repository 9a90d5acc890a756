"""gtsam optimizations (the only package importing gtsam): pose-only and local bundle adjustment."""

from dynaslam2.optim.local_ba import BAProblem, BAResult, local_bundle_adjustment
from dynaslam2.optim.pose_only import optimize_pose

__all__ = ["BAProblem", "BAResult", "local_bundle_adjustment", "optimize_pose"]
