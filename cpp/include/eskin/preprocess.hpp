// Preprocessing of Section 5.1 of Gastaldo et al. (Sensors 2014): find the touch window of a
// recording with an energy detector (docs/paper-readings.md, R19), then shrink its time axis to D
// samples with Algorithm 2 or an evenly spaced alternative (R18).
//
// Layout conventions
// - A recording has n_taxels = rows*cols taxels; the batch functions take it taxel-major, as
//   stored in a campaign: (rows, cols, T) C-order, i.e. taxel k's samples are contiguous
//   (taxel stride T, time stride 1). A live stream delivers one multi-taxel sample at a time:
//   n_taxels consecutive values (sample-major).
// - Output tensors are (n_taxels, D) row-major, i.e. (rows, cols, D) C-order, float64.
// - Windows are half-open sample ranges [start, stop).
//
// The batch detector and the streaming detector are one class (TouchDetector): the batch path
// feeds a recording to it sample by sample, so both give identical windows by construction.
// The per-sample path (TouchDetector::push*) never allocates and never throws: it returns a
// Status. Construction validates the configuration and allocates every buffer.
//
// See docs/preprocessing.md for the design and the choice of defaults.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <vector>

namespace eskin {

// All parameters of the touch-window detector, as plain numbers (times in seconds, so that the
// same configuration works at any sample rate; the detector converts them with its rate). It is
// a POD so that it can be written into a model file as a flat array (window_config_to_array).
struct WindowConfig {
  double frame_s = 0.010;          // short-time energy frame (non-overlapping), seconds
  double dc_cutoff_hz = 5.0;       // one-pole DC blocker per taxel before squaring; 0 = off
  double combine = 0;              // frame energy over taxels: 0 sum, 1 max, 2 sum minus max
  double noise_window_s = 1.0;     // noise floor: quantile of this much recent idle frames
  double noise_quantile = 0.5;     // which quantile of the idle-frame energies (robust floor)
  double warmup_s = 0.1;           // idle frames needed before detection is enabled
  double min_noise_energy = 0.0;   // absolute lower bound of the noise floor (input units^2)
  double on_factor = 4.0;          // onset: frame energy > on_factor * noise floor
  double off_factor = 2.0;         // stays active while energy > off_factor * noise floor
  double release_fraction = 1e-3;  // ... and > release_fraction * the touch's peak frame energy
  double lookback_s = 0.3;         // onset moved back over frames > off threshold, this far at most
  double hold_s = 0.15;            // the touch ends after this long below the off threshold
  double min_duration_s = 0.05;    // touches shorter than this (onset..offset) are dropped
  double pad_before_s = 0.05;      // window start = onset - pad_before
  double pad_after_s = 0.05;       // window stop  = offset + pad_after
  double max_window_s = 7.0;       // a window never exceeds this (the touch is cut)
  double select = 2;               // batch, several touches: 0 most energetic, 1 first, 2 span
  double span_fraction = 0.05;     // select = span ignores touches below this fraction of the
                                   // most energetic touch's energy
  double fallback = 0;             // batch, no touch: 0 whole recording, 1 error
  // The bounded window (docs/preprocessing.md, "Bounded window"): the samples per taxel a
  // stream keeps of a window, an even count >= 2; a longer window is kept at half the time
  // resolution each time it fills (every 2nd, 4th, ... sample), so the detector's RAM does not
  // grow with max_window_s. 0 = every sample up to max_window_s (model format versions 1, 2).
  double window_samples = 1024;
};

inline constexpr std::size_t kWindowConfigSize = 20;
// The fields a model file of format version 1 or 2 holds: all but window_samples (the last),
// which such a file leaves at 0 (an unbounded window).
inline constexpr std::size_t kWindowConfigSizeV2 = 19;
// Field names, in the order of window_config_to_array (the serialisation order).
const std::array<const char*, kWindowConfigSize>& window_config_field_names();
std::array<double, kWindowConfigSize> window_config_to_array(const WindowConfig& cfg);
// Throws std::invalid_argument when n != kWindowConfigSize.
WindowConfig window_config_from_array(const double* values, std::size_t n);

// The configuration converted to samples and frames for one sample rate. Throws
// std::invalid_argument naming the bad field and value.
struct DetectorParams {
  int64_t frame_len = 0;       // samples per frame
  double dc_alpha = 0.0;       // DC blocker coefficient (0 = off)
  int combine = 0;
  int64_t noise_frames = 0;    // capacity of the idle-frame history
  double noise_quantile = 0.0;
  int64_t warmup_frames = 0;   // >= 1
  double min_noise_energy = 0.0;
  double on_factor = 0.0;
  double off_factor = 0.0;
  double release_fraction = 0.0;
  int64_t lookback_frames = 0;
  int64_t hold_frames = 0;
  int64_t min_duration = 0;    // samples
  int64_t pad_before = 0;      // samples
  int64_t pad_after = 0;       // samples
  int64_t max_window = 0;      // samples
  int select = 0;
  double span_fraction = 0.0;
  int fallback = 0;
  int64_t window_capacity = 0;  // samples per taxel the window buffer keeps (<= max_window)
};
DetectorParams resolve_window_config(const WindowConfig& cfg, double sample_rate_hz);

// Resource limits of the detector (docs/preprocessing.md, "Limits"): resolve_window_config
// refuses a configuration beyond them with a std::invalid_argument naming the field and value,
// before anything is allocated.
inline constexpr double kMaxFieldSamples = 1e13;               // |seconds * rate| of a time field
inline constexpr int64_t kMaxNoiseFrames = int64_t{1} << 20;     // noise_window_s in frames
inline constexpr int64_t kMaxLookbackFrames = int64_t{1} << 20;  // lookback_s in frames
inline constexpr int64_t kMaxWindowSamples = int64_t{1} << 24;   // max_window_s in samples
// Samples a TouchDetector with store_samples keeps: (pre-pad ring + window buffer) * n_taxels.
// The constructor, and the model loader for its grid, check it.
inline constexpr int64_t kMaxStoredValues = int64_t{1} << 25;
// The samples (StoredSample) a storing TouchDetector over n_taxels taxels allocates:
// (pre-pad ring + window_capacity) * n_taxels.
int64_t detector_stored_values(const DetectorParams& p, int64_t n_taxels) noexcept;
// Throws std::invalid_argument naming max_window_s when detector_stored_values > kMaxStoredValues.
void check_detector_buffers(const DetectorParams& p, const WindowConfig& cfg, int64_t n_taxels);

// One detected touch. onset/offset delimit where the energy was above threshold (frame
// resolution); start/stop add the padding and are clipped to the stream and to max_window.
struct TouchWindow {
  int64_t start = 0;
  int64_t stop = 0;
  int64_t onset = 0;
  int64_t offset = 0;
  double energy = 0.0;     // sum of frame energy * frame_len over the touch's frames
  bool truncated = false;  // cut by max_window (or by the end of the stream) while still active
  bool found = true;       // batch result only: false when no touch was found (fallback window)
  // The bounded window's decimation: the stream kept every stride-th sample of the window
  // (window_stride of the samples it pushed since `start`); subsampling reads window sample t
  // as sample (t / stride) * stride. 1 = every sample.
  int64_t stride = 1;
};

// The decimation of a bounded window buffer of `capacity` samples per taxel after `pushed`
// samples: the smallest power of two s with ceil(pushed / s) <= capacity (1 when capacity <= 0).
int64_t window_stride(int64_t pushed, int64_t capacity) noexcept;

// The raw samples a streaming detector keeps of the touch in progress (store_samples): float32
// on the host (exact for ADC codes, and for any integer up to 2^24; a double sample is rounded
// to float32); on a controller (the device build, ESKIN_DEVICE) the ADC codes themselves, int16
// (these buffers are the largest of the device path; a float or double sample pushed there is
// rounded to the nearest code in [-32768, 32767]).
#if defined(ESKIN_DEVICE)
using StoredSample = int16_t;
#else
using StoredSample = float;
#endif

enum class Status : int32_t {
  kOk = 0,                // sample consumed, nothing to report
  kWindow = 1,            // sample consumed and a touch window completed: see last_window()
  kNonFiniteSample = -1,  // a value was NaN or infinite: the sample was ignored (not counted)
  kNullPointer = -2,      // no data given
  kNoWindow = -3,         // subsample_last_window: there is no stored window
  kBadArgument = -4,      // subsample_last_window: D < 1, or S < D with ShortPolicy::kError
};
const char* status_name(Status s) noexcept;

enum class SubsampleMethod : int32_t {
  kAlgorithm2 = 0,  // interval = floor(S/D); sample (d-1)*interval, d = 1..D (the paper)
  kEven = 1,        // sample round(d*(S-1)/(D-1)), d = 0..D-1 (spread over the whole window)
};
enum class ShortPolicy : int32_t {
  kInterpolate = 0,  // S < D: linear interpolation of the S samples at D evenly spaced points
  kError = 1,        // S < D: error
};

// The D sample indices (0-based, into a window of S samples) chosen by the method, for S >= D.
// Writes D indices to out. No allocation, no exceptions; returns false when D < 1 or S < D.
bool subsample_indices(int64_t S, int64_t D, SubsampleMethod method, int64_t* out) noexcept;

// Subsample one window of S samples: x points at the window's first sample of taxel 0; taxel
// k's window sample t is x[k*taxel_stride + (t / decimation)*time_stride] (decimation > 1: a
// bounded window that kept every decimation-th sample, TouchWindow::stride; the indices are
// those of S samples, each read from the kept sample at or before it). Writes out[k*D + d].
// Returns kBadArgument (D < 1, S < 1, decimation < 1, or S < D with kError) without writing,
// else kOk. No allocation, no exceptions.
template <class T>
Status subsample_window(const T* x, int64_t n_taxels, int64_t taxel_stride, int64_t time_stride,
                        int64_t S, int64_t D, SubsampleMethod method, ShortPolicy short_policy,
                        double* out, int64_t decimation = 1) noexcept;

// How a streaming detector keeps the raw samples of the touch in progress (the samples its
// window's tensor is read from). The windows and the tensors are the same in every mode (for
// int16 input: kCodes keeps the codes themselves, kNative their exact float32 or int16 copy).
enum class SampleStore : int32_t {
  kNone = 0,    // none: the batch path reads the window from the recording instead
  kNative = 1,  // StoredSample: a pre-onset ring (pad_before + lookback + one frame) and the
                // bounded window buffer, side by side; the last window stays readable until the
                // next touch's onset
  kCodes = 2,   // int16 ADC codes (a float sample is rounded and clamped, as on a controller)
                // in one compact pool: the window buffer, a ring of the recent samples that a
                // next touch can still reach once this one has ended (pad_before + hold), and
                // the older part of the pre-onset ring, kept only between touches, in the
                // window buffer's free end (docs/skin-engine.md, "Memory"); the last window is
                // readable until the next push. On a controller (ESKIN_DEVICE) it is kNative,
                // whose StoredSample is the int16 code already
};

// Window buffers shared by SampleStore::kCodes detectors, for many streams that are not all
// touched at once (a skin's patches, docs/skin-engine.md "Shared window buffers"): `buffers`
// buffers of `samples` kept samples of up to `taxels` int16 codes each, allocated once.
// - Whole buffers (samples >= a detector's window_capacity): a detector takes one at a touch's
//   onset and gives it back at its first push after the touch ended (or at once for a touch too
//   short to report).
// - Chunks (samples < window_capacity): the window's kept samples live in chunks of `samples`,
//   taken one by one as the window grows, given back when the bounded window halves its kept
//   samples (the chunks above the kept half) and when the touch ends as above; a detector holds
//   a table of ceil(window_capacity / samples) chunk pointers. Memory in use then follows each
//   touch's kept samples instead of a whole buffer per touch.
// When none is free the touch is still detected (its later windows do not change) but its
// samples are not kept (any chunks it held go back), so it has no tensor (counted in
// unbuffered(), once per touch). Host only; not thread-safe (one engine thread).
class WindowBufferPool {
 public:
  WindowBufferPool() = default;
  // Throws std::invalid_argument when buffers < 0, or samples or taxels < 1 with buffers > 0.
  WindowBufferPool(int64_t buffers, int64_t samples, int64_t taxels);
  int16_t* acquire() noexcept;  // nullptr (and one more unbuffered()) when none is free
  void release(int16_t* buffer) noexcept;
  int64_t buffers() const noexcept { return static_cast<int64_t>(free_.size()); }
  int64_t samples() const noexcept { return samples_; }
  int64_t taxels() const noexcept { return taxels_; }
  int64_t values() const noexcept { return samples_ * taxels_; }
  int64_t in_use() const noexcept { return buffers() - n_free_; }
  int64_t peak_in_use() const noexcept { return peak_; }
  int64_t unbuffered() const noexcept { return unbuffered_; }
  void reset_counts() noexcept { peak_ = in_use(), unbuffered_ = 0; }
  int64_t memory_bytes() const noexcept;

