"""mocap_sim_mujoco: the MuJoCo simulator plugin (batched envs, MJCF generated from skeletons, rendering)."""
