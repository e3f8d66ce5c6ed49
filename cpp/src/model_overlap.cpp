// Subspace-overlap micro-kernels of the model classifier (see model_overlap.hpp).
#include "model_overlap.hpp"

#include <array>
#include <cstdint>
#include <cstdlib>
#include <cstring>

#if (defined(__x86_64__) || defined(__i386__)) && (defined(__GNUC__) || defined(__clang__))
#define ESKIN_MODEL_X86_DISPATCH 1
#include <immintrin.h>
#endif

namespace eskin::detail {

namespace {

// Portable versions: 8 partial sums per dot product (float products accumulated in float within
// a lane, lanes summed in double), so the float32 and AVX2 variants round alike.
double overlap_f32_generic(const float* b, const float* x, std::size_t n,
                           std::size_t alpha) noexcept {
  double s = 0.0;
  for (std::size_t k = 0; k < alpha; ++k) {
    const float* bk = b + k * n;
    for (std::size_t l = 0; l < alpha; ++l) {
      const float* xl = x + l * n;
      float acc[8] = {0, 0, 0, 0, 0, 0, 0, 0};
      std::size_t i = 0;
      for (; i + 8 <= n; i += 8)
        for (std::size_t j = 0; j < 8; ++j) acc[j] += bk[i + j] * xl[i + j];
      double dot = 0.0;
      for (std::size_t j = 0; j < 8; ++j) dot += static_cast<double>(acc[j]);
      for (; i < n; ++i) dot += static_cast<double>(bk[i]) * static_cast<double>(xl[i]);
      s += dot * dot;
    }
  }
  return s;
}

double overlap_f64_generic(const double* b, const double* x, std::size_t n,
                           std::size_t alpha) noexcept {
  double s = 0.0;
  for (std::size_t k = 0; k < alpha; ++k) {
    const double* bk = b + k * n;
    for (std::size_t l = 0; l < alpha; ++l) {
      const double* xl = x + l * n;
      double acc[4] = {0, 0, 0, 0};
      std::size_t i = 0;
      for (; i + 4 <= n; i += 4)
        for (std::size_t j = 0; j < 4; ++j) acc[j] += bk[i + j] * xl[i + j];
      double dot = (acc[0] + acc[1]) + (acc[2] + acc[3]);
      for (; i < n; ++i) dot += bk[i] * xl[i];
      s += dot * dot;
    }
  }
  return s;
}

double dot_f32_generic(const float* a, const float* b, std::size_t n) noexcept {
  float acc[8] = {0, 0, 0, 0, 0, 0, 0, 0};
  std::size_t i = 0;
  for (; i + 8 <= n; i += 8)
    for (std::size_t j = 0; j < 8; ++j) acc[j] += a[i + j] * b[i + j];
  double dot = 0.0;
  for (std::size_t j = 0; j < 8; ++j) dot += static_cast<double>(acc[j]);
  for (; i < n; ++i) dot += static_cast<double>(a[i]) * static_cast<double>(b[i]);
  return dot;
}

double dot_f64_generic(const double* a, const double* b, std::size_t n) noexcept {
  double acc[4] = {0, 0, 0, 0};
  std::size_t i = 0;
  for (; i + 4 <= n; i += 4)
    for (std::size_t j = 0; j < 4; ++j) acc[j] += a[i + j] * b[i + j];
  double dot = (acc[0] + acc[1]) + (acc[2] + acc[3]);
  for (; i < n; ++i) dot += a[i] * b[i];
  return dot;
}

// The controller's overlap (a Cortex-M4F; compiled on the host too, where the tests check it):
// single precision throughout, double being emulated in software there. Its FPU has no lanes to
// fill but 32 registers: the overlap is cut into tiles of up to 4 x 4 dot products, each pass
// over i loading KB entries of b and LB of x once and feeding KB x LB multiply-adds
// (arm-none-eabi-gcc -O3: 8 post-incremented loads and 16 FMAs per pass of a 4 x 4 tile, about
// 1.6 instructions per multiply-add; one dot product at a time took about 6, each pass loading
// both operands and stepping its own loop).
// The tile's arrays are std::array: the same code at -O3, and a debug build with libstdc++'s
// assertions stops on an index past one of them.
template <int KB, int LB>
float overlap_tile(const float* b, const float* x, std::size_t n) noexcept {
  std::array<std::array<float, LB>, KB> acc{};
  std::array<const float*, KB> bp;
  std::array<const float*, LB> xp;
  for (int k = 0; k < KB; ++k) bp[k] = b + static_cast<std::size_t>(k) * n;
  for (int l = 0; l < LB; ++l) xp[l] = x + static_cast<std::size_t>(l) * n;
  for (std::size_t i = 0; i < n; ++i) {
    std::array<float, KB> bv;
    std::array<float, LB> xv;
    for (int k = 0; k < KB; ++k) bv[k] = bp[k][i];
    for (int l = 0; l < LB; ++l) xv[l] = xp[l][i];
    for (int k = 0; k < KB; ++k)
      for (int l = 0; l < LB; ++l) acc[k][l] += bv[k] * xv[l];
  }
  float s = 0.0f;
  for (int k = 0; k < KB; ++k)
    for (int l = 0; l < LB; ++l) s += acc[k][l] * acc[k][l];
  return s;
}

// The tiles of KB columns of b against every column of x (4 at a time, then the 1-3 left).
template <int KB>
float overlap_rows(const float* b, const float* x, std::size_t n, std::size_t alpha) noexcept {
  float s = 0.0f;
  std::size_t l = 0;
  for (; l + 4 <= alpha; l += 4) s += overlap_tile<KB, 4>(b, x + l * n, n);
  switch (alpha - l) {
    case 3: s += overlap_tile<KB, 3>(b, x + l * n, n); break;
    case 2: s += overlap_tile<KB, 2>(b, x + l * n, n); break;
    case 1: s += overlap_tile<KB, 1>(b, x + l * n, n); break;
    default: break;
  }
  return s;
}

}  // namespace

double overlap_f32_tiled(const float* b, const float* x, std::size_t n,
                         std::size_t alpha) noexcept {
  float s = 0.0f;
  std::size_t k = 0;
  for (; k + 4 <= alpha; k += 4) s += overlap_rows<4>(b + k * n, x, n, alpha);
  switch (alpha - k) {
    case 3: s += overlap_rows<3>(b + k * n, x, n, alpha); break;
    case 2: s += overlap_rows<2>(b + k * n, x, n, alpha); break;
    case 1: s += overlap_rows<1>(b + k * n, x, n, alpha); break;
    default: break;
  }
  return s;
}

namespace {

#if defined(ESKIN_DEVICE)
double dot_f32_single(const float* a, const float* b, std::size_t n) noexcept {
  float dot = 0.0f;
  for (std::size_t i = 0; i < n; ++i) dot += a[i] * b[i];
  return dot;
}
#endif

#ifdef ESKIN_MODEL_X86_DISPATCH
__attribute__((target("avx2,fma"))) double hsum8(__m256 v) noexcept {
  // lanes summed in double, as in the generic version
  const __m256d lo = _mm256_cvtps_pd(_mm256_castps256_ps128(v));
  const __m256d hi = _mm256_cvtps_pd(_mm256_extractf128_ps(v, 1));
  const __m256d s = _mm256_add_pd(lo, hi);
  const __m128d t = _mm_add_pd(_mm256_castpd256_pd128(s), _mm256_extractf128_pd(s, 1));
  return _mm_cvtsd_f64(_mm_add_sd(t, _mm_unpackhi_pd(t, t)));
}

// (b . x)^2 of one column pair, the dot product as overlap_f32_avx2 sums it.
__attribute__((target("avx2,fma"))) double overlap_pair(const float* b, const float* x,
                                                       std::size_t n) noexcept {
  const std::size_t n8 = n - n % 8;
  __m256 a = _mm256_setzero_ps();
  for (std::size_t i = 0; i < n8; i += 8)
    a = _mm256_fmadd_ps(_mm256_loadu_ps(b + i), _mm256_loadu_ps(x + i), a);
  double d = hsum8(a);
  double t = 0.0;
  for (std::size_t i = n8; i < n; ++i) t += static_cast<double>(b[i]) * static_cast<double>(x[i]);
  d += t;
  return d * d;
}

// Dot products of columns b_k (k in kb) with x_l (l in lb), 2 x 2 at a time: each pass loads
// two columns of b and two of x and feeds four FMAs.
__attribute__((target("avx2,fma"))) double overlap_f32_avx2(const float* b, const float* x,
                                                            std::size_t n,
                                                            std::size_t alpha) noexcept {
  double s = 0.0;
  const std::size_t n8 = n - n % 8;
  auto tail = [&](const float* p, const float* q) {
    double t = 0.0;
    for (std::size_t i = n8; i < n; ++i) t += static_cast<double>(p[i]) * static_cast<double>(q[i]);
    return t;
  };
  std::size_t k = 0;
  for (; k + 2 <= alpha; k += 2) {
    const float* b0 = b + k * n;
    const float* b1 = b0 + n;
    std::size_t l = 0;
    for (; l + 2 <= alpha; l += 2) {
      const float* x0 = x + l * n;
      const float* x1 = x0 + n;
      __m256 a00 = _mm256_setzero_ps(), a01 = _mm256_setzero_ps();
      __m256 a10 = _mm256_setzero_ps(), a11 = _mm256_setzero_ps();
      for (std::size_t i = 0; i < n8; i += 8) {
        const __m256 vb0 = _mm256_loadu_ps(b0 + i), vb1 = _mm256_loadu_ps(b1 + i);
        const __m256 vx0 = _mm256_loadu_ps(x0 + i), vx1 = _mm256_loadu_ps(x1 + i);
        a00 = _mm256_fmadd_ps(vb0, vx0, a00);
        a01 = _mm256_fmadd_ps(vb0, vx1, a01);
        a10 = _mm256_fmadd_ps(vb1, vx0, a10);
        a11 = _mm256_fmadd_ps(vb1, vx1, a11);
      }
      const double d00 = hsum8(a00) + tail(b0, x0), d01 = hsum8(a01) + tail(b0, x1);
      const double d10 = hsum8(a10) + tail(b1, x0), d11 = hsum8(a11) + tail(b1, x1);
      s += d00 * d00 + d01 * d01 + d10 * d10 + d11 * d11;
    }
    for (; l < alpha; ++l) {
      const float* x0 = x + l * n;
      __m256 a00 = _mm256_setzero_ps(), a10 = _mm256_setzero_ps();
      for (std::size_t i = 0; i < n8; i += 8) {
        const __m256 vx0 = _mm256_loadu_ps(x0 + i);
        a00 = _mm256_fmadd_ps(_mm256_loadu_ps(b0 + i), vx0, a00);
        a10 = _mm256_fmadd_ps(_mm256_loadu_ps(b1 + i), vx0, a10);
      }
      const double d00 = hsum8(a00) + tail(b0, x0), d10 = hsum8(a10) + tail(b1, x0);
      s += d00 * d00 + d10 * d10;
    }
  }
  for (; k < alpha; ++k) {
    const float* b0 = b + k * n;
    for (std::size_t l = 0; l < alpha; ++l) {
      const float* x0 = x + l * n;
      __m256 a00 = _mm256_setzero_ps();
      for (std::size_t i = 0; i < n8; i += 8)
        a00 = _mm256_fmadd_ps(_mm256_loadu_ps(b0 + i), _mm256_loadu_ps(x0 + i), a00);
      const double d00 = hsum8(a00) + tail(b0, x0);
      s += d00 * d00;
    }
  }
  return s;
}

// The sum of the squares of the dot products held in 4 x 8 float partial sums, each dot product
// summed as hsum8 does it (lanes j and j + 4 in double, then (0 + 2) + (1 + 3)): the same four
// dot products, bit for bit, in one pass of packed instructions instead of four reductions.
__attribute__((target("avx2,fma"))) inline __m256d half(__m256 v) noexcept {
  return _mm256_add_pd(_mm256_cvtps_pd(_mm256_castps256_ps128(v)),
                       _mm256_cvtps_pd(_mm256_extractf128_ps(v, 1)));
}
__attribute__((target("avx2,fma"))) __m256d hsum8x4(__m256 a, __m256 b, __m256 c,
                                                  __m256 d) noexcept {
  const __m256d sa = half(a), sb = half(b), sc = half(c), sd = half(d);
  const __m256d u = _mm256_add_pd(_mm256_permute2f128_pd(sa, sb, 0x20),
                                  _mm256_permute2f128_pd(sa, sb, 0x31));
  const __m256d v = _mm256_add_pd(_mm256_permute2f128_pd(sc, sd, 0x20),
                                  _mm256_permute2f128_pd(sc, sd, 0x31));
  return _mm256_hadd_pd(u, v);  // (dot a, dot c, dot b, dot d)
}

// ||B^T X||_F^2 of one support vector's block against the input's, LB = 4 columns of x at a
// time (held in registers with 2 columns of b: 8 partial sums, 14 of the 16 vector registers),
// so that each column of b is read from memory once; the 1-3 columns of x left, and an odd
// column of b, by the pairwise variant. Squares summed in a packed double accumulator.
__attribute__((target("avx2,fma"))) double overlap_f32_avx2_wide(const float* b, const float* x,
                                                                 std::size_t n,
                                                                 std::size_t alpha) noexcept {
  const std::size_t l4 = alpha - alpha % 4, k2 = alpha - alpha % 2;
  if (l4 == 0 || k2 == 0 || n % 8 != 0) return overlap_f32_avx2(b, x, n, alpha);
  __m256d sq = _mm256_setzero_pd();
  for (std::size_t k = 0; k < k2; k += 2) {
    const float* b0 = b + k * n;
    const float* b1 = b0 + n;
    for (std::size_t l = 0; l < l4; l += 4) {
      const float* x0 = x + l * n;
      __m256 a00 = _mm256_setzero_ps(), a01 = a00, a02 = a00, a03 = a00;
      __m256 a10 = a00, a11 = a00, a12 = a00, a13 = a00;
      for (std::size_t i = 0; i < n; i += 8) {
        const __m256 vb0 = _mm256_loadu_ps(b0 + i), vb1 = _mm256_loadu_ps(b1 + i);
        __m256 vx0 = _mm256_loadu_ps(x0 + i), vx1 = _mm256_loadu_ps(x0 + n + i);
        __m256 vx2 = _mm256_loadu_ps(x0 + 2 * n + i), vx3 = _mm256_loadu_ps(x0 + 3 * n + i);
        // one load per column and pass (the compiler would otherwise fold the loads of x into
        // both FMAs that use them: 10 loads a pass instead of 6, the loads then the bound)
        __asm__("" : "+x"(vx0), "+x"(vx1), "+x"(vx2), "+x"(vx3));
        a00 = _mm256_fmadd_ps(vb0, vx0, a00);
        a01 = _mm256_fmadd_ps(vb0, vx1, a01);
        a02 = _mm256_fmadd_ps(vb0, vx2, a02);
        a03 = _mm256_fmadd_ps(vb0, vx3, a03);
        a10 = _mm256_fmadd_ps(vb1, vx0, a10);
        a11 = _mm256_fmadd_ps(vb1, vx1, a11);
        a12 = _mm256_fmadd_ps(vb1, vx2, a12);
        a13 = _mm256_fmadd_ps(vb1, vx3, a13);
      }
      const __m256d d0 = hsum8x4(a00, a01, a02, a03), d1 = hsum8x4(a10, a11, a12, a13);
      sq = _mm256_fmadd_pd(d0, d0, sq);
      sq = _mm256_fmadd_pd(d1, d1, sq);
    }
  }
  const __m128d t = _mm_add_pd(_mm256_castpd256_pd128(sq), _mm256_extractf128_pd(sq, 1));
  double s = _mm_cvtsd_f64(_mm_add_sd(t, _mm_unpackhi_pd(t, t)));
  // the columns of x beyond l4 against the first k2 columns of b, then the last column of b
  // (odd alpha) against every column of x: the pairwise variant on those sub-blocks
  for (std::size_t l = l4; l < alpha; ++l)
    for (std::size_t k = 0; k < k2; ++k) s += overlap_pair(b + k * n, x + l * n, n);
  for (std::size_t k = k2; k < alpha; ++k)
    for (std::size_t l = 0; l < alpha; ++l) s += overlap_pair(b + k * n, x + l * n, n);
  return s;
}

// The overlaps of `count` support vectors (sv[t]'s block at bases + sv[t] * block) with the
// input's, into out[t]; the block after next is prefetched while one is computed (the stored
// bases of a large model come from memory: this keeps several of their lines on the way).
__attribute__((target("avx2,fma"))) void overlaps_f32_avx2(const float* bases, std::size_t block,
                                                          const std::uint32_t* sv,
                                                          std::size_t count, const float* x,
                                                          std::size_t n, std::size_t alpha,
                                                          double* out) noexcept {
  const std::size_t used = n * alpha;  // floats read of each block
  for (std::size_t t = 0; t < count; ++t) {
    if (t + 2 < count) {
      const char* p = reinterpret_cast<const char*>(bases + sv[t + 2] * block);
      for (std::size_t o = 0; o < used * sizeof(float); o += 64)
        _mm_prefetch(p + o, _MM_HINT_T0);
    }
    out[t] = overlap_f32_avx2_wide(bases + sv[t] * block, x, n, alpha);
  }
}

__attribute__((target("avx2,fma"))) double overlap_f64_avx2(const double* b, const double* x,
                                                            std::size_t n,
                                                            std::size_t alpha) noexcept {
  double s = 0.0;
  for (std::size_t k = 0; k < alpha; ++k) {
    const double* bk = b + k * n;
    for (std::size_t l = 0; l < alpha; ++l) {
      const double* xl = x + l * n;
      __m256d a0 = _mm256_setzero_pd();
      std::size_t i = 0;
      for (; i + 4 <= n; i += 4) a0 = _mm256_fmadd_pd(_mm256_loadu_pd(bk + i), _mm256_loadu_pd(xl + i), a0);
      const __m128d t = _mm_add_pd(_mm256_castpd256_pd128(a0), _mm256_extractf128_pd(a0, 1));
      double dot = _mm_cvtsd_f64(_mm_add_sd(t, _mm_unpackhi_pd(t, t)));
      for (; i < n; ++i) dot += bk[i] * xl[i];
      s += dot * dot;
    }
  }
  return s;
}

__attribute__((target("avx2,fma"))) double dot_f32_avx2(const float* a, const float* b,
                                                        std::size_t n) noexcept {
  __m256 a0 = _mm256_setzero_ps();
  std::size_t i = 0;
  for (; i + 8 <= n; i += 8) a0 = _mm256_fmadd_ps(_mm256_loadu_ps(a + i), _mm256_loadu_ps(b + i), a0);
  double dot = hsum8(a0);
  for (; i < n; ++i) dot += static_cast<double>(a[i]) * static_cast<double>(b[i]);
  return dot;
}

__attribute__((target("avx2,fma"))) double dot_f64_avx2(const double* a, const double* b,
                                                        std::size_t n) noexcept {
  __m256d a0 = _mm256_setzero_pd(), a1 = _mm256_setzero_pd();
  std::size_t i = 0;
  for (; i + 8 <= n; i += 8) {
    a0 = _mm256_fmadd_pd(_mm256_loadu_pd(a + i), _mm256_loadu_pd(b + i), a0);
    a1 = _mm256_fmadd_pd(_mm256_loadu_pd(a + i + 4), _mm256_loadu_pd(b + i + 4), a1);
  }
  a0 = _mm256_add_pd(a0, a1);
  const __m128d t = _mm_add_pd(_mm256_castpd256_pd128(a0), _mm256_extractf128_pd(a0, 1));
  double dot = _mm_cvtsd_f64(_mm_add_sd(t, _mm_unpackhi_pd(t, t)));
  for (; i < n; ++i) dot += a[i] * b[i];
  return dot;
}

bool cpu_has_avx2_fma() noexcept {
  __builtin_cpu_init();
  return __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
}
#endif

bool use_simd() noexcept {
#ifdef ESKIN_MODEL_X86_DISPATCH
  static const bool ok = [] {
    const char* env = std::getenv("ESKIN_KERNEL_ISA");
    return cpu_has_avx2_fma() && !(env != nullptr && std::strcmp(env, "generic") == 0);
  }();
  return ok;
#else
  return false;
#endif
}

}  // namespace

OverlapF32 select_overlap_f32() noexcept {
#if defined(ESKIN_DEVICE)
  return &overlap_f32_tiled;
#endif
#ifdef ESKIN_MODEL_X86_DISPATCH
  if (use_simd()) return &overlap_f32_avx2;
#endif
  return &overlap_f32_generic;
}

#if !defined(ESKIN_DEVICE)
namespace {
void overlaps_f32_generic(const float* bases, std::size_t block, const std::uint32_t* sv,
                          std::size_t count, const float* x, std::size_t n, std::size_t alpha,
                          double* out) noexcept {
  for (std::size_t t = 0; t < count; ++t)
    out[t] = overlap_f32_generic(bases + sv[t] * block, x, n, alpha);
}
}  // namespace

OverlapsF32 select_overlaps_f32() noexcept {
#ifdef ESKIN_MODEL_X86_DISPATCH
  if (use_simd()) return &overlaps_f32_avx2;
#endif
  return &overlaps_f32_generic;
}
#endif

OverlapF64 select_overlap_f64() noexcept {
#ifdef ESKIN_MODEL_X86_DISPATCH
  if (use_simd()) return &overlap_f64_avx2;
#endif
  return &overlap_f64_generic;
}

DotF32 select_dot_f32() noexcept {
#if defined(ESKIN_DEVICE)
  return &dot_f32_single;
#endif
#ifdef ESKIN_MODEL_X86_DISPATCH
  if (use_simd()) return &dot_f32_avx2;
#endif
  return &dot_f32_generic;
}

DotF64 select_dot_f64() noexcept {
#ifdef ESKIN_MODEL_X86_DISPATCH
  if (use_simd()) return &dot_f64_avx2;
#endif
  return &dot_f64_generic;
}

const char* overlap_kernel_name() noexcept {
#if defined(ESKIN_DEVICE)
  return "single";
#endif
  return use_simd() ? "avx2-fma" : "generic";
}

}  // namespace eskin::detail
