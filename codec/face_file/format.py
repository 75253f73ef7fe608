"""A person's face model as one file, shared before the call or carried in-band.

Layout (little-endian)::

    "FDFACE" | version (1 byte) | 0 | JSON length (u32) | JSON | vertices <f4 (n, 3)
    | uv <f4 (n, 2) | faces <u2 (m, 3) | motion basis | texture (JPEG or PNG, may be empty)
    | reference picture (WebP, JPEG or PNG; version 3, may be empty)

The JSON holds the counts (``vertices``, ``faces``, ``texture`` bytes, and
``motion``: [moved vertices k, patterns c, what they are over], absent without a basis) and the
feature points, regions and loops (``meta``, as codec/data/feature_points.json),
so a file is complete on its own and the Deformer takes it unchanged. The
motion basis (version 2; codec/model/motion_basis.py) is the moved vertices' indices
<u2 (k) then the patterns <f4 (c, k, 3); version 1 files have none. Version 3
adds the person's whole reference picture (codec/render/picture.py): ``picture`` in the
JSON is [bytes, width, height] and ``projection`` the (3, 4) similarity from
model points to its pixels (x right, y down) and depth; optionally their open
mouth, ``mouth`` [bytes, width, height] after the picture, with ``mouth_points``
the pixel positions in it of the mouth opening's vertices. Version 4 adds ``rings``
in the JSON: how far each ring vertex around the face follows the head
(codec/render/picture.SceneMesh, sender/motion_global.RingWeights), 0-255 for 0-1, and
takes fewer bytes: ``meta`` may be "base" (the generic face's, codec/data), the
motion basis's patterns are <f2, and a file with a reference picture may leave the
texture out (the face is then textured by the picture where the projection puts
it: codec/render/picture.face_texture). Version 5 stores the patterns as <i1, 127 for
1 (a pattern's largest vertex move is 1, so every coordinate fits): since the
basis covers the whole face that halves its bytes (16.8 KB for 12 patterns),
and the largest vertex error it adds, 1/254 of a coefficient, is a fortieth
of a quantiser step at the default level for any coefficient up to 0.02. Version 6 keeps
only what a receiver cannot derive, in a third of the bytes (38.5 to 14.8 KB for
liveportrait_d12's 256x256 face)::

    "FDFACE" | 6 | 0 | JSON length (u32) | JSON | LZMA (raw, ``packed`` bytes in the JSON) of:
        vertices as <i2 (n, 3) steps of 1/VERTEX_STEPS from the generic face's
        | uv <f4 (n, 2), unless ``uv`` is "base" | faces <u2 (m, 3), unless ``topology`` is "base"
        | motion basis (as version 5)
    | texture | reference picture | open mouth

A vertex moves by at most 1/(2 VERTEX_STEPS) of the face's height (0.02 pixels at 512x512).
Version 7 packs the reference picture's numbers with the mesh too, after the motion basis: the
projection <f8 (3, 4), the rings' weights u1 (``rings``: their count), the open mouth's points <f4
(``mouth_points``: their count, 2 numbers each); as JSON they were two thirds of its 1.6 KB
description, packed a third (1.1 KB less a face, 7 %; msgpack of the description would have saved
0.8 KB).
Version 8 stores each pattern of the motion basis in whole steps, as finely as its coefficients
need (``MotionBasis.steps``, one byte each after the vertices' indices), and each vertex's steps as
their difference from the mean of its mesh neighbours stored before it (``_stored_order``), modulo
256: the patterns are smooth over the face, so the differences are small and pack well. On the dev
clips' faces of 16 patterns the basis takes about 7 KB instead of 22; a vertex is off by at most
half a step, 1/2048 of the face's height at the largest coefficient the enrolment clip gave its
pattern.
Version 9 adds the person's shut eyes (``shut_eyes`` [bytes, width, height, x, y]: an image, as
the picture, after the open mouth, and where its top-left pixel lies in the reference picture:
codec/render/eyelids.py); a face without them is written as version 8, byte for byte as before.
Version 10 codes the mesh and the motion basis as integers by an adaptive arithmetic code
(protocol.arith.encode_integers) instead of LZMA, and the reference picture as AV1::

    "FDFACE" | 10 | 0 | JSON length (u32) | JSON | LZMA (``packed``) of: [uv] [faces]
        | the basis's steps u1 (c) | the picture's numbers (as version 7)
    | arithmetic code (``coded`` bytes) of: each vertex's steps of 1/``mesh`` (in the JSON, MESH_STEPS
        unless told) of the face's height from the generic face's,
        less their guess from its neighbours stored before it (_stored_order over the mesh), (n, 3)
        | the basis's vertices, each less the one before (from -1), (k) | the basis's differences as
        version 8's, not taken modulo 256, (c, k, 3)
    | texture | reference picture (AV1: a key frame's temporal unit without its delimiter) | open mouth
    | shut eyes (WebP)

On the nine dev clips' 256x256 faces the mesh and basis take 4.2-6.9 KB instead of 6.7-9.2, and the
picture 31-42 % fewer bytes (docs/face_file.md).
The face
id is the sha256 of the whole file (``sha256sum face.fdface`` prints it): what
the stream header names is exactly what the receiver holds, bit for bit.

At rest a face file can be sealed with a stream key (``fd-enroll --key``)::

    "FDSEAL" | version (1) | salt (16) | nonce (12) | AES-256-GCM ciphertext of the file | tag (16)

the AES key derived by HKDF-SHA256 from the key and the salt; the face id
stays the plain file's, and the readers here open it given the key.
"""

