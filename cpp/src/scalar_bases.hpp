// Private to the core: the per-pattern subspace bases of the tensor kernel (tensor_kernel.hpp) in
// a chosen scalar type, for one pattern at a time. The device build (ESKIN_DEVICE) classifies with
// ScalarBases<float>: a Cortex-M4F computes in single precision in hardware (double precision is
// emulated in software, tens of instructions per operation), and this workspace is a few
// kilobytes where BasisWorkspace keeps eight lanes.
//
// Same conventions as BasisWorkspace: mode-z unfolding with the remaining indices in C order; the
// first alpha_z right-singular vectors of the unfolding as an N_z x alpha_z column-major block;
// columns beyond the numerical rank exactly zero; each column's largest-magnitude entry (the
// first on ties) positive. The method differs, for accuracy in single precision: the host squares
// the unfolding (Gram matrix, then its eigenvectors), which in float would blur every singular
// direction whose gap to the next is below ~1e-7 of the largest squared singular value. Here the
// thin side of the unfolding is reduced by a Householder QR and the small triangular factor is
// diagonalised by one-sided (Hestenes) Jacobi rotations, both working on the data itself, so that
// errors scale with eps * s_1, not eps * s_1^2. The numerical rank counts the singular values
// with s^2 > tau * s_1^2, tau = max(1e-12, (16 eps_Real)^2) (with double, the host's 1e-12).
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

/// One-sided Jacobi: rotates the columns of the n x n column-major matrix `b` until they are
/// mutually orthogonal, accumulating the rotations in `w` (set to the identity first): on return
/// b = B0 W with orthogonal columns, so the singular values of B0 are the column norms of b and
/// its right-singular vectors the columns of w. `norms` (n values)
/// is workspace: the squared column norms, computed at the start of each sweep and updated by
/// each rotation (a' = a - t g, c' = c + t g), so that a pair costs one dot product, not three.
/// Returns the number of sweeps (the last one rotating nothing), or -1 if 60 did not converge.
template <class Real>
int one_sided_jacobi(std::size_t n, Real* b, Real* w, Real* norms) noexcept {
  for (std::size_t i = 0; i < n * n; ++i) w[i] = Real(0);
  for (std::size_t i = 0; i < n; ++i) w[i * n + i] = Real(1);
  const Real eps = std::numeric_limits<Real>::epsilon();
  Real total = 0;
  for (std::size_t i = 0; i < n * n; ++i) total += b[i] * b[i];
  const Real tiny = eps * eps * total;  // products of rounding-noise columns: nothing to rotate
  for (int sweep = 0; sweep < 60; ++sweep) {
    for (std::size_t j = 0; j < n; ++j) {
      Real a = 0;
      for (std::size_t i = 0; i < n; ++i) a += b[j * n + i] * b[j * n + i];
      norms[j] = a;
    }
    bool rotated = false;
    for (std::size_t j = 0; j + 1 < n; ++j)
      for (std::size_t k = j + 1; k < n; ++k) {
        Real* bj = b + j * n;
        Real* bk = b + k * n;
        const Real a = norms[j], c = norms[k];
        Real g = 0;
        for (std::size_t i = 0; i < n; ++i) g += bj[i] * bk[i];
        // orthogonal enough, or both columns at the level of rounding noise
        if (!(std::fabs(g) > eps * std::sqrt(a * c)) || !(std::fabs(g) > tiny)) continue;
        rotated = true;
        const Real zeta = (c - a) / (Real(2) * g);
        const Real t = (zeta >= 0 ? Real(1) : Real(-1)) /
                       (std::fabs(zeta) + std::sqrt(Real(1) + zeta * zeta));
        const Real cs = Real(1) / std::sqrt(Real(1) + t * t), sn = cs * t;
        for (std::size_t i = 0; i < n; ++i) {
          const Real x = bj[i], y = bk[i];
          bj[i] = cs * x - sn * y;
          bk[i] = sn * x + cs * y;
        }
        norms[j] = std::max(Real(0), a - t * g);
        norms[k] = std::max(Real(0), c + t * g);
        Real* wj = w + j * n;
        Real* wk = w + k * n;
        for (std::size_t i = 0; i < n; ++i) {
          const Real x = wj[i], y = wk[i];
          wj[i] = cs * x - sn * y;
          wk[i] = sn * x + cs * y;
        }
      }
    if (!rotated) return sweep + 1;
  }
  return -1;
}

