// Tests of the preprocessing concern: Algorithm 2 and even subsampling, the S < D rule, the
// energy touch detector on synthetic bursts, streaming == batch, and no heap allocation on
// the per-sample path (counted through a replaced global operator new).
#include <gtest/gtest.h>

#include <atomic>
#include <cmath>
#include <cstdlib>
#include <new>
#include <random>
#include <stdexcept>
#include <string>
#include <vector>

#include "eskin/preprocess.hpp"

// ---- allocation counter: every operator new in this executable goes through here
static std::atomic<long> g_allocations{0};

void* operator new(std::size_t n) {
  ++g_allocations;
  if (void* p = std::malloc(n ? n : 1)) return p;
  throw std::bad_alloc();
}
void* operator new[](std::size_t n) {
  ++g_allocations;
  if (void* p = std::malloc(n ? n : 1)) return p;
  throw std::bad_alloc();
}
void operator delete(void* p) noexcept { std::free(p); }
void operator delete[](void* p) noexcept { std::free(p); }
void operator delete(void* p, std::size_t) noexcept { std::free(p); }
void operator delete[](void* p, std::size_t) noexcept { std::free(p); }

namespace {

using eskin::ShortPolicy;
using eskin::Status;
using eskin::SubsampleMethod;
using eskin::TouchDetector;
using eskin::TouchWindow;
using eskin::WindowConfig;

constexpr double kRate = 3000.0;
constexpr int64_t kTaxels = 16;

struct Burst {
  int64_t a, b;      // [a, b) samples
  double amplitude;  // of an 80 Hz sine on every taxel
};

// Taxel-major recording (kTaxels x T) int16: Gaussian noise (sd 20 codes), an ADC offset per
// taxel, and sine bursts.
std::vector<int16_t> make_recording(int64_t T, const std::vector<Burst>& bursts, unsigned seed) {
  std::mt19937 gen(seed);
  std::normal_distribution<double> noise(0.0, 20.0);
  std::vector<int16_t> x(static_cast<std::size_t>(kTaxels * T));
  for (int64_t k = 0; k < kTaxels; ++k) {
    const double offset = 100.0 * static_cast<double>(k) - 700.0;
    for (int64_t t = 0; t < T; ++t) {
      double v = offset + noise(gen);
      for (const Burst& b : bursts) {
        if (t >= b.a && t < b.b) {
          v += b.amplitude * (1.0 + 0.05 * static_cast<double>(k)) *
               std::sin(2.0 * 3.14159265358979 * 80.0 * static_cast<double>(t) / kRate);
        }
      }
      x[static_cast<std::size_t>(k * T + t)] = static_cast<int16_t>(std::lround(v));
    }
  }
  return x;
}

// Sample-major copy (T x kTaxels) of a taxel-major recording.
std::vector<int16_t> interleave(const std::vector<int16_t>& x, int64_t T) {
  std::vector<int16_t> y(x.size());
  for (int64_t k = 0; k < kTaxels; ++k) {
    for (int64_t t = 0; t < T; ++t) y[t * kTaxels + k] = x[k * T + t];
  }
  return y;
}

bool same(const TouchWindow& a, const TouchWindow& b) {
  return a.start == b.start && a.stop == b.stop && a.onset == b.onset && a.offset == b.offset &&
         a.truncated == b.truncated && a.energy == b.energy;
}

std::vector<TouchWindow> stream_all(TouchDetector& det, const std::vector<int16_t>& inter,
                                    int64_t T) {
  std::vector<TouchWindow> out;
  for (int64_t t = 0; t < T; ++t) {
    if (det.push(inter.data() + t * kTaxels) == Status::kWindow) out.push_back(det.last_window());
  }
  if (det.flush() == Status::kWindow) out.push_back(det.last_window());
  return out;
}

}  // namespace

// ------------------------------------------------------------------ subsampling

TEST(Subsample, Algorithm2IndicesExactly) {
  std::vector<int64_t> idx(100);
  ASSERT_TRUE(eskin::subsample_indices(1000, 100, SubsampleMethod::kAlgorithm2, idx.data()));
  for (int64_t d = 0; d < 100; ++d) EXPECT_EQ(idx[d], d * 10);
  // interval = floor(1099/100) = 10: the last 99 samples are never used (the remainder)
  ASSERT_TRUE(eskin::subsample_indices(1099, 100, SubsampleMethod::kAlgorithm2, idx.data()));
  EXPECT_EQ(idx[99], 990);
  // D <= S < 2D: interval 1, Algorithm 2 keeps only the first D samples
  ASSERT_TRUE(eskin::subsample_indices(199, 100, SubsampleMethod::kAlgorithm2, idx.data()));
  for (int64_t d = 0; d < 100; ++d) EXPECT_EQ(idx[d], d);
  ASSERT_TRUE(eskin::subsample_indices(100, 100, SubsampleMethod::kAlgorithm2, idx.data()));
  EXPECT_EQ(idx[99], 99);
  EXPECT_FALSE(eskin::subsample_indices(99, 100, SubsampleMethod::kAlgorithm2, idx.data()));
  EXPECT_FALSE(eskin::subsample_indices(10, 0, SubsampleMethod::kAlgorithm2, idx.data()));
}

TEST(Subsample, Algorithm2PaperTranscription) {
  // L(:,:,d) = S(:,:,p), p = 1, p += interval (1-based), over many (S, D)
  for (int64_t S = 1; S <= 400; S += 7) {
    for (int64_t D : {1, 2, 3, 20, 50, 100}) {
      if (S < D) continue;
      std::vector<int64_t> idx(static_cast<std::size_t>(D));
      ASSERT_TRUE(eskin::subsample_indices(S, D, SubsampleMethod::kAlgorithm2, idx.data()));
      const int64_t interval = S / D;
      int64_t p = 1;
      for (int64_t d = 1; d <= D; ++d) {
        EXPECT_EQ(idx[d - 1] + 1, p) << "S=" << S << " D=" << D << " d=" << d;
        p += interval;
      }
    }
  }
}

