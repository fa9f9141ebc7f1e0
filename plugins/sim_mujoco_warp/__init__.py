"""mocap_sim_mujoco_warp: the ``mujoco_warp`` simulator plugin (MuJoCo Warp, GPU or Warp's CPU device).

Importing this package never imports ``warp`` or ``mujoco_warp``: the plugin registers without
them, and building the simulator without them raises :class:`~mocap_sim_mujoco_warp.simulator.MissingMujocoWarp`
("simulator 'mujoco_warp' needs MuJoCo Warp: pip install 'mocap[warp]'").
"""
