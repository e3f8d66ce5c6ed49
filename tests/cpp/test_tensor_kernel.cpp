// Tests of the tensor-kernel core: unfolding, bases, distances against a literal implementation
// (Eigen JacobiSVD + explicit projection matrices), the batch layer, and the heap-free layer.
#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <atomic>
#include <cmath>
#include <cstdlib>
#include <numeric>
#include <random>
#include <stdexcept>
#include <string>
#include <vector>

#include "eskin/tensor_kernel.hpp"

// ---- allocation counter: count malloc calls made while `g_count_mallocs` is set (glibc only;
// not under sanitizers, which intercept malloc themselves).
#if defined(__has_feature)
#if __has_feature(address_sanitizer) || __has_feature(memory_sanitizer)
#define ESKIN_NO_MALLOC_HOOK 1
#endif
#endif
#if defined(__GLIBC__) && !defined(__SANITIZE_ADDRESS__) && !defined(ESKIN_NO_MALLOC_HOOK)
#define ESKIN_COUNT_MALLOC 1
extern "C" void* __libc_malloc(std::size_t);
extern "C" void* __libc_calloc(std::size_t, std::size_t);
extern "C" void* __libc_realloc(void*, std::size_t);
static std::atomic<bool> g_count_mallocs{false};
static std::atomic<long> g_mallocs{0};
extern "C" void* malloc(std::size_t n) {
  if (g_count_mallocs.load(std::memory_order_relaxed)) g_mallocs.fetch_add(1);
  return __libc_malloc(n);
}
extern "C" void* calloc(std::size_t a, std::size_t b) {
  if (g_count_mallocs.load(std::memory_order_relaxed)) g_mallocs.fetch_add(1);
  return __libc_calloc(a, b);
}
extern "C" void* realloc(void* p, std::size_t n) {
  if (g_count_mallocs.load(std::memory_order_relaxed)) g_mallocs.fetch_add(1);
  return __libc_realloc(p, n);
}
#endif

