// ScalarBases (cpp/src/scalar_bases.hpp): the per-pattern bases of the device build, in a chosen
// scalar type, against the host's BasisWorkspace. The subspaces must agree (projection matrices
// V V^T: columns are defined up to sign and, inside a degenerate eigenspace, up to rotation), the
// ranks must be equal, the conventions (orthonormal columns, zero columns beyond the rank, the
// largest entry of each column positive) must hold, and compute() must not allocate.
#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>
#include <cstdlib>
#include <new>
#include <random>
#include <vector>

#include "../../cpp/src/scalar_bases.hpp"
#include "eskin/tensor_kernel.hpp"

namespace {
std::atomic<bool> g_counting{false};
std::atomic<long> g_allocations{0};
}  // namespace
void* operator new(std::size_t n) {
  if (g_counting.load()) g_allocations.fetch_add(1);
  if (void* p = std::malloc(n ? n : 1)) return p;
  throw std::bad_alloc();
}
void operator delete(void* p) noexcept { std::free(p); }
void operator delete(void* p, std::size_t) noexcept { std::free(p); }

namespace {

using eskin::BasisLayout;
using eskin::KernelStatus;

std::vector<double> random_tensor(std::size_t n, unsigned seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> g(0.0, 1000.0);
  std::vector<double> x(n);
  for (auto& v : x) v = std::round(g(rng));  // ADC-like integers
  return x;
}

// max |P_a - P_b| over the projection matrices of the first `alpha` columns of two N x alpha blocks
template <class A, class B>
double projection_gap(const A* a, const B* b, std::size_t n, std::size_t alpha) {
  double worst = 0;
  for (std::size_t r = 0; r < n; ++r)
    for (std::size_t c = 0; c < n; ++c) {
      double pa = 0, pb = 0;
      for (std::size_t k = 0; k < alpha; ++k) {
        pa += double(a[k * n + r]) * double(a[k * n + c]);
        pb += double(b[k * n + r]) * double(b[k * n + c]);
      }
      worst = std::fmax(worst, std::fabs(pa - pb));
    }
  return worst;
}

struct Case {
  std::size_t D;
  std::vector<std::size_t> alphas;
  std::size_t rows = 4, cols = 4;
};

class ScalarBasesTest : public ::testing::TestWithParam<Case> {};

TEST_P(ScalarBasesTest, SubspacesAndRanksMatchTheHostWorkspace) {
  const Case c = GetParam();
  const BasisLayout layout({c.rows, c.cols, c.D}, c.alphas);
  eskin::BasisWorkspace host(layout);
  eskin::detail::ScalarBases<double> sb64(layout);
  eskin::detail::ScalarBases<float> sb32(layout);
  std::vector<double> ref(layout.bases_size()), b64(layout.bases_size());
  std::vector<float> b32(layout.bases_size());
  for (unsigned seed = 1; seed <= 5; ++seed) {
    const auto x = random_tensor(layout.tensor_size(), seed);
    int r_ref[3], r64[3], r32[3];
    ASSERT_EQ(host.compute(x.data(), ref.data(), r_ref), KernelStatus::ok);
    g_counting = true;
    const KernelStatus s64 = sb64.compute(x.data(), b64.data(), r64);
    const KernelStatus s32 = sb32.compute(x.data(), b32.data(), r32);
    g_counting = false;
    ASSERT_EQ(s64, KernelStatus::ok);
    ASSERT_EQ(s32, KernelStatus::ok);
    for (std::size_t z = 0; z < 3; ++z) {
      EXPECT_EQ(r64[z], r_ref[z]) << "mode " << z << " seed " << seed;
      EXPECT_EQ(r32[z], r_ref[z]) << "mode " << z << " seed " << seed;
      const std::size_t n = layout.cols(z), a = layout.alpha(z), off = layout.offset(z);
      EXPECT_LT(projection_gap(ref.data() + off, b64.data() + off, n, a), 1e-9) << "mode " << z;
      // float32: the subspace agrees to float precision (QR and one-sided Jacobi work on the
      // data, not on its square)
      EXPECT_LT(projection_gap(ref.data() + off, b32.data() + off, n, a), 1e-4) << "mode " << z;
      for (std::size_t k = 0; k < a; ++k) {
        const float* col = b32.data() + off + k * n;
        double norm = 0, big = 0;
        for (std::size_t i = 0; i < n; ++i) {
          norm += double(col[i]) * col[i];
          if (std::fabs(col[i]) > std::fabs(big)) big = col[i];
        }
        EXPECT_NEAR(norm, 1.0, 1e-5);
        EXPECT_GT(big, 0.0) << "the largest entry of a column is positive";
      }
    }
  }
  EXPECT_EQ(g_allocations.load(), 0) << "compute() allocated";
}

INSTANTIATE_TEST_SUITE_P(Shapes, ScalarBasesTest,
                         ::testing::Values(Case{20, {1, 1, 1}}, Case{20, {2, 2, 8}},
                                           Case{50, {4, 4, 16}}, Case{100, {2, 2, 8}},
                                           // a square time unfolding (16 taxels x 16 samples)
                                           Case{16, {2, 2, 8}},
                                           // a 2 x 8 grid: the row mode has the longest
                                           // columns (8 x 20), the workspace sized by them
                                           Case{20, {2, 4, 8}, 2, 8}));

TEST(ScalarBases, TheTimeModeAtAlphaQSpansOrFallsBackToItsSingularVectors) {
  // alpha_3 = 16 = the taxels: a full-rank time unfolding spans R^16 (the identity is a basis of
  // it, and the rank is 16); one that mixes 4 temporal sources (sin and cos of one
  // frequency, two others) has rank 4, and its basis is the host's
  const BasisLayout layout({4, 4, 50}, {4, 4, 16});
  eskin::BasisWorkspace host(layout);
  eskin::detail::ScalarBases<float> sb(layout);
  std::vector<double> ref(layout.bases_size());
  std::vector<float> b(layout.bases_size());
  int r[3], r_ref[3];
  const std::size_t off = layout.offset(2), n = layout.cols(2);
  std::vector<double> x = random_tensor(layout.tensor_size(), 3);
  ASSERT_EQ(sb.compute(x.data(), b.data(), r), KernelStatus::ok);
  ASSERT_EQ(host.compute(x.data(), ref.data(), r_ref), KernelStatus::ok);
  EXPECT_EQ(r[2], 16);
  EXPECT_EQ(r_ref[2], 16);
  EXPECT_LT(projection_gap(ref.data() + off, b.data() + off, n, 16), 1e-5);
  for (std::size_t c = 0; c < n; ++c)
    for (std::size_t j = 0; j < n; ++j)
      ASSERT_EQ(b[off + c * n + j], c == j ? 1.0f : 0.0f);
  // full rank but ill-conditioned (one taxel 1e-4 of the others: beyond the quick proof of
  // full rank, within the rank's tolerance): the sweeps find rank 16
  for (std::size_t t = 0; t < 50; ++t) x[7 * 50 + t] *= 1e-4;
  ASSERT_EQ(sb.compute(x.data(), b.data(), r), KernelStatus::ok);
  ASSERT_EQ(host.compute(x.data(), ref.data(), r_ref), KernelStatus::ok);
  EXPECT_EQ(r[2], 16);
  EXPECT_EQ(r_ref[2], 16);
  EXPECT_LT(projection_gap(ref.data() + off, b.data() + off, n, 16), 1e-4);
  // decided by the sweeps (kappa about 1e4, beyond the proof's 8e3): the singular vectors, not
  // the identity
  float off_diagonal = 0.0f;
  for (std::size_t c = 0; c < n; ++c)
    for (std::size_t j = 0; j < n; ++j)
      if (c != j) off_diagonal = std::max(off_diagonal, std::fabs(b[off + c * n + j]));
  EXPECT_GT(off_diagonal, 1e-3f);
  for (std::size_t t = 0; t < 50; ++t)
    for (std::size_t i = 0; i < 16; ++i)
      x[i * 50 + t] = std::sin(0.2 * t + i) + (1.0 + 0.1 * i) * std::cos(0.45 * t) +
                      (i % 3) * std::sin(1.3 * t + 0.5);
  ASSERT_EQ(sb.compute(x.data(), b.data(), r), KernelStatus::ok);
  ASSERT_EQ(host.compute(x.data(), ref.data(), r_ref), KernelStatus::ok);
  EXPECT_EQ(r_ref[2], 4);
  EXPECT_EQ(r[2], 4);
  EXPECT_LT(projection_gap(ref.data() + off, b.data() + off, n, 16), 1e-4);
  for (std::size_t i = 4 * n; i < 16 * n; ++i) ASSERT_EQ(b[off + i], 0.0f);
}

TEST(ScalarBases, OneSidedJacobiConvergesInFewSweeps) {
  // random 16 x 16 factors (the time mode of a 4 x 4 grid) in float: orthogonal columns within
  // a few sweeps (9 at most here; 60 is the limit), and b = B0 W
  std::mt19937 rng(5);
  std::normal_distribution<float> g(0.0f, 1.0f);
  int worst = 0;
  for (int trial = 0; trial < 20; ++trial) {
    std::vector<float> b(256), b0, w(256), ws(16);
    for (auto& v : b) v = g(rng);
    b0 = b;
    const int sweeps = eskin::detail::one_sided_jacobi<float>(16, b.data(), w.data(), ws.data());
    ASSERT_GT(sweeps, 0);
    worst = std::max(worst, sweeps);
    for (std::size_t j = 0; j < 16; ++j)
      for (std::size_t k = j + 1; k < 16; ++k) {
        double d = 0, nj = 0, nk = 0;
        for (std::size_t i = 0; i < 16; ++i) {
          d += double(b[j * 16 + i]) * b[k * 16 + i];
          nj += double(b[j * 16 + i]) * b[j * 16 + i];
          nk += double(b[k * 16 + i]) * b[k * 16 + i];
        }
        ASSERT_LT(std::fabs(d), 1e-5 * std::sqrt(nj * nk) + 1e-6);
      }
    // b = B0 W
    for (std::size_t c = 0; c < 16; ++c)
      for (std::size_t r = 0; r < 16; ++r) {
        double v = 0;
        for (std::size_t k = 0; k < 16; ++k) v += double(b0[k * 16 + r]) * w[c * 16 + k];
        ASSERT_NEAR(v, b[c * 16 + r], 1e-4);
      }
  }
  EXPECT_LE(worst, 12);
}

TEST(ScalarBases, RankDeficientZeroAndNonFiniteTensors) {
  const BasisLayout layout({4, 4, 20}, {2, 2, 8});
  eskin::detail::ScalarBases<float> sb(layout);
  std::vector<float> b(layout.bases_size(), 7.0f);
  int r[3];
  // an outer product a (x) b (x) c has rank 1 in every mode: one column, the rest exactly zero
  std::vector<double> x(layout.tensor_size());
  for (std::size_t i = 0; i < 4; ++i)
    for (std::size_t j = 0; j < 4; ++j)
      for (std::size_t t = 0; t < 20; ++t)
        x[(i * 4 + j) * 20 + t] = (1.0 + i) * (2.0 - j) * std::sin(0.3 * t + 0.1);
  ASSERT_EQ(sb.compute(x.data(), b.data(), r), KernelStatus::ok);
  EXPECT_EQ(r[0], 1);
  EXPECT_EQ(r[1], 1);
  EXPECT_EQ(r[2], 1);
  for (std::size_t z = 0; z < 3; ++z) {
    const std::size_t n = layout.cols(z);
    for (std::size_t i = n; i < layout.alpha(z) * n; ++i)
      ASSERT_EQ(b[layout.offset(z) + i], 0.0f) << "mode " << z;
  }
  std::fill(x.begin(), x.end(), 0.0);
  ASSERT_EQ(sb.compute(x.data(), b.data(), r), KernelStatus::ok);
  EXPECT_EQ(r[0] + r[1] + r[2], 0);
  x[5] = std::nan("");
  std::fill(b.begin(), b.end(), 7.0f);
  EXPECT_EQ(sb.compute(x.data(), b.data(), r), KernelStatus::not_finite);
  for (float v : b) ASSERT_EQ(v, 0.0f);
  EXPECT_EQ(sb.compute(static_cast<const double*>(nullptr), b.data(), r),
            KernelStatus::bad_argument);
}

TEST(ScalarBases, OneSidedJacobiGivesTheSingularValueDecomposition) {
  // B0 = U diag(3, 1, 2) W0^T with rotations U, W0: the column norms of B0 W are 3, 1, 2 in some
  // order, W is orthogonal, and the columns of B0 W are mutually orthogonal
  const double c = std::cos(0.4), s = std::sin(0.4), c2 = std::cos(1.1), s2 = std::sin(1.1);
  const double U[9] = {c, -s, 0, s, c, 0, 0, 0, 1};
  const double W0[9] = {1, 0, 0, 0, c2, -s2, 0, s2, c2};
  const double L[3] = {3, 1, 2};
  double b[9] = {}, w[9], ws[3];  // column-major
  for (int r = 0; r < 3; ++r)
    for (int col = 0; col < 3; ++col)
      for (int k = 0; k < 3; ++k) b[col * 3 + r] += U[r * 3 + k] * L[k] * W0[col * 3 + k];
  ASSERT_GT(eskin::detail::one_sided_jacobi<double>(3, b, w, ws), 0);
  std::vector<double> norms;
  for (int j = 0; j < 3; ++j) {
    double n2 = 0, wn = 0;
    for (int i = 0; i < 3; ++i) {
      n2 += b[j * 3 + i] * b[j * 3 + i];
      wn += w[j * 3 + i] * w[j * 3 + i];
    }
    norms.push_back(std::sqrt(n2));
    EXPECT_NEAR(wn, 1.0, 1e-12);
    for (int k = j + 1; k < 3; ++k) {
      double d = 0, dw = 0;
      for (int i = 0; i < 3; ++i) {
        d += b[j * 3 + i] * b[k * 3 + i];
        dw += w[j * 3 + i] * w[k * 3 + i];
      }
      EXPECT_NEAR(d, 0.0, 1e-12);
      EXPECT_NEAR(dw, 0.0, 1e-12);
    }
  }
  std::sort(norms.begin(), norms.end());
  EXPECT_NEAR(norms[0], 1.0, 1e-12);
  EXPECT_NEAR(norms[1], 2.0, 1e-12);
  EXPECT_NEAR(norms[2], 3.0, 1e-12);
}

}  // namespace

