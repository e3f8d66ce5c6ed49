"""Write the seed corpus of the libFuzzer harnesses: tests/fuzz/corpus/<harness>/.

Small valid inputs of each format and a few near-valid ones (one field out of range), written
with eskin's own writers, so that the fuzzer starts from the structure it has to get past.
The corpus is committed; regenerate it when a format changes. Run from the repository root
with the compiled core in place (`make dev`):

    PYTHONPATH=python python tests/fuzz/make_corpus.py
"""

from __future__ import annotations

import io
import shutil
import struct
import zlib
from pathlib import Path

import numpy as np

from eskin.data.replay import write_replay_arrays
from eskin.deploy.export import MachineSpec, ModelSpec, model_to_bytes
from eskin.link import protocol as p
from eskin.signal import WindowConfig

ROOT = Path(__file__).resolve().parent / "corpus"
DATA = Path(__file__).resolve().parents[1] / "data"


def _fresh(name: str) -> Path:
    d = ROOT / name
    shutil.rmtree(d, ignore_errors=True)
    d.mkdir(parents=True)
    return d


def _model_crc(b: bytearray) -> bytes:
    b[-4:] = struct.pack("<I", zlib.crc32(bytes(b[:-4])))
    return bytes(b)


def _section(b: bytes, tag: bytes) -> int:
    pos = 32
    while True:
        size = struct.unpack_from("<I", b, pos + 4)[0]
        if b[pos : pos + 4] == tag:
            return pos + 8
        pos += 8 + (size + 7) // 8 * 8


def tiny_model(dtype: str, amplitude_width: float = 0.0) -> bytes:
    """A binary model on a 2x2 grid with D = 4 and three support vectors (format version 2, with
    an amplitude factor, when amplitude_width > 0)."""
    rng = np.random.default_rng(3)
    sv = rng.standard_normal((3, 2, 2, 4))
    if amplitude_width > 0:  # support vectors of different energies
        sv = sv * np.array([0.5, 1.0, 3.0])[:, None, None, None]
    machine = MachineSpec(1, 0, 0.25, (2, 2, 2), (1.0, 0.5, 2.0), sv, np.array([0.5, -1.0, 0.75]),
                          amplitude_width=amplitude_width)
    spec = ModelSpec(
        class_names=["brush", "finger"],
        rule="binary",
        machines=[machine],
        D=4,
        grid_shape=(2, 2),
        window_config=WindowConfig(),
    )
    return model_to_bytes(spec, dtype)


def model_corpus() -> None:
    d = _fresh("model")
    for dtype in ("float32", "float64"):
        good = tiny_model(dtype)
        (d / f"tiny_{dtype}.eskin").write_bytes(good)
        mach = _section(good, b"MACH")
        b = bytearray(good)
        struct.pack_into("<I", b, mach + 8 + 24, 2**31)  # alpha >= 2^31
        (d / f"alpha_2_31_{dtype}.eskin").write_bytes(_model_crc(b))
        b = bytearray(good)
        struct.pack_into("<d", b, mach + 8 + 24 + 8, 1e-300)  # sigma
        (d / f"sigma_tiny_{dtype}.eskin").write_bytes(_model_crc(b))
    for dtype in ("float32", "float64"):  # format version 2: the amplitude factor (AMPL)
        good = tiny_model(dtype, amplitude_width=0.75)
        (d / f"tiny_amplitude_{dtype}.eskin").write_bytes(good)
    ampl = _section(good, b"AMPL")
    b = bytearray(good)
    struct.pack_into("<d", b, ampl + 8 + 3 * 8, 1e-300)  # amplitude width
    (d / "amplitude_width_tiny_float64.eskin").write_bytes(_model_crc(b))
    b = bytearray(good)
    struct.pack_into("<d", b, ampl + 8, float("nan"))  # a support vector's log energy
    (d / "log_energy_nan_float64.eskin").write_bytes(_model_crc(b))
    shutil.copy(DATA / "model_small_float32.eskin", d / "small_one_vs_all_float32.eskin")


