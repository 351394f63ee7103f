"""Many unsigned MAVLink 2 frames in one compiled call: the framing of
:func:`protocols.mavlink.fast.pack_payload`, byte for byte, over a table of payloads.

A simulator tick sends a few hundred telemetry frames; framed one by one in Python (a header, the
trailing zeros cut, a CRC), that was a quarter of the simulator's time at 100 vehicles.
:func:`frame_many` frames them all: frame ``k`` is the payload ``payloads[starts[k]:starts[k] +
sizes[k]]`` (the message's full payload, its fields in wire order) of message ``msg_ids[k]``
(CRC_EXTRA ``crc_extras[k]``) from system ``sysids[k]``, component ``compids[k]`` with sequence
number ``seqs[k]``: trailing zero bytes of the payload cut (one kept), as MAVLink 2 sends it,
then the header before it and the checksum (CRC-16/MCRF4XX over the header after the magic byte
and the payload, then CRC_EXTRA) after. Pure and I/O-free; unsigned frames only (a signing codec's
frames go through pymavlink).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from protocols.runtime.compiled import jit

_MAGIC_V2 = 0xFD
#: header (10 bytes) and checksum (2) around a payload
OVERHEAD = 12


@jit(inline="always")
def _crc_step(crc, byte):  # type: ignore[no-untyped-def]
    """CRC-16/MCRF4XX (X.25) of one more byte."""
    tmp = (byte ^ (crc & 0xFF)) & 0xFF
    tmp = (tmp ^ (tmp << 4)) & 0xFF
    return ((crc >> 8) ^ (tmp << 8) ^ (tmp << 3) ^ (tmp >> 4)) & 0xFFFF


@jit
def frame_many(  # type: ignore[no-untyped-def]
    payloads, starts, sizes, msg_ids, crc_extras, seqs, sysids, compids, out, ends
):  # fmt: skip
    """Frame every payload (module doc) into ``out`` back to back; frame ``k`` ends at
    ``ends[k]``. ``out`` must hold ``sizes.sum() + OVERHEAD * len(sizes)`` bytes. Returns the
    bytes written."""
    at = 0
    for k in range(sizes.shape[0]):
        s = starts[k]
        n = sizes[k]
        while n > 1 and payloads[s + n - 1] == 0:
            n -= 1
        m = msg_ids[k]
        out[at] = _MAGIC_V2
        out[at + 1] = n
        out[at + 2] = 0
        out[at + 3] = 0
        out[at + 4] = seqs[k]
        out[at + 5] = sysids[k]
        out[at + 6] = compids[k]
        out[at + 7] = m & 0xFF
        out[at + 8] = (m >> 8) & 0xFF
        out[at + 9] = (m >> 16) & 0xFF
        for b in range(n):
            out[at + 10 + b] = payloads[s + b]
        crc = 0xFFFF
        for b in range(at + 1, at + 10 + n):
            crc = _crc_step(crc, out[b])
        crc = _crc_step(crc, crc_extras[k])
        out[at + 10 + n] = crc & 0xFF
        out[at + 11 + n] = crc >> 8
        at += OVERHEAD + n
        ends[k] = at
    return at


def frames_of(
    payloads: npt.NDArray[np.uint8],
    starts: npt.NDArray[np.int64],
    sizes: npt.NDArray[np.int64],
    msg_ids: npt.NDArray[np.int64],
    crc_extras: npt.NDArray[np.int64],
    seqs: npt.NDArray[np.int64],
    sysids: npt.NDArray[np.int64],
    compids: npt.NDArray[np.int64],
) -> tuple[bytes, list[int]]:
    """:func:`frame_many` into a new buffer: its bytes and where each frame ends."""
    out = np.empty(int(sizes.sum()) + OVERHEAD * sizes.shape[0], dtype=np.uint8)
    ends = np.empty(sizes.shape[0], dtype=np.int64)
    used = frame_many(payloads, starts, sizes, msg_ids, crc_extras, seqs, sysids, compids, out,
                      ends)  # fmt: skip
    return out[:used].tobytes(), ends.tolist()
