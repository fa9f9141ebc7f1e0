"""Reinforcement learning: the vectorized-environment protocol, networks, normalizers and PPO."""
