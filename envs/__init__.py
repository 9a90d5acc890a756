"""Gymnasium environments that step the simulated world, feed the SLAM system and score it.

The environment itself is not built yet; this package is reserved for it (DESIGN.md: `envs/`).
"""
