"""Tests of eskin.kernel: the tensor kernel against the shared test vectors, against a
paper-literal implementation (explicit projection matrices), its properties, and its errors."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import eskin
from eskin import _core
from eskin.learn.kernel import (
    bases_mode_distances,
    bases_tensor_kernel,
    distance_plan,
    kernel_from_distances,
    mode_distances,
    pattern_bases,
    resolve_alphas,
    tensor_kernel,
)

# ----------------------------------------------------------------------------------------------
# paper-literal reference (test only): cyclic unfolding of the paper, full SVD, N x N projections


def literal_unfold(x: np.ndarray, z: int) -> np.ndarray:
    """The paper's mode-z unfolding, columns ordered cyclically l(z+1)..l(Z), l(1)..l(z-1)."""
    order = [z, *range(z + 1, x.ndim), *range(z)]
    return x.transpose(order).reshape(x.shape[z], -1)


def literal_mode_distances(X: np.ndarray, Y: np.ndarray, alphas) -> np.ndarray:
    n_modes = X.ndim - 1
    out = np.empty((n_modes, len(X), len(Y)))
    for z, a in enumerate(alphas):

        def proj(x, z=z, a=a):
            _, _, vt = np.linalg.svd(literal_unfold(x, z), full_matrices=True)
            v = vt[:a].T
            return v @ v.T

        px = [proj(x) for x in X]
        py = [proj(y) for y in Y]
        for i, p in enumerate(px):
            for j, q in enumerate(py):
                out[z, i, j] = np.linalg.norm(p - q, "fro") ** 2
    return out


def literal_kernel(X, Y, alphas, sigma):
    d = literal_mode_distances(X, Y, alphas)
    return np.exp(-d.sum(axis=0) / (2 * sigma**2))


# ----------------------------------------------------------------------------------------------
# shared test vectors


def _vector_cases():
    data = np.load(
        __import__("pathlib").Path(__file__).resolve().parents[2]
        / "data"
        / "tensor_kernel_vectors.npz"
    )
    keys = sorted(k[: -len("/alphas")] for k in data.files if k.endswith("/alphas"))
    return keys


@pytest.fixture(scope="module")
def vectors(data_dir):
    return np.load(data_dir / "tensor_kernel_vectors.npz")


@pytest.mark.parametrize("key", _vector_cases())
def test_reproduces_shared_test_vectors(vectors, key):
    case = key.split("/")[0]
    X, Y = vectors[f"{case}/X"], vectors[f"{case}/Y"]
    alphas = tuple(int(a) for a in vectors[f"{key}/alphas"])
    d = mode_distances(X, Y, alpha=alphas)
    np.testing.assert_allclose(d, vectors[f"{key}/mode_dist"], rtol=0, atol=1e-10)
    for s, K_expected in zip(vectors["sigmas"], vectors[f"{key}/K"]):
        K = tensor_kernel(X, Y, sigma=float(s), alpha=alphas)
        np.testing.assert_allclose(K, K_expected, rtol=0, atol=1e-10)


def test_top_level_import_reproduces_vectors(vectors):
    X, Y = vectors["grid4x4_D20/X"], vectors["grid4x4_D20/Y"]
    K = eskin.tensor_kernel(X, Y, sigma=2.0, alpha=[2, 2, 8])
    expected = vectors["grid4x4_D20/a2_2_8/K"][list(vectors["sigmas"]).index(2.0)]
    np.testing.assert_allclose(K, expected, rtol=0, atol=1e-10)


# ----------------------------------------------------------------------------------------------
# against the paper-literal formulation

LITERAL_CASES = [
    ((4, 4, 20), (2, 2, 8)),
    ((4, 4, 20), "full"),
    ((4, 4, 20), 1),
    ((3, 5, 7), "half"),
    ((6, 9), "full"),
    ((6, 9), (3, 2)),
    ((2, 3, 4, 5), "half"),
    ((2, 3, 4, 5), (1, 2, 3, 4)),
    ((5, 1, 3), "full"),
    ((4, 4, 10), (4, 3, 10)),
    ((2, 12, 3), "full"),  # mode 2: M > N with columns not contiguous (general unfolding path)
    ((2, 12, 3), (1, 4, 2)),
]


