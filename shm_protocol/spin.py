"""Sleep, then spin: waking for a frame without paying the futex wake-up.

A futex wake-up costs about 50-100 us on a VM (the sleeping vCPU halts; the waker's IPI
brings it back), once on each side of a fused env step: the daemon waking for the camera
frame and the env waking for the fused frame. Spinning on the wake word instead sees a
publish within a microsecond, but a plain "spin N us, then sleep" does not help here: the
frames come every 1-3 ms (the env's physics + render, the daemon's network), far beyond
any spin cheap enough to keep.

So a :class:`SpinPlan` learns how long this reader's waits last (an average of the recent
ones) and, for the next wait, sleeps on the futex until ``spin`` before the frame is due,
then spins (looking at the wake word, yielding the core on every turn) until ``spin``
after. A frame that comes early still wakes the sleeper by the futex, as before; one that
comes later than the spin window costs the spin and then the ordinary futex sleep. Each
wait spins at most ``2 x spin``, so an idle reader (no frames coming) spins once per call
and then sleeps: its CPU stays near zero.

The budget is ``spin_us`` where a caller passes one, else the environment variable
``ROVERAV_SPIN_US`` (:data:`SPIN_ENV`), else :data:`DEFAULT_SPIN_US`; 0 turns spinning off
(the plain futex wait with short timeouts, the behaviour before this module).
"""

from __future__ import annotations

import os

SPIN_ENV = "ROVERAV_SPIN_US"
"""Environment variable: spin budget in microseconds for readers that are not given one."""
DEFAULT_SPIN_US = 200.0
"""Spin budget when neither the caller nor ``ROVERAV_SPIN_US`` gives one."""
MAX_SPIN_US = 100_000.0
_LEARN = 0.2  # weight of the newest wait in the running estimate
_IDLE_S = 0.1  # waits longer than this are idle gaps (an episode reset, no env), not learnt


def spin_budget_us(spin_us: float | None = None) -> float:
    """The spin budget in microseconds: ``spin_us``, else ``$ROVERAV_SPIN_US``, else
    :data:`DEFAULT_SPIN_US`.

    :raises ValueError: a negative or non-numeric budget (naming where it came from).
    """
    where = "spin_us"
    if spin_us is None:
        text = os.environ.get(SPIN_ENV, "").strip()
        if not text:
            return DEFAULT_SPIN_US
        where = f"${SPIN_ENV}"
        try:
            spin_us = float(text)
        except ValueError:
            raise ValueError(f"{where} must be a number of microseconds (0: no spinning), "
                             f"got {text!r}") from None
    if not 0.0 <= spin_us <= MAX_SPIN_US:
        raise ValueError(f"{where} must be in 0..{MAX_SPIN_US:g} microseconds (0: no "
                         f"spinning), got {spin_us!r}")
    return float(spin_us)


class SpinPlan:
    """When one waiter sleeps and when it spins (see the module docstring).

    ``sleep_s(waited)`` says how long to sleep on the futex before spinning, given the
    seconds already waited; ``spin_end(now, waited)`` where the spin stops
    (``time.perf_counter()`` time); ``learn(waited)`` takes the length of a wait that
    ended with a frame. Nothing is allocated per call.
    """

    __slots__ = ("spin_s", "expected_s")

    def __init__(self, spin_us: float) -> None:
        self.spin_s = spin_us * 1e-6
        self.expected_s = 0.0
        """Running estimate of a wait's length (0: nothing learnt yet: spin at once)."""

    def sleep_s(self, waited: float) -> float:
        return self.expected_s - self.spin_s - waited

    def spin_end(self, now: float, waited: float) -> float:
        return now + max(self.expected_s + self.spin_s - waited, self.spin_s)

    def learn(self, waited: float) -> None:
        if waited > _IDLE_S:
            return
        e = self.expected_s
        if e == 0.0:
            self.expected_s = waited
        else:  # an outlier moves the estimate by at most a fraction of (estimate + spin)
            self.expected_s = e + _LEARN * (min(waited, 2.0 * e + self.spin_s) - e)


__all__ = ["DEFAULT_SPIN_US", "SPIN_ENV", "SpinPlan", "spin_budget_us"]
