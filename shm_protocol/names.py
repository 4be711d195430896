"""Segment names: validation, the per-slot names of a vector env, the camera segment's name.

A segment named ``rl_observation`` is the file ``/dev/shm/rl_observation``; it is the same
object Python's ``SharedMemory(name="rl_observation")`` opens, so seed-style peers find it.
"""

from __future__ import annotations

import os
import re

from .errors import InvalidNameError

SHM_DIR = "/dev/shm"
"""Where POSIX shared memory lives on Linux (``shm_open`` names are files here)."""

DEFAULT_NAME = "rl_observation"
"""The seed's segment base name (``rl_obs_name='rl_observation'``), used by every CLI."""

NAME_ENV_VAR = "ROVERAV_SHM_NAME"
"""Set by ``rover-pair`` for its trainer: the daemon's segment base name."""

SLOTS_ENV_VAR = "ROVERAV_SLOTS"
"""Set by ``rover-pair`` for its trainer: how many slots the daemon serves."""

MAX_NAME_LENGTH = 128
"""Longest accepted name. NAME_MAX is 255; the margin leaves room for the ``_<slot>`` and
``_camera`` suffixes and for the hidden temporary name used while a segment is created."""

CAMERA_SUFFIX = "_camera"

_NAME_RE = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.\-]*")


def validate_name(name: str) -> str:
    """Return ``name`` if it can name a segment, else raise :class:`InvalidNameError`.

    Accepted: 1 to ``MAX_NAME_LENGTH`` characters from ``A-Z a-z 0-9 _ . -``, not starting
    with ``.`` or ``-`` (hidden files are this package's temporaries). No ``/``: POSIX names
    are one path component, and a leading ``/`` (the ``shm_open`` spelling) is rejected so
    that one segment has one spelling.
    """
    if not isinstance(name, str):
        raise InvalidNameError(f"segment name must be a str, got {type(name).__name__}")
    if "/" in name:
        hint = f"; use {name.lstrip('/')!r}" if name.startswith("/") and "/" not in name[1:] else ""
        raise InvalidNameError(
            f"invalid segment name {name!r}: it must not contain '/'{hint} "
            f"(the segment is the file {SHM_DIR}/<name>)"
        )
    if not 1 <= len(name) <= MAX_NAME_LENGTH:
        raise InvalidNameError(
            f"invalid segment name {name[:40]!r}{'...' if len(name) > 40 else ''}: length "
            f"{len(name)}, expected 1 to {MAX_NAME_LENGTH} characters"
        )
    if not _NAME_RE.fullmatch(name):
        bad = sorted({c for c in name if not re.fullmatch(r"[A-Za-z0-9_.\-]", c)})
        why = f"characters {bad!r} are not allowed" if bad else "it must not start with '.' or '-'"
        raise InvalidNameError(
            f"invalid segment name {name!r}: {why}; use letters, digits, '_', '.' and '-'"
        )
    return name


def slot_name(base: str, i: int) -> str:
    """Name of slot ``i`` of a daemon serving ``base``: ``base`` for 0, ``f"{base}_{i}"`` else."""
    validate_name(base)
    if isinstance(i, bool) or not isinstance(i, int) or i < 0:
        raise ValueError(f"slot index must be an int >= 0, got {i!r}")
    return base if i == 0 else validate_name(f"{base}_{i}")


def camera_name(name: str) -> str:
    """The camera input segment that pairs with fused segment ``name``: ``f"{name}_camera"``."""
    validate_name(name)
    return validate_name(f"{name}{CAMERA_SUFFIX}")


def segments_of(base: str, slots: int) -> list[str]:
    """Every segment a daemon serving ``base`` with ``slots`` slots owns: for each slot its
    fused segment, then that segment's camera segment."""
    if isinstance(slots, bool) or not isinstance(slots, int) or slots < 1:
        raise ValueError(f"slots must be an int >= 1, got {slots!r}")
    names: list[str] = []
    for i in range(slots):
        fused = slot_name(base, i)
        names += [fused, camera_name(fused)]
    return names


def existing_segments(base: str) -> list[str]:
    """The segments in :data:`SHM_DIR` that belong to base name ``base``, any slot count
    (``base``, ``base_<i>`` and their ``_camera`` twins), sorted."""
    validate_name(base)
    pattern = re.compile(rf"^{re.escape(base)}(_\d+)?({re.escape(CAMERA_SUFFIX)})?$")
    try:
        return sorted(n for n in os.listdir(SHM_DIR) if pattern.match(n))
    except FileNotFoundError:
        return []


def camera_segments() -> int:
    """How many env camera segments (``*_camera``) this machine's shared memory holds: the
    env slots of every av-daemon running here (and any a killed one left behind)."""
    try:
        return sum(1 for n in os.listdir(SHM_DIR) if n.endswith(CAMERA_SUFFIX))
    except OSError:
        return 0


def default_name() -> str:
    """``$ROVERAV_SHM_NAME`` (set by rover-pair) or :data:`DEFAULT_NAME`."""
    return os.environ.get(NAME_ENV_VAR) or DEFAULT_NAME


def default_slots() -> int:
    """``$ROVERAV_SLOTS`` (set by rover-pair) or 1."""
    text = os.environ.get(SLOTS_ENV_VAR, "")
    try:
        return max(int(text), 1) if text else 1
    except ValueError:
        return 1


def remove_segments(names: list[str] | tuple[str, ...]) -> list[str]:
    """Unlink the named segments that exist (no validation: temporaries' hidden names too);
    returns those removed."""
    removed = []
    for name in names:
        try:
            os.unlink(os.path.join(SHM_DIR, name))
            removed.append(name)
        except FileNotFoundError:
            pass
    return removed


def segment_path(name: str) -> str:
    """The file that holds segment ``name`` (validated)."""
    return os.path.join(SHM_DIR, validate_name(name))


__all__ = [
    "CAMERA_SUFFIX",
    "DEFAULT_NAME",
    "NAME_ENV_VAR",
    "SLOTS_ENV_VAR",
    "MAX_NAME_LENGTH",
    "SHM_DIR",
    "camera_name",
    "default_name",
    "default_slots",
    "existing_segments",
    "remove_segments",
    "segment_path",
    "segments_of",
    "slot_name",
    "validate_name",
]
