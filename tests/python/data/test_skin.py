"""eskin.data.skin: the skin description file, its layout, adjacency and one-line errors."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from eskin.data.skin import SIMULATED, load_skin
from eskin.errors import SkinFormatError

EXAMPLE = Path(__file__).resolve().parents[3] / "docs" / "examples" / "forearm_skin.toml"

THREE = """
name = "strip"
[defaults]
grid = [2, 3]
sample_rate_hz = 1000
pitch_mm = 10.0
link = "simulated"
model = "m.eskin"

[[patch]]
id = "a"
[[patch]]
id = "b"
origin_mm = [40.0, 0.0]
[[patch]]
id = "c"
origin_mm = [0.0, 0.0]
rotation_deg = 90.0
link = "/dev/ttyACM0"
model = "other.eskin"
"""


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "skin.toml"
    path.write_text(text)
    return path


def test_the_example_skin_has_16_patches_joined_edge_to_edge():
    skin = load_skin(EXAMPLE)
    assert len(skin) == 16 and skin.name == "forearm"
    assert all(p.grid == (4, 4) and p.sample_rate_hz == 3000.0 and p.simulated
               for p in skin.patches)
    # a patch in the middle of the forearm touches its 4 edge neighbours, not the corner ones
    assert skin.neighbours("forearm-11") == ("forearm-01", "forearm-10", "forearm-12",
                                             "forearm-21")
    assert skin.neighbours("palm-0") == ("forearm-30", "palm-1", "thumb")  # thumb: by hand
    for a in skin.ids:  # symmetric
        for b in skin.neighbours(a):
            assert a in skin.neighbours(b)


def test_layout_fields_defaults_and_relative_model_paths(tmp_path):
    skin = load_skin(write(tmp_path, THREE))
    a, b, c = skin.patches
    assert a.grid == (2, 3) and a.sample_rate_hz == 1000.0 and a.link == SIMULATED
    assert a.model == tmp_path / "m.eskin" and c.model == tmp_path / "other.eskin"
    assert c.link == "/dev/ttyACM0" and not c.simulated
    # taxel (r, k) at origin + (k * pitch, -r * pitch), row-major
    np.testing.assert_allclose(a.taxels_mm, [[0, 0], [10, 0], [20, 0],
                                             [0, -10], [10, -10], [20, -10]])
    np.testing.assert_allclose(b.taxels_mm[0], [40, 0])
    # turned 90 degrees counter-clockwise: columns go up, rows go right
    np.testing.assert_allclose(c.taxels_mm[[1, 3]], [[0, 10], [10, 0]], atol=1e-12)
    # a and c share taxel (0, 0)'s place; b is 20 mm (2 pitches) from a: not adjacent
    assert skin.neighbours("a") == ("c",) and skin.neighbours("b") == ()
    assert math.isclose(float(a.centre_mm[0]), 10.0)


def test_explicit_taxels_and_neighbours(tmp_path):
    skin = load_skin(write(tmp_path, """
adjacency_mm = 1.0
[[patch]]
id = "x"
grid = [1, 2]
sample_rate_hz = 500
link = "simulated"
taxels_mm = [[0.0, 0.0], [5.0, 1.0]]
neighbours = ["y"]
[[patch]]
id = "y"
grid = [1, 1]
sample_rate_hz = 500
link = "simulated"
taxels_mm = [[100.0, 0.0]]
"""))
    np.testing.assert_allclose(skin.patch("x").taxels_mm, [[0, 0], [5, 1]])
    assert skin.neighbours("y") == ("x",) and skin.patch("x").model is None
    assert skin.with_model(tmp_path / "z.eskin").patch("y").model == tmp_path / "z.eskin"


@pytest.mark.parametrize("change, field, words", [
    (("grid = [2, 3]", "grid = [2, 0]"), "patch[0].grid", "1..255"),
    (("grid = [2, 3]", 'grid = "2x3"'), "patch[0].grid", "[rows, cols]"),
    (("sample_rate_hz = 1000", "sample_rate_hz = -5"), "patch[0].sample_rate_hz", "-5"),
    (('id = "b"', 'id = "a"'), "patch[1].id", "already the id of patch[0]"),
    (('id = "b"', 'id = "b/../x"'), "patch[1].id", "letters, digits"),
    (("rotation_deg = 90.0", "rotation_deg = nan"), "patch[2].rotation_deg", "finite"),
    (("origin_mm = [40.0, 0.0]", "origin_mm = [40.0]"), "patch[1].origin_mm", "pair"),
    (('link = "/dev/ttyACM0"', 'lnk = "/dev/ttyACM0"'), "patch[2].lnk", "unknown key"),
    (("pitch_mm = 10.0", "pitch_mm = 0"), "patch[0].pitch_mm", "> 0"),
])
def test_bad_fields_are_one_line_errors_naming_file_field_value(tmp_path, change, field, words):
    path = write(tmp_path, THREE.replace(*change, 1))
    with pytest.raises(SkinFormatError) as err:
        load_skin(path)
    msg = str(err.value)
    assert msg.startswith(f"{path}: {field}: ") and words in msg and "\n" not in msg
    assert err.value.field == field


def test_missing_and_broken_files(tmp_path):
    with pytest.raises(SkinFormatError, match="no such file"):
        load_skin(tmp_path / "none.toml")
    with pytest.raises(SkinFormatError, match="not valid TOML"):
        load_skin(write(tmp_path, "name = \n"))
    with pytest.raises(SkinFormatError, match=r"patch: no \[\[patch\]\] table"):
        load_skin(write(tmp_path, 'name = "empty"\n'))
    no_grid = THREE.replace("grid = [2, 3]\n", "")
    with pytest.raises(SkinFormatError, match=r"patch\[0\]\.grid: missing"):
        load_skin(write(tmp_path, no_grid))
    with pytest.raises(SkinFormatError, match=r"neighbours: 'q': not the id"):
        load_skin(write(tmp_path, THREE + 'neighbours = ["q"]\n'))
    with pytest.raises(SkinFormatError, match="format_version: 2"):
        load_skin(write(tmp_path, "format_version = 2\n" + THREE))