namespace {

using eskin::BasisLayout;
using eskin::BasisWorkspace;
using eskin::KernelStatus;
using Matrix = Eigen::MatrixXd;

std::vector<double> random_tensors(std::size_t n, const std::vector<std::size_t>& dims,
                                   unsigned seed) {
  std::size_t size = n;
  for (auto d : dims) size *= d;
  std::mt19937_64 gen(seed);
  std::normal_distribution<double> nd;
  std::vector<double> x(size);
  for (auto& v : x) v = nd(gen);
  return x;
}

// Literal: unfolding by index arithmetic (independent of eskin::unfold), full SVD, projection.
Matrix literal_unfold(const double* x, const std::vector<std::size_t>& dims, std::size_t z) {
  std::size_t size = 1;
  for (auto d : dims) size *= d;
  Matrix a(dims[z], size / dims[z]);
  std::vector<std::size_t> idx(dims.size(), 0);
  for (std::size_t lin = 0; lin < size; ++lin) {
    std::size_t rem = lin;
    for (std::size_t k = dims.size(); k-- > 0;) {
      idx[k] = rem % dims[k];
      rem /= dims[k];
    }
    std::size_t col = 0;
    for (std::size_t k = 0; k < dims.size(); ++k)
      if (k != z) col = col * dims[k] + idx[k];
    a(Eigen::Index(idx[z]), Eigen::Index(col)) = x[lin];
  }
  return a;
}

Matrix literal_projection(const double* x, const std::vector<std::size_t>& dims, std::size_t z,
                          std::size_t alpha) {
  const Matrix a = literal_unfold(x, dims, z);
  Eigen::JacobiSVD<Matrix> svd(a, Eigen::ComputeFullV);
  const Matrix v = svd.matrixV().leftCols(Eigen::Index(alpha));
  return v * v.transpose();
}

struct Case {
  std::vector<std::size_t> dims, alphas;
};

class LiteralTest : public ::testing::TestWithParam<Case> {};

TEST_P(LiteralTest, BatchDistancesEqualProjectionFormula) {
  const Case c = GetParam();
  const BasisLayout layout(c.dims, c.alphas);
  const std::size_t n = 6, m = 5;
  const auto x = random_tensors(n, c.dims, 1);
  const auto y = random_tensors(m, c.dims, 2);
  const auto bx = eskin::compute_pattern_bases(x.data(), n, layout, 2);
  const auto by = eskin::compute_pattern_bases(y.data(), m, layout, 2);
  const std::size_t nz = c.dims.size();
  std::vector<double> dxy(nz * n * m), dxx(nz * n * n);
  eskin::mode_distances(bx, &by, dxy.data(), 2);
  eskin::mode_distances(bx, nullptr, dxx.data(), 2);
  const std::size_t ts = layout.tensor_size();
  for (std::size_t z = 0; z < nz; ++z)
    for (std::size_t i = 0; i < n; ++i) {
      const Matrix pi = literal_projection(x.data() + i * ts, c.dims, z, c.alphas[z]);
      for (std::size_t j = 0; j < m; ++j) {
        const Matrix pj = literal_projection(y.data() + j * ts, c.dims, z, c.alphas[z]);
        EXPECT_NEAR(dxy[(z * n + i) * m + j], (pi - pj).squaredNorm(), 1e-10);
      }
      for (std::size_t j = 0; j < n; ++j) {
        const Matrix pj = literal_projection(x.data() + j * ts, c.dims, z, c.alphas[z]);
        EXPECT_NEAR(dxx[(z * n + i) * n + j], (pi - pj).squaredNorm(), 1e-10);
        EXPECT_EQ(dxx[(z * n + i) * n + j], dxx[(z * n + j) * n + i]);
      }
      EXPECT_EQ(dxx[(z * n + i) * n + i], 0.0);
    }
}

INSTANTIATE_TEST_SUITE_P(Shapes, LiteralTest,
                         ::testing::Values(Case{{4, 4, 20}, {2, 2, 8}}, Case{{4, 4, 20}, {4, 4, 16}},
                                           Case{{3, 5, 7}, {1, 2, 3}}, Case{{6, 9}, {3, 2}},
                                           Case{{2, 3, 4, 5}, {2, 3, 4, 5}},
                                           Case{{4, 4, 10}, {3, 3, 9}}),
                         [](const ::testing::TestParamInfo<Case>& info) {
                           std::string s = "d";
                           for (std::size_t i = 0; i < info.param.dims.size(); ++i)
                             s += (i ? "x" : "") + std::to_string(info.param.dims[i]);
                           s += "_a";
                           for (std::size_t i = 0; i < info.param.alphas.size(); ++i)
                             s += (i ? "x" : "") + std::to_string(info.param.alphas[i]);
                           return s;
                         });

TEST(Unfold, ColumnsAreCOrderOfRemainingIndices) {
  const std::vector<std::size_t> dims{2, 3, 4};
  std::vector<double> x(24);
  std::iota(x.begin(), x.end(), 0.0);
  for (std::size_t z = 0; z < 3; ++z) {
    std::vector<double> out(24);
    eskin::unfold(x.data(), dims, z, out.data());
    const Matrix lit = literal_unfold(x.data(), dims, z);
    for (Eigen::Index i = 0; i < lit.rows(); ++i)
      for (Eigen::Index j = 0; j < lit.cols(); ++j)
        EXPECT_EQ(out[std::size_t(i * lit.cols() + j)], lit(i, j));
  }
  // mode 1 of a 2x3x4 tensor: row i2, column i1 * 4 + i3
  std::vector<double> out(24);
  eskin::unfold(x.data(), dims, 1, out.data());
  EXPECT_EQ(out[2 * 8 + 1 * 4 + 3], x[(1 * 3 + 2) * 4 + 3]);
}

TEST(Layout, AlphasAndErrors) {
  EXPECT_EQ(eskin::full_alphas({4, 4, 100}), (std::vector<std::size_t>{4, 4, 16}));
  EXPECT_EQ(eskin::half_alphas({4, 4, 100}), (std::vector<std::size_t>{2, 2, 8}));
  const BasisLayout l({4, 4, 100}, {2, 2, 8});
  EXPECT_EQ(l.cols(0), 400u);
  EXPECT_EQ(l.cols(2), 16u);
  EXPECT_EQ(l.offset(1), 800u);
  EXPECT_EQ(l.bases_size(), 800u + 800u + 128u);
  EXPECT_THROW(BasisLayout({4, 4, 100}, {2, 2, 17}), std::invalid_argument);
  EXPECT_THROW(BasisLayout({4, 4, 100}, {0, 2, 8}), std::invalid_argument);
  EXPECT_THROW(BasisLayout({4, 4, 100}, {2, 2}), std::invalid_argument);
  EXPECT_THROW(BasisLayout({100}, {1}), std::invalid_argument);
  EXPECT_THROW(BasisLayout({4, 0, 3}, {1, 1, 1}), std::invalid_argument);
  try {
    BasisLayout({4, 4, 100}, {2, 2, 17});
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("alpha 17 for mode 2"), std::string::npos) << e.what();
  }
}

