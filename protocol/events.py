"""What a decoder hands to its caller."""

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class Frame:
    """One output frame; ``params`` (k,) float64 in the header's layout, dequantised.

    concealed: not received, the last good frame held (or the neutral face before any);
    interpolated: between two sent frames of a stream with a frame-rate divisor.
    """

    seq: int
    params: np.ndarray
    face_seen: bool
    concealed: bool = False
    interpolated: bool = False


@dataclass(frozen=True)
class Model:
    """The face model bytes carried in-band after the header (their own format, see codec/);
    ``preview``: a preview face's (the header's ``preview_size``), to draw until the model has come."""

    data: bytes
    preview: bool = False


@dataclass(frozen=True)
class Picture:
    """The picture layer's payload for frame ``seq`` (its own format: codec/render/frame_video.py)."""

    seq: int
    data: bytes


@dataclass(frozen=True)
class Damage:
    """Frames from ``seq`` on are lost until the next keyframe; ``reason`` is one line for the user."""

    seq: int
    reason: str


@dataclass(frozen=True)
class End:
    frames: int


@dataclass
class Stats:
    """Counters a CLI can print: packets taken, rejected and ignored, bytes skipped, frames concealed,
    and frames packets repaired (taken from a later datagram's copies: the datagram that carried them
    first was lost or came late; none in a late joiner's first datagram, its keyframe perhaps a copy)."""

    packets: int = 0
    damaged: int = 0
    duplicates: int = 0
    skipped_bytes: int = 0
    concealed: int = 0
    repaired: int = 0
    #: picture layer payloads found lost where they were due, counted by the receiver that draws them
    #: (receiver.session): a payload lost whole leaves no trace in the packets that do arrive
    layer_lost: int = 0
    reasons: list[str] = field(default_factory=list)