/// The numerical rank's tolerance on squared singular values relative to the largest:
/// max(1e-12, (16 eps)^2) (with double, the host's 1e-12).
template <class Real>
constexpr Real rank_tolerance() noexcept {
  const Real e16 = Real(16) * std::numeric_limits<Real>::epsilon();
  return std::max(Real(1e-12), e16 * e16);
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
    qr_.assign(layout_.tensor_size(), Real(0));  // the thin side of an unfolding, then its QR
    b_.assign(q * q, Real(0));
    w_.assign(q * q, Real(0));
    tau_.assign(q, Real(0));
    diag_.assign(q, Real(0));
    sv_.assign(q, Real(0));
    norms_.assign(q, Real(0));
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

  // The tensor viewed as (before, m, after): unfolding A, entry (i, j = p * after + s).
  template <class Out>
  bool mode(std::size_t z, Out* out, int* rank) noexcept {
    const std::size_t m = layout_.rows(z), n = layout_.cols(z), q = layout_.q(z),
                      alpha = layout_.alpha(z);
    std::size_t before = 1;
    for (std::size_t k = 0; k < z; ++k) before *= layout_.dim(k);
    const std::size_t after = n / before;
    const Real* x = x_.data();
    // X: the unfolding's long side in q columns of L = max(m, n) rows (column-major): A itself
    // when m > n (columns j), else A^T (columns i).
    const std::size_t L = std::max(m, n);
    Real* X = qr_.data();
    for (std::size_t p = 0; p < before; ++p)
      for (std::size_t i = 0; i < m; ++i)
        for (std::size_t s = 0; s < after; ++s) {
          const std::size_t j = p * after + s;
          const Real v = x[(p * m + i) * after + s];
          if (m > n) X[j * L + i] = v;
          else X[i * L + j] = v;
        }
    // Householder QR of X (L x q): R's strict upper part in X above the diagonal, its diagonal
    // in diag_, the reflector of column c in X[c.., c] with tau_[c].
    for (std::size_t c = 0; c < q; ++c) {
      Real* col = X + c * L;
      Real nrm = 0;
      for (std::size_t i = c; i < L; ++i) nrm += col[i] * col[i];
      nrm = std::sqrt(nrm);
      if (nrm == Real(0)) {
        tau_[c] = 0;
        diag_[c] = 0;
        continue;
      }
      const Real a = col[c] > 0 ? -nrm : nrm;
      col[c] -= a;
      Real vv = 0;
      for (std::size_t i = c; i < L; ++i) vv += col[i] * col[i];
      tau_[c] = Real(2) / vv;
      diag_[c] = a;
      for (std::size_t k = c + 1; k < q; ++k) {
        Real* ck = X + k * L;
        Real d = 0;
        for (std::size_t i = c; i < L; ++i) d += col[i] * ck[i];
        d *= tau_[c];
        for (std::size_t i = c; i < L; ++i) ck[i] -= d * col[i];
      }
    }
    // alpha >= n = q (the time mode of a 4 x 4 grid at alpha = Q): at full rank the subspace is
    // all of R^n whatever the singular vectors, and the identity is a basis of it. A
    // well-conditioned R proves the rank without the Jacobi sweeps (see spans_all).
    if (m > n && alpha >= n && spans_all(n, X, L)) {
      for (std::size_t c = 0; c < n; ++c)
        for (std::size_t j = 0; j < n; ++j) out[c * n + j] = static_cast<Out>(c == j ? 1 : 0);
      std::fill(out + n * n, out + alpha * n, Out(0));
      *rank = static_cast<int>(n);
      return true;
    }
    // B = R (m > n: its right-singular vectors are A's) or R^T (m <= n: its right-singular
    // vectors U_R map to A's as Q U_R), q x q column-major.
    Real* B = b_.data();
    for (std::size_t r = 0; r < q; ++r)
      for (std::size_t c = 0; c < q; ++c) {
        const Real rv = r < c ? X[c * L + r] : (r == c ? diag_[r] : Real(0));  // R(r, c)
        if (m > n) B[c * q + r] = rv;
        else B[r * q + c] = rv;
      }
    Real* W = w_.data();
    if (one_sided_jacobi(q, B, W, norms_.data()) < 0) return false;
    for (std::size_t c = 0; c < q; ++c) {
      Real s2 = 0;
      for (std::size_t i = 0; i < q; ++i) s2 += B[c * q + i] * B[c * q + i];
      sv_[c] = s2;  // squared singular value of column c
    }
    const std::size_t k = std::min(alpha, numerical_rank(q));
    std::vector<Real>& col = col_;  // indexed: a debug build checks the bound
    for (std::size_t c = 0; c < k; ++c) {
      const Real* wv = W + order_[c] * q;
      if (m > n) {
        for (std::size_t j = 0; j < n; ++j) col[j] = wv[j];
      } else {  // Q [w; 0]: the reflectors applied last to first
        for (std::size_t j = 0; j < n; ++j) col[j] = j < q ? wv[j] : Real(0);
        for (std::size_t h = q; h-- > 0;) {
          if (tau_[h] == Real(0)) continue;
          const Real* v = X + h * L;
          Real d = 0;
          for (std::size_t i = h; i < L; ++i) d += v[i] * col[i];
          d *= tau_[h];
          for (std::size_t i = h; i < L; ++i) col[i] -= d * v[i];
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

  // Whether the n x n triangular factor R of the QR above (strict upper part in X, stride L;
  // diagonal in diag_) certainly has numerical rank n: ||R||_F ||R^-1||_F (at least the
  // condition number s_1 / s_n) below 1 / (64 sqrt(tau)) puts s_n^2 / s_1^2 above 4096 tau,
  // with room for the rounding of R^-1 (relative n kappa eps: 1.5 % in float at the limit).
  // R^-1 is formed column by column in w_ (n^3 / 6 multiply-adds, against some ten Jacobi
  // sweeps of n^2 / 2 rotations). Otherwise (a near-singular or rank-deficient unfolding) the
  // sweeps decide.
  bool spans_all(std::size_t n, const Real* X, std::size_t L) noexcept {
    Real r2 = 0;
    for (std::size_t c = 0; c < n; ++c) {
      if (!(diag_[c] != Real(0))) return false;
      r2 += diag_[c] * diag_[c];
      for (std::size_t r = 0; r < c; ++r) r2 += X[c * L + r] * X[c * L + r];
    }
    Real* T = w_.data();  // T = R^-1, upper triangular, column-major n x n
    Real t2 = 0;
    for (std::size_t j = 0; j < n; ++j) {
      Real* tj = T + j * n;
      tj[j] = Real(1) / diag_[j];
      t2 += tj[j] * tj[j];
      for (std::size_t i = j; i-- > 0;) {  // row i of R T = e_j: sum_k R(i, k) T(k, j) = 0
        Real acc = 0;
        for (std::size_t k = i + 1; k <= j; ++k) acc += X[k * L + i] * tj[k];
        tj[i] = -acc / diag_[i];
        t2 += tj[i] * tj[i];
      }
    }
    // kappa_F^2 = r2 t2 < 1 / (4096 tau)
    return std::isfinite(t2) && r2 * t2 * Real(4096) * rank_tolerance<Real>() < Real(1);
  }

  // The squared singular values sv_[0..q) in descending order (order_; insertion sort, stable:
  // std::stable_sort may allocate), and how many are above rank_tolerance() times the largest.
  std::size_t numerical_rank(std::size_t q) noexcept {
    for (std::size_t i = 0; i < q; ++i) {
      std::size_t j = i;
      for (; j > 0 && sv_[order_[j - 1]] < sv_[i]; --j) order_[j] = order_[j - 1];
      order_[j] = i;
    }
    const Real smax = sv_[order_[0]];
    const Real tau = rank_tolerance<Real>();
    std::size_t r = 0;
    while (r < q && smax > 0 && sv_[order_[r]] > tau * smax) ++r;
    return r;
  }

  BasisLayout layout_;
  std::vector<Real> x_, qr_, b_, w_, tau_, diag_, sv_, norms_, col_;
  std::vector<std::size_t> order_;
};

}  // namespace eskin::detail
