"""``python -m active_vision``: the av-daemon (see :mod:`active_vision.daemon`)."""

from active_vision.daemon import main

if __name__ == "__main__":
    raise SystemExit(main())
