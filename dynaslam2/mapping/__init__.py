"""Keyframe insertion and local mapping (triangulation, fusion, culling, local BA)."""