 private:
  std::vector<int16_t> data_;
  std::vector<int16_t*> free_;  // [0, n_free_): the free buffers
  int64_t samples_ = 0;
  int64_t taxels_ = 0;
  int64_t n_free_ = 0;
  int64_t peak_ = 0;
  int64_t unbuffered_ = 0;
};

// The streaming detector. Feed it one multi-taxel sample at a time (push) or a block of
// samples (push_block); it reports a touch when it ends.
class TouchDetector {
 public:
  // store_samples: keep the raw samples of the current window (a pre-pad ring buffer plus a
  // max_window buffer) so that the window's tensor can be produced (subsample_last_window).
  // The batch path turns it off (it reads the window from the recording instead).
  TouchDetector(int64_t n_taxels, double sample_rate_hz, const WindowConfig& cfg,
                bool store_samples = true)
      : TouchDetector(n_taxels, sample_rate_hz, cfg,
                      store_samples ? SampleStore::kNative : SampleStore::kNone) {}
  // shared (kCodes only, host only): the window's kept samples are taken from this pool (a
  // whole buffer at each onset, or chunks as the window grows: WindowBufferPool) instead of
  // the detector's own pool, which then holds the pre-onset ring alone; it must outlive the
  // detector and hold at least n_taxels codes per sample (std::invalid_argument otherwise).
  TouchDetector(int64_t n_taxels, double sample_rate_hz, const WindowConfig& cfg,
                SampleStore store, WindowBufferPool* shared = nullptr);