TEST(Subsample, EvenSpansWholeWindow) {
  for (int64_t S : {100, 101, 150, 199, 1000, 21000}) {
    for (int64_t D : {2, 20, 50, 100}) {
      std::vector<int64_t> idx(static_cast<std::size_t>(D));
      ASSERT_TRUE(eskin::subsample_indices(S, D, SubsampleMethod::kEven, idx.data()));
      EXPECT_EQ(idx.front(), 0);
      EXPECT_EQ(idx.back(), S - 1);
      for (int64_t d = 0; d < D; ++d) {
        const long double exact = static_cast<long double>(d) * (S - 1) / (D - 1);
        EXPECT_EQ(idx[d], static_cast<int64_t>(std::floor(exact + 0.5L)));
        if (d > 0) EXPECT_GT(idx[d], idx[d - 1]);
      }
    }
  }
  int64_t one = -1;
  ASSERT_TRUE(eskin::subsample_indices(50, 1, SubsampleMethod::kEven, &one));
  EXPECT_EQ(one, 0);
}

TEST(Subsample, WindowTakesTheIndexedSamplesOfEveryTaxel) {
  // taxel-major 3 taxels x 23 samples: x[k][t] = 100k + t
  const int64_t K = 3, S = 23, D = 5;
  std::vector<double> x(K * S);
  for (int64_t k = 0; k < K; ++k)
    for (int64_t t = 0; t < S; ++t) x[k * S + t] = 100.0 * k + t;
  std::vector<double> out(K * D);
  ASSERT_EQ(eskin::subsample_window(x.data(), K, S, 1, S, D, SubsampleMethod::kAlgorithm2,
                                    ShortPolicy::kError, out.data()),
            Status::kOk);
  for (int64_t k = 0; k < K; ++k)
    for (int64_t d = 0; d < D; ++d) EXPECT_EQ(out[k * D + d], 100.0 * k + 4 * d);  // interval 4
  // the same data sample-major gives the same tensor
  std::vector<double> y(K * S);
  for (int64_t k = 0; k < K; ++k)
    for (int64_t t = 0; t < S; ++t) y[t * K + k] = x[k * S + t];
  std::vector<double> out2(K * D);
  ASSERT_EQ(eskin::subsample_window(y.data(), K, 1, K, S, D, SubsampleMethod::kAlgorithm2,
                                    ShortPolicy::kError, out2.data()),
            Status::kOk);
  EXPECT_EQ(out, out2);
}

TEST(Subsample, ShortWindowInterpolatesOrFails) {
  // S = 4 < D = 7: a linear ramp stays a linear ramp through the D points
  const int64_t S = 4, D = 7;
  std::vector<double> x = {0.0, 3.0, 6.0, 9.0};
  std::vector<double> out(D, -1.0);
  ASSERT_EQ(eskin::subsample_window(x.data(), 1, S, 1, S, D, SubsampleMethod::kAlgorithm2,
                                    ShortPolicy::kInterpolate, out.data()),
            Status::kOk);
  for (int64_t d = 0; d < D; ++d) EXPECT_NEAR(out[d], 9.0 * d / (D - 1), 1e-12);
  EXPECT_EQ(out.front(), 0.0);
  EXPECT_EQ(out.back(), 9.0);
  // a single sample is repeated
  ASSERT_EQ(eskin::subsample_window(x.data(), 1, 1, 1, 1, D, SubsampleMethod::kEven,
                                    ShortPolicy::kInterpolate, out.data()),
            Status::kOk);
  for (double v : out) EXPECT_EQ(v, 0.0);
  EXPECT_EQ(eskin::subsample_window(x.data(), 1, S, 1, S, D, SubsampleMethod::kAlgorithm2,
                                    ShortPolicy::kError, out.data()),
            Status::kBadArgument);
  EXPECT_EQ(eskin::subsample_window(x.data(), 1, S, 1, 0, D, SubsampleMethod::kAlgorithm2,
                                    ShortPolicy::kInterpolate, out.data()),
            Status::kBadArgument);
}

// ------------------------------------------------------------------ configuration

TEST(WindowConfig, ArrayRoundTripAndNames) {
  WindowConfig c;
  c.on_factor = 5.5;
  c.select = 2;
  const auto a = eskin::window_config_to_array(c);
  const WindowConfig d = eskin::window_config_from_array(a.data(), a.size());
  EXPECT_EQ(eskin::window_config_to_array(d), a);
  EXPECT_STREQ(eskin::window_config_field_names()[7], "on_factor");
  EXPECT_EQ(a[7], 5.5);
  EXPECT_THROW(eskin::window_config_from_array(a.data(), a.size() - 1), std::invalid_argument);
}

TEST(WindowConfig, ResolvesToSamplesAtAnyRate) {
  const WindowConfig c;
  const auto p = eskin::resolve_window_config(c, 3000.0);
  EXPECT_EQ(p.frame_len, 30);
  EXPECT_EQ(p.pad_before, 150);
  EXPECT_EQ(p.max_window, 21000);
  EXPECT_EQ(p.hold_frames, 15);
  const auto q = eskin::resolve_window_config(c, 1000.0);
  EXPECT_EQ(q.frame_len, 10);
  EXPECT_EQ(q.max_window, 7000);
}

TEST(WindowConfig, RejectsBadValuesNamingTheField) {
  auto expect_bad = [](WindowConfig c, const char* field) {
    try {
      eskin::resolve_window_config(c, kRate);
      ADD_FAILURE() << "no error for " << field;
    } catch (const std::invalid_argument& e) {
      EXPECT_NE(std::string(e.what()).find(field), std::string::npos) << e.what();
    }
  };
  WindowConfig c;
  c.frame_s = 0;
  expect_bad(c, "frame_s");
  c = WindowConfig{};
  c.on_factor = 1.0;  // below off_factor
  expect_bad(c, "on_factor");
  c = WindowConfig{};
  c.noise_quantile = 1.5;
  expect_bad(c, "noise_quantile");
  c = WindowConfig{};
  c.combine = 0.5;
  expect_bad(c, "combine");
  c = WindowConfig{};
  c.max_window_s = 0.01;
  expect_bad(c, "max_window_s");
  c = WindowConfig{};
  c.hold_s = std::nan("");
  expect_bad(c, "hold_s");
  EXPECT_THROW(eskin::resolve_window_config(WindowConfig{}, 0.0), std::invalid_argument);
  EXPECT_THROW(TouchDetector(0, kRate, WindowConfig{}), std::invalid_argument);
}

