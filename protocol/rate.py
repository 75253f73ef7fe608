"""Choosing the quality level for a target bitrate, closed loop, from a sample of the call itself.

How many bits a level costs depends on the speaker, the layout and the
tracker's jitter far more than on the level alone (a factor of two between the
dev clips), so a table of typical rates misses. The sender holds its first
second anyway to find the rest face; coding that second at every level takes a
millisecond, and the finest level that fits is the choice.
"""

from collections.abc import Callable, Sequence
from dataclasses import replace

import numpy as np

from facedeform.protocol.encoder import Datagrams, PacketEncoder, stream_size
from facedeform.protocol.header import Header
from facedeform.protocol.quantise import QUALITIES
from facedeform.protocol.secure import envelope_bytes


def sample_bits_per_second(header: Header, sample: Sequence[tuple[np.ndarray, bool]], frames_per_packet: int,
                           dead_zone: float, seal_bytes: int = 0, copies: int | None = None) -> float:
    """Bit/s of ``sample`` ((k,) params, face seen) coded as a byte stream of its own under ``header``
    (without its face model or end mark: what every second of the call costs). ``seal_bytes``: what
    sealing adds to each packet (``SecureSealer.overhead``, and the envelope's length field; a sealed
    packet also takes a sync byte). ``copies``: the packets go as datagrams, each carrying that many
    packets before it again (``Datagrams``; the header's repeats for late joiners not counted)."""
    encoder = PacketEncoder(replace(header, model_size=0), frames_per_packet, dead_zone=dead_zone)
    packets = [p for params, seen in sample for p in encoder.frame(params, seen)] + encoder.end()[:-1]
    if copies is None:
        size = stream_size(packets, sealed=bool(seal_bytes))
    else:
        packets = Datagrams(b"", copies, header_every=0, eager=0).add(packets)
        size = sum(map(len, packets))
    if seal_bytes:
        size += sum(envelope_bytes(len(p), seal_bytes) for p in packets)
    return 8 * size * header.fps / len(sample)


def quality_for_bitrate(header_at: Callable[[int], Header], sample: Sequence[tuple[np.ndarray, bool]],
                        bits_per_second: float, frames_per_packet: int, dead_zone: float, seal_bytes: int = 0,
                        copies: int | None = None) -> int:
    """The finest level whose ``header_at(level)`` codes ``sample`` within ``bits_per_second``; the
    coarsest level if none does. ``copies``: as :func:`sample_bits_per_second`'s."""
    for quality in sorted(QUALITIES, reverse=True):
        if sample_bits_per_second(header_at(quality), sample, frames_per_packet, dead_zone,
                                  seal_bytes, copies) <= bits_per_second:
            return quality
    return min(QUALITIES)