@pytest.mark.parametrize(("shape", "alpha"), LITERAL_CASES)
def test_equals_paper_literal_formulation(shape, alpha):
    rng = np.random.default_rng(abs(hash((shape, str(alpha)))) % 2**32)
    X = rng.normal(size=(5, *shape))
    Y = rng.normal(size=(4, *shape))
    alphas = resolve_alphas(shape, alpha)
    expected = literal_mode_distances(X, Y, alphas)
    np.testing.assert_allclose(mode_distances(X, Y, alpha=alpha), expected, rtol=0, atol=1e-10)
    np.testing.assert_allclose(
        mode_distances(X, alpha=alpha), literal_mode_distances(X, X, alphas), rtol=0, atol=1e-10
    )
    np.testing.assert_allclose(
        tensor_kernel(X, Y, sigma=1.5, alpha=alpha),
        literal_kernel(X, Y, alphas, 1.5),
        rtol=0,
        atol=1e-10,
    )


def test_many_patterns_cross_tiles_and_threads():
    """Enough patterns to span many tiles and thread work items; odd counts for padding."""
    rng = np.random.default_rng(7)
    X = rng.normal(size=(37, 4, 4, 20))
    Y = rng.normal(size=(11, 4, 4, 20))
    for alpha in [(1, 1, 1), (2, 2, 8), (3, 3, 5), (4, 4, 16), (4, 3, 9)]:
        expected = literal_mode_distances(X[:9], Y, alpha)
        got = mode_distances(X, Y, alpha=alpha, n_threads=2)
        np.testing.assert_allclose(got[:, :9], expected, rtol=0, atol=1e-10)
        single = mode_distances(X, alpha=alpha, n_threads=1)
        multi = mode_distances(X, alpha=alpha, n_threads=3)
        np.testing.assert_array_equal(single, multi)
        np.testing.assert_allclose(
            single[:, :9, :9], literal_mode_distances(X[:9], X[:9], alpha), rtol=0, atol=1e-10
        )
        # X-vs-X equals X-vs-Y with Y = X
        np.testing.assert_allclose(single, mode_distances(X, X, alpha=alpha), rtol=0, atol=1e-12)
        # the fused kernel equals exp of the distances, in both layouts, for any thread count
        sig = (0.7, 1.3, 2.0)
        for nt in (1, 2):
            np.testing.assert_allclose(
                tensor_kernel(X, sigma=sig, alpha=alpha, n_threads=nt),
                kernel_from_distances(single, sig),
                rtol=1e-14,
                atol=0,
            )
            np.testing.assert_allclose(
                tensor_kernel(X, Y, sigma=sig, alpha=alpha, n_threads=nt),
                kernel_from_distances(got, sig),
                rtol=1e-14,
                atol=0,
            )


def test_generic_and_vector_micro_kernels_agree(monkeypatch):
    rng = np.random.default_rng(3)
    X = rng.normal(size=(21, 4, 4, 30))
    Y = rng.normal(size=(5, 4, 4, 30))
    results = {}
    for isa in ["generic", "avx2", "avx512"]:
        monkeypatch.setenv("ESKIN_KERNEL_ISA", isa)
        name = _core.tensor_kernel_isa()
        results[name] = [mode_distances(X, alpha=a) for a in [(2, 2, 8), (3, 1, 12)]]
        results[name] += [mode_distances(X, Y, alpha=(4, 4, 16))]
    assert "generic" in results
    for name, got in results.items():
        for g, ref in zip(got, results["generic"]):
            np.testing.assert_allclose(g, ref, rtol=0, atol=1e-12, err_msg=name)


# ----------------------------------------------------------------------------------------------
# properties


@st.composite
def pattern_sets(draw):
    shape = draw(st.sampled_from([(4, 4, 8), (3, 5, 7), (2, 6), (2, 3, 2, 3), (4, 4, 20)]))
    n = draw(st.integers(min_value=1, max_value=9))
    seed = draw(st.integers(min_value=0, max_value=2**32 - 1))
    q = resolve_alphas(shape, "full")
    alphas = tuple(draw(st.integers(min_value=1, max_value=qz)) for qz in q)
    rng = np.random.default_rng(seed)
    X = rng.normal(size=(n, *shape)) * rng.uniform(0.1, 10.0)
    return X, alphas, rng


HYP = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@HYP
@given(pattern_sets(), st.floats(min_value=0.2, max_value=5.0))
def test_gram_is_symmetric_psd_with_unit_diagonal(data, sigma):
    X, alphas, _ = data
    K = tensor_kernel(X, sigma=sigma, alpha=alphas)
    np.testing.assert_array_equal(K, K.T)
    np.testing.assert_array_equal(np.diag(K), np.ones(len(X)))
    assert np.all((K >= 0) & (K <= 1))
    assert np.linalg.eigvalsh(K).min() >= -1e-10 * len(X)


