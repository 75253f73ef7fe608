"""An image's width and height read from its header, before any pixel is decoded.

A face model (in a file, or in-band in a stream) carries PNG, JPEG or WebP
images; a small file can declare a huge picture (a 140 KB PNG of 30000x30000
pixels decodes to 2.7 GB). Readers check these dimensions against what the
model declares and allows, and only then decode. Anything that is not one of
the three formats, or whose header does not parse, has no size here.
"""

import struct

PNG = b"\x89PNG\r\n\x1a\n"
#: JPEG start-of-frame markers (baseline, progressive, lossless, arithmetic): they carry the size.
JPEG_SOF = {0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF}
JPEG_STANDALONE = {0x01, *range(0xD0, 0xDA)}  # markers without a length field
WEBP_ANIMATION = 0x02  # VP8X flag: frames of their own sizes, refused


def image_size(data: bytes) -> tuple[int, int] | None:
    """(width, height) of a PNG, JPEG or WebP image's bytes, or None if they are not one."""
    if data.startswith(PNG):
        return _png(data)
    if data.startswith(b"\xff\xd8"):
        return _jpeg(data)
    if data[:4] == b"RIFF" and data[8:12] == b"WEBP":
        return _webp(data)
    return None


def _png(data: bytes) -> tuple[int, int] | None:
    if len(data) < 24 or data[12:16] != b"IHDR":
        return None
    width, height = struct.unpack_from(">II", data, 16)
    return width, height


def _jpeg(data: bytes) -> tuple[int, int] | None:
    pos = 2
    while pos + 4 <= len(data):
        if data[pos] != 0xFF:
            return None
        marker = data[pos + 1]
        if marker == 0xFF:  # fill byte
            pos += 1
            continue
        if marker in JPEG_STANDALONE:
            pos += 2
            continue
        (length,) = struct.unpack_from(">H", data, pos + 2)
        if marker in JPEG_SOF:
            if length < 7 or pos + 9 > len(data):
                return None
            height, width = struct.unpack_from(">HH", data, pos + 5)
            return width, height
        if marker == 0xDA or length < 2:  # image data before any frame header
            return None
        pos += 2 + length
    return None


def _webp(data: bytes) -> tuple[int, int] | None:
    chunk, body = data[12:16], 20
    if chunk == b"VP8 " and len(data) >= body + 10 and data[body + 3:body + 6] == b"\x9d\x01\x2a":
        width, height = struct.unpack_from("<HH", data, body + 6)
        return width & 0x3FFF, height & 0x3FFF
    if chunk == b"VP8L" and len(data) >= body + 5 and data[body] == 0x2F:
        (bits,) = struct.unpack_from("<I", data, body + 1)
        return (bits & 0x3FFF) + 1, ((bits >> 14) & 0x3FFF) + 1
    if chunk == b"VP8X" and len(data) >= body + 10 and not data[body] & WEBP_ANIMATION:
        width = int.from_bytes(data[body + 4:body + 7], "little") + 1
        height = int.from_bytes(data[body + 7:body + 10], "little") + 1
        return width, height
    return None
