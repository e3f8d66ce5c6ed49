"""Write tests/data/model_small_*.eskin (a small valid 3-class model),
tests/data/model_binary_float64.eskin (a two-class model, binary rule) and
tests/data/model_projection_*.eskin (two machines of different alpha, a time mode cut wider than
4: the projection route), tests/data/model_uneven_float64.eskin (a 3x5 grid, a different alpha
per mode) and tests/data/model_wide_rows_float64.eskin (a 4x5 grid at D = 3 whose row mode has
the largest projection) for the C++ loader and decision tests.

Its bases are random orthonormal columns (QR), not bases of real patterns: the loader and fuzz
tests check the format, not the classifier. Regenerate it when the format or eskin::WindowConfig
changes. Run from the repository root:
    PYTHONPATH=python python tests/data/make_model_fixture.py
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from eskin.deploy.export import MachineSpec, ModelSpec, model_to_bytes
from eskin.signal.preprocess import WindowConfig


def _one_vs_all(class_names: list[str], machines: list[MachineSpec], D: int,
                grid_shape: tuple[int, int]) -> ModelSpec:
    """A one-vs-all model of the energy detector (whole windows) and Algorithm 2 at 3 kHz."""
    return ModelSpec(
        class_names=class_names,
        rule="one_vs_all",
        machines=machines,
        D=D,
        grid_shape=grid_shape,
        window="energy",
        subsample="algorithm2",
        sample_rate_hz=3000.0,
        window_config=WindowConfig(window_samples=0),
    )


def qr_bases(tensors, alphas):
    rng = np.random.default_rng(1)
    n = tensors.shape[0]
    shape = tensors.shape[1:]
    total = int(np.prod(shape))
    ranks = np.zeros((n, 3), dtype=np.uint32)
    bases = []
    for z in range(3):
        N = total // shape[z]
        a = int(alphas[z])
        b = np.zeros((n, a, N))
        for i in range(n):
            r = a if i % 4 else max(1, a - 1)  # some rank-deficient patterns
            q, _ = np.linalg.qr(rng.standard_normal((N, a)))
            b[i, :r] = q[:, :r].T
            ranks[i, z] = r
        bases.append(b)
    return ranks, bases


def fixture_spec() -> ModelSpec:
    """The fixture's description (format version 1: no amplitude factor)."""
    rng = np.random.default_rng(0)
    D = 8
    pool = rng.standard_normal((9, 4, 4, D))
    machines = []
    for k in range(3):
        idx = np.sort(rng.choice(9, size=5, replace=False))
        machines.append(
            MachineSpec(k, -1, 0.1 * (k - 1), (2, 2, 4), (1.0, 0.5, 2.0), pool[idx], rng.standard_normal(5))
        )
    return ModelSpec(
        class_names=["brush", "finger", "washer"],
        rule="one_vs_all",
        machines=machines,
        D=D,
        grid_shape=(4, 4),
        window="energy",
        subsample="algorithm2",
        sample_rate_hz=3000.0,
        # the detector's defaults with an unbounded window: a format version 1 file
        window_config=WindowConfig(window_samples=0),
        meta={"note": "loader test fixture, random bases"},
    )


def binary_spec() -> ModelSpec:
    """A two-class model with the binary rule: one machine (positive class 1) over 4 support
    vectors, 2x3 taxels, D = 4."""
    rng = np.random.default_rng(2)
    pool = rng.standard_normal((4, 2, 3, 4))
    machine = MachineSpec(1, 0, 0.25, (2, 2, 2), (1.0, 2.0, 0.5), pool, rng.standard_normal(4))
    return ModelSpec(
        class_names=["press", "tap"],
        rule="binary",
        machines=[machine],
        D=4,
        grid_shape=(2, 3),
        window="none",
        subsample="even",
        sample_rate_hz=1000.0,
        window_config=WindowConfig(window_samples=0),
    )


def projection_spec() -> ModelSpec:
    """Two machines of different alpha whose time mode (N = 4 x 4 = 16 rows) is cut to alpha 5
    and 6 > 4: on the host its distances go through the cached projections (N < alpha^2);
    4x4 taxels, D = 8, one-vs-all over two classes."""
    rng = np.random.default_rng(5)
    D = 8
    pool = rng.standard_normal((6, 4, 4, D))
    machines = [
        MachineSpec(0, -1, 0.05, (2, 3, 5), (1.0, 0.75, 1.5), pool[[0, 1, 2, 4]],
                    rng.standard_normal(4)),
        MachineSpec(1, -1, -0.1, (3, 2, 6), (0.5, 1.0, 2.0), pool[[1, 3, 4, 5]],
                    rng.standard_normal(4)),
    ]
    return _one_vs_all(["slide", "roll"], machines, D, (4, 4))


def uneven_spec() -> ModelSpec:
    """Two machines on a 3x5 grid whose modes are kept to different alphas (stored alphas 3, 4
    and 5: no two modes alike), D = 6, one-vs-all over two classes."""
    rng = np.random.default_rng(7)
    D = 6
    pool = rng.standard_normal((5, 3, 5, D))
    machines = [
        MachineSpec(0, -1, 0.1, (3, 2, 5), (1.0, 0.75, 1.5), pool[[0, 1, 3]],
                    rng.standard_normal(3)),
        MachineSpec(1, -1, -0.2, (1, 4, 3), (0.5, 1.25, 2.0), pool[[1, 2, 4]],
                    rng.standard_normal(3)),
    ]
    return _one_vs_all(["pinch", "stroke"], machines, D, (3, 5))


def wide_rows_spec() -> ModelSpec:
    """Two machines on a 4x5 grid at D = 3, every mode at its full alpha (4, 5, 3): the row and
    column modes take the projection route (N = 15 < 4^2 and 12 < 5^2), the row mode's
    projection (15 x 15) the larger one."""
    rng = np.random.default_rng(11)
    D = 3
    pool = rng.standard_normal((4, 4, 5, D))
    machines = [
        MachineSpec(0, -1, 0.1, (4, 5, 3), (1.0, 0.75, 1.5), pool[[0, 1, 2]],
                    rng.standard_normal(3)),
        MachineSpec(1, -1, -0.2, (4, 5, 3), (0.5, 1.25, 2.0), pool[[1, 3]],
                    rng.standard_normal(2)),
    ]
    return _one_vs_all(["pinch", "stroke"], machines, D, (4, 5))


def main() -> None:
    spec = fixture_spec()
    for dtype in ("float32", "float64"):
        out = Path(__file__).with_name(f"model_small_{dtype}.eskin")
        out.write_bytes(model_to_bytes(spec, dtype, bases_fn=qr_bases))
        print(out, out.stat().st_size)
    out = Path(__file__).with_name("model_binary_float64.eskin")
    out.write_bytes(model_to_bytes(binary_spec(), "float64", bases_fn=qr_bases))
    print(out, out.stat().st_size)
    for dtype in ("float32", "float64"):
        out = Path(__file__).with_name(f"model_projection_{dtype}.eskin")
        out.write_bytes(model_to_bytes(projection_spec(), dtype, bases_fn=qr_bases))
        print(out, out.stat().st_size)
    out = Path(__file__).with_name("model_uneven_float64.eskin")
    out.write_bytes(model_to_bytes(uneven_spec(), "float64", bases_fn=qr_bases))
    print(out, out.stat().st_size)
    out = Path(__file__).with_name("model_wide_rows_float64.eskin")
    out.write_bytes(model_to_bytes(wide_rows_spec(), "float64", bases_fn=qr_bases))
    print(out, out.stat().st_size)


if __name__ == "__main__":
    main()
