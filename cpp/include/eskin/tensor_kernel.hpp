// The tensor kernel of Gastaldo et al. (Sensors 2014, Appendix): per-mode subspace bases of a
// tensor pattern and the product of per-mode Gaussian factor kernels on the distances between
// the projections onto those subspaces.
//
// Conventions (see docs/kernel.md for the full story):
//
// * A pattern is a C-order (row-major) tensor of order Z >= 2 with dimensions d_1..d_Z.
// * Mode-z unfolding A_z (M_z x N_z): M_z = d_z rows; N_z = product of the other dimensions
//   columns. Column j is the C-order (last index fastest) linear index of the remaining indices
//   (i_1..i_{z-1}, i_{z+1}..i_Z), i.e. numpy's `np.moveaxis(x, z, 0).reshape(d_z, -1)`.
//   (The paper orders the columns cyclically; any fixed order gives the same kernel.)
// * Q_z = min(M_z, N_z); 1 <= alpha_z <= Q_z.
// * Bases of mode z: the first alpha_z right-singular vectors of A_z (the directions of the
//   largest singular values), as an N_z x alpha_z COLUMN-MAJOR block (column c at offset c*N_z).
//   Columns beyond the numerical rank r_z are exactly zero, and the stored rank is
//   min(alpha_z, r_z). A pattern's bases are the Z blocks one after another (mode 1 first), at
//   BasisLayout::offset(z); BasisLayout::bases_size() doubles in all.
// * Numerical rank: r_z = #{ i : s_i^2 > tau * s_1^2 } with tau = max(1e-12, 16*max(M,N)*eps)
//   (s_i singular values of A_z; eps = 2^-52). An all-zero pattern has rank 0 in every mode.
// * Sign: each stored column is flipped so that its entry of largest magnitude (the first one
//   on ties) is positive. Ties between singular values are broken by the deterministic
//   eigen-solver (same input, same build -> same bases).
// * Squared mode distance ||P_a - P_b||_F^2 = r_a + r_b - 2 ||V_a^T V_b||_F^2 (= 2 alpha -
//   2 ||V_a^T V_b||_F^2 at full rank), clamped at 0; never an N x N projection matrix.
// * Kernel K(a, b) = prod_z exp(-d_z(a, b) / (2 sigma_z^2)).
//
// Two layers:
// * Batch layer (host): PatternBases / compute_pattern_bases / mode_distances / tensor_kernel,
//   multi-threaded with std::thread (no OpenMP: safe under fork), throws std::invalid_argument.
// * Heap-free layer (embedded inference): BasisWorkspace allocates everything at construction;
//   BasisWorkspace::compute and the raw-pointer mode_distance / kernel_value neither allocate nor
//   throw, and report problems through Status.
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>
#include <utility>
#include <vector>

namespace eskin {

/// Result of the heap-free, exception-free functions.
enum class KernelStatus : int {
  ok = 0,
  not_finite = 1,      ///< the pattern holds a NaN or an infinity
  no_convergence = 2,  ///< the eigen-solver did not converge (not seen in practice)
  bad_argument = 3,    ///< null pointer or mismatched size
};

/// Human-readable name of a status ("ok", "not_finite", ...).
const char* to_string(KernelStatus s) noexcept;

/// Geometry of one pattern and of its bases: dimensions, alphas, offsets of the mode blocks.
class BasisLayout {
 public:
  BasisLayout() = default;
  /// Throws std::invalid_argument for fewer than 2 modes, a zero dimension, alphas of the wrong
  /// length, or an alpha outside [1, Q_z].
  BasisLayout(std::vector<std::size_t> dims, std::vector<std::size_t> alphas);

  std::size_t n_modes() const noexcept { return dims_.size(); }
  const std::vector<std::size_t>& dims() const noexcept { return dims_; }
  const std::vector<std::size_t>& alphas() const noexcept { return alphas_; }
  std::size_t dim(std::size_t z) const noexcept { return dims_[z]; }
  std::size_t alpha(std::size_t z) const noexcept { return alphas_[z]; }
  std::size_t rows(std::size_t z) const noexcept { return dims_[z]; }  ///< M_z
  std::size_t cols(std::size_t z) const noexcept { return size_ / dims_[z]; }  ///< N_z
  std::size_t q(std::size_t z) const noexcept;  ///< Q_z = min(M_z, N_z)
  /// Offset (in scalars) of mode z's N_z x alpha_z block inside one pattern's bases.
  std::size_t offset(std::size_t z) const noexcept { return offsets_[z]; }
  std::size_t bases_size() const noexcept { return bases_size_; }  ///< scalars per pattern
  std::size_t tensor_size() const noexcept { return size_; }        ///< prod d_z
  bool operator==(const BasisLayout& o) const noexcept {
    return dims_ == o.dims_ && alphas_ == o.alphas_;
  }
  bool operator!=(const BasisLayout& o) const noexcept { return !(*this == o); }

