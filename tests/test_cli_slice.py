"""Tests of cli/slice.py: option parsing, and library errors named by the options that set the parameter."""

from __future__ import annotations

import pytest

from heoslice.cli.slice import flag_error, parse_dpi
from heoslice.errors import InputError


@pytest.mark.parametrize("text, expected", [("600", (600.0, 600.0)), ("600x300", (600.0, 300.0)),
                                            ("1200X1200", (1200.0, 1200.0))])
def test_parse_dpi_accepts_n_and_nxm(text, expected):
    """--dpi takes N or NxM."""
    assert parse_dpi(text) == expected


@pytest.mark.parametrize("text", ["", "abc", "0", "-5", "600x", "1x2x3"])
def test_parse_dpi_rejects_nonsense(text):
    """Anything else is a one-line input error."""
    with pytest.raises(InputError, match="--dpi"):
        parse_dpi(text)


@pytest.mark.parametrize("message, shown", [
    ("layer_height_mm: must be at least 0.001 mm", "--layer: must be at least 0.001 mm"),
    ("canvas_mm: 5 x 5 mm is smaller than the part", "--canvas: 5 x 5 mm is smaller than the part"),
    ("part.ply: no faces", "part.ply: no faces"),
    ("dpi_like: not a parameter of the slice", "dpi_like: not a parameter of the slice"),
])
def test_library_errors_name_the_option_that_sets_their_parameter(message, shown):
    """An error naming a SliceSpec parameter is shown with its option; any other message is left as it is."""
    assert str(flag_error(InputError(message))) == shown
