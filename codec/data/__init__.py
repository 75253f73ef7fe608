"""The data the codec ships inside its package: the base face and the expression tables.

Found through ``importlib.resources``, so an installed wheel works from any
directory, not only a source checkout. Sources and licences: ``NOTICE`` here.
"""

from importlib.resources import files
from pathlib import Path


def data_path(name: str) -> Path:
    """The path of a file shipped in this package (``canonical_face.pbtxt``, ``au_table.json``, …)."""
    return Path(str(files(__name__) / name))