  // One sample: n_taxels values. Returns kOk, kWindow (a touch ended with this sample; read
  // last_window() before the next push), kNonFiniteSample or kNullPointer.
  Status push(const int16_t* sample) noexcept { return step(sample, 1); }
  Status push(const float* sample) noexcept { return step(sample, 1); }
  Status push(const double* sample) noexcept { return step(sample, 1); }
  // One sample whose taxel k is at sample[k*taxel_stride] (e.g. a taxel-major recording).
  template <class T>
  Status push_strided(const T* sample, int64_t taxel_stride) noexcept {
    return step(sample, taxel_stride);
  }
  // A block of n samples, sample-major (n x n_taxels). Stops right after a sample that
  // completes a window (returns kWindow) or is rejected (returns that status; the bad sample
  // counts as consumed); *consumed tells how many samples were taken. Call again with the rest.
  template <class T>
  Status push_block(const T* samples, int64_t n, int64_t* consumed) noexcept;

  // End of stream: a touch in progress ends at the current sample. Returns kWindow or kOk.
  Status flush() noexcept;
  // Back to the state right after construction (buffers kept).
  void reset() noexcept;

  const TouchWindow& last_window() const noexcept { return last_; }
  // The raw samples kept of the last window (sample-major, n_taxels values per kept sample:
  // every last_window_stride()-th sample of its last_window_length() samples), or nullptr when
  // none is stored (store_samples off, SampleStore::kCodes, or overwritten by a newer touch's
  // onset).
  const StoredSample* last_window_data() const noexcept;
  int64_t last_window_length() const noexcept;
  int64_t last_window_stride() const noexcept { return last_.stride; }
  // The (n_taxels x D) tensor of the last window. No allocation, no exceptions.
  Status subsample_last_window(int64_t D, SubsampleMethod method, ShortPolicy short_policy,
                               double* out) const noexcept;

