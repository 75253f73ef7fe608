"""A receiver's folder of face models by id (``fd-recv --faces DIR``): a stream that names one of
them is drawn with it from its first frame, and a face model that comes whole in a stream is kept
there for the next call.

Why: a face model in the stream is the call's wait (README, "One-off bytes": 25-29 s at 4 kbit/s
for a 256x256 face sent before the frames); a receiver that has met the speaker before holds it.
A file is named by its id, ``<sha256>.fdface`` (what fd-enroll prints, and ``sha256sum`` gives),
is checked against its name when read, and is sealed with the stream's key when there is one.
"""

from collections.abc import Callable
from pathlib import Path

from facedeform.codec.face_file.format import decode_face, face_id, read_face_bytes, save_face_file
from facedeform.codec.model.face_model import BaseFace
from facedeform.common.errors import InputError

SUFFIX = ".fdface"


class FaceCache:
    """The face models in ``folder`` (made if missing), sealed with ``key`` if given; the ``warn(line)``
    given to each method hears of a file that cannot be used or kept (the call goes on without it)."""

    def __init__(self, folder: str | Path, key: bytes | None) -> None:
        self.folder = Path(folder)
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise InputError(f"{folder}: cannot make a folder of face models ({exc.strerror or exc})") from None
        self._key = key

    def get(self, ident: str, warn: Callable[[str], None]) -> BaseFace | None:
        """The face model of id ``ident``, or None if the folder does not hold it whole."""
        path = self._path(ident)
        if not path.is_file():
            return None
        try:
            face = decode_face(read_face_bytes(path, self._key), str(path))
        except InputError as exc:
            warn(f"{exc}: not used")
            return None
        if face.content_id != ident:
            warn(f"{path}: holds face model {face.content_id[:12]}, not the one its name says: not used")
            return None
        return face

    def keep(self, data: bytes, warn: Callable[[str], None]) -> None:
        """Keeps a face file's ``data`` under its id, unless held already (written whole, then named)."""
        path = self._path(face_id(data))
        if path.exists():
            return
        part = path.with_name(path.name + ".part")
        try:
            save_face_file(data, part, self._key)
            part.replace(path)
        except (InputError, OSError) as exc:
            warn(f"cannot keep the stream's face model in {self.folder} ({exc})")

    def _path(self, ident: str) -> Path:
        return self.folder / f"{ident}{SUFFIX}"
