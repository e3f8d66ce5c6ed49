// Symmetric eigen-decomposition of kEigenLanes matrices at once (see batch_eigen.hpp).
#include "batch_eigen.hpp"

#include "tensor_kernel_tile.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

// The solver is written once for a GCC/Clang vector type V of W doubles (W lanes side by side)
// and instantiated for the widest registers the CPU has: W = 8 (one AVX-512 register), 4 (AVX2:
// the 8 lanes as two groups of 4) or 2 (SSE2 baseline: four groups); fewer matrices than lanes
// take narrower groups. The memory layout is the same for all (lane stride kEigenLanes).
// Run-time dispatch, as for the pairwise tile kernels: function-level target attributes, no -m
// flag. A lane's arithmetic does not depend on the other lanes of its group (a converged lane is
// frozen by masks), and this file is compiled without FMA contraction (-ffp-contract=off, see
// CMakeLists.txt): every lane operation is one correctly rounded IEEE operation, so the results
// are the same bits whatever the grouping and the instruction set.

#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC diagnostic ignored "-Wpsabi"  // vector arguments of inlined helpers: no ABI crosses
#endif

namespace eskin {

namespace {

constexpr std::size_t L = kEigenLanes;  // lane stride in memory

typedef double v8d __attribute__((vector_size(64)));
typedef double v4d __attribute__((vector_size(32)));
typedef double v2d __attribute__((vector_size(16)));
// the same vectors, aligned like a double and allowed to alias doubles: loads and stores of lane
// groups straight from the caller's double arrays
typedef double v8d_mem __attribute__((vector_size(64), aligned(8), may_alias));
typedef double v4d_mem __attribute__((vector_size(32), aligned(8), may_alias));
typedef double v2d_mem __attribute__((vector_size(16), aligned(8), may_alias));
template <class V>
struct Mem;
template <>
struct Mem<v8d> {
  using type = v8d_mem;
};
template <>
struct Mem<v4d> {
  using type = v4d_mem;
};
template <>
struct Mem<v2d> {
  using type = v2d_mem;
};


template <class V>
using mask_t = decltype(V{} < V{});
template <class V>
constexpr std::size_t width = sizeof(V) / sizeof(double);

#define ESKIN_INLINE inline __attribute__((always_inline))

template <class V>
ESKIN_INLINE V ld(const double* p) noexcept {
  return *reinterpret_cast<const typename Mem<V>::type*>(p);
}
template <class V>
ESKIN_INLINE void st(double* p, V v) noexcept {
  *reinterpret_cast<typename Mem<V>::type*>(p) = v;
}
template <class V>
ESKIN_INLINE V splat(double x) noexcept {
  return V{} + x;
}
// m ? a : b, lane by lane (m: all ones or all zeros per lane)
template <class V>
ESKIN_INLINE V sel(mask_t<V> m, V a, V b) noexcept {
  return m ? a : b;  // GCC/Clang vector conditional: one blend
}
template <class V>
ESKIN_INLINE V vabs(V v) noexcept {
  using M = mask_t<V>;
  return (V)((M)v & (M{} + std::numeric_limits<long long>::max()));
}
template <class V>
ESKIN_INLINE V vmax(V a, V b) noexcept {
  return sel<V>(a > b, a, b);
}
template <class V>
ESKIN_INLINE V vsqrt(V v) noexcept {
  V r;
  for (std::size_t i = 0; i < width<V>; ++i) r[i] = __builtin_sqrt(v[i]);
  return r;
}
template <class M>
ESKIN_INLINE unsigned bits(M m) noexcept {
  unsigned b = 0;
  for (std::size_t i = 0; i < sizeof(M) / sizeof(long long); ++i) b |= unsigned(m[i] != 0) << i;
  return b;
}
template <class V>
ESKIN_INLINE mask_t<V> finite(V v) noexcept {
  return vabs(v) <= splat<V>(std::numeric_limits<double>::max());
}

// Householder reduction to tridiagonal form. `a` (n x n per lane, COLUMN-major: entry (r, c) at
// (c * n + r) * L) holds the symmetric matrices; on exit the accumulated transformation, d the
// diagonal, e the subdiagonal (e[0] = 0). A lane whose remaining column is zero takes the
// EISPACK "scale == 0" branch; here the same values come out of the general branch with the
// divisors replaced by 1 on that lane.
template <class V>
ESKIN_INLINE void tred2(std::size_t n, double* a, double* d, double* e) noexcept {
  auto at = [a, n](std::size_t r, std::size_t c) { return a + (c * n + r) * L; };
  const V one = splat<V>(1.0), zero = splat<V>(0.0);
  for (std::size_t j = 0; j < n; ++j) st(d + j * L, ld<V>(at(n - 1, j)));
  for (std::size_t i = n - 1; i > 0; --i) {
    V scale = zero, h = zero;
    for (std::size_t k = 0; k < i; ++k) scale += vabs(ld<V>(d + k * L));
    const mask_t<V> null = scale == zero;
    scale = sel(null, one, scale);
    for (std::size_t k = 0; k < i; ++k) {
      const V dk = ld<V>(d + k * L) / scale;
      st(d + k * L, dk);
      h += dk * dk;
    }
    V f = ld<V>(d + (i - 1) * L);
    V g = vsqrt(h);
    g = sel(f > zero, -g, g);
    st(e + i * L, scale * g);
    h -= f * g;
    st(d + (i - 1) * L, f - g);
    const V hs = sel(null, one, h);
    for (std::size_t j = 0; j < i; ++j) st(e + j * L, zero);
    for (std::size_t j = 0; j < i; ++j) {
      f = ld<V>(d + j * L);
      st(at(j, i), f);
      g = ld<V>(e + j * L) + ld<V>(at(j, j)) * f;
      for (std::size_t k = j + 1; k < i; ++k) {
        const V vkj = ld<V>(at(k, j));
        g += vkj * ld<V>(d + k * L);
        st(e + k * L, ld<V>(e + k * L) + vkj * f);
      }
      st(e + j * L, g);
    }
    f = zero;
    for (std::size_t j = 0; j < i; ++j) {
      const V ej = ld<V>(e + j * L) / hs;
      st(e + j * L, ej);
      f += ej * ld<V>(d + j * L);
    }
    const V hh = f / (hs + hs);
    for (std::size_t j = 0; j < i; ++j) st(e + j * L, ld<V>(e + j * L) - hh * ld<V>(d + j * L));
    for (std::size_t j = 0; j < i; ++j) {
      f = ld<V>(d + j * L);
      g = ld<V>(e + j * L);
      for (std::size_t k = j; k < i; ++k)
        st(at(k, j), ld<V>(at(k, j)) - (f * ld<V>(e + k * L) + g * ld<V>(d + k * L)));
      st(d + j * L, ld<V>(at(i - 1, j)));
      st(at(i, j), zero);
    }
    st(d + i * L, h);
  }
  // accumulate the transformations
  for (std::size_t i = 0; i + 1 < n; ++i) {
    st(at(n - 1, i), ld<V>(at(i, i)));
    st(at(i, i), one);
    const V h = ld<V>(d + (i + 1) * L);
    const mask_t<V> nz = h != zero;
    const V hs = sel(nz, h, one);
    for (std::size_t k = 0; k <= i; ++k) st(d + k * L, sel(nz, ld<V>(at(k, i + 1)) / hs, zero));
    // columns j two at a time: two independent dot-product chains
    std::size_t j = 0;
    for (; j + 2 <= i + 1; j += 2) {
      V g0 = zero, g1 = zero;
      for (std::size_t k = 0; k <= i; ++k) {
        const V u = ld<V>(at(k, i + 1));
        g0 += u * ld<V>(at(k, j));
        g1 += u * ld<V>(at(k, j + 1));
      }
      for (std::size_t k = 0; k <= i; ++k) {
        const V dk = ld<V>(d + k * L);
        st(at(k, j), ld<V>(at(k, j)) - g0 * dk);
        st(at(k, j + 1), ld<V>(at(k, j + 1)) - g1 * dk);
      }
    }
    for (; j <= i; ++j) {
      V g = zero;
      for (std::size_t k = 0; k <= i; ++k) g += ld<V>(at(k, i + 1)) * ld<V>(at(k, j));
      for (std::size_t k = 0; k <= i; ++k) st(at(k, j), ld<V>(at(k, j)) - g * ld<V>(d + k * L));
    }
    for (std::size_t k = 0; k <= i; ++k) st(at(k, i + 1), zero);
  }
  for (std::size_t j = 0; j < n; ++j) {
    st(d + j * L, ld<V>(at(n - 1, j)));
    st(at(n - 1, j), zero);
  }
  st(at(n - 1, n - 1), one);
  st(e, zero);
}

// Apply the rotations of one QL sweep, (c[ii], s[ii]) for ii = n-2 down to l acting on rows ii
// and ii+1 of `a` (row-major, n x n per lane), in that order. Component by component, four at
// a time, the row being rotated stays in registers from one rotation to the next: every entry is
// loaded and stored once per sweep (rotating whole rows instead reloads each row right after
// storing it).
template <class V>
ESKIN_INLINE void rotate_rows(std::size_t n, std::size_t l, double* a, const double* rc,
                              const double* rs) noexcept {
  const std::size_t m = n - 1;
  std::size_t k = 0;
  for (; k + 4 <= n; k += 4) {
    double* col = a + k * L;
    V y0 = ld<V>(col + m * n * L), y1 = ld<V>(col + (m * n + 1) * L), y2 = ld<V>(col + (m * n + 2) * L),
       y3 = ld<V>(col + (m * n + 3) * L);
    for (std::size_t ii = m; ii-- > l;) {
      const V c = ld<V>(rc + ii * L), s = ld<V>(rs + ii * L);
      double* r0 = col + ii * n * L;
      double* r1 = r0 + n * L;
      const V x0 = ld<V>(r0), x1 = ld<V>(r0 + L), x2 = ld<V>(r0 + 2 * L), x3 = ld<V>(r0 + 3 * L);
      st(r1, s * x0 + c * y0);
      st(r1 + L, s * x1 + c * y1);
      st(r1 + 2 * L, s * x2 + c * y2);
      st(r1 + 3 * L, s * x3 + c * y3);
      y0 = c * x0 - s * y0;
      y1 = c * x1 - s * y1;
      y2 = c * x2 - s * y2;
      y3 = c * x3 - s * y3;
    }
    double* rl = col + l * n * L;
    st(rl, y0);
    st(rl + L, y1);
    st(rl + 2 * L, y2);
    st(rl + 3 * L, y3);
  }
  for (; k < n; ++k) {
    double* col = a + k * L;
    V y = ld<V>(col + m * n * L);
    for (std::size_t ii = m; ii-- > l;) {
      const V c = ld<V>(rc + ii * L), s = ld<V>(rs + ii * L);
      const V x = ld<V>(col + ii * n * L);
      st(col + (ii + 1) * n * L, s * x + c * y);
      y = c * x - s * y;
    }
    st(col + l * n * L, y);
  }
}

// Implicit QL on the tridiagonal (d, e) of tred2, rotating the rows of `a` (row-major view of
// tred2's column-major transformation). Returns the mask of failed lanes. rc, rs_: scratch of
// n * L each (a sweep's rotations). Lanes from `live` on are left alone.
//
// Each lane deflates at its own pace: lane w works on its own index l_w (EISPACK's l), and a
// sweep runs from the bottom up to the smallest l_w of the lanes still iterating; above its own
// l_w a lane's rotations are identities and its values are left alone. So a lane does exactly
// the sweeps it would do alone (no waiting for slower lanes at every l).
template <class V>
ESKIN_INLINE unsigned tql2(std::size_t n, double* a, double* d, double* e, double* rc,
                           double* rs_, std::size_t live) noexcept {
  constexpr std::size_t W = width<V>;
  using M = mask_t<V>;
  const V one = splat<V>(1.0), zero = splat<V>(0.0), two = splat<V>(2.0);
  const double eps = std::ldexp(1.0, -52);
  for (std::size_t i = 1; i < n; ++i) st(e + (i - 1) * L, ld<V>(e + i * L));
  st(e + (n - 1) * L, zero);
  // per-lane bookkeeping (scalar): deflation index, shift sum, EISPACK's tst1, iterations
  std::size_t lw[W];
  double f[W], tst1[W];
  int iters[W];
  bool done[W];
  unsigned failed = 0;
  for (std::size_t w = 0; w < W; ++w) {
    lw[w] = 0;
    f[w] = 0.0;
    tst1[w] = std::fabs(d[w]) + std::fabs(e[w]);
    iters[w] = 0;
    done[w] = w >= live;  // lanes past the live ones are never iterated
  }
  for (;;) {
    // lanes whose e[l] is negligible move on (d[l] += f, as EISPACK does when it leaves l)
    std::size_t lmin = n;
    V lv = zero, fv = zero;
    M act{};
    for (std::size_t w = 0; w < W; ++w) {
      if (done[w]) continue;
      std::size_t l = lw[w];
      while (l + 1 < n && std::fabs(e[l * L + w]) <= eps * tst1[w]) {
        d[l * L + w] += f[w];
        e[l * L + w] = 0.0;
        ++l;
        tst1[w] = std::max(tst1[w], std::fabs(d[l * L + w]) + std::fabs(e[l * L + w]));
        iters[w] = 0;
      }
      lw[w] = l;
      if (l + 1 == n) {
        d[l * L + w] += f[w];
        e[l * L + w] = 0.0;
        done[w] = true;
        continue;
      }
      if (++iters[w] > 100) {  // EISPACK's limit, per eigenvalue
        failed |= 1u << w;
        done[w] = true;
        continue;
      }
      act[w] = -1;
      lv[w] = double(l);
      fv[w] = f[w];
      lmin = std::min(lmin, l);
    }
    if (lmin == n) break;
    // one QL sweep for the active lanes: shift from the leading 2 x 2 block of each lane
    V g0 = zero, el = one, dl1_old = zero, el1 = zero;
    for (std::size_t w = 0; w < W; ++w)
      if (act[w]) {
        const std::size_t l = lw[w];
        g0[w] = d[l * L + w];
        el[w] = e[l * L + w];
        dl1_old[w] = d[(l + 1) * L + w];
        el1[w] = e[(l + 1) * L + w];
      }
    V p = (dl1_old - g0) / (two * el);
    V r = vsqrt(p * p + one);
    r = sel(p < zero, -r, r);
    const V dl = sel(act, el / (p + r), g0);
    const V dl1 = sel(act, el * (p + r), dl1_old);
    const V h0 = sel(act, g0 - dl, zero);
    for (std::size_t w = 0; w < W; ++w)
      if (act[w]) {
        const std::size_t l = lw[w];
        d[l * L + w] = dl[w];
        d[(l + 1) * L + w] = dl1[w];
      }
    for (std::size_t i = lmin + 2; i < n; ++i) {
      const M below = act & (splat<V>(double(i)) >= lv + two);  // i >= l + 2
      st(d + i * L, sel(below, ld<V>(d + i * L) - h0, ld<V>(d + i * L)));
    }
    fv += h0;
    for (std::size_t w = 0; w < W; ++w)
      if (act[w]) f[w] = fv[w];
    // chase from the bottom (no split search: see batch_eigen.hpp)
    p = ld<V>(d + (n - 1) * L);
    V c = one, c2 = one, c3 = one, s = zero, s2 = zero;
    for (std::size_t ii = n - 1; ii-- > lmin;) {
      const M on = act & (splat<V>(double(ii)) >= lv);  // this lane still rotates at ii
      c3 = sel(on, c2, c3);
      c2 = sel(on, c, c2);
      s2 = sel(on, s, s2);
      const V ei = ld<V>(e + ii * L), di = ld<V>(d + ii * L);
      const V g = c * ei;
      const V h = c * p;
      r = vsqrt(p * p + ei * ei);
      st(e + (ii + 1) * L, sel(on, s * r, ld<V>(e + (ii + 1) * L)));
      const M keep = on & (r != zero);  // r == 0: p = e = 0, identity rotation
      const V inv = one / sel(keep, r, one);
      const V sn = sel(keep, ei * inv, zero), cn = sel(keep, p * inv, one);
      s = sel(on, sn, s);
      c = sel(on, cn, c);
      p = sel(on, cn * di - sn * g, p);
      st(d + (ii + 1) * L, sel(on, h + sn * (cn * g + sn * di), ld<V>(d + (ii + 1) * L)));
      st(rc + ii * L, cn);
      st(rs_ + ii * L, sn);
    }
    rotate_rows<V>(n, lmin, a, rc, rs_);
    V el_now = one;
    for (std::size_t w = 0; w < W; ++w)
      if (act[w]) el_now[w] = e[lw[w] * L + w];
    p = -s * s2 * c3 * el1 * el_now / sel(act, dl1, one);
    const V new_e = s * p, new_d = c * p;
    const M bad = act & ~(finite(new_e) & finite(new_d));
    for (std::size_t w = 0; w < W; ++w)
      if (act[w]) {
        const std::size_t l = lw[w];
        e[l * L + w] = new_e[w];
        d[l * L + w] = new_d[w];
        if (bad[w]) {
          failed |= 1u << w;
          done[w] = true;
        }
      }
  }
  return failed;
}

// One group of width<V> lanes starting at lane `o`, of which the first `live` hold matrices
// (the others hold anything and are never iterated); returns the live lanes' failure bits
// shifted to o.
template <class V>
ESKIN_INLINE unsigned solve_group(std::size_t n, double* a, double* d, double* e, std::size_t o,
                                  std::size_t live) noexcept {
  a += o;
  d += o;
  e += o;
  tred2<V>(n, a, d, e);
  unsigned failed = tql2<V>(n, a, d, e, e + n * L, e + 2 * n * L, live);
  // a non-finite value the QL iteration never meets (n = 1, or an infinity that makes every
  // off-diagonal entry look negligible) must still fail its lane: check the results themselves
  mask_t<V> ok = finite(ld<V>(d));
  for (std::size_t j = 1; j < n; ++j) ok &= finite(ld<V>(d + j * L));
  for (std::size_t i = 0; i < n * n; ++i) ok &= finite(ld<V>(a + i * L));
  failed |= bits(~ok);
  return (failed & ((1u << live) - 1u)) << o;
}

// The group of lanes [o, o + W) with the lanes from `used` on left out.
template <class V>
ESKIN_INLINE unsigned solve_group_of(std::size_t n, double* a, double* d, double* e,
                                     std::size_t o, std::size_t used) noexcept {
  return solve_group<V>(n, a, d, e, o, std::min(width<V>, used - o));
}

// `used`: lanes 0..used-1 hold matrices; the groups past them are skipped (a single pattern
// costs one narrow group, not eight lanes' work).
unsigned solve_sse2(std::size_t n, double* a, double* d, double* e, std::size_t used) noexcept {
  unsigned f = 0;
  for (std::size_t o = 0; o < used; o += 2) f |= solve_group_of<v2d>(n, a, d, e, o, used);
  return f;
}

#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__)
#define ESKIN_EIGEN_DISPATCH 1
__attribute__((target("arch=x86-64-v3"))) unsigned solve_avx2(std::size_t n, double* a,
                                                              double* d, double* e,
                                                              std::size_t used) noexcept {
  if (used <= 2) return solve_group_of<v2d>(n, a, d, e, 0, used);
  unsigned f = solve_group_of<v4d>(n, a, d, e, 0, used);
  if (used > 4) f |= solve_group_of<v4d>(n, a, d, e, 4, used);
  return f;
}

__attribute__((target("arch=x86-64-v4"))) unsigned solve_avx512(std::size_t n, double* a,
                                                                double* d, double* e,
                                                                std::size_t used) noexcept {
  if (used <= 2) return solve_group_of<v2d>(n, a, d, e, 0, used);
  if (used <= 4) return solve_group_of<v4d>(n, a, d, e, 0, used);
  return solve_group_of<v8d>(n, a, d, e, 0, used);
}

#endif

}  // namespace

unsigned batch_symmetric_eigen(std::size_t n, double* a, double* d, double* e, int level,
                               std::size_t used) noexcept {
  if (n == 0 || used == 0) return 0;
  if (used > L) used = L;
#ifdef ESKIN_EIGEN_DISPATCH
  const int best = isa_level();
  if (level < 0 || level > best) level = best;
  if (level == 2) return solve_avx512(n, a, d, e, used);
  if (level == 1) return solve_avx2(n, a, d, e, used);
#else
  (void)level;
#endif
  return solve_sse2(n, a, d, e, used);
}

}  // namespace eskin
