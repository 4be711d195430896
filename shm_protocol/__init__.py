"""shm_protocol: frames between processes over POSIX shared memory.

One writer publishes ``(H, W, C)`` float32/uint8 frames into ``/dev/shm/<name>``; any number
of readers copy them out. The first bytes are the seed's layout (float64 timestamp, uint32
valid flag, payload), so seed-style peers interoperate; a 64-byte trailer adds a seqlock,
the source frame number, the writer's pid and heartbeat, and a futex word for waking.
See docs/protocol.md.

    w = FrameWriter("rl_observation", shape=(96, 96, 3), dtype=np.float32)
    seq = w.publish(frame, source_seq=k)
    r = FrameReader("rl_observation", attach_timeout=30.0)
    f = r.wait_for(source_seq=k, timeout=2.0)     # Frame(data, timestamp, seq, source_seq)
"""

from .errors import (
    FrameTimeoutError,
    InvalidNameError,
    LayoutError,
    NonFiniteError,
    SegmentBusyError,
    SegmentNotFoundError,
    ShmError,
    WriterGoneError,
)
from .multiwait import AVAILABLE as MULTIWAIT_AVAILABLE
from .multiwait import MultiWaiter
from .names import (
    DEFAULT_NAME,
    SHM_DIR,
    camera_name,
    default_name,
    default_slots,
    existing_segments,
    remove_segments,
    segment_path,
    segments_of,
    slot_name,
    validate_name,
)
from .reader import (
    SPIN_S,
    Frame,
    FrameReader,
    available_cores,
    machine_spin,
    spin_for,
    writer_alive,
)
from .writer import FrameWriter

__all__ = [
    "DEFAULT_NAME",
    "Frame",
    "FrameReader",
    "FrameTimeoutError",
    "FrameWriter",
    "InvalidNameError",
    "LayoutError",
    "MULTIWAIT_AVAILABLE",
    "MultiWaiter",
    "NonFiniteError",
    "SHM_DIR",
    "SPIN_S",
    "SegmentBusyError",
    "SegmentNotFoundError",
    "ShmError",
    "WriterGoneError",
    "available_cores",
    "camera_name",
    "default_name",
    "default_slots",
    "existing_segments",
    "machine_spin",
    "remove_segments",
    "segment_path",
    "segments_of",
    "slot_name",
    "spin_for",
    "validate_name",
    "writer_alive",
]