 private:
  std::vector<std::size_t> dims_, alphas_, offsets_;
  std::size_t size_ = 0, bases_size_ = 0;
};

/// Q_z = min(d_z, prod of the other dimensions) for every mode. Throws for < 2 modes / zero dims.
std::vector<std::size_t> full_alphas(const std::vector<std::size_t>& dims);
/// floor(Q_z / 2), at least 1, for every mode.
std::vector<std::size_t> half_alphas(const std::vector<std::size_t>& dims);

/// Mode-z unfolding of one C-order tensor `x` of dimensions `dims` into `out`, row-major
/// M_z x N_z (out[i * N_z + j]); column order as documented above. Throws for a bad mode.
void unfold(const double* x, const std::vector<std::size_t>& dims, std::size_t mode, double* out);

// ---------------------------------------------------------------------------------------------
// Heap-free layer

/// Everything needed to compute the bases of up to kMaxBatch patterns at once, allocated once
/// for a given layout. compute() and compute_batch() perform no heap allocation and throw
/// nothing. Not thread-safe: use one workspace per thread.
///
/// The eigen-solves of a batch run side by side, one pattern per SIMD lane; a pattern's bases do
/// not depend on the other patterns of its batch (compute() and compute_batch() give the same
/// bits).
class BasisWorkspace {
 public:
  static constexpr std::size_t kMaxBatch = 8;  ///< patterns per compute_batch() call

  /// max_batch (1..kMaxBatch): the most patterns one compute_batch() call takes; its scaled
  /// copies of the patterns are allocated for that many (a classifier, one pattern per
  /// decision, passes 1).
  explicit BasisWorkspace(const BasisLayout& layout,
                          std::size_t max_batch = kMaxBatch);  // allocates; may throw
  const BasisLayout& layout() const noexcept { return layout_; }

  /// Bases of pattern `x` (layout().tensor_size() doubles, C-order) into `bases`
  /// (layout().bases_size() doubles, layout above) and `ranks` (n_modes ints, each
  /// min(alpha_z, numerical rank)). On failure the outputs are zero-filled.
  KernelStatus compute(const double* x, double* bases, int* ranks) noexcept;
  /// Same, with the bases rounded to float (for float32 models).
  KernelStatus compute(const double* x, float* bases, int* ranks) noexcept;

  /// Bases of `count` <= kMaxBatch patterns stored one after another in `x`: pattern i's bases
  /// at bases + i * bases_size(), its ranks at ranks + i * n_modes(), its status in status[i]
  /// (a failed pattern's outputs are zero-filled; the others are unaffected). Returns
  /// bad_argument (and touches nothing) for null pointers or count > max_batch, else ok.
  KernelStatus compute_batch(const double* x, std::size_t count, double* bases, int* ranks,
                             KernelStatus* status) noexcept;

  /// Singular values of mode z of the first pattern of the last compute() / compute_batch()
  /// (descending, Q_z of them, in the units of x; zeros if that pattern failed).
  const double* singular_values(std::size_t z) const noexcept { return sv_.data() + sv_off_[z]; }

