"""mocap_sim_mujoco: the MuJoCo simulator plugin (batched envs, MJCF generated from skeletons, rendering).

MuJoCo picks its OpenGL backend when it is first imported, so headless EGL rendering is selected
here, before any module of the plugin imports mujoco (a user's own ``MUJOCO_GL`` wins).
"""

import os

os.environ.setdefault("MUJOCO_GL", "egl")
