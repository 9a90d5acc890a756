"""MuJoCo street world: scenarios, procedural textures, kinematic traffic, stereo rig.

`MUJOCO_GL` defaults to `egl` (headless CPU/GPU rendering) and is set here, before any module of
this package imports mujoco.
"""

import os

os.environ.setdefault("MUJOCO_GL", "egl")
