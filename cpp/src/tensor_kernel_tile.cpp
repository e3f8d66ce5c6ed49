// The 8 x 8 tile micro-kernel of the batched mode distances (see tensor_kernel_tile.hpp).
// Plain loops and intrinsics only: no Eigen, no std templates in this file.
#include "tensor_kernel_tile.hpp"

#include <cstdlib>
#include <cstring>

#if (defined(__x86_64__) || defined(__i386__)) && defined(__GNUC__)
#define ESKIN_HAVE_X86_DISPATCH 1
#include <immintrin.h>
#endif

namespace eskin {

void tile_generic(const double* a, const double* b, std::size_t k, double* c) noexcept {
  double acc[64];
  for (int i = 0; i < 64; ++i) acc[i] = 0.0;
  for (std::size_t kk = 0; kk < k; ++kk) {
    const double* ar = a + kk * 8;
    const double* br = b + kk * 8;
    for (int r = 0; r < 8; ++r) {
      const double x = ar[r];
      double* cr = acc + r * 8;
      for (int s = 0; s < 8; ++s) cr[s] += x * br[s];
    }
  }
  for (int i = 0; i < 64; ++i) c[i] = acc[i];
}

#ifdef ESKIN_HAVE_X86_DISPATCH
namespace {

// Four rows (r0..r0+3) of the tile over k in [k0, k1), added into c.
__attribute__((target("avx2,fma"))) inline void rows4_avx2(const double* a, const double* b,
                                                           std::size_t k0, std::size_t k1,
                                                           double* c) {
  __m256d c00 = _mm256_setzero_pd(), c01 = _mm256_setzero_pd();
  __m256d c10 = _mm256_setzero_pd(), c11 = _mm256_setzero_pd();
  __m256d c20 = _mm256_setzero_pd(), c21 = _mm256_setzero_pd();
  __m256d c30 = _mm256_setzero_pd(), c31 = _mm256_setzero_pd();
  for (std::size_t k = k0; k < k1; ++k) {
    const __m256d b0 = _mm256_loadu_pd(b + k * 8);
    const __m256d b1 = _mm256_loadu_pd(b + k * 8 + 4);
    const double* ak = a + k * 8;
    __m256d x = _mm256_broadcast_sd(ak + 0);
    c00 = _mm256_fmadd_pd(x, b0, c00);
    c01 = _mm256_fmadd_pd(x, b1, c01);
    x = _mm256_broadcast_sd(ak + 1);
    c10 = _mm256_fmadd_pd(x, b0, c10);
    c11 = _mm256_fmadd_pd(x, b1, c11);
    x = _mm256_broadcast_sd(ak + 2);
    c20 = _mm256_fmadd_pd(x, b0, c20);
    c21 = _mm256_fmadd_pd(x, b1, c21);
    x = _mm256_broadcast_sd(ak + 3);
    c30 = _mm256_fmadd_pd(x, b0, c30);
    c31 = _mm256_fmadd_pd(x, b1, c31);
  }
  _mm256_storeu_pd(c + 0, _mm256_add_pd(_mm256_loadu_pd(c + 0), c00));
  _mm256_storeu_pd(c + 4, _mm256_add_pd(_mm256_loadu_pd(c + 4), c01));
  _mm256_storeu_pd(c + 8, _mm256_add_pd(_mm256_loadu_pd(c + 8), c10));
  _mm256_storeu_pd(c + 12, _mm256_add_pd(_mm256_loadu_pd(c + 12), c11));
  _mm256_storeu_pd(c + 16, _mm256_add_pd(_mm256_loadu_pd(c + 16), c20));
  _mm256_storeu_pd(c + 20, _mm256_add_pd(_mm256_loadu_pd(c + 20), c21));
  _mm256_storeu_pd(c + 24, _mm256_add_pd(_mm256_loadu_pd(c + 24), c30));
  _mm256_storeu_pd(c + 28, _mm256_add_pd(_mm256_loadu_pd(c + 28), c31));
}

__attribute__((target("avx2,fma"))) void tile_avx2(const double* a, const double* b,
                                                   std::size_t k, double* c) noexcept {
  for (int i = 0; i < 64; ++i) c[i] = 0.0;
  // k in chunks so that both halves of the tile reuse the chunk of b from L1
  const std::size_t kc = 128;
  for (std::size_t k0 = 0; k0 < k; k0 += kc) {
    const std::size_t k1 = k0 + kc < k ? k0 + kc : k;
    rows4_avx2(a, b, k0, k1, c);
    rows4_avx2(a + 4, b, k0, k1, c + 32);
  }
}

bool cpu_has_avx2_fma() noexcept {
  __builtin_cpu_init();
  return __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
}

}  // namespace
#endif

namespace {
bool force_generic() noexcept {
  const char* env = std::getenv("ESKIN_KERNEL_ISA");
  return env != nullptr && std::strcmp(env, "generic") == 0;
}
}  // namespace

TileFn select_tile_kernel() noexcept {
#ifdef ESKIN_HAVE_X86_DISPATCH
  static const bool avx2 = cpu_has_avx2_fma();
  if (avx2 && !force_generic()) return &tile_avx2;
#endif
  return &tile_generic;
}

const char* tile_kernel_name() noexcept {
  return select_tile_kernel() == &tile_generic ? "generic" : "avx2-fma";
}

}  // namespace eskin
