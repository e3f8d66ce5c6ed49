// Private to the core: the per-pattern subspace bases of the tensor kernel (tensor_kernel.hpp) in
// a chosen scalar type, for one pattern at a time, with a cyclic Jacobi eigen-solver. The device
// build (ESKIN_DEVICE) classifies with ScalarBases<float>: a Cortex-M4F computes in single
// precision in hardware (double precision is emulated in software, tens of instructions per
// operation), and its workspace is a few kilobytes where BasisWorkspace keeps eight lanes.
//
// Same conventions as BasisWorkspace: mode-z unfolding with the remaining indices in C order; the
// first alpha_z right-singular vectors of the unfolding as an N_z x alpha_z column-major block;
// columns beyond the numerical rank exactly zero; each column's largest-magnitude entry (the
// first on ties) positive. Differences, which the float32 parity test bounds (docs/mcu.md): the
// arithmetic is Real's, and the numerical rank counts the Gram eigenvalues above
// tau = max(1e-12, 16 * n * eps_Real) times the largest one (n the Gram matrix's size), the level
// below which a Gram eigenvalue in precision Real is rounding noise.
//
// The constructor allocates; compute() neither allocates nor throws.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <limits>
#include <vector>

#include "eskin/tensor_kernel.hpp"

namespace eskin::detail {

/// Eigen-decomposition of the symmetric n x n matrix `a` (row-major, overwritten) by cyclic
/// Jacobi rotations: on return the diagonal of `a` holds the eigenvalues and row j of `v` the
/// unit eigenvector of a[j * n + j]. Returns false if 50 sweeps did not converge.
template <class Real>
bool jacobi_eigen(std::size_t n, Real* a, Real* v) noexcept {
  for (std::size_t i = 0; i < n * n; ++i) v[i] = Real(0);
  for (std::size_t i = 0; i < n; ++i) v[i * n + i] = Real(1);
  Real total = 0;
  for (std::size_t i = 0; i < n * n; ++i) total += a[i] * a[i];
  const Real eps = std::numeric_limits<Real>::epsilon();
  for (int sweep = 0; sweep < 50; ++sweep) {
    Real off = 0;
    for (std::size_t p = 0; p < n; ++p)
      for (std::size_t q = p + 1; q < n; ++q) off += a[p * n + q] * a[p * n + q];
    if (!(off > eps * eps * total * Real(0.25))) return std::isfinite(off);
    for (std::size_t p = 0; p + 1 < n; ++p)
      for (std::size_t q = p + 1; q < n; ++q) {
        const Real apq = a[p * n + q];
        if (apq == Real(0)) continue;
        const Real theta = (a[q * n + q] - a[p * n + p]) / (Real(2) * apq);
        const Real t = (theta >= 0 ? Real(1) : Real(-1)) /
                       (std::fabs(theta) + std::sqrt(theta * theta + Real(1)));
        const Real c = Real(1) / std::sqrt(t * t + Real(1)), s = t * c;
        // A <- J^T A J on rows and columns p, q
        for (std::size_t k = 0; k < n; ++k) {
          const Real akp = a[k * n + p], akq = a[k * n + q];
          a[k * n + p] = c * akp - s * akq;
          a[k * n + q] = s * akp + c * akq;
        }
        for (std::size_t k = 0; k < n; ++k) {
          const Real apk = a[p * n + k], aqk = a[q * n + k];
          a[p * n + k] = c * apk - s * aqk;
          a[q * n + k] = s * apk + c * aqk;
        }
        Real* vp = v + p * n;
        Real* vq = v + q * n;
        for (std::size_t k = 0; k < n; ++k) {
          const Real x = vp[k], y = vq[k];
          vp[k] = c * x - s * y;
          vq[k] = s * x + c * y;
        }
      }
  }
  return false;
}

template <class Real>
class ScalarBases {
 public:
  explicit ScalarBases(const BasisLayout& layout) : layout_(layout) {
    std::size_t q = 1, n = 1;
    for (std::size_t z = 0; z < layout_.n_modes(); ++z) {
      q = std::max(q, layout_.q(z));
      n = std::max(n, layout_.cols(z));
    }
    x_.assign(layout_.tensor_size(), Real(0));
    g_.assign(q * q, Real(0));
    v_.assign(q * q, Real(0));
    order_.assign(q, 0);
    col_.assign(n, Real(0));
  }
  const BasisLayout& layout() const noexcept { return layout_; }

  /// Bases of the C-order pattern `x` (tensor_size() values) into `bases` (bases_size(), layout
  /// of BasisLayout) and `ranks` (one per mode). On failure the outputs are zero-filled.
  template <class In, class Out>
  KernelStatus compute(const In* x, Out* bases, int* ranks) noexcept {
    if (x == nullptr || bases == nullptr || ranks == nullptr) return KernelStatus::bad_argument;
    const std::size_t size = layout_.tensor_size();
    Real amax = 0;
    for (std::size_t i = 0; i < size; ++i) {
      const Real v = static_cast<Real>(x[i]);
      if (!std::isfinite(v)) return fail(bases, ranks, KernelStatus::not_finite);
      amax = std::max(amax, std::fabs(v));
    }
    if (amax == Real(0)) return fail(bases, ranks, KernelStatus::ok);  // rank 0 everywhere
    const Real inv = Real(1) / amax;
    for (std::size_t i = 0; i < size; ++i) x_[i] = static_cast<Real>(x[i]) * inv;
    for (std::size_t z = 0; z < layout_.n_modes(); ++z) {
      if (!mode(z, bases + layout_.offset(z), ranks + z))
        return fail(bases, ranks, KernelStatus::no_convergence);
    }
    return KernelStatus::ok;
  }