TEST(ScalarBases, AnyOneNullArgumentIsABadArgument) {
  // each of the three pointers alone null: bad_argument, and nothing written through the others
  const BasisLayout layout({4, 4, 20}, {2, 2, 8});
  eskin::detail::ScalarBases<float> sb(layout);
  const auto x = random_tensor(layout.tensor_size(), 11);
  std::vector<float> b(layout.bases_size(), 7.0f);
  int r[3] = {9, 9, 9};
  EXPECT_EQ(sb.compute(x.data(), static_cast<float*>(nullptr), r), KernelStatus::bad_argument);
  for (int v : r) EXPECT_EQ(v, 9);
  EXPECT_EQ(sb.compute(x.data(), b.data(), static_cast<int*>(nullptr)),
            KernelStatus::bad_argument);
  for (float v : b) ASSERT_EQ(v, 7.0f);
  EXPECT_EQ(sb.compute(static_cast<const double*>(nullptr), b.data(), r),
            KernelStatus::bad_argument);
  for (float v : b) ASSERT_EQ(v, 7.0f);
  for (int v : r) EXPECT_EQ(v, 9);
}

TEST(ScalarBases, OneSidedJacobiTouchesOnlyItsNByNMatricesAndNNorms) {
  // the buffers one entry longer than documented: the extra entry keeps its value
  const double c = std::cos(0.7), s = std::sin(0.7);
  // 2 x 2, columns not orthogonal, then two guard entries
  std::vector<double> b = {3 * c, 3 * s, 0.5 - s, c, 12345.0, 12345.0};
  std::vector<double> w(6, 12345.0), norms(3, 12345.0);
  ASSERT_GT(eskin::detail::one_sided_jacobi<double>(2, b.data(), w.data(), norms.data()), 0);
  EXPECT_EQ(b[4], 12345.0);
  EXPECT_EQ(b[5], 12345.0);
  EXPECT_EQ(w[4], 12345.0);
  EXPECT_EQ(w[5], 12345.0);
  EXPECT_EQ(norms[2], 12345.0);
  EXPECT_NEAR(b[0] * b[2] + b[1] * b[3], 0.0, 1e-12);
}