@HYP
@given(pattern_sets(), st.floats(min_value=1e-3, max_value=1e3), st.booleans())
def test_invariant_to_scaling_a_pattern(data, scale, negative):
    X, alphas, rng = data
    c = -scale if negative else scale
    i = int(rng.integers(len(X)))
    X2 = X.copy()
    X2[i] *= c
    np.testing.assert_allclose(
        mode_distances(X2, alpha=alphas), mode_distances(X, alpha=alphas), rtol=0, atol=1e-9
    )
    # a pattern against its own scaled copy: distance 0, kernel 1
    np.testing.assert_allclose(
        mode_distances(X[i : i + 1], X2[i : i + 1], alpha=alphas), 0, atol=1e-9
    )


@HYP
@given(pattern_sets())
def test_invariant_to_sign_flips_of_singular_vectors(data):
    """The distances depend on V only through V V^T: flipping any basis column changes nothing."""
    X, alphas, rng = data
    bx = pattern_bases(X, alpha=alphas)
    expected = bases_mode_distances(bx)
    for z in range(len(alphas)):
        V = bx.mode_bases(z)
        flips = rng.choice([-1.0, 1.0], size=(V.shape[0], 1, V.shape[2]))
        Vf = V * flips
        r = bx.ranks[:, z].astype(float)
        overlap = np.einsum("akc,bkd->abcd", Vf, Vf)
        d = r[:, None] + r[None, :] - 2 * (overlap**2).sum(axis=(2, 3))
        np.testing.assert_allclose(np.maximum(d, 0), expected[z], rtol=0, atol=1e-10)


def test_pattern_bases_are_orthonormal_and_sign_normalised():
    rng = np.random.default_rng(11)
    X = rng.normal(size=(6, 4, 4, 20))
    bx = pattern_bases(X, alpha=(2, 3, 8))
    assert bx.count == 6 and tuple(bx.shape) == (4, 4, 20) and tuple(bx.alphas) == (2, 3, 8)
    for z, (n_z, a) in enumerate([(80, 2), (80, 3), (16, 8)]):
        V = bx.mode_bases(z)
        assert V.shape == (6, n_z, a)
        for v in V:
            np.testing.assert_allclose(v.T @ v, np.eye(a), atol=1e-12)
            top = np.abs(v).argmax(axis=0)
            assert np.all(v[top, np.arange(a)] > 0)
    # the bases of -X are those of X (sign rule), and equal the first right-singular vectors
    np.testing.assert_allclose(
        pattern_bases(-X, alpha=(2, 3, 8)).mode_bases(2), bx.mode_bases(2), atol=1e-10
    )
    _, _, vt = np.linalg.svd(np.moveaxis(X[0], 2, 0).reshape(20, -1))
    proj = bx.mode_bases(2)[0] @ bx.mode_bases(2)[0].T
    np.testing.assert_allclose(proj, vt[:8].T @ vt[:8], atol=1e-10)


def test_heap_free_workspace_matches_batch_bases():
    rng = np.random.default_rng(5)
    X = rng.normal(size=(4, 3, 5, 7))
    alphas = (2, 3, 5)
    bx = pattern_bases(X, alpha=alphas)
    ws = _core.BasisWorkspace([3, 5, 7], list(alphas))
    for i, x in enumerate(X):
        bases, ranks, status = ws.compute(x)
        assert status == "ok"
        np.testing.assert_array_equal(ranks, bx.ranks[i])
        off = 0
        for z, a in enumerate(alphas):
            n_z = 105 // (3, 5, 7)[z]
            block = bases[off : off + n_z * a].reshape(a, n_z).T  # column-major N x alpha
            np.testing.assert_array_equal(block, bx.mode_bases(z)[i])
            off += n_z * a
    bad = X[0].copy()
    bad[1, 2, 3] = np.nan
    assert ws.compute(bad)[2] == "not_finite"