import hashlib
import json
import lzma
import os
import struct
from collections import deque
from dataclasses import dataclass, replace
from functools import cache, cached_property
from pathlib import Path

import cv2
import numpy as np
from cryptography.exceptions import InvalidTag
from cryptography.hazmat.primitives.ciphers.aead import AESGCM

from facedeform.codec.face_file.image_header import image_size
from facedeform.codec.model.face_model import (
    N_LANDMARKS,
    BaseFace,
    ReferencePicture,
    build_face,
    load_base_face,
    mouth_vertices,
    normalise,
)
from facedeform.codec.model.motion_basis import MOST_STEPS, OVER, MotionBasis
from facedeform.codec.render.frame_video import StillDecoder, encode_still, even
from facedeform.codec.render.picture import RINGS, Placement, outer_loop
from facedeform.common.errors import InputError
from facedeform.common.keys import derive
from facedeform.common.limits import MAX_SIDE
from facedeform.common.parameters import MAX_COMPONENTS
from facedeform.protocol.arith import decode_integers, encode_integers

MAGIC = b"FDFACE"
VERSION = 10
SHUT_EYES_VERSION = 9  # the first with the person's shut eyes
CODED_VERSION = 10  # the first with the mesh and motion basis arithmetic-coded
READS = (1, 2, 3, 4, 5, 6, 7, 8, 9, 10)
#: Version 6's vertex coordinates: steps of the face's height, from the generic face's.
VERTEX_STEPS = 8192
#: Version 10's: 1/2048 of the face's height (a vertex off by at most half a step, a quarter pixel of a
#: face 1,000 pixels tall): the mesh takes about 0.9 KB instead of 1.25 at 1/8192 (docs/face_file.md).
MESH_STEPS = 2048
MESH_STEPS_ALLOWED = (16, 1 << 16)  # what a file may say its mesh's steps are (JSON ``mesh``)
#: Version 5-7's pattern coordinates: this many steps for 1.
PATTERN_SCALE = 127
MAX_FILE = 16 << 20  # the stream header's limit for an in-band model
MAX_FACES = 4096
MAX_RINGS = 4096  # ring weights (one a ring vertex of the scene mesh: 144 for the generic face)
MAX_TEXTURE_SIDE = 2048
PICTURE_SIDES = (16, MAX_SIDE)  # pixels of a reference picture's width and height
#: The face's height in a reference picture, over the picture's larger side: a face, not a speck or a blow-up.
FACE_IN_PICTURE = (0.02, 2.0)
#: How a face file codes its reference picture: AV1 at SVT-AV1's CRF 28 (on the dev clips' 256x256 crops 28-44 %
#: fewer bytes than WebP 80, and the whole picture within 0.13 dB, most clips higher: docs/face_file.md) ...
PICTURE_FORMAT = ".av1"
#: ... and its open mouth and shut eyes, images of a few dozen pixels a side, where AV1's frame costs half
#: as many bytes again as WebP's.
PARTS_FORMAT = ".webp"
#: Each image format's quality unless told (AV1: SVT-AV1's CRF, finer lower; PNG is lossless).
QUALITY = {".av1": 28, ".webp": 80, ".jpg": 90, ".png": 0}
#: The most bytes of a face file :func:`personal_face` makes (fd-enroll's), as far as a coarser picture
#: can make it so: at 256x256 a face at 4 kbit/s in the stream within about 20 s; HD_BUDGET where the
#: picture has more than HD_PIXELS. Over it, the picture's CRF rises by 2 up to COARSEST_CRF (at CRF 40
#: sadtalker_WDA_KatieHill's whole picture was as at 28, its face 2.7 KB smaller: docs/face_file.md).
BUDGET, HD_BUDGET, HD_PIXELS = 10_000, 20_000, 640 * 480
COARSEST_CRF = 40
#: ... and then the fewest patterns of its motion basis it keeps (each of the last ones about 100-250
#: bytes at 256x256; sadtalker_WDA_KatieHill's face kept 9 of 12: docs/face_file.md).
LEAST_PATTERNS = 8
#: A preview face's (:func:`preview_face`) vertices in steps of 1/256 of the face's height (a vertex off by
#: at most 0.3 pixels of a 256x256 crop's face), and its picture's AV1 CRF.
PREVIEW_MESH_STEPS = 256
PREVIEW_QUALITY = 50
SEALED = b"FDSEAL\x01"
#: Version 6's packing: raw LZMA2 (no container: a hostile file cannot ask for a larger dictionary)
#: with a dictionary larger than any file's mesh and basis (about 35 KB at most).
_PACKING = [{"id": lzma.FILTER_LZMA2, "preset": 9 | lzma.PRESET_EXTREME, "dict_size": 1 << 16}]
_PREFIX = struct.Struct("<6sBBI")
_AV1_SEQUENCE = b"\x0a"  # an AV1 picture's first byte: its sequence header's OBU header