TEST(ScalarBases, OneSidedJacobiReadsOnlyItsNByNMatrix) {
  // a huge value just past the 2 x 2 matrix is not part of it: the columns are still rotated
  // until orthogonal (read into the matrix's size, it would make every column pair look like
  // rounding noise and leave them as they were)
  const double c = std::cos(0.7), s = std::sin(0.7);
  std::vector<double> b = {3 * c, 3 * s, 0.5 - s, c, 1e300};
  std::vector<double> w(4), norms(2);
  ASSERT_GT(eskin::detail::one_sided_jacobi<double>(2, b.data(), w.data(), norms.data()), 0);
  EXPECT_NEAR(b[0] * b[2] + b[1] * b[3], 0.0, 1e-12);
}

TEST(ScalarBases, OneSidedJacobiOrthogonalisesAPairWithOneRotation) {
  // two columns are made orthogonal by one exact rotation: one sweep that rotates, then one that
  // finds nothing to rotate (an inexact angle leaves them to later sweeps: 4 or 5 here)
  const double c = std::cos(0.7), s = std::sin(0.7);
  for (const double off : {0.5, -2.0, 0.25}) {
    std::vector<double> b = {3 * c, 3 * s, off - s, c};
    std::vector<double> w(4), norms(2);
    EXPECT_EQ(eskin::detail::one_sided_jacobi<double>(2, b.data(), w.data(), norms.data()), 2)
        << off;
    EXPECT_NEAR(b[0] * b[2] + b[1] * b[3], 0.0, 1e-12) << off;
  }
}

