"""A renewal of the picture as bytes: the residual image of receiver.face_view.residual_of, coded
as WebP at whichever scale and quality show it best within a byte budget.

WebP through OpenCV, because on the dev clips' 256x256 crops, where a renewal has 100 to 2,000
bytes, WebP scaled down matched AVIF's PSNR at the same bytes (at 680 bytes: WebP at 176 pixels
29.2 dB, AVIF 28.5 dB) and encodes five times faster (3-4 ms against 16-25 ms a picture), while
JPEG needs twice the bytes (docs/picture_layer.md). Decoding checks the image's own header
before a byte is decoded: a renewal never decodes to more than the reference picture's size.
"""

import cv2
import numpy as np

from facedeform.codec.image_header import image_size

FORMAT = ".webp"
SCALES = (0.125, 0.25, 0.375, 0.5, 0.75, 1.0)  # of the picture's size a residual is coded at
MIN_SIDE = 8  # pixels


def encode_renewal(residual: np.ndarray, budget: int) -> bytes | None:
    """The WebP of ``residual`` ((H, W, 3) uint8 RGB) of at most ``budget`` bytes that, scaled back
    to (W, H), is nearest to it, over SCALES and qualities (bisected per scale); None if
    nothing fits. Scales are tried from the smallest up, until the coarsest quality does not fit
    or the result is further than the scale below's."""
    height, width = residual.shape[:2]
    bgr = cv2.cvtColor(residual, cv2.COLOR_RGB2BGR)
    best: tuple[float, bytes] | None = None
    for scale in SCALES:
        size = (max(MIN_SIDE, round(width * scale)), max(MIN_SIDE, round(height * scale)))
        small = bgr if size == (width, height) else cv2.resize(bgr, size, interpolation=cv2.INTER_AREA)
        fitted = _webp(small, 1)
        if len(fitted) > budget:
            break
        lo, hi = 2, 100
        while lo <= hi:
            quality = (lo + hi) // 2
            data = _webp(small, quality)
            if len(data) <= budget:
                fitted, lo = data, quality + 1
            else:
                hi = quality - 1
        decoded = decode_renewal(fitted, (width, height))
        error = float(np.mean((decoded.astype(np.float32) - residual) ** 2)) if decoded is not None else np.inf
        if best is not None and error >= best[0]:
            break  # past the best scale: larger ones get fewer bytes a pixel still
        best = (error, fitted)
    return None if best is None else best[1]


def _webp(bgr: np.ndarray, quality: int) -> bytes:
    return cv2.imencode(FORMAT, bgr, [cv2.IMWRITE_WEBP_QUALITY, quality])[1].tobytes()


def decode_renewal(data: bytes, picture_size: tuple[int, int]) -> np.ndarray | None:
    """The (H, W, 3) uint8 RGB residual, scaled to ``picture_size`` (W, H); None unless ``data`` is a
    WebP of MIN_SIDE to the picture's size a side (checked before decoding)."""
    size = image_size(data)
    if size is None or not data.startswith(b"RIFF") or not all(
            MIN_SIDE <= s <= most for s, most in zip(size, picture_size)):
        return None
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    if image is None or image.shape[1::-1] != size:
        return None
    image = cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
    return image if size == tuple(picture_size) else cv2.resize(image, picture_size, interpolation=cv2.INTER_LINEAR)