def test_precomputed_bases_reuse_and_sigma_sweep():
    rng = np.random.default_rng(2)
    X = rng.normal(size=(8, 4, 4, 10))
    Y = rng.normal(size=(3, 4, 4, 10))
    bx, by = pattern_bases(X, alpha="half"), pattern_bases(Y, alpha="half")
    np.testing.assert_array_equal(
        bases_tensor_kernel(bx, by, sigma=0.7), tensor_kernel(X, Y, sigma=0.7, alpha="half")
    )
    D = mode_distances(X, Y, alpha="half")
    np.testing.assert_array_equal(bases_mode_distances(bx, by), D)
    for sigma in [0.5, (0.5, 1.0, 2.0)]:
        np.testing.assert_allclose(
            kernel_from_distances(D, sigma),
            tensor_kernel(X, Y, sigma=sigma, alpha="half"),
            rtol=1e-14,
        )
    with pytest.raises(ValueError, match="alphas differ"):
        bases_mode_distances(bx, pattern_bases(Y, alpha="full"))


def test_per_mode_sigma_is_product_of_factors():
    rng = np.random.default_rng(4)
    X = rng.normal(size=(5, 3, 4, 6))
    D = mode_distances(X, alpha=1)
    sig = (0.5, 2.0, 3.0)
    expected = np.prod([np.exp(-D[z] / (2 * s**2)) for z, s in enumerate(sig)], axis=0)
    np.testing.assert_allclose(tensor_kernel(X, sigma=sig, alpha=1), expected, rtol=1e-13)


# ----------------------------------------------------------------------------------------------
# degenerate patterns: documented, finite results


def test_all_zero_pattern_has_rank_zero_and_finite_kernel():
    rng = np.random.default_rng(9)
    X = rng.normal(size=(3, 4, 4, 20))
    X[1] = 0.0
    alphas = (2, 2, 8)
    bx = pattern_bases(X, alpha=alphas)
    np.testing.assert_array_equal(bx.ranks[1], [0, 0, 0])
    assert all(np.all(bx.mode_bases(z)[1] == 0) for z in range(3))
    D = mode_distances(X, alpha=alphas)
    assert np.all(np.isfinite(D))
    # distance of the zero pattern to a full-rank one: r_a + r_b - 0 = alpha
    np.testing.assert_allclose(D[:, 1, 0], alphas)
    K = tensor_kernel(X, X, alpha=alphas)
    assert K[1, 1] == 1.0 and np.all(np.isfinite(K))


def test_rank_deficient_pattern_zero_columns_beyond_rank():
    rng = np.random.default_rng(10)
    a, b, c = rng.normal(size=4), rng.normal(size=4), rng.normal(size=20)
    rank1 = np.einsum("i,j,k->ijk", a, b, c)
    dead = rng.normal(size=(4, 4, 20))
    dead[:, 2, :] = 0.0  # a dead column of taxels: mode-2 rank 3
    X = np.stack([rank1, dead, rng.normal(size=(4, 4, 20))])
    bx = pattern_bases(X, alpha=(2, 4, 8))
    np.testing.assert_array_equal(bx.ranks[0], [1, 1, 1])
    np.testing.assert_array_equal(bx.ranks[1], [2, 3, 8])
    V = bx.mode_bases(1)[1]
    assert np.all(V[:, 3] == 0)
    np.testing.assert_allclose(V[:, :3].T @ V[:, :3], np.eye(3), atol=1e-12)
    D = mode_distances(X, alpha=(2, 4, 8))
    assert np.all(np.isfinite(D)) and np.all(D >= 0)
    # rank-1 pattern against itself scaled: 0; the literal formula on its rank-1 part agrees
    np.testing.assert_allclose(mode_distances(X[:1], 3 * X[:1], alpha=(2, 4, 8)), 0, atol=1e-10)
    K = tensor_kernel(X, alpha=(2, 4, 8))
    np.testing.assert_array_equal(np.diag(K), 1.0)


# ----------------------------------------------------------------------------------------------
# alphas and errors


def test_resolve_alphas():
    assert resolve_alphas((4, 4, 100), "full") == (4, 4, 16)
    assert resolve_alphas((4, 4, 100), "half") == (2, 2, 8)
    assert resolve_alphas((4, 4, 100), 1) == (1, 1, 1)
    assert resolve_alphas((4, 4, 100), [2, 2, 8]) == (2, 2, 8)
    assert resolve_alphas((4, 4, 10), "full") == (4, 4, 10)
    assert resolve_alphas((3, 1, 2), "half") == (1, 1, 1)
    assert resolve_alphas((2, 3, 4, 5), "full") == (2, 3, 4, 5)
    assert resolve_alphas(np.array([4, 4, 20]), np.array([2, 2, 8])) == (2, 2, 8)


