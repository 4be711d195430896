"""The zoo's ``Agent`` protocol: what ``zoo.load`` returns and ``evaluate_agent`` runs.

This file is also in mypy's ``files`` (pyproject.toml), so the annotated assignments below
are checked statically, signatures included; the tests check the same at run time.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np

from rover_train import zoo
from rover_train.agents import RandomAgent


def _student() -> zoo.StudentAgent:
    spec = zoo.FeatureSpec(centre=(0.0, 0.0), scale=1.0, lidar_points=8)
    return zoo.StudentAgent(zoo.StudentNet(spec, hidden=16))


def test_a_student_agent_is_an_agent() -> None:
    agent: zoo.Agent = _student()  # mypy: StudentAgent satisfies Agent
    assert isinstance(agent, zoo.Agent)


def test_the_random_agent_is_an_agent_and_acts_in_the_space() -> None:
    space = gym.spaces.Box(
        low=np.array([-1.0, -np.pi], np.float32), high=np.array([1.0, np.pi], np.float32)
    )
    agent: zoo.Agent = RandomAgent(space, seed=0)  # mypy: RandomAgent satisfies Agent
    assert isinstance(agent, zoo.Agent)
    agent.reset()
    assert space.contains(agent.act(None))


def test_something_without_act_is_not_an_agent() -> None:
    class ResetOnly:
        def reset(self) -> None:
            return None

    assert not isinstance(ResetOnly(), zoo.Agent)
    assert not isinstance(zoo.ENTRIES, zoo.Agent)