def face_id(data: bytes) -> str:
    """The id of a face file's bytes: their sha256 hex."""
    return hashlib.sha256(data).hexdigest()


def encode_face(face: BaseFace, texture_format: str = ".jpg", quality: int = 90,
                picture_format: str | None = None, picture_quality: int = 0, mesh_steps: int = MESH_STEPS) -> bytes:
    """A face file's bytes; ``face.texture`` (RGB) goes in as ``texture_format`` (.jpg or .png),
    ``face.picture``'s images as ``picture_format`` (.av1, .webp, .jpg or .png) at ``picture_quality``
    (0: the format's QUALITY), or by default the picture as PICTURE_FORMAT (at ``picture_quality``) and
    its parts as PARTS_FORMAT;
    the vertices in steps of 1/``mesh_steps`` of the face's height.

    The same face gives the same bytes (and id); a JPEG texture loaded and
    saved again is re-compressed and so gets a new id.
    """
    texture = _encode_image(face.texture, texture_format, quality, "texture") if face.texture is not None else b""
    info: dict[str, object] = {"vertices": len(face.vertices), "faces": len(face.faces), "texture": len(texture),
                               "meta": "base" if face.meta == _base().meta else face.meta}
    picture, numbers = b"", []  # the picture's numbers, packed after the motion basis
    if face.picture is not None:
        image = face.picture.image
        picture = _encode_image(image, picture_format or PICTURE_FORMAT, picture_quality, "reference picture")
        parts = (picture_format, picture_quality) if picture_format else (PARTS_FORMAT, 0)
        info["picture"] = [len(picture), image.shape[1], image.shape[0]]
        numbers.append(np.ascontiguousarray(face.picture.projection, dtype="<f8").tobytes())
        if face.picture.ring_weights is not None:
            rings = np.rint(255 * np.clip(face.picture.ring_weights, 0.0, 1.0)).astype("u1")
            info["rings"] = len(rings)
            numbers.append(rings.tobytes())
        if face.picture.mouth is not None:
            mouth = face.picture.mouth
            data = _encode_image(mouth, *parts, "open mouth")
            info["mouth"] = [len(data), mouth.shape[1], mouth.shape[0]]
            points = np.ascontiguousarray(face.picture.mouth_points, dtype="<f4")
            info["mouth_points"] = len(points)
            numbers.append(points.tobytes())
            picture += data
        if face.picture.shut_eyes is not None and face.picture.shut_eyes_at is not None:
            shut = face.picture.shut_eyes
            data = _encode_image(shut, *parts, "shut eyes")
            info["shut_eyes"] = [len(data), shut.shape[1], shut.shape[0], *map(int, face.picture.shut_eyes_at)]
            picture += data
    motion, basis = b"", np.zeros(0, np.int64)
    if face.motion is not None:
        info["motion"] = [len(face.motion.vertices), face.motion.components, face.motion.over]
        if np.abs(face.motion.vectors).max() > 1.0:
            raise ValueError("a motion basis's patterns move no vertex coordinate by more than 1 (learn_basis)")
        motion, basis = _encode_motion(face.motion, face.faces)
    base = _base()
    steps = np.rint((face.vertices - base.vertices) * mesh_steps).astype(np.int64)
    if np.abs(steps).max() > np.iinfo(np.int16).max:
        raise ValueError("a face file's vertices lie within 32767 of its steps of the generic face's")
    if mesh_steps != MESH_STEPS:
        info["mesh"] = mesh_steps
    arrays = []
    if np.array_equal(face.uv.astype("<f4"), base.uv.astype("<f4")):  # as an older file stored them
        info["uv"] = "base"
    else:
        arrays.append(np.ascontiguousarray(face.uv, dtype="<f4").tobytes())
    if np.array_equal(face.faces, base.faces):
        info["topology"] = "base"
    else:
        arrays.append(np.ascontiguousarray(face.faces, dtype="<u2").tobytes())
    packed = lzma.compress(b"".join(arrays) + motion + b"".join(numbers), lzma.FORMAT_RAW, filters=_PACKING)
    info["packed"] = len(packed)
    mesh = _differences(steps[None], _stored_order(np.arange(len(steps)), face.faces))[0]
    k, c = (len(face.motion.vertices), face.motion.components) if face.motion is not None else (0, 0)
    coded = encode_integers(np.concatenate([mesh.ravel(), basis]), *_groups(len(steps), c, k))
    info["coded"] = len(coded)
    text = json.dumps(info, sort_keys=True, separators=(",", ":")).encode()
    return b"".join([_PREFIX.pack(MAGIC, VERSION, 0, len(text)), text, packed, coded, texture, picture])


