// The deployable model: the `.eskin` file format (docs/model-format.md), its validating loader,
// and the classifier that runs a loaded model on raw piezo windows.
//
// Loading allocates and throws (ModelFormatError, a std::runtime_error, whose message names the
// field and the bad value); Model::parse is the same loader returning a status instead. Classifying does neither: a Classifier allocates its workspace once,
// at construction, and its per-decision calls return a ClassifyStatus. The StreamClassifier
// (below) is the controller's path: one multi-taxel sample at a time, no allocation after
// construction.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include "eskin/crc32.hpp"
#include "eskin/preprocess.hpp"
#include "eskin/tensor_kernel.hpp"

namespace eskin {

namespace detail {
struct DecisionTables;
}

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

/// What the status-code loader (Model::parse) reports instead of throwing.
struct ModelLoadError {
  ModelError code = ModelError::kIo;
  std::string message;  ///< names the field and the value, as ModelFormatError::what()
};

/// Binary layout constants (docs/model-format.md).
namespace model_format {
inline constexpr std::uint8_t kMagic[8] = {0x89, 'E', 'S', 'K', 'I', 'N', '\r', '\n'};
/// Versions this library reads: 1 (the tensor kernel), 2 (adds the AMPL section: an amplitude
/// factor on some machines), 3 (adds the bounded window's field window_samples to PREP; AMPL
/// present when some machine has the factor), 4 (adds the CALB section: the calibrated decision
/// rule). kVersion is the newest; a file is written in the lowest version that holds it.
inline constexpr std::uint16_t kMinVersion = 1;
inline constexpr std::uint16_t kVersion = 4;
inline constexpr std::uint16_t kVersionAmplitude = 2;
inline constexpr std::uint16_t kVersionBoundedWindow = 3;
inline constexpr std::uint16_t kVersionCalibration = 4;
/// CALB's rule field: the one calibrated rule (per-machine sigmoid, normalised, threshold).
inline constexpr std::uint32_t kCalibratedRule = 1;
/// Largest CALB slope and |offset|: with |f| <= 1e300 (MACH's bound) a*f + b stays finite.
inline constexpr double kMaxCalibration = 1e6;
/// Amplitude factor (format version 2): e(x) = log(mean(x^2) + kLogEnergyFloor).
inline constexpr double kLogEnergyFloor = 1e-12;
inline constexpr std::uint32_t kHeaderBytes = 32;
inline constexpr std::uint32_t kFlagFloat64 = 1u;
inline constexpr std::size_t kNameBytes = 32;  ///< class and window-field names, NUL padded
inline constexpr int kModes = 3;               ///< (rows, cols, D) tensors
/// The file's CRC-32: the core's one (eskin/crc32.hpp, zlib's).
using eskin::crc32;
}  // namespace model_format

enum class DecisionRule : std::uint32_t { kBinary = 0, kOneVsAll = 1 };

/// One binary machine f(x) = sum_t coef[t] K(sv[t], x) + intercept, with
/// K = prod_z exp(-dist_z / (2 sigma_z^2)) on the first alpha_z basis columns of each mode,
/// times exp(-(e(x) - e(sv[t]))^2 / (2 w^2)) when the amplitude width w > 0 (e: log energy,
/// docs/model-format.md, "Decision").
struct ModelMachine {
  int positive = 0;   ///< class index claimed when f > 0
  int negative = -1;  ///< class index when f <= 0 (binary rule), -1 = "all the others"
  double intercept = 0.0;
  std::array<int, model_format::kModes> alpha{};
  std::array<double, model_format::kModes> sigma{};
  std::vector<std::uint32_t> sv_index;  ///< rows of the model's support-vector table
  std::vector<double> coef;             ///< dual coefficients, as stored (float32 or float64)
  double amplitude_width = 0.0;         ///< w of the amplitude factor; 0 = no factor
  /// Calibrated rule (format version 4, CALB): p = 1 / (1 + exp(-(slope * f + offset))).
  double calib_slope = 0.0;
  double calib_offset = 0.0;
};

/// log(1 / (1 + exp(-z))), finite for every finite z (the calibrated rule's one formula).
double log_sigmoid(double z) noexcept;

/// Log energy of a (rows, cols, D) tensor of n entries: log(mean(x^2) + 1e-12), in double;
/// +inf when the mean square overflows.
double tensor_log_energy(const double* x, std::size_t n) noexcept;

/// A loaded, fully validated model. Immutable once loaded.
class Model {
 public:
  /// The loader without exceptions: parse and validate a model held in memory. Returns true
  /// and fills `*out`, or returns false, leaves `*out` unchanged and fills `*error` (if not
  /// null) with what ModelFormatError would have said. `in_place` as view_bytes. (In a build
  /// without exceptions, detector settings that the detector itself rejects still end in
  /// detail::fatal_error; the exporter never writes such a file.)
  static bool parse(const std::uint8_t* data, std::size_t size, Model* out, ModelLoadError* error,
                    bool in_place = false);
  /// Parse and validate a model held in memory (e.g. a C header's byte array); throws
  /// ModelFormatError (parse() is the same loader without exceptions).
  static Model from_bytes(const std::uint8_t* data, std::size_t size);
  /// Same, but the support-vector bases stay where they are in `data` (not copied) when they are
  /// aligned for their type on a little-endian machine: a controller's model stays in flash
  /// and only its small tables take RAM. `data` must outlive the model (and its copies).
  static Model view_bytes(const std::uint8_t* data, std::size_t size);
#if !defined(ESKIN_DEVICE)
  /// Read and validate a `.eskin` file. Errors name the path.
  static Model load(const std::string& path);
#endif

