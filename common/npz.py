"""A NumPy archive written as rows arrive, so a long call's research dump holds no rows in memory.

Each row's arrays are appended to temporary files beside the archive; :meth:`NpzAppender.close`
assembles the ``.npz`` (the same arrays and names ``np.savez`` would give), adding the small
arrays that describe the whole (layout, rate).
"""

import shutil
import tempfile
import zipfile
from pathlib import Path

import numpy as np


class NpzAppender:
    """fields: name -> (dtype, shape of one row); :meth:`add` one row (a field left out is NaN,
    or False/0 for types without NaN), :meth:`close` once."""

    def __init__(self, path: str | Path, fields: dict[str, tuple[type, tuple[int, ...]]]) -> None:
        self.path = Path(path)
        self._fields = {name: (np.dtype(dtype), tuple(shape)) for name, (dtype, shape) in fields.items()}
        self._dir = tempfile.TemporaryDirectory(dir=self.path.parent, prefix=".fd-dump-")
        self._files = {name: open(Path(self._dir.name) / name, "wb") for name in self._fields}
        self.count = 0

    def add(self, **values) -> None:
        for name, (dtype, shape) in self._fields.items():
            value = values.get(name)
            if value is None:
                row = np.full(shape, np.nan if dtype.kind == "f" else 0, dtype)
            else:
                row = np.asarray(value, dtype).reshape(shape)
            self._files[name].write(row.tobytes())
        self.count += 1

    def close(self, extra: dict | None = None) -> None:
        """Writes the archive with ``extra`` (name -> small array or scalar) beside the rows."""
        for f in self._files.values():
            f.close()
        try:
            with zipfile.ZipFile(self.path, "w", zipfile.ZIP_DEFLATED, allowZip64=True) as z:
                for name, (dtype, shape) in self._fields.items():
                    with z.open(f"{name}.npy", "w", force_zip64=True) as out, \
                            open(Path(self._dir.name) / name, "rb") as raw:
                        np.lib.format.write_array_header_1_0(out, {
                            "descr": np.lib.format.dtype_to_descr(dtype), "fortran_order": False,
                            "shape": (self.count, *shape)})
                        shutil.copyfileobj(raw, out, 1 << 16)  # a bounded buffer, however long the call
                for name, value in (extra or {}).items():
                    with z.open(f"{name}.npy", "w") as out:
                        np.lib.format.write_array(out, np.asarray(value))
        finally:
            self._dir.cleanup()

    def discard(self) -> None:
        """Drops the rows without writing an archive."""
        for f in self._files.values():
            f.close()
        self._dir.cleanup()