// The resource limits: a configuration whose buffers would be unbounded is refused by the
// validation (std::invalid_argument naming the field and its value), before any allocation.
TEST(WindowConfig, RefusesUnboundedBuffersNamingTheFieldAndValue) {
  auto message = [](WindowConfig c, double rate = kRate) -> std::string {
    try {
      eskin::resolve_window_config(c, rate);
    } catch (const std::invalid_argument& e) {
      return e.what();
    }
    return "";
  };
  WindowConfig c;
  c.noise_window_s = 1e6;  // 1e8 frames of 10 ms
  std::string m = message(c);
  EXPECT_NE(m.find("noise_window_s = 1e+06"), std::string::npos) << m;
  EXPECT_NE(m.find("limit is 1048576"), std::string::npos) << m;
  c.noise_window_s = 1e12;
  EXPECT_NE(message(c).find("noise_window_s = 1e+12"), std::string::npos);
  c = WindowConfig{};
  c.noise_window_s = 10485.76;  // exactly kMaxNoiseFrames frames at 3 kHz: still accepted
  EXPECT_EQ(eskin::resolve_window_config(c, kRate).noise_frames, eskin::kMaxNoiseFrames);
  c.noise_window_s = 10485.78;
  EXPECT_NE(message(c).find("noise_window_s"), std::string::npos);
  c = WindowConfig{};
  c.max_window_s = 1e6;
  m = message(c);
  EXPECT_NE(m.find("max_window_s = 1e+06"), std::string::npos) << m;
  EXPECT_NE(m.find("limit is 16777216"), std::string::npos) << m;
  c = WindowConfig{};
  c.max_window_s = 2000;  // 6e6 samples: a lookback of 1e6 frames fits inside it
  c.frame_s = 1.0 / kRate;
  c.lookback_s = 1000;  // 3e6 one-sample frames
  EXPECT_NE(message(c).find("lookback_s = 1000"), std::string::npos);
}

// A finite but huge time is out of range (its conversion to samples would overflow), not
// "non-finite"; every time field is checked.
TEST(WindowConfig, HugeFiniteTimesAreOutOfRange) {
  const auto names = eskin::window_config_field_names();
  for (const std::size_t i : {0u, 3u, 5u, 10u, 11u, 12u, 13u, 14u, 15u}) {
    for (const double v : {1e308, -1e308, 1e10}) {
      auto a = eskin::window_config_to_array(WindowConfig{});
      a[i] = v;
      try {
        eskin::resolve_window_config(eskin::window_config_from_array(a.data(), a.size()), kRate);
        ADD_FAILURE() << names[i] << " = " << v << " accepted";
      } catch (const std::invalid_argument& e) {
        const std::string m = e.what();
        EXPECT_NE(m.find(std::string("WindowConfig.") + names[i] + " = "), std::string::npos) << m;
        EXPECT_NE(m.find("out of range"), std::string::npos) << m;
        EXPECT_EQ(m.find("finite"), std::string::npos) << m;
      }
    }
  }
}

// The samples a storing detector keeps grow with the grid: bounded by kMaxStoredValues, checked
// by the constructor (a non-storing detector, as in batch preprocessing, keeps no samples).
TEST(WindowConfig, StoredSamplesAreBoundedPerGrid) {
  WindowConfig c;  // 7 s at 3 kHz, and a pre-pad ring of 150 + 31 frames of 30
  c.window_samples = 0;  // unbounded: the window buffer holds max_window_s
  const auto p = eskin::resolve_window_config(c, kRate);
  EXPECT_EQ(eskin::detector_stored_values(p, 16), 16 * (150 + 31 * 30 + 21000));
  const int64_t most = eskin::kMaxStoredValues / eskin::detector_stored_values(p, 1);
  EXPECT_NO_THROW(TouchDetector(most, kRate, c, /*store_samples=*/false));
  EXPECT_NO_THROW(eskin::check_detector_buffers(p, c, most));
  try {
    TouchDetector(most + 1, kRate, c, /*store_samples=*/true);
    ADD_FAILURE() << "no error for " << most + 1 << " taxels";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("WindowConfig.max_window_s = 7: too large for " +
                                         std::to_string(most + 1) + " taxels"),
              std::string::npos)
        << e.what();
  }
  EXPECT_NO_THROW(TouchDetector(most + 1, kRate, c, /*store_samples=*/false));
}

// ------------------------------------------------------------------ detector

TEST(Detector, FindsBurstsWithKnownOnsetAndOffset) {
  const int64_t T = 21000;
  const std::vector<Burst> bursts = {{4000, 9000, 150.0}, {12500, 15000, 150.0}};
  const auto x = make_recording(T, bursts, 1);
  TouchDetector det(kTaxels, kRate, WindowConfig{});
  const auto ws = stream_all(det, interleave(x, T), T);
  ASSERT_EQ(ws.size(), 2u);
  const int64_t frame = det.params().frame_len, pad = det.params().pad_before;
  for (std::size_t i = 0; i < 2; ++i) {
    EXPECT_LE(std::llabs(ws[i].onset - bursts[i].a), frame) << i;
    EXPECT_LE(std::llabs(ws[i].offset - bursts[i].b), 2 * frame) << i;
    EXPECT_EQ(ws[i].start, ws[i].onset - pad);
    EXPECT_EQ(ws[i].stop, ws[i].offset + det.params().pad_after);
    EXPECT_FALSE(ws[i].truncated);
    EXPECT_GT(ws[i].energy, 0.0);
  }
  // select = energy picks the longer (more energetic) burst; first picks the first; span both
  WindowConfig c;
  c.select = 0;
  const TouchWindow w0 = eskin::detect_window(x.data(), kTaxels, T, T, kRate, c);
  EXPECT_TRUE(same(w0, ws[0]));
  c.select = 1;
  EXPECT_TRUE(same(eskin::detect_window(x.data(), kTaxels, T, T, kRate, c), ws[0]));
  c.select = 2;
  const TouchWindow span = eskin::detect_window(x.data(), kTaxels, T, T, kRate, c);
  EXPECT_EQ(span.start, ws[0].start);
  EXPECT_EQ(span.stop, ws[1].stop);
}