def _groups(n: int, c: int, k: int) -> tuple[np.ndarray, int]:
    """The groups of a version 10 file's coded integers (:func:`protocol.arith.encode_integers`): its n
    vertices' (n, 3) differences by axis; its motion basis's k vertices, each as the step from the one
    before (from -1); their (c, k, 3) differences by pattern and axis. And the groups' number."""
    mesh = np.tile(np.arange(3), n)
    basis = 4 + np.arange(3 * c).reshape(c, 1, 3).repeat(k, axis=1).ravel()
    return np.concatenate([mesh, np.full(k, 3), basis]), 4 + 3 * c


def preview_face(face: BaseFace) -> bytes:
    """The face file of a preview of ``face``, drawn while ``face`` itself is on its way (a paced call,
    sender/face_pacing.py): its mesh in steps of 1/PREVIEW_MESH_STEPS of the face's height and its picture
    at PREVIEW_QUALITY, without the motion basis, open mouth, shut eyes or texture: on the nine dev clips'
    faces 1.3-2.3 KB, against 7.8-13.4 KB whole."""
    picture = None if face.picture is None else replace(face.picture, mouth=None, mouth_points=None,
                                                        shut_eyes=None, shut_eyes_at=None)
    preview = replace(face, motion=None, texture=None, picture=picture)
    return encode_face(preview, picture_format=PICTURE_FORMAT, picture_quality=PREVIEW_QUALITY,
                       mesh_steps=PREVIEW_MESH_STEPS)


def described(data: bytes) -> dict:
    """A face file's description (its JSON: counts and bytes of each part), unchecked: for reports."""
    return json.loads(data[_PREFIX.size:_PREFIX.size + _PREFIX.unpack_from(data)[3]])


def _encode_image(rgb: np.ndarray, ext: str, quality: int, what: str) -> bytes:
    """``rgb`` as an ``ext`` image at ``quality`` (0: QUALITY's)."""
    quality = quality or QUALITY.get(ext, 0)
    if ext == ".av1":
        return encode_still(rgb, quality)
    params = {".jpg": [cv2.IMWRITE_JPEG_QUALITY, quality], ".webp": [cv2.IMWRITE_WEBP_QUALITY, quality]}
    ok, buf = cv2.imencode(ext, cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), params.get(ext, []))
    if not ok:
        raise InputError(f"cannot encode the face {what} as {ext}")
    return buf.tobytes()


def personal_face(neutral: np.ndarray, texture: np.ndarray | None = None,
                  base: BaseFace | None = None, motion: MotionBasis | None = None,
                  picture: ReferencePicture | None = None, budget: int | None = None) -> bytes:
    """A face file from a person's (468, 3) pose-free neutral landmarks (base-face axes, e.g.
    ``sender.pose`` output), an optional (h, w, 3) uint8 RGB texture in ``base``'s UV layout,
    an optional motion basis and an optional reference picture (its projection takes the
    normalised landmarks, :func:`codec.model.face_model.normalise`).

    The landmarks become the vertices, normalised as the base face is (face
    height 1, bounding box centred), so the receiver's framing fits; topology,
    UVs and feature points are ``base``'s (default: the generic face); ``budget``: :func:`within_budget`'s.
    """
    base = base or load_base_face()
    neutral = np.asarray(neutral, dtype=np.float64)
    if neutral.shape != (N_LANDMARKS, 3) or not np.all(np.isfinite(neutral)):
        raise InputError(f"a face needs ({N_LANDMARKS}, 3) finite landmarks, got {neutral.shape}")
    if texture is not None and (texture.ndim != 3 or texture.shape[2] != 3 or texture.dtype != np.uint8):
        raise InputError(f"a face texture must be (h, w, 3) uint8, got {texture.dtype} {texture.shape}")
    person = build_face(normalise(neutral), base.faces, base.uv, base.meta, "", texture, motion=motion,
                        picture=picture)
    return within_budget(person, budget)


def within_budget(face: BaseFace, budget: int | None = None) -> bytes:
    """``face``'s file with its reference picture at the AV1 CRF of QUALITY or, while the file is over
    ``budget`` bytes (None: BUDGET, HD_BUDGET for an HD picture; 0: no budget), coarser by 2 up to
    COARSEST_CRF; then, while still over, without its motion basis's last pattern (the one that
    explained least of the enrolment clip), down to LEAST_PATTERNS."""
    data = encode_face(face)
    if face.picture is None or budget == 0:
        return data
    h, w = face.picture.image.shape[:2]
    budget = budget or (HD_BUDGET if h * w > HD_PIXELS else BUDGET)
    crf = QUALITY[PICTURE_FORMAT]
    while len(data) > budget and crf < COARSEST_CRF:
        crf += 2
        data = encode_face(face, picture_quality=crf)
    while len(data) > budget and face.motion is not None and len(face.motion.vectors) > LEAST_PATTERNS:
        motion = face.motion
        face = replace(face, motion=replace(motion, vectors=motion.vectors[:-1],
                                            steps=None if motion.steps is None else motion.steps[:-1]))
        data = encode_face(face, picture_quality=crf)
    return data