TEST(Workspace, OrthonormalSignNormalisedBasesAndSingularValues) {
  const std::vector<std::size_t> dims{4, 4, 20};
  const BasisLayout layout(dims, {3, 2, 8});
  BasisWorkspace ws(layout);
  const auto x = random_tensors(1, dims, 3);
  std::vector<double> bases(layout.bases_size());
  std::vector<int> ranks(3);
  ASSERT_EQ(ws.compute(x.data(), bases.data(), ranks.data()), KernelStatus::ok);
  for (std::size_t z = 0; z < 3; ++z) {
    EXPECT_EQ(ranks[z], int(layout.alpha(z)));
    const Eigen::Map<const Matrix> v(bases.data() + layout.offset(z), Eigen::Index(layout.cols(z)),
                                     Eigen::Index(layout.alpha(z)));
    EXPECT_LT((v.transpose() * v - Matrix::Identity(v.cols(), v.cols())).norm(), 1e-12);
    for (Eigen::Index c = 0; c < v.cols(); ++c) {
      Eigen::Index top = 0;
      v.col(c).cwiseAbs().maxCoeff(&top);
      EXPECT_GT(v(top, c), 0.0);
    }
    const Eigen::JacobiSVD<Matrix> svd(literal_unfold(x.data(), dims, z));
    for (std::size_t i = 0; i < layout.q(z); ++i)
      EXPECT_NEAR(ws.singular_values(z)[i], svd.singularValues()(Eigen::Index(i)), 1e-10);
  }
}

