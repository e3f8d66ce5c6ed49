"""RAM of one host stream: the heap one eskin::StreamClassifier holds, for the default model.

The default model is what ``eskin.train_model(campaign)`` (``eskin train CAMPAIGN
--all-classes``) fits on a simulated campaign (70 participants unless --participants, or the
.eskin file given with --model). Its classifiers share the model's decision tables (machine
groups, support-vector projections: ``Model::decision_tables``); each stream holds the
detector's samples (float32 on the host: the pre-onset ring and the bounded window buffer,
``WindowConfig.window_samples``) and the workspace of one decision.

Measured, not estimated: glibc's heap in use (``mallinfo2``: arena bytes in use plus mmapped
chunks) before and after constructing N stream classifiers of one loaded model (and the model
itself, for its shared tables); bytes per stream = the difference / N. Baseline in the same run:
the same model with an unbounded window (``window_samples = 0``: every sample of a 7 s window
kept), as every stream was before the bounded window.

Run:  ESKIN_BIN_DIR=build/dev PYTHONPATH=python python benchmarks/bench_stream_memory.py
      [--model m.eskin] [--participants 70] [--streams 20]
The data are simulated (eskin.simulate). Linux/glibc only (mallinfo2).
"""

from __future__ import annotations

import argparse
import ctypes
import gc
import struct
import tempfile
import time
import zlib
from pathlib import Path

import eskin
from eskin import _core
from eskin.deploy.export import CompiledModel, export_model


class _MallInfo2(ctypes.Structure):
    _fields_ = [(name, ctypes.c_size_t) for name in (
        "arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks", "fsmblks", "uordblks",
        "fordblks", "keepcost")]


_libc = ctypes.CDLL("libc.so.6")
_libc.mallinfo2.restype = _MallInfo2


def heap_in_use() -> int:
    """Bytes of the C heap in use: small-chunk arena bytes plus mmapped big chunks."""
    gc.collect()
    m = _libc.mallinfo2()
    return int(m.uordblks + m.hblkhd)


def per_stream(model_bytes: bytes, n: int) -> tuple[int, int]:
    """(bytes of the loaded model, bytes per stream classifier) measured on the heap."""
    h0 = heap_in_use()
    cm = CompiledModel(model_bytes)
    h1 = heap_in_use()
    streams = [_core.StreamClassifier(cm._model) for _ in range(n)]
    h2 = heap_in_use()
    del streams
    return h1 - h0, (h2 - h1) // n


def with_unbounded_window(data: bytes) -> bytes:
    """The same model file with window_samples = 0 (the value after the field's name in PREP)
    and its checksum recomputed: every sample of a max_window_s window kept."""
    name = b"window_samples".ljust(32, b"\0")
    at = data.index(name) + len(name)
    body = data[:at] + struct.pack("<d", 0.0) + data[at + 8 : -4]
    return body + struct.pack("<I", zlib.crc32(body) & 0xFFFFFFFF)


def default_model(participants: int, work: Path) -> Path:
    camp = eskin.simulate(work / "campaign.h5", participants=participants, seed=0, overwrite=True)
    t0 = time.perf_counter()
    model = eskin.train_model(camp, n_jobs=1)
    print(f"trained the default recipe on {participants} simulated participants in "
          f"{time.perf_counter() - t0:.0f} s")
    return export_model(model, work / "default.eskin")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", type=Path, default=None, help="a .eskin model (default: train one)")
    ap.add_argument("--participants", type=int, default=70)
    ap.add_argument("--streams", type=int, default=20)
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        path = a.model or default_model(a.participants, Path(tmp))
        data = Path(path).read_bytes()
        cm = CompiledModel(data)
        cfg = eskin.WindowConfig.from_array([cm.window_config[k] for k in
                                             eskin.WindowConfig.field_names()])
        unbounded = with_unbounded_window(data)
    print(f"model: {len(data)} bytes, {cm.n_support} support vectors, D={cm.D}, "
          f"grid {cm.grid_shape}, {cm.sample_rate_hz:g} Hz, window_samples="
          f"{cfg.window_samples:g}, max_window_s={cfg.max_window_s:g}")
    rows = [("bounded window (the model as trained)", data),
            ("unbounded window (window_samples = 0)", unbounded)]
    results = {}
    for name, blob in rows:
        model_heap, stream_heap = per_stream(blob, a.streams)
        results[name] = stream_heap
        print(f"{name}: loaded model {model_heap / 1024:.0f} KB (shared), one stream "
              f"{stream_heap / 1024:.1f} KB ({stream_heap} bytes; mean of {a.streams})")
    base, new = results[rows[1][0]], results[rows[0][0]]
    print(f"one stream: {new / 1024:.1f} KB, {base / new:.1f}x less than the unbounded "
          f"window's {base / 1024:.1f} KB; 1000 streams: {1000 * new / 2**20:.0f} MiB")


if __name__ == "__main__":
    main()
