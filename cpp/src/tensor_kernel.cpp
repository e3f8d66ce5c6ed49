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
#include <utility>
#if !defined(ESKIN_DEVICE)
#include <thread>  // the batch layer only: the device build has no threads
#endif

#include "batch_eigen.hpp"
#include "raise.hpp"
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
    detail::raise<std::invalid_argument>("tensor shape " + dims_str(dims) +
                                " has fewer than 2 modes; the tensor kernel needs order >= 2");
  for (std::size_t d : dims)
    if (d == 0) detail::raise<std::invalid_argument>("tensor shape " + dims_str(dims) + " has a zero dimension");
}

// Dot product and axpy used by the basis computation. On x86-64 with GCC they are compiled
// twice (function multi-versioning: an x86-64-v3 = AVX2+FMA clone and the baseline one) and
// the loader picks one for the CPU; no -m flag anywhere. Partial sums in a fixed order:
// deterministic for a given clone.
#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && defined(__linux__)
#define ESKIN_CLONES __attribute__((target_clones("arch=x86-64-v4", "arch=x86-64-v3", "default")))
#else
#define ESKIN_CLONES
#endif

#if defined(__GNUC__)
typedef double eskin_v4d __attribute__((vector_size(32)));
ESKIN_CLONES double dot(const double* a, const double* b, std::size_t n) noexcept {
  eskin_v4d s0 = {0.0, 0.0, 0.0, 0.0}, s1 = s0;
  std::size_t k = 0;
  for (; k + 8 <= n; k += 8) {
    eskin_v4d a0, b0, a1, b1;
    std::memcpy(&a0, a + k, sizeof a0);
    std::memcpy(&b0, b + k, sizeof b0);
    std::memcpy(&a1, a + k + 4, sizeof a1);
    std::memcpy(&b1, b + k + 4, sizeof b1);
    s0 += a0 * b0;
    s1 += a1 * b1;
  }
  if (k + 4 <= n) {
    eskin_v4d a0, b0;
    std::memcpy(&a0, a + k, sizeof a0);
    std::memcpy(&b0, b + k, sizeof b0);
    s0 += a0 * b0;
    k += 4;
  }
  const eskin_v4d t = s0 + s1;
  double r = (t[0] + t[1]) + (t[2] + t[3]);
  for (; k < n; ++k) r += a[k] * b[k];
  return r;
}
#else
double dot(const double* a, const double* b, std::size_t n) noexcept {
  double s0 = 0, s1 = 0, s2 = 0, s3 = 0;
  std::size_t k = 0;
  for (; k + 4 <= n; k += 4) {
    s0 += a[k] * b[k];
    s1 += a[k + 1] * b[k + 1];
    s2 += a[k + 2] * b[k + 2];
    s3 += a[k + 3] * b[k + 3];
  }
  for (; k < n; ++k) s0 += a[k] * b[k];
  return (s0 + s1) + (s2 + s3);
}
#endif

#if defined(__GNUC__)
__attribute__((always_inline)) inline eskin_v4d load4(const double* p) noexcept {
  eskin_v4d v;
  std::memcpy(&v, p, sizeof v);
  return v;
}
__attribute__((always_inline)) inline double hsum4(eskin_v4d v) noexcept { return (v[0] + v[1]) + (v[2] + v[3]); }

// Lower triangle (k <= i < R) of G = sum_{p < P} X_p X_p^T, X_p the R x S row-major block at
// x + p * R * S: g[i * q + k] = sum_p <x[p, i, :], x[p, k, :]>. Blocks of 4 x 4 rows keep 16
// accumulators in registers, summed over every p before one horizontal reduction each; the
// partial sums run in a fixed order (deterministic for a given clone).
ESKIN_CLONES void gram_rows(const double* x, std::size_t P, std::size_t R, std::size_t S,
                            double* g, std::size_t q) noexcept {
  const std::size_t S4 = S & ~std::size_t(3);
  for (std::size_t i0 = 0; i0 < R; i0 += 4)
    for (std::size_t k0 = 0; k0 <= i0; k0 += 4) {
      eskin_v4d acc[4][4];
      double tail[4][4];
      for (std::size_t a = 0; a < 4; ++a)
        for (std::size_t b = 0; b < 4; ++b) {
          acc[a][b] = eskin_v4d{0.0, 0.0, 0.0, 0.0};
          tail[a][b] = 0.0;
        }
      for (std::size_t p = 0; p < P; ++p) {
        const double* xi[4];
        const double* xk[4];
        for (std::size_t a = 0; a < 4; ++a) {  // rows past R repeat the last one (ignored)
          xi[a] = x + (p * R + std::min(i0 + a, R - 1)) * S;
          xk[a] = x + (p * R + std::min(k0 + a, R - 1)) * S;
        }
        for (std::size_t t = 0; t < S4; t += 4) {
          const eskin_v4d b0 = load4(xk[0] + t), b1 = load4(xk[1] + t), b2 = load4(xk[2] + t),
                          b3 = load4(xk[3] + t);
          for (std::size_t a = 0; a < 4; ++a) {
            const eskin_v4d va = load4(xi[a] + t);
            acc[a][0] += va * b0;
            acc[a][1] += va * b1;
            acc[a][2] += va * b2;
            acc[a][3] += va * b3;
          }
        }
        for (std::size_t t = S4; t < S; ++t)
          for (std::size_t a = 0; a < 4; ++a)
            for (std::size_t b = 0; b < 4; ++b) tail[a][b] += xi[a][t] * xk[b][t];
      }
      for (std::size_t a = 0; a < 4 && i0 + a < R; ++a)
        for (std::size_t b = 0; b < 4 && k0 + b <= i0 + a; ++b)
          g[(i0 + a) * q + k0 + b] = hsum4(acc[a][b]) + tail[a][b];
    }
}