TEST(Workspace, DegeneratePatterns) {
  const std::vector<std::size_t> dims{4, 4, 20};
  const BasisLayout layout(dims, {2, 4, 8});
  BasisWorkspace ws(layout);
  std::vector<double> bases(layout.bases_size(), 7.0);
  std::vector<int> ranks(3, 9);
  // all zero: rank 0, zero bases
  std::vector<double> zero(layout.tensor_size(), 0.0);
  ASSERT_EQ(ws.compute(zero.data(), bases.data(), ranks.data()), KernelStatus::ok);
  for (int r : ranks) EXPECT_EQ(r, 0);
  for (double b : bases) EXPECT_EQ(b, 0.0);
  // rank-one tensor: rank 1 in every mode, columns beyond are zero
  std::vector<double> r1(layout.tensor_size());
  for (std::size_t i = 0; i < 4; ++i)
    for (std::size_t j = 0; j < 4; ++j)
      for (std::size_t k = 0; k < 20; ++k)
        r1[(i * 4 + j) * 20 + k] = (1.0 + double(i)) * (2.0 - double(j)) * std::sin(0.3 * double(k) + 1.0);
  ASSERT_EQ(ws.compute(r1.data(), bases.data(), ranks.data()), KernelStatus::ok);
  for (int r : ranks) EXPECT_EQ(r, 1);
  for (std::size_t z = 0; z < 3; ++z)
    for (std::size_t k = layout.cols(z); k < layout.cols(z) * layout.alpha(z); ++k)
      EXPECT_EQ(bases[layout.offset(z) + k], 0.0);
  // distance of the rank-1 pattern to itself and to a huge/tiny scaled copy: 0
  std::vector<double> b2(layout.bases_size());
  std::vector<int> r2(3);
  for (double s : {1e-200, 1e200, -3.0}) {
    std::vector<double> scaled(r1);
    for (auto& v : scaled) v *= s;
    ASSERT_EQ(ws.compute(scaled.data(), b2.data(), r2.data()), KernelStatus::ok);
    for (std::size_t z = 0; z < 3; ++z)
      EXPECT_NEAR(eskin::mode_distance(bases.data() + layout.offset(z), ranks[z],
                                       b2.data() + layout.offset(z), r2[z], layout.cols(z),
                                       layout.alpha(z)),
                  0.0, 1e-12);
  }
  // non-finite input: status, zeroed outputs
  std::vector<double> bad(layout.tensor_size(), 1.0);
  bad[17] = std::nan("");
  EXPECT_EQ(ws.compute(bad.data(), bases.data(), ranks.data()), KernelStatus::not_finite);
  for (int r : ranks) EXPECT_EQ(r, 0);
  bad[17] = INFINITY;
  EXPECT_EQ(ws.compute(bad.data(), bases.data(), ranks.data()), KernelStatus::not_finite);
  EXPECT_EQ(ws.compute(nullptr, bases.data(), ranks.data()), KernelStatus::bad_argument);
  EXPECT_STREQ(eskin::to_string(KernelStatus::not_finite), "not_finite");
}

TEST(Workspace, BatchEqualsOnePatternAtATimeWhateverItsBatchMates) {
  const std::vector<std::size_t> dims{4, 4, 24};
  const BasisLayout layout(dims, {2, 3, 8});
  const std::size_t size = layout.tensor_size(), bs = layout.bases_size();
  auto x = random_tensors(BasisWorkspace::kMaxBatch, dims, 21);
  // batch mates of every kind: all zero, NaN, infinite, rank one, huge
  std::fill(x.begin() + 1 * size, x.begin() + 2 * size, 0.0);
  x[2 * size + 5] = std::nan("");
  x[3 * size + 11] = -INFINITY;
  for (std::size_t i = 0; i < 4; ++i)
    for (std::size_t j = 0; j < 4; ++j)
      for (std::size_t k = 0; k < 24; ++k)
        x[4 * size + (i * 4 + j) * 24 + k] = double(i + 1) * double(j) * std::cos(0.2 * double(k));
  for (std::size_t i = 0; i < size; ++i) x[6 * size + i] *= 1e250;
  BasisWorkspace ws(layout);
  for (std::size_t count : {std::size_t(1), std::size_t(5), BasisWorkspace::kMaxBatch}) {
    SCOPED_TRACE(count);
    std::vector<double> bases(count * bs, 9.0);
    std::vector<int> ranks(count * 3, 9);
    std::vector<KernelStatus> status(count, KernelStatus::bad_argument);
    ASSERT_EQ(ws.compute_batch(x.data(), count, bases.data(), ranks.data(), status.data()),
              KernelStatus::ok);
    for (std::size_t b = 0; b < count; ++b) {
      std::vector<double> one(bs, 7.0);
      std::vector<int> r(3, 7);
      const KernelStatus st = ws.compute(x.data() + b * size, one.data(), r.data());
      EXPECT_EQ(status[b], st) << "pattern " << b;
      EXPECT_EQ(std::vector<double>(bases.begin() + b * bs, bases.begin() + (b + 1) * bs), one)
          << "pattern " << b;
      EXPECT_EQ(std::vector<int>(ranks.begin() + b * 3, ranks.begin() + (b + 1) * 3), r);
    }
    if (count > 4) {
      EXPECT_EQ(status[1], KernelStatus::ok);  // all zero: rank 0
      EXPECT_EQ(ranks[3], 0);
      EXPECT_EQ(status[2], KernelStatus::not_finite);
      EXPECT_EQ(status[3], KernelStatus::not_finite);
      EXPECT_EQ(ranks[4 * 3 + 0], 1);  // rank one in every mode
      EXPECT_EQ(ranks[4 * 3 + 2], 1);
    }
  }
  std::vector<double> bases(9 * bs);
  std::vector<int> ranks(9 * 3);
  std::vector<KernelStatus> status(9);
  EXPECT_EQ(ws.compute_batch(x.data(), 9, bases.data(), ranks.data(), status.data()),
            KernelStatus::bad_argument);
  EXPECT_EQ(ws.compute_batch(x.data(), 2, bases.data(), ranks.data(), nullptr),
            KernelStatus::bad_argument);
}

