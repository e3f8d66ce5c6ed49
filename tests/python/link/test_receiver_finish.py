"""The end of a stream (eskin.link.receiver, through LinkListener.feed and .finish): a touch
still in progress when the stream ends is ended there and recorded, up to the last sample
received."""

from __future__ import annotations

import numpy as np
import pytest

from eskin.link.listener import LinkListener
from eskin.link.protocol import DELIMITER, DataFrame, InfoFrame, encode_frame
from eskin.link.recorder import Recorded

SPF = 10


def _stream(n_quiet: int = 4500, n_touch: int = 2000,
            grid: tuple[int, int] = (4, 4)) -> np.ndarray:
    """Quiet noise, then a strong burst on (up to) four taxels that the stream ends in:
    (n, rows, cols)."""
    rng = np.random.default_rng(11)
    x = rng.normal(0, 5, size=(n_quiet + n_touch, *grid))
    t = np.arange(n_touch) / 3000.0
    x[n_quiet:, 1:3, 1:3] += (800 * np.sin(2 * np.pi * 40 * t))[:, None, None]
    return np.rint(x).astype(np.int16)


def _frames(stream: np.ndarray) -> list[bytes]:
    """The encoded INFO frame of the stream's grid, then its DATA frames of SPF samples."""
    rows, cols = stream.shape[1:]
    frames = [encode_frame(InfoFrame(rows, cols, 3000.0, volts_per_count=1e-4, has_model=False,
                                     class_names=(), seq=0))]
    for k, first in enumerate(range(0, len(stream), SPF)):
        frames.append(encode_frame(DataFrame(first, first * 333, stream[first:first + SPF],
                                             (k + 1) % 65536, 0)))
    return frames


def _wire(stream: np.ndarray) -> bytes:
    return DELIMITER + b"".join(_frames(stream))


def test_a_touch_in_progress_at_the_end_is_recorded_up_to_the_last_sample(tmp_path):
    stream = _stream()
    out = tmp_path / "touches.h5"
    listener = LinkListener("/dev/null-not-opened", record=out, stats_interval=None)
    during = listener.feed(_wire(stream))
    assert not [e for e in during if isinstance(e, Recorded)]  # the touch has not ended
    at_end = [e for e in listener.finish() if isinstance(e, Recorded)]
    listener.close()
    assert len(at_end) == 1
    rec = at_end[0]
    assert rec.stop == len(stream) and rec.start < 4500 and rec.lost_samples == 0


def test_an_info_grid_other_than_the_models_names_both_grids_rows_first(tmp_path):
    import pytest

    from eskin.deploy.export import CompiledModel, MachineSpec, ModelSpec, model_to_bytes
    from eskin.errors import LinkStreamError

    rng = np.random.default_rng(3)
    X = rng.normal(size=(4, 2, 3, 5))  # a 2x3 model: rows and columns tell apart
    machines = [MachineSpec(k, -1, 0.0, (2, 2, 2), (1.0, 1.0, 1.0), X, rng.normal(size=4))
                for k in range(2)]
    model = CompiledModel(model_to_bytes(ModelSpec(["a", "b"], "one_vs_all", machines, 5, (2, 3)),
                                         "float64"))
    for rows, cols in ((3, 2), (2, 2), (1, 3)):  # a larger or a smaller grid
        listener = LinkListener("/dev/null-not-opened", model=model, stats_interval=None)
        with pytest.raises(LinkStreamError) as info:
            listener.feed(DELIMITER + encode_frame(InfoFrame(rows, cols, 3000.0,
                                                             volts_per_count=1e-4,
                                                             has_model=False, class_names=(),
                                                             seq=0)))
        listener.close()
        assert str(info.value) == f"INFO frame: grid = {rows}x{cols}: the host model expects 2x3"


@pytest.mark.parametrize("kept,rows,cols", [((4, 4), 3, 2), ((4, 4), 8, 8), ((4, 4), 4, 5),
                                             ((2, 3), 3, 2)])
