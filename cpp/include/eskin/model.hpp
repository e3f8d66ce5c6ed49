// The deployable model: the `.eskin` file format (docs/model-format.md), its validating loader,
// and the classifier that runs a loaded model on raw piezo windows.
//
// Loading allocates and throws (ModelFormatError, a std::runtime_error, whose message names the
// field and the bad value). Classifying does neither: a Classifier allocates its workspace once,
// at construction, and its per-decision calls return a Status.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>


namespace eskin {

/// What went wrong while reading a model file.
enum class ModelError : int {
  kIo = 1,             ///< the file cannot be opened or read
  kNotAModel,          ///< magic bytes missing: a foreign file
  kVersion,            ///< a format version this library does not read
  kTruncated,          ///< shorter than its header says
  kChecksum,           ///< CRC-32 mismatch: corrupted
  kLayout,             ///< sections missing, out of order, or of the wrong size
  kValue,              ///< a field holds an impossible value (NaN, out of range, inconsistent)
};

/// Thrown by the loader. `what()` names the file (when there is one), the field and the value.
class ModelFormatError : public std::runtime_error {
 public:
  ModelFormatError(ModelError code, const std::string& msg) : std::runtime_error(msg), code_(code) {}
  ModelError code() const noexcept { return code_; }

 private:
  ModelError code_;
};

/// Binary layout constants (docs/model-format.md).
namespace model_format {
inline constexpr std::uint8_t kMagic[8] = {0x89, 'E', 'S', 'K', 'I', 'N', '\r', '\n'};
inline constexpr std::uint16_t kVersion = 1;
inline constexpr std::uint32_t kHeaderBytes = 32;
inline constexpr std::uint32_t kFlagFloat64 = 1u;
inline constexpr std::size_t kNameBytes = 32;  ///< class and window-field names, NUL padded
inline constexpr int kModes = 3;               ///< (rows, cols, D) tensors
/// CRC-32 with the zlib polynomial (reflected 0xEDB88320, init and final xor 0xFFFFFFFF);
/// equal to Python's zlib.crc32. `crc` continues a previous call (start with 0).
std::uint32_t crc32(const std::uint8_t* data, std::size_t n, std::uint32_t crc = 0) noexcept;
}  // namespace model_format

enum class WindowMode : std::uint32_t { kNone = 0, kEnergy = 1 };
enum class Subsample : std::uint32_t { kAlgorithm2 = 0, kEven = 1 };

/// One named window-detector parameter as stored in the file (eskin::WindowConfig field).
struct WindowField {
  std::string name;
  double value = 0.0;
};
enum class DecisionRule : std::uint32_t { kBinary = 0, kOneVsAll = 1 };

/// One binary machine f(x) = sum_t coef[t] K(sv[t], x) + intercept, with
/// K = prod_z exp(-dist_z / (2 sigma_z^2)) on the first alpha_z basis columns of each mode.
struct ModelMachine {
  int positive = 0;   ///< class index claimed when f > 0
  int negative = -1;  ///< class index when f <= 0 (binary rule), -1 = "all the others"
  double intercept = 0.0;
  std::array<int, model_format::kModes> alpha{};
  std::array<double, model_format::kModes> sigma{};
  std::vector<std::uint32_t> sv_index;  ///< rows of the model's support-vector table
  std::vector<double> coef;             ///< dual coefficients, as stored (float32 or float64)
};

/// A loaded, fully validated model. Immutable once loaded.
class Model {
 public:
  /// Parse and validate a model held in memory (e.g. a C header's byte array).
  static Model from_bytes(const std::uint8_t* data, std::size_t size);
  /// Read and validate a `.eskin` file. Errors name the path.
  static Model load(const std::string& path);

  // preprocessing settings
  int rows() const noexcept { return rows_; }
  int cols() const noexcept { return cols_; }
  int D() const noexcept { return D_; }
  WindowMode window_mode() const noexcept { return window_mode_; }
  Subsample subsample() const noexcept { return subsample_; }
  double sample_rate_hz() const noexcept { return sample_rate_hz_; }
  const std::vector<WindowField>& window_fields() const noexcept { return window_fields_; }

  // classes and machines
  DecisionRule rule() const noexcept { return rule_; }
  const std::vector<std::string>& class_names() const noexcept { return class_names_; }
  const std::vector<ModelMachine>& machines() const noexcept { return machines_; }

