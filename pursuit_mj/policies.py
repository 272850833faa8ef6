"""Hand-made policies by name, so that eval, render and flights pick them the same way.

Trained models are loaded by `train.load_policy`; the simulator never imports `train/`, so
the command line (`pursuit_cli/common.py: load_model`) does that.
"""

from __future__ import annotations

import re

import numpy as np

from .config import TaskConfig
from .heuristic import HeuristicTeam
from .policy import Policy, RandomPolicy
from .policy_file import is_policy_file, load_policy_file

POLICY_NAMES = ("heuristic", "random")
#: the labels eval gives the built-in teams' rows, which a policy of one's own may not take
BUILTIN_LABEL = re.compile(rf"({'|'.join(POLICY_NAMES)})(\+shield)?(#\d+)?")


def make_policy(name: str, config: TaskConfig, seed: int = 0, source: str = "make_policy name") -> Policy:
    """A hand-made team by name ('heuristic' or 'random') for `config`, or a policy of one's own
    by FILE.py:NAME (pursuit_mj.policy_file); ValueError names `source` (where `name` came from:
    a command passes its flag, '--policy'), or make_policy for a config that is no TaskConfig or a
    seed that is no integer.

    `seed` (a command's --seed) goes to a policy file's NAME(config, seed). The built-in teams
    draw nothing from it: the random team's draws follow from each episode's own observations
    and steps (RandomPolicy with its stream 0), so an episode of any eval table replays by its
    episode seed alone (render --episode-seed), whatever --seed the replay is given."""
    if not isinstance(config, TaskConfig):
        raise ValueError(f"make_policy: config: expected a TaskConfig, got {type(config).__name__}")
    if isinstance(seed, (bool, np.bool_)) or not isinstance(seed, (int, np.integer)):
        raise ValueError(f"make_policy: seed: expected an integer, got {seed!r}")
    if is_policy_file(name):
        policy = load_policy_file(name, config, seed, source)
        if BUILTIN_LABEL.fullmatch(policy.name.strip()):
            raise ValueError(f"{source} {name}: the policy it gives is named {policy.name!r}, as a built-in team's rows are "
                             f"labelled ({', '.join(POLICY_NAMES)}, +shield, #2): tables, --versus and the pairing with "
                             f"heuristic would take it for that team; give it a name of its own")
        return policy
    if name == "heuristic":
        return HeuristicTeam.from_config(config)
    if name == "random":
        return RandomPolicy(0)  # not `seed`: the table seed already chose the episodes
    raise ValueError(f"{source} {name!r}: unknown policy (valid: {', '.join(POLICY_NAMES)}, or FILE.py:NAME "
                     f"for one of your own; trained models go through --model FILE)")