def decode_face(data: bytes, origin: str = "face model") -> BaseFace:
    """The BaseFace in a face file's bytes, its content_id their sha256; InputError naming
    ``origin`` (a path, or the stream) if they are not one."""
    def bad(why: str):
        return InputError(f"{origin}: not an fd face model ({why})")

    if len(data) > MAX_FILE:
        raise bad(f"over {MAX_FILE >> 20} MiB")
    if len(data) < _PREFIX.size or data[:6] != MAGIC:
        raise bad("no FDFACE mark")
    _, version, _, n_text = _PREFIX.unpack_from(data)
    if version not in READS:
        raise bad(f"version {version}, this program reads {READS[0]}-{READS[-1]}")
    try:
        info = json.loads(data[_PREFIX.size:_PREFIX.size + n_text])
        n, m, n_tex, meta = int(info["vertices"]), int(info["faces"]), int(info["texture"]), info["meta"]
        k, c, over = info.get("motion", (0, 0, "rest"))
        k, c = int(k), int(c)
        n_pic, pic_w, pic_h = (int(x) for x in info.get("picture", (0, 0, 0)))
        n_mouth, mouth_w, mouth_h = (int(x) for x in info.get("mouth", (0, 0, 0)))
        n_shut, shut_w, shut_h, shut_x, shut_y = (int(x) for x in info.get("shut_eyes", (0,) * 5)) \
            if version >= SHUT_EYES_VERSION else (0,) * 5
        if version >= 7:  # counts here, the numbers packed
            n_rings, n_points = int(info.get("rings", 0)), int(info.get("mouth_points", 0))
        else:
            projection = np.array(info.get("projection", np.zeros((3, 4))), dtype=np.float64)
            mouth_points = np.array(info.get("mouth_points", np.zeros((0, 2))), dtype=np.float64)
            rings = None if "rings" not in info else np.array(info["rings"], dtype=np.int64)
        n_packed = int(info["packed"]) if version >= 6 else 0
        n_coded = int(info["coded"]) if version >= CODED_VERSION else 0
        mesh_steps = int(info.get("mesh", MESH_STEPS))
        uv_base = version >= 6 and info.get("uv") == "base"
        topology_base = version >= 6 and info.get("topology") == "base"
    except (ValueError, KeyError, TypeError, OverflowError, RecursionError):
        raise bad("unreadable description") from None
    if not MESH_STEPS_ALLOWED[0] <= mesh_steps <= MESH_STEPS_ALLOWED[1]:
        raise bad(f"mesh in steps of 1/{mesh_steps}")
    if n != N_LANDMARKS or not 0 < m <= MAX_FACES or n_tex < 0 or (topology_base and m != len(_base().faces)):
        raise bad(f"{n} vertices, {m} triangles")
    if (k, c) != (0, 0) and not (0 < k <= n and 0 < c <= MAX_COMPONENTS and over in OVER):
        raise bad(f"motion basis of {c} patterns over {k} vertices")
    if version >= 4 and meta == "base":
        meta = _base().meta
    pos = _PREFIX.size + n_text
    n_motion = _motion_size(version, k, c)
    if n_pic < 0 or (n_pic and not all(PICTURE_SIDES[0] <= x <= PICTURE_SIDES[1] for x in (pic_w, pic_h))):
        raise bad(f"reference picture of {pic_w}x{pic_h} pixels")
    if n_mouth < 0 or (n_mouth and not (n_pic and all(0 < x <= s for x, s in ((mouth_w, pic_w), (mouth_h, pic_h))))):
        raise bad(f"open mouth of {mouth_w}x{mouth_h} pixels")
    if n_shut < 0 or (n_shut and not (n_pic and 0 < shut_w and 0 < shut_h and 0 <= shut_x and 0 <= shut_y
                                      and shut_x + shut_w <= pic_w and shut_y + shut_h <= pic_h)):
        raise bad(f"shut eyes of {shut_w}x{shut_h} pixels at ({shut_x}, {shut_y})")
    if version >= 7 and not (0 <= n_rings <= MAX_RINGS and 0 <= n_points <= N_LANDMARKS
                             and (n_pic or not n_rings) and (n_mouth or not n_points)):
        raise bad(f"{n_rings} ring weights, {n_points} open mouth points")
    n_numbers = (96 if n_pic else 0) + n_rings + 8 * n_points if version >= 7 else 0
    widths = ((0 if version >= CODED_VERSION else 6 if version >= 6 else 12) * n, 0 if uv_base else 8 * n,
              0 if topology_base else 6 * m)
    n_raw = sum(widths) + n_motion + n_numbers
    n_stored = n_packed if version >= 6 else n_raw
    if n_stored < 0 or n_coded < 0 or len(data) != pos + n_stored + n_coded + n_tex + n_pic + n_mouth + n_shut:
        raise bad("its length does not match its description")
    raw = _unpacked(data[pos:pos + n_stored], n_raw, bad) if version >= 6 else data[pos:pos + n_raw]
    faces = _base().faces if topology_base else \
        np.frombuffer(raw, "<u2", 3 * m, widths[0] + widths[1]).reshape(m, 3).astype(np.int32)
    if faces.max() >= n:
        raise bad("vertex, texture coordinate or triangle out of range")
    coded = np.zeros(0, np.int64)
    if version >= CODED_VERSION:  # the mesh's steps and the basis's differences
        coded = decode_integers(data[pos + n_stored:pos + n_stored + n_coded], *_groups(n, c, k))
        steps = _steps_back(coded[:3 * n].reshape(1, n, 3), _stored_order(np.arange(n), faces), False)[0]
        vertices = _base().vertices + steps / mesh_steps
    elif version >= 6:
        vertices = _base().vertices + np.frombuffer(raw, "<i2", 3 * n).reshape(n, 3) / VERTEX_STEPS
    else:
        vertices = np.frombuffer(raw, "<f4", 3 * n).reshape(n, 3).astype(np.float64)
    uv = _base().uv if uv_base else np.frombuffer(raw, "<f4", 2 * n, widths[0]).reshape(n, 2).astype(np.float64)
    if not (np.all(np.isfinite(vertices)) and np.all(np.abs(vertices) < 10) and np.all(np.isfinite(uv))):
        raise bad("vertex, texture coordinate or triangle out of range")
    motion = _decode_motion(raw, sum(widths), k, c, over, version, faces, coded[3 * n:], bad) if k else None
    if version >= 7 and n_pic:
        at = sum(widths) + n_motion
        projection = np.frombuffer(raw, "<f8", 12, at).reshape(3, 4).copy()
        rings = np.frombuffer(raw, "u1", n_rings, at + 96).astype(np.int64) if "rings" in info else None
        mouth_points = np.frombuffer(raw, "<f4", 2 * n_points, at + 96 + n_rings).reshape(-1, 2).astype(np.float64)
    end = len(data) - n_pic - n_mouth - n_shut
    texture = _decode_texture(data[end - n_tex:end], bad) if n_tex else None
    face = build_face(vertices, faces, uv, meta, face_id(data), texture, origin, motion)
    if not n_pic:
        return face
    picture = _decode_picture(data[end:end + n_pic], (pic_w, pic_h), projection, bad)
    if rings is not None:
        picture = replace(picture, ring_weights=_ring_weights(rings, faces, bad))
    at = end + n_pic
    if n_mouth:
        picture = replace(picture, mouth=_decode_image(data[at:at + n_mouth], (mouth_w, mouth_h), "open mouth", bad),
                          mouth_points=_mouth_points(mouth_points, face, (mouth_w, mouth_h), bad))
    if n_shut:
        picture = replace(picture, shut_eyes=_decode_image(data[at + n_mouth:], (shut_w, shut_h), "shut eyes", bad),
                          shut_eyes_at=(shut_x, shut_y))
    return replace(face, picture=picture)


