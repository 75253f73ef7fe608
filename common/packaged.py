"""Data files the package installs beside its code and both ends of a stream must agree on."""

import hashlib
from pathlib import Path

from facedeform.common.errors import FdError


def read_packaged(path: Path, sha256: str, what: str) -> bytes:
    """The bytes of ``path``, checked against ``sha256``; FdError (one line from the tools) if the
    installed file is missing or another than ``what`` of this version."""
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise FdError(f"cannot read {path}: {exc.strerror} (reinstall facedeform)") from None
    if hashlib.sha256(data).hexdigest() != sha256:
        raise FdError(f"{path} is not {what} (reinstall facedeform)")
    return data
