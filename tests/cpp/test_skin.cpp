// The multi-patch engine: the same decisions as one StreamClassifier per patch, whatever the
// block sizes and the order of the patches; skin events; positions; construction errors.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <fstream>
#include <iterator>
#include <random>
#include <stdexcept>
#include <string>
#include <vector>

#include "eskin/model.hpp"
#include "eskin/skin.hpp"

namespace {

using eskin::Model;
using eskin::SkinConfig;
using eskin::SkinDecision;
using eskin::SkinEngine;
using eskin::SkinStatus;

constexpr int kTaxels = 16;

Model fixture(const char* dtype) {
  std::ifstream f(std::string(ESKIN_TEST_DATA_DIR) + "/model_small_" + dtype + ".eskin", std::ios::binary);
  const std::vector<std::uint8_t> b((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
  return Model::from_bytes(b.data(), b.size());
}

struct Burst {
  std::int64_t a, b;
  double amp;
  int only_taxel = -1;  // -1: every taxel
};

// One patch's stream, sample-major (T x 16): noise (sd 15), sine bursts. With only_taxel set
// for every burst, the other taxels are a constant (no noise, no signal).
std::vector<std::int16_t> patch_stream(std::int64_t T, const std::vector<Burst>& bursts, unsigned seed,
                                       int quiet_except = -1) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> noise(0.0, 15.0);
  std::vector<std::int16_t> x(static_cast<std::size_t>(T * kTaxels));
  for (std::int64_t t = 0; t < T; ++t)
    for (int k = 0; k < kTaxels; ++k) {
      double v = 0.0;
      if (quiet_except < 0 || k == quiet_except) v += noise(rng);
      for (const Burst& b : bursts)
        if (t >= b.a && t < b.b && (b.only_taxel < 0 || b.only_taxel == k))
          v += b.amp * (1.0 + 0.1 * k) * std::sin(2 * 3.14159265358979 * (40.0 + 13.0 * k) * t / 3000.0);
      x[static_cast<std::size_t>(t * kTaxels + k)] = static_cast<std::int16_t>(std::lround(v));
    }
  return x;
}

std::vector<Burst> random_bursts(std::mt19937& gen, std::int64_t T) {
  std::uniform_int_distribution<std::int64_t> gap(100, 5000), len(200, 6000);
  std::uniform_real_distribution<double> amp(200.0, 900.0);
  std::vector<Burst> out;
  for (std::int64_t t = 600 + gap(gen); t < T;) {
    const std::int64_t b = std::min(T, t + len(gen));
    out.push_back({t, b, amp(gen)});
    t = b + gap(gen);
  }
  return out;
}

struct Got {
  int patch, label;
  bool dont_know;
  std::int64_t start, stop, sample, event;
  std::vector<double> values;
  std::array<double, 3> position;
  bool operator==(const Got& o) const {
    return patch == o.patch && label == o.label && dont_know == o.dont_know && start == o.start &&
           stop == o.stop && sample == o.sample && values == o.values;
  }
};

struct Collect : eskin::SkinSink {
  std::vector<Got> got;
  void on_decision(const SkinDecision& d) noexcept override {
    got.push_back({d.patch, d.label, d.dont_know, d.window_start, d.window_stop, d.sample, d.event,
                   std::vector<double>(d.values, d.values + d.n_machines), d.position});
  }
};

// The reference: one StreamClassifier per patch, sample by sample.
std::vector<Got> reference(const std::vector<const Model*>& models, const std::vector<int>& model_of,
                           const std::vector<std::vector<std::int16_t>>& streams, std::int64_t T) {
  std::vector<Got> out;
  for (std::size_t p = 0; p < streams.size(); ++p) {
    eskin::StreamClassifier sc(*models[static_cast<std::size_t>(model_of[p])]);
    auto take = [&](eskin::ClassifyStatus s) {
      if (s != eskin::ClassifyStatus::kDecision) return;
      const eskin::Decision& d = sc.decision();
      out.push_back({static_cast<int>(p), d.label, d.dont_know, d.window_start, d.window_stop,
                     sc.samples_seen(), -1, std::vector<double>(d.values, d.values + d.n_machines), {}});
    };
    for (std::int64_t t = 0; t < T; ++t) take(sc.push(streams[p].data() + t * kTaxels));
    take(sc.flush());
  }
  return out;
}

std::vector<Got> by_patch(std::vector<Got> g) {
  std::stable_sort(g.begin(), g.end(), [](const Got& a, const Got& b) {
    return a.patch != b.patch ? a.patch < b.patch : a.sample < b.sample;
  });
  return g;
}

}  // namespace

// The property: over seeds, block sizes and patch orders, per-patch blocks and interleaved
// blocks give every StreamClassifier decision (values, labels, windows, sample), bit for bit,
// with one shared model or two models through the patch -> model table.
TEST(SkinEngine, SameDecisionsAsOneStreamClassifierPerPatch) {
  const Model m32 = fixture("float32"), m64 = fixture("float64");
  const std::vector<const Model*> models = {&m32, &m64};
  const std::int64_t T = 30000;
  int compared = 0;
  for (unsigned seed = 0; seed < 3; ++seed) {
    std::mt19937 gen(seed);
    const int P = 3 + static_cast<int>(seed);
    std::vector<int> model_of(static_cast<std::size_t>(P));
    for (int p = 0; p < P; ++p) model_of[static_cast<std::size_t>(p)] = seed == 0 ? 0 : p % 2;
    std::vector<std::vector<std::int16_t>> streams;
    for (int p = 0; p < P; ++p) streams.push_back(patch_stream(T, random_bursts(gen, T), seed * 100 + p));
    const std::vector<Got> want = reference(models, model_of, streams, T);
    ASSERT_GE(want.size(), static_cast<std::size_t>(2 * P));

    SkinConfig c;
    c.models = models;
    c.patch_model = model_of;
    SkinEngine engine(c);
    // interleaved, in blocks of random sizes
    std::vector<std::int16_t> block;
    Collect inter;
    std::uniform_int_distribution<std::int64_t> size(1, 3000);
    for (std::int64_t t = 0; t < T;) {
      const std::int64_t n = std::min(T - t, size(gen));
      block.assign(static_cast<std::size_t>(n * P * kTaxels), 0);
      for (std::int64_t i = 0; i < n; ++i)
        for (int p = 0; p < P; ++p)
          std::copy_n(streams[static_cast<std::size_t>(p)].data() + (t + i) * kTaxels, kTaxels,
                      block.data() + (i * P + p) * kTaxels);
      ASSERT_EQ(engine.push_interleaved(block.data(), n, &inter), SkinStatus::kOk);
      t += n;
    }
    ASSERT_EQ(engine.flush(&inter), SkinStatus::kOk);
    EXPECT_EQ(by_patch(inter.got), want);
    EXPECT_TRUE(std::is_sorted(inter.got.begin(), inter.got.end(), [](const Got& a, const Got& b) {
      return a.sample != b.sample ? a.sample < b.sample : a.patch < b.patch;
    }));
    // per patch, in a shuffled patch order and random block sizes
    engine.reset();
    Collect per;
    std::vector<std::int64_t> at(static_cast<std::size_t>(P), 0);
    std::uniform_int_distribution<int> pick(0, P - 1);
    while (std::any_of(at.begin(), at.end(), [&](std::int64_t v) { return v < T; })) {
      const int p = pick(gen);
      auto& t = at[static_cast<std::size_t>(p)];
      const std::int64_t n = std::min(T - t, size(gen));
      ASSERT_EQ(engine.push_block(p, streams[static_cast<std::size_t>(p)].data() + t * kTaxels, n, &per),
                SkinStatus::kOk);
      t += n;
    }
    ASSERT_EQ(engine.flush(&per), SkinStatus::kOk);
    EXPECT_EQ(by_patch(per.got), want);
    compared += static_cast<int>(want.size());
  }
  EXPECT_GT(compared, 20);
}

// Interleaved blocks of every patch's stream through an engine with `buffers` shared window
// buffers (0: each patch its own).
std::vector<Got> run_interleaved(SkinEngine& engine, const std::vector<std::vector<std::int16_t>>& streams,
                                 std::int64_t T, std::int64_t n) {
  const auto P = static_cast<int>(streams.size());
  Collect got;
  std::vector<std::int16_t> block;
  for (std::int64_t t = 0; t < T; t += n) {
    const std::int64_t m = std::min(n, T - t);
    block.assign(static_cast<std::size_t>(m * P * kTaxels), 0);
    for (std::int64_t i = 0; i < m; ++i)
      for (int p = 0; p < P; ++p)
        std::copy_n(streams[static_cast<std::size_t>(p)].data() + (t + i) * kTaxels, kTaxels,
                    block.data() + (i * P + p) * kTaxels);
    EXPECT_EQ(engine.push_interleaved(block.data(), m, &got), SkinStatus::kOk);
  }
  EXPECT_EQ(engine.flush(&got), SkinStatus::kOk);
  return by_patch(got.got);
}

// Shared window buffers: with as many as the most touches in progress at once, every decision
// is the StreamClassifier's; with fewer, the touches that start while all are taken are the
// only ones missing (counted), every other decision unchanged; the memory per patch falls.
TEST(SkinEngine, SharedWindowBuffersKeepEveryDecisionTheyHaveRoomFor) {
  const Model m32 = fixture("float32");
  const std::vector<const Model*> models = {&m32};
  const std::int64_t T = 40000;
  for (unsigned seed = 10; seed < 13; ++seed) {
    std::mt19937 gen(seed);
    const int P = 6;
    const std::vector<int> model_of(static_cast<std::size_t>(P), 0);
    std::vector<std::vector<std::int16_t>> streams;
    for (int p = 0; p < P; ++p) {
      std::vector<Burst> sparse;  // every other burst: patches not all touched at once
      const std::vector<Burst> bursts = random_bursts(gen, T);
      for (std::size_t i = p % 2; i < bursts.size(); i += 2) sparse.push_back(bursts[i]);
      streams.push_back(patch_stream(T, sparse, seed * 100 + p));
    }
    const std::vector<Got> want = reference(models, model_of, streams, T);
    SkinConfig c;
    c.models = models;
    c.patch_model = model_of;
    SkinEngine own(c);
    c.window_buffers = P;
    SkinEngine all(c);
    EXPECT_EQ(run_interleaved(all, streams, T, 700), want);
    EXPECT_EQ(all.unbuffered(), 0);
    const std::int64_t peak = all.window_buffers_peak();
    ASSERT_GE(peak, 2) << "the streams must have touches in progress at once";
    ASSERT_LT(peak, P);

    c.window_buffers = peak;  // as many as were ever taken at once: nothing missing
    SkinEngine enough(c);
    EXPECT_EQ(run_interleaved(enough, streams, T, 1), want);
    EXPECT_EQ(enough.unbuffered(), 0);
    EXPECT_EQ(enough.window_buffers_peak(), peak);

    c.window_buffers = 1;
    SkinEngine one(c);
    EXPECT_LT(one.bytes_per_patch(), own.bytes_per_patch());
    const std::vector<Got> got = run_interleaved(one, streams, T, 333);
    EXPECT_GT(one.unbuffered(), 0);
    EXPECT_EQ(one.window_buffers_peak(), 1);
    EXPECT_EQ(static_cast<std::int64_t>(got.size()) + one.unbuffered(), static_cast<std::int64_t>(want.size()));
    EXPECT_EQ(one.dropped(), one.unbuffered());
    for (const Got& g : got) EXPECT_NE(std::find(want.begin(), want.end(), g), want.end());
    one.reset();
    EXPECT_EQ(one.unbuffered(), 0);
    EXPECT_EQ(run_interleaved(one, streams, T, 333), got);  // reset gave every buffer back
  }
}

// Chunked window store: the window's kept samples in chunks of a shared pool, taken as the
// window grows and given back when it ends (halving: tests/cpp/test_preprocess.cpp,
// ChunkedStore). With the pool of every patch's full window every decision is the
// StreamClassifier's and less memory is in use than with whole buffers; with one window's
// worth for six patches touched at once the touches that find no free chunk are the only
// ones missing (counted), every other decision unchanged; reset gives every chunk back.
TEST(SkinEngine, ChunkedWindowStoreKeepsEveryDecisionItHasRoomFor) {
  const Model m32 = fixture("float32");
  const std::vector<const Model*> models = {&m32};
  const std::int64_t T = 40000;
  const int P = 6;
  const std::vector<int> model_of(static_cast<std::size_t>(P), 0);
  SkinConfig c;
  c.models = models;
  c.patch_model = model_of;
  const std::int64_t cap = eskin::resolve_window_config(m32.window_config(), m32.sample_rate_hz()).window_capacity;
  ASSERT_GE(cap, 128);
  for (unsigned seed = 20; seed < 22; ++seed) {
    std::mt19937 gen(seed);
    std::vector<std::vector<std::int16_t>> streams;
    for (int p = 0; p < P; ++p) {
      std::vector<Burst> sparse;
      const std::vector<Burst> bursts = random_bursts(gen, T);
      for (std::size_t i = p % 2; i < bursts.size(); i += 2) sparse.push_back(bursts[i]);
      streams.push_back(patch_stream(T, sparse, seed * 100 + p));
    }
    const std::vector<Got> want = reference(models, model_of, streams, T);
    std::vector<std::vector<std::int16_t>> together;  // the same bursts on every patch
    const std::vector<Burst> common = random_bursts(gen, T);
    for (int p = 0; p < P; ++p) together.push_back(patch_stream(T, common, seed * 100 + 50 + p));
    const std::vector<Got> want_together = reference(models, model_of, together, T);
    c.window_buffers = P;
    c.window_chunk_samples = 0;
    SkinEngine whole(c);
    EXPECT_EQ(run_interleaved(whole, streams, T, 700), want);
    for (const std::int64_t chunk : {std::int64_t{1}, std::int64_t{7}, std::int64_t{64}, cap - 1}) {
      SCOPED_TRACE(chunk);
      c.window_buffers = P;
      c.window_chunk_samples = chunk;
      SkinEngine all(c);
      const std::int64_t per_window = (cap + chunk - 1) / chunk;
      EXPECT_EQ(all.window_pool_size(), P * per_window);
      EXPECT_EQ(all.window_pool_samples(), chunk);
      EXPECT_EQ(run_interleaved(all, streams, T, 700), want);
      EXPECT_EQ(all.unbuffered(), 0);
      EXPECT_EQ(all.dropped(), 0);
      EXPECT_GT(all.window_pool_in_use(), 0);  // the last windows, readable until the next push
      EXPECT_LT(all.window_buffers_peak() * chunk, whole.window_buffers_peak() * cap);
      all.reset();
      EXPECT_EQ(all.window_pool_in_use(), 0);

      c.window_buffers = 1;  // one window's worth of chunks for six patches touched at once
      SkinEngine small(c);
      const std::vector<Got> got = run_interleaved(small, together, T, 333);
      EXPECT_GT(small.unbuffered(), 0);
      EXPECT_EQ(small.window_buffers_peak(), per_window);
      EXPECT_EQ(static_cast<std::int64_t>(got.size()) + small.unbuffered(),
                static_cast<std::int64_t>(want_together.size()));
      EXPECT_EQ(small.dropped(), small.unbuffered());
      EXPECT_GT(got.size(), 0u);
      for (const Got& g : got) EXPECT_NE(std::find(want_together.begin(), want_together.end(), g), want_together.end());
      small.reset();
      EXPECT_EQ(small.window_pool_in_use(), 0);
      EXPECT_EQ(small.unbuffered(), 0);
      EXPECT_EQ(run_interleaved(small, together, T, 333), got);  // reset gave every chunk back
    }
  }
}

// Three patches in a row (0-1 adjacent, 1-2 adjacent), a fourth apart: a touch on 0 and 1 at
// once is one event, the simultaneous touch on 3 another; later, touches on 1 and 2 whose
// windows overlap are one event; a touch on 2 alone, a third.
TEST(SkinEngine, AdjacentOverlappingTouchesAreOneSkinEvent) {
  const Model m = fixture("float32");
  SkinConfig c;
  c.models = {&m};
  c.n_patches = 4;
  c.adjacency = {{0, 1}, {1, 2}};
  SkinEngine engine(c);
  const std::int64_t T = 40000;
  const std::vector<std::vector<Burst>> bursts = {
      {{3000, 6000, 600.0}},
      {{3300, 5800, 600.0}, {15000, 18000, 600.0}},
      {{16500, 20000, 600.0}, {30000, 33000, 600.0}},
      {{3100, 6100, 600.0}}};
  std::vector<std::int16_t> block(static_cast<std::size_t>(T * 4 * kTaxels));
  for (int p = 0; p < 4; ++p) {
    const auto s = patch_stream(T, bursts[static_cast<std::size_t>(p)], 7 + p);
    for (std::int64_t t = 0; t < T; ++t)
      std::copy_n(s.data() + t * kTaxels, kTaxels, block.data() + (t * 4 + p) * kTaxels);
  }
  Collect out;
  ASSERT_EQ(engine.push_interleaved(block.data(), T, &out), SkinStatus::kOk);
  ASSERT_EQ(engine.flush(&out), SkinStatus::kOk);
  ASSERT_EQ(out.got.size(), 6u);
  auto event_of = [&](int patch, std::int64_t near) {
    for (const Got& g : out.got)
      if (g.patch == patch && g.start <= near && near < g.stop) return g.event;
    return std::int64_t{-100};
  };
  // in the order the touches ended: 1 (3300-5800) first, then 0, then 3
  EXPECT_EQ(event_of(1, 4000), 0);
  EXPECT_EQ(event_of(0, 4000), 0);
  EXPECT_EQ(event_of(3, 4000), 1);
  EXPECT_EQ(event_of(1, 16000), 2);
  EXPECT_EQ(event_of(2, 17000), 2);
  EXPECT_EQ(event_of(2, 31000), 3);
}

// With a layout, the position is the energy-weighted centroid of the taxel positions: a touch
// on one taxel of an otherwise constant patch sits exactly on that taxel.
TEST(SkinEngine, PositionIsTheEnergyWeightedCentroid) {
  const Model m = fixture("float64");
  SkinConfig c;
  c.models = {&m};
  c.n_patches = 2;
  c.position_dims = 3;
  for (int p = 0; p < 2; ++p)
    for (int k = 0; k < kTaxels; ++k) c.positions.insert(c.positions.end(), {0.01 * (k % 4) + p, 0.01 * (k / 4), 0.5 * p});
  SkinEngine engine(c);
  const std::int64_t T = 12000;
  Collect out;
  for (int p = 0; p < 2; ++p) {
    const int taxel = p == 0 ? 5 : 14;
    const auto s = patch_stream(T, {{3000, 7000, 900.0, taxel}}, 3, taxel);
    ASSERT_EQ(engine.push_block(p, s.data(), T, &out), SkinStatus::kOk);
  }
  ASSERT_EQ(engine.flush(&out), SkinStatus::kOk);
  ASSERT_EQ(out.got.size(), 2u);
  EXPECT_DOUBLE_EQ(out.got[0].position[0], 0.01);
  EXPECT_DOUBLE_EQ(out.got[0].position[1], 0.01);
  EXPECT_DOUBLE_EQ(out.got[0].position[2], 0.0);
  EXPECT_DOUBLE_EQ(out.got[1].position[0], 1.02);
  EXPECT_DOUBLE_EQ(out.got[1].position[1], 0.03);
  EXPECT_DOUBLE_EQ(out.got[1].position[2], 0.5);
}

TEST(SkinEngine, BadConfigurationNamesTheFieldAndValue) {
  const Model m = fixture("float32");
  auto message = [](const SkinConfig& c) {
    try {
      SkinEngine e(c);
    } catch (const std::invalid_argument& err) {
      return std::string(err.what());
    }
    return std::string("no error");
  };
  SkinConfig c;
  EXPECT_EQ(message(c), "SkinConfig.models = []: needs at least one model");
  c.models = {&m};
  EXPECT_EQ(message(c), "SkinConfig.n_patches = 0: must be in [1, 1048576] when patch_model is empty");
  c.patch_model = {0, 1};
  EXPECT_EQ(message(c), "SkinConfig.patch_model[1] = 1: must be a model index in [0, 1)");
  c.patch_model = {0, 0};
  c.adjacency = {{0, 2}};
  EXPECT_EQ(message(c), "SkinConfig.adjacency[0] = (0, 2): must be two different patches in [0, 2)");
  c.adjacency = {{1, 1}};
  EXPECT_EQ(message(c), "SkinConfig.adjacency[0] = (1, 1): must be two different patches in [0, 2)");
  c.adjacency = {};
  c.position_dims = 2;
  c.positions = std::vector<double>(10, 0.0);
  EXPECT_EQ(message(c), "SkinConfig.positions = 10 values: must hold 64 (32 taxels x 2 coordinates)");
  c.position_dims = 4;
  EXPECT_EQ(message(c), "SkinConfig.position_dims = 4: must be 0 (no layout), 2 or 3");
  c.position_dims = 0;
  c.positions = {};
  c.chunk_samples = -1;
  EXPECT_EQ(message(c), "SkinConfig.chunk_samples = -1: must be in [0, 1048576] (0: the default)");
  c.chunk_samples = 0;
  c.window_buffers = 3;
  EXPECT_EQ(message(c), "SkinConfig.window_buffers = 3: must be in [0, 2] (0: one per patch)");
  c.window_buffers = -1;
  EXPECT_EQ(message(c), "SkinConfig.window_buffers = -1: must be in [0, 2] (0: one per patch)");
  c.window_buffers = 0;
  c.window_chunk_samples = 64;
  EXPECT_EQ(message(c), "SkinConfig.window_chunk_samples = 64: needs shared window buffers (window_buffers > 0)");
  c.window_buffers = 2;
  c.window_chunk_samples = -1;
  EXPECT_EQ(message(c), "SkinConfig.window_chunk_samples = -1: must be in [0, 21000] (0: whole window buffers; at most the largest window_samples)");
  c.window_chunk_samples = 21001;  // the fixture's window: every sample of 7 s
  EXPECT_EQ(message(c), "SkinConfig.window_chunk_samples = 21001: must be in [0, 21000] (0: whole window buffers; at most the largest window_samples)");
  c.window_chunk_samples = 64;
  EXPECT_EQ(message(c), "no error");
}

TEST(SkinEngine, BadCallsReturnAStatus) {
  const Model m = fixture("float32");
  SkinConfig c;
  c.models = {&m};
  c.n_patches = 2;
  SkinEngine engine(c);
  Collect out;
  std::vector<std::int16_t> s(kTaxels * 2, 0);
  EXPECT_EQ(engine.push_block(2, s.data(), 1, &out), SkinStatus::kBadPatch);
  EXPECT_EQ(engine.push_block(-1, s.data(), 1, &out), SkinStatus::kBadPatch);
  EXPECT_EQ(engine.push_block(0, nullptr, 1, &out), SkinStatus::kNullPointer);
  EXPECT_EQ(engine.push_block(0, s.data(), -1, &out), SkinStatus::kBadLength);
  EXPECT_EQ(engine.push_interleaved(s.data(), 1, nullptr), SkinStatus::kNullPointer);
  EXPECT_EQ(engine.push_interleaved(s.data(), 1, &out), SkinStatus::kOk);
  EXPECT_EQ(engine.samples_seen(0), 1);
  EXPECT_EQ(engine.samples_seen(1), 1);
  EXPECT_EQ(engine.total_taxels(), 32);
  EXPECT_EQ(engine.taxel_offset(1), 16);
  EXPECT_STREQ(eskin::to_string(SkinStatus::kBadPatch), "bad patch");
}