 private:
  void gram(std::size_t z, const double* xs, double* g) noexcept;
  KernelStatus finish_mode(std::size_t z, const double* xs, double* g, const double* d,
                           double* out, int* rank, double* sv) noexcept;
  BasisLayout layout_;
  std::size_t max_batch_ = kMaxBatch;
  std::size_t sv_count_ = 0;
  // per lane: scaled pattern, 1/scale; lane-interleaved matrices, eigenvalues, scratch
  std::vector<double> scaled_, inv_scale_, lanes_, lane_d_, lane_e_;
  std::vector<double> unfold_, gram_, d_, sv_, tmp_;
  std::vector<std::size_t> sv_off_;
};

/// ||V_a^T V_b||_F^2 for two N x alpha column-major blocks (the stored bases of one mode).
double mode_overlap(const double* va, const double* vb, std::size_t n, std::size_t alpha) noexcept;
double mode_overlap(const double* va, const float* vb, std::size_t n, std::size_t alpha) noexcept;
double mode_overlap(const float* va, const float* vb, std::size_t n, std::size_t alpha) noexcept;

/// Squared distance of mode projections: max(0, ra + rb - 2 ||V_a^T V_b||_F^2).
double mode_distance(const double* va, int ra, const double* vb, int rb, std::size_t n,
                     std::size_t alpha) noexcept;
double mode_distance(const double* va, int ra, const float* vb, int rb, std::size_t n,
                     std::size_t alpha) noexcept;
double mode_distance(const float* va, int ra, const float* vb, int rb, std::size_t n,
                     std::size_t alpha) noexcept;

/// Kernel value between two patterns given their bases and ranks (layout as in BasisLayout) and
/// one sigma per mode: prod_z exp(-d_z / (2 sigma_z^2)). No allocation, no exception.
double kernel_value(const BasisLayout& layout, const double* bases_a, const int* ranks_a,
                    const double* bases_b, const int* ranks_b, const double* sigmas) noexcept;
double kernel_value(const BasisLayout& layout, const double* bases_a, const int* ranks_a,
                    const float* bases_b, const int* ranks_b, const double* sigmas) noexcept;

// ---------------------------------------------------------------------------------------------
// Batch layer (host)

/// std::allocator, except that resize() leaves new elements uninitialised (every element of
/// PatternBases::bases is written by the threads that compute it: no serial zero-fill first).
template <class T>
struct UninitAllocator : std::allocator<T> {
  template <class U>
  struct rebind {
    using other = UninitAllocator<U>;
  };
  UninitAllocator() = default;
  template <class U>
  UninitAllocator(const UninitAllocator<U>&) noexcept {}
  template <class U>
  void construct(U* p) noexcept {
    ::new (static_cast<void*>(p)) U;
  }
  template <class U, class... Args>
  void construct(U* p, Args&&... args) {
    ::new (static_cast<void*>(p)) U(std::forward<Args>(args)...);
  }
};

/// The bases of n patterns: pattern i's bases at bases.data() + i * layout.bases_size(),
/// its ranks at ranks.data() + i * layout.n_modes().
struct PatternBases {
  BasisLayout layout;
  std::size_t count = 0;
  std::vector<double, UninitAllocator<double>> bases;
  std::vector<int> ranks;
};

/// Instruction set of the pairwise micro-kernel chosen at run time ("avx512", "avx2-fma" or
/// "generic"; ESKIN_KERNEL_ISA=generic|avx2 in the environment caps the choice).
const char* tensor_kernel_isa() noexcept;

/// Number of threads used when the caller passes n_threads <= 0: $ESKIN_NUM_THREADS if set,
/// else std::thread::hardware_concurrency().
int default_threads() noexcept;

/// Bases of n patterns stored one after another (n * layout.tensor_size() doubles, C-order).
/// Throws std::invalid_argument naming the pattern for NaN/Inf.
PatternBases compute_pattern_bases(const double* x, std::size_t n, const BasisLayout& layout,
                                   int n_threads = 0);

/// How the pairwise engine lays out its scratch memory (the bases repacked for the tile kernel,
/// a whole mode's packed projections in the projection modes): patterns are packed in blocks of
/// `block` patterns (a multiple of 8, or all of them), a row block of a against a column block of
/// b (of a itself for X-vs-X), so that at most two blocks are packed at a time.
struct DistancePlan {
  std::size_t block = 0;       ///< patterns per block (the whole set when blocks == 1)
  std::size_t row_blocks = 0;  ///< blocks of a
  std::size_t col_blocks = 0;  ///< blocks of b (of a for X-vs-X)
  std::size_t pack_bytes = 0;  ///< scratch memory the packed blocks take at once
  std::size_t pattern_bytes = 0;  ///< scratch memory per packed pattern
  /// bit z set: mode z packed as bases although its packed projections are cheaper per pair
  /// (taken when the whole set does not fit in max_bytes and the bases take less memory)
  unsigned bases_only = 0;
};

/// The plan of mode_distances for n patterns against m (self: X-vs-X, m == n) of one layout,
/// with at most max_bytes of scratch memory (0: no limit, one block). When the whole set does
/// not fit, the modes whose bases take less memory than their packed projections are packed as
/// bases, then the patterns are blocked. Throws
/// std::invalid_argument when not even two blocks of 8 patterns fit in max_bytes.
DistancePlan plan_distances(const BasisLayout& layout, std::size_t n, std::size_t m, bool self,
                            std::size_t max_bytes);

/// Per-mode squared distances, out (n_modes, a.count, m) C-order with m = b ? b->count :
/// a.count. b == nullptr: X-vs-X, each pair computed once, exact zeros on the diagonal.
/// max_bytes: the scratch memory allowed (plan_distances; 0: no limit); the distances are the
/// same bits for any block size, and agree to rounding (1e-12) when a mode is packed as bases.
void mode_distances(const PatternBases& a, const PatternBases* b, double* out, int n_threads = 0,
                    std::size_t max_bytes = 0);

/// Gram matrix out (a.count, m) C-order: prod_z exp(-d_z / (2 sigma_z^2)). sigmas: one per mode
/// (or a single value for all modes), all > 0.
void tensor_kernel(const PatternBases& a, const PatternBases* b, const std::vector<double>& sigmas,
                   double* out, int n_threads = 0);

}  // namespace eskin
