"""Pre-shared keys: the key file both ends read, its public id, and the keys derived from it.

One key serves a call's sealed stream (``protocol.secure``) and the face file
at rest (``codec.face_file``); each use derives its own key with HKDF-SHA256
under its own label, so the two never share key material.
"""

import hashlib
import os

from cryptography.hazmat.primitives import hashes
from cryptography.hazmat.primitives.kdf.hkdf import HKDF

from facedeform.common.errors import InputError

KEY_BYTES, KEY_ID_BYTES = 32, 4


def key_id(key: bytes) -> bytes:
    """A short public name of the key: lets a receiver holding another key say so."""
    return hashlib.sha256(b"facedeform key id" + key).digest()[:KEY_ID_BYTES]


def derive(key: bytes, salt: bytes, label: bytes, size: int) -> bytes:
    """``size`` bytes of key material for one use (``label``) of the key with a fresh ``salt``."""
    return HKDF(hashes.SHA256(), size, salt, label).derive(key)


def parse_key(text: str) -> bytes:
    """The key in a key file: 64 hex digits; lines starting with # are comments."""
    lines = [line.strip() for line in text.splitlines() if line.strip() and not line.lstrip().startswith("#")]
    try:
        key = bytes.fromhex(lines[0]) if len(lines) == 1 else b""
    except ValueError:
        key = b""
    if len(key) != KEY_BYTES:
        raise InputError(f"not a key file: expected one line of {2 * KEY_BYTES} hex digits (make one with fd-keygen)")
    return key


def read_key(path: str) -> bytes:
    """The key in ``path``; a missing or malformed file is one line for the user."""
    try:
        with open(path, encoding="ascii") as f:
            text = f.read(4096)
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read the key ({getattr(exc, 'strerror', None) or exc})") from None
    try:
        return parse_key(text)
    except InputError as exc:
        raise InputError(f"{path}: {exc}") from None


def write_key(path: str, force: bool = False) -> bytes:
    """Writes a new key to ``path`` (mode 0600, created that way: never readable by others in between)."""
    key = os.urandom(KEY_BYTES)
    flags = os.O_WRONLY | os.O_CREAT | (os.O_TRUNC if force else os.O_EXCL)
    try:
        fd = os.open(path, flags, 0o600)
    except FileExistsError:
        raise InputError(f"{path} exists: not overwriting a key (--force to replace it)") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot write ({exc.strerror})") from None
    with os.fdopen(fd, "w", encoding="ascii") as f:
        os.fchmod(f.fileno(), 0o600)
        f.write(f"# facedeform stream key {key_id(key).hex()}: keep it secret\n{key.hex()}\n")
    return key