  int64_t n_taxels() const noexcept { return n_taxels_; }
  int64_t samples_seen() const noexcept { return now_; }
  bool in_touch() const noexcept { return state_ == State::kActive; }
  bool ready() const noexcept { return frames_seen_ >= p_.warmup_frames; }
  double noise_floor() const noexcept { return floor_; }
  double last_frame_energy() const noexcept { return last_energy_; }
  const DetectorParams& params() const noexcept { return p_; }
  const WindowConfig& config() const noexcept { return cfg_; }
  SampleStore sample_store() const noexcept { return mode_; }
  // Bytes this detector occupies: the object and every buffer it allocated.
  int64_t memory_bytes() const noexcept;

 private:
  enum class State { kIdle, kActive, kRefractory };

  template <class T>
  Status step(const T* x, int64_t taxel_stride) noexcept;
  Status on_frame() noexcept;
  Status finalise(bool forced) noexcept;
  void push_noise(double e) noexcept;
  // the window's next sample into the bounded window buffer w (window_)
  template <class S>
  void keep(S* w, const S* sample) noexcept;
  // kCodes: the window's next sample into its chunks (taking one from the shared pool when
  // the window grows into it; none free: the touch is lost, its chunks go back)
  void keep_code(const int16_t* sample) noexcept;
  // kCodes: kept sample j of the window (a shift and a mask for chunks of a power of two)
  int16_t* kept_slot(int64_t j) const noexcept {
    if (chunk_shift_ >= 0)
      return chunks_[static_cast<std::size_t>(j >> chunk_shift_)] + (j & (chunk_samples_ - 1)) * n_taxels_;
    return chunks_[static_cast<std::size_t>(j / chunk_samples_)] + (j % chunk_samples_) * n_taxels_;
  }
  void release_chunks(int64_t keep) noexcept;  // the shared chunks from `keep` on go back
  // kCodes: sample t's slot in the pool at an onset (t in [now - ring capacity, now))
  const int16_t* code_slot(int64_t t) const noexcept;
  template <class T>
  void store_code(const T* x, int64_t taxel_stride) noexcept;
  void release_window() noexcept;

