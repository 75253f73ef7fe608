"""fd-animate: a timed script of expressions in, rendered face video out (the paper's animation).

A script is text, one key per line: a time in seconds, then one or more
expression or viseme names or Action Units (AU12), each optionally followed by
an intensity, summed ("1.2 smile 0.6 blink", "2.0 AU12 0.8 AU6 0.5"); '#'
starts a comment. Or JSON: a list of
{"time": s, "expression": name, "intensity": x} or {"time": s, "aus": {AU: x}}.
Parameters ease between keys (smoothstep: no jump in speed at a key); the
video lasts until the last key.
"""

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from facedeform.codec.model.regions import DEFAULT_RULE, RULES
from facedeform.common.cli import ArgumentParser, check_output, fitted, number, parse_size, run_main

MAX_SECONDS = 3600  # an hour of animation: a longer script is a mistake, not a wish
EPILOG = """script example (samples/animation.txt):
  0.0  neutral
  0.5  smile 0.8
  1.0  smile 0.8 blink
  1.6  AA
  2.2  AU12 0.8 AU6 0.5
examples:
  fd-animate samples/animation.txt -o anim.mp4
  fd-animate samples/animation.txt -o anim.y4m --size 256
"""


def parse_args(argv=None) -> argparse.Namespace:
    p = ArgumentParser(
        prog="fd-animate", epilog=EPILOG,
        description="Render a timed script of expressions and visemes (codec/data/expressions.json) "
                    "as a video of the base face.")
    p.add_argument("script", help="text or JSON file of timed keys")
    p.add_argument("-o", "--output", default="-", metavar="FILE",
                   help="video file (.mp4, .mkv, .mov: H.264), .y4m, or - for Y4M on stdout (default)")
    p.add_argument("--size", type=parse_size, default=(512, 512), metavar="WxH",
                   help="output size in pixels, e.g. 512 (default) or 640x480")
    p.add_argument("--fps", type=number(1.0, 240.0), default=25.0, help="frames per second, 1-240 (default 25)")
    p.add_argument("--rule", choices=RULES, default=DEFAULT_RULE,
                   help="deformation rule: refined (default) or paper (the paper's equations exactly)")
    p.add_argument("-q", "--quiet", action="store_true", help="no summary on stderr")
    args = p.parse_args(argv)
    args.size = fitted(args.size, (1, 1))  # a face alone: square unless both sides are given
    return args


def main(argv=None) -> int:
    args = parse_args(argv)
    return run_main("fd-animate", lambda: _run(args))


def read_script(path: str) -> tuple[np.ndarray, np.ndarray]:
    """(k,) increasing key times and (k, len(EXTENDED_PARAMS)) parameters of a script file."""
    from facedeform.codec.model.expressions import au_params, expression_params
    from facedeform.common.errors import InputError

    try:
        text = Path(path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read ({getattr(exc, 'strerror', None) or exc})") from None
    keys = []
    try:
        if text.lstrip().startswith("["):
            for entry in json.loads(text):
                if "aus" in entry:
                    keys.append((float(entry["time"]), au_params(entry["aus"])))
                else:
                    params = expression_params(entry["expression"], float(entry.get("intensity", 1.0)))
                    keys.append((float(entry["time"]), params))
        else:
            for number, line in enumerate(text.splitlines(), 1):
                words = line.split("#")[0].split()
                if words:
                    keys.append((float(words[0]), _line_params(words[1:], f"{path}:{number}")))
    except InputError as exc:
        raise InputError(f"{path}: {exc}") from None
    except (ValueError, TypeError, KeyError, AttributeError) as exc:
        raise InputError(f"{path}: malformed script ({exc})") from None
    except RecursionError:
        raise InputError(f"{path}: malformed script (nested too deeply)") from None
    times = np.array([t for t, _ in keys])
    if len(keys) < 2 or times[0] < 0 or not np.all(np.diff(times) > 0) or not np.isfinite(times).all():
        raise InputError(f"{path}: needs at least two keys with increasing times from 0")
    if times[-1] > MAX_SECONDS:
        raise InputError(f"{path}: the script lasts {times[-1]:g} s, more than fd-animate renders ({MAX_SECONDS} s)")
    return times, np.array([p for _, p in keys])


def _line_params(words: list[str], where: str) -> np.ndarray:
    """Sum of 'name [intensity]' pairs of one text key; a name AU<n> is Action Unit n."""
    from facedeform.codec.model.expressions import au_params, expression_params
    from facedeform.common.errors import InputError
    from facedeform.common.parameters import EXTENDED_PARAMS

    if not words:
        raise InputError(f"{where}: a time needs an expression after it")
    total, k = np.zeros(len(EXTENDED_PARAMS)), 0
    while k < len(words):
        intensity = 1.0
        if k + 1 < len(words) and _is_number(words[k + 1]):
            intensity = float(words[k + 1])
        name = words[k]
        is_au = name.upper().startswith("AU") and name[2:].isdigit()
        total = total + (au_params({int(name[2:]): intensity}) if is_au else expression_params(name, intensity))
        k += 2 if k + 1 < len(words) and _is_number(words[k + 1]) else 1
    return total


def _is_number(word: str) -> bool:
    try:
        float(word)
    except ValueError:
        return False
    return True


def interpolate(times: np.ndarray, keys: np.ndarray, t: float) -> np.ndarray:
    """(p,) parameters at time t, eased with smoothstep between the keys around it."""
    k = int(np.clip(np.searchsorted(times, t, side="right") - 1, 0, len(times) - 2))
    s = float(np.clip((t - times[k]) / (times[k + 1] - times[k]), 0.0, 1.0))
    w = s * s * (3.0 - 2.0 * s)
    return (1.0 - w) * keys[k] + w * keys[k + 1]


def _run(args) -> int:
    from facedeform.codec.model.deform import Deformer
    from facedeform.codec.model.face_model import load_base_face
    from facedeform.codec.render.render import WARMING_UP, warm_up
    from facedeform.common.errors import InputError
    from facedeform.common.progress import slow_step
    from facedeform.receiver.face_view import face_renderer, portrait_camera
    from facedeform.receiver.output import open_writer

    check_output(args.output, "-o", (args.script,))
    times, keys = read_script(args.script)
    with slow_step("fd-animate", WARMING_UP, args.quiet):
        warm_up()
    count = int(round(times[-1] * args.fps))
    if args.output == "-" and sys.stdout.isatty():
        raise InputError("refusing to write video to a terminal: use -o FILE.mp4")
    face = load_base_face()
    deformer = Deformer(face, args.rule)
    renderer = face_renderer(face, args.size)
    camera = portrait_camera(face)
    started = time.perf_counter()
    writer = open_writer(args.output, args.fps, args.size, sys.stdout.buffer)
    try:
        for i in range(count):
            params = interpolate(times, keys, i / args.fps)
            vertices = deformer.deform_extended(params)
            writer.write(renderer.image(vertices, camera, deformer.iris(params)[0]))
    finally:
        writer.close()
    if not args.quiet:
        took = time.perf_counter() - started
        print(f"fd-animate: {count} frames ({count / args.fps:.2f} s) in {took:.1f} s", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
