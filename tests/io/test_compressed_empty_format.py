"""A CompressedImage whose ``format`` is empty: decoded by its bytes' magic (bug hunt 16B F9).

Before: refused ("unsupported compressed image format ''"), though README says png and jpeg
are told apart by their bytes and mislabelled ones decode.
"""

from __future__ import annotations

from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from pcainterp_stream.io.logreader import decode_image


@pytest.mark.parametrize("ext", [".png", ".jpg"])
def test_an_empty_format_decodes_by_the_bytes(ext: str) -> None:
    rng = np.random.default_rng(4)
    bgr = rng.integers(0, 256, (12, 16, 3), dtype=np.uint8)
    ok, encoded = cv2.imencode(ext, bgr)
    assert ok
    image = decode_image(SimpleNamespace(format="", data=encoded.ravel()))
    assert image.shape == (12, 16, 3)
    if ext == ".png":  # lossless: the RGB of the BGR written
        assert np.array_equal(image, bgr[..., ::-1])


def test_an_empty_format_with_other_bytes_is_still_refused() -> None:
    data = np.frombuffer(b"GIF89a" + bytes(32), dtype=np.uint8)
    with pytest.raises(ValueError, match="unsupported compressed image format ''"):
        decode_image(SimpleNamespace(format="", data=data))