 private:
  template <class Out>
  KernelStatus fail(Out* bases, int* ranks, KernelStatus st) noexcept {
    std::fill(bases, bases + layout_.bases_size(), Out(0));
    std::fill(ranks, ranks + layout_.n_modes(), 0);
    return st;
  }

  // The tensor viewed as (before, m, after): unfolding entry (i, j = p * after + s).
  template <class Out>
  bool mode(std::size_t z, Out* out, int* rank) noexcept {
    const std::size_t m = layout_.rows(z), n = layout_.cols(z), q = layout_.q(z),
                      alpha = layout_.alpha(z);
    std::size_t before = 1;
    for (std::size_t k = 0; k < z; ++k) before *= layout_.dim(k);
    const std::size_t after = n / before;
    const Real* x = x_.data();
    Real* g = g_.data();
    if (m <= n) {  // G = A A^T (m x m)
      for (std::size_t i = 0; i < m; ++i)
        for (std::size_t k = 0; k <= i; ++k) {
          Real acc = 0;
          for (std::size_t p = 0; p < before; ++p) {
            const Real* xi = x + (p * m + i) * after;
            const Real* xk = x + (p * m + k) * after;
            for (std::size_t s = 0; s < after; ++s) acc += xi[s] * xk[s];
          }
          g[i * m + k] = g[k * m + i] = acc;
        }
    } else {  // G = A^T A (n x n); column j = (p, s) has entries x[(p * m + i) * after + s]
      for (std::size_t j = 0; j < n; ++j)
        for (std::size_t l = 0; l <= j; ++l) {
          const Real* xj = x + (j / after) * m * after + j % after;
          const Real* xl = x + (l / after) * m * after + l % after;
          Real acc = 0;
          for (std::size_t i = 0; i < m; ++i) acc += xj[i * after] * xl[i * after];
          g[j * n + l] = g[l * n + j] = acc;
        }
    }
    Real* v = v_.data();
    if (!jacobi_eigen(q, g, v)) return false;
    // eigenvalues descending (stable: the first index on ties)
    // (insertion sort: std::stable_sort may allocate a buffer)
    for (std::size_t i = 0; i < q; ++i) {
      std::size_t j = i;
      for (; j > 0 && g[order_[j - 1] * q + order_[j - 1]] < g[i * q + i]; --j) order_[j] = order_[j - 1];
      order_[j] = i;
    }
    const Real lmax = std::max(Real(0), g[order_[0] * q + order_[0]]);
    const Real tau = std::max(Real(1e-12), Real(16) * Real(q) * std::numeric_limits<Real>::epsilon());
    std::size_t r = 0;
    while (r < q && lmax > 0 && g[order_[r] * q + order_[r]] > tau * lmax) ++r;
    const std::size_t k = std::min(alpha, r);
    Real* col = col_.data();
    for (std::size_t c = 0; c < k; ++c) {
      const Real* u = v + order_[c] * q;
      if (m > n) {
        for (std::size_t j = 0; j < n; ++j) col[j] = u[j];
      } else {  // v_c = A^T u_c / s_c, then orthogonalised against the previous columns
        const Real inv_s = Real(1) / std::sqrt(g[order_[c] * q + order_[c]]);
        for (std::size_t p = 0; p < before; ++p)
          for (std::size_t s = 0; s < after; ++s) {
            Real acc = 0;
            for (std::size_t i = 0; i < m; ++i) acc += u[i] * x[(p * m + i) * after + s];
            col[p * after + s] = acc * inv_s;
          }
        for (int pass = 0; pass < 2; ++pass) {
          for (std::size_t b = 0; b < c; ++b) {
            Real dt = 0;
            for (std::size_t j = 0; j < n; ++j) dt += col[j] * static_cast<Real>(out[b * n + j]);
            for (std::size_t j = 0; j < n; ++j) col[j] -= dt * static_cast<Real>(out[b * n + j]);
          }
          Real nrm = 0;
          for (std::size_t j = 0; j < n; ++j) nrm += col[j] * col[j];
          nrm = std::sqrt(nrm);
          if (!(nrm > 0)) return false;
          for (std::size_t j = 0; j < n; ++j) col[j] /= nrm;
        }
      }
      std::size_t big = 0;
      for (std::size_t j = 1; j < n; ++j)
        if (std::fabs(col[j]) > std::fabs(col[big])) big = j;
      const Real sign = col[big] < 0 ? Real(-1) : Real(1);
      for (std::size_t j = 0; j < n; ++j) out[c * n + j] = static_cast<Out>(sign * col[j]);
    }
    std::fill(out + k * n, out + alpha * n, Out(0));
    *rank = static_cast<int>(k);
    return true;
  }

  BasisLayout layout_;
  std::vector<Real> x_, g_, v_, col_;
  std::vector<std::size_t> order_;
};

}  // namespace eskin::detail
