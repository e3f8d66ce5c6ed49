// Touch-window detector and Algorithm 2 subsampling; see preprocess.hpp and
// docs/preprocessing.md.
#include "eskin/preprocess.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <cstdio>
#include <stdexcept>
#include <string>
#include <type_traits>
#if !defined(ESKIN_DEVICE)  // the batch functions only: the device build has no threads
#include <atomic>
#include <exception>
#include <mutex>
#include <thread>
#endif

#include "raise.hpp"

namespace eskin {

namespace {

constexpr double kPi = 3.14159265358979323846;

// As `std::ostream << v` (%g, 6 digits), without iostreams (which a controller build leaves out).
std::string fmt(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%g", v);
  return buf;
}

[[noreturn]] void bad(const std::string& field, double value, const std::string& why) {
  detail::raise<std::invalid_argument>("WindowConfig." + field + " = " + fmt(value) + ": " + why);
}

int64_t to_samples(double seconds, double rate) {
  return static_cast<int64_t>(std::llround(seconds * rate));
}

int64_t ceil_div(int64_t a, int64_t b) { return (a + b - 1) / b; }

template <class T>
constexpr bool kIsFloat = std::is_floating_point_v<T>;

// A sample value as the detector stores it (StoredSample): unchanged on the host; on a
// controller, whose buffers hold int16 ADC codes, a floating-point value is rounded and clamped.
template <class T>
StoredSample to_stored(T v) noexcept {
  if constexpr (std::is_integral_v<StoredSample> && !std::is_same_v<T, StoredSample>) {
    const double r = std::nearbyint(static_cast<double>(v));
    return static_cast<StoredSample>(std::min(32767.0, std::max(-32768.0, r)));
  } else {
    return static_cast<StoredSample>(v);
  }
}

// A sample value as an ADC code (SampleStore::kCodes): an integer code unchanged, a
// floating-point value rounded to the nearest code in [-32768, 32767].
template <class T>
int16_t to_code(T v) noexcept {
  if constexpr (std::is_same_v<T, int16_t>) {
    return v;
  } else {
    const double r = std::nearbyint(static_cast<double>(v));
    return static_cast<int16_t>(std::min(32767.0, std::max(-32768.0, r)));
  }
}

}  // namespace

// ---------------------------------------------------------------- configuration

const std::array<const char*, kWindowConfigSize>& window_config_field_names() {
  static const std::array<const char*, kWindowConfigSize> names = {
      "frame_s",          "dc_cutoff_hz", "combine",        "noise_window_s",
      "noise_quantile",   "warmup_s",     "min_noise_energy", "on_factor",
      "off_factor",       "release_fraction", "lookback_s", "hold_s",
      "min_duration_s",   "pad_before_s", "pad_after_s",    "max_window_s",
      "select",           "span_fraction", "fallback",     "window_samples"};
  return names;
}

std::array<double, kWindowConfigSize> window_config_to_array(const WindowConfig& c) {
  return {c.frame_s,          c.dc_cutoff_hz,     c.combine,        c.noise_window_s,
          c.noise_quantile,   c.warmup_s,         c.min_noise_energy, c.on_factor,
          c.off_factor,       c.release_fraction, c.lookback_s,     c.hold_s,
          c.min_duration_s,   c.pad_before_s,     c.pad_after_s,    c.max_window_s,
          c.select,           c.span_fraction,    c.fallback,       c.window_samples};
}

WindowConfig window_config_from_array(const double* v, std::size_t n) {
  if (v == nullptr || n != kWindowConfigSize) {
    detail::raise<std::invalid_argument>("WindowConfig array: expected " +
                                std::to_string(kWindowConfigSize) + " values, got " +
                                std::to_string(v == nullptr ? 0 : n));
  }
  WindowConfig c;
  c.frame_s = v[0];
  c.dc_cutoff_hz = v[1];
  c.combine = v[2];
  c.noise_window_s = v[3];
  c.noise_quantile = v[4];
  c.warmup_s = v[5];
  c.min_noise_energy = v[6];
  c.on_factor = v[7];
  c.off_factor = v[8];
  c.release_fraction = v[9];
  c.lookback_s = v[10];
  c.hold_s = v[11];
  c.min_duration_s = v[12];
  c.pad_before_s = v[13];
  c.pad_after_s = v[14];
  c.max_window_s = v[15];
  c.select = v[16];
  c.span_fraction = v[17];
  c.fallback = v[18];
  c.window_samples = v[19];
  return c;
}

DetectorParams resolve_window_config(const WindowConfig& c, double rate) {
  if (!(std::isfinite(rate) && rate > 0)) {
    detail::raise<std::invalid_argument>("sample_rate_hz = " + fmt(rate) + ": must be finite and > 0");
  }
  const auto arr = window_config_to_array(c);
  for (std::size_t i = 0; i < kWindowConfigSize; ++i) {
    if (!std::isfinite(arr[i])) bad(window_config_field_names()[i], arr[i], "must be finite");
  }
  // times become sample counts: bounded first, so that no conversion or later sum overflows
  static constexpr std::size_t kTimeFields[] = {0, 3, 5, 10, 11, 12, 13, 14, 15};
  for (const std::size_t i : kTimeFields) {
    if (!(std::fabs(arr[i]) * rate <= kMaxFieldSamples)) {
      bad(window_config_field_names()[i], arr[i],
          "out of range (more than 1e13 samples at " + fmt(rate) + " Hz)");
    }
  }
  auto choice = [](const char* name, double v, int n) {
    if (v != std::floor(v) || v < 0 || v >= n) {
      bad(name, v, "must be an integer in [0, " + std::to_string(n - 1) + "]");
    }
    return static_cast<int>(v);
  };
  DetectorParams p;
  if (!(c.frame_s > 0)) bad("frame_s", c.frame_s, "must be > 0");
  p.frame_len = std::max<int64_t>(1, to_samples(c.frame_s, rate));
  if (c.dc_cutoff_hz < 0 || c.dc_cutoff_hz >= rate / 2) {
    bad("dc_cutoff_hz", c.dc_cutoff_hz, "must be in [0, sample_rate_hz/2)");
  }
  p.dc_alpha = c.dc_cutoff_hz > 0 ? 1.0 - std::exp(-2.0 * kPi * c.dc_cutoff_hz / rate) : 0.0;
  p.combine = choice("combine", c.combine, 3);
  if (!(c.noise_window_s > 0)) bad("noise_window_s", c.noise_window_s, "must be > 0");
  p.noise_frames = std::max<int64_t>(1, to_samples(c.noise_window_s, rate) / p.frame_len);
  if (p.noise_frames > kMaxNoiseFrames) {
    bad("noise_window_s", c.noise_window_s,
        "too large: " + std::to_string(p.noise_frames) + " frames of frame_s = " + fmt(c.frame_s) +
            " s, the limit is " + std::to_string(kMaxNoiseFrames));
  }
  if (c.noise_quantile < 0 || c.noise_quantile > 1) {
    bad("noise_quantile", c.noise_quantile, "must be in [0, 1]");
  }
  p.noise_quantile = c.noise_quantile;
  if (c.warmup_s < 0) bad("warmup_s", c.warmup_s, "must be >= 0");
  p.warmup_frames = std::max<int64_t>(1, ceil_div(to_samples(c.warmup_s, rate), p.frame_len));
  if (p.warmup_frames > p.noise_frames) {
    bad("warmup_s", c.warmup_s, "must not exceed noise_window_s = " + fmt(c.noise_window_s));
  }
  if (c.min_noise_energy < 0) bad("min_noise_energy", c.min_noise_energy, "must be >= 0");
  p.min_noise_energy = c.min_noise_energy;
  if (!(c.off_factor > 0)) bad("off_factor", c.off_factor, "must be > 0");
  if (!(c.on_factor >= c.off_factor)) {
    bad("on_factor", c.on_factor, "must be >= off_factor = " + fmt(c.off_factor) + " (hysteresis)");
  }
  p.on_factor = c.on_factor;
  p.off_factor = c.off_factor;
  if (c.release_fraction < 0 || c.release_fraction >= 1) {
    bad("release_fraction", c.release_fraction, "must be in [0, 1)");
  }
  p.release_fraction = c.release_fraction;
  if (c.lookback_s < 0) bad("lookback_s", c.lookback_s, "must be >= 0");
  p.lookback_frames = to_samples(c.lookback_s, rate) / p.frame_len;
  if (p.lookback_frames > kMaxLookbackFrames) {
    bad("lookback_s", c.lookback_s,
        "too large: " + std::to_string(p.lookback_frames) + " frames of frame_s = " +
            fmt(c.frame_s) + " s, the limit is " + std::to_string(kMaxLookbackFrames));
  }
  if (c.hold_s < 0) bad("hold_s", c.hold_s, "must be >= 0");
  p.hold_frames = std::max<int64_t>(1, ceil_div(to_samples(c.hold_s, rate), p.frame_len));
  if (c.min_duration_s < 0) bad("min_duration_s", c.min_duration_s, "must be >= 0");
  p.min_duration = to_samples(c.min_duration_s, rate);
  if (c.pad_before_s < 0) bad("pad_before_s", c.pad_before_s, "must be >= 0");
  if (c.pad_after_s < 0) bad("pad_after_s", c.pad_after_s, "must be >= 0");
  p.pad_before = to_samples(c.pad_before_s, rate);
  p.pad_after = to_samples(c.pad_after_s, rate);
  p.max_window = to_samples(c.max_window_s, rate);
  const int64_t room = p.pad_before + (p.lookback_frames + 2) * p.frame_len;
  if (p.max_window < room) {
    bad("max_window_s", c.max_window_s,
        "must leave room for pad_before_s, lookback_s and two frames (" +
            fmt(static_cast<double>(room) / rate) + " s)");
  }
  if (p.max_window > kMaxWindowSamples) {
    bad("max_window_s", c.max_window_s,
        "too large: " + std::to_string(p.max_window) + " samples at " + fmt(rate) +
            " Hz, the limit is " + std::to_string(kMaxWindowSamples));
  }
  p.select = choice("select", c.select, 3);
  if (c.span_fraction < 0 || c.span_fraction > 1) {
    bad("span_fraction", c.span_fraction, "must be in [0, 1]");
  }
  p.span_fraction = c.span_fraction;
  p.fallback = choice("fallback", c.fallback, 2);
  if (c.window_samples != std::floor(c.window_samples) || c.window_samples < 0 ||
      c.window_samples == 1 || std::fmod(c.window_samples, 2.0) != 0 ||
      c.window_samples > static_cast<double>(kMaxWindowSamples)) {
    bad("window_samples", c.window_samples,
        "must be 0 (every sample) or an even integer in [2, " + std::to_string(kMaxWindowSamples) +
            "]");
  }
  const auto cap = static_cast<int64_t>(c.window_samples);
  p.window_capacity = cap == 0 ? p.max_window : std::min(cap, p.max_window);
  return p;
}

int64_t detector_stored_values(const DetectorParams& p, int64_t n_taxels) noexcept {
  const int64_t ring = p.pad_before + (p.lookback_frames + 1) * p.frame_len;
  return (ring + p.window_capacity) * std::max<int64_t>(n_taxels, 0);
}

int64_t window_stride(int64_t pushed, int64_t capacity) noexcept {
  int64_t s = 1;
  if (capacity <= 0) return s;
  while ((pushed + s - 1) / s > capacity) s *= 2;
  return s;
}

void check_detector_buffers(const DetectorParams& p, const WindowConfig& cfg, int64_t n_taxels) {
  if (n_taxels > kMaxStoredValues) {
    detail::raise<std::invalid_argument>("n_taxels = " + std::to_string(n_taxels) + ": more than " +
                                std::to_string(kMaxStoredValues));
  }
  const int64_t values = detector_stored_values(p, n_taxels);
  if (values > kMaxStoredValues) {
    bad(cfg.window_samples > 0 ? "window_samples" : "max_window_s",
        cfg.window_samples > 0 ? cfg.window_samples : cfg.max_window_s,
        "too large for " + std::to_string(n_taxels) + " taxels: a stream detector would store " +
            std::to_string(values) + " samples (pre-pad ring and window), the limit is " +
            std::to_string(kMaxStoredValues));
  }
}

const char* status_name(Status s) noexcept {
  switch (s) {
    case Status::kOk: return "ok";
    case Status::kWindow: return "window";
    case Status::kNonFiniteSample: return "non-finite sample";
    case Status::kNullPointer: return "null pointer";
    case Status::kNoWindow: return "no window";
    case Status::kBadArgument: return "bad argument";
  }
  return "unknown";
}

// ---------------------------------------------------------------- subsampling

namespace {

// The (n_taxels x D) tensor of an S-sample window whose sample t of taxel k is at(k, t) (a
// double): Algorithm 2 or evenly spaced indices for S >= D, linear interpolation for S < D.
// The arguments are checked by the caller.
template <class At>
Status subsample_at(At at, int64_t n_taxels, int64_t S, int64_t D, SubsampleMethod method,
                    ShortPolicy short_policy, double* out) noexcept {
  if (S >= D) {
    const int64_t interval = S / D;
    const int64_t num = S - 1, den = std::max<int64_t>(D - 1, 1);
    for (int64_t k = 0; k < n_taxels; ++k) {
      double* ok = out + k * D;
      for (int64_t d = 0; d < D; ++d) {
        const int64_t t = method == SubsampleMethod::kAlgorithm2
                              ? d * interval
                              : (D == 1 ? 0 : (2 * d * num + den) / (2 * den));
        ok[d] = at(k, t);
      }
    }
    return Status::kOk;
  }
  if (short_policy == ShortPolicy::kError) return Status::kBadArgument;
  for (int64_t k = 0; k < n_taxels; ++k) {
    double* ok = out + k * D;
    for (int64_t d = 0; d < D; ++d) {
      const int64_t num = d * (S - 1);
      const int64_t i0 = num / (D - 1);
      const double frac = static_cast<double>(num - i0 * (D - 1)) / static_cast<double>(D - 1);
      const double a = at(k, i0);
      ok[d] = frac == 0.0 ? a : a + frac * (at(k, i0 + 1) - a);
    }
  }
  return Status::kOk;
}

}  // namespace

bool subsample_indices(int64_t S, int64_t D, SubsampleMethod method, int64_t* out) noexcept {
  if (D < 1 || S < D || out == nullptr) return false;
  if (method == SubsampleMethod::kAlgorithm2) {
    const int64_t interval = S / D;  // floor(S/D) >= 1
    for (int64_t d = 0; d < D; ++d) out[d] = d * interval;
  } else {
    if (D == 1) {
      out[0] = 0;
      return true;
    }
    // round(d*(S-1)/(D-1)) in exact integer arithmetic, halves rounded up
    const int64_t num = S - 1, den = D - 1;
    for (int64_t d = 0; d < D; ++d) out[d] = (2 * d * num + den) / (2 * den);
  }
  return true;
}

template <class T>
Status subsample_window(const T* x, int64_t n_taxels, int64_t taxel_stride, int64_t time_stride,
                        int64_t S, int64_t D, SubsampleMethod method, ShortPolicy short_policy,
                        double* out, int64_t decimation) noexcept {
  if (x == nullptr || out == nullptr) return Status::kNullPointer;
  if (D < 1 || S < 1 || n_taxels < 0 || decimation < 1) return Status::kBadArgument;
  if (decimation > 1) {
    // a bounded window kept every decimation-th sample: window sample t is the kept sample
    // t / decimation (time_stride apart); the indices are those of the S-sample window
    return subsample_at(
        [=](int64_t k, int64_t t) {
          return static_cast<double>(x[k * taxel_stride + (t / decimation) * time_stride]);
        },
        n_taxels, S, D, method, short_policy, out);
  }
  if (S >= D) {
    if (method == SubsampleMethod::kAlgorithm2) {
      const int64_t interval = S / D;
      for (int64_t k = 0; k < n_taxels; ++k) {
        const T* xk = x + k * taxel_stride;
        double* ok = out + k * D;
        for (int64_t d = 0; d < D; ++d) ok[d] = static_cast<double>(xk[d * interval * time_stride]);
      }
    } else {
      const int64_t num = S - 1, den = std::max<int64_t>(D - 1, 1);
      for (int64_t k = 0; k < n_taxels; ++k) {
        const T* xk = x + k * taxel_stride;
        double* ok = out + k * D;
        for (int64_t d = 0; d < D; ++d) {
          const int64_t t = D == 1 ? 0 : (2 * d * num + den) / (2 * den);
          ok[d] = static_cast<double>(xk[t * time_stride]);
        }
      }
    }
    return Status::kOk;
  }
  if (short_policy == ShortPolicy::kError) return Status::kBadArgument;
  // S < D (so D >= 2): linear interpolation at positions d*(S-1)/(D-1)
  for (int64_t k = 0; k < n_taxels; ++k) {
    const T* xk = x + k * taxel_stride;
    double* ok = out + k * D;
    for (int64_t d = 0; d < D; ++d) {
      const int64_t num = d * (S - 1);
      const int64_t i0 = num / (D - 1);
      const double frac = static_cast<double>(num - i0 * (D - 1)) / static_cast<double>(D - 1);
      const double a = static_cast<double>(xk[i0 * time_stride]);
      ok[d] = frac == 0.0 ? a
                          : a + frac * (static_cast<double>(xk[(i0 + 1) * time_stride]) - a);
    }
  }
  return Status::kOk;
}

template Status subsample_window<int16_t>(const int16_t*, int64_t, int64_t, int64_t, int64_t,
                                          int64_t, SubsampleMethod, ShortPolicy, double*,
                                          int64_t) noexcept;
template Status subsample_window<float>(const float*, int64_t, int64_t, int64_t, int64_t, int64_t,
                                        SubsampleMethod, ShortPolicy, double*, int64_t) noexcept;
template Status subsample_window<double>(const double*, int64_t, int64_t, int64_t, int64_t,
                                         int64_t, SubsampleMethod, ShortPolicy, double*,
                                         int64_t) noexcept;

// ---------------------------------------------------------------- streaming detector

#if !defined(ESKIN_DEVICE)
WindowBufferPool::WindowBufferPool(int64_t buffers, int64_t samples, int64_t taxels) {
  const bool sized = samples >= 1 && taxels >= 1 && samples <= kMaxStoredValues / taxels;
  if (buffers < 0 || buffers > kMaxStoredValues ||
      (buffers > 0 && (!sized || samples * taxels > kMaxStoredValues / buffers))) {
    detail::raise<std::invalid_argument>(
        "WindowBufferPool: " + std::to_string(buffers) + " buffers of " + std::to_string(samples) +
        " samples x " + std::to_string(taxels) +
        " taxels: must be >= 0 buffers of >= 1 sample x >= 1 taxel, at most " +
        std::to_string(kMaxStoredValues) + " values in all");
  }
  samples_ = samples;
  taxels_ = taxels;
  const int64_t values = buffers > 0 ? samples * taxels : 0;
  data_.assign(static_cast<std::size_t>(buffers * values), int16_t{0});
  free_.resize(static_cast<std::size_t>(buffers));
  for (int64_t b = 0; b < buffers; ++b) free_[static_cast<std::size_t>(b)] = data_.data() + b * values;
  n_free_ = buffers;
}

int16_t* WindowBufferPool::acquire() noexcept {
  if (n_free_ == 0) {
    ++unbuffered_;
    return nullptr;
  }
  int16_t* b = free_[static_cast<std::size_t>(--n_free_)];
  peak_ = std::max(peak_, in_use());
  return b;
}

void WindowBufferPool::release(int16_t* buffer) noexcept {
  if (buffer != nullptr && n_free_ < buffers()) free_[static_cast<std::size_t>(n_free_++)] = buffer;
}

int64_t WindowBufferPool::memory_bytes() const noexcept {
  return static_cast<int64_t>(sizeof(*this) + data_.capacity() * sizeof(int16_t) +
                              free_.capacity() * sizeof(int16_t*));
}

void TouchDetector::release_chunks(int64_t keep) noexcept {
  if (shared_ == nullptr) return;  // the own store's one chunk is held for good
  while (held_ > keep) shared_->release(chunks_[static_cast<std::size_t>(--held_)]);
}

void TouchDetector::release_window() noexcept {
  release_chunks(0);
  release_pending_ = false;
}

void TouchDetector::keep_code(const int16_t* sample) noexcept {
  // as keep(), over the chunks: every window_stride_-th sample is kept; a full window drops
  // every other kept sample, doubles its stride and gives back the chunks above the half
  const int64_t t = window_len_++;
  if (lost_ || (t & (window_stride_ - 1)) != 0) return;  // the stride is a power of two
  const int64_t K = n_taxels_;
  if (window_kept_ == p_.window_capacity) {
    for (int64_t j = 1; j < window_kept_ / 2; ++j) {
      const int16_t* from = kept_slot(2 * j);
      std::copy(from, from + K, kept_slot(j));
    }
    window_kept_ /= 2;
    window_stride_ *= 2;
    release_chunks(ceil_div(window_kept_, chunk_samples_));
  }
  if (window_kept_ == held_ * chunk_samples_) {  // the window grows into a new chunk
    int16_t* c = shared_ != nullptr ? shared_->acquire() : nullptr;
    if (c == nullptr) {  // none free: this touch keeps nothing (and has no tensor)
      lost_ = true;
      release_chunks(0);
      return;
    }
    chunks_[static_cast<std::size_t>(held_++)] = c;
  }
  std::copy(sample, sample + K, kept_slot(window_kept_));
  ++window_kept_;
}
#else
void TouchDetector::release_window() noexcept {}
#endif

TouchDetector::TouchDetector(int64_t n_taxels, double sample_rate_hz, const WindowConfig& cfg,
                             SampleStore store, WindowBufferPool* shared)
    : cfg_(cfg), p_(resolve_window_config(cfg, sample_rate_hz)), n_taxels_(n_taxels),
#if defined(ESKIN_DEVICE)
      // a controller's native store holds the int16 codes already (and one patch)
      mode_(store == SampleStore::kCodes ? SampleStore::kNative : store),
#else
      mode_(store),
#endif
      store_(store != SampleStore::kNone) {
  if (n_taxels < 1) {
    detail::raise<std::invalid_argument>("n_taxels = " + std::to_string(n_taxels) + ": must be >= 1");
  }
  if (p_.dc_alpha > 0) {
    // the number of first samples n for which 1/(n+1) >= dc_alpha
    int64_t N = static_cast<int64_t>(std::floor(1.0 / p_.dc_alpha));
    while (N >= 1 && 1.0 / static_cast<double>(N) < p_.dc_alpha) --N;
    while (1.0 / static_cast<double>(N + 1) >= p_.dc_alpha) ++N;
    dc_fast_n_ = N;
  }
  dc_mean_.assign(static_cast<std::size_t>(n_taxels), 0.0);
  acc_.assign(static_cast<std::size_t>(n_taxels), 0.0);
  noise_ring_.assign(static_cast<std::size_t>(p_.noise_frames), 0.0);
  noise_sorted_.assign(static_cast<std::size_t>(p_.noise_frames), 0.0);
  frame_ring_.assign(static_cast<std::size_t>(std::max<int64_t>(1, p_.lookback_frames)), 0.0);
  if (store_) {
    check_detector_buffers(p_, cfg_, n_taxels);
    ring_cap_ = p_.pad_before + (p_.lookback_frames + 1) * p_.frame_len;
  }
  if (mode_ == SampleStore::kNative) {
    ring_.assign(static_cast<std::size_t>(ring_cap_ * n_taxels), StoredSample{});
    window_.assign(static_cast<std::size_t>(p_.window_capacity * n_taxels), StoredSample{});
  }
#if !defined(ESKIN_DEVICE)
  if (mode_ == SampleStore::kCodes) {
    // Once a touch has ended (at sample F), the next touch's window starts at or after
    // stop - pad_before (its onset backtracking stops at stop), and stop is pad_after after the
    // last loud frame, F the quiet frames after it (hold_s, at least one frame, at least
    // pad_after_s): older samples of a touch are needed in its own window only. So while a
    // touch is active only the recent ring is written; between touches the sample leaving it
    // moves to the older part, which lives in the window buffer's last old_cap_ slots: an
    // onset copies the older samples first, into window slots below old_cap_ <= cap / 2.
    const int64_t fl = p_.frame_len, cap = p_.window_capacity;
    const int64_t quiet = std::max({p_.hold_frames, int64_t{1}, ceil_div(p_.pad_after, fl)});
    const int64_t needed = p_.pad_before + std::max<int64_t>(0, quiet * fl - p_.pad_after) + fl;
    recent_cap_ = std::min(ring_cap_, std::max(needed, ring_cap_ - cap / 2));
    chunk_samples_ = cap;  // the own store: one chunk, the window buffer at the pool's start
    if (shared != nullptr) {
      // the window buffer is not ours between touches: the whole pre-onset ring is recent
      if (shared->taxels() < n_taxels || shared->samples() < 1) {
        detail::raise<std::invalid_argument>(
            "TouchDetector: shared window buffers of " + std::to_string(shared->taxels()) +
            " taxels: this detector has " + std::to_string(n_taxels));
      }
      shared_ = shared;
      recent_cap_ = ring_cap_;
      chunk_samples_ = std::min(cap, shared->samples());  // a whole buffer when samples >= cap
    }
    old_cap_ = ring_cap_ - recent_cap_;
    old_at_ = cap - old_cap_;
    ring_at_ = shared != nullptr ? 0 : cap;
    const int64_t slots = ring_at_ + recent_cap_;
    pool_.assign(static_cast<std::size_t>(slots * n_taxels), int16_t{0});
    chunks_.assign(static_cast<std::size_t>(ceil_div(cap, chunk_samples_)), nullptr);
    if (shared == nullptr) {  // one chunk: any power of two >= cap indexes it
      chunk_samples_ = 1;
      while (chunk_samples_ < cap) chunk_samples_ *= 2;
    }
    if ((chunk_samples_ & (chunk_samples_ - 1)) == 0) {
      chunk_shift_ = 0;
      while ((int64_t{1} << chunk_shift_) < chunk_samples_) ++chunk_shift_;
    }
    if (shared == nullptr) chunks_[0] = pool_.data(), held_ = 1;
  }
#endif
#if !defined(ESKIN_DEVICE)
  if (shared != nullptr && mode_ != SampleStore::kCodes) {
    detail::raise<std::invalid_argument>(
        "TouchDetector: shared window buffers need SampleStore::kCodes on the host");
  }
#else
  (void)shared;  // a controller has one stream and its own buffers
#endif
  reset();
}

int64_t TouchDetector::memory_bytes() const noexcept {
  auto bytes = [](const auto& v) {
    return static_cast<int64_t>(v.capacity() * sizeof(typename std::decay_t<decltype(v)>::value_type));
  };
  return static_cast<int64_t>(sizeof(*this)) + bytes(dc_mean_) + bytes(acc_) + bytes(noise_ring_) +
         bytes(noise_sorted_) + bytes(frame_ring_) + bytes(ring_) + bytes(window_) + bytes(pool_) +
         bytes(chunks_);
}

#if !defined(ESKIN_DEVICE)
const int16_t* TouchDetector::code_slot(int64_t t) const noexcept {
  const int64_t slot = t >= now_ - recent_cap_ ? ring_at_ + t % recent_cap_ : old_at_ + t % old_cap_;
  return pool_.data() + slot * n_taxels_;
}

template <class T>
void TouchDetector::store_code(const T* x, int64_t taxel_stride) noexcept {
  const int64_t K = n_taxels_;
  if (release_pending_) {  // the last window has been read: its shared chunks go back
    release_window();
    window_valid_ = false;
  }
  int16_t* pool = pool_.data();
  int16_t* r = pool + (ring_at_ + now_ % recent_cap_) * K;
  if (state_ != State::kActive && old_cap_ > 0 && now_ >= recent_cap_) {
    // between touches: sample now - recent_cap_ leaves the recent ring for the older part
    std::copy(r, r + K, pool + (old_at_ + (now_ - recent_cap_) % old_cap_) * K);
  }
  for (int64_t k = 0; k < K; ++k) r[k] = to_code(x[k * taxel_stride]);
  if (state_ == State::kActive) keep_code(r);
}
#endif

void TouchDetector::reset() noexcept {
  release_window();
  lost_ = false;
  std::fill(dc_mean_.begin(), dc_mean_.end(), 0.0);
  std::fill(acc_.begin(), acc_.end(), 0.0);
  noise_count_ = noise_pos_ = 0;
  window_len_ = window_kept_ = 0;
  window_stride_ = 1;
  window_valid_ = false;
  state_ = State::kIdle;
  now_ = frame_pos_ = frames_seen_ = 0;
  floor_ = p_.min_noise_energy;
  last_energy_ = 0.0;
  onset_ = start_ = last_above_end_ = quiet_frames_ = 0;
  energy_ = peak_ = 0.0;
  last_stop_ = 0;
  std::fill(frame_ring_.begin(), frame_ring_.end(), 0.0);
  last_ = TouchWindow{};
}

template <class T>
Status TouchDetector::step(const T* x, int64_t taxel_stride) noexcept {
  if (x == nullptr) return Status::kNullPointer;
  if constexpr (kIsFloat<T>) {
    for (int64_t k = 0; k < n_taxels_; ++k) {
      if (!std::isfinite(x[k * taxel_stride])) return Status::kNonFiniteSample;
    }
  }
  const int64_t K = n_taxels_;
  if (mode_ == SampleStore::kNative) {
    StoredSample* r = ring_.data() + (now_ % ring_cap_) * K;
    for (int64_t k = 0; k < K; ++k) r[k] = to_stored(x[k * taxel_stride]);
    if (state_ == State::kActive) keep(window_.data(), static_cast<const StoredSample*>(r));
  }
#if !defined(ESKIN_DEVICE)
  if (mode_ == SampleStore::kCodes) store_code(x, taxel_stride);
#endif
  double* __restrict acc = acc_.data();
  if (p_.dc_alpha > 0) {
    // DC blocker: an exponential mean with a fast start (the plain running mean while that is
    // the faster, i.e. a = max(dc_alpha, 1/(n+1)), so that an ADC offset is removed from the
    // first sample on)
    const double a = now_ < dc_fast_n_ ? 1.0 / static_cast<double>(now_ + 1) : p_.dc_alpha;
    double* __restrict m = dc_mean_.data();
    for (int64_t k = 0; k < K; ++k) {
      const double v = static_cast<double>(x[k * taxel_stride]);
      m[k] += a * (v - m[k]);
      const double y = v - m[k];
      acc[k] += y * y;
    }
  } else {
    for (int64_t k = 0; k < K; ++k) {
      const double y = static_cast<double>(x[k * taxel_stride]);
      acc[k] += y * y;
    }
  }
  ++now_;
  Status st = Status::kOk;
  if (state_ == State::kActive && now_ - start_ >= p_.max_window) st = finalise(true);
  if (++frame_pos_ == p_.frame_len) {
    frame_pos_ = 0;
    if (on_frame() == Status::kWindow) st = Status::kWindow;
  }
  return st;
}

template <class T>
Status TouchDetector::push_block(const T* samples, int64_t n, int64_t* consumed) noexcept {
  int64_t i = 0;
  Status st = Status::kOk;
  if (samples == nullptr && n > 0) {
    st = Status::kNullPointer;
  } else {
    while (i < n) {
      st = step(samples + i * n_taxels_, 1);
      ++i;
      if (st != Status::kOk) break;
    }
  }
  if (consumed != nullptr) *consumed = i;
  return st;
}

template <class S>
void TouchDetector::keep(S* w, const S* sample) noexcept {
  // the bounded window: every window_stride_-th sample is kept; when the buffer is full, every
  // other kept sample is dropped and the stride doubles (the time resolution halves)
  const int64_t t = window_len_++;
  if (t % window_stride_ != 0) return;
  const int64_t K = n_taxels_;
  if (window_kept_ == p_.window_capacity) {
    for (int64_t j = 1; j < window_kept_ / 2; ++j) std::copy(w + 2 * j * K, w + (2 * j + 1) * K, w + j * K);
    window_kept_ /= 2;
    window_stride_ *= 2;  // t = capacity * old stride = (capacity / 2) * new stride: kept
  }
  std::copy(sample, sample + K, w + window_kept_ * K);
  ++window_kept_;
}

void TouchDetector::push_noise(double e) noexcept {
  // keep noise_sorted_ sorted: drop the value that leaves the window, insert the new one
  // (a shift of at most noise_frames values, instead of a selection per frame)
  double* sorted = noise_sorted_.data();
  int64_t n = noise_count_;
  if (n == p_.noise_frames) {
    const double old = noise_ring_[noise_pos_];
    const int64_t i = std::lower_bound(sorted, sorted + n, old) - sorted;
    std::copy(sorted + i + 1, sorted + n, sorted + i);
    --n;
  }
  const int64_t j = std::upper_bound(sorted, sorted + n, e) - sorted;
  std::copy_backward(sorted + j, sorted + n, sorted + n + 1);
  sorted[j] = e;
  noise_count_ = n + 1;
  noise_ring_[noise_pos_] = e;
  noise_pos_ = (noise_pos_ + 1) % p_.noise_frames;
  // the "lower" quantile: element floor(q*(n-1)) of the sorted values (numpy method="lower")
  const auto kq = static_cast<int64_t>(
      std::floor(p_.noise_quantile * static_cast<double>(noise_count_ - 1)));
  floor_ = std::max(p_.min_noise_energy, sorted[kq]);
}

Status TouchDetector::on_frame() noexcept {
  const double inv = 1.0 / static_cast<double>(p_.frame_len);
  double e = 0.0;
  if (p_.combine == 1) {
    for (double v : acc_) e = std::max(e, v);
  } else {
    double top = 0.0;
    for (double v : acc_) {
      e += v;
      top = std::max(top, v);
    }
    // combine 2: the sum without the most energetic taxel (one noisy taxel cannot trigger)
    if (p_.combine == 2 && n_taxels_ > 1) e -= top;
  }
  e *= inv;  // mean square per sample (summed, maxed or trimmed over taxels)
  std::fill(acc_.begin(), acc_.end(), 0.0);
  last_energy_ = e;
  const int64_t f = frames_seen_++;  // index of this frame
  // energies of the frames before this one, for onset backtracking
  const auto ring_n = static_cast<int64_t>(frame_ring_.size());
  auto previous = [&](int64_t j) { return frame_ring_[(f - j) % ring_n]; };  // frame f - j
  Status st = Status::kOk;
  if (frames_seen_ <= p_.warmup_frames) {
    push_noise(e);
  } else {
    const double on = p_.on_factor * floor_;
    const double off = p_.off_factor * floor_;
    switch (state_) {
      case State::kIdle:
        if (e > on) {
          state_ = State::kActive;
          // double-threshold hysteresis: the touch also covers the frames just before the
          // trigger that were already above the off threshold (at most lookback_frames, not
          // into the warm-up nor the previous touch)
          int64_t first = f;
          while (f - first < p_.lookback_frames && first - 1 >= p_.warmup_frames &&
                 (first - 1) * p_.frame_len >= last_stop_ && previous(f - first + 1) > off) {
            --first;
          }
          onset_ = first * p_.frame_len;
          start_ = std::max<int64_t>(0, onset_ - p_.pad_before);
          last_above_end_ = now_;
          quiet_frames_ = 0;
          energy_ = e * static_cast<double>(p_.frame_len);
          for (int64_t j = 1; j <= f - first; ++j) {
            energy_ += previous(j) * static_cast<double>(p_.frame_len);
          }
          peak_ = e;
          window_valid_ = false;
          if (store_) {
            window_len_ = window_kept_ = 0;
            window_stride_ = 1;
#if !defined(ESKIN_DEVICE)
            if (mode_ == SampleStore::kCodes) {
              // oldest first: the older part's samples go to window slots below old_at_
              lost_ = false;
              for (int64_t t = start_; t < now_; ++t) keep_code(code_slot(t));
            } else  // the native store:
#endif
            {
              for (int64_t t = start_; t < now_; ++t)
                keep(window_.data(),
                     static_cast<const StoredSample*>(ring_.data() + (t % ring_cap_) * n_taxels_));
            }
          }
        } else {
          push_noise(e);
        }
        break;
      case State::kActive: {
        peak_ = std::max(peak_, e);
        if (e > std::max(off, p_.release_fraction * peak_)) {
          last_above_end_ = now_;
          quiet_frames_ = 0;
          energy_ += e * static_cast<double>(p_.frame_len);
        } else if (++quiet_frames_ >= p_.hold_frames && now_ >= last_above_end_ + p_.pad_after) {
          st = finalise(false);
        }
        break;
      }
      case State::kRefractory:
        // after a cut at max_window: wait for the energy to fall, re-learning the noise floor
        // meanwhile (a raised background is not a touch that never ends)
        if (e <= off) state_ = State::kIdle;
        push_noise(e);
        break;
    }
  }
  if (ring_n > 0) frame_ring_[f % ring_n] = e;
  return st;
}

Status TouchDetector::finalise(bool forced) noexcept {
  // still above threshold (or not yet quiet for the hold time): the touch was cut here
  const bool truncated = quiet_frames_ < p_.hold_frames && quiet_frames_ == 0;
  TouchWindow w;
  w.onset = onset_;
  w.start = start_;
  w.offset = truncated ? now_ : last_above_end_;
  w.stop = truncated ? now_ : std::min(now_, last_above_end_ + p_.pad_after);
  w.energy = energy_;
  w.truncated = truncated;
  w.found = true;
  w.stride = window_stride(now_ - start_, p_.window_capacity);  // = window_stride_ when storing
  state_ = forced ? State::kRefractory : State::kIdle;
  last_stop_ = w.stop;
  if (w.offset - w.onset < p_.min_duration) {
    if (store_) window_len_ = window_kept_ = 0;
    release_window();
    return Status::kOk;
  }
  last_ = w;
  if (store_) window_valid_ = !lost_;
  release_pending_ = shared_ != nullptr && held_ > 0;
  return Status::kWindow;
}

Status TouchDetector::flush() noexcept {
  if (state_ != State::kActive) return Status::kOk;
  return finalise(false);
}

const StoredSample* TouchDetector::last_window_data() const noexcept {
  return (mode_ == SampleStore::kNative && window_valid_) ? window_.data() : nullptr;
}

int64_t TouchDetector::last_window_length() const noexcept {
  return (store_ && window_valid_) ? last_.stop - last_.start : 0;
}

Status TouchDetector::subsample_last_window(int64_t D, SubsampleMethod method,
                                            ShortPolicy short_policy, double* out) const noexcept {
#if !defined(ESKIN_DEVICE)
  if (mode_ == SampleStore::kCodes && window_valid_) {
    if (out == nullptr) return Status::kNullPointer;
    if (D < 1 || last_window_length() < 1) return Status::kBadArgument;
    const int64_t step = last_.stride;
    return subsample_at(
        [this, step](int64_t k, int64_t t) { return static_cast<double>(kept_slot(t / step)[k]); },
        n_taxels_, last_window_length(), D, method, short_policy, out);
  }
#endif
  const StoredSample* data = last_window_data();
  if (data == nullptr) return Status::kNoWindow;
  return subsample_window(data, n_taxels_, 1, n_taxels_, last_window_length(), D, method,
                          short_policy, out, last_.stride);
}

template Status TouchDetector::push_block<int16_t>(const int16_t*, int64_t, int64_t*) noexcept;
template Status TouchDetector::push_block<float>(const float*, int64_t, int64_t*) noexcept;
template Status TouchDetector::push_block<double>(const double*, int64_t, int64_t*) noexcept;
template Status TouchDetector::step<int16_t>(const int16_t*, int64_t) noexcept;
template Status TouchDetector::step<float>(const float*, int64_t) noexcept;
template Status TouchDetector::step<double>(const double*, int64_t) noexcept;

// ---------------------------------------------------------------- window selection

int64_t WindowSelector::capacity_for(const DetectorParams& p, int64_t length) noexcept {
  // reported touches: each next onset is at or after the previous stop, so onsets are at least
  // min_duration apart; each next trigger comes after the previous end decision, so offsets
  // are at least hold (and one frame) apart
  const int64_t period =
      std::max({p.frame_len, p.min_duration, p.hold_frames * p.frame_len});
  return std::max<int64_t>(1, length / std::max<int64_t>(1, period) + 2);
}

WindowSelector::WindowSelector(const DetectorParams& p, int64_t capacity)
    : select_(p.select), span_fraction_(p.span_fraction), max_window_(p.max_window),
      capacity_(p.window_capacity) {
  if (capacity < 1) capacity = capacity_for(p, 4 * p.max_window);
  buf_.assign(static_cast<std::size_t>(select_ == 2 ? capacity : 1), TouchWindow{});
}

void WindowSelector::add(const TouchWindow& w) noexcept {
  if (select_ == 1) {  // first
    if (n_ == 0) buf_[0] = w, n_ = 1;
    return;
  }
  if (select_ == 0) {  // most energetic (the earliest on ties)
    if (n_ == 0 || w.energy > buf_[0].energy) buf_[0] = w;
    n_ = 1;
    return;
  }
  const auto cap = static_cast<int64_t>(buf_.size());
  if (n_ == cap) {  // full: drop the least energetic touch (never reached within capacity_for)
    int64_t lo = 0;
    for (int64_t i = 1; i < n_; ++i) {
      if (buf_[i].energy < buf_[lo].energy) lo = i;
    }
    if (w.energy <= buf_[lo].energy) return;
    for (int64_t i = lo; i + 1 < n_; ++i) buf_[i] = buf_[i + 1];
    --n_;
  }
  buf_[n_++] = w;
}

TouchWindow WindowSelector::result() const noexcept {
  if (select_ != 2 || n_ == 0) return buf_[0];
  double peak = buf_[0].energy;
  for (int64_t i = 1; i < n_; ++i) peak = std::max(peak, buf_[i].energy);
  // span: from the first to the last touch holding at least span_fraction of the peak energy
  const double min_energy = span_fraction_ * peak;
  TouchWindow out{};
  bool any = false;
  for (int64_t i = 0; i < n_; ++i) {
    const TouchWindow& w = buf_[i];
    if (w.energy < min_energy) continue;
    if (!any) {
      out = w;
      any = true;
      continue;
    }
    out.energy += w.energy;
    out.truncated = out.truncated || w.truncated || w.stop > out.start + max_window_;
    out.stop = std::min(w.stop, out.start + max_window_);
    out.offset = std::min(w.offset, out.stop);
    // a span of several touches is read as a bounded window of its length would keep it
    out.stride = std::max({out.stride, w.stride, window_stride(out.stop - out.start, capacity_)});
  }
  return out;
}

// ---------------------------------------------------------------- batch
#if !defined(ESKIN_DEVICE)  // the device build (ESKIN_DEVICE) streams: no batch functions

namespace {

// Chooses one window among the touches of a recording (cfg.select).
constexpr int64_t kBlock = 256;  // samples transposed at a time by the batch path

// Runs the detector over one taxel-major recording: blocks of kBlock samples are transposed to
// the stream's sample-major layout into `block` (n_taxels * kBlock values) and pushed, so the
// taxels of a sample are processed side by side (independent dependency chains).
template <class T>
TouchWindow detect_one(TouchDetector& det, WindowSelector& sel, std::vector<T>& block,
                       const T* rec, int64_t T_total, int64_t length, int64_t index) {
  det.reset();
  sel.reset();
  const DetectorParams& p = det.params();
  const int64_t K = det.n_taxels();
  for (int64_t t0 = 0; t0 < length; t0 += kBlock) {
    const int64_t n = std::min(kBlock, length - t0);
    for (int64_t k = 0; k < K; ++k) {
      const T* src = rec + k * T_total + t0;
      for (int64_t j = 0; j < n; ++j) block[j * K + k] = src[j];
    }
    int64_t done = 0;
    while (done < n) {
      int64_t consumed = 0;
      const Status st = det.push_block(block.data() + done * K, n - done, &consumed);
      done += consumed;
      if (st == Status::kWindow) sel.add(det.last_window());
      if (st != Status::kNonFiniteSample) continue;
      const int64_t t = t0 + done - 1;
      for (int64_t k = 0; k < K; ++k) {
        if (!std::isfinite(static_cast<double>(rec[k * T_total + t]))) {
          throw std::invalid_argument(
              (index >= 0 ? "signals[" + std::to_string(index) + "]" : std::string("signal")) +
              " has a non-finite value at taxel " + std::to_string(k) + ", sample " +
              std::to_string(t));
        }
      }
    }
  }
  if (det.flush() == Status::kWindow) sel.add(det.last_window());
  if (!sel.empty()) return sel.result();
  if (p.fallback == 1) {
    throw std::runtime_error(
        (index >= 0 ? "signals[" + std::to_string(index) + "]" : std::string("signal")) +
        ": no touch detected (WindowConfig.fallback = 1)");
  }
  TouchWindow w;
  w.start = w.onset = 0;
  w.stop = w.offset = length;
  w.found = false;
  return w;
}

// Per-thread state of the batch functions, allocated once per thread.
template <class T>
struct Worker {
  Worker(const TouchDetector& proto, int64_t T_total)
      : det(proto),
        sel(proto.params(), WindowSelector::capacity_for(proto.params(), T_total)),
        block(static_cast<std::size_t>(proto.n_taxels() * kBlock)) {}
  TouchDetector det;
  WindowSelector sel;
  std::vector<T> block;
};

void check_batch(int64_t n, int64_t n_taxels, int64_t T_total, const int64_t* lengths) {
  if (n < 0) throw std::invalid_argument("n = " + std::to_string(n) + ": must be >= 0");
  if (n_taxels < 1) {
    throw std::invalid_argument("n_taxels = " + std::to_string(n_taxels) + ": must be >= 1");
  }
  if (T_total < 1) {
    throw std::invalid_argument("T = " + std::to_string(T_total) + ": must be >= 1");
  }
  if (lengths != nullptr) {
    for (int64_t i = 0; i < n; ++i) {
      if (lengths[i] < 1 || lengths[i] > T_total) {
        throw std::invalid_argument("lengths[" + std::to_string(i) + "] = " +
                                    std::to_string(lengths[i]) + ": must be in [1, " +
                                    std::to_string(T_total) + "]");
      }
    }
  }
}

// Runs body(worker_state, i) for i in [0, n) on up to n_threads threads; rethrows the first
// error (lowest index) in the caller.
template <class MakeState, class Body>
void parallel_for(int64_t n, int n_threads, MakeState make_state, Body body) {
  if (n == 0) return;
  int nt = n_threads > 0 ? n_threads : static_cast<int>(std::thread::hardware_concurrency());
  nt = static_cast<int>(std::max<int64_t>(1, std::min<int64_t>(nt, n)));
  std::atomic<int64_t> next{0};
  std::mutex mu;
  std::exception_ptr err;
  int64_t err_index = std::numeric_limits<int64_t>::max();
  auto worker = [&]() {
    try {
      auto state = make_state();
      for (int64_t i = next++; i < n; i = next++) {
        try {
          body(state, i);
        } catch (...) {
          std::lock_guard<std::mutex> lock(mu);
          if (i < err_index) {
            err_index = i;
            err = std::current_exception();
          }
        }
      }
    } catch (...) {
      std::lock_guard<std::mutex> lock(mu);
      if (!err) err = std::current_exception();
    }
  };
  if (nt == 1) {
    worker();
  } else {
    std::vector<std::thread> threads;
    threads.reserve(static_cast<std::size_t>(nt));
    for (int i = 0; i < nt; ++i) threads.emplace_back(worker);
    for (auto& t : threads) t.join();
  }
  if (err) std::rethrow_exception(err);
}

}  // namespace

template <class T>
TouchWindow detect_window(const T* recording, int64_t n_taxels, int64_t T_total, int64_t length,
                          double sample_rate_hz, const WindowConfig& cfg) {
  if (recording == nullptr) throw std::invalid_argument("recording is null");
  if (length < 1 || length > T_total) {
    throw std::invalid_argument("length = " + std::to_string(length) + ": must be in [1, " +
                                std::to_string(T_total) + "]");
  }
  Worker<T> wk(TouchDetector(n_taxels, sample_rate_hz, cfg, false), length);
  return detect_one(wk.det, wk.sel, wk.block, recording, T_total, length, -1);
}

template <class T>
std::vector<TouchWindow> detect_windows(const T* data, int64_t n, int64_t n_taxels, int64_t T_total,
                                        const int64_t* lengths, double sample_rate_hz,
                                        const WindowConfig& cfg, int n_threads) {
  check_batch(n, n_taxels, T_total, lengths);
  TouchDetector proto(n_taxels, sample_rate_hz, cfg, false);  // validates cfg once
  std::vector<TouchWindow> out(static_cast<std::size_t>(n));
  parallel_for(
      n, n_threads, [&]() { return Worker<T>(proto, T_total); },
      [&](Worker<T>& wk, int64_t i) {
        const int64_t len = lengths ? lengths[i] : T_total;
        const T* rec = data + i * n_taxels * T_total;
        out[i] = detect_one(wk.det, wk.sel, wk.block, rec, T_total, len, i);
      });
  return out;
}

template <class T>
void preprocess(const T* data, int64_t n, int64_t n_taxels, int64_t T_total,
                const int64_t* lengths, const PreprocessOptions& opt, double* out,
                TouchWindow* windows_out, const int64_t* given) {
  check_batch(n, n_taxels, T_total, lengths);
  if (opt.D < 1 || opt.D > kMaxD) {
    throw std::invalid_argument("D = " + std::to_string(opt.D) + ": must be in [1, " +
                                std::to_string(kMaxD) + "]");
  }
  if (opt.window == WindowMode::kGiven && given == nullptr) {
    throw std::invalid_argument("window = given but no windows were passed");
  }
  const bool energy = opt.window == WindowMode::kEnergy;
  // validates the configuration and the rate even when it is not used
  TouchDetector proto(n_taxels, opt.sample_rate_hz, opt.config, false);
  parallel_for(
      n, opt.n_threads, [&]() { return Worker<T>(proto, T_total); },
      [&](Worker<T>& wk, int64_t i) {
        const T* rec = data + i * n_taxels * T_total;
        const int64_t len = lengths ? lengths[i] : T_total;
        TouchWindow w;
        if (energy) {
          w = detect_one(wk.det, wk.sel, wk.block, rec, T_total, len, i);
        } else if (opt.window == WindowMode::kGiven) {
          const int64_t cols = opt.given_strides ? 3 : 2;
          w.start = w.onset = given[cols * i];
          w.stop = w.offset = given[cols * i + 1];
          if (w.start < 0 || w.stop > len || w.stop <= w.start) {
            throw std::invalid_argument("windows[" + std::to_string(i) + "] = [" +
                                        std::to_string(w.start) + ", " + std::to_string(w.stop) +
                                        "): must satisfy 0 <= start < stop <= length = " +
                                        std::to_string(len));
          }
          if (opt.given_strides) {
            w.stride = given[cols * i + 2];
            // a decimation the bounded window can have: a power of two, at most the window
            if (w.stride < 1 || (w.stride & (w.stride - 1)) != 0 || w.stride > w.stop - w.start) {
              throw std::invalid_argument("windows[" + std::to_string(i) + "]: stride = " +
                                          std::to_string(w.stride) +
                                          ": must be a power of two in [1, stop - start = " +
                                          std::to_string(w.stop - w.start) + "]");
            }
          }
        } else {
          w.start = w.onset = 0;
          w.stop = w.offset = len;
          if constexpr (kIsFloat<T>) {
            for (int64_t k = 0; k < n_taxels; ++k) {
              for (int64_t t = 0; t < len; ++t) {
                if (!std::isfinite(rec[k * T_total + t])) {
                  throw std::invalid_argument("signals[" + std::to_string(i) +
                                              "] has a non-finite value at taxel " +
                                              std::to_string(k) + ", sample " + std::to_string(t));
                }
              }
            }
          }
        }
        if (windows_out != nullptr) windows_out[i] = w;
        const int64_t S = w.stop - w.start;
        const Status st = subsample_window(rec + w.start, n_taxels, T_total, w.stride, S, opt.D,
                                           opt.method, opt.short_policy,
                                           out + i * n_taxels * opt.D, w.stride);
        if (st != Status::kOk) {
          throw std::invalid_argument("signals[" + std::to_string(i) + "]: window of S = " +
                                      std::to_string(S) + " samples is shorter than D = " +
                                      std::to_string(opt.D) + " (short = error)");
        }
      });
}

#define ESKIN_INSTANTIATE(T)                                                                     \
  template TouchWindow detect_window<T>(const T*, int64_t, int64_t, int64_t, double,             \
                                        const WindowConfig&);                                    \
  template std::vector<TouchWindow> detect_windows<T>(const T*, int64_t, int64_t, int64_t,       \
                                                      const int64_t*, double, const WindowConfig&, \
                                                      int);                                      \
  template void preprocess<T>(const T*, int64_t, int64_t, int64_t, const int64_t*,               \
                              const PreprocessOptions&, double*, TouchWindow*, const int64_t*);
ESKIN_INSTANTIATE(int16_t)
ESKIN_INSTANTIATE(float)
ESKIN_INSTANTIATE(double)
#undef ESKIN_INSTANTIATE

#endif  // !ESKIN_DEVICE

}  // namespace eskin