  // preprocessing settings
  int rows() const noexcept { return rows_; }
  int cols() const noexcept { return cols_; }
  int D() const noexcept { return D_; }
  WindowMode window_mode() const noexcept { return window_mode_; }
  SubsampleMethod subsample() const noexcept { return subsample_; }
  ShortPolicy short_policy() const noexcept { return short_policy_; }
  double sample_rate_hz() const noexcept { return sample_rate_hz_; }
  const WindowConfig& window_config() const noexcept { return window_config_; }

  // classes and machines
  DecisionRule rule() const noexcept { return rule_; }
  const std::vector<std::string>& class_names() const noexcept { return class_names_; }
  const std::vector<ModelMachine>& machines() const noexcept { return machines_; }
  /// True when the model carries the calibrated decision rule (section CALB, format version
  /// 4): label = the largest calibrated score, "don't know" = confidence < reject_threshold().
  /// False: the paper's rule (docs/model-format.md, "Decision").
  bool calibrated() const noexcept { return calibrated_; }
  double reject_threshold() const noexcept { return reject_threshold_; }

  // support-vector table: bases stored with alpha_store(z) columns per mode
  bool is_float64() const noexcept { return float64_; }
  int n_support() const noexcept { return n_sv_; }
  int alpha_store(int z) const noexcept { return alpha_store_[z]; }
  /// Rows of the mode-z basis (product of the other tensor dimensions).
  int basis_rows(int z) const noexcept { return basis_rows_[z]; }
  /// Numerical rank of support vector i in mode z (its nonzero basis columns).
  int rank(int i, int z) const noexcept { return ranks_[static_cast<std::size_t>(i) * 3 + z]; }
  /// Mode-z bases of all support vectors: SV i, column k, row n at
  /// ((i * alpha_store(z) + k) * basis_rows(z) + n). Exactly one of the two is non-null: the
  /// model's own copy, or the caller's bytes (view_bytes).
  const float* bases_f32(int z) const noexcept {
    return bases32_[z].empty() ? b32_[z] : bases32_[z].data();
  }
  const double* bases_f64(int z) const noexcept {
    return bases64_[z].empty() ? b64_[z] : bases64_[z].data();
  }
  std::size_t file_bytes() const noexcept { return file_bytes_; }
  /// 1 to 4 (docs/model-format.md): the version the file was written in.
  int format_version() const noexcept { return format_version_; }
  /// Log energy e(sv_i) of each support vector (n_support() entries) when the model has an
  /// amplitude factor (format version 2), else empty.
  const std::vector<double>& sv_log_energy() const noexcept { return sv_log_energy_; }
  bool has_amplitude() const noexcept { return !sv_log_energy_.empty(); }
  /// The decision path's read-only tables (machine groups, support-vector projections), built
  /// once by the loader and shared by every classifier of this model and of its copies.
  const detail::DecisionTables& decision_tables() const noexcept { return *tables_; }

 private:
  int rows_ = 0, cols_ = 0, D_ = 0;
  WindowMode window_mode_ = WindowMode::kEnergy;
  SubsampleMethod subsample_ = SubsampleMethod::kAlgorithm2;
  ShortPolicy short_policy_ = ShortPolicy::kInterpolate;
  double sample_rate_hz_ = 0.0;
  WindowConfig window_config_{};
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
  std::array<const float*, 3> b32_{};   // borrowed bases (view_bytes), else null
  std::array<const double*, 3> b64_{};
  bool borrow_ = false;
  std::size_t file_bytes_ = 0;
  int format_version_ = 1;
  std::vector<double> sv_log_energy_;
  bool calibrated_ = false;
  double reject_threshold_ = 0.0;
  std::shared_ptr<const detail::DecisionTables> tables_;

