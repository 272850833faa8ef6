"""Learning for pursuit-mj: networks, PPO / MAPPO, training regimes, checkpoints, the study.

Uses pursuit_mj only through its public API (config, env, obs_spec, policy, evaluation).
`load_policy(path, env_spec)` turns a checkpoint into a pursuit_mj.policy.Policy; it is what
`pursuit-mj eval --model` and `render --model` import (lazily, from the command-line layer).
"""

from .config import TrainConfig, load_train_config
from .policy import load_policy

__all__ = ["TrainConfig", "load_train_config", "load_policy"]