TEST(ScalarBases, OneSidedJacobiRotatesAnEqualNormPairByTheTextbookAngle) {
  // an exact tie: columns (3, 4) and (4, 3), equal norms (zeta = 0). Both t = 1 and t = -1
  // orthogonalise them; the textbook rule (Golub and Van Loan, Matrix Computations, sym.schur2:
  // t = 1 / (tau + sqrt(1 + tau^2)) for tau >= 0) takes t = 1, so the pair becomes
  // ((x - y) / sqrt 2, (x + y) / sqrt 2), and w the same rotation of the identity
  std::vector<double> b = {3, 4, 4, 3}, w(4), norms(2);
  EXPECT_EQ(eskin::detail::one_sided_jacobi<double>(2, b.data(), w.data(), norms.data()), 2);
  const double h = 1 / std::sqrt(2.0);
  const double want_b[4] = {-h, h, 7 * h, 7 * h}, want_w[4] = {h, -h, h, h};
  for (int i = 0; i < 4; ++i) {
    EXPECT_NEAR(b[static_cast<std::size_t>(i)], want_b[i], 1e-15) << i;
    EXPECT_NEAR(w[static_cast<std::size_t>(i)], want_w[i], 1e-15) << i;
  }
}

TEST(ScalarBases, ASingleTaxelTouchedHasRankOneAtThatTaxel) {
  // a sparse tensor: one taxel (row 2, column 1) pressed with signal s(t), the other fifteen
  // exactly zero. Every mode has rank 1; its one basis vector lives on the other two indices (C
  // order): e_1 (x) s / |s| for the rows, e_2 (x) s / |s| for the columns, e_9 (the taxel 2 * 4 + 1)
  // for time
  const BasisLayout layout({4, 4, 20}, {2, 2, 8});
  eskin::detail::ScalarBases<float> sb(layout);
  std::vector<double> x(layout.tensor_size(), 0.0);
  double n2 = 0;
  for (std::size_t t = 0; t < 20; ++t) {
    x[(2 * 4 + 1) * 20 + t] = 100.0 + 10.0 * t;
    n2 += (100.0 + 10.0 * t) * (100.0 + 10.0 * t);
  }
  std::vector<float> b(layout.bases_size(), 7.0f);
  int r[3];
  ASSERT_EQ(sb.compute(x.data(), b.data(), r), KernelStatus::ok);
  EXPECT_EQ(r[0], 1);
  EXPECT_EQ(r[1], 1);
  EXPECT_EQ(r[2], 1);
  const std::size_t other[2] = {1, 2};  // the pressed taxel's index among the other two
  for (std::size_t z = 0; z < 2; ++z)
    for (std::size_t i = 0; i < 4 * 20; ++i) {
      const double want = i / 20 == other[z] ? (100.0 + 10.0 * (i % 20)) / std::sqrt(n2) : 0.0;
      ASSERT_NEAR(b[layout.offset(z) + i], want, 1e-6) << "mode " << z << " entry " << i;
    }
  for (std::size_t i = 0; i < 16; ++i) ASSERT_EQ(b[layout.offset(2) + i], i == 9 ? 1.0f : 0.0f);
  for (std::size_t z = 0; z < 3; ++z)
    for (std::size_t i = layout.cols(z); i < layout.alpha(z) * layout.cols(z); ++i)
      ASSERT_EQ(b[layout.offset(z) + i], 0.0f) << "mode " << z;
}

TEST(ScalarBases, ReadsExactlyTensorSizeValues) {
  // the pattern followed in memory by a NaN and a huge value: neither is part of it, so the
  // status and the bases are those of the pattern alone
  const BasisLayout layout({4, 4, 20}, {2, 2, 8});
  eskin::detail::ScalarBases<float> sb(layout);
  auto x = random_tensor(layout.tensor_size(), 5);
  std::vector<float> alone(layout.bases_size()), b(layout.bases_size());
  int r_alone[3], r[3];
  ASSERT_EQ(sb.compute(x.data(), alone.data(), r_alone), KernelStatus::ok);
  for (double next : {std::nan(""), 1e30}) {
    auto longer = x;
    longer.push_back(next);
    ASSERT_EQ(sb.compute(longer.data(), b.data(), r), KernelStatus::ok);
    for (std::size_t z = 0; z < 3; ++z) EXPECT_EQ(r[z], r_alone[z]);
    for (std::size_t i = 0; i < b.size(); ++i) ASSERT_EQ(b[i], alone[i]) << "entry " << i;
  }
}

