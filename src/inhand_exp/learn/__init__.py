"""Learners: PPO (mid level); DDPG and search baselines and evaluation come later."""
