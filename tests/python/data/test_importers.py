"""Importers: real CSV folders and real LabVIEW TDMS files written in tmp_path."""

from __future__ import annotations

import numpy as np
import pytest
from nptdms import ChannelObject, GroupObject, RootObject, TdmsWriter

from eskin.data.campaign import load_campaign
from eskin.data.importers import import_csv_folder, import_tdms


def _csv_folder(tmp_path, *, n=4, grid=(4, 4), header=True, time_col=False, volts=False,
                manifest_extra=None):
    rng = np.random.default_rng(0)
    folder = tmp_path / "rec"
    folder.mkdir()
    truth = []
    lines = ["file,modality,participant,direction,run" + (
        "," + ",".join(manifest_extra) if manifest_extra else "")]
    labels = ["finger", "brush", "washer", "finger"]
    dirs = ["h", "vertical", "1", ""]
    for i in range(n):
        length = 50 + 10 * i
        counts = rng.integers(-500, 500, (grid[0] * grid[1], length))
        name = f"r{i:02d}.csv"
        with open(folder / name, "w") as fh:
            cols = [f"r{k // grid[1]}c{k % grid[1]}" for k in range(grid[0] * grid[1])]
            if header:
                fh.write(",".join((["time"] if time_col else []) + cols) + "\n")
            for s in range(length):
                vals = [f"{v * 1e-3:.6f}" if volts else str(int(v)) for v in counts[:, s]]
                if time_col:
                    vals = [f"{s / 1000:.4f}"] + vals
                fh.write(",".join(vals) + "\n")
        truth.append(counts)
        extra = ("," + ",".join(manifest_extra.values())) if manifest_extra else ""
        lines.append(f"{name},{labels[i % 4]},{10 + i // 2},{dirs[i % 4]},{1 + i % 2}{extra}")
    (folder / "manifest.csv").write_text("\n".join(lines) + "\n")
    return folder, truth


@pytest.mark.parametrize("header,time_col", [(True, False), (False, False), (True, True)])
def test_csv_round_trip(tmp_path, header, time_col):
    folder, truth = _csv_folder(tmp_path, header=header, time_col=time_col)
    out = tmp_path / "c.h5"
    import_csv_folder(folder, out, grid_shape=(4, 4), sample_rate_hz=1000.0,
                      volts_per_count=1e-3)
    with load_campaign(out) as c:
        assert c.source == "recorded" and c.sample_rate_hz == 1000.0
        assert c.modalities == ["brush", "finger", "washer"]  # sorted labels
        assert c.modality.tolist() == [1, 0, 2, 1]
        assert c.participant.tolist() == [10, 10, 11, 11]
        assert c.direction.tolist() == [0, 1, 1, 255]
        assert c.run.tolist() == [1, 2, 1, 2]
        assert c.lengths.tolist() == [50, 60, 70, 80] and c.n_samples == 80
        for i, counts in enumerate(truth):
            np.testing.assert_array_equal(c.recording(i).reshape(16, -1), counts)


def test_csv_volts_settings_from_manifest_and_modality_order(tmp_path):
    folder, truth = _csv_folder(
        tmp_path, grid=(2, 3), volts=True,
        manifest_extra={"rows": "2", "cols": "3", "sample_rate_hz": "500",
                        "volts_per_count": "0.001"})
    out = tmp_path / "c.h5"
    import_csv_folder(folder, out, modalities=["washer", "finger", "brush"])
    with load_campaign(out) as c:
        assert c.grid_shape == (2, 3) and c.sample_rate_hz == 500.0
        assert c.modalities == ["washer", "finger", "brush"]
        assert c.modality.tolist() == [1, 2, 0, 1]
        np.testing.assert_array_equal(c.recording(2).reshape(6, -1), truth[2])


