"""The pairing summary's decoding reason keeps a quoted format whole (bug hunt 16B F10).

``'rgb8; compressedDepth'`` was cut at its ``;``: ``(unsupported compressed image format 'rgb8)``.
"""

from __future__ import annotations

from pcainterp_stream.frontend.pairing import _reason


def test_a_quoted_format_with_a_semicolon_is_kept_whole() -> None:
    err = ValueError(
        "unsupported compressed image format 'rgb8; compressedDepth'; supported: png, jpeg"
    )
    assert _reason(err) == "unsupported compressed image format 'rgb8; compressedDepth'"


def test_apostrophes_and_unquoted_clauses_still_cut() -> None:
    assert _reason(ValueError("densify's image does not decode; use png")) == (
        "densify's image does not decode"
    )
    assert _reason(ValueError('format "a (b)" is unknown (3 bytes)')) == 'format "a (b)" is unknown'
    assert _reason(ValueError("no clause at all")) == "no clause at all"
