"""Shared material of the skin tests: a strip of three 4x4 patches side by side (48 mm apart,
so each touches its neighbours), all simulated."""

from __future__ import annotations


def strip_skin(extra_defaults: str = "") -> str:
    """The strip's skin description (TOML); ``extra_defaults`` adds lines to ``[defaults]``
    (e.g. ``'model = "model.eskin"'``)."""
    return f"""
name = "strip"
[defaults]
grid = [4, 4]
sample_rate_hz = 3000
pitch_mm = 12.0
link = "simulated"
{extra_defaults}
[[patch]]
id = "p0"
[[patch]]
id = "p1"
origin_mm = [48.0, 0.0]
[[patch]]
id = "p2"
origin_mm = [96.0, 0.0]
"""
