"""eskin.link.skin_classifier: one stream classifier per patch behind one object; each patch
keeps its own stream state, and decides as the compiled model's stream classifier does."""

from __future__ import annotations

import numpy as np
import pytest

from eskin.data.skin import parse_skin
from eskin.deploy.export import CompiledModel
from eskin.link.skin_classifier import SkinClassifier
from web_data import synthetic_touch


def skin_of(tmp_path, data_dir, third_model=None):
    (tmp_path / "m.eskin").write_bytes((data_dir / "model_small_float64.eskin").read_bytes())
    rows = [{"id": "a", "model": "m.eskin"}, {"id": "b", "model": "m.eskin"}, {"id": "c"}]
    if third_model is not None:
        rows[2]["model"] = third_model
    data = {"defaults": {"grid": [4, 4], "sample_rate_hz": 3000, "link": "simulated"},
            "patch": rows}
    return parse_skin(data, path=tmp_path / "skin.toml")


def stream(samples):
    return np.concatenate([r.reshape(16, -1).T for r in samples]).astype(np.int16)


def test_each_patch_decides_as_the_compiled_stream_classifier(tmp_path, data_dir):
    skin = skin_of(tmp_path, data_dir)
    clf = SkinClassifier(skin)
    assert clf.has_model("a") and clf.has_model("b") and not clf.has_model("c")
    assert clf.patch_view("c") is None
    x = stream([synthetic_touch(k, 7 + k) for k in range(3)])
    y = stream([synthetic_touch(2 - k, 3 + k) for k in range(3)])
    # patch a sees x in two pieces, with patch b's samples fed in between: its own state
    touches_a = clf.push("a", x[:4000])
    touches_b = clf.push("b", y)
    touches_a += clf.push("a", x[4000:]) + clf.flush("a")
    touches_b += clf.flush("b")
    compiled = CompiledModel(tmp_path / "m.eskin")
    for touches, samples in ((touches_a, x), (touches_b, y)):
        expected = [e for e in compiled.stream(samples.astype(np.float64)) if "label" in e]
        assert [(t.start, t.stop, compiled.class_names[t.label_index]) for t in touches] == [
            (e["window"][0], e["window"][1], e["label"]) for e in expected]
    assert touches_a  # the synthetic touches were found


def test_the_patch_view_is_the_patch(tmp_path, data_dir):
    clf = SkinClassifier(skin_of(tmp_path, data_dir))
    view = clf.patch_view("b")
    assert view.grid == (4, 4) and view.kind == "compiled"
    assert view.class_names == clf.class_names("b") == ["brush", "finger", "washer"]
    x = stream([synthetic_touch(1, 4)])
    assert view.push(x) + view.flush() == clf.push("a", x) + clf.flush("a")


def test_a_model_of_another_grid_or_a_missing_file_is_refused(tmp_path, data_dir):
    data = {"defaults": {"grid": [3, 3], "sample_rate_hz": 3000, "link": "simulated"},
            "patch": [{"id": "a", "model": "m.eskin"}]}
    (tmp_path / "m.eskin").write_bytes((data_dir / "model_small_float64.eskin").read_bytes())
    with pytest.raises(ValueError, match="a 4x4 model for patch 'a', whose grid is 3x3"):
        SkinClassifier(parse_skin(data, path=tmp_path / "s.toml"))
    with pytest.raises(FileNotFoundError, match="none.eskin does not exist"):
        SkinClassifier(skin_of(tmp_path, data_dir, third_model="none.eskin"))