TEST(ScalarBases, WritesExactlyBasesSizeValuesAndOneRankPerMode) {
  // output buffers one entry longer than documented: the extra entry keeps its value, whether
  // the last mode's basis comes from the singular vectors (alpha 8 of 16) or is the identity
  // (alpha 16 of 16, a full-rank time unfolding)
  for (std::size_t alpha : {8, 16}) {
    const BasisLayout layout({4, 4, 20}, {2, 2, alpha});
    eskin::detail::ScalarBases<float> sb(layout);
    const auto x = random_tensor(layout.tensor_size(), 13);
    std::vector<float> b(layout.bases_size() + 1, 7.0f);
    int r[4] = {9, 9, 9, 9};
    ASSERT_EQ(sb.compute(x.data(), b.data(), r), KernelStatus::ok);
    EXPECT_EQ(r[2], static_cast<int>(alpha));
    EXPECT_EQ(b.back(), 7.0f) << "alpha " << alpha;
    EXPECT_EQ(r[3], 9);
  }
}

TEST(ScalarBases, ASingleSampleOfASingleTaxelHasUnitVectorBases) {
  // one value at taxel (0, 1), sample 3: each mode's basis is the unit vector of that entry
  // among the other two indices (row mode: (1, 3) -> 23; column mode: (0, 3) -> 3; time: taxel
  // 1). The row mode's first reflector then has tau exactly 1 (a unit column with a zero first
  // entry): it must still be applied
  const BasisLayout layout({4, 4, 20}, {2, 2, 8});
  eskin::detail::ScalarBases<float> sb(layout);
  std::vector<double> x(layout.tensor_size(), 0.0);
  x[(0 * 4 + 1) * 20 + 3] = 250.0;
  std::vector<float> b(layout.bases_size(), 7.0f);
  int r[3];
  ASSERT_EQ(sb.compute(x.data(), b.data(), r), KernelStatus::ok);
  const std::size_t at[3] = {23, 3, 1};
  for (std::size_t z = 0; z < 3; ++z) {
    EXPECT_EQ(r[z], 1) << "mode " << z;
    const std::size_t n = layout.cols(z);
    for (std::size_t i = 0; i < layout.alpha(z) * n; ++i)
      ASSERT_NEAR(b[layout.offset(z) + i], i == at[z] ? 1.0f : 0.0f, 1e-6f)
          << "mode " << z << " entry " << i;
  }
}

TEST(ScalarBases, ThePatternsFirstValueCounts) {
  // the only non-zero value at index 0 (taxel (0, 0), sample 0), +1 or -1: rank 1 in every
  // mode, each basis the unit vector of entry 0 (the largest entry of each column positive);
  // a NaN there alone makes the pattern not finite
  const BasisLayout layout({4, 4, 20}, {2, 2, 8});
  eskin::detail::ScalarBases<float> sb(layout);
  for (const double v : {1.0, -1.0}) {
    std::vector<double> x(layout.tensor_size(), 0.0);
    x[0] = v;
    std::vector<float> b(layout.bases_size(), 7.0f);
    int r[3];
    ASSERT_EQ(sb.compute(x.data(), b.data(), r), KernelStatus::ok);
    for (std::size_t z = 0; z < 3; ++z) {
      EXPECT_EQ(r[z], 1) << "mode " << z << ", value " << v;
      const std::size_t n = layout.cols(z);
      for (std::size_t i = 0; i < layout.alpha(z) * n; ++i)
        ASSERT_NEAR(b[layout.offset(z) + i], i == 0 ? 1.0f : 0.0f, 1e-6f)
            << "mode " << z << " entry " << i << ", value " << v;
    }
  }
  std::vector<double> x(layout.tensor_size(), 0.0);
  x[0] = std::nan("");
  std::vector<float> b(layout.bases_size(), 7.0f);
  int r[3];
  EXPECT_EQ(sb.compute(x.data(), b.data(), r), KernelStatus::not_finite);
}

TEST(ScalarBases, ExactTiesKeepTheFirstEntryAndTheFirstSingularVector) {
  const BasisLayout layout({4, 4, 20}, {2, 2, 8});
  eskin::detail::ScalarBases<float> sb(layout);
  const auto expect_column = [&](const std::vector<float>& b, std::size_t z, std::size_t c,
                                 const std::vector<std::pair<std::size_t, float>>& want) {
    const std::size_t n = layout.cols(z);
    for (std::size_t i = 0; i < n; ++i) {
      float w = 0.0f;
      for (const auto& [at, v] : want) w = at == i ? v : w;
      ASSERT_NEAR(b[layout.offset(z) + c * n + i], w, 1e-6f)
          << "mode " << z << " column " << c << " entry " << i;
    }
  };
  const float h = 0.70710677f;
  {  // taxels (0, 0) and (0, 1) at sample 3, +1 and -1: the time mode's basis is (1, -1) / sqrt 2
     // over those taxels, entries of equal magnitude: the first is the one made positive
    std::vector<double> x(layout.tensor_size(), 0.0);
    x[0 * 20 + 3] = 1.0;
    x[1 * 20 + 3] = -1.0;
    std::vector<float> b(layout.bases_size());
    int r[3];
    ASSERT_EQ(sb.compute(x.data(), b.data(), r), KernelStatus::ok);
    EXPECT_EQ(r[2], 1);
    expect_column(b, 2, 0, {{0, h}, {1, -h}});
  }
  {  // taxel (0, 0) at sample 3 and taxel (0, 1) at sample 5, both 1: the column and time modes
     // have two equal singular values; their vectors come in the unfolding's order
    std::vector<double> x(layout.tensor_size(), 0.0);
    x[0 * 20 + 3] = 1.0;
    x[1 * 20 + 5] = 1.0;
    std::vector<float> b(layout.bases_size());
    int r[3];
    ASSERT_EQ(sb.compute(x.data(), b.data(), r), KernelStatus::ok);
    EXPECT_EQ(r[0], 1);
    EXPECT_EQ(r[1], 2);
    EXPECT_EQ(r[2], 2);
    expect_column(b, 1, 0, {{3, 1.0f}});
    expect_column(b, 1, 1, {{5, 1.0f}});
    expect_column(b, 2, 0, {{0, 1.0f}});
    expect_column(b, 2, 1, {{1, 1.0f}});
  }
}