// A workspace for one pattern at a time (a classifier's): the same bases as the batch one, and
// a batch above its size is refused untouched.
TEST(Workspace, OnePatternWorkspaceGivesTheSameBasesAndRefusesBatches) {
  const std::vector<std::size_t> dims{4, 4, 24};
  const BasisLayout layout(dims, {2, 3, 8});
  const std::size_t bs = layout.bases_size();
  const auto x = random_tensors(2, dims, 5);
  BasisWorkspace one(layout, 1), eight(layout);
  std::vector<double> b1(bs), b8(bs);
  int r1[3], r8[3];
  ASSERT_EQ(one.compute(x.data(), b1.data(), r1), KernelStatus::ok);
  ASSERT_EQ(eight.compute(x.data(), b8.data(), r8), KernelStatus::ok);
  EXPECT_EQ(b1, b8);
  EXPECT_EQ(std::vector<int>(r1, r1 + 3), std::vector<int>(r8, r8 + 3));
  std::vector<double> bases(2 * bs, -7.0);
  std::vector<int> ranks(2 * 3);
  std::vector<KernelStatus> status(2);
  EXPECT_EQ(one.compute_batch(x.data(), 2, bases.data(), ranks.data(), status.data()),
            KernelStatus::bad_argument);
  EXPECT_EQ(bases[0], -7.0);
  EXPECT_THROW(BasisWorkspace(layout, 0), std::invalid_argument);
  EXPECT_THROW(BasisWorkspace(layout, 9), std::invalid_argument);
}

TEST(HeapFree, ComputeAndDistancesDoNotAllocate) {
#ifndef ESKIN_COUNT_MALLOC
  GTEST_SKIP() << "malloc counting not available in this build";
#else
  const std::vector<std::size_t> dims{4, 4, 100};
  const BasisLayout layout(dims, {2, 2, 8});
  BasisWorkspace ws(layout);
  const auto x = random_tensors(2, dims, 4);
  std::vector<double> ba(layout.bases_size()), bb(layout.bases_size());
  std::vector<float> bf(layout.bases_size());
  std::vector<int> ra(3), rb(3), rf(3);
  const double sigmas[3] = {1.0, 1.0, 0.5};
  std::vector<double> bbatch(2 * layout.bases_size());
  std::vector<int> rbatch(6);
  KernelStatus sb[2];
  g_mallocs = 0;
  g_count_mallocs = true;
  const KernelStatus s1 = ws.compute(x.data(), ba.data(), ra.data());
  const KernelStatus s2 = ws.compute(x.data() + layout.tensor_size(), bb.data(), rb.data());
  const KernelStatus s3 = ws.compute(x.data() + layout.tensor_size(), bf.data(), rf.data());
  const KernelStatus s4 = ws.compute_batch(x.data(), 2, bbatch.data(), rbatch.data(), sb);
  const double k1 = eskin::kernel_value(layout, ba.data(), ra.data(), bb.data(), rb.data(), sigmas);
  const double k2 = eskin::kernel_value(layout, ba.data(), ra.data(), bf.data(), rf.data(), sigmas);
  g_count_mallocs = false;
  EXPECT_EQ(g_mallocs.load(), 0);
  EXPECT_EQ(s1, KernelStatus::ok);
  EXPECT_EQ(s2, KernelStatus::ok);
  EXPECT_EQ(s3, KernelStatus::ok);
  EXPECT_EQ(s4, KernelStatus::ok);
  EXPECT_EQ(sb[1], KernelStatus::ok);
  EXPECT_NEAR(k1, k2, 1e-6);
  EXPECT_GT(k1, 0.0);
  // the counter works: a vector allocation is seen
  g_count_mallocs = true;
  { std::vector<double> v(1000); }
  g_count_mallocs = false;
  EXPECT_GT(g_mallocs.load(), 0);
#endif
}