def _unpacked(packed: bytes, size: int, bad) -> bytes:
    """Version 6's mesh and basis: ``packed`` inflated to exactly ``size`` bytes (never more)."""
    inflate = lzma.LZMADecompressor(lzma.FORMAT_RAW, filters=_PACKING)
    try:
        raw = inflate.decompress(packed, max_length=size)
    except lzma.LZMAError:
        raise bad("damaged mesh") from None
    if len(raw) != size or not inflate.eof or inflate.unused_data:
        raise bad("its mesh does not match its description")
    return raw


def _stored_order(vertices: np.ndarray, faces: np.ndarray) -> list[tuple[int, list[int]]]:
    """The order a version 8 basis stores its vertices in: (position in ``vertices``, positions of its
    mesh neighbours stored before it) each, breadth first over the mesh ``faces`` from the first vertex
    (and from the next one not yet reached, where the basis's vertices are not all connected)."""
    at = {int(v): i for i, v in enumerate(vertices)}
    near: list[set[int]] = [set() for _ in vertices]
    for triangle in faces.tolist():
        inside = [at[v] for v in triangle if v in at]
        for i in inside:
            near[i].update(j for j in inside if j != i)
    order: list[tuple[int, list[int]]] = []
    reached, stored = [False] * len(vertices), [False] * len(vertices)
    for root in range(len(vertices)):
        if reached[root]:
            continue
        reached[root] = True
        queue = deque([root])
        while queue:
            i = queue.popleft()
            order.append((i, sorted(j for j in near[i] if stored[j])))
            stored[i] = True
            for j in sorted(near[i]):
                if not reached[j]:
                    reached[j] = True
                    queue.append(j)
    return order


