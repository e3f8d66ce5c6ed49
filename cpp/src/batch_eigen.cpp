// Symmetric eigen-decomposition of kEigenLanes matrices at once (see batch_eigen.hpp).
#include "batch_eigen.hpp"

#include <cmath>
#include <limits>

// The lane type is a GCC/Clang vector of kEigenLanes doubles; each operation acts on all lanes.
// On x86-64 Linux with GCC the solver is compiled three times (function multi-versioning: an
// x86-64-v4 = AVX-512 clone, where a lane group is one register, an x86-64-v3 = AVX2+FMA clone
// and the baseline one), and the loader picks one for the CPU; no -m flag anywhere. Within one clone every lane runs the same instructions, so lanes agree bit for
// bit with each other.
#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && defined(__linux__)
#define ESKIN_EIGEN_CLONES __attribute__((target_clones("arch=x86-64-v4", "arch=x86-64-v3", "default")))
#else
#define ESKIN_EIGEN_CLONES
#endif

#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC diagnostic ignored "-Wpsabi"  // vector arguments of inlined helpers: no ABI crosses
#endif

namespace eskin {

namespace {

constexpr std::size_t L = kEigenLanes;
static_assert(L == 8, "the lane type below holds 8 doubles");

typedef double vd __attribute__((vector_size(L * sizeof(double))));
typedef long long vm __attribute__((vector_size(L * sizeof(long long))));

#define ESKIN_INLINE inline __attribute__((always_inline))

// the same vector, aligned like a double and allowed to alias doubles: loads and stores of lane
// groups straight from the caller's double arrays
typedef double vd_mem __attribute__((vector_size(L * sizeof(double)), aligned(8), may_alias));

ESKIN_INLINE vd ld(const double* p) noexcept { return *reinterpret_cast<const vd_mem*>(p); }
ESKIN_INLINE void st(double* p, vd v) noexcept { *reinterpret_cast<vd_mem*>(p) = v; }
ESKIN_INLINE vd splat(double x) noexcept { return vd{} + x; }
// m ? a : b, lane by lane (m: all ones or all zeros per lane)
ESKIN_INLINE vd sel(vm m, vd a, vd b) noexcept { return (vd)(((vm)a & m) | ((vm)b & ~m)); }
ESKIN_INLINE vd vabs(vd v) noexcept {
  return (vd)((vm)v & (vm{} + std::numeric_limits<long long>::max()));
}
ESKIN_INLINE vd vmax(vd a, vd b) noexcept { return sel(a > b, a, b); }
ESKIN_INLINE vd vsqrt(vd v) noexcept {
  vd r;
  for (std::size_t i = 0; i < L; ++i) r[i] = __builtin_sqrt(v[i]);
  return r;
}
ESKIN_INLINE unsigned bits(vm m) noexcept {
  unsigned b = 0;
  for (std::size_t i = 0; i < L; ++i) b |= unsigned(m[i] != 0) << i;
  return b;
}
ESKIN_INLINE vm finite(vd v) noexcept { return vabs(v) <= splat(std::numeric_limits<double>::max()); }

// Householder reduction to tridiagonal form. `a` (n x n per lane, COLUMN-major: entry (r, c) at
// (c * n + r) * L) holds the symmetric matrices; on exit the accumulated transformation, d the
// diagonal, e the subdiagonal (e[0] = 0). A lane whose remaining column is zero takes the
// EISPACK "scale == 0" branch; here the same values come out of the general branch with the
// divisors replaced by 1 on that lane.
ESKIN_INLINE void tred2(std::size_t n, double* a, double* d, double* e) noexcept {
  auto V = [a, n](std::size_t r, std::size_t c) { return a + (c * n + r) * L; };
  const vd one = splat(1.0), zero = splat(0.0);
  for (std::size_t j = 0; j < n; ++j) st(d + j * L, ld(V(n - 1, j)));
  for (std::size_t i = n - 1; i > 0; --i) {
    vd scale = zero, h = zero;
    for (std::size_t k = 0; k < i; ++k) scale += vabs(ld(d + k * L));
    const vm null = scale == zero;
    scale = sel(null, one, scale);
    for (std::size_t k = 0; k < i; ++k) {
      const vd dk = ld(d + k * L) / scale;
      st(d + k * L, dk);
      h += dk * dk;
    }
    vd f = ld(d + (i - 1) * L);
    vd g = vsqrt(h);
    g = sel(f > zero, -g, g);
    st(e + i * L, scale * g);
    h -= f * g;
    st(d + (i - 1) * L, f - g);
    const vd hs = sel(null, one, h);
    for (std::size_t j = 0; j < i; ++j) st(e + j * L, zero);
    for (std::size_t j = 0; j < i; ++j) {
      f = ld(d + j * L);
      st(V(j, i), f);
      g = ld(e + j * L) + ld(V(j, j)) * f;
      for (std::size_t k = j + 1; k < i; ++k) {
        const vd vkj = ld(V(k, j));
        g += vkj * ld(d + k * L);
        st(e + k * L, ld(e + k * L) + vkj * f);
      }
      st(e + j * L, g);
    }
    f = zero;
    for (std::size_t j = 0; j < i; ++j) {
      const vd ej = ld(e + j * L) / hs;
      st(e + j * L, ej);
      f += ej * ld(d + j * L);
    }
    const vd hh = f / (hs + hs);
    for (std::size_t j = 0; j < i; ++j) st(e + j * L, ld(e + j * L) - hh * ld(d + j * L));
    for (std::size_t j = 0; j < i; ++j) {
      f = ld(d + j * L);
      g = ld(e + j * L);
      for (std::size_t k = j; k < i; ++k)
        st(V(k, j), ld(V(k, j)) - (f * ld(e + k * L) + g * ld(d + k * L)));
      st(d + j * L, ld(V(i - 1, j)));
      st(V(i, j), zero);
    }
    st(d + i * L, h);
  }
  // accumulate the transformations
  for (std::size_t i = 0; i + 1 < n; ++i) {
    st(V(n - 1, i), ld(V(i, i)));
    st(V(i, i), one);
    const vd h = ld(d + (i + 1) * L);
    const vm nz = h != zero;
    const vd hs = sel(nz, h, one);
    for (std::size_t k = 0; k <= i; ++k) st(d + k * L, sel(nz, ld(V(k, i + 1)) / hs, zero));
    // columns j two at a time: two independent dot-product chains
    std::size_t j = 0;
    for (; j + 2 <= i + 1; j += 2) {
      vd g0 = zero, g1 = zero;
      for (std::size_t k = 0; k <= i; ++k) {
        const vd u = ld(V(k, i + 1));
        g0 += u * ld(V(k, j));
        g1 += u * ld(V(k, j + 1));
      }
      for (std::size_t k = 0; k <= i; ++k) {
        const vd dk = ld(d + k * L);
        st(V(k, j), ld(V(k, j)) - g0 * dk);
        st(V(k, j + 1), ld(V(k, j + 1)) - g1 * dk);
      }
    }
    for (; j <= i; ++j) {
      vd g = zero;
      for (std::size_t k = 0; k <= i; ++k) g += ld(V(k, i + 1)) * ld(V(k, j));
      for (std::size_t k = 0; k <= i; ++k) st(V(k, j), ld(V(k, j)) - g * ld(d + k * L));
    }
    for (std::size_t k = 0; k <= i; ++k) st(V(k, i + 1), zero);
  }
  for (std::size_t j = 0; j < n; ++j) {
    st(d + j * L, ld(V(n - 1, j)));
    st(V(n - 1, j), zero);
  }
  st(V(n - 1, n - 1), one);
  st(e, zero);
}

// Apply the rotations of one QL sweep, (c[ii], s[ii]) for ii = n-2 down to l acting on rows ii
// and ii+1 of `a` (row-major, n x n per lane), in that order. Component by component, four at
// a time, the row being rotated stays in registers from one rotation to the next: every entry is
// loaded and stored once per sweep (rotating whole rows instead reloads each row right after
// storing it).
ESKIN_INLINE void rotate_rows(std::size_t n, std::size_t l, double* a, const double* rc,
                              const double* rs) noexcept {
  const std::size_t m = n - 1;
  std::size_t k = 0;
  for (; k + 4 <= n; k += 4) {
    double* col = a + k * L;
    vd y0 = ld(col + m * n * L), y1 = ld(col + (m * n + 1) * L), y2 = ld(col + (m * n + 2) * L),
       y3 = ld(col + (m * n + 3) * L);
    for (std::size_t ii = m; ii-- > l;) {
      const vd c = ld(rc + ii * L), s = ld(rs + ii * L);
      double* r0 = col + ii * n * L;
      double* r1 = r0 + n * L;
      const vd x0 = ld(r0), x1 = ld(r0 + L), x2 = ld(r0 + 2 * L), x3 = ld(r0 + 3 * L);
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
    vd y = ld(col + m * n * L);
    for (std::size_t ii = m; ii-- > l;) {
      const vd c = ld(rc + ii * L), s = ld(rs + ii * L);
      const vd x = ld(col + ii * n * L);
      st(col + (ii + 1) * n * L, s * x + c * y);
      y = c * x - s * y;
    }
    st(col + l * n * L, y);
  }
}

// Implicit QL on the tridiagonal (d, e) of tred2, rotating the rows of `a` (row-major view of
// tred2's column-major transformation). Returns the mask of failed lanes. rc, rs_: scratch of
// n * L each (a sweep's rotations).
ESKIN_INLINE unsigned tql2(std::size_t n, double* a, double* d, double* e, double* rc,
                           double* rs_) noexcept {
  const vd one = splat(1.0), zero = splat(0.0), two = splat(2.0);
  const vd eps = splat(std::ldexp(1.0, -52));
  for (std::size_t i = 1; i < n; ++i) st(e + (i - 1) * L, ld(e + i * L));
  st(e + (n - 1) * L, zero);
  vd f = zero, tst1 = zero;
  unsigned failed = 0;
  for (std::size_t l = 0; l < n; ++l) {
    tst1 = vmax(tst1, vabs(ld(d + l * L)) + vabs(ld(e + l * L)));
    if (l + 1 < n) {
      vm act = vabs(ld(e + l * L)) > eps * tst1;
      int iter = 0;
      while (bits(act)) {
        if (++iter > 100) {
          failed |= bits(act);
          break;
        }
        // shift from the leading 2 x 2 block
        const vd g0 = ld(d + l * L), el = ld(e + l * L);
        const vd els = sel(act, el, one);
        vd p = (ld(d + (l + 1) * L) - g0) / (two * els);
        vd r = vsqrt(p * p + one);
        r = sel(p < zero, -r, r);
        const vd dl = sel(act, el / (p + r), g0);
        const vd dl1 = sel(act, el * (p + r), ld(d + (l + 1) * L));
        st(d + l * L, dl);
        st(d + (l + 1) * L, dl1);
        vd h = sel(act, g0 - dl, zero);
        for (std::size_t i = l + 2; i < n; ++i) st(d + i * L, ld(d + i * L) - h);
        f += h;
        // chase from the bottom (no split search: see batch_eigen.hpp)
        p = ld(d + (n - 1) * L);
        vd c = one, c2 = one, c3 = one, s = zero, s2 = zero;
        const vd el1 = ld(e + (l + 1) * L);
        for (std::size_t ii = n - 1; ii-- > l;) {
          c3 = c2;
          c2 = c;
          s2 = s;
          const vd ei = ld(e + ii * L), di = ld(d + ii * L);
          const vd g = c * ei;
          h = c * p;
          r = vsqrt(p * p + ei * ei);
          st(e + (ii + 1) * L, sel(act, s * r, ld(e + (ii + 1) * L)));
          const vm keep = act & (r != zero);  // r == 0: p = e = 0, identity rotation
          const vd inv = one / sel(keep, r, one);
          s = sel(keep, ei * inv, zero);
          c = sel(keep, p * inv, one);
          p = c * di - s * g;
          st(d + (ii + 1) * L, sel(act, h + s * (c * g + s * di), ld(d + (ii + 1) * L)));
          st(rc + ii * L, c);
          st(rs_ + ii * L, s);
        }
        rotate_rows(n, l, a, rc, rs_);
        p = -s * s2 * c3 * el1 * ld(e + l * L) / sel(act, dl1, one);
        const vd new_e = sel(act, s * p, ld(e + l * L));
        const vd new_d = sel(act, c * p, ld(d + l * L));
        st(e + l * L, new_e);
        st(d + l * L, new_d);
        const vm bad = act & ~(finite(new_e) & finite(new_d));
        failed |= bits(bad);
        act = act & ~bad & (vabs(new_e) > eps * tst1);
      }
    }
    st(d + l * L, ld(d + l * L) + f);
    st(e + l * L, zero);
  }
  return failed;
}

}  // namespace

ESKIN_EIGEN_CLONES unsigned batch_symmetric_eigen(std::size_t n, double* a, double* d,
                                                  double* e) noexcept {
  if (n == 0) return 0;
  tred2(n, a, d, e);
  unsigned failed = tql2(n, a, d, e, e + n * L, e + 2 * n * L);
  // a NaN never looks converged nor failing to converge: check the results themselves
  vm ok = finite(ld(d));
  for (std::size_t j = 1; j < n; ++j) ok &= finite(ld(d + j * L));
  for (std::size_t i = 0; i < n * n; ++i) ok &= finite(ld(a + i * L));
  return failed | (bits(~ok) & ((1u << L) - 1u));
}

}  // namespace eskin