TEST(ScalarBases, TheQuickProofOfFullRankHoldsJustInsideItsBoundAndNotBeyond) {
  // 16 taxels, each one value at its own sample: the time unfolding has orthogonal rows, its
  // singular values the values. All 1 but taxel 0's d: ||R||_F^2 ||R^-1||_F^2 = (15 + d^2)
  // (15 + 1 / d^2), against the bound 1 / (4096 tau) = 6.7e7 in float. d = 4.8e-4 (6.5e7, 3 %
  // inside): the identity basis, without the sweeps. d = 2.5e-4 (2.4e8): the sweeps' singular
  // vectors, largest first (taxels 1 to 15 in order, then taxel 0). Either way rank 16.
  const BasisLayout layout({4, 4, 20}, {2, 2, 16});
  eskin::detail::ScalarBases<float> sb(layout);
  // And two more: 0.012 % inside (15 / d^2 + 15 d^2 + 226 = the bound times 1 - 1.2e-4), the
  // identity still; 1.5 times the bound, the sweeps. The same negated (R's diagonal then +1
  // and +d, not -1 and -d): the same bases.
  const double bound = 1.0 / (4096.0 * eskin::detail::rank_tolerance<float>());
  const double d_edge = std::sqrt(15.0 / (bound * (1.0 - 1.2e-4) - 226.0));
  const double d_over = std::sqrt(15.0 / (bound * 1.5 - 226.0));
  for (const double sign : {1.0, -1.0})
  for (const double d : {4.8e-4, d_edge, d_over, 2.5e-4}) {
    const bool inside = d >= d_edge;
    std::vector<double> x(layout.tensor_size(), 0.0);
    for (std::size_t k = 0; k < 16; ++k) x[k * 20 + k] = sign * (k == 0 ? d : 1.0);
    std::vector<float> b(layout.bases_size());
    int r[3];
    ASSERT_EQ(sb.compute(x.data(), b.data(), r), KernelStatus::ok);
    EXPECT_EQ(r[2], 16);
    for (std::size_t c = 0; c < 16; ++c) {
      const std::size_t at = inside ? c : (c + 1) % 16;
      for (std::size_t i = 0; i < 16; ++i)
        ASSERT_NEAR(b[layout.offset(2) + c * 16 + i], i == at ? 1.0f : 0.0f, 1e-6f)
            << "sign " << sign << " d " << d << " column " << c << " entry " << i;
    }
  }
}

TEST(ScalarBases, TheQuickProofOfFullRankReadsEveryEntryOfR) {
  // A time unfolding already upper triangular, R = 1 on the diagonal and -2 above it: a
  // moderate diagonal, but R^-1 grows as 2 * 3^(k - 1) k places off it, so the condition
  // number is about 1e8 and R is numerically of rank 15 (s_16^2 / s_1^2 below the tolerance).
  // The quick proof (||R||_F ||R^-1||_F) must see all of R^-1 and refuse; the sweeps find 15,
  // as the host does.
  const std::size_t D = 20;
  const BasisLayout layout({4, 4, D}, {2, 2, 16});
  std::vector<double> x(layout.tensor_size(), 0.0);
  for (std::size_t i = 0; i < 16; ++i)
    for (std::size_t t = 0; t <= i; ++t) x[i * D + t] = t == i ? 1.0 : -2.0;
  eskin::BasisWorkspace host(layout);
  std::vector<double> ref(layout.bases_size());
  int r_ref[3];
  ASSERT_EQ(host.compute(x.data(), ref.data(), r_ref), KernelStatus::ok);
  EXPECT_EQ(r_ref[2], 15);
  eskin::detail::ScalarBases<float> sb32(layout);
  eskin::detail::ScalarBases<double> sb64(layout);
  std::vector<float> b32(layout.bases_size());
  std::vector<double> b64(layout.bases_size());
  int r32[3], r64[3];
  ASSERT_EQ(sb32.compute(x.data(), b32.data(), r32), KernelStatus::ok);
  ASSERT_EQ(sb64.compute(x.data(), b64.data(), r64), KernelStatus::ok);
  EXPECT_EQ(r32[2], 15);
  EXPECT_EQ(r64[2], 15);
  const std::size_t off = layout.offset(2);
  EXPECT_LT(projection_gap(ref.data() + off, b64.data() + off, 16, 15), 1e-9);
}