@pytest.mark.parametrize(
    ("shape", "alpha", "match"),
    [
        ((4, 4, 20), 5, r"alpha=5 for mode 0 is outside \[1, Q_0=4\]"),
        ((4, 4, 20), 0, r"alpha=0 for mode 0"),
        ((4, 4, 20), (2, 2, 17), r"alpha=17 for mode 2 is outside \[1, Q_2=16\]"),
        ((4, 4, 20), (2, 2), r"has 2 values .* 3 modes"),
        ((4, 4, 20), "most", r"alpha='most'"),
        ((4, 4, 20), 2.5, r"alpha=2.5"),
        ((4, 4, 20), (2, 2.0, 3), r"integer"),
        ((4, 4, 20), True, r"alpha=True"),
        ((20,), 1, r"order >= 2"),
    ],
)
def test_bad_alpha_is_a_value_error(shape, alpha, match):
    with pytest.raises(ValueError, match=match):
        resolve_alphas(shape, alpha)


def test_errors_name_the_argument_and_value():
    rng = np.random.default_rng(1)
    X = rng.normal(size=(3, 4, 4, 10))
    with pytest.raises(ValueError, match=r"X has shape \(3, 4\)"):
        tensor_kernel(X[:, :, 0, 0])
    with pytest.raises(ValueError, match=r"Y patterns have shape \(4, 4, 9\)"):
        tensor_kernel(X, X[:, :, :, :9])
    with pytest.raises(ValueError, match=r"Y patterns have shape \(4, 4\)"):
        mode_distances(X, X[:, :, :, 0])
    bad = X.copy()
    bad[2, 0, 1, 3] = np.nan
    with pytest.raises(ValueError, match=r"X: pattern 2 contains NaN or Inf"):
        tensor_kernel(bad)
    bad[2, 0, 1, 3] = np.inf
    with pytest.raises(ValueError, match=r"Y: pattern 2 contains NaN or Inf"):
        mode_distances(X, bad)
    for sigma, match in [
        (0.0, r"sigma=0.0"),
        (-1.0, r"sigma=-1.0"),
        (np.nan, r"sigma=nan"),
        ((1.0, 2.0), r"sigma=\(1.0, 2.0\) has 2 values"),
        ("1", r"sigma='1'"),
    ]:
        with pytest.raises(ValueError, match=match):
            tensor_kernel(X, sigma=sigma)
    with pytest.raises(ValueError, match=r"alpha=17 for mode 2"):
        tensor_kernel(X, alpha=(1, 1, 17))
    with pytest.raises(ValueError, match=r"alpha=0"):
        mode_distances(X, alpha=0)
    with pytest.raises(ValueError, match=r"dtype complex"):
        tensor_kernel(X.astype(complex))
    with pytest.raises(ValueError, match=r"n_threads=0"):
        tensor_kernel(X, n_threads=0)
    with pytest.raises(ValueError, match=r"distances has shape"):
        kernel_from_distances(np.zeros((3, 3)))


def test_empty_and_single_pattern_sets():
    rng = np.random.default_rng(6)
    X = rng.normal(size=(1, 4, 4, 10))
    assert tensor_kernel(X).shape == (1, 1)
    assert tensor_kernel(X, np.zeros((0, 4, 4, 10))).shape == (1, 0)
    assert mode_distances(np.zeros((0, 4, 4, 10))).shape == (3, 0, 0)


def test_integer_input_is_converted():
    rng = np.random.default_rng(8)
    X = rng.integers(-100, 100, size=(4, 4, 4, 12)).astype(np.int16)
    np.testing.assert_allclose(
        tensor_kernel(X, alpha="half"), tensor_kernel(X.astype(float), alpha="half"), rtol=0, atol=0
    )


def test_unfold_column_order_is_c_order_of_remaining_indices():
    x = np.arange(2 * 3 * 4, dtype=float).reshape(2, 3, 4)
    for z in range(3):
        np.testing.assert_array_equal(
            _core.unfold(x, z), np.moveaxis(x, z, 0).reshape(x.shape[z], -1)
        )


# ----------------------------------------------------------------------------------------------
# blocked distances: the scratch memory limit changes the plan, never the distances


