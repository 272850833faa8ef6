"""PettingZoo's own conformance tests on the ParallelEnv, in both fidelities."""

import numpy as np
import pytest
from pettingzoo.test import parallel_api_test, parallel_seed_test

from pursuit_mj.config import default_config
from pursuit_mj.pz_env import PursuitParallelEnv


@pytest.mark.parametrize("fidelity", ["point", "quadrotor"])
def test_parallel_api(fidelity):
    env = PursuitParallelEnv(default_config(fidelity=fidelity, random_obstacles=2, max_steps=40))
    parallel_api_test(env, num_cycles=60)


@pytest.mark.parametrize("fidelity", ["point", "quadrotor"])
def test_parallel_seed(fidelity):
    parallel_seed_test(lambda: PursuitParallelEnv(default_config(fidelity=fidelity, random_obstacles=2, max_steps=30)), num_cycles=40)


def test_action_dict_errors_name_the_agent():
    env = PursuitParallelEnv(default_config(fidelity="point", random_obstacles=0))
    env.reset(seed=0)
    with pytest.raises(ValueError, match="missing agents \\['pursuer_2'\\]"):
        env.step({"pursuer_0": np.zeros(2), "pursuer_1": np.zeros(2)})
    with pytest.raises(ValueError, match="unknown agents \\['pursuer_9'\\]"):
        env.step({f"pursuer_{i}": np.zeros(2) for i in (0, 1, 2, 9)})
    with pytest.raises(ValueError, match="expected shape \\(2,\\)"):
        env.step({f"pursuer_{i}": np.zeros(3) for i in range(3)})