TEST(Detector, NoTouchFallsBackOrFails) {
  const int64_t T = 6000;
  const auto x = make_recording(T, {}, 2);
  WindowConfig c;
  const TouchWindow w = eskin::detect_window(x.data(), kTaxels, T, 5000, kRate, c);
  EXPECT_FALSE(w.found);
  EXPECT_EQ(w.start, 0);
  EXPECT_EQ(w.stop, 5000);
  c.fallback = 1;
  EXPECT_THROW(eskin::detect_window(x.data(), kTaxels, T, T, kRate, c), std::runtime_error);
}

TEST(Detector, DropsBlipsShorterThanMinDuration) {
  const int64_t T = 9000;
  const auto x = make_recording(T, {{4000, 4040, 400.0}}, 3);  // 13 ms
  TouchDetector det(kTaxels, kRate, WindowConfig{});
  EXPECT_TRUE(stream_all(det, interleave(x, T), T).empty());
}

TEST(Detector, BridgesShortGapsWithTheHoldTime) {
  const int64_t T = 12000;
  // a 60 ms gap (< hold 150 ms) is bridged, a 600 ms gap is not
  const auto x = make_recording(T, {{3000, 4000, 150}, {4180, 5000, 150}, {6800, 8000, 150}}, 4);
  TouchDetector det(kTaxels, kRate, WindowConfig{});
  const auto ws = stream_all(det, interleave(x, T), T);
  ASSERT_EQ(ws.size(), 2u);
  EXPECT_LE(std::llabs(ws[0].onset - 3000), 30);
  EXPECT_LE(std::llabs(ws[0].offset - 5000), 60);
  EXPECT_LE(std::llabs(ws[1].onset - 6800), 30);
}

TEST(Detector, MaxWindowCutsALongTouch) {
  const int64_t T = 15000;
  const auto x = make_recording(T, {{3000, 14000, 150.0}}, 5);
  WindowConfig c;
  c.max_window_s = 1.0;  // 3000 samples
  TouchDetector det(kTaxels, kRate, c);
  const auto ws = stream_all(det, interleave(x, T), T);
  // one cut window, then the detector waits for the energy to fall (no second window)
  ASSERT_EQ(ws.size(), 1u);
  EXPECT_TRUE(ws[0].truncated);
  EXPECT_EQ(ws[0].stop - ws[0].start, 3000);
  EXPECT_EQ(ws[0].stop, ws[0].offset);
  // its tensor is still available from the window buffer (no newer onset overwrote it)
  std::vector<double> t(kTaxels * 10);
  EXPECT_EQ(det.subsample_last_window(10, SubsampleMethod::kAlgorithm2, ShortPolicy::kError,
                                      t.data()),
            Status::kOk);
  EXPECT_EQ(det.last_window_length(), 3000);
}

TEST(Detector, TouchAtTheEndIsClosedByFlush) {
  const int64_t T = 9000;
  const auto x = make_recording(T, {{6000, 9000, 150.0}}, 6);
  TouchDetector det(kTaxels, kRate, WindowConfig{});
  const auto ws = stream_all(det, interleave(x, T), T);
  ASSERT_EQ(ws.size(), 1u);
  EXPECT_TRUE(ws[0].truncated);
  EXPECT_EQ(ws[0].stop, T);
}

TEST(Detector, RejectsNonFiniteSamplesWithAStatus) {
  TouchDetector det(2, kRate, WindowConfig{});
  const double good[2] = {1.0, 2.0};
  const double bad[2] = {1.0, std::nan("")};
  EXPECT_EQ(det.push(good), Status::kOk);
  EXPECT_EQ(det.push(bad), Status::kNonFiniteSample);
  EXPECT_EQ(det.samples_seen(), 1);
  EXPECT_EQ(det.push(static_cast<const double*>(nullptr)), Status::kNullPointer);
  // the batch path throws, naming the sample
  std::vector<float> rec(2 * 100, 0.0f);
  rec[1 * 100 + 42] = INFINITY;
  try {
    eskin::detect_window(rec.data(), 2, 100, 100, kRate, WindowConfig{});
    ADD_FAILURE() << "no error";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("taxel 1, sample 42"), std::string::npos) << e.what();
  }
}

// ------------------------------------------------------------------ streaming == batch

TEST(StreamingEqualsBatch, SameWindowsSampleBySampleBlocksAndBatch) {
  const int64_t T = 21000;
  for (unsigned seed = 10; seed < 14; ++seed) {
    std::mt19937 gen(seed);
    std::uniform_int_distribution<int64_t> pos(1000, 16000), len(200, 4000);
    std::vector<Burst> bursts;
    for (int i = 0; i < 3; ++i) {
      const int64_t a = pos(gen);
      bursts.push_back({a, std::min<int64_t>(T, a + len(gen)), 60.0 + 40.0 * i});
    }
    const auto x = make_recording(T, bursts, seed);
    const auto inter = interleave(x, T);
    for (double select : {0.0, 1.0, 2.0}) {
      WindowConfig c;
      c.select = select;
      TouchDetector det(kTaxels, kRate, c);
      const auto ws = stream_all(det, inter, T);
      ASSERT_FALSE(ws.empty());
      // blocks of uneven size
      TouchDetector det2(kTaxels, kRate, c);
      std::vector<TouchWindow> ws2;
      int64_t t = 0, chunk = 1;
      while (t < T) {
        const int64_t n = std::min<int64_t>(chunk, T - t);
        int64_t consumed = 0;
        const Status st = det2.push_block(inter.data() + t * kTaxels, n, &consumed);
        t += consumed;
        if (st == Status::kWindow) ws2.push_back(det2.last_window());
        chunk = chunk * 3 % 2047 + 1;
      }
      if (det2.flush() == Status::kWindow) ws2.push_back(det2.last_window());
      ASSERT_EQ(ws.size(), ws2.size());
      for (std::size_t i = 0; i < ws.size(); ++i) EXPECT_TRUE(same(ws[i], ws2[i]));
      // the batch function's choice is one of the streamed windows (or their span)
      const TouchWindow b = eskin::detect_window(x.data(), kTaxels, T, T, kRate, c);
      if (select == 1.0) {
        EXPECT_TRUE(same(b, ws.front()));
      } else if (select == 0.0) {
        const TouchWindow* best = &ws[0];
        for (const auto& w : ws)
          if (w.energy > best->energy) best = &w;
        EXPECT_TRUE(same(b, *best));
      } else {
        EXPECT_EQ(b.start, ws.front().start);
        EXPECT_EQ(b.stop, std::min(ws.back().stop, ws.front().start + det.params().max_window));
      }
    }
  }
}

