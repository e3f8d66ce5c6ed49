// Tensor kernel: per-pattern subspace bases and per-mode distances (see tensor_kernel.hpp).
#include "eskin/tensor_kernel.hpp"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <stdexcept>
#include <string>
#include <thread>
#include <utility>

#include "tensor_kernel_tile.hpp"

namespace eskin {

namespace {

std::string dims_str(const std::vector<std::size_t>& v) {
  std::string s = "(";
  for (std::size_t i = 0; i < v.size(); ++i) {
    if (i) s += ", ";
    s += std::to_string(v[i]);
  }
  return s + (v.size() == 1 ? ",)" : ")");
}

void check_dims(const std::vector<std::size_t>& dims) {
  if (dims.size() < 2)
    throw std::invalid_argument("tensor shape " + dims_str(dims) +
                                " has fewer than 2 modes; the tensor kernel needs order >= 2");
  for (std::size_t d : dims)
    if (d == 0) throw std::invalid_argument("tensor shape " + dims_str(dims) + " has a zero dimension");
}

// ---- symmetric eigen-decomposition (Householder tridiagonalisation + implicit QL), after the
// public-domain JAMA/EISPACK tred2/tql2. Works on caller buffers, allocates nothing.
// v: n x n row-major, holds the matrix on entry and the eigenvectors (columns) on exit;
// d: eigenvalues ascending; e: scratch of n.

inline double hyp(double a, double b) noexcept {
  const double r = std::sqrt(a * a + b * b);
  if (r > 1e-150 && r < 1e150) return r;
  return std::hypot(a, b);
}

void tred2(std::size_t n, double* v, double* d, double* e) noexcept {
  auto V = [v, n](std::size_t r, std::size_t c) -> double& { return v[r * n + c]; };
  for (std::size_t j = 0; j < n; ++j) d[j] = V(n - 1, j);
  for (std::size_t i = n - 1; i > 0; --i) {
    double scale = 0.0, h = 0.0;
    for (std::size_t k = 0; k < i; ++k) scale += std::fabs(d[k]);
    if (scale == 0.0) {
      e[i] = d[i - 1];
      for (std::size_t j = 0; j < i; ++j) {
        d[j] = V(i - 1, j);
        V(i, j) = 0.0;
        V(j, i) = 0.0;
      }
    } else {
      for (std::size_t k = 0; k < i; ++k) {
        d[k] /= scale;
        h += d[k] * d[k];
      }
      double f = d[i - 1];
      double g = std::sqrt(h);
      if (f > 0) g = -g;
      e[i] = scale * g;
      h -= f * g;
      d[i - 1] = f - g;
      for (std::size_t j = 0; j < i; ++j) e[j] = 0.0;
      for (std::size_t j = 0; j < i; ++j) {
        f = d[j];
        V(j, i) = f;
        g = e[j] + V(j, j) * f;
        for (std::size_t k = j + 1; k + 1 <= i; ++k) {
          g += V(k, j) * d[k];
          e[k] += V(k, j) * f;
        }
        e[j] = g;
      }
      f = 0.0;
      for (std::size_t j = 0; j < i; ++j) {
        e[j] /= h;
        f += e[j] * d[j];
      }
      const double hh = f / (h + h);
      for (std::size_t j = 0; j < i; ++j) e[j] -= hh * d[j];
      for (std::size_t j = 0; j < i; ++j) {
        f = d[j];
        g = e[j];
        for (std::size_t k = j; k + 1 <= i; ++k) V(k, j) -= (f * e[k] + g * d[k]);
        d[j] = V(i - 1, j);
        V(i, j) = 0.0;
      }
    }
    d[i] = h;
  }
  for (std::size_t i = 0; i + 1 < n; ++i) {
    V(n - 1, i) = V(i, i);
    V(i, i) = 1.0;
    const double h = d[i + 1];
    if (h != 0.0) {
      for (std::size_t k = 0; k <= i; ++k) d[k] = V(k, i + 1) / h;
      for (std::size_t j = 0; j <= i; ++j) {
        double g = 0.0;
        for (std::size_t k = 0; k <= i; ++k) g += V(k, i + 1) * V(k, j);
        for (std::size_t k = 0; k <= i; ++k) V(k, j) -= g * d[k];
      }
    }
    for (std::size_t k = 0; k <= i; ++k) V(k, i + 1) = 0.0;
  }
  for (std::size_t j = 0; j < n; ++j) {
    d[j] = V(n - 1, j);
    V(n - 1, j) = 0.0;
  }
  V(n - 1, n - 1) = 1.0;
  e[0] = 0.0;
}

bool tql2(std::size_t n, double* v, double* d, double* e) noexcept {
  auto V = [v, n](std::size_t r, std::size_t c) -> double& { return v[r * n + c]; };
  for (std::size_t i = 1; i < n; ++i) e[i - 1] = e[i];
  e[n - 1] = 0.0;
  double f = 0.0, tst1 = 0.0;
  const double eps = std::ldexp(1.0, -52);
  for (std::size_t l = 0; l < n; ++l) {
    tst1 = std::max(tst1, std::fabs(d[l]) + std::fabs(e[l]));
    std::size_t m = l;
    while (m < n) {
      if (std::fabs(e[m]) <= eps * tst1) break;
      ++m;
    }
    if (m == n) m = n - 1;  // e[n-1] == 0, unreachable in exact arithmetic
    if (m > l) {
      int iter = 0;
      do {
        if (++iter > 100) return false;
        double g = d[l];
        double p = (d[l + 1] - g) / (2.0 * e[l]);
        double r = hyp(p, 1.0);
        if (p < 0) r = -r;
        d[l] = e[l] / (p + r);
        d[l + 1] = e[l] * (p + r);
        const double dl1 = d[l + 1];
        double h = g - d[l];
        for (std::size_t i = l + 2; i < n; ++i) d[i] -= h;
        f += h;
        p = d[m];
        double c = 1.0, c2 = 1.0, c3 = 1.0;
        const double el1 = e[l + 1];
        double s = 0.0, s2 = 0.0;
        for (std::size_t ii = m; ii-- > l;) {
          c3 = c2;
          c2 = c;
          s2 = s;
          g = c * e[ii];
          h = c * p;
          r = hyp(p, e[ii]);
          e[ii + 1] = s * r;
          s = e[ii] / r;
          c = p / r;
          p = c * d[ii] - s * g;
          d[ii + 1] = h + s * (c * g + s * d[ii]);
          for (std::size_t k = 0; k < n; ++k) {
            h = V(k, ii + 1);
            V(k, ii + 1) = s * V(k, ii) + c * h;
            V(k, ii) = c * V(k, ii) - s * h;
          }
        }
        p = -s * s2 * c3 * el1 * e[l] / dl1;
        e[l] = s * p;
        d[l] = c * p;
        if (!std::isfinite(d[l]) || !std::isfinite(e[l])) return false;
      } while (std::fabs(e[l]) > eps * tst1);
    }
    d[l] += f;
    e[l] = 0.0;
  }
  // sort ascending (selection sort: stable choice of the first minimum -> deterministic)
  for (std::size_t i = 0; i + 1 < n; ++i) {
    std::size_t k = i;
    double p = d[i];
    for (std::size_t j = i + 1; j < n; ++j)
      if (d[j] < p) {
        k = j;
        p = d[j];
      }
    if (k != i) {
      d[k] = d[i];
      d[i] = p;
      for (std::size_t j = 0; j < n; ++j) std::swap(V(j, i), V(j, k));
    }
  }
  return true;
}

template <class TA, class TB>
double overlap_impl(const TA* va, const TB* vb, std::size_t n, std::size_t alpha) noexcept {
  double s = 0.0;
  for (std::size_t i = 0; i < alpha; ++i) {
    const TA* a = va + i * n;
    for (std::size_t j = 0; j < alpha; ++j) {
      const TB* b = vb + j * n;
      double d0 = 0, d1 = 0, d2 = 0, d3 = 0;
      std::size_t k = 0;
      for (; k + 4 <= n; k += 4) {
        d0 += double(a[k]) * double(b[k]);
        d1 += double(a[k + 1]) * double(b[k + 1]);
        d2 += double(a[k + 2]) * double(b[k + 2]);
        d3 += double(a[k + 3]) * double(b[k + 3]);
      }
      for (; k < n; ++k) d0 += double(a[k]) * double(b[k]);
      const double dot = (d0 + d1) + (d2 + d3);
      s += dot * dot;
    }
  }
  return s;
}

template <class TA, class TB>
double kernel_value_impl(const BasisLayout& layout, const TA* ba, const int* ra, const TB* bb,
                         const int* rb, const double* sigmas) noexcept {
  double e = 0.0;
  for (std::size_t z = 0; z < layout.n_modes(); ++z) {
    const std::size_t off = layout.offset(z);
    const double ov = overlap_impl(ba + off, bb + off, layout.cols(z), layout.alpha(z));
    const double d = std::max(0.0, double(ra[z]) + double(rb[z]) - 2.0 * ov);
    e += d / (2.0 * sigmas[z] * sigmas[z]);
  }
  return std::exp(-e);
}

// Number of threads parallel_for will use for n_items.
std::size_t team_size(std::size_t n_items, int n_threads) {
  return std::max<std::size_t>(1, std::min<std::size_t>(n_threads > 0 ? std::size_t(n_threads) : 1, n_items));
}

// Run f(i, t) for i in [0, n_items) on up to n_threads threads (dynamic scheduling; t is the
// thread's index in [0, team_size)). f must not throw. Threads are created and joined per call
// (no pool survives the call: safe under fork).
template <class F>
void parallel_for(std::size_t n_items, int n_threads, const F& f) {
  const std::size_t nt = team_size(n_items, n_threads);
  if (nt <= 1) {
    for (std::size_t i = 0; i < n_items; ++i) f(i, std::size_t(0));
    return;
  }
  std::atomic<std::size_t> next{0};
  auto worker = [&](std::size_t t) {
    for (;;) {
      const std::size_t i = next.fetch_add(1, std::memory_order_relaxed);
      if (i >= n_items) break;
      f(i, t);
    }
  };
  std::vector<std::thread> pool;
  pool.reserve(nt - 1);
  for (std::size_t t = 1; t < nt; ++t) pool.emplace_back(worker, t);
  worker(0);
  for (auto& t : pool) t.join();
}

int resolve_threads(int n_threads) { return n_threads > 0 ? n_threads : default_threads(); }

}  // namespace

const char* to_string(KernelStatus s) noexcept {
  switch (s) {
    case KernelStatus::ok: return "ok";
    case KernelStatus::not_finite: return "not_finite";
    case KernelStatus::no_convergence: return "no_convergence";
    case KernelStatus::bad_argument: return "bad_argument";
  }
  return "unknown";
}

// ---- layout ------------------------------------------------------------------------------

BasisLayout::BasisLayout(std::vector<std::size_t> dims, std::vector<std::size_t> alphas)
    : dims_(std::move(dims)), alphas_(std::move(alphas)) {
  check_dims(dims_);
  if (alphas_.size() != dims_.size())
    throw std::invalid_argument("alpha has " + std::to_string(alphas_.size()) +
                                " values but the tensor shape " + dims_str(dims_) + " has " +
                                std::to_string(dims_.size()) + " modes");
  size_ = 1;
  for (std::size_t d : dims_) size_ *= d;
  offsets_.resize(dims_.size());
  bases_size_ = 0;
  for (std::size_t z = 0; z < dims_.size(); ++z) {
    if (alphas_[z] < 1 || alphas_[z] > q(z))
      throw std::invalid_argument("alpha " + std::to_string(alphas_[z]) + " for mode " +
                                  std::to_string(z) + " is outside [1, Q=" + std::to_string(q(z)) +
                                  "] (tensor shape " + dims_str(dims_) + ")");
    offsets_[z] = bases_size_;
    bases_size_ += cols(z) * alphas_[z];
  }
}

std::size_t BasisLayout::q(std::size_t z) const noexcept { return std::min(rows(z), cols(z)); }

std::vector<std::size_t> full_alphas(const std::vector<std::size_t>& dims) {
  check_dims(dims);
  std::size_t size = 1;
  for (std::size_t d : dims) size *= d;
  std::vector<std::size_t> out;
  for (std::size_t d : dims) out.push_back(std::min(d, size / d));
  return out;
}

std::vector<std::size_t> half_alphas(const std::vector<std::size_t>& dims) {
  auto out = full_alphas(dims);
  for (auto& a : out) a = std::max<std::size_t>(1, a / 2);
  return out;
}

void unfold(const double* x, const std::vector<std::size_t>& dims, std::size_t mode, double* out) {
  check_dims(dims);
  if (mode >= dims.size())
    throw std::invalid_argument("mode " + std::to_string(mode) + " out of range for tensor shape " +
                                dims_str(dims));
  std::size_t before = 1, after = 1;
  for (std::size_t z = 0; z < mode; ++z) before *= dims[z];
  for (std::size_t z = mode + 1; z < dims.size(); ++z) after *= dims[z];
  const std::size_t m = dims[mode], n = before * after;
  // x[(p * m + i) * after + s] -> out[i * n + p * after + s]
  for (std::size_t p = 0; p < before; ++p)
    for (std::size_t i = 0; i < m; ++i)
      std::memcpy(out + i * n + p * after, x + (p * m + i) * after, after * sizeof(double));
}

// ---- heap-free workspace --------------------------------------------------------------------

BasisWorkspace::BasisWorkspace(const BasisLayout& layout) : layout_(layout) {
  if (layout_.n_modes() < 2) throw std::invalid_argument("BasisWorkspace needs a layout with >= 2 modes");
  std::size_t qmax = 1, svn = 0;
  sv_off_.resize(layout_.n_modes());
  for (std::size_t z = 0; z < layout_.n_modes(); ++z) {
    qmax = std::max(qmax, layout_.q(z));
    sv_off_[z] = svn;
    svn += layout_.q(z);
  }
  unfold_.assign(layout_.tensor_size(), 0.0);
  gram_.assign(qmax * qmax, 0.0);
  d_.assign(qmax, 0.0);
  e_.assign(qmax, 0.0);
  sv_.assign(svn, 0.0);
  tmp_.assign(layout_.bases_size(), 0.0);
}

KernelStatus BasisWorkspace::compute(const double* x, float* bases, int* ranks) noexcept {
  if (bases == nullptr) return KernelStatus::bad_argument;
  const KernelStatus st = compute(x, tmp_.data(), ranks);
  for (std::size_t i = 0; i < tmp_.size(); ++i) bases[i] = static_cast<float>(tmp_[i]);
  return st;
}

KernelStatus BasisWorkspace::compute(const double* x, double* bases, int* ranks) noexcept {
  const std::size_t nz = layout_.n_modes();
  if (x == nullptr || bases == nullptr || ranks == nullptr) return KernelStatus::bad_argument;
  std::fill(bases, bases + layout_.bases_size(), 0.0);
  std::fill(ranks, ranks + nz, 0);
  std::fill(sv_.begin(), sv_.end(), 0.0);
  double amax = 0.0;
  for (std::size_t i = 0; i < layout_.tensor_size(); ++i) {
    const double a = std::fabs(x[i]);
    if (!(a <= std::numeric_limits<double>::max())) return KernelStatus::not_finite;
    amax = std::max(amax, a);
  }
  if (amax == 0.0) return KernelStatus::ok;  // all-zero pattern: rank 0, zero bases
  // scale by a power of two (exact) so that max |x| is in [0.5, 1)
  int ex = 0;
  std::frexp(amax, &ex);
  const double scale = std::ldexp(1.0, -ex);
  for (std::size_t z = 0; z < nz; ++z) {
    unfold(x, layout_.dims(), z, unfold_.data());
    for (double& v : unfold_) v *= scale;
    const KernelStatus st = compute_mode(z, bases + layout_.offset(z), ranks + z);
    if (st != KernelStatus::ok) {
      std::fill(bases, bases + layout_.bases_size(), 0.0);
      std::fill(ranks, ranks + nz, 0);
      return st;
    }
    double* sv = sv_.data() + sv_off_[z];
    for (std::size_t i = 0; i < layout_.q(z); ++i) sv[i] /= scale;
  }
  return KernelStatus::ok;
}

KernelStatus BasisWorkspace::compute_mode(std::size_t z, double* out, int* rank) noexcept {
  const std::size_t m = layout_.rows(z), n = layout_.cols(z), q = layout_.q(z),
                    alpha = layout_.alpha(z);
  const double* a = unfold_.data();  // m x n row-major
  double* g = gram_.data();          // q x q row-major
  if (m <= n) {
    // G = A A^T
    for (std::size_t i = 0; i < m; ++i)
      for (std::size_t k = 0; k <= i; ++k) {
        const double* ai = a + i * n;
        const double* ak = a + k * n;
        double s0 = 0, s1 = 0, s2 = 0, s3 = 0;
        std::size_t j = 0;
        for (; j + 4 <= n; j += 4) {
          s0 += ai[j] * ak[j];
          s1 += ai[j + 1] * ak[j + 1];
          s2 += ai[j + 2] * ak[j + 2];
          s3 += ai[j + 3] * ak[j + 3];
        }
        for (; j < n; ++j) s0 += ai[j] * ak[j];
        g[i * q + k] = g[k * q + i] = (s0 + s1) + (s2 + s3);
      }
  } else {
    // G = A^T A, accumulated row by row (axpy form)
    std::fill(g, g + q * q, 0.0);
    for (std::size_t i = 0; i < m; ++i) {
      const double* ai = a + i * n;
      for (std::size_t j = 0; j < n; ++j) {
        const double f = ai[j];
        double* gj = g + j * q;
        for (std::size_t l = 0; l < n; ++l) gj[l] += f * ai[l];
      }
    }
  }
  double* d = d_.data();
  tred2(q, g, d, e_.data());
  if (!tql2(q, g, d, e_.data())) return KernelStatus::no_convergence;
  // eigenvalues ascending in d; eigenvector j = column j of g
  const double lmax = std::max(0.0, d[q - 1]);
  double* sv = sv_.data() + sv_off_[z];
  for (std::size_t i = 0; i < q; ++i) sv[i] = std::sqrt(std::max(0.0, d[q - 1 - i]));
  const double eps = std::ldexp(1.0, -52);
  const double tau = std::max(1e-12, 16.0 * double(std::max(m, n)) * eps);
  std::size_t r = 0;
  while (r < q && lmax > 0.0 && d[q - 1 - r] > tau * lmax) ++r;
  const std::size_t k = std::min(alpha, r);
  if (m > n) {
    for (std::size_t c = 0; c < k; ++c) {
      const std::size_t col = q - 1 - c;
      for (std::size_t j = 0; j < n; ++j) out[c * n + j] = g[j * q + col];
    }
  } else {
    for (std::size_t c = 0; c < k; ++c) {
      const std::size_t col = q - 1 - c;
      const double inv = 1.0 / std::sqrt(d[col]);
      double* v = out + c * n;
      std::fill(v, v + n, 0.0);
      for (std::size_t i = 0; i < m; ++i) {
        const double ui = g[i * q + col] * inv;
        const double* ai = a + i * n;
        for (std::size_t j = 0; j < n; ++j) v[j] += ui * ai[j];
      }
    }
    // re-orthonormalise (modified Gram-Schmidt, two passes): V = A^T U S^-1 loses
    // orthogonality in proportion to s_1 / s_k.
    for (int pass = 0; pass < 2; ++pass)
      for (std::size_t c = 0; c < k; ++c) {
        double* v = out + c * n;
        for (std::size_t p = 0; p < c; ++p) {
          const double* w = out + p * n;
          double dot = 0.0;
          for (std::size_t j = 0; j < n; ++j) dot += v[j] * w[j];
          for (std::size_t j = 0; j < n; ++j) v[j] -= dot * w[j];
        }
        double nrm = 0.0;
        for (std::size_t j = 0; j < n; ++j) nrm += v[j] * v[j];
        nrm = std::sqrt(nrm);
        if (!(nrm > 0.0)) return KernelStatus::no_convergence;
        for (std::size_t j = 0; j < n; ++j) v[j] /= nrm;
      }
  }
  // sign: largest-magnitude entry (first on ties) positive
  for (std::size_t c = 0; c < k; ++c) {
    double* v = out + c * n;
    std::size_t best = 0;
    for (std::size_t j = 1; j < n; ++j)
      if (std::fabs(v[j]) > std::fabs(v[best])) best = j;
    if (v[best] < 0)
      for (std::size_t j = 0; j < n; ++j) v[j] = -v[j];
  }
  std::fill(out + k * n, out + alpha * n, 0.0);
  *rank = static_cast<int>(k);
  return KernelStatus::ok;
}

// ---- raw-pointer pairwise functions -----------------------------------------------------------

double mode_overlap(const double* va, const double* vb, std::size_t n, std::size_t alpha) noexcept {
  return overlap_impl(va, vb, n, alpha);
}
double mode_overlap(const double* va, const float* vb, std::size_t n, std::size_t alpha) noexcept {
  return overlap_impl(va, vb, n, alpha);
}
double mode_overlap(const float* va, const float* vb, std::size_t n, std::size_t alpha) noexcept {
  return overlap_impl(va, vb, n, alpha);
}
double mode_distance(const double* va, int ra, const double* vb, int rb, std::size_t n,
                     std::size_t alpha) noexcept {
  return std::max(0.0, double(ra) + double(rb) - 2.0 * overlap_impl(va, vb, n, alpha));
}
double mode_distance(const double* va, int ra, const float* vb, int rb, std::size_t n,
                     std::size_t alpha) noexcept {
  return std::max(0.0, double(ra) + double(rb) - 2.0 * overlap_impl(va, vb, n, alpha));
}
double mode_distance(const float* va, int ra, const float* vb, int rb, std::size_t n,
                     std::size_t alpha) noexcept {
  return std::max(0.0, double(ra) + double(rb) - 2.0 * overlap_impl(va, vb, n, alpha));
}
double kernel_value(const BasisLayout& layout, const double* ba, const int* ra, const double* bb,
                    const int* rb, const double* sigmas) noexcept {
  return kernel_value_impl(layout, ba, ra, bb, rb, sigmas);
}
double kernel_value(const BasisLayout& layout, const double* ba, const int* ra, const float* bb,
                    const int* rb, const double* sigmas) noexcept {
  return kernel_value_impl(layout, ba, ra, bb, rb, sigmas);
}

// ---- batch layer ----------------------------------------------------------------------------

const char* tensor_kernel_isa() noexcept { return tile_kernel_name(); }

int default_threads() noexcept {
  if (const char* env = std::getenv("ESKIN_NUM_THREADS")) {
    const int v = std::atoi(env);
    if (v > 0) return v;
  }
  const unsigned hc = std::thread::hardware_concurrency();
  return hc > 0 ? static_cast<int>(hc) : 1;
}

PatternBases compute_pattern_bases(const double* x, std::size_t n, const BasisLayout& layout,
                                   int n_threads) {
  PatternBases pb;
  pb.layout = layout;
  pb.count = n;
  pb.bases.assign(n * layout.bases_size(), 0.0);
  pb.ranks.assign(n * layout.n_modes(), 0);
  if (n == 0) return pb;
  if (x == nullptr) throw std::invalid_argument("compute_pattern_bases: null data pointer");
  const std::size_t chunk = 8;
  const std::size_t n_chunks = (n + chunk - 1) / chunk;
  const int nt = resolve_threads(n_threads);
  std::vector<KernelStatus> status(n, KernelStatus::ok);
  std::vector<BasisWorkspace> ws;
  const std::size_t team = team_size(n_chunks, nt);
  ws.reserve(team);
  for (std::size_t t = 0; t < team; ++t) ws.emplace_back(layout);
  auto run = [&](std::size_t c, std::size_t t) {
    BasisWorkspace* mine = &ws[t];
    const std::size_t i0 = c * chunk, i1 = std::min(n, i0 + chunk);
    for (std::size_t i = i0; i < i1; ++i)
      status[i] = mine->compute(x + i * layout.tensor_size(),
                                pb.bases.data() + i * layout.bases_size(),
                                pb.ranks.data() + i * layout.n_modes());
  };
  parallel_for(n_chunks, nt, run);
  for (std::size_t i = 0; i < n; ++i) {
    if (status[i] == KernelStatus::not_finite)
      throw std::invalid_argument("pattern " + std::to_string(i) + " contains NaN or Inf");
    if (status[i] != KernelStatus::ok)
      throw std::runtime_error("bases of pattern " + std::to_string(i) + " failed: " +
                               to_string(status[i]));
  }
  return pb;
}

namespace {

// Bases of one mode repacked for the tile kernel: patterns are put in groups of `ppg` whole
// patterns (ppg = floor(8 / alpha), at least 1); a group's ppg*alpha basis vectors fill
// `panels` panels of 8 vectors each (zero padded); a panel is K x 8 row-major (K = N_z).
struct ModePack {
  std::size_t count = 0, alpha = 0, k = 0, ppg = 0, panels = 0, groups = 0;
  std::vector<double> data;
  const double* panel(std::size_t g, std::size_t p) const {
    return data.data() + (g * panels + p) * k * kTileWidth;
  }
  std::size_t group_count(std::size_t g) const { return std::min(ppg, count - g * ppg); }
};

ModePack pack_mode(const PatternBases& pb, std::size_t z, int n_threads) {
  ModePack mp;
  const BasisLayout& L = pb.layout;
  mp.count = pb.count;
  mp.alpha = L.alpha(z);
  mp.k = L.cols(z);
  mp.ppg = std::max<std::size_t>(1, kTileWidth / mp.alpha);
  mp.panels = (mp.ppg * mp.alpha + kTileWidth - 1) / kTileWidth;
  mp.groups = (pb.count + mp.ppg - 1) / mp.ppg;
  mp.data.assign(mp.groups * mp.panels * mp.k * kTileWidth, 0.0);
  const std::size_t off = L.offset(z), bs = L.bases_size();
  parallel_for(mp.groups, n_threads, [&](std::size_t g, std::size_t) {
    for (std::size_t lp = 0; lp < mp.group_count(g); ++lp) {
      const double* src = pb.bases.data() + (g * mp.ppg + lp) * bs + off;
      for (std::size_t c = 0; c < mp.alpha; ++c) {
        const std::size_t lv = lp * mp.alpha + c;
        double* dst = mp.data.data() + (g * mp.panels + lv / kTileWidth) * mp.k * kTileWidth +
                      lv % kTileWidth;
        const double* col = src + c * mp.k;
        for (std::size_t kk = 0; kk < mp.k; ++kk) dst[kk * kTileWidth] = col[kk];
      }
    }
  });
  return mp;
}

}  // namespace

void mode_distances(const PatternBases& a, const PatternBases* b, double* out, int n_threads) {
  const bool self = (b == nullptr);
  const PatternBases& B = self ? a : *b;
  if (!self && a.layout != B.layout)
    throw std::invalid_argument("mode_distances: the two pattern sets have different layouts");
  const std::size_t nz = a.layout.n_modes(), n = a.count, m = B.count;
  if (n == 0 || m == 0) return;
  const int nt = resolve_threads(n_threads);
  std::vector<ModePack> pa(nz), pbk(self ? 0 : nz);
  for (std::size_t z = 0; z < nz; ++z) {
    pa[z] = pack_mode(a, z, nt);
    if (!self) pbk[z] = pack_mode(B, z, nt);
  }
  const TileFn tile = select_tile_kernel();
  // work items: (mode, row group), biggest first
  struct Item {
    std::size_t z, g;
    double cost;
  };
  std::vector<Item> items;
  for (std::size_t z = 0; z < nz; ++z) {
    const ModePack& P = pa[z];
    const std::size_t gb = self ? P.groups : pbk[z].groups;
    for (std::size_t g = 0; g < P.groups; ++g) {
      const double cols = double(self ? gb - g : gb);
      items.push_back({z, g, cols * double(P.panels * P.panels) * double(P.k + 8)});
    }
  }
  std::stable_sort(items.begin(), items.end(),
                   [](const Item& x, const Item& y) { return x.cost > y.cost; });
  const std::size_t zstride = n * m;
  parallel_for(items.size(), nt, [&](std::size_t it, std::size_t) {
    const std::size_t z = items[it].z, gi = items[it].g;
    const ModePack& PA = pa[z];
    const ModePack& PB = self ? pa[z] : pbk[z];
    const std::size_t alpha = PA.alpha, ppg = PA.ppg, nz_ = a.layout.n_modes();
    double* o = out + z * zstride;
    double tilebuf[kTileWidth * kTileWidth];
    double acc[kTileWidth * kTileWidth];  // ppg x ppg <= 8 x 8
    const std::size_t na = PA.group_count(gi);
    for (std::size_t gj = self ? gi : 0; gj < PB.groups; ++gj) {
      const std::size_t nb = PB.group_count(gj);
      const bool diag = self && gj == gi;
      std::fill(acc, acc + ppg * ppg, 0.0);
      for (std::size_t pi = 0; pi < PA.panels; ++pi)
        for (std::size_t pj = 0; pj < PB.panels; ++pj) {
          tile(PA.panel(gi, pi), PB.panel(gj, pj), PA.k, tilebuf);
          for (std::size_t r = 0; r < kTileWidth; ++r) {
            const std::size_t lv = pi * kTileWidth + r;
            if (lv >= na * alpha) break;
            const std::size_t pa_ = lv / alpha;
            const double* trow = tilebuf + r * kTileWidth;
            for (std::size_t s = 0; s < kTileWidth; ++s) {
              const std::size_t lw = pj * kTileWidth + s;
              if (lw >= nb * alpha) break;
              const std::size_t pb_ = lw / alpha;
              acc[pa_ * ppg + pb_] += trow[s] * trow[s];
            }
          }
        }
      for (std::size_t x = 0; x < na; ++x) {
        const std::size_t ia = gi * ppg + x;
        const double ra = a.ranks[ia * nz_ + z];
        for (std::size_t y = 0; y < nb; ++y) {
          const std::size_t ib = gj * ppg + y;
          if (diag && y <= x) {
            if (y == x) o[ia * m + ia] = 0.0;
            continue;
          }
          const double rb = B.ranks[ib * nz_ + z];
          const double d = std::max(0.0, ra + rb - 2.0 * acc[x * ppg + y]);
          o[ia * m + ib] = d;
          if (self) o[ib * m + ia] = d;
        }
      }
    }
  });
}

void tensor_kernel(const PatternBases& a, const PatternBases* b, const std::vector<double>& sigmas,
                   double* out, int n_threads) {
  const std::size_t nz = a.layout.n_modes();
  if (sigmas.size() != 1 && sigmas.size() != nz)
    throw std::invalid_argument("sigma has " + std::to_string(sigmas.size()) +
                                " values; expected 1 or one per mode (" + std::to_string(nz) + ")");
  std::vector<double> coef(nz);
  for (std::size_t z = 0; z < nz; ++z) {
    const double s = sigmas.size() == 1 ? sigmas[0] : sigmas[z];
    if (!(s > 0.0) || !std::isfinite(s))
      throw std::invalid_argument("sigma " + std::to_string(s) + " must be a positive finite number");
    coef[z] = 1.0 / (2.0 * s * s);
  }
  const std::size_t n = a.count, m = b ? b->count : a.count;
  if (n == 0 || m == 0) return;
  std::vector<double> dist(nz * n * m);
  mode_distances(a, b, dist.data(), n_threads);
  const int nt = resolve_threads(n_threads);
  const std::size_t total = n * m, chunk = 4096;
  parallel_for((total + chunk - 1) / chunk, nt, [&](std::size_t c, std::size_t) {
    const std::size_t i0 = c * chunk, i1 = std::min(total, i0 + chunk);
    for (std::size_t i = i0; i < i1; ++i) {
      double e = 0.0;
      for (std::size_t z = 0; z < nz; ++z) e += coef[z] * dist[z * total + i];
      out[i] = std::exp(-e);
    }
  });
}

}  // namespace eskin
