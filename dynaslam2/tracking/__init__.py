"""Camera tracking: frame construction (frontend), motion model / reference keyframe / local map
tracking (camera), relocalization."""