def _guess(values: np.ndarray, before: list[int]):
    """A vertex's steps as its neighbours stored before it suggest: their mean, rounded (0 for none)."""
    if not before:
        return 0
    return (2 * values[:, before].sum(axis=1) + len(before)) // (2 * len(before))


def _encode_motion(motion: MotionBasis, faces: np.ndarray) -> tuple[bytes, np.ndarray]:
    """A motion basis as version 10 stores it: its steps u1 (c), packed; its vertices, each as the step
    from the one before, then per stored vertex (_stored_order) and pattern the steps' difference from
    their guess (c, k, 3), coded."""
    steps = np.full(motion.components, MOST_STEPS) if motion.steps is None else np.asarray(motion.steps, np.int64)
    values = np.rint(motion.vectors * steps[:, None, None]).astype(np.int64)
    vertices = np.asarray(motion.vertices, np.int64)
    return steps.astype("u1").tobytes(), np.concatenate([
        np.diff(vertices, prepend=-1), _differences(values, _stored_order(vertices, faces)).ravel()])


def _differences(values: np.ndarray, order: list[tuple[int, list[int]]]) -> np.ndarray:
    """(c, k, 3) ``values`` as each stored vertex's difference from its guess, in the stored ``order``."""
    return np.stack([values[:, i] - _guess(values, before) for i, before in order], axis=1)


def _steps_back(differences: np.ndarray, order: list[tuple[int, list[int]]], wrap: bool) -> np.ndarray:
    """The (c, k, 3) values that :func:`_differences` made ``differences`` of; ``wrap``: a version 8-9
    basis, whose differences were stored modulo 256 (as u1) and whose steps lie within +-128."""
    values = np.zeros_like(differences)
    for n, (i, before) in enumerate(order):
        guessed = _guess(values, before) + differences[:, n]
        values[:, i] = (guessed + 128) % 256 - 128 if wrap else guessed
    return values


def _pattern_type(version: int) -> str:
    """The dtype of a version 2-7 file's pattern coordinates."""
    return "<i1" if version >= 5 else "<f2" if version == 4 else "<f4"


def _motion_size(version: int, k: int, c: int) -> int:
    """Bytes of a motion basis of c patterns over k vertices in a file of ``version``."""
    if version >= CODED_VERSION:
        return c
    if version >= 8:
        return 2 * k + c + 3 * c * k
    return 2 * k + 3 * np.dtype(_pattern_type(version)).itemsize * c * k


def _decode_motion(data: bytes, pos: int, k: int, c: int, over: str, version: int, faces: np.ndarray,
                   coded: np.ndarray, bad) -> MotionBasis:
    """The motion basis at ``pos`` in a file's unpacked ``data``, with its vertices and differences
    ``coded`` in version 10 (else in ``data``)."""
    wrap = version < CODED_VERSION
    vertices = np.frombuffer(data, "<u2", k, pos).astype(np.int64) if wrap else np.cumsum(coded[:k]) - 1
    if vertices.min() < 0 or vertices.max() >= N_LANDMARKS or len(set(vertices.tolist())) != k:
        raise bad("motion basis out of range")
    if version >= 8:
        pos += 2 * k if wrap else 0
        steps = np.frombuffer(data, "u1", c, pos).astype(np.int64)
        if steps.min() < 1 or steps.max() > MOST_STEPS:
            raise bad("motion basis out of range")
        differences = np.frombuffer(data, "u1", 3 * c * k, pos + c).reshape(c, k, 3).astype(np.int64) \
            if wrap else coded[k:].reshape(c, k, 3)
        values = _steps_back(differences, _stored_order(vertices, faces), wrap)
        if np.any(np.abs(values) > steps[:, None, None]):
            raise bad("motion basis out of range")
        return MotionBasis(vertices, values / steps[:, None, None], over, steps)
    pattern = _pattern_type(version)
    vectors = np.frombuffer(data, pattern, 3 * c * k, pos + 2 * k).reshape(c, k, 3).astype(np.float64)
    if pattern == "<i1":
        vectors /= PATTERN_SCALE
    if not np.all(np.abs(vectors) <= 10):
        raise bad("motion basis out of range")
    return MotionBasis(vertices, vectors, over)


def _decode_texture(data: bytes, bad) -> np.ndarray:
    size = image_size(data)  # before decoding: a small file can declare a huge image
    image = None if size is None or max(size) > MAX_TEXTURE_SIDE or min(size) < 1 else \
        cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    if image is None or image.shape[1::-1] != size:
        raise bad(f"texture is not a JPEG or PNG image up to {MAX_TEXTURE_SIDE} pixels")
    return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)


def _decode_picture(data: bytes, size: tuple[int, int], projection: np.ndarray, bad) -> ReferencePicture:
    """The reference picture, refused unless it decodes to its declared size and its projection
    is a similarity that puts a face of sensible size near the picture."""
    try:
        place = Placement.from_matrix(projection)
    except ValueError as exc:
        raise bad(str(exc)) from None
    side = max(size)
    centre = place.shift * [1.0, -1.0, 1.0]
    if not (FACE_IN_PICTURE[0] * side <= place.scale <= FACE_IN_PICTURE[1] * side
            and np.all(np.abs(centre) <= 4 * side)):
        raise bad("the reference picture's projection puts the face out of the picture")
    return ReferencePicture(_decode_image(data, size, "reference picture", bad), projection)