  WindowConfig cfg_;
  DetectorParams p_;
  int64_t n_taxels_;
  SampleStore mode_;
  bool store_;

  int64_t dc_fast_n_ = 0;  // samples n < dc_fast_n_ use the running mean (1/(n+1) >= dc_alpha)
  // per-taxel state
  std::vector<double> dc_mean_;
  std::vector<double> acc_;
  // idle-frame energies (noise floor)
  std::vector<double> noise_ring_;    // in arrival order (to know which value leaves)
  std::vector<double> noise_sorted_;  // the same values, sorted (the quantile is an index)
  // energies of the last lookback_frames frames (onset backtracking)
  std::vector<double> frame_ring_;
  int64_t noise_count_ = 0;
  int64_t noise_pos_ = 0;
  // raw samples: pre-pad ring (capacity pad_before + frame_len) and the window buffer
  std::vector<StoredSample> ring_;
  int64_t ring_cap_ = 0;
  std::vector<StoredSample> window_;  // window_capacity kept samples
  int64_t window_len_ = 0;            // samples of the window pushed so far
  int64_t window_kept_ = 0;           // of which kept (every window_stride_-th)
  int64_t window_stride_ = 1;
  bool window_valid_ = false;
  // kCodes: one pool of int16 samples (n_taxels each): the window buffer at slots
  // [0, window_capacity), the recent ring at [window_capacity, + recent_cap_) (sample t at
  // slot window_capacity + t % recent_cap_), the older pre-onset samples in the window
  // buffer's last slots [old_at_, window_capacity) (sample t at old_at_ + t % old_cap_),
  // written only between touches
  std::vector<int16_t> pool_;
  int64_t ring_at_ = 0;  // the recent ring's first slot (window_capacity, or 0 when shared)
  WindowBufferPool* shared_ = nullptr;
  // the window's kept samples: kept sample j at chunks_[j / chunk_samples_], row
  // j % chunk_samples_; chunks_[0, held_) are held (own store: one chunk, the pool's start,
  // held for good; shared: taken from shared_ from an onset to the push after its end)
  std::vector<int16_t*> chunks_;
  int64_t chunk_samples_ = 1;
  int chunk_shift_ = -1;  // log2(chunk_samples_) when a power of two, else -1
  int64_t held_ = 0;
  bool lost_ = false;             // the touch in progress found no free chunk: no tensor
  bool release_pending_ = false;  // give the chunks back at the next push
  int64_t recent_cap_ = 0;
  int64_t old_cap_ = 0;
  int64_t old_at_ = 0;