TEST(RawPointer, DistancesMatchBatchAndFloatVariant) {
  const std::vector<std::size_t> dims{4, 4, 30};
  const BasisLayout layout(dims, {2, 2, 8});
  const std::size_t n = 9;
  const auto x = random_tensors(n, dims, 5);
  const auto pb = eskin::compute_pattern_bases(x.data(), n, layout, 1);
  std::vector<double> d(3 * n * n), k(n * n);
  eskin::mode_distances(pb, nullptr, d.data(), 1);
  const std::vector<double> sig{0.8, 1.2, 0.5};
  eskin::tensor_kernel(pb, nullptr, sig, k.data(), 2);
  std::vector<float> fb(pb.bases.begin(), pb.bases.end());
  const std::size_t bs = layout.bases_size();
  for (std::size_t i = 0; i < n; ++i)
    for (std::size_t j = 0; j < n; ++j) {
      double e = 0.0;
      for (std::size_t z = 0; z < 3; ++z) {
        const std::size_t off = layout.offset(z);
        const double dd = eskin::mode_distance(pb.bases.data() + i * bs + off, pb.ranks[i * 3 + z],
                                               pb.bases.data() + j * bs + off, pb.ranks[j * 3 + z],
                                               layout.cols(z), layout.alpha(z));
        const double df = eskin::mode_distance(pb.bases.data() + i * bs + off, pb.ranks[i * 3 + z],
                                               fb.data() + j * bs + off, pb.ranks[j * 3 + z],
                                               layout.cols(z), layout.alpha(z));
        const double ff = eskin::mode_distance(fb.data() + i * bs + off, pb.ranks[i * 3 + z],
                                               fb.data() + j * bs + off, pb.ranks[j * 3 + z],
                                               layout.cols(z), layout.alpha(z));
        EXPECT_NEAR(dd, d[(z * n + i) * n + j], 1e-12);
        EXPECT_NEAR(df, dd, 1e-5);
        EXPECT_NEAR(ff, dd, 1e-5);
        e += dd / (2 * sig[z] * sig[z]);
      }
      EXPECT_NEAR(k[i * n + j], std::exp(-e), 1e-12);
      EXPECT_NEAR(eskin::kernel_value(layout, pb.bases.data() + i * bs, &pb.ranks[i * 3],
                                      pb.bases.data() + j * bs, &pb.ranks[j * 3], sig.data()),
                  k[i * n + j], 1e-12);
    }
}

