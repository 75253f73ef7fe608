"""fd-keygen: a fresh pre-shared key for sealed streams (fd-send --key, fd-recv --key).

The key is 32 random bytes from the operating system, written as hex with a
comment line, readable by its owner only: whoever holds it can watch and forge
the streams sealed with it.
"""

import os
import sys

from codec.cli import ArgumentParser, run_main
from codec.errors import InputError
from protocol.secure import KEY_BYTES, key_id, parse_key

EPILOG = """examples:
  fd-keygen call.key
  fd-send talk.mp4 --key call.key -o udp://127.0.0.1:5000
  fd-recv --listen udp://:5000 --key call.key -o call.mp4
"""


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


def main(argv=None) -> int:
    p = ArgumentParser(prog="fd-keygen", epilog=EPILOG,
                       description="Write a new random key for encrypted, authenticated fd streams. "
                                   "Give the same file to both ends (--key FILE), over a safe channel.")
    p.add_argument("output", help="key file to create")
    p.add_argument("--force", action="store_true", help="replace an existing file")
    args = p.parse_args(argv)

    def run() -> int:
        key = write_key(args.output, args.force)
        print(f"fd-keygen: wrote key {key_id(key).hex()} to {args.output}", file=sys.stderr)
        return 0

    return run_main("fd-keygen", run)


if __name__ == "__main__":
    sys.exit(main())
