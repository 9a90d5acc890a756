"""The package versions recorded with every output (a sequence's meta.json, a run's run.json)."""

from __future__ import annotations

import cv2
import numpy as np

from dynaslam2 import __version__


def package_versions(**extra: str) -> dict[str, str]:
    """dynaslam2's, numpy's and OpenCV's versions, which shape every output, with the caller's `extra` entries
    (name -> version), sorted by name."""
    return dict(sorted({"dynaslam2": __version__, "numpy": np.__version__, "opencv": cv2.__version__,
                        **extra}.items()))
