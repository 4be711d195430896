"""launch.restart_policy: the windowed start limit and its backoff, on a simulated clock."""

from __future__ import annotations

import math

import pytest

from launch.restart_policy import RestartPolicy


def test_crashes_slower_than_the_window_are_restarted_forever() -> None:
    policy = RestartPolicy(max_restarts=5, window=60.0)
    for hour in range(100):  # a crash an hour for 100 hours
        decision = policy.on_crash(3600.0 * hour)
        assert decision.restart and decision.recent == 1 and decision.delay == 0.5
    assert policy.total == 100


def test_a_sixth_crash_within_the_window_is_a_crash_loop() -> None:
    policy = RestartPolicy(max_restarts=5, window=60.0)
    delays = [policy.on_crash(t) for t in (0.0, 10.0, 20.0, 30.0, 40.0)]
    assert [d.delay for d in delays] == [0.5, 1.0, 2.0, 4.0, 8.0]
    assert all(d.restart for d in delays)
    loop = policy.on_crash(50.0)
    assert not loop.restart and loop.recent == 6 and loop.total == 6


def test_backoff_resets_after_a_healthy_window() -> None:
    policy = RestartPolicy(max_restarts=5, window=60.0, backoff=1.0, backoff_cap=3.0)
    assert [policy.on_crash(t).delay for t in (0.0, 1.0, 2.0)] == [1.0, 2.0, 3.0]  # capped
    assert policy.recent(62.5) == 0  # a healthy minute later, the window is empty
    after = policy.on_crash(63.0)
    assert after.restart and after.delay == 1.0 and after.total == 4


def test_zero_restarts_and_an_infinite_window() -> None:
    assert not RestartPolicy(max_restarts=0).on_crash(0.0).restart
    budget = RestartPolicy(max_restarts=2, window=math.inf)
    assert budget.on_crash(0.0).restart and budget.on_crash(1e6).restart
    assert not budget.on_crash(2e6).restart
    assert "per run" in budget.describe()


@pytest.mark.parametrize(("kwargs", "fragment"),
                         [({"max_restarts": -1}, "0 or more"), ({"window": 0.0}, "positive")])
def test_bad_limits_are_named(kwargs: dict[str, float], fragment: str) -> None:
    with pytest.raises(ValueError, match=fragment):
        RestartPolicy(**kwargs)  # type: ignore[arg-type]