TEST(StreamingEqualsBatch, StreamedTensorEqualsBatchPreprocess) {
  const int64_t T = 12000, D = 50;
  const auto x = make_recording(T, {{5000, 8000, 120.0}}, 21);
  TouchDetector det(kTaxels, kRate, WindowConfig{});
  const auto inter = interleave(x, T);
  std::vector<double> streamed(kTaxels * D);
  bool got = false;
  for (int64_t t = 0; t < T; ++t) {
    if (det.push(inter.data() + t * kTaxels) == Status::kWindow) {
      ASSERT_EQ(det.subsample_last_window(D, SubsampleMethod::kAlgorithm2,
                                          ShortPolicy::kInterpolate, streamed.data()),
                Status::kOk);
      got = true;
    }
  }
  ASSERT_TRUE(got);
  for (auto method : {SubsampleMethod::kAlgorithm2}) {
    eskin::PreprocessOptions opt;
    opt.D = D;
    opt.method = method;
    std::vector<double> batch(kTaxels * D);
    TouchWindow w;
    eskin::preprocess(x.data(), 1, kTaxels, T, nullptr, opt, batch.data(), &w);
    EXPECT_TRUE(same(w, det.last_window()));
    EXPECT_EQ(batch, streamed);
  }
}

// ------------------------------------------------------------------ bounded window

TEST(BoundedWindow, StrideIsTheSmallestPowerOfTwoThatFits) {
  EXPECT_EQ(eskin::window_stride(1, 8), 1);
  EXPECT_EQ(eskin::window_stride(8, 8), 1);
  EXPECT_EQ(eskin::window_stride(9, 8), 2);
  EXPECT_EQ(eskin::window_stride(16, 8), 2);
  EXPECT_EQ(eskin::window_stride(17, 8), 4);
  EXPECT_EQ(eskin::window_stride(1000, 0), 1);  // unbounded
  for (int64_t n = 1; n < 5000; n += 7) {
    const int64_t s = eskin::window_stride(n, 64);
    EXPECT_LE((n + s - 1) / s, 64);
    if (s > 1) EXPECT_GT((n + s / 2 - 1) / (s / 2), 64);
  }
}

TEST(BoundedWindow, DetectorRamDoesNotGrowWithMaxWindow) {
  WindowConfig c;
  c.window_samples = 512;
  for (double max_s : {1.0, 7.0, 60.0, 600.0}) {
    c.max_window_s = max_s;
    const auto p = eskin::resolve_window_config(c, kRate);
    EXPECT_EQ(p.window_capacity, 512);
    EXPECT_EQ(eskin::detector_stored_values(p, 16), 16 * (150 + 31 * 30 + 512)) << max_s;
  }
  c.window_samples = 0;  // every sample: grows with max_window_s
  c.max_window_s = 60.0;
  EXPECT_EQ(eskin::resolve_window_config(c, kRate).window_capacity, 180000);
  for (double bad : {1.0, 3.0, -2.0, 2.5, 1e9}) {
    c.window_samples = bad;
    EXPECT_THROW(eskin::resolve_window_config(c, kRate), std::invalid_argument) << bad;
  }
}

// A window far longer than the buffer (a 6 s touch in 64 kept samples, stride 512): the stream's
// tensor equals the batch preprocessing's, which reads the recording as the buffer kept it, for
// both subsampling methods, short windows (S < D) included.
TEST(BoundedWindow, StreamedTensorEqualsBatchAtEveryStride) {
  const int64_t T = 24000;
  for (const double cap : {64.0, 256.0, 2048.0, 0.0}) {
    for (const auto& burst : std::vector<Burst>{{3000, 21000, 90.0}, {5000, 5600, 150.0}}) {
      WindowConfig c;
      c.window_samples = cap;
      const auto x = make_recording(T, {burst}, 40);
      const auto inter = interleave(x, T);
      for (auto method : {SubsampleMethod::kAlgorithm2, SubsampleMethod::kEven}) {
        for (const int64_t D : {int64_t{50}, int64_t{100}, int64_t{1500}}) {
          TouchDetector det(kTaxels, kRate, c);
          std::vector<double> streamed(kTaxels * D);
          TouchWindow last;
          for (int64_t t = 0; t < T; ++t) {
            if (det.push(inter.data() + t * kTaxels) == Status::kWindow) {
              ASSERT_EQ(det.subsample_last_window(D, method, ShortPolicy::kInterpolate,
                                                  streamed.data()),
                        Status::kOk);
              last = det.last_window();
            }
          }
          if (det.flush() == Status::kWindow) {
            ASSERT_EQ(det.subsample_last_window(D, method, ShortPolicy::kInterpolate,
                                                streamed.data()),
                      Status::kOk);
            last = det.last_window();
          }
          ASSERT_GT(last.stop, last.start) << cap;
          const int64_t S = last.stop - last.start;
          if (cap > 0 && S > 2 * cap) {
            EXPECT_GT(last.stride, 1);
          }
          if (cap == 0) {
            EXPECT_EQ(last.stride, 1);
          }
          eskin::PreprocessOptions opt;
          opt.D = D;
          opt.method = method;
          opt.config = c;
          std::vector<double> batch(kTaxels * D);
          TouchWindow w;
          eskin::preprocess(x.data(), 1, kTaxels, T, nullptr, opt, batch.data(), &w);
          EXPECT_TRUE(same(w, last));
          EXPECT_EQ(w.stride, last.stride);
          EXPECT_EQ(batch, streamed) << "capacity " << cap << " D " << D;
          // and each value is the recording's sample at (t / stride) * stride
          std::vector<int64_t> idx(static_cast<std::size_t>(D));
          if (S >= D) {
            ASSERT_TRUE(eskin::subsample_indices(S, D, method, idx.data()));
            for (int64_t k = 0; k < kTaxels; k += 5)
              for (int64_t d = 0; d < D; ++d)
                EXPECT_EQ(batch[k * D + d],
                          x[k * T + w.start + (idx[d] / w.stride) * w.stride]);
          }
        }
      }
    }
  }
}

