// The whole skin on one host: many patches, each a stream of multi-taxel samples, classified by
// shared models (one for all patches, or one per patch through a patch -> model table).
//
// Each patch has its own touch detector (the model's window detector, SampleStore::kCodes: the
// int16 ADC codes in one compact pool); the classifiers and the tensor scratch belong to the
// models, one of each per model, because the engine runs on one thread and decides one touch at
// a time. Every decision equals the one a StreamClassifier of that patch's model would make on
// the same samples (same values, labels and windows: the stored codes are the samples
// themselves). Decisions carry the patch, the position of the touch on the body when a layout
// is given (the energy-weighted centroid of the taxel positions over the window), and a skin
// event: decisions whose windows overlap in time on adjacent patches share an event id.
//
// Construction validates everything and allocates everything (std::invalid_argument naming
// the argument and the value); pushing and flushing never allocate and never throw: they
// return a SkinStatus and hand each decision to a SkinSink. See docs/skin-engine.md.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <vector>

#include "eskin/model.hpp"
#include "eskin/preprocess.hpp"

namespace eskin {

/// What the engine is built from. The models must outlive the engine.
struct SkinConfig {
  std::vector<const Model*> models;  ///< one or more loaded models
  /// Model of each patch (indices into `models`); its size is the number of patches. Empty:
  /// `n_patches` patches, all on models[0].
  std::vector<int> patch_model;
  int n_patches = 0;  ///< used only when patch_model is empty
  /// The body layout, optional: 0 (none), 2 or 3 coordinates per taxel. Then `positions`
  /// holds, patch after patch, each patch's taxels (taxel (r, c) at r * cols + c of its
  /// model's grid) times position_dims coordinates.
  int position_dims = 0;
  std::vector<double> positions;
  /// Pairs of adjacent patches (a, b), optional: decisions on adjacent patches whose windows
  /// overlap in time belong to one skin event.
  std::vector<std::array<int, 2>> adjacency;
  /// Samples per patch an interleaved block is cut into before the engine moves to the next
  /// patch (0: 8 frames of the shortest detector frame). Larger: fewer cache misses, a larger
  /// buffer of decisions waiting to be ordered.
  std::int64_t chunk_samples = 0;
  /// Window buffers (the touch's kept samples, window_samples x taxels int16 codes, about half
  /// a 4x4 patch's state at 3 kHz) shared by the patches: 0 (default), one of its own per
  /// patch; n (1 to the number of patches), a pool of n that the patches touched at the same
  /// time take from, so memory follows the contact a skin can have at once instead of its
  /// size. A touch that starts while all n are taken is detected but not classified (counted
  /// in unbuffered()); every other decision is the same. docs/skin-engine.md.
  std::int64_t window_buffers = 0;
  /// With window_buffers > 0: 0 (default), whole buffers, one per touch; c (1 to the largest
  /// window_samples), the same memory cut into chunks of c samples: window_buffers x
  /// ceil(window_samples / c) chunks, which a touch takes one by one as its window's kept
  /// samples grow and gives back when they halve and when it ends, so the pool holds
  /// window_buffers full windows' worth of kept samples however they are spread over the
  /// touches. Decisions are the same either way (docs/skin-engine.md, "Chunked window store").
  std::int64_t window_chunk_samples = 0;
};

/// One decision of the skin. `values` points into the engine (valid during the sink's call).
struct SkinDecision {
  int patch = -1;
  int model = -1;                  ///< index into SkinConfig::models
  int label = -1;                  ///< class index into the model's class_names()
  bool dont_know = false;
  double confidence = 0.0;         ///< as Decision::confidence (NaN under the paper's rule)
  int n_machines = 0;
  const double* values = nullptr;  ///< per-machine decision values
  std::int64_t window_start = 0;   ///< the window [start, stop), in samples of the patch's stream
  std::int64_t window_stop = 0;
  std::int64_t sample = 0;         ///< samples of the patch consumed when the touch ended
  std::int64_t event = -1;         ///< skin event id (0, 1, ...): shared by adjacent overlapping touches
  bool has_position = false;
  std::array<double, 3> position{};  ///< energy-weighted centroid (position_dims coordinates)
};

/// Receives the decisions (called from push/flush; must not call back into the engine).
class SkinSink {
 public:
  virtual ~SkinSink() = default;
  virtual void on_decision(const SkinDecision& d) noexcept = 0;
};

enum class SkinStatus : int {
  kOk = 0,
  kBadPatch = -1,     ///< a patch index out of range
  kNullPointer = -2,  ///< samples or sink missing (with n > 0)
  kBadLength = -3,    ///< a negative sample count
};
const char* to_string(SkinStatus s) noexcept;

class SkinEngine {
 public:
  /// Throws std::invalid_argument naming the bad argument and value.
  explicit SkinEngine(const SkinConfig& config);
  SkinEngine(const SkinEngine&) = delete;
  SkinEngine& operator=(const SkinEngine&) = delete;

