"""The one overwrite rule, through the real command line: every command that writes a file
refuses an existing file without --force and never writes onto one of its own inputs, even
with --force; the refused file keeps its bytes.

The check comes before any work, so the inputs here need not be valid campaigns or models:
a refusal must not even read them."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from typer.testing import CliRunner

from eskin._files import refuse_overwrite, refuse_overwrite_all, same_file
from eskin.cli import app
from eskin.errors import OverwriteError

OLD = b"recorded data that must survive\n"


def _file(path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(OLD)
    return path


def _run(args: list) -> object:
    return CliRunner().invoke(app, [str(a) for a in args])


def _refused(res, path: Path, why: str) -> None:
    assert res.exit_code == 2, res.output
    assert str(path) in res.output and why in res.output, res.output
    assert "Traceback" not in res.output
    assert path.read_bytes() == OLD


EXISTS = "file exists; refusing to overwrite it (use --force"
INPUT = "also an input of the command"


# ------------------------------------------------------------------ the rule itself


def test_the_rule(tmp_path):
    a = _file(tmp_path / "a.h5")
    assert refuse_overwrite(tmp_path / "new.h5") == tmp_path / "new.h5"
    assert refuse_overwrite(a, force=True) == a
    with pytest.raises(OverwriteError, match=re.escape(EXISTS)):
        refuse_overwrite(a)
    with pytest.raises(OverwriteError, match=INPUT):
        refuse_overwrite(a, force=True, inputs=(None, a))
    # the same file under another name is still the input
    (tmp_path / "link.h5").symlink_to(a)
    assert same_file(tmp_path / "link.h5", a)
    with pytest.raises(OverwriteError, match=INPUT):
        refuse_overwrite(tmp_path / "sub" / ".." / "link.h5", force=True, inputs=(a,))
    with pytest.raises(OverwriteError, match="given twice"):
        refuse_overwrite_all([tmp_path / "x", tmp_path / "x"])
    with pytest.raises(OverwriteError, match="is a folder"):
        refuse_overwrite(tmp_path, force=True)
    assert issubclass(OverwriteError, FileExistsError)


# ------------------------------------------------------------------ every writing command


def test_simulate(tmp_path):
    out = _file(tmp_path / "c.h5")
    _refused(_run(["simulate", "-o", out, "--participants", "1"]), out, EXISTS)


def test_plot(tmp_path):
    camp, png = _file(tmp_path / "c.h5"), _file(tmp_path / "p.png")
    _refused(_run(["plot", camp, "-o", png]), png, EXISTS)
    _refused(_run(["plot", camp, "-o", camp, "--force"]), camp, INPUT)


def test_import_csv(tmp_path):
    folder = tmp_path / "csv"
    manifest = _file(folder / "manifest.csv")
    rec = _file(folder / "r0.csv")
    out = _file(tmp_path / "c.h5")
    _refused(_run(["import-csv", folder, "-o", out]), out, EXISTS)
    _refused(_run(["import-csv", folder, "-o", manifest, "--force"]), manifest, INPUT)
    _refused(_run(["import-csv", folder, "-o", rec, "--force"]), rec, INPUT)


def test_import_tdms(tmp_path):
    tdms, out = _file(tmp_path / "a.tdms"), _file(tmp_path / "c.h5")
    _refused(_run(["import-tdms", tdms, "-o", out]), out, EXISTS)
    _refused(_run(["import-tdms", tdms, "-o", tdms, "--force"]), tdms, INPUT)


def test_replay(tmp_path):
    camp, out = _file(tmp_path / "c.h5"), _file(tmp_path / "s.eskr")
    _refused(_run(["replay", camp, "-o", out]), out, EXISTS)
    _refused(_run(["replay", camp, "-o", camp, "--format", "replay", "--force"]), camp, INPUT)


def test_train(tmp_path):
    camp, model = _file(tmp_path / "c.h5"), _file(tmp_path / "m.joblib")
    _refused(_run(["train", camp, "-o", model, "--all-classes"]), model, EXISTS)
    _refused(_run(["train", camp, "-o", camp, "--all-classes", "--force"]), camp, INPUT)


def test_predict_json(tmp_path):
    model, camp, js = (
        _file(tmp_path / "m.joblib"),
        _file(tmp_path / "c.h5"),
        _file(tmp_path / "p.json"),
    )
    _refused(_run(["predict", model, camp, "--json", js]), js, EXISTS)
    _refused(_run(["predict", model, camp, "--json", camp, "--force"]), camp, INPUT)
    _refused(_run(["predict", model, camp, "--json", model, "--force"]), model, INPUT)


def test_export_and_c_header(tmp_path):
    model, out = _file(tmp_path / "m.joblib"), _file(tmp_path / "m.eskin")
    header = _file(tmp_path / "m.h")
    _refused(_run(["export", model, "-o", out]), out, EXISTS)
    _refused(
        _run(["export", model, "-o", tmp_path / "new.eskin", "--c-header", header]), header, EXISTS
    )
    _refused(_run(["export", model, "-o", model, "--force"]), model, INPUT)
    res = _run(["export", model, "-o", out, "--c-header", out, "--force"])
    _refused(res, out, "given twice")


def test_experiment_out(tmp_path):
    camp = _file(tmp_path / "c.h5")
    results = _file(tmp_path / "out" / "results.json")
    _refused(_run(["experiment", camp, "--out", tmp_path / "out"]), results, EXISTS)
    camp2 = _file(tmp_path / "out2" / "results.json")
    _refused(_run(["experiment", camp2, "--out", tmp_path / "out2", "--force"]), camp2, INPUT)


def test_evaluate_out(tmp_path):
    camp = _file(tmp_path / "c.h5")
    report = _file(tmp_path / "out" / "evaluation.md")
    _refused(_run(["evaluate", camp, "--out", tmp_path / "out"]), report, EXISTS)


def test_listen_record_and_jsonl(tmp_path):
    port = tmp_path / "no-such-port"
    rec, js = _file(tmp_path / "live.h5"), _file(tmp_path / "d.jsonl")
    model = _file(tmp_path / "m.eskin")
    _refused(_run(["listen", port, "--record", rec]), rec, EXISTS)
    _refused(_run(["listen", port, "--jsonl", js]), js, EXISTS)
    _refused(_run(["listen", port, "--model", model, "--jsonl", model, "--force"]), model, INPUT)
    _refused(_run(["listen", port, "--record", js, "--jsonl", js, "--force"]), js, "given twice")


def test_demo_out(tmp_path):
    out = tmp_path / "demo"
    mine = _file(out / "my-notes.txt")
    res = _run(["demo", "--out", out])
    assert (
        res.exit_code == 2 and f"{out}: the folder holds files the demo did not write" in res.output
    )
    assert "(my-notes.txt)" in res.output and mine.read_bytes() == OLD
    not_a_folder = _file(tmp_path / "demo.txt")
    _refused(_run(["demo", "--out", not_a_folder, "--force"]), not_a_folder, "is a file")