// The detector's window handed back as a given [start, stop, stride] triple (training detects
// once and subsamples each D from it) is read as the stream read it; as a [start, stop) pair it
// is read sample by sample, which differs once the window was decimated.
TEST(BoundedWindow, GivenWindowsWithTheirStrideAreReadAsTheStreamReadThem) {
  const int64_t T = 24000, D = 50;
  WindowConfig c;
  c.window_samples = 64;
  const auto x = make_recording(T, {{3000, 21000, 90.0}}, 41);
  eskin::PreprocessOptions opt;
  opt.D = D;
  opt.config = c;
  std::vector<double> energy(kTaxels * D), given(kTaxels * D), plain(kTaxels * D);
  TouchWindow w;
  eskin::preprocess(x.data(), 1, kTaxels, T, nullptr, opt, energy.data(), &w);
  ASSERT_GT(w.stride, 1);
  opt.window = eskin::WindowMode::kGiven;
  opt.given_strides = true;
  const int64_t triple[3] = {w.start, w.stop, w.stride};
  TouchWindow used;
  eskin::preprocess(x.data(), 1, kTaxels, T, nullptr, opt, given.data(), &used, triple);
  EXPECT_EQ(used.stride, w.stride);
  EXPECT_EQ(given, energy);
  opt.given_strides = false;
  eskin::preprocess(x.data(), 1, kTaxels, T, nullptr, opt, plain.data(), nullptr, triple);
  EXPECT_NE(plain, energy);
  // a stride no bounded window has is refused, naming the window and the value
  opt.given_strides = true;
  const int64_t bad[3] = {w.start, w.stop, 3};
  try {
    eskin::preprocess(x.data(), 1, kTaxels, T, nullptr, opt, plain.data(), nullptr, bad);
    ADD_FAILURE() << "stride 3 accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("windows[0]: stride = 3"), std::string::npos) << e.what();
  }
}

TEST(Batch, ThreadsGiveTheSameResultAsOneThread) {
  const int64_t T = 9000, n = 7;
  std::vector<int16_t> data;
  std::vector<int64_t> lengths;
  for (int64_t i = 0; i < n; ++i) {
    const auto x = make_recording(T, {{1000 + 500 * i, 3000 + 700 * i, 100.0}}, 30 + i);
    data.insert(data.end(), x.begin(), x.end());
    lengths.push_back(T - 300 * i);
  }
  const auto w1 = eskin::detect_windows(data.data(), n, kTaxels, T, lengths.data(), kRate,
                                        WindowConfig{}, 1);
  const auto w4 = eskin::detect_windows(data.data(), n, kTaxels, T, lengths.data(), kRate,
                                        WindowConfig{}, 4);
  for (int64_t i = 0; i < n; ++i) {
    EXPECT_TRUE(same(w1[i], w4[i]));
    EXPECT_TRUE(w1[i].found);
    EXPECT_LE(w1[i].stop, lengths[i]);
  }
  eskin::PreprocessOptions opt;
  opt.D = 20;
  opt.n_threads = 3;
  std::vector<double> out(n * kTaxels * 20);
  std::vector<TouchWindow> ws(n);
  eskin::preprocess(data.data(), n, kTaxels, T, lengths.data(), opt, out.data(), ws.data());
  for (int64_t i = 0; i < n; ++i) EXPECT_TRUE(same(ws[i], w1[i]));
  // a bad length names the recording
  lengths[3] = T + 1;
  try {
    eskin::detect_windows(data.data(), n, kTaxels, T, lengths.data(), kRate, WindowConfig{}, 2);
    ADD_FAILURE() << "no error";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("lengths[3]"), std::string::npos) << e.what();
  }
}

// ------------------------------------------------------------------ no allocation per sample

TEST(NoAllocation, PerSamplePathNeverAllocates) {
  const int64_t T = 21000, D = 100;
  const auto x = make_recording(T, {{3000, 6000, 150.0}, {9000, 9500, 150.0}, {14000, 20000, 90.0}},
                                40);
  const auto inter = interleave(x, T);
  std::vector<float> inter_f(inter.begin(), inter.end());
  TouchDetector det(kTaxels, kRate, WindowConfig{});
  std::vector<double> tensor(kTaxels * D);
  int windows = 0;
  const long before = g_allocations.load();
  for (int64_t t = 0; t < T; ++t) {
    const Status st = (t % 2) ? det.push(inter.data() + t * kTaxels)
                              : det.push(inter_f.data() + t * kTaxels);
    if (st == Status::kWindow) {
      ++windows;
      if (det.subsample_last_window(D, SubsampleMethod::kEven, ShortPolicy::kInterpolate,
                                    tensor.data()) != Status::kOk) {
        ADD_FAILURE() << "subsample failed";
      }
    }
  }
  if (det.flush() == Status::kWindow) ++windows;
  det.reset();
  int64_t consumed = 0;
  (void)det.push_block(inter.data(), T, &consumed);
  const long after = g_allocations.load();
  EXPECT_EQ(after - before, 0);
  EXPECT_EQ(windows, 3);
  // the counter does count: constructing a detector allocates
  TouchDetector other(kTaxels, kRate, WindowConfig{});
  EXPECT_GT(g_allocations.load(), after);
}

// ------------------------------------------------------------------ compact sample store

// Random touches: bursts of random length, amplitude and gap (gaps down to a few frames, so
// that a touch starts right after the previous one's window; touches longer than max_window).
static std::vector<Burst> random_bursts(std::mt19937& gen, int64_t T) {
  std::uniform_int_distribution<int64_t> gap(60, 4000), len(100, 9000);
  std::uniform_real_distribution<double> amp(60.0, 400.0);
  std::vector<Burst> out;
  for (int64_t t = 600 + gap(gen); t < T;) {
    const int64_t b = std::min(T, t + len(gen)), m = t + (b - t) / 2;
    const double a = amp(gen);
    out.push_back({t, m, a});  // loud, then softer: with a high release_fraction the soft half
    out.push_back({m, b, 0.3 * a});  // ends the touch and starts the next one at once
    t = b + gap(gen);
  }
  return out;
}

