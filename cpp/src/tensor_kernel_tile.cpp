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
  tile_dot_generic(a, b, k, c);
  for (int i = 0; i < 64; ++i) c[i] *= c[i];
}

void tile_dot_generic(const double* a, const double* b, std::size_t k, double* c) noexcept {
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

namespace {
double tile_sum_generic(const double* a, const double* b, std::size_t k) noexcept {
  double c[64];
  tile_generic(a, b, k, c);
  double s[8] = {0, 0, 0, 0, 0, 0, 0, 0};
  for (int r = 0; r < 8; ++r)
    for (int j = 0; j < 8; ++j) s[j] += c[r * 8 + j];
  return ((s[0] + s[1]) + (s[2] + s[3])) + ((s[4] + s[5]) + (s[6] + s[7]));
}
}  // namespace

#ifdef ESKIN_HAVE_X86_DISPATCH
namespace {

// Four rows (r0..r0+3) of the tile, A^T B over k in [k0, k1): eight ymm accumulators, c[2 r + h]
// holding columns 4h..4h+3 of row r.
struct Rows4 {
  __m256d c[8];
};

__attribute__((target("avx2,fma"))) inline Rows4 rows4_dot_avx2(const double* a, const double* b,
                                                                std::size_t k0, std::size_t k1) {
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
  return Rows4{{c00, c01, c10, c11, c20, c21, c30, c31}};
}

// Four rows of the tile over k in [k0, k1), added into c (row-major, 8 per row).
__attribute__((target("avx2,fma"))) inline void rows4_avx2(const double* a, const double* b,
                                                           std::size_t k0, std::size_t k1,
                                                           double* c) {
  const Rows4 r = rows4_dot_avx2(a, b, k0, k1);
  for (int i = 0; i < 8; ++i)
    _mm256_storeu_pd(c + 4 * i, _mm256_add_pd(_mm256_loadu_pd(c + 4 * i), r.c[i]));
}

__attribute__((target("avx2,fma"))) void tile_dot_avx2(const double* a, const double* b,
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

__attribute__((target("avx2,fma"))) void tile_avx2(const double* a, const double* b,
                                                   std::size_t k, double* c) noexcept {
  tile_dot_avx2(a, b, k, c);
  for (int i = 0; i < 64; i += 4) {
    const __m256d v = _mm256_loadu_pd(c + i);
    _mm256_storeu_pd(c + i, _mm256_mul_pd(v, v));
  }
}

// Sum of squares of four rows (r0..r0+3) of the tile over the whole of k (no chunking).
__attribute__((target("avx2,fma"))) inline __m256d rows4_sumsq_avx2(const double* a,
                                                                    const double* b,
                                                                    std::size_t k) {
  const Rows4 r = rows4_dot_avx2(a, b, 0, k);
  __m256d s0 = _mm256_mul_pd(r.c[0], r.c[0]), s1 = _mm256_mul_pd(r.c[1], r.c[1]);
  s0 = _mm256_fmadd_pd(r.c[2], r.c[2], s0);
  s1 = _mm256_fmadd_pd(r.c[3], r.c[3], s1);
  s0 = _mm256_fmadd_pd(r.c[4], r.c[4], s0);
  s1 = _mm256_fmadd_pd(r.c[5], r.c[5], s1);
  s0 = _mm256_fmadd_pd(r.c[6], r.c[6], s0);
  s1 = _mm256_fmadd_pd(r.c[7], r.c[7], s1);
  return _mm256_add_pd(s0, s1);
}

__attribute__((target("avx2,fma"))) double tile_sum_avx2(const double* a, const double* b,
                                                         std::size_t k) noexcept {
  __m256d s;
  if (k <= 256) {
    s = _mm256_add_pd(rows4_sumsq_avx2(a, b, k), rows4_sumsq_avx2(a + 4, b, k));
  } else {
    alignas(32) double c[64];
    tile_avx2(a, b, k, c);
    __m256d s0 = _mm256_load_pd(c), s1 = _mm256_load_pd(c + 4);
    for (int i = 8; i < 64; i += 8) {
      s0 = _mm256_add_pd(s0, _mm256_load_pd(c + i));
      s1 = _mm256_add_pd(s1, _mm256_load_pd(c + i + 4));
    }
    s = _mm256_add_pd(s0, s1);
  }
  alignas(32) double t[4];
  _mm256_store_pd(t, s);
  return (t[0] + t[1]) + (t[2] + t[3]);
}

// AVX-512: the whole 8 x 8 tile in eight zmm accumulators (one per row of A^T B), no chunking.
#define ESKIN_TILE512_BODY                                   \
  __m512d c0 = _mm512_setzero_pd(), c1 = _mm512_setzero_pd(); \
  __m512d c2 = _mm512_setzero_pd(), c3 = _mm512_setzero_pd(); \
  __m512d c4 = _mm512_setzero_pd(), c5 = _mm512_setzero_pd(); \
  __m512d c6 = _mm512_setzero_pd(), c7 = _mm512_setzero_pd(); \
  for (std::size_t kk = 0; kk < k; ++kk) {                    \
    const __m512d bv = _mm512_loadu_pd(b + kk * 8);           \
    const double* ak = a + kk * 8;                            \
    c0 = _mm512_fmadd_pd(_mm512_set1_pd(ak[0]), bv, c0);      \
    c1 = _mm512_fmadd_pd(_mm512_set1_pd(ak[1]), bv, c1);      \
    c2 = _mm512_fmadd_pd(_mm512_set1_pd(ak[2]), bv, c2);      \
    c3 = _mm512_fmadd_pd(_mm512_set1_pd(ak[3]), bv, c3);      \
    c4 = _mm512_fmadd_pd(_mm512_set1_pd(ak[4]), bv, c4);      \
    c5 = _mm512_fmadd_pd(_mm512_set1_pd(ak[5]), bv, c5);      \
    c6 = _mm512_fmadd_pd(_mm512_set1_pd(ak[6]), bv, c6);      \
    c7 = _mm512_fmadd_pd(_mm512_set1_pd(ak[7]), bv, c7);      \
  }

__attribute__((target("avx512f"))) void tile_avx512(const double* a, const double* b,
                                                    std::size_t k, double* c) noexcept {
  ESKIN_TILE512_BODY
  _mm512_storeu_pd(c + 0, _mm512_mul_pd(c0, c0));
  _mm512_storeu_pd(c + 8, _mm512_mul_pd(c1, c1));
  _mm512_storeu_pd(c + 16, _mm512_mul_pd(c2, c2));
  _mm512_storeu_pd(c + 24, _mm512_mul_pd(c3, c3));
  _mm512_storeu_pd(c + 32, _mm512_mul_pd(c4, c4));
  _mm512_storeu_pd(c + 40, _mm512_mul_pd(c5, c5));
  _mm512_storeu_pd(c + 48, _mm512_mul_pd(c6, c6));
  _mm512_storeu_pd(c + 56, _mm512_mul_pd(c7, c7));
}

__attribute__((target("avx512f"))) void tile_dot_avx512(const double* a, const double* b,
                                                        std::size_t k, double* c) noexcept {
  ESKIN_TILE512_BODY
  _mm512_storeu_pd(c + 0, c0);
  _mm512_storeu_pd(c + 8, c1);
  _mm512_storeu_pd(c + 16, c2);
  _mm512_storeu_pd(c + 24, c3);
  _mm512_storeu_pd(c + 32, c4);
  _mm512_storeu_pd(c + 40, c5);
  _mm512_storeu_pd(c + 48, c6);
  _mm512_storeu_pd(c + 56, c7);
}

__attribute__((target("avx512f"))) double tile_sum_avx512(const double* a, const double* b,
                                                         std::size_t k) noexcept {
  ESKIN_TILE512_BODY
  __m512d s0 = _mm512_mul_pd(c0, c0), s1 = _mm512_mul_pd(c1, c1);
  s0 = _mm512_fmadd_pd(c2, c2, s0);
  s1 = _mm512_fmadd_pd(c3, c3, s1);
  s0 = _mm512_fmadd_pd(c4, c4, s0);
  s1 = _mm512_fmadd_pd(c5, c5, s1);
  s0 = _mm512_fmadd_pd(c6, c6, s0);
  s1 = _mm512_fmadd_pd(c7, c7, s1);
  alignas(64) double t[8];
  _mm512_store_pd(t, _mm512_add_pd(s0, s1));
  return ((t[0] + t[1]) + (t[2] + t[3])) + ((t[4] + t[5]) + (t[6] + t[7]));
}
#undef ESKIN_TILE512_BODY

// the x86-64-v4 set (what the eigen-solver's AVX-512 variant is compiled for; the tiles need
// only AVX-512F of it)
bool cpu_has_avx512() noexcept {
  __builtin_cpu_init();
  return __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512dq") &&
         __builtin_cpu_supports("avx512vl") && __builtin_cpu_supports("avx512bw");
}

bool cpu_has_avx2_fma() noexcept {
  __builtin_cpu_init();
  return __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
}

}  // namespace
#endif

namespace {
// Highest instruction set allowed by ESKIN_KERNEL_ISA: 0 generic, 1 avx2, 2 avx512 (default).
[[maybe_unused]] int isa_cap() noexcept {
  const char* env = std::getenv("ESKIN_KERNEL_ISA");
  if (env == nullptr) return 2;
  if (std::strcmp(env, "generic") == 0) return 0;
  if (std::strcmp(env, "avx2") == 0) return 1;
  return 2;
}

}  // namespace

int isa_level() noexcept {
#ifdef ESKIN_HAVE_X86_DISPATCH
  static const int cpu = cpu_has_avx512() && cpu_has_avx2_fma() ? 2 : (cpu_has_avx2_fma() ? 1 : 0);
  const int cap = isa_cap();
  return cpu < cap ? cpu : cap;
#else
  return 0;
#endif
}

TileFn select_tile_kernel() noexcept {
#ifdef ESKIN_HAVE_X86_DISPATCH
  switch (isa_level()) {
    case 2: return &tile_avx512;
    case 1: return &tile_avx2;
    default: break;
  }
#endif
  return &tile_generic;
}

TileFn select_tile_dot_kernel() noexcept {
#ifdef ESKIN_HAVE_X86_DISPATCH
  switch (isa_level()) {
    case 2: return &tile_dot_avx512;
    case 1: return &tile_dot_avx2;
    default: break;
  }
#endif
  return &tile_dot_generic;
}

TileSumFn select_tile_sum_kernel() noexcept {
#ifdef ESKIN_HAVE_X86_DISPATCH
  switch (isa_level()) {
    case 2: return &tile_sum_avx512;
    case 1: return &tile_sum_avx2;
    default: break;
  }
#endif
  return &tile_sum_generic;
}

const char* tile_kernel_name() noexcept {
  switch (isa_level()) {
    case 2: return "avx512";
    case 1: return "avx2-fma";
    default: return "generic";
  }
}

}  // namespace eskin
