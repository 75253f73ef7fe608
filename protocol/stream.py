"""The stream format (one version, :data:`VERSION`): the public API in one import.

No I/O here: encoders return bytes or packets, decoders take bytes in any
chunking (byte streams) or one packet at a time (datagrams) and return events.
Pipes, files and sockets belong to the command-line tools. The format is
specified in docs/bitstream.md.
"""

from facedeform.protocol.decoder import DatagramDecoder, PacketDecoder, StreamDecoder
from facedeform.protocol.encoder import Datagrams, PacketEncoder, StreamEncoder, frame_bytes, stream_size
from facedeform.protocol.events import Damage, End, Frame, Model, Picture, Stats
from facedeform.protocol.header import VERSION, Header
from facedeform.protocol.quantise import DEFAULT_QUALITY, QUALITIES, steps_for
from facedeform.protocol.rate import RateKeeper, quality_for_bitrate

__all__ = [
    "DEFAULT_QUALITY", "QUALITIES", "VERSION", "Damage", "DatagramDecoder", "Datagrams", "End", "Frame", "Header",
    "Model", "PacketDecoder", "Picture", "PacketEncoder", "Stats", "StreamDecoder", "StreamEncoder", "frame_bytes",
    "RateKeeper", "quality_for_bitrate", "steps_for", "stream_size",
]