  /// n samples of one patch, sample-major (n x its taxels, int16 ADC codes). Its decisions go
  /// to `sink` in the order the touches end.
  SkinStatus push_block(int patch, const std::int16_t* samples, std::int64_t n,
                        SkinSink* sink) noexcept;
  /// n samples of every patch, interleaved: sample t is total_taxels() codes, patch after patch
  /// (patch p's taxels at taxel_offset(p)). Decisions of the block go to `sink` ordered by the
  /// sample at which their touch ended, then by patch: the same for any block size.
  SkinStatus push_interleaved(const std::int16_t* block, std::int64_t n, SkinSink* sink) noexcept;
  /// End of the streams: touches in progress end now (patch order).
  SkinStatus flush(SkinSink* sink) noexcept;
  /// Forget every stream and event (buffers kept).
  void reset() noexcept;

  int n_patches() const noexcept { return static_cast<int>(patches_.size()); }
  int n_models() const noexcept { return static_cast<int>(models_.size()); }
  int patch_model(int patch) const noexcept { return patches_[static_cast<std::size_t>(patch)].model; }
  std::int64_t patch_taxels(int patch) const noexcept;
  std::int64_t taxel_offset(int patch) const noexcept;
  std::int64_t total_taxels() const noexcept { return total_taxels_; }
  std::int64_t samples_seen(int patch) const noexcept;
  bool in_touch(int patch) const noexcept;
  /// Touches whose classification failed (too short for D, a kernel failure): dropped, as a
  /// StreamClassifier drops them.
  std::int64_t dropped() const noexcept { return dropped_; }
  /// With shared window buffers: touches that ended without a tensor because every buffer was
  /// taken when they started, or every chunk when their window grew (among the dropped
  /// ones), and the most buffers (chunks) in use at once; 0 without.
  std::int64_t unbuffered() const noexcept { return unbuffered_; }
  std::int64_t window_buffers_peak() const noexcept { return window_pool_.peak_in_use(); }
  /// The shared pool: its buffers (chunks with window_chunk_samples), those in use now, and
  /// the samples one holds; 0 without shared buffers.
  std::int64_t window_pool_size() const noexcept { return window_pool_.buffers(); }
  std::int64_t window_pool_in_use() const noexcept { return window_pool_.in_use(); }
  std::int64_t window_pool_samples() const noexcept { return window_pool_.samples(); }
  /// Bytes of the largest patch's state (detector, event history, positions, its share of the
  /// decision buffer and of the shared window buffers); the bound a deployment plans memory with.
  std::int64_t bytes_per_patch() const noexcept;

 private:
  struct Recent {  // one of a patch's last decisions, for the skin events
    std::int64_t start = 0, stop = 0, event = -1;
  };
  static constexpr int kRecent = 4;
  struct Patch {
    int model = 0;
    std::int64_t taxel_offset = 0;
    std::int64_t position_offset = -1;  // into positions_, or -1
    TouchDetector detector;
    std::array<Recent, kRecent> recent{};
    int recent_next = 0;
  };
  struct Pending {  // a decision of an interleaved chunk, waiting to be ordered
    SkinDecision d;
    std::size_t values_at = 0;
  };

  void run(int patch, const std::int16_t* samples, std::int64_t n, std::int64_t stride,
           SkinSink* sink) noexcept;
  void record(int patch, SkinSink* sink) noexcept;  // the touch that just ended, decided
  bool decide(int patch, SkinDecision* out) noexcept;
  void position(const Patch& p, const double* tensor, std::int64_t D, SkinDecision* out) const noexcept;
  void assign_event(int patch, SkinDecision* d) noexcept;
  void deliver(SkinSink* sink) noexcept;

  std::vector<const Model*> models_;
  std::vector<Classifier> classifiers_;  // one per model
  WindowBufferPool window_pool_;         // shared window buffers (empty: each patch its own)
  std::vector<Patch> patches_;
  std::vector<double> tensor_;           // the largest model's (taxels x D)
  std::vector<double> positions_;
  int position_dims_ = 0;
  std::vector<std::int64_t> adj_offset_;  // CSR adjacency
  std::vector<int> adj_;
  std::int64_t total_taxels_ = 0;
  std::int64_t chunk_ = 0;
  std::vector<Pending> pending_;          // capacity: one chunk's decisions of every patch
  std::size_t n_pending_ = 0;
  std::vector<double> pending_values_;
  std::size_t max_machines_ = 0;
  std::int64_t next_event_ = 0;
  std::int64_t dropped_ = 0;
  std::int64_t unbuffered_ = 0;
};

}  // namespace eskin