// SampleStore::kCodes keeps the int16 codes in one pool of the window buffer, the recent ring
// and the older pre-onset samples (in the window buffer's end between touches): the windows and
// every window's tensor equal those of the native store, for small and large window buffers,
// every-sample windows, long pads and look-backs, and pads after longer than the hold.
TEST(CompactStore, SameWindowsAndTensorsAsTheNativeStore) {
  std::vector<WindowConfig> configs(9);
  configs[1].window_samples = 64;  // most of the pre-onset ring in the recent ring
  configs[2].window_samples = 0;
  configs[2].max_window_s = 2.0;
  configs[3].pad_before_s = 0.2;
  configs[3].lookback_s = 0.5;
  configs[3].window_samples = 256;
  configs[4].hold_s = 0.02;
  configs[4].pad_after_s = 0.2;
  configs[5].max_window_s = 0.5;  // cut touches, refractory periods
  configs[5].dc_cutoff_hz = 0.0;
  configs[6].window_samples = 4096;  // the recent ring exactly what a next touch can reach
  configs[6].hold_s = 0.1;
  configs[7].release_fraction = 0.5;  // a next touch's onset backtracks to the last one's stop
  configs[8].release_fraction = 0.5;
  configs[8].window_samples = 4096;
  const int64_t T = 60000, D = 20;
  std::mt19937 gen(2026);
  int windows = 0;
  for (std::size_t ci = 0; ci < configs.size(); ++ci) {
    for (unsigned seed = 0; seed < 3; ++seed) {
      const auto inter = interleave(make_recording(T, random_bursts(gen, T), 100 + seed), T);
      TouchDetector native(kTaxels, kRate, configs[ci], eskin::SampleStore::kNative);
      TouchDetector codes(kTaxels, kRate, configs[ci], eskin::SampleStore::kCodes);
      EXPECT_LT(codes.memory_bytes(), native.memory_bytes());
      std::vector<double> a(kTaxels * D), b(kTaxels * D);
      auto compare = [&](Status sa, Status sb, int64_t t) {
        ASSERT_EQ(sa, sb) << "config " << ci << " seed " << seed << " t " << t;
        if (sa != Status::kWindow) return;
        ++windows;
        ASSERT_TRUE(same(native.last_window(), codes.last_window())) << ci << " " << t;
        EXPECT_EQ(codes.last_window_data(), nullptr);
        for (auto m : {SubsampleMethod::kAlgorithm2, SubsampleMethod::kEven}) {
          ASSERT_EQ(native.subsample_last_window(D, m, ShortPolicy::kInterpolate, a.data()), Status::kOk);
          ASSERT_EQ(codes.subsample_last_window(D, m, ShortPolicy::kInterpolate, b.data()), Status::kOk);
          ASSERT_EQ(a, b) << "config " << ci << " seed " << seed << " t " << t;
        }
      };
      for (int64_t t = 0; t < T; ++t)
        compare(native.push(inter.data() + t * kTaxels), codes.push(inter.data() + t * kTaxels), t);
      compare(native.flush(), codes.flush(), T);
    }
  }
  EXPECT_GT(windows, 100);
}

// SampleStore::kCodes with its window in chunks of a shared pool (WindowBufferPool of fewer
// samples than the window): the window's kept samples are taken chunk by chunk as it grows and
// given back as it halves and ends; the windows and tensors equal the native store's for
// chunks of one sample, of a size that divides no window, and larger; the pool's chunks are all
// back after reset, and the per-sample path does not allocate.
TEST(ChunkedStore, SameWindowsAndTensorsAsTheNativeStore) {
  std::vector<WindowConfig> configs(4);
  configs[1].window_samples = 64;
  configs[2].window_samples = 256;
  configs[2].lookback_s = 0.5;
  configs[3].window_samples = 4096;
  configs[3].release_fraction = 0.5;
  const int64_t T = 40000, D = 20;
  std::mt19937 gen(7);
  int windows = 0;
  for (std::size_t ci = 0; ci < configs.size(); ++ci) {
    const int64_t cap = eskin::resolve_window_config(configs[ci], kRate).window_capacity;
    for (const int64_t chunk : {int64_t{1}, int64_t{7}, int64_t{32}}) {
      const auto inter = interleave(make_recording(T, random_bursts(gen, T), 300 + chunk), T);
      eskin::WindowBufferPool pool((cap + chunk - 1) / chunk, chunk, kTaxels);
      TouchDetector native(kTaxels, kRate, configs[ci], eskin::SampleStore::kNative);
      TouchDetector codes(kTaxels, kRate, configs[ci], eskin::SampleStore::kCodes, &pool);
      std::vector<double> a(kTaxels * D), b(kTaxels * D);
      auto compare = [&](Status sa, Status sb, int64_t t) {
        ASSERT_EQ(sa, sb) << "config " << ci << " chunk " << chunk << " t " << t;
        if (sa != Status::kWindow) return;
        ++windows;
        ASSERT_TRUE(same(native.last_window(), codes.last_window())) << ci << " " << t;
        for (auto m : {SubsampleMethod::kAlgorithm2, SubsampleMethod::kEven}) {
          ASSERT_EQ(native.subsample_last_window(D, m, ShortPolicy::kInterpolate, a.data()), Status::kOk);
          ASSERT_EQ(codes.subsample_last_window(D, m, ShortPolicy::kInterpolate, b.data()), Status::kOk);
          ASSERT_EQ(a, b) << "config " << ci << " chunk " << chunk << " t " << t;
        }
      };
      const long before = g_allocations.load();
      for (int64_t t = 0; t < T; ++t)
        compare(native.push(inter.data() + t * kTaxels), codes.push(inter.data() + t * kTaxels), t);
      compare(native.flush(), codes.flush(), T);
      EXPECT_EQ(g_allocations.load() - before, 0);
      EXPECT_EQ(pool.unbuffered(), 0);
      EXPECT_GT(pool.peak_in_use(), 0);
      codes.reset();
      EXPECT_EQ(pool.in_use(), 0);
    }
  }
  EXPECT_GT(windows, 50);
}