  // support-vector table: bases stored with alpha_store(z) columns per mode
  bool is_float64() const noexcept { return float64_; }
  int n_support() const noexcept { return n_sv_; }
  int alpha_store(int z) const noexcept { return alpha_store_[z]; }
  /// Rows of the mode-z basis (product of the other tensor dimensions).
  int basis_rows(int z) const noexcept { return basis_rows_[z]; }
  /// Numerical rank of support vector i in mode z (its nonzero basis columns).
  int rank(int i, int z) const noexcept { return ranks_[static_cast<std::size_t>(i) * 3 + z]; }
  /// Mode-z bases of all support vectors: SV i, column k, row n at
  /// ((i * alpha_store(z) + k) * basis_rows(z) + n). Exactly one of the two is non-empty.
  const std::vector<float>& bases_f32(int z) const noexcept { return bases32_[z]; }
  const std::vector<double>& bases_f64(int z) const noexcept { return bases64_[z]; }
  std::size_t file_bytes() const noexcept { return file_bytes_; }

 private:
  int rows_ = 0, cols_ = 0, D_ = 0;
  WindowMode window_mode_ = WindowMode::kEnergy;
  Subsample subsample_ = Subsample::kAlgorithm2;
  double sample_rate_hz_ = 0.0;
  std::vector<WindowField> window_fields_;
  DecisionRule rule_ = DecisionRule::kBinary;
  std::vector<std::string> class_names_;
  std::vector<ModelMachine> machines_;
  bool float64_ = false;
  int n_sv_ = 0;
  std::array<int, 3> alpha_store_{};
  std::array<int, 3> basis_rows_{};
  std::vector<int> ranks_;
  std::array<std::vector<float>, 3> bases32_;
  std::array<std::vector<double>, 3> bases64_;
  std::size_t file_bytes_ = 0;

  friend class ModelParser;
};

/// Status of a per-decision call (no exceptions on that path).
enum class Status : int {
  kOk = 0,
  kBadShape = 1,     ///< the window's rows/cols do not match the model
  kTooShort = 2,     ///< fewer samples than the model needs
  kNoTouch = 3,      ///< the energy detector found no touch in the window
  kNotFinite = 4,    ///< NaN or Inf in the input
  kTooLong = 5,      ///< more samples than the classifier was sized for
};
const char* status_name(Status s) noexcept;

/// One decision.
struct Decision {
  int label = -1;            ///< class index (into Model::class_names), -1 if no decision
  bool dont_know = false;    ///< one-vs-all: no machine, or more than one, claims the pattern
  int n_machines = 0;        ///< number of valid entries in `values`
  const double* values = nullptr;  ///< per-machine decision values (owned by the classifier)
  std::int64_t window_start = 0;   ///< detected window [start, stop) in samples of the input
  std::int64_t window_stop = 0;
};

/// Runs a Model on raw windows. Owns every buffer it needs (sized at construction for windows up
/// to `max_samples` samples); classify() performs no heap allocation and throws nothing.
/// Not thread-safe: use one Classifier per thread (the Model can be shared).
class Classifier {
 public:
  explicit Classifier(const Model& model, std::int64_t max_samples = 21000);
  ~Classifier();
  Classifier(Classifier&&) noexcept;
  Classifier& operator=(Classifier&&) = delete;
  Classifier(const Classifier&) = delete;
  Classifier& operator=(const Classifier&) = delete;

  /// A raw recording or window, C order (rows, cols, T): sample t of taxel (r, c) at
  /// (r * cols + c) * T + t. Applies the model's preprocessing (energy window if configured,
  /// then subsampling to D) and the machines.
  Status classify(const std::int16_t* x, int rows, int cols, std::int64_t T, Decision* out) noexcept;
  Status classify(const float* x, int rows, int cols, std::int64_t T, Decision* out) noexcept;
  Status classify(const double* x, int rows, int cols, std::int64_t T, Decision* out) noexcept;
  /// An already preprocessed tensor (rows, cols, D), C order: only the machines run.
  Status classify_tensor(const double* tensor, Decision* out) noexcept;

  const Model& model() const noexcept { return *model_; }
  std::int64_t max_samples() const noexcept { return max_samples_; }

  struct Impl;

 private:
  template <typename T>
  Status classify_raw(const T* x, int rows, int cols, std::int64_t n, Decision* out) noexcept;
  const Model* model_;
  std::int64_t max_samples_;
  std::unique_ptr<Impl> impl_;
};

}  // namespace eskin