def test_an_info_grid_other_than_the_recordings_names_the_file_and_both_grids(tmp_path, kept,
                                                                              rows, cols):
    """Once a recording is in the campaign file, an INFO frame of another grid (smaller,
    larger, the same taxels turned) stops the stream with one line naming the file and both
    grids (the file keeps what it has)."""

    from eskin.data.campaign import load_campaign
    from eskin.errors import LinkStreamError

    stream = np.concatenate([_stream(grid=kept),
                             _stream(n_touch=0, grid=kept)[:4500]])  # the touch ends, quiet
    out = tmp_path / "touches.h5"
    listener = LinkListener("/dev/null-not-opened", record=out, stats_interval=None)
    recorded = [e for e in listener.feed(_wire(stream)) if isinstance(e, Recorded)]
    assert len(recorded) == 1
    with pytest.raises(LinkStreamError) as info:
        listener.feed(DELIMITER + encode_frame(InfoFrame(rows, cols, 3000.0, volts_per_count=1e-4,
                                                         has_model=False, class_names=(),
                                                         seq=1)))
    listener.close()
    assert str(info.value) == (f"INFO frame: grid = {rows}x{cols}: {out} is being recorded "
                               f"with {kept[0]}x{kept[1]}")
    assert len(load_campaign(out)) == 1


def test_an_info_frame_of_the_recordings_own_grid_sent_again_goes_on_recording(tmp_path):
    """A controller sends its INFO again (an INFO_REQUEST answered, a reconnect) while a
    campaign file is being written, in the middle of a touch and after the touch is in the
    file: the same grid, so the stream goes on and the touch is recorded exactly as without
    those frames."""
    from eskin.data.campaign import load_campaign

    stream = np.concatenate([_stream(), _stream(n_touch=0)[:4500]])  # the touch ends, quiet
    frames = _frames(stream)
    # the INFO frame, then the DATA up to sample 5500 (the touch: 4500-6500), and up to 10800
    cut, late = 1 + 5500 // SPF, 1 + 10800 // SPF

    def run(data: bytes, name: str):
        out = tmp_path / name
        listener = LinkListener("/dev/null-not-opened", record=out, stats_interval=None)
        events = listener.feed(data) + listener.finish()
        listener.close()
        with load_campaign(out) as camp:
            return ([(e.start, e.stop, e.lost_samples) for e in events
                     if isinstance(e, Recorded)],
                    [np.asarray(camp.recording(i)) for i in range(len(camp))])

    plain, plain_recs = run(DELIMITER + b"".join(frames), "plain.h5")
    resent, resent_recs = run(DELIMITER + b"".join(
        frames[:cut] + frames[:1] + frames[cut:late] + frames[:1] + frames[late:]), "again.h5")
    assert len(plain) == 1 and plain[0][0] < 5500 < plain[0][1]
    assert resent == plain
    np.testing.assert_array_equal(resent_recs[0], plain_recs[0])

def test_an_info_without_volts_per_count_records_one_volt_per_count(tmp_path):
    """volts_per_count = 0 in the INFO frame means the controller does not say: the recording
    takes 1.0, not 0."""
    from eskin.data.campaign import load_campaign

    stream = np.concatenate([_stream(), _stream(n_touch=0)[:4500]])
    wire = _wire(stream).replace(
        encode_frame(InfoFrame(4, 4, 3000.0, volts_per_count=1e-4, has_model=False,
                               class_names=(), seq=0)),
        encode_frame(InfoFrame(4, 4, 3000.0, volts_per_count=0.0, has_model=False,
                               class_names=(), seq=0)))
    out = tmp_path / "touches.h5"
    listener = LinkListener("/dev/null-not-opened", record=out, stats_interval=None)
    assert len([e for e in listener.feed(wire) if isinstance(e, Recorded)]) == 1
    listener.close()
    with load_campaign(out) as c:
        assert c.volts_per_count == 1.0


def test_a_grid_of_other_rows_and_columns_is_kept_as_rows_by_columns():
    x = np.arange(40 * 2 * 3, dtype=np.int16).reshape(40, 2, 3) % 50
    frames = [encode_frame(InfoFrame(2, 3, 1000.0, volts_per_count=1e-4, has_model=False,
                                     class_names=(), seq=0))]
    frames += [encode_frame(DataFrame(k, k * 1000, x[k:k + 10], k // 10 + 1))
               for k in range(0, 40, 10)]
    listener = LinkListener("/dev/null-not-opened", stats_interval=None)
    blocks = [e for e in listener.feed(DELIMITER + b"".join(frames))
              if type(e).__name__ == "DataBlock"]
    assert [b.samples.shape for b in blocks] == [(10, 2, 3)] * 4
    assert listener.activity().shape == (2, 3)
    listener.close()
