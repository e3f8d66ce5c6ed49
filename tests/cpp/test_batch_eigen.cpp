// The lane-parallel symmetric eigen-solver behind the tensor kernel's bases (a private module,
// tested through its header in cpp/src).
#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <cmath>
#include <cstring>
#include <random>
#include <tuple>
#include <vector>

#include "../../cpp/src/batch_eigen.hpp"

namespace {

using eskin::kEigenLanes;
using Matrix = Eigen::MatrixXd;
constexpr std::size_t L = kEigenLanes;

Matrix random_symmetric(std::size_t n, std::mt19937_64& gen) {
  std::normal_distribution<double> nd;
  Matrix a(n, n);
  for (std::size_t i = 0; i < n; ++i)
    for (std::size_t j = 0; j < n; ++j) a(i, j) = nd(gen);
  return a + a.transpose();
}

// kEigenLanes random symmetric n x n matrices
std::vector<Matrix> random_batch(std::size_t n, unsigned seed) {
  std::mt19937_64 gen(seed);
  std::vector<Matrix> mats;
  for (std::size_t l = 0; l < L; ++l) mats.push_back(random_symmetric(n, gen));
  return mats;
}

struct Solved {
  std::vector<double> a, d, e;
  unsigned failed = 0;
};

// The first `count` matrices in their lanes (the other lanes: zero matrices), outputs zeroed.
Solved lanes_of(const std::vector<Matrix>& mats, std::size_t n, std::size_t count) {
  Solved s;
  s.a.assign(n * n * L, 0.0);
  s.d.assign(n * L, 0.0);
  s.e.assign(3 * n * L, 0.0);
  for (std::size_t l = 0; l < count; ++l)
    for (std::size_t r = 0; r < n; ++r)
      for (std::size_t c = 0; c < n; ++c) s.a[(r * n + c) * L + l] = mats[l](r, c);
  return s;
}

// Solve the matrices given per lane (missing lanes: zero matrices) with the instruction set
// `level` (2 AVX-512, 1 AVX2, 0 baseline; capped by the CPU; -1 best).
Solved solve(const std::vector<Matrix>& mats, std::size_t n, int level = -1) {
  Solved s = lanes_of(mats, n, mats.size());
  s.failed = eskin::batch_symmetric_eigen(n, s.a.data(), s.d.data(), s.e.data(), level);
  return s;
}

// lane l's eigenvectors as the columns of a matrix, and its eigenvalues
Matrix vectors(const Solved& s, std::size_t n, std::size_t l) {
  Matrix v(n, n);
  for (std::size_t j = 0; j < n; ++j)
    for (std::size_t k = 0; k < n; ++k) v(k, j) = s.a[(j * n + k) * L + l];
  return v;
}
Eigen::VectorXd values(const Solved& s, std::size_t n, std::size_t l) {
  Eigen::VectorXd d(n);
  for (std::size_t j = 0; j < n; ++j) d(j) = s.d[j * L + l];
  return d;
}

void expect_decomposition(const Matrix& a, const Solved& s, std::size_t n, std::size_t l) {
  const Matrix v = vectors(s, n, l);
  const Eigen::VectorXd d = values(s, n, l);
  const double scale = std::max(1.0, a.norm());
  EXPECT_LT((v.transpose() * v - Matrix::Identity(n, n)).norm(), 1e-13 * n);
  EXPECT_LT((a * v - v * d.asDiagonal()).norm(), 1e-13 * n * scale);
  // the same spectrum as Eigen's solver
  Eigen::VectorXd sorted = d;
  std::sort(sorted.data(), sorted.data() + n);
  const Eigen::VectorXd ref = Eigen::SelfAdjointEigenSolver<Matrix>(a).eigenvalues();
  EXPECT_LT((sorted - ref).cwiseAbs().maxCoeff(), 1e-12 * scale);
}

class BatchEigenSizes : public ::testing::TestWithParam<std::tuple<std::size_t, int>> {};

TEST_P(BatchEigenSizes, EveryLaneIsAnOrthonormalEigenDecomposition) {
  const std::size_t n = std::get<0>(GetParam());
  const int level = std::get<1>(GetParam());
  const std::vector<Matrix> mats = random_batch(n, unsigned(n));
  const Solved s = solve(mats, n, level);
  EXPECT_EQ(s.failed, 0u);
  for (std::size_t l = 0; l < L; ++l) expect_decomposition(mats[l], s, n, l);
}

// every instruction-set variant (levels above what the CPU has fall back to the best it has)
INSTANTIATE_TEST_SUITE_P(Sizes, BatchEigenSizes,
                         ::testing::Combine(::testing::Values(1, 2, 3, 4, 5, 8, 16, 17, 33),
                                            ::testing::Values(0, 1, 2)));

class BatchEigenLevels : public ::testing::TestWithParam<int> {};

TEST_P(BatchEigenLevels, DegenerateMatricesBesideOrdinaryOnes) {
  const int level = GetParam();
  const std::size_t n = 16;
  std::mt19937_64 gen(7);
  std::vector<Matrix> mats(L, Matrix::Zero(n, n));
  mats[0] = random_symmetric(n, gen);
  mats[1] = Matrix::Zero(n, n);                     // all zero
  mats[2] = Matrix::Identity(n, n) * 3.0;           // one eigenvalue, 16 times
  mats[3] = Matrix::Zero(n, n);                     // block diagonal: exact zero couplings
  mats[3].topLeftCorner(5, 5) = random_symmetric(5, gen);
  mats[3].bottomRightCorner(7, 7) = random_symmetric(7, gen);
  Matrix b(n, 3);                                   // rank 3, PSD (a Gram matrix)
  for (std::size_t i = 0; i < n; ++i)
    for (std::size_t j = 0; j < 3; ++j) b(i, j) = std::sin(double(i * 3 + j));
  mats[4] = b * b.transpose();
  mats[5] = Matrix::Zero(n, n);                     // diagonal with ties
  for (std::size_t i = 0; i < n; ++i) mats[5](i, i) = double(i % 3);
  mats[6] = random_symmetric(n, gen) * 1e-150;      // tiny
  mats[7] = random_symmetric(n, gen) * 1e150;       // huge
  const Solved s = solve(mats, n, level);
  EXPECT_EQ(s.failed, 0u);
  for (std::size_t l = 0; l < L; ++l) {
    SCOPED_TRACE(l);
    if (l == 6) {  // check the tiny one scaled up (the absolute tolerances are in units of 1)
      Matrix v = vectors(s, n, l);
      EXPECT_LT((v.transpose() * v - Matrix::Identity(n, n)).norm(), 1e-13 * n);
      const Matrix a = mats[l] * 1e150;
      const Eigen::VectorXd d = values(s, n, l) * 1e150;
      EXPECT_LT((a * v - v * d.asDiagonal()).norm(), 1e-12 * a.norm());
      continue;
    }
    expect_decomposition(mats[l], s, n, l);
  }
  // a zero matrix: zero eigenvalues, identity eigenvectors
  EXPECT_EQ(values(s, n, 1), Eigen::VectorXd::Zero(n));
  EXPECT_EQ(vectors(s, n, 1), Matrix::Identity(n, n));
}

TEST_P(BatchEigenLevels, ALaneDoesNotDependOnItsBatchMatesOrItsPosition) {
  const int level = GetParam();
  const std::size_t n = 16;
  std::mt19937_64 gen(11);
  const Matrix target = random_symmetric(n, gen);
  std::vector<Matrix> alone(1, target);
  const Solved ref = solve(alone, n, level);
  for (std::size_t pos : {0u, 3u, 7u}) {
    std::vector<Matrix> mats;
    for (std::size_t l = 0; l < L; ++l)
      mats.push_back(l == pos ? target : random_symmetric(n, gen) * double(l + 1));
    const Solved s = solve(mats, n, level);
    EXPECT_EQ(s.failed, 0u);
    for (std::size_t i = 0; i < n * n; ++i)
      ASSERT_EQ(s.a[i * L + pos], ref.a[i * L]) << "eigenvector entry " << i << ", lane " << pos;
    for (std::size_t j = 0; j < n; ++j) ASSERT_EQ(s.d[j * L + pos], ref.d[j * L]);
  }
}

TEST_P(BatchEigenLevels, FewerMatricesThanLanesGiveTheSameBits) {
  const int level = GetParam();
  const std::size_t n = 16;
  const std::vector<Matrix> mats = random_batch(n, 13);
  const Solved all = solve(mats, n, level);
  for (std::size_t used : {1u, 2u, 3u, 4u, 5u}) {
    Solved s = lanes_of(mats, n, used);
    for (std::size_t i = 0; i < n * n; ++i)  // the lanes not used hold NaN: ignored
      for (std::size_t l = used; l < L; ++l) s.a[i * L + l] = std::nan("");
    EXPECT_EQ(eskin::batch_symmetric_eigen(n, s.a.data(), s.d.data(), s.e.data(), level, used), 0u);
    for (std::size_t l = 0; l < used; ++l) {
      for (std::size_t i = 0; i < n * n; ++i)
        ASSERT_EQ(s.a[i * L + l], all.a[i * L + l]) << "used " << used << ", lane " << l;
      for (std::size_t j = 0; j < n; ++j) ASSERT_EQ(s.d[j * L + l], all.d[j * L + l]);
    }
  }
}

TEST(BatchEigen, EveryInstructionSetGivesTheSameBits) {
  // no FMA contraction in the solver: each lane operation is one IEEE operation on every ISA
  for (std::size_t n : {4u, 16u, 17u}) {
    const std::vector<Matrix> mats = random_batch(n, unsigned(100 + n));
    const Solved base = solve(mats, n, 0);
    for (int level : {1, 2}) {
      const Solved s = solve(mats, n, level);
      EXPECT_EQ(s.a, base.a) << "n " << n << ", level " << level;
      EXPECT_EQ(s.d, base.d) << "n " << n << ", level " << level;
    }
  }
}

TEST_P(BatchEigenLevels, NonFiniteInputIsReportedPerLane) {
  const int level = GetParam();
  const std::size_t n = 6;
  std::vector<Matrix> mats = random_batch(n, 3);
  mats[2](1, 4) = mats[2](4, 1) = std::nan("");
  mats[5](0, 0) = INFINITY;
  const Solved s = solve(mats, n, level);
  EXPECT_EQ(s.failed, (1u << 2) | (1u << 5));
  for (std::size_t l : {0u, 1u, 3u, 4u, 6u, 7u}) expect_decomposition(mats[l], s, n, l);
  // 1 x 1: no QL iteration at all, only the check of the results can see them
  std::vector<Matrix> ones = random_batch(1, 4);
  ones[1](0, 0) = std::nan("");
  ones[6](0, 0) = -INFINITY;
  const Solved s1 = solve(ones, 1, level);
  EXPECT_EQ(s1.failed, (1u << 1) | (1u << 6));
  EXPECT_EQ(s1.d[0], ones[0](0, 0));
}

INSTANTIATE_TEST_SUITE_P(Isa, BatchEigenLevels, ::testing::Values(0, 1, 2));

}  // namespace