// max |x[i]| over n values; *nan set when one of them is a NaN (an infinity shows in the max).
ESKIN_CLONES double abs_max(const double* x, std::size_t n, bool* nan) noexcept {
  typedef long long eskin_v4i __attribute__((vector_size(32)));
  const eskin_v4i mag = {0x7fffffffffffffffLL, 0x7fffffffffffffffLL, 0x7fffffffffffffffLL,
                         0x7fffffffffffffffLL};
  eskin_v4d m0 = {0.0, 0.0, 0.0, 0.0}, m1 = m0;
  eskin_v4i bad = {0, 0, 0, 0};
  std::size_t i = 0;
  for (; i + 8 <= n; i += 8) {
    const eskin_v4d a = load4(x + i), b = load4(x + i + 4);
    const eskin_v4d fa = (eskin_v4d)((eskin_v4i)a & mag), fb = (eskin_v4d)((eskin_v4i)b & mag);
    bad |= (a != a) | (b != b);
    const eskin_v4i ga = fa > m0, gb = fb > m1;
    m0 = (eskin_v4d)(((eskin_v4i)fa & ga) | ((eskin_v4i)m0 & ~ga));
    m1 = (eskin_v4d)(((eskin_v4i)fb & gb) | ((eskin_v4i)m1 & ~gb));
  }
  double m = 0.0;
  bool any = (bad[0] | bad[1] | bad[2] | bad[3]) != 0;
  for (std::size_t k = 0; k < 4; ++k) m = std::max(m, std::max(m0[k], m1[k]));
  for (; i < n; ++i) {
    any |= x[i] != x[i];
    m = std::max(m, std::fabs(x[i]));
  }
  *nan = any;
  return m;
}
#else
void gram_rows(const double* x, std::size_t P, std::size_t R, std::size_t S, double* g,
               std::size_t q) noexcept {
  for (std::size_t i = 0; i < R; ++i)
    for (std::size_t k = 0; k <= i; ++k) {
      double sum = 0.0;
      for (std::size_t p = 0; p < P; ++p) sum += dot(x + (p * R + i) * S, x + (p * R + k) * S, S);
      g[i * q + k] = sum;
    }
}

double abs_max(const double* x, std::size_t n, bool* nan) noexcept {
  double m = 0.0;
  bool any = false;
  for (std::size_t i = 0; i < n; ++i) {
    any |= x[i] != x[i];
    m = std::max(m, std::fabs(x[i]));
  }
  *nan = any;
  return m;
}
#endif

#if defined(__GNUC__)
// out[t] = sum_{i < m} w[i] * x[i * S + t] for t < S (the rows of x combined; one pass)
ESKIN_CLONES void combine_rows(const double* x, std::size_t m, std::size_t S, const double* w,
                               double* out) noexcept {
  std::size_t t = 0;
  for (; t + 4 <= S; t += 4) {
    eskin_v4d acc = w[0] * load4(x + t);
    for (std::size_t i = 1; i < m; ++i) acc += w[i] * load4(x + i * S + t);
    std::memcpy(out + t, &acc, sizeof acc);
  }
  for (; t < S; ++t) {
    double acc = w[0] * x[t];
    for (std::size_t i = 1; i < m; ++i) acc += w[i] * x[i * S + t];
    out[t] = acc;
  }
}

// Index of the entry of largest magnitude (the first one on ties); n >= 1.
ESKIN_CLONES std::size_t argmax_abs(const double* v, std::size_t n) noexcept {
  typedef long long eskin_v4i __attribute__((vector_size(32)));
  const eskin_v4i mag = {0x7fffffffffffffffLL, 0x7fffffffffffffffLL, 0x7fffffffffffffffLL,
                         0x7fffffffffffffffLL};
  eskin_v4d best = {-1.0, -1.0, -1.0, -1.0};
  eskin_v4i idx = {0, 0, 0, 0}, cur = {0, 1, 2, 3};
  const eskin_v4i step = {4, 4, 4, 4};
  std::size_t j = 0;
  for (; j + 4 <= n; j += 4, cur += step) {
    const eskin_v4d a = (eskin_v4d)((eskin_v4i)load4(v + j) & mag);
    const eskin_v4i gt = a > best;  // strict: the first index wins within a lane
    best = (eskin_v4d)(((eskin_v4i)a & gt) | ((eskin_v4i)best & ~gt));
    idx = (cur & gt) | (idx & ~gt);
  }
  double top = -1.0;
  std::size_t at = 0;
  for (std::size_t k = 0; k < 4; ++k)  // lanes: the largest value, then the smallest index
    if (best[k] > top || (best[k] == top && std::size_t(idx[k]) < at)) {
      top = best[k];
      at = std::size_t(idx[k]);
    }
  for (; j < n; ++j)
    if (std::fabs(v[j]) > top) {
      top = std::fabs(v[j]);
      at = j;
    }
  return at;
}

// P = V V^T (n x n, row-major) for V n x alpha, column-major
[[maybe_unused]] ESKIN_CLONES void projection_matrix(const double* v, std::size_t n, std::size_t alpha,
                                    double* P) noexcept {
  for (std::size_t i = 0; i < n; ++i) {
    double* row = P + i * n;
    std::size_t j = 0;
    for (; j + 4 <= n; j += 4) {
      eskin_v4d acc = v[i] * load4(v + j);
      for (std::size_t a = 1; a < alpha; ++a) acc += v[a * n + i] * load4(v + a * n + j);
      std::memcpy(row + j, &acc, sizeof acc);
    }
    for (; j < n; ++j) {
      double acc = v[i] * v[j];
      for (std::size_t a = 1; a < alpha; ++a) acc += v[a * n + i] * v[a * n + j];
      row[j] = acc;
    }
  }
}

// out = f * x
ESKIN_CLONES void scale_copy(const double* x, std::size_t n, double f, double* out) noexcept {
  std::size_t j = 0;
  for (; j + 4 <= n; j += 4) {
    const eskin_v4d a = f * load4(x + j);
    std::memcpy(out + j, &a, sizeof a);
  }
  for (; j < n; ++j) out[j] = f * x[j];
}

// v *= f
ESKIN_CLONES void scale_in_place(double* v, std::size_t n, double f) noexcept {
  std::size_t j = 0;
  for (; j + 4 <= n; j += 4) {
    const eskin_v4d a = f * load4(v + j);
    std::memcpy(v + j, &a, sizeof a);
  }
  for (; j < n; ++j) v[j] *= f;
}
#else
void combine_rows(const double* x, std::size_t m, std::size_t S, const double* w,
                  double* out) noexcept {
  for (std::size_t t = 0; t < S; ++t) {
    double acc = w[0] * x[t];
    for (std::size_t i = 1; i < m; ++i) acc += w[i] * x[i * S + t];
    out[t] = acc;
  }
}
std::size_t argmax_abs(const double* v, std::size_t n) noexcept {
  std::size_t at = 0;
  for (std::size_t j = 1; j < n; ++j)
    if (std::fabs(v[j]) > std::fabs(v[at])) at = j;
  return at;
}
void scale_in_place(double* v, std::size_t n, double f) noexcept {
  for (std::size_t j = 0; j < n; ++j) v[j] *= f;
}
void scale_copy(const double* x, std::size_t n, double f, double* out) noexcept {
  for (std::size_t j = 0; j < n; ++j) out[j] = f * x[j];
}
void projection_matrix(const double* v, std::size_t n, std::size_t alpha, double* P) noexcept {
  for (std::size_t i = 0; i < n; ++i)
    for (std::size_t j = 0; j < n; ++j) {
      double acc = v[i] * v[j];
      for (std::size_t a = 1; a < alpha; ++a) acc += v[a * n + i] * v[a * n + j];
      P[i * n + j] = acc;
    }
}
#endif