// A chunk pool whose other chunks are taken (by other streams) while a touch grows: that touch
// has no tensor (kNoWindow, counted once) and gives back the chunks it held; the next touch,
// with the chunks free again, has the native store's window and tensor.
TEST(ChunkedStore, ATouchThatFindsNoChunkHasNoTensorAndTheNextOneIsExact) {
  WindowConfig c;
  c.window_samples = 256;
  const int64_t T = 20000, D = 20;
  const auto inter =
      interleave(make_recording(T, {{3000, 3900, 150.0}, {9000, 9150, 150.0}}, 43), T);
  eskin::WindowBufferPool pool(8, 32, kTaxels);  // one window of 256 samples
  std::vector<int16_t*> others;
  for (int i = 0; i < 5; ++i) others.push_back(pool.acquire());  // 96 samples left
  TouchDetector native(kTaxels, kRate, c, eskin::SampleStore::kNative);
  TouchDetector codes(kTaxels, kRate, c, eskin::SampleStore::kCodes, &pool);
  std::vector<double> a(kTaxels * D), b(kTaxels * D);
  int windows = 0;
  for (int64_t t = 0; t < T; ++t) {
    const Status sa = native.push(inter.data() + t * kTaxels);
    ASSERT_EQ(sa, codes.push(inter.data() + t * kTaxels)) << t;
    if (sa != Status::kWindow) continue;
    ASSERT_TRUE(same(native.last_window(), codes.last_window()));
    const Status got = codes.subsample_last_window(D, SubsampleMethod::kAlgorithm2,
                                                   ShortPolicy::kInterpolate, b.data());
    if (windows++ == 0) {
      EXPECT_EQ(got, Status::kNoWindow);
      EXPECT_EQ(pool.in_use(), 5);
      EXPECT_EQ(pool.unbuffered(), 1);
      for (int16_t* o : others) pool.release(o);
      continue;
    }
    ASSERT_EQ(got, Status::kOk);
    ASSERT_EQ(native.subsample_last_window(D, SubsampleMethod::kAlgorithm2, ShortPolicy::kInterpolate,
                                           a.data()), Status::kOk);
    EXPECT_EQ(a, b);
  }
  EXPECT_EQ(windows, 2);
  EXPECT_EQ(pool.unbuffered(), 1);
  EXPECT_THROW(eskin::WindowBufferPool(-1, 32, kTaxels), std::invalid_argument);
  EXPECT_THROW(eskin::WindowBufferPool(4, 0, kTaxels), std::invalid_argument);
  eskin::WindowBufferPool narrow(4, 32, kTaxels - 1);
  EXPECT_THROW(TouchDetector(kTaxels, kRate, c, eskin::SampleStore::kCodes, &narrow), std::invalid_argument);
}

// The compact store of a 4x4 patch at 3 kHz with the default detector fits 64 KB, and its
// per-sample path does not allocate.
TEST(CompactStore, DefaultPatchFits64KiBAndDoesNotAllocate) {
  TouchDetector codes(kTaxels, kRate, WindowConfig{}, eskin::SampleStore::kCodes);
  EXPECT_LE(codes.memory_bytes(), 65536);
  TouchDetector native(kTaxels, kRate, WindowConfig{}, eskin::SampleStore::kNative);
  EXPECT_GT(native.memory_bytes(), 2 * 65536);
  const int64_t T = 21000;
  const auto inter = interleave(make_recording(T, {{3000, 6000, 150.0}, {9000, 9500, 150.0}}, 41), T);
  std::vector<double> tensor(kTaxels * 100);
  int windows = 0;
  const long before = g_allocations.load();
  for (int64_t t = 0; t < T; ++t)
    if (codes.push(inter.data() + t * kTaxels) == Status::kWindow) {
      ++windows;
      EXPECT_EQ(codes.subsample_last_window(100, SubsampleMethod::kAlgorithm2,
                                            ShortPolicy::kInterpolate, tensor.data()),
                Status::kOk);
    }
  EXPECT_EQ(g_allocations.load() - before, 0);
  EXPECT_EQ(windows, 2);
}

// ------------------------------------------------------------------ window selection

TEST(WindowSelector, SpanIgnoresWeakTouchesAndCapacityBoundHolds) {
  WindowConfig c;  // select = span, span_fraction = 0.05
  const auto p = eskin::resolve_window_config(c, kRate);
  eskin::WindowSelector sel(p, 8);
  auto touch = [](int64_t a, int64_t b, double e) {
    TouchWindow w;
    w.start = a - 10;
    w.onset = a;
    w.offset = b;
    w.stop = b + 10;
    w.energy = e;
    return w;
  };
  sel.add(touch(100, 200, 1.0));     // weak: ignored by span
  sel.add(touch(1000, 3000, 100.0));
  sel.add(touch(4000, 4500, 10.0));
  sel.add(touch(6000, 6100, 2.0));   // weak
  const TouchWindow w = sel.result();
  EXPECT_EQ(w.start, 990);
  EXPECT_EQ(w.stop, 4510);
  EXPECT_DOUBLE_EQ(w.energy, 110.0);
  // over capacity, the least energetic touches are dropped: the span stays right
  for (int i = 0; i < 20; ++i) sel.add(touch(7000 + 100 * i, 7050 + 100 * i, 0.5));
  EXPECT_EQ(sel.result().start, 990);
  EXPECT_EQ(sel.result().stop, 4510);
  // no recording can produce more touches than capacity_for says: a burst every frame-ish
  const int64_t T = 21000;
  std::vector<Burst> bursts;
  for (int64_t a = 1000; a + 300 < T; a += 700) bursts.push_back({a, a + 200, 150.0});
  const auto x = make_recording(T, bursts, 50);
  TouchDetector det(kTaxels, kRate, c);
  const auto ws = stream_all(det, interleave(x, T), T);
  EXPECT_GT(ws.size(), 20u);
  EXPECT_LE(static_cast<int64_t>(ws.size()), eskin::WindowSelector::capacity_for(p, T));
}
