// The subspace-overlap kernels of the model classifier (cpp/src/model_overlap.hpp): the
// controller's register-tiled version and the host's variants against the definition
//   ov = sum_{k < alpha, l < alpha} (b_k . x_l)^2
// summed in double, for every alpha that cuts into full and partial 4 x 4 tiles.
#include <gtest/gtest.h>

#include <cstddef>
#include <cstdint>
#include <random>
#include <vector>

#include "../../cpp/src/model_overlap.hpp"

namespace {

double reference(const std::vector<float>& b, const std::vector<float>& x, std::size_t n,
                 std::size_t alpha) {
  double s = 0.0;
  for (std::size_t k = 0; k < alpha; ++k)
    for (std::size_t l = 0; l < alpha; ++l) {
      double dot = 0.0;
      for (std::size_t i = 0; i < n; ++i)
        dot += static_cast<double>(b[k * n + i]) * static_cast<double>(x[l * n + i]);
      s += dot * dot;
    }
  return s;
}

std::vector<float> columns(std::size_t n, std::size_t cols, std::mt19937& rng) {
  std::normal_distribution<float> g(0.0f, 1.0f);
  std::vector<float> v(n * cols);
  for (auto& e : v) e = g(rng) / 4.0f;
  return v;
}

}  // namespace

TEST(ModelOverlap, TiledMatchesTheDefinitionForEveryTileShape) {
  std::mt19937 rng(7);
  // alpha 1-3 (one partial tile), 4 (one full), 5-9 (full and partial), 16 (mode 3 at Q)
  for (std::size_t n : {1u, 3u, 16u, 200u}) {
    for (std::size_t alpha = 1; alpha <= 9; ++alpha) {
      const auto b = columns(n, 16, rng);
      const auto x = columns(n, 16, rng);
      const double want = reference(b, x, n, alpha);
      const double got = eskin::detail::overlap_f32_tiled(b.data(), x.data(), n, alpha);
      EXPECT_NEAR(got, want, 2e-5 * (1.0 + want)) << "n " << n << " alpha " << alpha;
    }
    const auto b = columns(n, 16, rng);
    const auto x = columns(n, 16, rng);
    EXPECT_NEAR(eskin::detail::overlap_f32_tiled(b.data(), x.data(), n, 16),
                reference(b, x, n, 16), 2e-5 * (1.0 + reference(b, x, n, 16)))
        << "n " << n << " alpha 16";
  }
}

TEST(ModelOverlap, OnlyTheFirstAlphaColumnsCount) {
  // a block holds alpha_store columns; the overlap of a group with a smaller alpha must not read
  // the others (here poisoned with huge values)
  std::mt19937 rng(11);
  const std::size_t n = 12;
  auto b = columns(n, 8, rng);
  auto x = columns(n, 8, rng);
  const double want = reference(b, x, n, 5);
  for (std::size_t i = 5 * n; i < 8 * n; ++i) b[i] = x[i] = 1e18f;
  EXPECT_NEAR(eskin::detail::overlap_f32_tiled(b.data(), x.data(), n, 5), want,
              2e-5 * (1.0 + want));
}

TEST(ModelOverlap, TheSelectedVariantsAgreeWithTheTiledOne) {
  std::mt19937 rng(3);
  const std::size_t n = 200, alpha = 4;
  const auto b = columns(n, alpha, rng);
  const auto x = columns(n, alpha, rng);
  const double tiled = eskin::detail::overlap_f32_tiled(b.data(), x.data(), n, alpha);
  const double chosen = eskin::detail::select_overlap_f32()(b.data(), x.data(), n, alpha);
  EXPECT_NEAR(chosen, tiled, 2e-5 * (1.0 + tiled));
}

TEST(ModelOverlap, TheOverlapsOfManySupportVectorsAreEachOnesOverlap) {
  // the host's one call per mode (detail::OverlapsF32): support vectors taken by index from a
  // table of blocks of alpha_store columns, for alphas that cut into the 4-column tiles, the
  // pairs and the columns left; against the definition and against the single overlap
  std::mt19937 rng(5);
  const std::size_t n = 200, stored = 6, count = 7;
  const std::vector<std::uint32_t> sv = {4, 0, 9, 2, 2, 7, 5};
  const auto table = columns(n, stored * 10, rng);
  const auto x = columns(n, stored, rng);
  for (std::size_t alpha = 1; alpha <= stored; ++alpha) {
    std::vector<double> out(count, -1.0);
    eskin::detail::select_overlaps_f32()(table.data(), stored * n, sv.data(), count, x.data(), n,
                                         alpha, out.data());
    for (std::size_t t = 0; t < count; ++t) {
      const float* b = table.data() + sv[t] * stored * n;
      const std::vector<float> block(b, b + stored * n);
      const double want = reference(block, x, n, alpha);
      EXPECT_NEAR(out[t], want, 2e-5 * (1.0 + want)) << "alpha " << alpha << " sv " << sv[t];
      const double one = eskin::detail::select_overlap_f32()(b, x.data(), n, alpha);
      EXPECT_NEAR(out[t], one, 1e-12 * (1.0 + one)) << "alpha " << alpha << " sv " << sv[t];
    }
  }
}