def frame_corpus() -> None:
    d = _fresh("frame_decoder")
    rng = np.random.default_rng(4)
    frames = {
        "data": p.DataFrame(
            first_sample=100,
            timestamp_us=5,
            seq=1,
            samples=rng.integers(-2000, 2000, (6, 4, 4)).astype(np.int16),
        ),
        "decision": p.DecisionFrame(
            onset_sample=10, offset_sample=90, label=1, values=(-0.5, 0.25, 1.5), seq=2
        ),
        "status": p.StatusFrame(uptime_us=7, next_sample=1000, samples_sent=990, seq=3),
        "info": p.InfoFrame(
            rows=4,
            cols=4,
            sample_rate_hz=3000.0,
            volts_per_count=1e-3,
            class_names=("brush", "finger", "washer"),
            seq=4,
        ),
        "ping": p.PingFrame(token=9, timestamp_us=11, seq=5),
    }
    encoded = {k: p.encode_frame(f) for k, f in frames.items()}
    for k, e in encoded.items():
        # the first byte chooses the sizes of the pieces the harness feeds (and, bit 7 set,
        # the frames mode: raw frames that the harness checksums and encodes)
        (d / f"{k}.bin").write_bytes(b"\x05" + p.DELIMITER + e)
    raw_frames = b""
    for k, e in encoded.items():
        raw = p.cobs_decode(e[:-1])[:-4]  # header and payload, without the CRC
        (d / f"{k}_raw.bin").write_bytes(b"\x85" + struct.pack("<H", len(raw)) + raw)
        raw_frames += struct.pack("<H", len(raw)) + raw
    (d / "stream_raw.bin").write_bytes(b"\x9f" + raw_frames)
    stream = p.DELIMITER + b"".join(encoded.values())
    (d / "stream.bin").write_bytes(b"\x20" + stream)
    damaged = bytearray(stream)
    damaged[len(damaged) // 3] ^= 0x40
    (d / "stream_damaged.bin").write_bytes(b"\x01" + bytes(damaged))


def _replay_crc(b: bytearray) -> bytes:
    offset = struct.unpack_from("<I", b, 12)[0]
    crc = zlib.crc32(bytes(b[:52]) + b"\0\0\0\0" + bytes(b[56:offset]))
    struct.pack_into("<I", b, 52, crc)
    return bytes(b)


def replay_corpus(tmp: Path) -> None:
    d = _fresh("replay")
    rng = np.random.default_rng(5)
    recs = [rng.integers(-500, 500, (2, 2, 40)).astype(np.int16) for _ in range(2)]
    path = tmp / "r.eskr"
    write_replay_arrays(
        path, recs, labels=[0, 1], class_names=["brush", "finger"], gap_s=0.01, volts_per_count=1e-3
    )
    good = path.read_bytes()
    (d / "two_recordings.eskr").write_bytes(good)
    for name, off, value in (("rate_inf", 32, float("inf")), ("vpc_nan", 40, float("nan"))):
        b = bytearray(good)
        struct.pack_into("<d", b, off, value)
        (d / f"{name}.eskr").write_bytes(_replay_crc(b))
    b = bytearray(good)
    struct.pack_into("<Q", b, 16, 2**63 + 8)  # n_samples whose byte count wraps around
    (d / "n_samples_wraps.eskr").write_bytes(_replay_crc(b))
    buf = io.BytesIO()
    np.save(buf, rng.integers(-500, 500, (20, 4, 4)).astype("<i2"))
    (d / "samples_4x4.npy").write_bytes(buf.getvalue())
    buf = io.BytesIO()
    np.save(buf, rng.integers(-500, 500, (20, 16)).astype("<i2"))
    (d / "samples_16_taxels.npy").write_bytes(buf.getvalue())


def npy_corpus() -> None:
    d = _fresh("npy")
    rng = np.random.default_rng(6)
    arrays = {
        "i2_2x3": rng.integers(-9, 9, (2, 3)).astype("<i2"),
        "f4_4x4x5": rng.standard_normal((4, 4, 5)).astype("<f4"),
        "f8_scalar": np.array(1.5, dtype="<f8"),
        "i2_empty": np.zeros((0, 4), dtype="<i2"),
        "f8_fortran": np.asfortranarray(rng.standard_normal((3, 2))),
        "i2_big_endian": rng.integers(-9, 9, (3,)).astype(">i2"),
    }
    for name, a in arrays.items():
        buf = io.BytesIO()
        np.save(buf, a)
        (d / f"{name}.npy").write_bytes(buf.getvalue())
    for version in ((2, 0), (3, 0)):
        buf = io.BytesIO()
        np.lib.format.write_array(buf, arrays["i2_2x3"], version=version)
        (d / f"i2_2x3_v{version[0]}.npy").write_bytes(buf.getvalue())
    whole = (d / "f4_4x4x5.npy").read_bytes()
    (d / "f4_truncated.npy").write_bytes(whole[:-7])


def main() -> None:
    tmp = ROOT.parent / ".corpus_tmp"
    tmp.mkdir(exist_ok=True)
    try:
        model_corpus()
        frame_corpus()
        replay_corpus(tmp)
        npy_corpus()
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    for d in sorted(ROOT.iterdir()):
        files = sorted(d.iterdir())
        print(f"{d.name}: {len(files)} files, {sum(f.stat().st_size for f in files)} bytes")


if __name__ == "__main__":
    main()
