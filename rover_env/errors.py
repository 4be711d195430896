"""The exceptions the roverav envs raise for misuse a caller can act on.

Errors of the daemon link (missing segment, layout mismatch, a slot already in use, a dead
or stalled daemon) are :mod:`shm_protocol`'s; this module holds the env's own.
"""

from __future__ import annotations

from gymnasium.error import ClosedEnvironmentError


class EnvClosedError(ClosedEnvironmentError, RuntimeError):
    """``reset()``, ``step()`` or ``render()`` on an env after its ``close()``.

    A Gymnasium :class:`~gymnasium.error.ClosedEnvironmentError` (and a ``RuntimeError``), so
    code written for either catches it. A closed env has freed its renderer and detached
    from the daemon; it cannot be reopened: make a new env.
    """


def closed_env_message(env_name: str, method: str) -> str:
    """The message of :class:`EnvClosedError` for ``method`` called on a closed env."""
    return (
        f"{env_name}.{method}() called after close(): this env is closed (its renderer is "
        f"freed and, for a fused env, its daemon link is detached) and cannot be used again. "
        f"Make a new env, e.g. gymnasium.make(...) or {env_name}(...), and call reset() on it."
    )


__all__ = ["EnvClosedError", "closed_env_message"]