def test_csv_errors(tmp_path):
    folder, _ = _csv_folder(tmp_path)
    out = tmp_path / "c.h5"
    kw = dict(grid_shape=(4, 4), sample_rate_hz=1000.0, volts_per_count=1e-3)
    with pytest.raises(ValueError, match=r"r00\.csv: 16 taxel columns.*expected 12"):
        import_csv_folder(folder, out, **{**kw, "grid_shape": (3, 4)})
    with pytest.raises(ValueError, match=r"manifest\.csv: 1 setting\(s\) not given: the sample rate"):
        import_csv_folder(folder, out, grid_shape=(4, 4), volts_per_count=1.0)
    with pytest.raises(ValueError, match=r"not among the given modalities"):
        import_csv_folder(folder, out, modalities=["finger", "brush"], **kw)
    with pytest.raises(FileNotFoundError, match="manifest not found"):
        import_csv_folder(tmp_path, out, **kw)
    # a bad value in a recording names the file
    bad = folder / "r01.csv"
    text = bad.read_text().splitlines()
    text[5] = text[5].replace(text[5].split(",")[3], "oops", 1)
    bad.write_text("\n".join(text) + "\n")
    with pytest.raises(ValueError, match=r"r01\.csv"):
        import_csv_folder(folder, out, **kw)
    assert not out.exists()
    # manifest problems name the line
    (folder / "manifest.csv").write_text(
        "file,modality,participant,direction,run\nr00.csv,finger,1,diagonal,1\n")
    with pytest.raises(ValueError, match=r"manifest\.csv, line 2: direction 'diagonal'"):
        import_csv_folder(folder, out, **kw)
    (folder / "manifest.csv").write_text(
        "file,modality,participant,direction,run\nmissing.csv,finger,1,h,1\n")
    with pytest.raises(FileNotFoundError, match="'missing.csv' not found"):
        import_csv_folder(folder, out, **kw)
    (folder / "manifest.csv").write_text("file,modality,participant\nr00.csv,finger,1\n")
    with pytest.raises(ValueError, match=r"missing column\(s\) \['direction', 'run'\]"):
        import_csv_folder(folder, out, **kw)