namespace {

// A time unfolding R already upper triangular (D = 20): 1 on the diagonal and, in column k > 0,
// `value` at row above(k). Its time mode in float: rank 16, and bases that are the sweeps'
// singular vectors, mixing the taxels (not the identity the quick proof of full rank gives).
void expect_rank_16_from_the_sweeps(std::size_t (*above)(std::size_t), double value) {
  const std::size_t D = 20;
  const BasisLayout layout({4, 4, D}, {2, 2, 16});
  std::vector<double> x(layout.tensor_size(), 0.0);
  for (std::size_t k = 0; k < 16; ++k) {
    x[k * D + k] = 1.0;
    if (k > 0) x[k * D + above(k)] = value;
  }
  eskin::detail::ScalarBases<float> sb(layout);
  std::vector<float> b(layout.bases_size());
  int r[3];
  ASSERT_EQ(sb.compute(x.data(), b.data(), r), KernelStatus::ok);
  EXPECT_EQ(r[2], 16);
  const std::size_t off = layout.offset(2);
  float off_diagonal = 0.0f;
  for (std::size_t c = 0; c < 16; ++c)
    for (std::size_t j = 0; j < 16; ++j)
      if (c != j) off_diagonal = std::max(off_diagonal, std::fabs(b[off + c * 16 + j]));
  EXPECT_GT(off_diagonal, 0.1f);
}

}  // namespace

TEST(ScalarBases, TheQuickProofOfFullRankReadsTheFirstRowOfR) {
  // R = I but for a first row of 100s: R^-1 = I but for a first row of -100s, so all of
  // ||R^-1||_F beyond its diagonal is in row 0. ||R||_F^2 ||R^-1||_F^2 = (16 + 15e4)^2 = 2.3e10,
  // past the proof's bound (6.7e7 in float): the sweeps decide (rank 16, s_16^2 / s_1^2 about
  // 4e-11, above the tolerance), and their singular vectors mix the taxels: not the identity.
  expect_rank_16_from_the_sweeps([](std::size_t) -> std::size_t { return 0; }, -100.0);
}

TEST(ScalarBases, AZeroPatternHasRankZeroAndZeroBases) {
  const BasisLayout layout({4, 4, 20}, {2, 2, 8});
  eskin::detail::ScalarBases<float> sb(layout);
  const std::vector<double> x(layout.tensor_size(), 0.0);
  std::vector<float> b(layout.bases_size(), 7.0f);
  int r[3] = {9, 9, 9};
  ASSERT_EQ(sb.compute(x.data(), b.data(), r), KernelStatus::ok);
  for (std::size_t z = 0; z < 3; ++z) EXPECT_EQ(r[z], 0) << "mode " << z;
  for (std::size_t i = 0; i < b.size(); ++i) ASSERT_EQ(b[i], 0.0f) << "entry " << i;
}

TEST(ScalarBases, TheRankCountsSquaredSingularValuesAboveTheTolerance) {
  // two taxels, one value each at their own sample: 1 and d. In double the rank tolerance on
  // squared singular values is 1e-12 of the largest: d^2 = 5e-13 is below it (rank 1 in the
  // column and time modes), d^2 = 2e-12 above it (rank 2)
  const BasisLayout layout({4, 4, 20}, {2, 2, 8});
  eskin::detail::ScalarBases<double> sb(layout);
  for (const auto& [d2, rank] : {std::pair<double, int>{5e-13, 1}, {2e-12, 2}}) {
    std::vector<double> x(layout.tensor_size(), 0.0);
    x[0 * 20 + 3] = 1.0;
    x[1 * 20 + 5] = std::sqrt(d2);
    std::vector<double> b(layout.bases_size());
    int r[3];
    ASSERT_EQ(sb.compute(x.data(), b.data(), r), KernelStatus::ok);
    EXPECT_EQ(r[0], 1) << d2;
    EXPECT_EQ(r[1], rank) << d2;
    EXPECT_EQ(r[2], rank) << d2;
  }
}

// The rounding-noise threshold on a pair's product is eps^2 times the whole matrix's squared
// norm (the first entry's included): two columns of norm about eps whose product is 1.4 eps^2
// (beside a unit column) are rotated, at 0.7 eps^2 left as they are.
TEST(ScalarBases, OneSidedJacobiLeavesPairsBelowEpsSquaredTimesTheNormAlone) {
  const double eps = std::numeric_limits<double>::epsilon();
  for (const auto& [share, rotated] : {std::pair<double, bool>{1.4, true}, {0.7, false}}) {
    const double s = std::sqrt(share) * eps;
    const std::vector<double> b0 = {1, 0, 0, 0, s, 0, 0, s, s};  // columns e1, s e2, s (e2 + e3)
    std::vector<double> b = b0, w(9), norms(3);
    const int sweeps = eskin::detail::one_sided_jacobi<double>(3, b.data(), w.data(),
                                                               norms.data());
    EXPECT_EQ(sweeps > 1, rotated) << share;
    EXPECT_EQ(b != b0, rotated) << share;
  }
}

// Orthogonality is judged relative to the two columns' own norms: the same pair at scale 1 and
// at 2^-10 (exact in binary) takes the same sweeps and rotations, its product of 1e-13 of
// their norms is rotated at both scales.
TEST(ScalarBases, OneSidedJacobiIsTheSameAtAnyScale) {
  const std::vector<double> b1 = {1, 0, 1e-13, 1};
  std::vector<double> ref = b1, w1(4), n1(2);
  const int sweeps = eskin::detail::one_sided_jacobi<double>(2, ref.data(), w1.data(), n1.data());
  EXPECT_GT(sweeps, 1);
  const double scale = std::ldexp(1.0, -10);
  std::vector<double> b(4), w(4), norms(2);
  for (std::size_t i = 0; i < 4; ++i) b[i] = b1[i] * scale;
  EXPECT_EQ(eskin::detail::one_sided_jacobi<double>(2, b.data(), w.data(), norms.data()), sweeps);
  for (std::size_t i = 0; i < 4; ++i) {
    EXPECT_EQ(b[i], ref[i] * scale) << i;
    EXPECT_EQ(w[i], w1[i]) << i;
  }
}