@pytest.mark.parametrize(
    ("shape", "alpha", "n", "m"),
    [
        ((3, 5, 12), "full", 37, None),  # alphas 3, 5, 12: several panels per pattern
        ((3, 5, 12), "half", 29, 21),  # alphas 1, 2, 6: 8, 4 and 1 patterns per group
        ((4, 4, 16), "full", 41, None),  # mode 3 by packed projections
        ((6, 7, 9), 1, 33, 18),  # one vector per pattern in every mode
        ((5, 6, 4, 3), "half", 35, None),  # order 4
    ],
)
def test_blocked_distances_are_the_unblocked_ones_bit_for_bit(shape, alpha, n, m):
    rng = np.random.default_rng(sum(shape) + n)
    X = rng.normal(size=(n, *shape))
    Y = None if m is None else rng.normal(size=(m, *shape))
    alphas = resolve_alphas(shape, alpha)
    whole = mode_distances(X, Y, alpha=alphas, n_threads=2)
    smallest = distance_plan(shape, alphas, 8, 8)["pack_bytes"]
    for limit in (smallest, 2 * smallest, 3 * smallest):
        plan = distance_plan(shape, alphas, n, m, max_bytes=limit)
        assert plan["pack_bytes"] <= limit
        assert plan["row_blocks"] == -(-n // plan["block"])
        blocked = mode_distances(X, Y, alpha=alphas, n_threads=2, max_bytes=limit)
        if plan["bases_only"] == 0:  # the same packing: the same bits
            np.testing.assert_array_equal(blocked, whole)
        else:  # a projection mode packed as bases: the same sums in another order
            np.testing.assert_allclose(blocked, whole, rtol=0, atol=1e-12)


def test_short_of_memory_a_projection_mode_is_packed_as_bases():
    shape = (19, 27, 70)
    alphas = resolve_alphas(shape, "full")
    unlimited = distance_plan(shape, alphas, 336)
    assert unlimited["pack_bytes"] > 2_800_000_000 and unlimited["bases_only"] == 0
    plan = distance_plan(shape, alphas, 336, max_bytes=512 << 20)
    assert plan["bases_only"] == 0b110  # the second mode (N = 1330) and the time mode (N = 513)
    assert plan["row_blocks"] == 1 and plan["pack_bytes"] < 512 << 20
    X = np.random.default_rng(1).normal(size=(20, 3, 4, 9))
    al = resolve_alphas((3, 4, 9), "full")
    small = distance_plan((3, 4, 9), al, 20, max_bytes=distance_plan((3, 4, 9), al, 20)[
        "pack_bytes"] - 1)
    np.testing.assert_allclose(
        mode_distances(X, alpha=al, max_bytes=small["pack_bytes"]),
        mode_distances(X, alpha=al, max_bytes=None), rtol=0, atol=1e-12)


def test_the_distance_plan_keeps_within_the_limit():
    shape, alphas = (19, 27, 10), resolve_alphas((19, 27, 10), "full")
    unlimited = distance_plan(shape, alphas, 330)
    assert unlimited["row_blocks"] == 1 and unlimited["block"] == 330
    assert 330 * unlimited["pattern_bytes"] <= unlimited["pack_bytes"] <= 336 * unlimited["pattern_bytes"]
    for limit in (unlimited["pack_bytes"] // 3, 50 * 2**20, 20 * 2**20):
        plan = distance_plan(shape, alphas, 330, max_bytes=limit)
        assert plan["pack_bytes"] <= limit
        assert plan["row_blocks"] == -(-330 // plan["block"])
        if plan["row_blocks"] > 1:  # the largest block of 8s that fits: 8 more would not
            assert plan["block"] % 8 == 0
            assert 2 * (plan["block"] + 8) * plan["pattern_bytes"] > limit
    # a limit the whole set fits in is one block
    assert distance_plan(shape, alphas, 330, max_bytes=unlimited["pack_bytes"])["row_blocks"] == 1


def test_a_limit_below_two_blocks_of_eight_is_refused_with_the_figures():
    shape, alphas = (4, 4, 16), resolve_alphas((4, 4, 16), "full")
    per_pattern = distance_plan(shape, alphas, 8)["pattern_bytes"]
    X = np.random.default_rng(0).normal(size=(20, *shape))
    with pytest.raises(ValueError, match=r"need \d+ bytes of scratch memory, more than the limit"):
        mode_distances(X, alpha=alphas, max_bytes=16 * per_pattern - 1)
    with pytest.raises(ValueError, match="max_bytes"):
        mode_distances(X, alpha=alphas, max_bytes=0)
