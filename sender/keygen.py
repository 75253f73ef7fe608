"""fd-keygen: a fresh pre-shared key for sealed streams (fd-send --key, fd-recv --key).

The key is 32 random bytes from the operating system, written as hex with a
comment line, readable by its owner only: whoever holds it can watch and forge
the streams sealed with it.
"""

import sys

from facedeform.common.cli import ArgumentParser, run_main
from facedeform.common.keys import key_id, write_key

EPILOG = """examples:
  fd-keygen call.key
  fd-send talk.mp4 --key call.key -o udp://127.0.0.1:5000
  fd-recv --listen udp://:5000 --key call.key -o call.mp4
"""


def main(argv=None) -> int:
    p = ArgumentParser(prog="fd-keygen", epilog=EPILOG,
                       description="Write a new random key for encrypted, authenticated fd streams. "
                                   "Give the same file to both ends (--key FILE), over a safe channel.")
    p.add_argument("output", help="key file to create")
    p.add_argument("--force", action="store_true", help="replace an existing file")
    args = p.parse_args(argv)

    def run() -> int:
        from facedeform.common.errors import InputError

        if args.output == "-":
            raise InputError("give the key a file name: a key is not written to stdout, where a terminal or a log "
                             "would keep it")
        key = write_key(args.output, args.force)
        print(f"fd-keygen: wrote key {key_id(key).hex()} to {args.output}", file=sys.stderr)
        return 0

    return run_main("fd-keygen", run)


if __name__ == "__main__":
    sys.exit(main())