// y += f * x
ESKIN_CLONES void axpy(double f, const double* x, double* y, std::size_t n) noexcept {
  for (std::size_t k = 0; k < n; ++k) y[k] += f * x[k];
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

#if !defined(ESKIN_DEVICE)  // the device build (ESKIN_DEVICE) has no batch layer
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
#endif

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
    detail::raise<std::invalid_argument>("alpha has " + std::to_string(alphas_.size()) +
                                " values but the tensor shape " + dims_str(dims_) + " has " +
                                std::to_string(dims_.size()) + " modes");
  size_ = 1;
  for (std::size_t d : dims_) size_ *= d;
  offsets_.resize(dims_.size());
  bases_size_ = 0;
  for (std::size_t z = 0; z < dims_.size(); ++z) {
    if (alphas_[z] < 1 || alphas_[z] > q(z))
      detail::raise<std::invalid_argument>("alpha " + std::to_string(alphas_[z]) + " for mode " +
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

namespace {
// x[(p * m + i) * after + s] -> out[i * n + p * after + s]  (no checks, no allocation)
void unfold_unchecked(const double* x, const std::vector<std::size_t>& dims, std::size_t mode,
                      double* out) noexcept {
  std::size_t before = 1, after = 1;
  for (std::size_t z = 0; z < mode; ++z) before *= dims[z];
  for (std::size_t z = mode + 1; z < dims.size(); ++z) after *= dims[z];
  const std::size_t m = dims[mode], n = before * after;
  for (std::size_t p = 0; p < before; ++p)
    for (std::size_t i = 0; i < m; ++i)
      std::memcpy(out + i * n + p * after, x + (p * m + i) * after, after * sizeof(double));
}
}  // namespace

void unfold(const double* x, const std::vector<std::size_t>& dims, std::size_t mode, double* out) {
  check_dims(dims);
  if (mode >= dims.size())
    detail::raise<std::invalid_argument>("mode " + std::to_string(mode) + " out of range for tensor shape " +
                                dims_str(dims));
  unfold_unchecked(x, dims, mode, out);
}

// ---- heap-free workspace --------------------------------------------------------------------

BasisWorkspace::BasisWorkspace(const BasisLayout& layout, std::size_t max_batch)
    : layout_(layout), max_batch_(max_batch) {
  if (layout_.n_modes() < 2) detail::raise<std::invalid_argument>("BasisWorkspace needs a layout with >= 2 modes");
  if (max_batch_ < 1 || max_batch_ > kMaxBatch)
    detail::raise<std::invalid_argument>("BasisWorkspace: max_batch must be in [1, 8]");
  static_assert(kMaxBatch == kEigenLanes, "one pattern per eigen-solver lane");
  std::size_t qmax = 1;
  sv_off_.resize(layout_.n_modes());
  for (std::size_t z = 0; z < layout_.n_modes(); ++z) {
    qmax = std::max(qmax, layout_.q(z));
    sv_off_[z] = sv_count_;
    sv_count_ += layout_.q(z);
  }
  scaled_.assign(max_batch_ * layout_.tensor_size(), 0.0);
  inv_scale_.assign(kMaxBatch, 0.0);
  lanes_.assign(qmax * qmax * kEigenLanes, 0.0);
  lane_d_.assign(qmax * kEigenLanes, 0.0);
  lane_e_.assign(3 * qmax * kEigenLanes, 0.0);
  unfold_.assign(layout_.tensor_size(), 0.0);
  gram_.assign(qmax * qmax, 0.0);
  d_.assign(2 * qmax, 0.0);  // eigenvalues, then combination weights
  sv_.assign(sv_count_, 0.0);
  tmp_.assign(layout_.bases_size(), 0.0);
}

KernelStatus BasisWorkspace::compute(const double* x, float* bases, int* ranks) noexcept {
  if (bases == nullptr) return KernelStatus::bad_argument;
  const KernelStatus st = compute(x, tmp_.data(), ranks);
  for (std::size_t i = 0; i < tmp_.size(); ++i) bases[i] = static_cast<float>(tmp_[i]);
  return st;
}

KernelStatus BasisWorkspace::compute(const double* x, double* bases, int* ranks) noexcept {
  if (x == nullptr || bases == nullptr || ranks == nullptr) return KernelStatus::bad_argument;
  KernelStatus st = KernelStatus::ok;
  compute_batch(x, 1, bases, ranks, &st);
  return st;
}

ESKIN_CLONES KernelStatus BasisWorkspace::compute_batch(const double* x, std::size_t count, double* bases,
                                           int* ranks, KernelStatus* status) noexcept {
  if (x == nullptr || bases == nullptr || ranks == nullptr || status == nullptr ||
      count > max_batch_)
    return KernelStatus::bad_argument;
  const std::size_t nz = layout_.n_modes(), size = layout_.tensor_size(),
                    bs = layout_.bases_size();
  std::fill(sv_.begin(), sv_.end(), 0.0);
  // lanes that go through the eigen-solver: finite patterns that are not all zero
  bool live[kMaxBatch] = {};
  for (std::size_t b = 0; b < count; ++b) {
    const double* xb = x + b * size;
    status[b] = KernelStatus::ok;
    bool nan = false;
    const double amax = abs_max(xb, size, &nan);
    if (nan || !(amax <= std::numeric_limits<double>::max())) {
      status[b] = KernelStatus::not_finite;
      continue;
    }
    if (amax == 0.0) continue;  // all-zero pattern: rank 0, zero bases
    // scale by a power of two (exact) so that max |x| is in [0.5, 1)
    int ex = 0;
    std::frexp(amax, &ex);
    const double scale = std::ldexp(1.0, -ex);
    inv_scale_[b] = std::ldexp(1.0, ex);
    double* xs = scaled_.data() + b * size;
    scale_copy(xb, size, scale, xs);
    live[b] = true;
  }
  // the patterns that skip the solver (all zero, non-finite) get zero bases and ranks; the others
  // have every entry written mode by mode below
  for (std::size_t b = 0; b < count; ++b)
    if (!live[b]) {
      std::fill(bases + b * bs, bases + (b + 1) * bs, 0.0);
      std::fill(ranks + b * nz, ranks + (b + 1) * nz, 0);
    }
  for (std::size_t z = 0; z < nz; ++z) {
    const std::size_t q = layout_.q(z);
    // lane-interleaved Gram matrices of the batch (patterns that skip the solver: zeros; the
    // lanes past `count` are not solved)
    double* g = gram_.data();
    double* lanes = lanes_.data();
    for (std::size_t b = 0; b < count; ++b) {
      if (live[b]) {
        gram(z, scaled_.data() + b * size, g);
        for (std::size_t i = 0; i < q * q; ++i) lanes[i * kEigenLanes + b] = g[i];
      } else {
        for (std::size_t i = 0; i < q * q; ++i) lanes[i * kEigenLanes + b] = 0.0;
      }
    }
    const unsigned failed =
        batch_symmetric_eigen(q, lanes, lane_d_.data(), lane_e_.data(), -1, count);
    for (std::size_t b = 0; b < count; ++b) {
      if (!live[b]) continue;
      KernelStatus st = KernelStatus::no_convergence;
      if (!((failed >> b) & 1u)) {
        // this lane's eigenpairs, sorted ascending (selection sort: the first minimum is
        // chosen, so equal eigenvalues keep the solver's order: deterministic)
        double* d = d_.data();
        for (std::size_t j = 0; j < q; ++j) {
          d[j] = lane_d_[j * kEigenLanes + b];
          for (std::size_t k = 0; k < q; ++k) g[j * q + k] = lanes[(j * q + k) * kEigenLanes + b];
        }
        for (std::size_t i = 0; i + 1 < q; ++i) {
          std::size_t k = i;
          double p = d[i];
          for (std::size_t j = i + 1; j < q; ++j)
            if (d[j] < p) {
              k = j;
              p = d[j];
            }
          if (k != i) {
            d[k] = d[i];
            d[i] = p;
            std::swap_ranges(g + i * q, g + (i + 1) * q, g + k * q);
          }
        }
        double* sv = b == 0 ? sv_.data() + sv_off_[z] : nullptr;
        st = finish_mode(z, scaled_.data() + b * size, g, d, bases + b * bs + layout_.offset(z),
                         ranks + b * nz + z, sv);
        if (sv)
          for (std::size_t i = 0; i < q; ++i) sv[i] *= inv_scale_[b];
      }
      if (st != KernelStatus::ok) {
        status[b] = st;
        live[b] = false;
        std::fill(bases + b * bs, bases + (b + 1) * bs, 0.0);
        std::fill(ranks + b * nz, ranks + (b + 1) * nz, 0);
        if (b == 0) std::fill(sv_.begin(), sv_.end(), 0.0);
      }
    }
  }
  return KernelStatus::ok;
}

// Gram matrix (q x q, row-major, symmetric) of mode z's unfolding of the scaled pattern xs:
// A A^T when M_z <= N_z, else A^T A.
void BasisWorkspace::gram(std::size_t z, const double* xs, double* g) noexcept {
  // The pattern seen as P x M x S (C-order): P = product of the dimensions before z, M = d_z,
  // S = product of those after. Unfolding: A[i][p * S + s] = x[(p * M + i) * S + s].
  const std::size_t m = layout_.rows(z), n = layout_.cols(z), q = layout_.q(z);
  std::size_t before = 1;
  for (std::size_t k = 0; k < z; ++k) before *= layout_.dim(k);
  const std::size_t after = n / before;
  const double* x = xs;  // g: q x q row-major
  if (m <= n) {
    // G = A A^T: G[i][k] = sum_p <x[p, i, :], x[p, k, :]>
    std::fill(g, g + q * q, 0.0);
    if (after >= 4) {
      gram_rows(x, before, m, after, g, q);
    } else {
      // short rows: rank-one updates with the unfolding's columns x[p, :, s]
      for (std::size_t p = 0; p < before; ++p)
        for (std::size_t s0 = 0; s0 < after; ++s0) {
          const double* col = x + p * m * after + s0;
          for (std::size_t i = 0; i < m; ++i) {
            const double f = col[i * after];
            double* gi = g + i * q;
            for (std::size_t k = 0; k <= i; ++k) gi[k] += f * col[k * after];
          }
        }
    }
  } else if (after == 1) {
    // G = A^T A with A's columns the contiguous rows x[p, :]: G[p][p'] = <x[p, :], x[p', :]>
    gram_rows(x, 1, n, m, g, q);
  } else {
    // general case: materialise the unfolding, then G = A^T A by rank-one updates of its rows
    unfold_unchecked(x, layout_.dims(), z, unfold_.data());
    const double* a = unfold_.data();
    std::fill(g, g + q * q, 0.0);
    for (std::size_t i = 0; i < m; ++i) {
      const double* ai = a + i * n;
      for (std::size_t j = 0; j < n; ++j) {
        const double f = ai[j];
        double* gj = g + j * q;
        for (std::size_t l = 0; l <= j; ++l) gj[l] += f * ai[l];
      }
    }
  }
  for (std::size_t i = 0; i < q; ++i)
    for (std::size_t k = 0; k < i; ++k) g[k * q + i] = g[i * q + k];
  for (std::size_t i = 0; i < q; ++i)
    for (std::size_t k = 0; k < i; ++k) g[k * q + i] = g[i * q + k];
}

// Bases of mode z from the eigenpairs of its Gram matrix (eigenvalues ascending in d, eigenvector
// j in row j of g): rank, V (directly, or as A^T U S^-1 re-orthonormalised), signs.
ESKIN_CLONES KernelStatus BasisWorkspace::finish_mode(std::size_t z, const double* x, double* g,
                                         const double* d, double* out, int* rank,
                                         double* sv) noexcept {
  const std::size_t m = layout_.rows(z), n = layout_.cols(z), q = layout_.q(z),
                    alpha = layout_.alpha(z);
  std::size_t before = 1;
  for (std::size_t k = 0; k < z; ++k) before *= layout_.dim(k);
  const std::size_t after = n / before;
  const double lmax = std::max(0.0, d[q - 1]);
  if (sv)
    for (std::size_t i = 0; i < q; ++i) sv[i] = std::sqrt(std::max(0.0, d[q - 1 - i]));
  const double eps = std::ldexp(1.0, -52);
  const double tau = std::max(1e-12, 16.0 * double(std::max(m, n)) * eps);
  std::size_t r = 0;
  while (r < q && lmax > 0.0 && d[q - 1 - r] > tau * lmax) ++r;
  const std::size_t k = std::min(alpha, r);
  if (m > n) {
    for (std::size_t c = 0; c < k; ++c) std::copy(g + (q - 1 - c) * q, g + (q - c) * q, out + c * n);
  } else {
    // v_c = A^T u_c / s_c: v_c[p * S + s] = sum_i u_c[i] x[p, i, s] / s_c
    double* w = d_.data() + q;  // m <= q scratch values after the eigenvalues
    for (std::size_t c = 0; c < k; ++c) {
      const double* u = g + (q - 1 - c) * q;
      const double inv = 1.0 / std::sqrt(d[q - 1 - c]);
      for (std::size_t i = 0; i < m; ++i) w[i] = u[i] * inv;
      double* v = out + c * n;
      for (std::size_t p = 0; p < before; ++p)
        combine_rows(x + p * m * after, m, after, w, v + p * after);
    }
    // re-orthonormalise (modified Gram-Schmidt, two passes): V = A^T U S^-1 loses
    // orthogonality in proportion to s_1 / s_k.
    // A second pass runs only when the first one corrected more than 1e-8 (twice is enough).
    bool again = true;
    for (int pass = 0; pass < 2 && again; ++pass) {
      again = false;
      for (std::size_t c = 0; c < k; ++c) {
        double* v = out + c * n;
        for (std::size_t p = 0; p < c; ++p) {
          const double* w = out + p * n;
          const double dt = dot(v, w, n);
          if (std::fabs(dt) > 1e-8) again = true;
          axpy(-dt, w, v, n);
        }
        const double nrm = std::sqrt(dot(v, v, n));
        if (!(nrm > 0.0)) return KernelStatus::no_convergence;
        scale_in_place(v, n, 1.0 / nrm);
        if (std::fabs(nrm - 1.0) > 1e-8) again = true;
      }
    }
  }
  // sign: largest-magnitude entry (first on ties) positive
  for (std::size_t c = 0; c < k; ++c) {
    double* v = out + c * n;
    if (v[argmax_abs(v, n)] < 0) scale_in_place(v, n, -1.0);
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

#if !defined(ESKIN_DEVICE)  // the device build (ESKIN_DEVICE): no batch layer, no threads
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
  pb.bases.resize(n * layout.bases_size());  // uninitialised: compute_batch writes every entry
  pb.ranks.assign(n * layout.n_modes(), 0);
  if (n == 0) return pb;
  if (x == nullptr) throw std::invalid_argument("compute_pattern_bases: null data pointer");
  const std::size_t chunk = BasisWorkspace::kMaxBatch;  // one eigen-solver batch per work item
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
    mine->compute_batch(x + i0 * layout.tensor_size(), i1 - i0,
                        pb.bases.data() + i0 * layout.bases_size(),
                        pb.ranks.data() + i0 * layout.n_modes(), status.data() + i0);
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
// Scratch memory kept by the calling thread between calls, so that repeated Gram computations
// do not pay the page faults of fresh large allocations; released after a call that needed more
// than kKeepScratch doubles.
constexpr std::size_t kKeepScratch = std::size_t(1) << 20;  // 8 MiB
struct Scratch {
  std::vector<double> buf;
  double* get(std::size_t n) {
    if (buf.size() < n) buf.resize(n);
    return buf.data();
  }
  void trim() {
    if (buf.size() > kKeepScratch) std::vector<double>().swap(buf);
  }
};
thread_local Scratch g_pack_scratch, g_dist_scratch;

struct ModePack {
  // proj: the mode is packed as one vector per pattern, the packed projection matrix (below),
  // so that a dot product of two vectors gives ||V_a^T V_b||_F^2 directly
  bool proj = false;
  std::size_t first = 0;  // index in its PatternBases of the pack's first pattern
  std::size_t count = 0, alpha = 0, k = 0, ppg = 0, panels = 0, groups = 0;
  double* data = nullptr;  // groups * panels * k * 8 doubles (in scratch memory)
  // local pattern index (within its group) of each of the panels * 8 vectors of a group, or -1
  // for padding; one map for full groups, one for the last (possibly partial) group
  std::vector<int> map_full, map_last;
  std::size_t size() const { return groups * panels * k * kTileWidth; }
  const double* panel(std::size_t g, std::size_t p) const {
    return data + (g * panels + p) * k * kTileWidth;
  }
  std::size_t group_count(std::size_t g) const { return std::min(ppg, count - g * ppg); }
  const int* map(std::size_t g) const {
    return (g + 1 == groups ? map_last : map_full).data();
  }
};

// Two ways to get ||V_a^T V_b||_F^2 for all pairs of a mode (N = N_z):
// * bases: dot products of the alpha basis vectors of a and of b (alpha^2 N multiply-adds per
//   pair, more when alpha does not divide the tile width);
// * projections: <P_a, P_b>_F with P = V V^T, symmetric, packed as its N(N+1)/2 upper entries,
//   the off-diagonal ones times sqrt(2) (N(N+1)/2 multiply-adds per pair).
// The cheaper one is taken per mode (for 4 x 4 x D patterns with alpha = Q/2: bases in modes 1
// and 2, projections in mode 3: 136 instead of 1024 multiply-adds per pair).
std::size_t packed_size(std::size_t n) { return n * (n + 1) / 2; }

bool use_projection(std::size_t n, std::size_t alpha) {
  const std::size_t ppg = std::max<std::size_t>(1, kTileWidth / alpha);
  const std::size_t panels = (ppg * alpha + kTileWidth - 1) / kTileWidth;
  const double basis_cost = double(kTileWidth * kTileWidth) * double(n) * double(panels * panels) /
                            double(ppg * ppg);
  return double(packed_size(n)) < basis_cost;
}

// The pack of patterns [first, first + count) of a set of patterns of layout L, mode z.
// bases_only: bit z set = mode z packed as bases even where projections are cheaper per pair
ModePack plan_mode(const BasisLayout& L, std::size_t z, std::size_t first, std::size_t count,
                   unsigned bases_only = 0) {
  ModePack mp;
  mp.first = first;
  mp.count = count;
  mp.proj = !((bases_only >> z) & 1u) && use_projection(L.cols(z), L.alpha(z));
  mp.alpha = mp.proj ? 1 : L.alpha(z);
  mp.k = mp.proj ? packed_size(L.cols(z)) : L.cols(z);
  mp.ppg = std::max<std::size_t>(1, kTileWidth / mp.alpha);
  mp.panels = (mp.ppg * mp.alpha + kTileWidth - 1) / kTileWidth;
  mp.groups = (count + mp.ppg - 1) / mp.ppg;
  const std::size_t width = mp.panels * kTileWidth;
  mp.map_full.assign(width, -1);
  mp.map_last.assign(width, -1);
  const std::size_t last_count = mp.groups ? mp.group_count(mp.groups - 1) : 0;
  for (std::size_t lv = 0; lv < width; ++lv) {
    if (lv < mp.ppg * mp.alpha) mp.map_full[lv] = int(lv / mp.alpha);
    if (lv < last_count * mp.alpha) mp.map_last[lv] = int(lv / mp.alpha);
  }
  return mp;
}

// Fill groups [g0, g1) of mp.data (already pointing at mp.size() doubles) from the bases of mode z.
ESKIN_CLONES void pack_groups(const PatternBases& pb, std::size_t z, ModePack& mp, std::size_t g0,
                 std::size_t g1) {
  const BasisLayout& L = pb.layout;
  const std::size_t off = L.offset(z), bs = L.bases_size();
  static const double kZeros[1] = {0.0};
  if (mp.proj) {
    // one panel per group, column c = pattern g * 8 + c: its packed projection matrix
    const std::size_t n = L.cols(z), alpha = L.alpha(z);
    const double r2 = std::sqrt(2.0);
    std::vector<double> proj_buf(n * n);  // one pattern's P = V V^T
    double* proj = proj_buf.data();
    for (std::size_t g = g0; g < g1; ++g) {
      double* dst = mp.data + g * mp.k * kTileWidth;
      const std::size_t used = mp.group_count(g);
      for (std::size_t c = 0; c < kTileWidth; ++c) {
        if (c >= used) {
          for (std::size_t kk = 0; kk < mp.k; ++kk) dst[kk * kTileWidth + c] = 0.0;
          continue;
        }
        const double* v =
            pb.bases.data() + (mp.first + g * kTileWidth + c) * bs + off;  // n x alpha, col-major
        projection_matrix(v, n, alpha, proj);
        std::size_t kk = 0;
        for (std::size_t i = 0; i < n; ++i) {
          const double* row = proj + i * n;
          dst[kk++ * kTileWidth + c] = row[i];
          for (std::size_t j = i + 1; j < n; ++j) dst[kk++ * kTileWidth + c] = r2 * row[j];
        }
      }
    }
    return;
  }
  for (std::size_t g = g0; g < g1; ++g) {
    const std::size_t used = mp.group_count(g) * mp.alpha;
    for (std::size_t p = 0; p < mp.panels; ++p) {
      // the panel's 8 source columns (padding: a zero read with stride 0)
      const double* col[kTileWidth];
      std::size_t stride[kTileWidth];
      for (std::size_t c = 0; c < kTileWidth; ++c) {
        const std::size_t lv = p * kTileWidth + c;
        if (lv < used) {
          col[c] = pb.bases.data() + (mp.first + g * mp.ppg + lv / mp.alpha) * bs + off +
                   (lv % mp.alpha) * mp.k;
          stride[c] = 1;
        } else {
          col[c] = kZeros;
          stride[c] = 0;
        }
      }
      double* dst = mp.data + (g * mp.panels + p) * mp.k * kTileWidth;
      std::size_t kk = 0;
#if defined(__GNUC__) && !defined(__clang__)
      if (used >= (p + 1) * kTileWidth) {
        // eight real columns: 4 x 4 register transposes, four rows of the panel at a time
        typedef long long v4i __attribute__((vector_size(32)));
        for (; kk + 4 <= mp.k; kk += 4, dst += 4 * kTileWidth)
          for (std::size_t h = 0; h < kTileWidth; h += 4) {
            const eskin_v4d a0 = load4(col[h] + kk), a1 = load4(col[h + 1] + kk),
                            a2 = load4(col[h + 2] + kk), a3 = load4(col[h + 3] + kk);
            const eskin_v4d t0 = __builtin_shuffle(a0, a1, v4i{0, 4, 2, 6});
            const eskin_v4d t1 = __builtin_shuffle(a0, a1, v4i{1, 5, 3, 7});
            const eskin_v4d t2 = __builtin_shuffle(a2, a3, v4i{0, 4, 2, 6});
            const eskin_v4d t3 = __builtin_shuffle(a2, a3, v4i{1, 5, 3, 7});
            const eskin_v4d r0 = __builtin_shuffle(t0, t2, v4i{0, 1, 4, 5});
            const eskin_v4d r1 = __builtin_shuffle(t1, t3, v4i{0, 1, 4, 5});
            const eskin_v4d r2 = __builtin_shuffle(t0, t2, v4i{2, 3, 6, 7});
            const eskin_v4d r3 = __builtin_shuffle(t1, t3, v4i{2, 3, 6, 7});
            std::memcpy(dst + h, &r0, sizeof r0);
            std::memcpy(dst + kTileWidth + h, &r1, sizeof r1);
            std::memcpy(dst + 2 * kTileWidth + h, &r2, sizeof r2);
            std::memcpy(dst + 3 * kTileWidth + h, &r3, sizeof r3);
          }
      }
#endif
      for (; kk < mp.k; ++kk, dst += kTileWidth)
        for (std::size_t c = 0; c < kTileWidth; ++c) dst[c] = col[c][kk * stride[c]];
    }
  }
}

}  // namespace

namespace {

// Row blocks of kRowBlock patterns of `a`: a whole number of pattern groups in every mode
// (patterns per group = floor(8 / alpha) is 1, 2, 4 or 8), so that one work item owns every
// output entry of its rows, for all modes at once.
constexpr std::size_t kRowBlock = 8;

// Scratch doubles of the packs of `count` patterns of layout L (every mode).
std::size_t pack_doubles(const BasisLayout& L, std::size_t count, unsigned bases_only) {
  std::size_t total = 0;
  for (std::size_t z = 0; z < L.n_modes(); ++z)
    total += plan_mode(L, z, 0, count, bases_only).size();
  return total;
}

// The packs of patterns [first, first + count) of pb in every mode, in mem (pack_doubles of
// them), filled by nt threads.
std::vector<ModePack> pack_block(const PatternBases& pb, std::size_t first, std::size_t count,
                                 unsigned bases_only, double* mem, int nt) {
  const std::size_t nz = pb.layout.n_modes();
  std::vector<ModePack> packs(nz);
  struct PackItem {
    std::size_t z, g0, g1;
  };
  std::vector<PackItem> items;
  std::size_t total = 0;
  for (std::size_t z = 0; z < nz; ++z) {
    ModePack& mp = packs[z];
    mp = plan_mode(pb.layout, z, first, count, bases_only);
    mp.data = mem;
    mem += mp.size();
    total += mp.size();
    const std::size_t step = std::max<std::size_t>(1, 64 / mp.panels);
    for (std::size_t g = 0; g < mp.groups; g += step)
      items.push_back({z, g, std::min(mp.groups, g + step)});
  }
  // packing is a copy: not worth a thread below ~2 MB
  const int pack_threads = total < (std::size_t(1) << 18) ? 1 : nt;
  parallel_for(items.size(), pack_threads, [&](std::size_t i, std::size_t) {
    pack_groups(pb, items[i].z, packs[items[i].z], items[i].g0, items[i].g1);
  });
  return packs;
}

// Every pair of a packed row block A against a packed column block B (the same packs for a
// diagonal block of X-vs-X, `diag_block`: each pair once, ib > ia), reported to the sink with
// the patterns' indices in their whole sets. For every row block of kRowBlock patterns (a work
// item, run on some thread t) it calls sink.begin(t, r0, r1), then
// sink.row(t, z, ia, ib0, count, ra, rb, ov) for runs of pairs (ia, ib0 + k), k < count, with
// ranks ra and rb[k] and overlaps ||V_a^T V_b||^2 = ov[k] (distance max(0, ra + rb - 2 ov)),
// then sink.end(t, r0, r1).
template <class Sink>
void pair_block(const std::vector<ModePack>& A, const std::vector<ModePack>& B, bool diag_block,
                const double* rank_a, std::size_t n, const double* rk_b, std::size_t m, int nt,
                Sink& sink) {
  const bool self = diag_block;
  const std::size_t nz = A.size(), first = A[0].first, count = A[0].count;
  const TileFn tile_sq = select_tile_kernel();
  const TileDotFn tile_dot = select_tile_dot_kernel();
  const TileSumFn tile_sum = select_tile_sum_kernel();
  // work items: row blocks, biggest first (in X-vs-X the first blocks have the most pairs)
  const std::size_t n_blocks = (count + kRowBlock - 1) / kRowBlock;
  parallel_for(n_blocks, nt, [&](std::size_t rb, std::size_t t) {
    const std::size_t r0 = rb * kRowBlock, r1 = std::min(count, r0 + kRowBlock);
    sink.begin(t, first + r0, first + r1);
    alignas(64) double tilebuf[kTileWidth * kTileWidth];
    double acc[kTileWidth * kTileWidth];  // ppg x ppg <= 8 x 8
    for (std::size_t z = 0; z < nz; ++z) {
      const ModePack& PA = A[z];
      const ModePack& PB = B[z];
      const std::size_t ppg = PA.ppg;
      const TileFn tile = PA.proj ? tile_dot : tile_sq;  // projections: plain dot products
      const std::size_t g_begin = r0 / ppg, g_end = (r1 + ppg - 1) / ppg;
      for (std::size_t gi = g_begin; gi < g_end; ++gi) {
        const std::size_t na = PA.group_count(gi);
        const int* rmap_g = PA.map(gi);
        for (std::size_t gj = self ? gi : 0; gj < PB.groups; ++gj) {
          const std::size_t nb = PB.group_count(gj);
          const bool diag = self && gj == gi;
          if (ppg == 1) {
            // one pattern per group: every tile belongs to the pair (padding vectors are zero)
            if (diag) continue;
            double sum = 0.0;
            for (std::size_t pi = 0; pi < PA.panels; ++pi)
              for (std::size_t pj = 0; pj < PB.panels; ++pj)
                sum += tile_sum(PA.panel(gi, pi), PB.panel(gj, pj), PA.k);
            acc[0] = sum;
          } else if (PA.panels == 1 && ppg * PA.alpha == kTileWidth) {
            // alpha divides the tile width: one tile, pattern x's vectors are rows
            // x*alpha..x*alpha+alpha-1 (padding vectors are zero and land on absent patterns)
            tile(PA.panel(gi, 0), PB.panel(gj, 0), PA.k, tilebuf);
            const std::size_t al = PA.alpha;
            if (al == 1) {
              std::copy(tilebuf, tilebuf + kTileWidth * kTileWidth, acc);
            } else if (al == 2) {  // 2 x 2 blocks: pairs of rows, then pairs of columns
              double rs[4][kTileWidth];
              for (std::size_t x = 0; x < 4; ++x)
                for (std::size_t c = 0; c < kTileWidth; ++c)
                  rs[x][c] = tilebuf[2 * x * kTileWidth + c] + tilebuf[(2 * x + 1) * kTileWidth + c];
              for (std::size_t x = 0; x < 4; ++x)
                for (std::size_t y = 0; y < 4; ++y) acc[x * 4 + y] = rs[x][2 * y] + rs[x][2 * y + 1];
            } else {
              for (std::size_t x = 0; x < ppg; ++x)
                for (std::size_t y = 0; y < ppg; ++y) {
                  double sum = 0.0;
                  for (std::size_t r = x * al; r < (x + 1) * al; ++r)
                    for (std::size_t c = y * al; c < (y + 1) * al; ++c)
                      sum += tilebuf[r * kTileWidth + c];
                  acc[x * ppg + y] = sum;
                }
            }
          } else {
            std::fill(acc, acc + ppg * ppg, 0.0);
            const int* cmap_g = PB.map(gj);
            for (std::size_t pi = 0; pi < PA.panels; ++pi) {
              const int* rmap = rmap_g + pi * kTileWidth;
              if (rmap[0] < 0) break;
              for (std::size_t pj = 0; pj < PB.panels; ++pj) {
                const int* cmap = cmap_g + pj * kTileWidth;
                if (cmap[0] < 0) break;
                tile(PA.panel(gi, pi), PB.panel(gj, pj), PA.k, tilebuf);
                // rows -> local row patterns (vector adds), then columns -> column patterns
                double rsum[kTileWidth * kTileWidth];
                const int x0 = rmap[0];
                int x1 = x0;
                for (std::size_t r = 0; r < kTileWidth; ++r)
                  if (rmap[r] >= 0) x1 = rmap[r];
                std::fill(rsum, rsum + (x1 - x0 + 1) * kTileWidth, 0.0);
                for (std::size_t r = 0; r < kTileWidth; ++r) {
                  if (rmap[r] < 0) break;
                  double* dst = rsum + (rmap[r] - x0) * kTileWidth;
                  const double* src = tilebuf + r * kTileWidth;
                  for (std::size_t s2 = 0; s2 < kTileWidth; ++s2) dst[s2] += src[s2];
                }
                for (int x = x0; x <= x1; ++x) {
                  const double* src = rsum + (x - x0) * kTileWidth;
                  double* arow = acc + std::size_t(x) * ppg;
                  for (std::size_t s2 = 0; s2 < kTileWidth; ++s2)
                    if (cmap[s2] >= 0) arow[cmap[s2]] += src[s2];
                }
              }
            }
          }
          for (std::size_t x = 0; x < na; ++x) {
            const std::size_t ia = PA.first + gi * ppg + x;
            const std::size_t y0 = diag ? x + 1 : 0;
            if (y0 < nb)
              sink.row(t, z, ia, PB.first + gj * ppg + y0, nb - y0, rank_a[z * n + ia],
                       rk_b + z * m + PB.first + gj * ppg + y0, acc + x * ppg + y0);
          }
        }
      }
    }
    sink.end(t, first + r0, first + r1);
  });
}

// The pairwise engine shared by mode_distances and tensor_kernel: the pairs of a (against b, or
// each pair of a once when b is null) block by block as plan_distances lays them out.
template <class Sink>
void pairwise_distances(const PatternBases& a, const PatternBases* b, int n_threads, Sink& sink,
                        std::size_t max_bytes = 0) {
  const bool self = (b == nullptr);
  const PatternBases& B = self ? a : *b;
  if (!self && a.layout != B.layout)
    throw std::invalid_argument("the two pattern sets have different shapes or alphas");
  const std::size_t nz = a.layout.n_modes(), n = a.count, m = B.count;
  if (n == 0 || m == 0) return;
  const DistancePlan plan = plan_distances(a.layout, n, m, self, max_bytes);
  const int nt = resolve_threads(n_threads);
  // ranks as doubles, mode-major (contiguous per mode for the row updates)
  std::vector<double> rank_a(nz * n), rank_b(self ? 0 : nz * m);
  for (std::size_t z = 0; z < nz; ++z) {
    for (std::size_t i = 0; i < n; ++i) rank_a[z * n + i] = a.ranks[i * nz + z];
    if (!self)
      for (std::size_t i = 0; i < m; ++i) rank_b[z * m + i] = B.ranks[i * nz + z];
  }
  const double* rk_b = self ? rank_a.data() : rank_b.data();
  const std::size_t blk = plan.block;
  double* mem = g_pack_scratch.get(plan.pack_bytes / sizeof(double));
  for (std::size_t i0 = 0; i0 < n; i0 += blk) {
    const std::size_t ni = std::min(blk, n - i0);
    const std::vector<ModePack> rows = pack_block(a, i0, ni, plan.bases_only, mem, nt);
    double* col_mem = mem + pack_doubles(a.layout, ni, plan.bases_only);
    for (std::size_t j0 = self ? i0 : 0; j0 < m; j0 += blk) {
      const std::size_t nj = std::min(blk, m - j0);
      if (self && j0 == i0) {
        pair_block(rows, rows, true, rank_a.data(), n, rk_b, m, nt, sink);
        continue;
      }
      const std::vector<ModePack> cols = pack_block(B, j0, nj, plan.bases_only, col_mem, nt);
      pair_block(rows, cols, false, rank_a.data(), n, rk_b, m, nt, sink);
    }
  }
  g_pack_scratch.trim();
}

}  // namespace

DistancePlan plan_distances(const BasisLayout& layout, std::size_t n, std::size_t m, bool self,
                            std::size_t max_bytes) {
  DistancePlan plan;
  auto whole = [&](unsigned mask) {
    return (pack_doubles(layout, n, mask) + (self ? 0 : pack_doubles(layout, m, mask))) *
           sizeof(double);
  };
  plan.pack_bytes = whole(0);
  if (max_bytes != 0 && plan.pack_bytes > max_bytes) {
    // short of memory: the modes whose packed projections take more than their bases are
    // packed as bases (more work per pair, none repeated per block)
    for (std::size_t z = 0; z < layout.n_modes(); ++z)
      if (plan_mode(layout, z, 0, kRowBlock, 1u << z).size() <
          plan_mode(layout, z, 0, kRowBlock).size())
        plan.bases_only |= 1u << z;
    plan.pack_bytes = whole(plan.bases_only);
  }
  // a multiple of kRowBlock patterns fills whole groups in every mode (ppg is 1, 2, 4 or 8)
  plan.pattern_bytes =
      pack_doubles(layout, kRowBlock, plan.bases_only) / kRowBlock * sizeof(double);
  if (max_bytes == 0 || plan.pack_bytes <= max_bytes) {
    plan.block = std::max(n, m);
    plan.row_blocks = plan.col_blocks = (n && m) ? 1 : 0;
    return plan;
  }
  const std::size_t per_block = 2 * kRowBlock * plan.pattern_bytes;  // a row and a column block
  if (per_block > max_bytes)
    throw std::invalid_argument(
        "mode distances: two blocks of " + std::to_string(kRowBlock) + " patterns of shape " +
        dims_str(layout.dims()) + " with alphas " + dims_str(layout.alphas()) + " need " +
        std::to_string(per_block) + " bytes of scratch memory, more than the limit of " +
        std::to_string(max_bytes));
  plan.block = max_bytes / per_block * kRowBlock;
  plan.row_blocks = (n + plan.block - 1) / plan.block;
  plan.col_blocks = (m + plan.block - 1) / plan.block;
  plan.pack_bytes = (pack_doubles(layout, std::min(plan.block, n), plan.bases_only) +
                     pack_doubles(layout, std::min(plan.block, m), plan.bases_only)) *
                    sizeof(double);
  return plan;
}

void mode_distances(const PatternBases& a, const PatternBases* b, double* out, int n_threads,
                    std::size_t max_bytes) {
  const bool self = (b == nullptr);
  const std::size_t n = a.count, m = self ? a.count : b->count, zs = n * m;
  struct Sink {
    double* out;
    std::size_t m, zs;
    bool self;
    void begin(std::size_t, std::size_t, std::size_t) {}
    void row(std::size_t, std::size_t z, std::size_t ia, std::size_t ib0, std::size_t count,
             double ra, const double* rb, const double* ov) {
      double* o = out + z * zs + ia * m + ib0;
      for (std::size_t k = 0; k < count; ++k) {
        const double d = std::max(0.0, ra + rb[k] - 2.0 * ov[k]);
        o[k] = d;
        if (self) out[z * zs + (ib0 + k) * m + ia] = d;
      }
    }
    void end(std::size_t, std::size_t, std::size_t) {}
  } sink{out, m, zs, self};
  pairwise_distances(a, b, n_threads, sink, max_bytes);
  if (self)  // the diagonal is exactly zero
    for (std::size_t z = 0; z < a.layout.n_modes(); ++z)
      for (std::size_t i = 0; i < n; ++i) out[z * zs + i * m + i] = 0.0;
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
  const bool self = (b == nullptr);
  const std::size_t n = a.count, m = self ? a.count : b->count;
  if (n == 0 || m == 0) return;
  // Each row block accumulates the exponents of its rows in a per-thread buffer
  // (kRowBlock x m), then writes exp(-.) (and the mirror image in X-vs-X).
  const std::size_t team = team_size((n + kRowBlock - 1) / kRowBlock, resolve_threads(n_threads));
  double* expo = g_dist_scratch.get(team * kRowBlock * m);
  struct Sink {
    double* out;
    double* expo;
    const double* coef;
    std::size_t m;
    bool self;
    double* rows(std::size_t t) { return expo + t * kRowBlock * m; }
    void begin(std::size_t t, std::size_t r0_, std::size_t r1) {
      std::fill(rows(t), rows(t) + (r1 - r0_) * m, 0.0);
    }
    void row(std::size_t t, std::size_t z, std::size_t ia, std::size_t ib0, std::size_t count,
             double ra, const double* rb, const double* ov) {
      double* r = rows(t) + (ia % kRowBlock) * m + ib0;
      const double cz = coef[z];
      for (std::size_t k = 0; k < count; ++k) r[k] += cz * std::max(0.0, ra + rb[k] - 2.0 * ov[k]);
    }
    void end(std::size_t t, std::size_t r0_, std::size_t r1) {
      for (std::size_t ia = r0_; ia < r1; ++ia) {
        const double* e = rows(t) + (ia - r0_) * m;
        double* o = out + ia * m;
        if (self) {
          o[ia] = 1.0;
          for (std::size_t ib = ia + 1; ib < m; ++ib) o[ib] = out[ib * m + ia] = std::exp(-e[ib]);
        } else {
          for (std::size_t ib = 0; ib < m; ++ib) o[ib] = std::exp(-e[ib]);
        }
      }
    }
  } sink{out, expo, coef.data(), m, self};
  pairwise_distances(a, b, n_threads, sink);
  g_dist_scratch.trim();
}

#endif  // !ESKIN_DEVICE

}  // namespace eskin
