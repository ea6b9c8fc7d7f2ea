"""Texture images: decoding (PNG/JPEG, bounded), PNG encoding and bilinear sampling at UVs.

Decisions
---------
- **Formats**: PNG and JPEG only (what OBJ ``map_Kd`` and glTF ``baseColorTexture`` use in
  practice); anything else is an :class:`InputFormatError`.
- **Decompression bombs**: the image's width x height is read from its header and checked
  against ``max_pixels`` (default :data:`MAX_TEXTURE_PIXELS`, 8192 x 8192) *before* any pixel
  is decoded, so a small file declaring a huge image costs nothing; Pillow's own bomb check
  stays on as a second guard.
- **UV convention**: glTF's, origin at the image's top-left corner, ``u`` to the right, ``v``
  down; pixel ``(row i, column j)`` covers ``[j, j+1] / W x [i, i+1] / H``. OBJ's ``vt`` (origin
  bottom-left) is converted by the caller (``v -> 1 - v``). Sampling wraps (glTF's default
  ``REPEAT``).
"""

from __future__ import annotations

import io

import numpy as np

from core.errors import InputFormatError

MAX_TEXTURE_PIXELS = 8192 * 8192
_FORMATS = ("PNG", "JPEG")


def decode_image(
    data: bytes, *, name: str = "texture image", max_pixels: int = MAX_TEXTURE_PIXELS
) -> np.ndarray:
    """Decode a PNG or JPEG into an (H, W, 3) uint8 RGB array (alpha dropped, palettes and
    grey expanded).

    Raises
    ------
    InputFormatError
        Not a PNG/JPEG, corrupt or truncated data, or more than ``max_pixels`` pixels (checked
        from the header, before decoding).
    """
    from PIL import Image, UnidentifiedImageError

    def too_large(w: int | str, h: int | str) -> InputFormatError:
        return InputFormatError(
            f"{name}: the image is {w} x {h} pixels, above the limit of {max_pixels:,} "
            "pixels; downscale the texture (e.g. to 4096 x 4096)",
            width=w,
            height=h,
            limit_pixels=max_pixels,
        )

    try:
        im = Image.open(io.BytesIO(data), formats=_FORMATS)
    except Image.DecompressionBombError:  # Pillow's own guard fired on the header first
        raise too_large("?", "?") from None
    except UnidentifiedImageError:
        raise InputFormatError(
            f"{name}: not a PNG or JPEG image (first bytes {bytes(data[:8])!r}); textures must "
            "be PNG or JPEG"
        ) from None
    except Exception as e:  # Pillow raises many types on corrupt headers
        raise InputFormatError(f"{name}: unreadable image ({type(e).__name__})") from None
    with im:
        w, h = im.size
        if w <= 0 or h <= 0 or w * h > max_pixels:
            raise too_large(w, h)
        try:
            rgb = im.convert("RGB") if im.mode != "RGB" else im
            rgb.load()
            out = np.asarray(rgb, dtype=np.uint8)
        except Exception as e:  # truncated or corrupt pixel data, bombs past the header check
            raise InputFormatError(
                f"{name}: cannot decode the image data ({type(e).__name__}); the file is "
                "truncated or corrupt"
            ) from None
    if out.shape != (h, w, 3):
        raise InputFormatError(f"{name}: unexpected decoded shape {out.shape}")
    return out


def encode_png(image: np.ndarray) -> bytes:
    """PNG bytes of an (H, W, 3) uint8 RGB image."""
    from PIL import Image

    img = np.ascontiguousarray(image, dtype=np.uint8)
    if img.ndim != 3 or img.shape[2] != 3:
        raise ValueError(f"image must have shape (H, W, 3), got {img.shape}")
    buf = io.BytesIO()
    Image.fromarray(img, "RGB").save(buf, format="PNG", optimize=False, compress_level=6)
    return buf.getvalue()


def sample_image(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear samples of ``image`` at texture coordinates, wrapping (glTF ``REPEAT``).

    Parameters
    ----------
    image : (H, W, c) uint8 or float image.
    uv : (k, 2) texture coordinates, glTF convention (origin top-left, v down).

    Returns
    -------
    (k, c) float64 values; uint8 images are scaled to [0, 1].
    """
    img = np.asarray(image)
    H, W = img.shape[:2]
    uv = np.asarray(uv, dtype=np.float64)
    x = uv[:, 0] * W - 0.5  # pixel-centre coordinates
    y = uv[:, 1] * H - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    x0 = x0.astype(np.int64)
    y0 = y0.astype(np.int64)
    i0, i1 = y0 % H, (y0 + 1) % H
    j0, j1 = x0 % W, (x0 + 1) % W
    val = (
        img[i0, j0] * ((1 - fx) * (1 - fy))
        + img[i0, j1] * (fx * (1 - fy))
        + img[i1, j0] * ((1 - fx) * fy)
        + img[i1, j1] * (fx * fy)
    )
    return val / 255.0 if img.dtype == np.uint8 else val