  State state_ = State::kIdle;
  int64_t now_ = 0;          // samples consumed
  int64_t frame_pos_ = 0;    // samples in the current frame
  int64_t frames_seen_ = 0;  // complete frames
  double floor_ = 0.0;
  double last_energy_ = 0.0;
  // the touch in progress
  int64_t onset_ = 0;
  int64_t start_ = 0;
  int64_t last_above_end_ = 0;
  int64_t quiet_frames_ = 0;
  double energy_ = 0.0;
  double peak_ = 0.0;
  int64_t last_stop_ = 0;  // end of the previous touch (onset backtracking stops there)
  TouchWindow last_;
};

// ---- batch (whole recordings)

// Picks the one window of a recording among its touches (WindowConfig.select, span_fraction),
// fed the touches in stream order. Allocates at construction only; add() never allocates.
// Exact while at most capacity() touches are added (capacity_for gives a bound that holds for
// any recording of a given length); beyond that, span drops the least energetic touch.
class WindowSelector {
 public:
  explicit WindowSelector(const DetectorParams& p, int64_t capacity = 0);
  // The most touches a recording of `length` samples can produce with these parameters.
  static int64_t capacity_for(const DetectorParams& p, int64_t length) noexcept;
  void reset() noexcept { n_ = 0; }
  void add(const TouchWindow& w) noexcept;
  bool empty() const noexcept { return n_ == 0; }
  int64_t capacity() const noexcept { return static_cast<int64_t>(buf_.size()); }
  // The chosen window (found = true); precondition: !empty().
  TouchWindow result() const noexcept;

 private:
  int select_;
  double span_fraction_;
  int64_t max_window_;
  int64_t capacity_;
  std::vector<TouchWindow> buf_;
  int64_t n_ = 0;
};

// The touch window of one taxel-major recording (n_taxels x T, taxel stride T): runs a
// TouchDetector over its first `length` samples and picks one touch with cfg.select; when none
// is found, cfg.fallback decides (whole recording with found=false, or std::runtime_error).
// Throws std::invalid_argument for a NaN/inf sample (naming taxel and sample).
template <class T>
TouchWindow detect_window(const T* recording, int64_t n_taxels, int64_t T_total, int64_t length,
                          double sample_rate_hz, const WindowConfig& cfg);

// Windows of n recordings (data: n x n_taxels x T_total, lengths: n values in [1, T_total] or
// nullptr for T_total), on n_threads std::threads (0 = hardware concurrency). Errors name the
// recording index.
template <class T>
std::vector<TouchWindow> detect_windows(const T* data, int64_t n, int64_t n_taxels, int64_t T_total,
                                        const int64_t* lengths, double sample_rate_hz,
                                        const WindowConfig& cfg, int n_threads = 0);

enum class WindowMode : int32_t {
  kEnergy = 0,  // energy detector
  kNone = 1,    // the whole valid recording [0, length)
  kGiven = 2,   // windows given by the caller
};

// The largest D (samples per window after subsampling) preprocess and the models accept.
inline constexpr int64_t kMaxD = 100000;

struct PreprocessOptions {
  int64_t D = 100;
  WindowMode window = WindowMode::kEnergy;
  SubsampleMethod method = SubsampleMethod::kAlgorithm2;
  ShortPolicy short_policy = ShortPolicy::kInterpolate;
  double sample_rate_hz = 3000.0;
  WindowConfig config{};
  int n_threads = 0;
  // WindowMode::kGiven: `given` holds [start, stop, stride] triples instead of [start, stop)
  // pairs, stride being the bounded window's decimation the detector reported with the window
  // (TouchWindow::stride): the window is then read as the stream read it.
  bool given_strides = false;
};

// Preprocess n recordings: out receives n x n_taxels x D float64 values; windows_out (n
// entries, may be nullptr) receives the window used. With WindowMode::kGiven, `given` holds n
// [start, stop) pairs (2n values) within [0, length], read sample by sample (stride 1), or n
// [start, stop, stride] triples with opt.given_strides. Throws std::invalid_argument.
template <class T>
void preprocess(const T* data, int64_t n, int64_t n_taxels, int64_t T_total,
                const int64_t* lengths, const PreprocessOptions& opt, double* out,
                TouchWindow* windows_out = nullptr, const int64_t* given = nullptr);

}  // namespace eskin
