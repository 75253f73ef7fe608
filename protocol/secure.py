"""Sealed packets: encryption and truncated authentication that cost a few bytes per packet.

A stream sealed with a pre-shared key starts with a preamble in clear::

    "FDS" | version (1) | tag bytes (1) | salt (16) | key id (4) | tag

then carries every packet of the ordinary format (header and model included),
each in an envelope that says its own length::

    counter (2 bytes, big-endian) | length (varint) | AES-256-CTR ciphertext of the packet | tag

A receiver finds the tag from the envelope alone and checks it before it
decrypts anything: no byte of a packet is parsed before it is authentic.
Per-stream keys come from HKDF-SHA256 of the key and the preamble's random
salt, so a key can serve many streams. The counter is the low 16 bits of a
48-bit packet index; the receiver restores the rest from the highest index it
holds, as SRTP does with its rollover counter: two bytes, not a growing varint,
so the cost stays fixed and up to 32767 lost packets (22 minutes at 25 packets
per second) keep sync. The counter block of AES-CTR is IV (8 bytes, from HKDF)
| index (6) | block (2), so no keystream is ever used twice and the ciphertext
is exactly as long as the packet. The tag is HMAC-SHA256 over the index, the
length and the ciphertext, truncated to 4 bytes unless asked for more (up to 16); the
preamble's own tag proves the salt. The key id (a hash of the key) lets a
receiver holding another key say so rather than see noise. No I/O here.
"""

import hashlib
import hmac
import os
from dataclasses import dataclass

from cryptography.hazmat.primitives.ciphers import Cipher, algorithms, modes

from facedeform.common.errors import BitstreamError, InputError
from facedeform.common.keys import KEY_ID_BYTES, derive, key_id
from facedeform.protocol.framing import MAX_BODY, read_varint, varint

MAGIC = b"FDS\x02"  # version 2: envelopes with a length
SALT_BYTES = 16
DEFAULT_TAG_BITS = 32
TAG_BITS = tuple(range(32, 129, 8))
WINDOW = 64  # packets: later than this behind the newest is a replay (or useless anyway)
COUNTER_BYTES = 2
MAX_SEALED = MAX_BODY + 16  # bytes of one sealed packet: longer than any the encoder makes
_MAX_INDEX = 1 << 48


def preamble_size(tag_bytes: int) -> int:
    return len(MAGIC) + 1 + SALT_BYTES + KEY_ID_BYTES + tag_bytes


class _Keys:
    """The stream's cipher key, IV and MAC key, derived from the pre-shared key and the salt."""

    def __init__(self, key: bytes, salt: bytes) -> None:
        material = derive(key, salt, b"facedeform stream v1", 72)
        self.cipher = algorithms.AES(material[:32])
        self.iv, self.mac = material[32:40], material[40:]

    def crypt(self, index: int, data: bytes) -> bytes:
        """AES-CTR both ways; packets are at most 257 blocks, well inside the 2-byte block counter."""
        nonce = self.iv + index.to_bytes(6, "big") + b"\0\0"
        return Cipher(self.cipher, modes.CTR(nonce)).encryptor().update(data)

    def tag(self, domain: bytes, data: bytes, size: int) -> bytes:
        return hmac.new(self.mac, domain + data, hashlib.sha256).digest()[:size]


def _tag_bytes(tag_bits: int) -> int:
    if tag_bits not in TAG_BITS:
        raise InputError(f"tag length must be a multiple of 8 from 32 to 128 bits, not {tag_bits}")
    return tag_bits // 8


class SecureSealer:
    """The sending side: :meth:`preamble` once, then :meth:`seal` every packet in order."""

    def __init__(self, key: bytes, tag_bits: int = DEFAULT_TAG_BITS, salt: bytes | None = None) -> None:
        self.tag_bytes = _tag_bytes(tag_bits)
        self.salt = os.urandom(SALT_BYTES) if salt is None else salt
        self._keys, self._key_id = _Keys(key, self.salt), key_id(key)
        self._index = 0

    @property
    def overhead(self) -> int:
        """Bytes sealing adds to each packet apart from its length field (:func:`envelope_bytes`)."""
        return COUNTER_BYTES + self.tag_bytes

    def preamble(self) -> bytes:
        data = MAGIC + bytes([self.tag_bytes]) + self.salt + self._key_id
        return data + self._keys.tag(b"\0", data, self.tag_bytes)

    def seal(self, packet: bytes) -> bytes:
        """One packet, as the encoder returns it, in its envelope."""
        if not 0 < len(packet) <= MAX_SEALED:
            raise BitstreamError(f"cannot seal a packet of {len(packet)} bytes")
        if self._index >= _MAX_INDEX:
            raise BitstreamError("stream too long for one key stream: start a new one")
        index, self._index = self._index, self._index + 1
        body = varint(len(packet)) + self._keys.crypt(index, packet)
        tag = self._keys.tag(b"\1" + index.to_bytes(6, "big"), body, self.tag_bytes)
        return index.to_bytes(6, "big")[-COUNTER_BYTES:] + body + tag

    def seal_all(self, packets: list[bytes]) -> list[bytes]:
        return [self.seal(p) for p in packets]


def envelope_bytes(size: int, overhead: int) -> int:
    """Bytes sealing adds to a packet of ``size`` bytes: ``overhead`` (:attr:`SecureSealer.overhead`)
    and the length field."""
    return overhead + len(varint(size))


