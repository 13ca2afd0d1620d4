"""The camera's test pattern: a 32-bit LFSR bit stream, generated with numpy, and one frame per sequence number.

Definition (what a subscriber in any language needs to regenerate a frame):

* The bit stream b0, b1, b2, ... obeys the linear recurrence ``b[n+32] = b[n+22] ^ b[n+2] ^ b[n+1] ^ b[n]``, whose
  characteristic polynomial x^32 + x^22 + x^2 + x + 1 is primitive over GF(2): every non-zero start repeats only
  after 2^32 - 1 bits. ``tests/test_camera.py`` checks the primitivity.
* As a Fibonacci register: the 32-bit state holds b[n] .. b[n+31] (bit j = b[n+j]); one step outputs bit 0 and
  shifts in ``parity(state & TAPS) << 31``. The stream starts from the state ``SEED`` (bits b0 .. b31).
* Byte k of the stream is b[8k] .. b[8k+7], least significant bit first. Equivalently, the little-endian 32-bit
  word m of the stream is the register's state after 32*m steps.
* The frame with sequence number s is the ``size`` bytes of the stream starting at byte ``frame_offset(s)`` =
  ``(s * OFFSET_STRIDE) % OFFSET_PERIOD``: its seed is the register's state after 8 * frame_offset(s) steps.
  Consecutive frames are therefore different byte-shifted windows of one stream, and a frame delivered under
  another sequence number (or mixed with another frame) does not match.

Speed: a frame is never computed per bit, nor per frame. :class:`FramePattern` generates ``size + OFFSET_PERIOD``
bytes of the stream once (a few milliseconds for 4 MiB) and each frame is a slice of it: no work at all to produce
a frame, one ``memcmp`` to verify one. The one-off generation is vectorised with the squaring identity of GF(2)
polynomials: p(x)^D = p(x^D) for D a power of two, so ``b[n+32D] = b[n+22D] ^ b[n+2D] ^ b[n+D] ^ b[n]``. With
D = 32d, d a power of two, whole 32-bit words obey ``w[m] = w[m-10d] ^ w[m-30d] ^ w[m-31d] ^ w[m-32d]``, and the
10d words after the first 32d known ones follow from those in three numpy XORs. Each round picks the largest d
the known prefix allows, so the prefix grows geometrically from the 32 words that the register computes one bit
at a time.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

TAPS = (1 << 22) | (1 << 2) | (1 << 1) | 1  # b[n+32] = b[n+22] ^ b[n+2] ^ b[n+1] ^ b[n]
SEED = 0xACE1_2468  # any non-zero state
OFFSET_PERIOD = 65_521  # largest prime below 2^16: frames repeat their pattern only every 65521 sequence numbers
OFFSET_STRIDE = 4_099  # coprime with the period; consecutive frames start far apart in the stream
_BOOTSTRAP_WORDS = 32


def step(state: int) -> tuple[int, int]:
    """One step of the register: (output bit, next state). The reference definition; far too slow for frames."""
    feedback = bin(state & TAPS).count("1") & 1
    return state & 1, (state >> 1) | (feedback << 31)


def stream_words(count: int, seed: int = SEED) -> npt.NDArray[np.uint32]:
    """The first ``count`` little-endian 32-bit words of the stream started from ``seed``."""
    if not 0 < seed < 1 << 32:
        raise ValueError(f"LFSR seed {seed:#x} must be a non-zero 32-bit value")
    words = np.empty(max(count, _BOOTSTRAP_WORDS), dtype=np.uint32)
    state = seed
    for index in range(_BOOTSTRAP_WORDS):  # 1024 register steps: the only per-bit work
        words[index] = state
        for _ in range(32):
            _, state = step(state)
    known = _BOOTSTRAP_WORDS
    while known < count:
        d = 1 << ((known // 32).bit_length() - 1)  # largest power of two with 32 * d <= known
        new = min(10 * d, count - known)
        end = known + new
        block = words[known - 10 * d:end - 10 * d] ^ words[known - 30 * d:end - 30 * d]
        block ^= words[known - 31 * d:end - 31 * d]
        block ^= words[known - 32 * d:end - 32 * d]
        words[known:end] = block
        known = end
    return words[:count]


def stream_bytes(count: int, seed: int = SEED) -> bytes:
    """The first ``count`` bytes of the stream started from ``seed``."""
    words = stream_words((count + 3) // 4, seed)
    return words.astype("<u4", copy=False).tobytes()[:count]


def frame_offset(seqnum: int) -> int:
    """Where in the stream the frame with this sequence number starts (bytes)."""
    return (seqnum * OFFSET_STRIDE) % OFFSET_PERIOD


class FramePattern:
    """All frames of one size: one generated stream, each frame a window of it."""

    def __init__(self, size: int, seed: int = SEED):
        if size < 0:
            raise ValueError(f"frame size {size} must not be negative")
        self.size = size
        self.stream = stream_bytes(size + OFFSET_PERIOD, seed)
        self._view = memoryview(self.stream)

    def offset(self, seqnum: int) -> int:
        """Where in :attr:`stream` the frame with this sequence number starts."""
        return frame_offset(seqnum)

    def frame(self, seqnum: int) -> memoryview:
        """The frame's bytes, without a copy."""
        offset = frame_offset(seqnum)
        return self._view[offset:offset + self.size]

    def matches(self, seqnum: int, data: bytes | bytearray | memoryview) -> bool:
        """True when ``data`` is exactly this frame. One memcmp in C: bytes.startswith at an offset copies nothing."""
        return len(data) == self.size and self.stream.startswith(data, frame_offset(seqnum))

    def mismatched_bytes(self, seqnum: int, data: bytes | bytearray | memoryview) -> int:
        """How many bytes differ from the frame (a frame of the wrong size counts every expected byte)."""
        if len(data) != self.size:
            return self.size
        received = np.frombuffer(data, dtype=np.uint8)
        expected = np.frombuffer(self.frame(seqnum), dtype=np.uint8)
        return int(np.count_nonzero(received != expected))