def _tdms(path, recordings, *, float_volts=False, rate=3000.0, use_props=False,
          root_props=None, names=None):
    objs = [RootObject(properties=root_props or {"rows": 4, "cols": 4})]
    for g, (counts, props) in enumerate(recordings):
        gname = f"recording {g}"
        objs.append(GroupObject(gname, properties=props))
        order = list(range(counts.shape[0]))
        rng = np.random.default_rng(g)
        rng.shuffle(order)  # channels stored out of order: the importer must sort them
        for k in order:
            data = counts[k] * 1e-3 if float_volts else counts[k].astype(np.int16)
            cprops = {"wf_increment": 1.0 / rate}
            if use_props:
                cprops.update(taxel_row=k // 4, taxel_col=k % 4)
                cname = f"ai{(k * 7) % 16}"
            else:
                cname = names(k) if names else f"r{k // 4}c{k % 4}"
            objs.append(ChannelObject(gname, cname, data, properties=cprops))
    with TdmsWriter(path) as w:
        w.write_segment(objs)


def _recs(n=3, lengths=(300, 200, 250)):
    rng = np.random.default_rng(1)
    labs = ["brush", "washer", "finger"]
    return [(rng.integers(-2000, 2000, (16, lengths[i])),
             {"modality": labs[i % 3], "participant": 3 + i, "direction": "v" if i % 2 else "h",
              "run": 2}) for i in range(n)]


@pytest.mark.parametrize("mode", ["names", "props", "taxel-numbers"])
def test_tdms_round_trip(tmp_path, mode):
    recs = _recs()
    p = tmp_path / "acquisition.tdms"
    if mode == "names":
        _tdms(p, recs)
    elif mode == "props":
        _tdms(p, recs, use_props=True)
    else:
        _tdms(p, recs, names=lambda k: f"Taxel {k + 1}")
    out = tmp_path / "c.h5"
    import_tdms(p, out)
    with load_campaign(out) as c:
        assert len(c) == 3 and c.sample_rate_hz == 3000.0 and c.source == "recorded"
        assert c.modalities == ["brush", "finger", "washer"]
        assert c.modality.tolist() == [0, 2, 1]
        assert c.participant.tolist() == [3, 4, 5] and c.direction.tolist() == [0, 1, 0]
        assert c.lengths.tolist() == [300, 200, 250]
        for i, (counts, _) in enumerate(recs):
            np.testing.assert_array_equal(c.recording(i).reshape(16, -1), counts)


def test_tdms_volts_and_several_files(tmp_path):
    recs = _recs()
    a, b = tmp_path / "a.tdms", tmp_path / "b.tdms"
    _tdms(a, recs[:2], float_volts=True, rate=2000.0)
    # labels in the file's properties, one recording in the file
    counts, _ = recs[2]
    _tdms(b, [(counts, {})], float_volts=True, rate=2000.0,
          root_props={"modality": "finger", "participant": 9, "run": 1})
    out = tmp_path / "c.h5"
    import_tdms([a, b], out, volts_per_count=1e-3)
    with load_campaign(out) as c:
        assert c.sample_rate_hz == 2000.0 and c.volts_per_count == 1e-3
        assert c.participant.tolist() == [3, 4, 9] and c.direction.tolist() == [0, 1, 255]
        np.testing.assert_array_equal(c.recording(2).reshape(16, -1), counts)


def test_tdms_errors(tmp_path):
    recs = _recs()
    p = tmp_path / "s.tdms"
    _tdms(p, recs)
    out = tmp_path / "c.h5"
    with pytest.raises(ValueError, match=r"16 channels, expected one per taxel \(3x4 = 12\)"):
        import_tdms(p, out, grid_shape=(3, 4))
    with pytest.raises(FileNotFoundError, match="no such TDMS file"):
        import_tdms(tmp_path / "none.tdms", out)
    junk = tmp_path / "junk.tdms"
    junk.write_bytes(b"TDSm" + b"\x00" * 40)
    with pytest.raises(ValueError, match=r"junk\.tdms"):
        import_tdms(junk, out)
    text = tmp_path / "notes.tdms"
    text.write_text("hello")
    with pytest.raises(ValueError, match=r"notes\.tdms"):
        import_tdms(text, out)
    nolabel = tmp_path / "nolabel.tdms"
    _tdms(nolabel, [(recs[0][0], {"participant": 1})])
    with pytest.raises(ValueError, match=r"group 'recording 0': no 'modality' property"):
        import_tdms(nolabel, out)
    assert not out.exists()


def test_cli_import_csv_and_tdms(tmp_path):
    from typer.testing import CliRunner

    from eskin.cli import app

    folder, truth = _csv_folder(tmp_path)
    out = tmp_path / "csv.h5"
    run = CliRunner().invoke
    r = run(app, ["import-csv", str(folder), "-o", str(out), "--rows", "4", "--cols", "4",
                  "--rate", "1000", "--volts-per-count", "0.001"])
    assert r.exit_code == 0, r.output
    assert "4 recordings" in r.output
    r = run(app, ["import-csv", str(folder), "-o", str(out), "--rows", "4", "--cols", "4",
                  "--rate", "1000", "--volts-per-count", "0.001"])
    assert r.exit_code == 2 and "refusing to overwrite" in r.output
    r = run(app, ["import-csv", str(folder), "-o", str(tmp_path / "x.h5"), "--rows", "3",
                  "--cols", "4", "--rate", "1000", "--volts-per-count", "0.001"])
    assert r.exit_code == 2 and "expected 12" in r.output

    p = tmp_path / "s.tdms"
    _tdms(p, _recs())
    r = run(app, ["import-tdms", str(p), "-o", str(tmp_path / "t.h5"),
                  "--modalities", "brush,finger,washer"])
    assert r.exit_code == 0, r.output
    assert "3 recordings" in r.output


def test_csv_names_every_missing_setting_at_once(tmp_path):
    folder, _ = _csv_folder(tmp_path, grid=(3, 4))
    with pytest.raises(ValueError) as err:
        import_csv_folder(folder, tmp_path / "c.h5")
    msg = str(err.value)
    assert msg.startswith(f"{folder / 'manifest.csv'}: 2 setting(s) not given: the grid (--rows")
    assert "4x4 is taken only for 16 taxel columns" in msg
    assert "; the sample rate (--rate" in msg and "--time-column NAME --time-unit s|ms|us" in msg
    assert "volts" not in msg  # integer counts need no volts per count
    assert not (tmp_path / "c.h5").exists()


def test_csv_grid_and_rate_from_the_recordings(tmp_path):
    # 16 taxel columns: the paper's 4x4 grid; a time column in seconds: the rate
    folder, truth = _csv_folder(tmp_path, time_col=True)
    out = import_csv_folder(folder, tmp_path / "c.h5", volts_per_count=1e-3)
    with load_campaign(out) as c:
        assert c.grid_shape == (4, 4) and c.sample_rate_hz == 1000.0
        np.testing.assert_array_equal(c.recording(2).reshape(16, -1), truth[2])
    # an uneven time column gives no rate, and says so
    rec = folder / "r00.csv"
    lines = rec.read_text().splitlines()
    lines[3] = "0.0025" + lines[3][lines[3].index(","):]
    rec.write_text("\n".join(lines) + "\n")
    with pytest.raises(ValueError, match=r"r00\.csv: time column 'time' is not evenly spaced"):
        import_csv_folder(folder, tmp_path / "d.h5", volts_per_count=1e-3)


def test_tdms_takes_4x4_only_for_16_channels(tmp_path):
    p = tmp_path / "twelve.tdms"
    _tdms(p, [(c[:12], props) for c, props in _recs(1)], root_props={"source": "no grid"})
    with pytest.raises(ValueError, match=r"12 channels, expected one per taxel \(4x4 = 16\); 4x4 "
                                         r"is taken only for 16 channels: give the grid"):
        import_tdms([p], tmp_path / "t.h5", sample_rate_hz=3000.0)


def _retime(folder, name, scale):
    """Rename the recordings' time column to ``name`` and write its values in units of
    ``scale`` seconds (the helper writes seconds)."""
    for rec in sorted(folder.glob("r*.csv")):
        lines = rec.read_text().splitlines()
        out = [name + lines[0][lines[0].index(","):]]
        for ln in lines[1:]:
            t, rest = ln.split(",", 1)
            out.append(f"{float(t) / scale:.6g},{rest}")
        rec.write_text("\n".join(out) + "\n")


def _import(folder, out, *args):
    from typer.testing import CliRunner

    from eskin.cli import app

    return CliRunner().invoke(app, ["import-csv", str(folder), "-o", str(out), *args])


@pytest.mark.parametrize("name,scale,args", [
    ("time_ms", 1e-3, []),
    ("Timestamp_us", 1e-6, []),
    ("clock", 1e-3, ["--time-column", "clock", "--time-unit", "ms"]),
    ("t", 1e-6, ["--time-unit", "us"]),
])
def test_cli_import_csv_reads_the_time_column_in_its_unit(tmp_path, name, scale, args):
    """A time column of a common name is recognised with the unit its name says (any case),
    --time-column/--time-unit name any other; it is dropped and gives the rate. Integer
    counts need no --volts-per-count."""
    folder, truth = _csv_folder(tmp_path, time_col=True)
    _retime(folder, name, scale)
    r = _import(folder, tmp_path / "c.h5", *args)
    assert r.exit_code == 0, r.output
    assert ("4 recordings, 4x4 taxels, 1000 Hz, values as ADC counts (no --volts-per-count)"
            in r.output)
    with load_campaign(tmp_path / "c.h5") as c:
        assert c.sample_rate_hz == 1000.0 and c.grid_shape == (4, 4)
        np.testing.assert_array_equal(c.recording(1).reshape(16, -1), truth[1])
        assert "not given" in c.attrs["volts_per_count_given"]
    from typer.testing import CliRunner

    from eskin.cli import app

    info = CliRunner().invoke(app, ["info", str(tmp_path / "c.h5")])
    assert "volts per count   not given (values imported as ADC counts)" in info.output


def test_cli_import_csv_names_an_unknown_time_column_and_bad_cells_by_line(tmp_path):
    folder, _ = _csv_folder(tmp_path, time_col=True)
    _retime(folder, "clock", 1e-3)
    out = tmp_path / "c.h5"
    # an unrecognised time column: the column count names it and the options
    r = _import(folder, out, "--rate", "1000")
    assert r.exit_code == 2 and "Traceback" not in r.output
    assert ("4x4 is taken only for 16 taxel columns, the first recording has 17; if column "
            "'clock' is the time, give --time-column clock --time-unit s|ms|us"
            ) in " ".join(r.output.split())
    r = _import(folder, out, "--rate", "1000", "--rows", "4", "--cols", "4")
    assert r.exit_code == 2 and "Traceback" not in r.output
    assert ("r00.csv: 17 taxel columns, expected 16 (rows x cols); if column 'clock' is the "
            "time, give --time-column clock --time-unit s|ms|us") in " ".join(r.output.split())
    r = _import(folder, out, "--time-column", "clock")
    assert r.exit_code == 2 and "time column 'clock': its name does not say its unit; give " \
        "--time-unit s, ms or us" in " ".join(r.output.split())
    r = _import(folder, out, "--time-column", "zeit", "--time-unit", "ms")
    assert r.exit_code == 2 and "no column 'zeit' (--time-column)" in " ".join(r.output.split())
    # a blank cell: the file's own line (1-based, header counted) and column, with its name
    rec = folder / "r02.csv"
    lines = rec.read_text().splitlines()
    cells = lines[59].split(",")
    cells[1] = ""
    lines[59] = ",".join(cells)
    rec.write_text("\n".join(lines) + "\n")
    r = _import(folder, out, "--time-column", "clock", "--time-unit", "ms")
    assert r.exit_code == 2 and not out.exists()
    assert "r02.csv, line 60, column 2 ('r0c0'): '' is not a number" in " ".join(
        r.output.split())


def test_cli_import_csv_volts_need_volts_per_count(tmp_path):
    folder, truth = _csv_folder(tmp_path, volts=True, time_col=True)
    r = _import(folder, tmp_path / "c.h5")
    assert r.exit_code == 2 and "values are not integers (the first at sample 0), so they are " \
        "taken for volts and need the volts per ADC count (--volts-per-count" in " ".join(
            r.output.split())
    r = _import(folder, tmp_path / "c.h5", "--volts-per-count", "0.001")
    assert r.exit_code == 0 and "0.001 V per count" in r.output
    with load_campaign(tmp_path / "c.h5") as c:
        np.testing.assert_array_equal(c.recording(0).reshape(16, -1), truth[0])
    from typer.testing import CliRunner

    from eskin.cli import app

    help_text = " ".join(CliRunner().invoke(app, ["import-csv", "--help"]).output.split())
    assert "Integer counts are imported as they are" in help_text.replace("│ ", "")


@pytest.mark.parametrize("name,unit", [("time_ms", "s"), ("Timestamp_us", "ms"),
                                       ("elapsed_s", "ms"), ("millis", "us")])
def test_cli_import_csv_refuses_a_time_unit_the_column_name_contradicts(tmp_path, name, unit):
    """--time-unit s on a column named time_ms made a 1 Hz campaign without a word."""
    folder, _ = _csv_folder(tmp_path, time_col=True)
    _retime(folder, name, 1e-3)
    out = tmp_path / "c.h5"
    for args in (["--time-unit", unit], ["--time-column", name, "--time-unit", unit]):
        r = _import(folder, out, *args)
        assert r.exit_code == 2 and r.output.count("\n") == 1, r.output
        from eskin.data.importers import unit_in_name

        stated = unit_in_name(name)
        assert r.output == (
            f"error: {folder / 'r00.csv'}: time column {name!r}: its name says {stated}, "
            f"--time-unit says {unit}; give --time-unit {stated} (or leave it out), or name "
            f"the column by its unit\n")
        assert not out.exists()


def test_unit_in_name():
    from eskin.data.importers import unit_in_name

    assert [unit_in_name(n) for n in ("time_ms", "T_US", "elapsed_s", "ms", "seconds",
                                      "time-ms", "t", "time", "timestamp", "clock", "samples",
                                      "status")] == [
        "ms", "us", "s", "ms", "s", "ms", None, None, None, None, None, None]


@pytest.mark.parametrize("args,line", [
    (["--rows", "0", "--cols", "4"], "--rows 0: a grid has at least 1 taxel row and column"),
    (["--rows", "4", "--cols", "-2"], "--cols -2: a grid has at least 1 taxel row and column"),
    (["--rows", "0"], "--rows 0: a grid has at least 1 taxel row and column"),
    (["--rows", "4"], "--rows 4 needs --cols too (the grid is rows x cols)"),
    (["--cols", "4"], "--cols 4 needs --rows too (the grid is rows x cols)"),
])
def test_cli_import_csv_and_tdms_refuse_a_partial_or_empty_grid(tmp_path, args, line):
    """--rows 0 (or --rows alone) was ignored: the grid came from elsewhere, without a word."""
    folder, _ = _csv_folder(tmp_path)
    out = tmp_path / "c.h5"
    r = _import(folder, out, *args)
    assert (r.exit_code, r.output) == (2, f"error: {line}\n")
    from typer.testing import CliRunner

    from eskin.cli import app

    tdms = tmp_path / "r.tdms"
    _tdms(tdms, _recs())
    r = CliRunner().invoke(app, ["import-tdms", str(tdms), "-o", str(out), *args])
    assert (r.exit_code, r.output) == (2, f"error: {line}\n")
    assert not out.exists()