// The rank tolerance on squared singular values is max(1e-12, (16 eps)^2): 1e-12 in double,
// (16 eps)^2 in float (the controller's), whose 16 eps is above 1e-6.
TEST(ScalarBases, TheRankToleranceIsSixteenEpsilonSquaredInFloatAndOneEMinus12InDouble) {
  const float e16 = 16.0f * std::numeric_limits<float>::epsilon();
  EXPECT_EQ(eskin::detail::rank_tolerance<float>(), e16 * e16);
  EXPECT_EQ(eskin::detail::rank_tolerance<double>(), 1e-12);
}

// A pattern's bases and ranks do not depend on its scale, even where its squares would
// underflow: x 2^-600 in double and x 2^-100 in float give the bases of x bit for bit (the
// pattern is divided by its largest magnitude first).
template <class Real>
void expect_scale_free(int exponent) {
  const BasisLayout layout({4, 4, 20}, {2, 2, 8});
  eskin::detail::ScalarBases<Real> sb(layout);
  const std::vector<double> x = random_tensor(layout.tensor_size(), 17);
  std::vector<Real> one(x.size()), small(x.size());
  for (std::size_t i = 0; i < x.size(); ++i) {
    one[i] = static_cast<Real>(x[i]);
    small[i] = std::ldexp(one[i], exponent);
  }
  std::vector<Real> b1(layout.bases_size()), b2(layout.bases_size());
  int r1[3], r2[3];
  ASSERT_EQ(sb.compute(one.data(), b1.data(), r1), KernelStatus::ok);
  ASSERT_EQ(sb.compute(small.data(), b2.data(), r2), KernelStatus::ok);
  for (int z = 0; z < 3; ++z) EXPECT_EQ(r1[z], r2[z]) << z;
  EXPECT_EQ(r1[2], 8);
  EXPECT_EQ(b1, b2);
}

TEST(ScalarBases, APatternsBasesDoNotDependOnItsScaleEvenWhereItsSquaresUnderflow) {
  expect_scale_free<double>(-600);
  expect_scale_free<float>(-100);
}

// One taxel dominates: value 1 at its sample, the fifteen others e = 1e-6 at theirs. R is
// diagonal (1, e, ..., e) with its large entry first: ||R||_F^2 ||R^-1||_F^2 = (1 + 15 e^2)
// (1 + 15 / e^2), far past the quick proof's bound, and the sweeps find the numerical rank
// (e^2 is below the tolerance): 1, the dominant taxel.
TEST(ScalarBases, TheQuickProofOfFullRankCountsTheFirstDiagonalEntryOfR) {
  const BasisLayout layout({4, 4, 20}, {2, 2, 16});
  eskin::detail::ScalarBases<float> sb(layout);
  std::vector<double> x(layout.tensor_size(), 0.0);
  for (std::size_t k = 0; k < 16; ++k) x[k * 20 + k] = k == 0 ? 1.0 : 1e-6;
  std::vector<float> b(layout.bases_size());
  int r[3];
  ASSERT_EQ(sb.compute(x.data(), b.data(), r), KernelStatus::ok);
  EXPECT_EQ(r[2], 1);
  for (std::size_t i = 0; i < 16; ++i)
    EXPECT_EQ(b[layout.offset(2) + i], i == 0 ? 1.0f : 0.0f) << i;
}

// The same proof on long windows (D = 2000), 0.001 % inside its bound: each taxel a block of 125
// samples of its value (1, or d for taxel 0), so R = sqrt(125) diag(d, 1, ..., 1): the product
// is the same as for one sample each, but ||R^-1||_F^2 is 125 times smaller, and counting it
// one too large (2.8e-5 of the bound) would move the pattern outside (the sweeps' order).
TEST(ScalarBases, TheQuickProofOfFullRankHoldsJustInsideItsBoundOnLongWindows) {
  const std::size_t D = 2000, w = 125;
  const BasisLayout layout({4, 4, D}, {2, 2, 16});
  eskin::detail::ScalarBases<float> sb(layout);
  const double bound = 1.0 / (4096.0 * eskin::detail::rank_tolerance<float>());
  const double d = std::sqrt(15.0 / (bound * (1.0 - 1e-5) - 226.0));
  std::vector<double> x(layout.tensor_size(), 0.0);
  for (std::size_t k = 0; k < 16; ++k)
    for (std::size_t t = k * w; t < (k + 1) * w; ++t) x[k * D + t] = k == 0 ? d : 1.0;
  std::vector<float> b(layout.bases_size());
  int r[3];
  ASSERT_EQ(sb.compute(x.data(), b.data(), r), KernelStatus::ok);
  EXPECT_EQ(r[2], 16);
  for (std::size_t c = 0; c < 16; ++c)
    for (std::size_t i = 0; i < 16; ++i)
      ASSERT_EQ(b[layout.offset(2) + c * 16 + i], i == c ? 1.0f : 0.0f) << c << " " << i;
}

// R^-1 is formed from every entry of R next to the diagonal: R = I with -2 just above the
// diagonal (a time unfolding already upper bidiagonal) has R^-1 = 2^(j - i) above it, so
// ||R||_F ||R^-1||_F is about 1e9, past the proof's bound; the sweeps decide (rank 16: s_16^2 /
// s_1^2 about 1e-10 is above the tolerance) and their singular vectors mix the taxels. Had the
// proof missed the entries next to the diagonal, R^-1 would have looked like I: the identity.
TEST(ScalarBases, TheQuickProofOfFullRankReadsTheEntriesNextToTheDiagonalOfR) {
  expect_rank_16_from_the_sweeps([](std::size_t k) { return k - 1; }, -2.0);
}