@dataclass
class SecureStats:
    """Sealed packets taken and rejected; a receiver prints them."""

    opened: int = 0
    auth_failures: int = 0  # wrong tag: damage, forgery or junk
    replays: int = 0  # seen before, or older than the window
    wrong_key: int = 0  # preambles of a stream sealed with another key
    foreign_key_id: str = ""

    def as_dict(self) -> dict:
        return {"opened": self.opened, "auth_failures": self.auth_failures, "replays": self.replays,
                "wrong_key": self.wrong_key}


class SecureOpener:
    """The receiving side: :meth:`preamble` until one is genuine, then :meth:`open` each sealed packet.

    Every check that costs nothing (size, window) comes before the MAC; the
    window state changes only for packets that authenticate, so junk can
    neither advance nor clog it. Memory is constant.
    """

    def __init__(self, key: bytes, window: int = WINDOW) -> None:
        self._key, self._key_id, self._window = key, key_id(key), window
        self._keys: _Keys | None = None
        self.tag_bytes = 0
        self.accepted = b""  #: the genuine preamble taken
        self.stats = SecureStats()
        self._highest = -1
        self._seen = 0  # bit i: index highest - i has been opened

    @property
    def ready(self) -> bool:
        return self._keys is not None

    def wants_preamble(self, head: bytes) -> bool:
        """Whether data starting with ``head`` goes to :meth:`preamble`: until a packet has opened, a
        later genuine preamble replaces the first, so an old stream's preamble replayed ahead of
        the real one cannot lock the receiver out."""
        return self._keys is None or (not self.stats.opened and bytes(head[:len(MAGIC)]) == MAGIC)

    def preamble(self, data: bytes) -> bool:
        """True if ``data`` is a genuine preamble for our key: its stream is the one opened from now on."""
        data = bytes(data)
        tag_bytes = data[len(MAGIC)] if len(data) > len(MAGIC) else 0
        if not data.startswith(MAGIC) or tag_bytes * 8 not in TAG_BITS or len(data) != preamble_size(tag_bytes):
            self.stats.auth_failures += 1
            return False
        salt = data[len(MAGIC) + 1:len(MAGIC) + 1 + SALT_BYTES]
        if data[-tag_bytes - KEY_ID_BYTES:-tag_bytes] != self._key_id:
            self.stats.wrong_key += 1
            self.stats.foreign_key_id = data[-tag_bytes - KEY_ID_BYTES:-tag_bytes].hex()
            return False
        keys = _Keys(self._key, salt)
        if not hmac.compare_digest(keys.tag(b"\0", data[:-tag_bytes], tag_bytes), data[-tag_bytes:]):
            self.stats.auth_failures += 1
            return False
        self._keys, self.tag_bytes, self.accepted = keys, tag_bytes, data
        return True

    def _index(self, counter: int) -> int:
        delta = (counter - self._highest + (1 << 15)) % (1 << 16) - (1 << 15)
        return self._highest + delta if self._highest >= 0 else counter

    def size(self, data: bytes, pos: int) -> int | None:
        """Size of the sealed packet at ``data[pos]`` (byte streams) from its envelope alone, None if
        more bytes are needed to tell; BitstreamError when the bytes cannot start one."""
        got = read_varint(data, pos + COUNTER_BYTES, MAX_SEALED)
        if got is None:
            return None
        n, start = got
        if not n:
            raise BitstreamError("empty sealed packet")
        return start - pos + n + self.tag_bytes

    def open(self, sealed: bytes) -> bytes | None:
        """The packet inside ``sealed``, or None (counted) if it fails authentication or replays.

        The envelope's length and tag are checked before anything is decrypted."""
        try:
            got = read_varint(sealed, COUNTER_BYTES, MAX_SEALED)
        except BitstreamError:
            got = None
        keys = self._keys
        if keys is None or got is None or not got[0] or got[1] + got[0] + self.tag_bytes != len(sealed):
            self.stats.auth_failures += 1
            return None
        index = self._index(int.from_bytes(sealed[:COUNTER_BYTES], "big"))
        age = self._highest - index
        if not 0 <= index < _MAX_INDEX or age >= self._window or (age >= 0 and self._seen >> age & 1):
            self.stats.replays += 1
            return None
        body, tag = bytes(sealed[COUNTER_BYTES:-self.tag_bytes]), bytes(sealed[-self.tag_bytes:])
        if not hmac.compare_digest(keys.tag(b"\1" + index.to_bytes(6, "big"), body, self.tag_bytes), tag):
            self.stats.auth_failures += 1
            return None
        if age < 0:
            self._seen, self._highest = (self._seen << -age | 1) & ((1 << self._window) - 1), index
        else:
            self._seen |= 1 << age
        self.stats.opened += 1
        return keys.crypt(index, bytes(sealed[got[1]:-self.tag_bytes]))

    def no_stream(self) -> str:
        """Why nothing could be opened, for the user."""
        if self._keys is None and self.stats.wrong_key:
            return (f"the stream is sealed with another key (key id {self.stats.foreign_key_id}, "
                    f"this key's is {self._key_id.hex()})")
        if self._keys is None:
            return "no sealed fd stream arrived (is the sender using --key?)"
        if self.stats.opened:
            return "the sealed stream's header did not arrive intact"
        return "no packet of the sealed stream could be authenticated"