def _decode_image(data: bytes, size: tuple[int, int], what: str, bad) -> np.ndarray:
    """The image (AV1, or WebP, JPEG or PNG), decoded only once its header declares the ``size`` the
    face model does (AV1: within as many pixels, checked by the decoder before it allocates them)."""
    if data[:1] == _AV1_SEQUENCE:  # an odd side coded one longer (encode_still)
        image = StillDecoder(even(size)).decode_still(data)
        if image is not None and image.shape[1::-1] == even(size):
            return np.ascontiguousarray(image[:size[1], :size[0]])
    else:
        image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR) if image_size(data) == size else None
        if image is not None and image.shape[1::-1] == size:
            return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
    raise bad(f"{what} is not a {size[0]}x{size[1]} AV1, WebP, JPEG or PNG image")


def _mouth_points(points: np.ndarray, face: BaseFace, size: tuple[int, int], bad) -> np.ndarray:
    """The open mouth's (k, 2) vertex positions, refused unless one per mouth vertex and inside it."""
    if points.shape != (len(mouth_vertices(face)), 2) or not np.all(np.isfinite(points)) \
            or np.any(points < -1) or np.any(points > np.array(size) + 1):
        raise bad("open mouth's points do not fit it")
    return points


@cache
def _base() -> BaseFace:
    """The generic face, whose vertices, uv, topology and feature points (most face files share
    the last three) face files start from."""
    return load_base_face()


def _ring_weights(rings: np.ndarray, faces: np.ndarray, bad) -> np.ndarray:
    """The rings' weights in 0..1, refused unless one byte per ring vertex of the face's scene mesh."""
    if rings.shape != (len(RINGS) * len(outer_loop(faces)),) or np.any(rings < 0) or np.any(rings > 255):
        raise bad("ring weights do not fit the face")
    return rings / 255.0


def _file_key(key: bytes, salt: bytes) -> AESGCM:
    return AESGCM(derive(key, salt, b"facedeform face file v1", 32))


def seal_face(data: bytes, key: bytes) -> bytes:
    """A face file's bytes encrypted and authenticated with ``key`` (a stream key)."""
    salt, nonce = os.urandom(16), os.urandom(12)
    head = SEALED + salt + nonce
    return head + _file_key(key, salt).encrypt(nonce, data, head)


def open_face(data: bytes, key: bytes | None, origin: str = "face model") -> bytes:
    """The plain bytes of a face file, sealed or not; InputError without the right key."""
    if not data.startswith(SEALED):
        return data
    if key is None:
        raise InputError(f"{origin} is encrypted: give --key FILE")
    head = data[:len(SEALED) + 28]
    try:
        return _file_key(key, head[len(SEALED):-12]).decrypt(head[-12:], data[len(head):], head)
    except (InvalidTag, ValueError):
        raise InputError(f"{origin}: cannot decrypt (sealed with another key, or damaged)") from None


def read_face_bytes(path: str | Path, key: bytes | None = None) -> bytes:
    """A face file's plain bytes (opened with ``key`` if sealed); InputError (one line) if unreadable."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except IsADirectoryError:
        raise InputError(f"{path}: not a file") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror or exc})") from None
    return open_face(data, key, str(path))


def save_face_file(data: bytes, path: str | Path, key: bytes | None = None) -> str:
    """Writes a face file's bytes, sealed with ``key`` if given; returns its id (the plain file's)."""
    try:
        Path(path).write_bytes(data if key is None else seal_face(data, key))
    except OSError as exc:
        raise InputError(f"{path}: cannot write ({exc.strerror or exc})") from None
    return face_id(data)


@dataclass(frozen=True, eq=False)
class Face:
    """A person's face model as the bytes both ends hold (what fd-enroll writes): ``data`` is the
    plain face file, ``id`` its sha256 (what a stream names), ``model`` the decoded BaseFace."""

    data: bytes

    @classmethod
    def load(cls, path: str | Path, key: bytes | None = None) -> "Face":
        """The face model in a file, sealed or not; InputError (one line) if it is missing or not one."""
        face = cls(read_face_bytes(path, key))
        face._decode(str(path))
        return face

    @property
    def id(self) -> str:
        return face_id(self.data)

    @cached_property
    def model(self) -> BaseFace:
        return self._decode("face model")

    def _decode(self, origin: str) -> BaseFace:
        model = decode_face(self.data, origin)
        self.__dict__["model"] = model  # cached_property's slot, filled once with the origin's name in errors
        return model

    def save(self, path: str | Path, key: bytes | None = None) -> str:
        """Writes the file (sealed with ``key`` if given); returns its id."""
        return save_face_file(self.data, path, key)
