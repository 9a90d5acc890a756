"""ORB features, stereo/RGB-D depth for keypoints, descriptor matching (ORB-SLAM2's front end)."""

from dynaslam2.features.matcher import (
    hamming_distance,
    hamming_indexed,
    hamming_pairs,
    match_descriptors,
    rotation_consistent,
    search_by_projection,
    unique_by_distance,
)
from dynaslam2.features.orb import Keypoints, ORBExtractor, to_gray
from dynaslam2.features.stereo import depth_from_image, match_stereo

__all__ = [
    "Keypoints",
    "ORBExtractor",
    "depth_from_image",
    "hamming_distance",
    "hamming_indexed",
    "hamming_pairs",
    "match_descriptors",
    "match_stereo",
    "rotation_consistent",
    "search_by_projection",
    "to_gray",
    "unique_by_distance",
]