TEST(Batch, ThreadCountAndMicroKernelDoNotChangeResults) {
  const std::vector<std::size_t> dims{4, 4, 40};
  const BasisLayout layout(dims, {3, 2, 5});
  const std::size_t n = 29;
  const auto x = random_tensors(n, dims, 6);
  const auto p1 = eskin::compute_pattern_bases(x.data(), n, layout, 1);
  const auto p3 = eskin::compute_pattern_bases(x.data(), n, layout, 3);
  EXPECT_EQ(p1.bases, p3.bases);
  EXPECT_EQ(p1.ranks, p3.ranks);
  std::vector<double> d1(3 * n * n), d3(3 * n * n), dg(3 * n * n);
  eskin::mode_distances(p1, nullptr, d1.data(), 1);
  eskin::mode_distances(p1, nullptr, d3.data(), 3);
  EXPECT_EQ(d1, d3);
  // every micro-kernel variant this CPU has agrees with the portable one
  ::setenv("ESKIN_KERNEL_ISA", "generic", 1);
  EXPECT_STREQ(eskin::tensor_kernel_isa(), "generic");
  eskin::mode_distances(p1, nullptr, dg.data(), 2);
  for (const char* isa : {"avx2", "avx512"}) {
    ::setenv("ESKIN_KERNEL_ISA", isa, 1);
    std::vector<double> dv(3 * n * n);
    eskin::mode_distances(p1, nullptr, dv.data(), 2);
    for (std::size_t i = 0; i < dv.size(); ++i)
      EXPECT_NEAR(dv[i], dg[i], 1e-12) << eskin::tensor_kernel_isa();
  }
  ::unsetenv("ESKIN_KERNEL_ISA");
  for (std::size_t i = 0; i < d1.size(); ++i) EXPECT_NEAR(d1[i], dg[i], 1e-12);
}

TEST(Batch, BlockedDistancesAreTheUnblockedOnesWithinTheirPlan) {
  const std::vector<std::size_t> dims{4, 4, 40};
  const BasisLayout layout(dims, {3, 2, 16});  // mode 3 by packed projections
  const std::size_t n = 29, m = 19;
  const auto x = random_tensors(n, dims, 7);
  const auto y = random_tensors(m, dims, 8);
  const auto pa = eskin::compute_pattern_bases(x.data(), n, layout, 2);
  const auto pb = eskin::compute_pattern_bases(y.data(), m, layout, 2);
  const auto one = eskin::plan_distances(layout, n, n, true, 0);
  EXPECT_EQ(one.row_blocks, 1u);
  for (const bool self : {true, false}) {
    const std::size_t mm = self ? n : m;
    const eskin::PatternBases* b = self ? nullptr : &pb;
    std::vector<double> whole(3 * n * mm), blocked(3 * n * mm);
    eskin::mode_distances(pa, b, whole.data(), 2);
    const std::size_t limit = 2 * 8 * one.pattern_bytes + 100;  // two blocks of 8 patterns
    const auto plan = eskin::plan_distances(layout, n, mm, self, limit);
    EXPECT_EQ(plan.block, 8u);
    EXPECT_EQ(plan.row_blocks, 4u);
    EXPECT_LE(plan.pack_bytes, limit);
    eskin::mode_distances(pa, b, blocked.data(), 2, limit);
    EXPECT_EQ(whole, blocked);
  }
  EXPECT_THROW(eskin::plan_distances(layout, n, n, true, 16 * one.pattern_bytes - 1),
               std::invalid_argument);
}

TEST(Batch, Errors) {
  const BasisLayout layout({4, 4, 10}, {2, 2, 8});
  std::vector<double> x(3 * layout.tensor_size(), 1.0);
  x[layout.tensor_size() + 5] = std::nan("");
  try {
    eskin::compute_pattern_bases(x.data(), 3, layout, 1);
    FAIL() << "no exception";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("pattern 1"), std::string::npos) << e.what();
  }
  x[layout.tensor_size() + 5] = 1.0;
  const auto pb = eskin::compute_pattern_bases(x.data(), 3, layout, 1);
  const auto other = eskin::compute_pattern_bases(
      x.data(), 3, BasisLayout({4, 4, 10}, {1, 2, 8}), 1);
  std::vector<double> out(27);
  EXPECT_THROW(eskin::mode_distances(pb, &other, out.data(), 1), std::invalid_argument);
  EXPECT_THROW(eskin::tensor_kernel(pb, nullptr, {1.0, 0.0, 1.0}, out.data(), 1),
               std::invalid_argument);
  EXPECT_THROW(eskin::tensor_kernel(pb, nullptr, {1.0, 2.0}, out.data(), 1), std::invalid_argument);
}

}  // namespace
