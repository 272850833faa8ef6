"""Learning for pursuit-mj: networks, PPO / MAPPO, training regimes, checkpoints, the study.

Uses pursuit_mj through its public modules (config, configio, env, obs_spec, sensing, policy,
policies, evaluation, comparison, io_utils, recording, and the policy wrappers it trains
behind: belief, residual, shield; docs/training.md keeps the list). `load_policy(path,
env_spec)` turns a checkpoint into a pursuit_mj.policy.Policy; the command line
(`pursuit_cli`) imports it for `eval --model`, `render --model`, `demo` and `fly --model`.
Importing this package does not import torch; `load_policy` does, when first used.
"""

from .config import TrainConfig, load_train_config

__all__ = ["TrainConfig", "load_train_config", "load_policy"]


def __getattr__(name: str):
    if name == "load_policy":
        from .policy import load_policy

        return load_policy
    raise AttributeError(f"module 'train' has no attribute {name!r}")
