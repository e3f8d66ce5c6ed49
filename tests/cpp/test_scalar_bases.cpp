// ScalarBases (cpp/src/scalar_bases.hpp): the per-pattern bases of the device build, in a chosen
// scalar type, against the host's BasisWorkspace. The subspaces must agree (projection matrices
// V V^T: columns are defined up to sign and, inside a degenerate eigenspace, up to rotation), the
// ranks must be equal, the conventions (orthonormal columns, zero columns beyond the rank, the
// largest entry of each column positive) must hold, and compute() must not allocate.
#include <gtest/gtest.h>

#include <atomic>
#include <cmath>
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
};

class ScalarBasesTest : public ::testing::TestWithParam<Case> {};

TEST_P(ScalarBasesTest, SubspacesAndRanksMatchTheHostWorkspace) {
  const Case c = GetParam();
  const BasisLayout layout({4, 4, c.D}, c.alphas);
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
      // float32: the subspace agrees to the precision its Gram matrix resolves
      EXPECT_LT(projection_gap(ref.data() + off, b32.data() + off, n, a), 2e-3) << "mode " << z;
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
                                           Case{50, {4, 4, 16}}, Case{100, {2, 2, 8}}));

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

TEST(ScalarBases, JacobiEigenpairsOfAKnownMatrix) {
  // diag(3, 1, 2) rotated: eigenvalues 3, 2, 1 whatever the rotation
  const double c = std::cos(0.4), s = std::sin(0.4);
  const double R[9] = {c, -s, 0, s, c, 0, 0, 0, 1};
  const double L[3] = {3, 1, 2};
  double a[9] = {}, v[9];
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j)
      for (int k = 0; k < 3; ++k) a[i * 3 + j] += R[i * 3 + k] * L[k] * R[j * 3 + k];
  const double a0[9] = {a[0], a[1], a[2], a[3], a[4], a[5], a[6], a[7], a[8]};
  ASSERT_TRUE(eskin::detail::jacobi_eigen<double>(3, a, v));
  for (int j = 0; j < 3; ++j) {
    // A0 v_j = lambda_j v_j
    for (int i = 0; i < 3; ++i) {
      double av = 0;
      for (int k = 0; k < 3; ++k) av += a0[i * 3 + k] * v[j * 3 + k];
      EXPECT_NEAR(av, a[j * 3 + j] * v[j * 3 + i], 1e-12);
    }
  }
  std::vector<double> ev = {a[0], a[4], a[8]};
  std::sort(ev.begin(), ev.end());
  EXPECT_NEAR(ev[0], 1.0, 1e-12);
  EXPECT_NEAR(ev[1], 2.0, 1e-12);
  EXPECT_NEAR(ev[2], 3.0, 1e-12);
}

}  // namespace