  friend class ModelParser;
};

/// Result of a per-decision call (no exceptions on that path).
enum class ClassifyStatus : int {
  kOk = 0,
  kDecision = 1,     ///< StreamClassifier: a touch ended and was classified (see decision())
  kBadShape = -1,    ///< the window's rows/cols/length do not fit the model or the classifier
  kNoTouch = -2,     ///< the energy detector found no touch and the model's fallback is "error"
  kNotFinite = -3,   ///< NaN or Inf in the input
  kTooShort = -4,    ///< the window is shorter than D and the model's short policy is "error"
  kKernel = -5,      ///< the basis computation failed (eigen-solver did not converge)
  kNullPointer = -6,
  kOverflow = -7,    ///< reserved (beyond 4096 touches in one recording the least energetic
                     ///< are dropped, as eskin::WindowSelector does in batch preprocessing)
};
const char* to_string(ClassifyStatus s) noexcept;

/// Name of the subspace-overlap micro-kernel the classifiers use on this CPU ("avx2-fma" or
/// "generic"; ESKIN_KERNEL_ISA=generic forces the portable one).
const char* overlap_kernel_name() noexcept;

/// One decision. `values` points into the classifier that produced it (valid until its next call).
struct Decision {
  int label = -1;                  ///< class index into Model::class_names(), -1 if no decision
  /// the paper's rule: one-vs-all and no machine, or more than one, claims the pattern;
  /// the calibrated rule: confidence < the model's reject threshold
  bool dont_know = false;
  /// the calibrated rule: the normalised calibrated score of the label, in (0, 1]; NaN under
  /// the paper's rule
  double confidence = std::numeric_limits<double>::quiet_NaN();
  int n_machines = 0;              ///< entries in `values`
  const double* values = nullptr;  ///< per-machine decision values f_k(x)
  std::int64_t window_start = 0;   ///< window used, [start, stop) in samples of the input/stream
  std::int64_t window_stop = 0;
  bool window_found = true;        ///< false when the detector found no touch (fallback window)
};

/// Runs a Model on raw windows. Owns the per-decision buffers it needs (allocated at
/// construction) and reads the model's shared tables (Model::decision_tables); the classify
/// calls perform no heap allocation and throw nothing. Not thread-safe: one Classifier per
/// thread (a Model can be shared; it must outlive its classifiers).
class Classifier {
 public:
  explicit Classifier(const Model& model);
  ~Classifier();
  Classifier(Classifier&&) noexcept;
  Classifier& operator=(Classifier&&) = delete;
  Classifier(const Classifier&) = delete;
  Classifier& operator=(const Classifier&) = delete;

  /// A raw recording (or window) in C order (rows, cols, T): sample t of taxel (r, c) at
  /// (r * cols + c) * T + t; only its first `length` samples are used (length <= T; pass T).
  /// Applies the model's preprocessing (energy window or whole recording, then subsampling
  /// to D) and its machines, as eskin.preprocess + the Python model would.
  ClassifyStatus classify(const std::int16_t* x, int rows, int cols, std::int64_t T,
                          std::int64_t length, Decision* out) noexcept;
  ClassifyStatus classify(const float* x, int rows, int cols, std::int64_t T, std::int64_t length,
                          Decision* out) noexcept;
  ClassifyStatus classify(const double* x, int rows, int cols, std::int64_t T, std::int64_t length,
                          Decision* out) noexcept;
  /// An already preprocessed tensor (rows, cols, D), C order: only the machines run.
  ClassifyStatus classify_tensor(const double* tensor, Decision* out) noexcept;

  /// Only classify_tensor (the raw-recording buffers and window detector of classify are not
  /// allocated; classify returns kBadShape): a stream's classifier, whose detector brings the
  /// tensor (StreamClassifier, SkinEngine).
  struct TensorsOnly {};
  Classifier(const Model& model, TensorsOnly);

  const Model& model() const noexcept { return *model_; }

  struct Impl;

 private:
  template <typename T>
  ClassifyStatus classify_raw(const T* x, int rows, int cols, std::int64_t T_total,
                              std::int64_t length, Decision* out) noexcept;
  const Model* model_;
  std::unique_ptr<Impl> impl_;
};

/// The controller's path: fed one multi-taxel sample at a time (rows*cols values, taxel
/// (r, c) at r * cols + c), it detects each touch with the model's window detector and
/// classifies it when it ends. No heap allocation after construction, no exceptions. It holds
/// the detector's sample buffers (bounded by WindowConfig::window_samples, StoredSample) and the
/// per-decision scratch; the model's tables are shared, not copied.
class StreamClassifier {
 public:
  explicit StreamClassifier(const Model& model);

  /// One sample. Returns kOk (nothing to report), kDecision (a touch just ended and was
  /// classified: read decision()), or an error status (the sample, or the touch, is dropped).
  ClassifyStatus push(const std::int16_t* sample) noexcept;
  ClassifyStatus push(const float* sample) noexcept;
  ClassifyStatus push(const double* sample) noexcept;
  /// End of the stream: a touch in progress ends now. kDecision or kOk.
  ClassifyStatus flush() noexcept;
  /// Forget the stream (keeps the buffers).
  void reset() noexcept;

  const Decision& decision() const noexcept { return decision_; }
  std::int64_t samples_seen() const noexcept { return detector_.samples_seen(); }
  bool in_touch() const noexcept { return detector_.in_touch(); }
  const TouchDetector& detector() const noexcept { return detector_; }

 private:
  ClassifyStatus after_push(Status st) noexcept;
  const Model* model_;
  Classifier classifier_;
  TouchDetector detector_;
  std::vector<double> tensor_;
  Decision decision_{};
};

}  // namespace eskin
