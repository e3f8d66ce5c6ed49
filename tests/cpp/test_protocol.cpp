#include <gtest/gtest.h>

#include <atomic>
#include <cstdlib>
#include <cstring>
#include <map>
#include <new>
#include <random>
#include <string>
#include <vector>

#include <memory>

#include "eskin/protocol.hpp"

namespace p = eskin::protocol;
using Bytes = std::vector<std::uint8_t>;

// Counts heap allocations in this test binary, to check the byte path allocates nothing.
static std::atomic<long> g_allocations{0};
void* operator new(std::size_t n) {
  ++g_allocations;
  if (void* q = std::malloc(n ? n : 1)) return q;
  throw std::bad_alloc();
}
void operator delete(void* q) noexcept { std::free(q); }
void operator delete(void* q, std::size_t) noexcept { std::free(q); }

namespace {

Bytes bytes_of(const std::string& s) { return Bytes(s.begin(), s.end()); }

Bytes cobs(const Bytes& in) {
  Bytes out(p::max_encoded_size(in.size()));
  const std::size_t n = p::cobs_encode(in.data(), in.size(), out.data(), out.size());
  out.resize(n);
  return out;
}

Bytes uncobs(const Bytes& in, bool* ok = nullptr) {
  Bytes out(in.size() + 1);
  const auto n = p::cobs_decode(in.data(), in.size(), out.data(), out.size());
  if (ok) *ok = n >= 0;
  out.resize(n < 0 ? 0 : static_cast<std::size_t>(n));
  return out;
}

Bytes serialize(const p::Frame& f) {
  Bytes raw(p::kMaxFrameSize);
  const std::size_t n = p::serialize_frame(f, raw.data(), raw.size());
  raw.resize(n);
  return raw;
}

Bytes encode(const p::Frame& f) {
  Bytes out(p::kMaxEncodedFrameSize);
  p::FrameEncoder enc;
  const std::size_t n = enc.encode(f, out.data(), out.size());
  EXPECT_GT(n, 0U) << p::encode_status_message(enc.status());
  out.resize(n);
  return out;
}

/// A stream of frames of every type with distinct content; samples live in `store`.
struct Stream {
  std::vector<std::vector<std::int16_t>> store;
  std::vector<p::Frame> frames;
  std::string names = "brush\nfinger\nwasher";
};

Stream make_stream(std::size_t n, std::uint32_t seed) {
  Stream s;
  std::mt19937 rng(seed);
  std::uniform_int_distribution<int> adc(-32768, 32767);
  s.store.reserve(n);
  std::uint64_t sample = 0;
  for (std::size_t i = 0; i < n; ++i) {
    p::Frame f;
    f.seq = static_cast<std::uint16_t>(i);
    switch (i % 7) {
      case 3: {
        f.type = p::FrameType::decision;
        f.decision.onset_sample = sample - 100;
        f.decision.offset_sample = sample;
        f.decision.decided_sample = sample + 3;
        f.decision.timestamp_us = i * 1000;
        f.decision.latency_us = 17;
        f.decision.label = static_cast<std::int16_t>(i % 3);
        f.decision.n_values = 3;
        for (int k = 0; k < 3; ++k) f.decision.values[k] = 0.25 * (k - 1) + 1e-3 * i;
        break;
      }
      case 5:
        f.type = p::FrameType::status;
        f.status.uptime_us = i * 3333;
        f.status.next_sample = sample;
        f.status.dropped_samples = i;
        f.status.state = p::StreamState::streaming;
        break;
      case 6:
        if (i % 2 == 0) {
          f.type = p::FrameType::info;
          f.info.rows = 4;
          f.info.cols = 4;
          f.info.samples_per_frame = 10;
          f.info.n_classes = 3;
          f.info.sample_rate_hz = 3000.0;
          f.info.names_len = static_cast<std::uint16_t>(s.names.size());
          f.info.class_names = s.names.data();
        } else {
          f.type = p::FrameType::pong;
          f.ping.token = static_cast<std::uint32_t>(i);
          f.ping.timestamp_us = i;
        }
        break;
      default: {
        f.type = p::FrameType::data;
        s.store.emplace_back(160);
        for (auto& v : s.store.back()) v = static_cast<std::int16_t>(adc(rng));
        // plenty of zero bytes so COBS has work to do
        for (std::size_t k = 0; k < 160; k += 3) s.store.back()[k] = 0;
        f.data.first_sample = sample;
        f.data.timestamp_us = sample * 333;
        f.data.rows = 4;
        f.data.cols = 4;
        f.data.n_samples = 10;
        f.data.samples = s.store.back().data();
        sample += 10;
      }
    }
    s.frames.push_back(f);
  }
  return s;
}

Bytes wire(const Stream& s) {
  Bytes out{p::kDelimiter};
  for (const auto& f : s.frames) {
    const Bytes e = encode(f);
    out.insert(out.end(), e.begin(), e.end());
  }
  return out;
}

/// Decodes `data` in the given chunk sizes; returns the accepted frames re-serialised.
std::vector<Bytes> decode_chunks(p::FrameDecoder& dec, const Bytes& data,
                                 const std::vector<std::size_t>& chunks) {
  std::vector<Bytes> got;
  std::size_t at = 0;
  for (std::size_t c : chunks) {
    c = std::min(c, data.size() - at);
    dec.feed_all(data.data() + at, c, [&](const p::Frame& f) { got.push_back(serialize(f)); });
    at += c;
  }
  dec.feed_all(data.data() + at, data.size() - at,
               [&](const p::Frame& f) { got.push_back(serialize(f)); });
  return got;
}

}  // namespace

TEST(Crc32, KnownVectors) {
  auto crc = [](const std::string& s) {
    return p::crc32(reinterpret_cast<const std::uint8_t*>(s.data()), s.size());
  };
  EXPECT_EQ(crc("123456789"), 0xCBF43926U);
  EXPECT_EQ(crc(""), 0x00000000U);
  EXPECT_EQ(crc("a"), 0xE8B7BE43U);
  EXPECT_EQ(crc("The quick brown fox jumps over the lazy dog"), 0x414FA339U);
  // running checksum, zlib style
  const std::string a = "12345", b = "6789";
  const std::uint32_t part = crc(a);
  EXPECT_EQ(p::crc32(reinterpret_cast<const std::uint8_t*>(b.data()), b.size(), part),
            0xCBF43926U);
}

TEST(Cobs, WikipediaVectors) {
  struct Case {
    Bytes in, out;
  };
  std::vector<Case> cases = {
      {{0x00}, {0x01, 0x01}},
      {{0x00, 0x00}, {0x01, 0x01, 0x01}},
      {{0x00, 0x11, 0x00}, {0x01, 0x02, 0x11, 0x01}},
      {{0x11, 0x22, 0x00, 0x33}, {0x03, 0x11, 0x22, 0x02, 0x33}},
      {{0x11, 0x22, 0x33, 0x44}, {0x05, 0x11, 0x22, 0x33, 0x44}},
      {{0x11, 0x00, 0x00, 0x00}, {0x02, 0x11, 0x01, 0x01, 0x01}},
      {{}, {0x01}},
  };
  // 254 non-zero bytes: one full block, no trailing code
  Bytes run254(254), enc254{0xFF};
  for (int i = 0; i < 254; ++i) run254[i] = static_cast<std::uint8_t>(i + 1);
  enc254.insert(enc254.end(), run254.begin(), run254.end());
  cases.push_back({run254, enc254});
  // 00 01 .. FE (255 bytes)
  Bytes z255{0x00}, ez255{0x01, 0xFF};
  z255.insert(z255.end(), run254.begin(), run254.end());
  ez255.insert(ez255.end(), run254.begin(), run254.end());
  cases.push_back({z255, ez255});
  // 01 .. FE FF (255 bytes): a full block then a 1-byte block
  Bytes r255 = run254, er255 = enc254;
  r255.push_back(0xFF);
  er255.push_back(0x02);
  er255.push_back(0xFF);
  cases.push_back({r255, er255});
  // 02 .. FF 00 (255 bytes)
  Bytes t255, et255{0xFF};
  for (int i = 2; i <= 255; ++i) t255.push_back(static_cast<std::uint8_t>(i));
  et255.insert(et255.end(), t255.begin(), t255.end());
  t255.push_back(0x00);
  et255.push_back(0x01);
  et255.push_back(0x01);
  cases.push_back({t255, et255});
  for (const auto& c : cases) {
    EXPECT_EQ(cobs(c.in), c.out) << "input of " << c.in.size() << " bytes";
    bool ok = false;
    EXPECT_EQ(uncobs(c.out, &ok), c.in);
    EXPECT_TRUE(ok);
    EXPECT_LE(c.out.size() + 1, p::max_encoded_size(c.in.size()));
  }
}

TEST(Cobs, RoundTripsRandomRuns) {
  std::mt19937 rng(7);
  for (std::size_t len : {0, 1, 253, 254, 255, 256, 507, 508, 509, 1000, 4096}) {
    for (double zero_p : {0.0, 0.01, 0.5, 1.0}) {
      Bytes in(len);
      std::bernoulli_distribution zero(zero_p);
      std::uniform_int_distribution<int> byte(1, 255);
      for (auto& b : in) b = zero(rng) ? 0 : static_cast<std::uint8_t>(byte(rng));
      const Bytes e = cobs(in);
      EXPECT_EQ(std::count(e.begin(), e.end(), 0), 0);
      EXPECT_LE(e.size() + 1, p::max_encoded_size(len));
      bool ok = false;
      EXPECT_EQ(uncobs(e, &ok), in) << len << " " << zero_p;
      EXPECT_TRUE(ok);
    }
  }
}

TEST(Cobs, RejectsInvalidBlocks) {
  bool ok = true;
  uncobs({0x05, 0x11, 0x22}, &ok);  // code runs past the end
  EXPECT_FALSE(ok);
  uncobs({0x03, 0x00, 0x22}, &ok);  // zero inside
  EXPECT_FALSE(ok);
  uncobs({0x00}, &ok);
  EXPECT_FALSE(ok);
  Bytes out(2);
  const Bytes in{0x05, 0x11, 0x22, 0x33, 0x44};
  EXPECT_LT(p::cobs_decode(in.data(), in.size(), out.data(), out.size()), 0);  // too small
  // the documented failure is -1, for each cause: a zero code, a zero inside a run, a run
  // past the end
  Bytes big(8);
  for (const Bytes& bad : {Bytes{0x00}, Bytes{0x02, 0x11, 0x00, 0x01}, Bytes{0x03, 0x00, 0x22},
                           Bytes{0x05, 0x11, 0x22}})
    EXPECT_EQ(p::cobs_decode(bad.data(), bad.size(), big.data(), big.size()), -1);
}

TEST(Frames, EveryTypeRoundTrips) {
  const Stream s = make_stream(14, 1);
  for (const auto& f : s.frames) {
    const Bytes e = encode(f);
    ASSERT_EQ(e.back(), 0);
    EXPECT_EQ(std::count(e.begin(), e.end() - 1, 0), 0);
    p::FrameDecoder dec(p::kMaxFrameSize, false);
    std::vector<Bytes> got;
    dec.feed_all(e.data(), e.size(), [&](const p::Frame& g) { got.push_back(serialize(g)); });
    ASSERT_EQ(got.size(), 1U) << p::frame_type_name(f.type);
    EXPECT_EQ(got[0], serialize(f)) << p::frame_type_name(f.type);
  }
  // commands with empty payloads
  for (auto t : {p::FrameType::start, p::FrameType::stop, p::FrameType::info_request,
                 p::FrameType::ping}) {
    p::Frame f;
    f.type = t;
    f.seq = 65535;
    f.ping.token = 0xDEADBEEF;
    const Bytes e = encode(f);
    p::FrameDecoder dec(p::kMaxFrameSize, false);
    ASSERT_EQ(dec.feed(e.data(), e.size()), e.size());
    ASSERT_TRUE(dec.has_frame());
    EXPECT_EQ(dec.frame().type, t);
    EXPECT_EQ(dec.frame().seq, 65535);
  }
}

TEST(Frames, LayoutIsLittleEndianWithTrailingCrc) {
  std::int16_t samples[4] = {1, -2, 0x1234, 0};
  p::Frame f;
  f.type = p::FrameType::data;
  f.flags = p::flags::kSync;
  f.seq = 0x0102;
  f.data.first_sample = 0x1122334455667788ULL;
  f.data.timestamp_us = 5;
  f.data.rows = 2;
  f.data.cols = 2;
  f.data.n_samples = 1;
  f.data.samples = samples;
  const Bytes raw = serialize(f);
  ASSERT_EQ(raw.size(), 4 + 20 + 8 + 4U);
  EXPECT_EQ(raw[0], 0x01);
  EXPECT_EQ(raw[1], p::flags::kSync);
  EXPECT_EQ(raw[2], 0x02);
  EXPECT_EQ(raw[3], 0x01);
  EXPECT_EQ(raw[4], 0x88);
  EXPECT_EQ(raw[11], 0x11);
  EXPECT_EQ(raw[24], 0x01);
  EXPECT_EQ(raw[26], 0xFE);
  EXPECT_EQ(raw[27], 0xFF);
  EXPECT_EQ(raw[28], 0x34);
  EXPECT_EQ(raw[29], 0x12);
  const std::uint32_t crc = p::crc32(raw.data(), raw.size() - 4);
  EXPECT_EQ(raw[raw.size() - 4], crc & 0xFF);
  EXPECT_EQ(raw[raw.size() - 1], crc >> 24);
}

TEST(Encoder, ReportsErrorsWithoutWriting) {
  p::FrameEncoder enc;
  p::Frame f;
  f.type = p::FrameType::decision;
  f.decision.n_values = p::kMaxDecisionValues + 1;
  Bytes out(p::kMaxEncodedFrameSize);
  EXPECT_EQ(enc.encode(f, out.data(), out.size()), 0U);
  EXPECT_EQ(enc.status(), p::EncodeStatus::invalid_frame);
  f.decision.n_values = 2;
  EXPECT_EQ(enc.encode(f, out.data(), 10), 0U);
  EXPECT_EQ(enc.status(), p::EncodeStatus::buffer_too_small);
  std::vector<std::int16_t> big(16 * 200);
  f.type = p::FrameType::data;
  f.data = {};
  f.data.rows = 4;
  f.data.cols = 4;
  f.data.n_samples = 200;  // 6400 bytes > kMaxFrameSize
  f.data.samples = big.data();
  EXPECT_EQ(enc.encode(f, out.data(), out.size()), 0U);
  EXPECT_EQ(enc.status(), p::EncodeStatus::invalid_frame);
  f.data.n_samples = static_cast<std::uint16_t>(p::max_samples_per_frame(16));
  EXPECT_GT(enc.encode(f, out.data(), out.size()), 0U);
  f.type = static_cast<p::FrameType>(0x7F);
  EXPECT_EQ(enc.encode(f, out.data(), out.size()), 0U);
}

TEST(Decoder, SameFramesForAnySplit) {
  const Stream s = make_stream(300, 2);
  const Bytes data = wire(s);
  p::FrameDecoder whole;
  const auto expected = decode_chunks(whole, data, {});
  ASSERT_EQ(expected.size(), s.frames.size());
  for (std::size_t i = 0; i < expected.size(); ++i) EXPECT_EQ(expected[i], serialize(s.frames[i]));
  std::mt19937 rng(3);
  for (int trial = 0; trial < 20; ++trial) {
    std::uniform_int_distribution<std::size_t> len(0, trial < 10 ? 3 : 700);
    std::vector<std::size_t> chunks;
    for (std::size_t at = 0; at < data.size();) chunks.push_back(len(rng)), at += chunks.back();
    p::FrameDecoder dec;
    EXPECT_EQ(decode_chunks(dec, data, chunks), expected) << "trial " << trial;
    EXPECT_EQ(dec.stats().frames, s.frames.size());
    EXPECT_EQ(dec.stats().bytes, data.size());
  }
}

TEST(Decoder, CountsSequenceGapsAndLostSamples) {
  Stream s = make_stream(70, 4);
  const p::Frame removed_data = s.frames[8];  // a DATA frame (i % 7 == 1)
  ASSERT_EQ(removed_data.type, p::FrameType::data);
  s.frames.erase(s.frames.begin() + 8);
  s.frames.erase(s.frames.begin() + 40, s.frames.begin() + 43);  // 3 frames, incl. one DATA-less?
  std::size_t lost_data = 1;
  // frames 41..43 of the original stream: count the DATA among them
  const Stream orig = make_stream(70, 4);
  for (int i = 41; i <= 43; ++i) lost_data += orig.frames[i].type == p::FrameType::data;
  const Bytes data = wire(s);
  p::FrameDecoder dec;
  decode_chunks(dec, data, {});
  EXPECT_EQ(dec.stats().sequence_gaps, 2U);
  EXPECT_EQ(dec.stats().lost_frames, 4U);
  EXPECT_EQ(dec.stats().lost_samples, 10U * lost_data);
  EXPECT_EQ(dec.stats().crc_errors + dec.stats().malformed + dec.stats().oversize, 0U);
}

TEST(Decoder, SyncFlagSuppressesGapAndWrapIsNoGap) {
  p::Frame a;
  a.type = p::FrameType::stop;
  a.seq = 65535;
  p::Frame b = a;
  b.seq = 0;  // wraps: no gap
  p::Frame c = a;
  c.seq = 500;
  c.flags = p::flags::kSync;  // new stream: no gap
  Bytes data{0};
  for (const auto& f : {a, b, c}) {
    const Bytes e = encode(f);
    data.insert(data.end(), e.begin(), e.end());
  }
  p::FrameDecoder dec;
  decode_chunks(dec, data, {});
  EXPECT_EQ(dec.stats().frames, 3U);
  EXPECT_EQ(dec.stats().sequence_gaps, 0U);
}

TEST(Decoder, SkipsUntilFirstDelimiterAndResyncsAfterOversize) {
  const Stream s = make_stream(3, 5);
  Bytes data = {0x11, 0x22, 0x33};  // tail of a frame we joined in the middle of
  const Bytes w = wire(s);
  data.insert(data.end(), w.begin(), w.end());
  Bytes junk(10000, 0x5A);  // far longer than any frame
  data.insert(data.end(), junk.begin(), junk.end());
  data.insert(data.end(), w.begin(), w.end());
  p::FrameDecoder dec;
  const auto got = decode_chunks(dec, data, {1, 2, 5000});
  EXPECT_EQ(got.size(), 6U);
  EXPECT_EQ(dec.stats().skipped_bytes, 3U);
  EXPECT_EQ(dec.stats().oversize, 1U);
  EXPECT_EQ(dec.stats().malformed + dec.stats().crc_errors, 0U);
  // a small limit turns normal DATA frames into oversize blocks, never into partial frames
  p::FrameDecoder small(64);
  const auto none = decode_chunks(small, w, {});
  EXPECT_EQ(none.size(), 0U);  // frames 0..2 are 348-byte DATA frames
  EXPECT_EQ(small.stats().oversize, 3U);
}

TEST(Decoder, NeverAcceptsCorruptedFramesAndEachFaultCostsAtMostTwo) {
  const Stream s = make_stream(2000, 6);
  const Bytes clean = wire(s);
  std::map<std::uint16_t, Bytes> original;
  for (const auto& f : s.frames) original[f.seq] = serialize(f);
  // frame boundaries in the clean stream (index of each delimiter)
  std::vector<std::size_t> ends;
  for (std::size_t i = 1; i < clean.size(); ++i)
    if (clean[i] == 0) ends.push_back(i);
  ASSERT_EQ(ends.size(), s.frames.size());

  std::mt19937 rng(11);
  for (int kind = 0; kind < 4; ++kind) {  // 0 bit flip, 1 byte drop, 2 garbage burst, 3 truncate
    Bytes data(clean.begin(), clean.begin() + static_cast<std::ptrdiff_t>(ends[4] + 1));
    std::size_t faults = 0;
    std::size_t f = 5;
    while (f + 6 < ends.size()) {
      // one fault inside frame f (between delimiter ends[f-1] and ends[f], inclusive of the
      // closing delimiter), then clean frames up to a random distance >= 3 frames later
      const std::size_t lo = ends[f - 1] + 1, hi = ends[f];
      // a truncation keeps the delimiter, so it must start before it
      std::uniform_int_distribution<std::size_t> pos(lo, kind == 3 ? hi - 1 : hi);
      const std::size_t at = pos(rng);
      Bytes frame(clean.begin() + static_cast<std::ptrdiff_t>(lo),
                  clean.begin() + static_cast<std::ptrdiff_t>(hi + 1));
      const std::size_t k = at - lo;
      switch (kind) {
        case 0: frame[k] ^= static_cast<std::uint8_t>(1U << (rng() % 8)); break;
        case 1: frame.erase(frame.begin() + static_cast<std::ptrdiff_t>(k)); break;
        case 2: {
          Bytes g(1 + rng() % 40);
          for (auto& b : g) b = static_cast<std::uint8_t>(rng());
          frame.insert(frame.begin() + static_cast<std::ptrdiff_t>(k), g.begin(), g.end());
          break;
        }
        case 3:
          frame.erase(frame.begin() + static_cast<std::ptrdiff_t>(k), frame.end() - 1);
          break;
      }
      data.insert(data.end(), frame.begin(), frame.end());
      ++faults;
      const std::size_t next = f + 3 + rng() % 5;
      for (std::size_t c = f + 1; c < next && c < ends.size(); ++c)
        data.insert(data.end(), clean.begin() + static_cast<std::ptrdiff_t>(ends[c - 1] + 1),
                    clean.begin() + static_cast<std::ptrdiff_t>(ends[c] + 1));
      f = next;
    }
    data.insert(data.end(), clean.begin() + static_cast<std::ptrdiff_t>(ends[f - 1] + 1),
                clean.end());
    const std::size_t sent = ends.size();
    p::FrameDecoder dec;
    std::size_t accepted = 0;
    std::mt19937 split(kind);
    std::size_t at = 0;
    while (at < data.size()) {
      const std::size_t c = std::min<std::size_t>(1 + split() % 400, data.size() - at);
      dec.feed_all(data.data() + at, c, [&](const p::Frame& g) {
        ++accepted;
        auto it = original.find(g.seq);
        ASSERT_NE(it, original.end());
        EXPECT_EQ(serialize(g), it->second) << "corrupted frame accepted, kind " << kind;
      });
      at += c;
    }
    const auto& st = dec.stats();
    const std::size_t lost = sent - accepted;
    EXPECT_LE(lost, 2 * faults) << "kind " << kind;
    EXPECT_GE(lost, kind == 2 ? 0 : faults) << "kind " << kind;  // a burst may land between frames
    EXPECT_EQ(st.lost_frames, lost) << "every lost frame is counted, kind " << kind;
    EXPECT_GE(st.crc_errors + st.malformed + st.oversize, lost > 0 ? 1U : 0U);
    // samples of every lost DATA frame are counted
    std::size_t lost_samples = 0;
    std::size_t got_samples = st.samples;
    for (std::size_t i = 0; i < sent; ++i)
      if (s.frames[i].type == p::FrameType::data) lost_samples += 10;
    EXPECT_EQ(st.lost_samples, lost_samples - got_samples) << "kind " << kind;
  }
}

TEST(Decoder, RandomGarbageNeverCrashesAndIsNeverAccepted) {
  std::mt19937 rng(12);
  p::FrameDecoder dec(p::kMaxFrameSize, false);
  Bytes data(1 << 20);
  for (auto& b : data) b = static_cast<std::uint8_t>(rng() % 8 == 0 ? 0 : rng());
  std::size_t accepted = 0;
  dec.feed_all(data.data(), data.size(), [&](const p::Frame&) { ++accepted; });
  EXPECT_EQ(accepted, 0U);
  EXPECT_GT(dec.stats().crc_errors + dec.stats().malformed, 1000U);
  EXPECT_EQ(dec.stats().bytes, data.size());
}

TEST(Decoder, ResetForgetsPartialInput) {
  const Stream s = make_stream(2, 8);
  const Bytes w = wire(s);
  p::FrameDecoder dec;
  dec.feed_all(w.data(), w.size() / 2, [](const p::Frame&) {});
  dec.reset();
  std::size_t n = 0;
  dec.feed_all(w.data(), w.size(), [&](const p::Frame&) { ++n; });
  EXPECT_EQ(n, 2U);
  dec.reset(true);
  EXPECT_EQ(dec.stats().frames, 0U);
}

TEST(Decoder, AfterResetTheTailOfAFrameIsSkippedNotCountedAsCorrupted) {
  const Stream s = make_stream(2, 8);
  const Bytes w = wire(s);
  Bytes resumed(w.begin() + static_cast<std::ptrdiff_t>(w.size() / 3), w.end());
  resumed.insert(resumed.end(), w.begin(), w.end());  // then the stream from its start
  for (const bool wait : {true, false}) {
    p::FrameDecoder dec(p::kMaxFrameSize, wait);
    dec.feed_all(w.data(), w.size() / 3, [](const p::Frame&) {});
    dec.reset();  // e.g. the port was reopened: the input resumes in the middle of a frame
    std::size_t n = 0;
    dec.feed_all(resumed.data(), resumed.size(), [&](const p::Frame&) { ++n; });
    if (wait) {  // the tail up to the next delimiter is skipped, every whole frame decoded
      EXPECT_GT(dec.stats().skipped_bytes, 0U);
      EXPECT_EQ(dec.stats().crc_errors + dec.stats().malformed, 0U);
      EXPECT_GE(n, 2U);
    } else {  // decoding from the very first byte: the tail is a damaged frame
      EXPECT_EQ(dec.stats().skipped_bytes, 0U);
      EXPECT_EQ(dec.stats().crc_errors + dec.stats().malformed, 1U);
    }
  }
}

TEST(NoHeap, EncodeAndDecodeAllocateNothing) {
  const Stream s = make_stream(200, 13);
  Bytes out(p::kMaxEncodedFrameSize * 200 + 1);
  auto enc = std::make_unique<p::FrameEncoder>();
  auto dec = std::make_unique<p::FrameDecoder>();
  std::size_t accepted = 0;
  const long before = g_allocations.load();
  std::size_t n = 0;
  out[n++] = p::kDelimiter;
  for (const auto& f : s.frames) n += enc->encode(f, out.data() + n, out.size() - n);
  for (std::size_t at = 0; at < n; at += 37)
    dec->feed_all(out.data() + at, std::min<std::size_t>(37, n - at),
                  [&](const p::Frame&) { ++accepted; });
  // garbage too
  for (std::size_t i = 0; i < n; i += 7) out[i] ^= 0x5A;
  dec->feed_all(out.data(), n, [&](const p::Frame&) {});
  const long after = g_allocations.load();
  EXPECT_EQ(after - before, 0);
  EXPECT_EQ(accepted, s.frames.size());
}

// A codec sized for one use holds only what its frames need, and refuses larger frames the way
// the full-size one refuses frames over kMaxFrameSize: the encoder without writing, the decoder
// by counting the block oversize and resyncing at the next delimiter.
TEST(SizedCodecs, HoldOnlyTheirFramesAndRefuseLargerOnes) {
  static_assert(sizeof(p::BasicFrameDecoder<32>) < 1024 && sizeof(p::FrameDecoder) > 12000,
                "a command decoder is small");
  static_assert(sizeof(p::BasicFrameEncoder<512>) < 1024, "a controller encoder is small");
  const Stream s = make_stream(21, 9);
  p::BasicFrameEncoder<512> enc;  // DATA of 10 x 16 taxels is 348 bytes decoded
  p::FrameEncoder full;
  p::BasicFrameDecoder<32> commands(32, false);  // host commands are at most 20 bytes
  std::size_t accepted = 0, small = 0;
  Bytes out(p::kMaxEncodedFrameSize), ref(p::kMaxEncodedFrameSize);
  for (const auto& f : s.frames) {
    const std::size_t n = enc.encode(f, out.data(), out.size());
    ASSERT_EQ(n, full.encode(f, ref.data(), ref.size()));  // every frame here fits 512 bytes
    ASSERT_TRUE(std::equal(out.begin(), out.begin() + n, ref.begin()));
    commands.feed_all(out.data(), n, [&](const p::Frame& g) {
      ++accepted;
      EXPECT_EQ(g.type, p::FrameType::pong);
    });
    if (serialize(f).size() <= 32) ++small;
  }
  EXPECT_EQ(accepted, small);  // PONGs (20 bytes) only
  EXPECT_GT(accepted, 0U);
  EXPECT_EQ(commands.stats().oversize + commands.stats().frames, s.frames.size());

  // a DATA frame of 20 samples (668 bytes) does not fit the 512-byte encoder: refused, nothing
  // written
  std::vector<std::int16_t> codes(20 * 16, 7);
  p::Frame big;
  big.type = p::FrameType::data;
  big.data.rows = big.data.cols = 4;
  big.data.n_samples = 20;
  big.data.samples = codes.data();
  std::fill(out.begin(), out.end(), 0xAB);
  EXPECT_EQ(enc.encode(big, out.data(), out.size()), 0U);
  EXPECT_EQ(enc.status(), p::EncodeStatus::buffer_too_small);
  EXPECT_EQ(out[0], 0xAB);
  EXPECT_GT(full.encode(big, out.data(), out.size()), 0U);
}

// ---- checks beside the decoder's main job: each was once passed by a mutant of
// cpp/src/protocol.cpp without a test failing (docs/testing.md).
namespace {

// A raw frame (header, payload, CRC) with its CRC recomputed after an edit.
Bytes rechecked(Bytes raw) {
  const std::uint32_t c = p::crc32(raw.data(), raw.size() - 4);
  for (int i = 0; i < 4; ++i) raw[raw.size() - 4 + static_cast<std::size_t>(i)] = static_cast<std::uint8_t>(c >> (8 * i));
  return raw;
}

// The frames a fresh decoder accepts from one raw frame, and its malformed count.
std::pair<int, std::uint64_t> decode_raw(const Bytes& raw) {
  Bytes e = cobs(raw);
  e.push_back(0);
  p::FrameDecoder dec(p::kMaxFrameSize, false);
  int n = 0;
  dec.feed_all(e.data(), e.size(), [&](const p::Frame&) { ++n; });
  return {n, dec.stats().malformed};
}

// Index of the one byte in which two raw frames differ.
std::size_t differing_byte(const Bytes& a, const Bytes& b) {
  std::size_t at = a.size();
  for (std::size_t i = 0; i + 4 < a.size(); ++i)
    if (a[i] != b[i]) at = i;
  return at;
}

}  // namespace

TEST(DecoderChecks, EveryStreamStateIsAcceptedAndNoneBeyond) {
  p::Frame f;
  f.type = p::FrameType::status;
  f.status.state = p::StreamState::stopped;
  const Bytes stopped = serialize(f);
  f.status.state = p::StreamState::finished;
  const Bytes finished = serialize(f);
  const std::size_t at = differing_byte(stopped, finished);
  ASSERT_LT(at, finished.size());
  EXPECT_EQ(decode_raw(finished), std::make_pair(1, std::uint64_t{0}));
  Bytes beyond = finished;
  beyond[at] = 3;
  EXPECT_EQ(decode_raw(rechecked(beyond)), std::make_pair(0, std::uint64_t{1}));
}

TEST(DecoderChecks, InfoPayloadMustHoldExactlyItsNames) {
  const std::string names = "a\nb";
  p::Frame f;
  f.type = p::FrameType::info;
  f.info.rows = f.info.cols = 2;
  f.info.sample_rate_hz = 100;
  f.info.n_classes = 2;
  f.info.names_len = static_cast<std::uint16_t>(names.size());
  f.info.class_names = names.data();
  const Bytes raw = serialize(f);
  EXPECT_EQ(decode_raw(raw), std::make_pair(1, std::uint64_t{0}));
  Bytes longer = raw;
  longer.insert(longer.end() - 4, 'c');
  EXPECT_EQ(decode_raw(rechecked(longer)), std::make_pair(0, std::uint64_t{1}));
  Bytes shorter = raw;
  shorter.erase(shorter.end() - 5);
  EXPECT_EQ(decode_raw(rechecked(shorter)), std::make_pair(0, std::uint64_t{1}));
}

TEST(DecoderChecks, APayloadShorterThanItsTypesFixedPartIsMalformed) {
  p::Frame f;
  f.type = p::FrameType::status;
  Bytes raw = serialize(f);
  raw.erase(raw.begin() + 10, raw.begin() + 20);  // 10 bytes of the 64-byte STATUS payload
  EXPECT_EQ(decode_raw(rechecked(raw)), std::make_pair(0, std::uint64_t{1}));
  p::Frame ping;
  ping.type = p::FrameType::pong;
  Bytes short_pong = serialize(ping);
  short_pong.erase(short_pong.begin() + 4);
  EXPECT_EQ(decode_raw(rechecked(short_pong)), std::make_pair(0, std::uint64_t{1}));
}

// A decoded DECISION holds its n_values values and zeros after them, whatever the decoder held
// before (values of an earlier, longer decision are not left behind).
TEST(DecoderChecks, DecisionValuesPastTheirCountAreZero) {
  p::FrameDecoder dec(p::kMaxFrameSize, false);
  for (const std::uint8_t n : {std::uint8_t{3}, std::uint8_t{1}, std::uint8_t{0}}) {
    p::Frame f;
    f.type = p::FrameType::decision;
    f.decision.n_values = n;
    for (std::size_t k = 0; k < n; ++k) f.decision.values[k] = 1.5 + static_cast<double>(k);
    const Bytes e = encode(f);
    ASSERT_EQ(dec.feed(e.data(), e.size()), e.size());
    ASSERT_TRUE(dec.has_frame());
    const auto& d = dec.frame().decision;
    ASSERT_EQ(d.n_values, n);
    for (std::size_t k = 0; k < p::kMaxDecisionValues; ++k)
      EXPECT_EQ(d.values[k], k < n ? 1.5 + static_cast<double>(k) : 0.0) << int(n) << " " << k;
  }
}

// INFO's class names: joined by '\n' when they all fit as they are; otherwise -1 and nothing a
// controller could announce as a shortened list.
TEST(ClassNames, PackedWholeOrRefused) {
  using eskin::protocol::pack_class_names;
  const std::vector<std::string> names = {"brush", "finger", "washer"};
  char out[32];
  ASSERT_EQ(pack_class_names(names.data(), names.size(), out, sizeof out), 19);
  EXPECT_EQ(std::string(out, 19), "brush\nfinger\nwasher");
  EXPECT_EQ(pack_class_names(names.data(), names.size(), out, 19), 19);  // exactly full
  EXPECT_EQ(pack_class_names(names.data(), names.size(), out, 18), -1);  // one byte short
  EXPECT_EQ(pack_class_names(names.data(), 0, nullptr, 0), 0);
  const std::vector<std::string> newline = {"a", "b\nc"};
  EXPECT_EQ(pack_class_names(newline.data(), newline.size(), out, sizeof out), -1);
  const std::vector<std::string> many(256, "x");
  std::vector<char> big(4096);
  EXPECT_EQ(pack_class_names(many.data(), many.size(), big.data(), big.size()), -1);
  EXPECT_EQ(pack_class_names(many.data(), 255, big.data(), big.size()), 255 * 2 - 1);
}

// Every frame type's payload has exactly its size: one byte more or one byte fewer (the CRC
// recomputed) is malformed, for the types with a variable part (DATA, DECISION) and the fixed
// ones (PING, PONG); a type the protocol does not know is malformed too.
TEST(DecoderChecks, APayloadOneByteLongerOrShorterThanItsTypeSaysIsMalformed) {
  const Stream s = make_stream(14, 1);
  std::vector<p::Frame> frames;
  for (const auto t : {p::FrameType::data, p::FrameType::decision})
    frames.push_back(*std::find_if(s.frames.begin(), s.frames.end(),
                                   [t](const p::Frame& f) { return f.type == t; }));
  for (const auto t : {p::FrameType::ping, p::FrameType::pong}) {
    p::Frame f;
    f.type = t;
    f.ping.token = 0x01020304;
    frames.push_back(f);
  }
  for (const p::Frame& f : frames) {
    const Bytes raw = serialize(f);
    ASSERT_EQ(decode_raw(raw), std::make_pair(1, std::uint64_t{0})) << p::frame_type_name(f.type);
    Bytes longer = raw;
    longer.insert(longer.end() - 4, 0x01);
    EXPECT_EQ(decode_raw(rechecked(longer)), std::make_pair(0, std::uint64_t{1}))
        << p::frame_type_name(f.type);
    Bytes shorter = raw;
    shorter.erase(shorter.end() - 5);
    EXPECT_EQ(decode_raw(rechecked(shorter)), std::make_pair(0, std::uint64_t{1}))
        << p::frame_type_name(f.type);
  }
  p::Frame ping, pong;
  ping.type = p::FrameType::ping;
  pong.type = p::FrameType::pong;
  const Bytes a = serialize(ping), b = serialize(pong);
  const std::size_t at = differing_byte(a, b);  // the type byte
  ASSERT_LT(at, a.size());
  Bytes unknown = a;
  unknown[at] = 0x7E;
  EXPECT_EQ(decode_raw(rechecked(unknown)), std::make_pair(0, std::uint64_t{1}));
}

// A DATA frame of one sample of one taxel is read, value and all; one of no sample (the count
// or the grid made 0, the payload shortened to match) is malformed, and the encoder makes none.
TEST(DecoderChecks, ADataFrameOfOneSampleIsReadAndOneOfNoSampleIsMalformed) {
  const std::int16_t value = -7;
  p::Frame f;
  f.type = p::FrameType::data;
  f.data.first_sample = 41;
  f.data.rows = f.data.cols = 1;
  f.data.n_samples = 1;
  f.data.samples = &value;
  const Bytes raw = serialize(f);
  ASSERT_EQ(raw.size(), p::kHeaderSize + p::kDataFixedSize + 2 + p::kCrcSize);
  p::FrameDecoder dec(p::kMaxFrameSize, false);
  const Bytes e = encode(f);
  ASSERT_EQ(dec.feed(e.data(), e.size()), e.size());
  ASSERT_TRUE(dec.has_frame());
  EXPECT_EQ(dec.frame().data.n_samples, 1);
  EXPECT_EQ(dec.frame().data.first_sample, 41U);
  EXPECT_EQ(dec.frame().data.samples[0], value);
  const std::size_t rows_at = p::kHeaderSize + 16, count_at = p::kHeaderSize + 18;
  ASSERT_EQ(raw[rows_at], 1);
  ASSERT_EQ(raw[count_at], 1);
  for (const std::size_t at : {rows_at, count_at}) {
    Bytes none = raw;
    none[at] = 0;
    none.erase(none.end() - 6, none.end() - 4);  // the one sample's two bytes
    EXPECT_EQ(decode_raw(rechecked(none)), std::make_pair(0, std::uint64_t{1})) << at;
  }
  f.data.n_samples = 0;
  Bytes out(p::kMaxFrameSize);
  p::EncodeStatus status = p::EncodeStatus::ok;
  EXPECT_EQ(p::serialize_frame(f, out.data(), out.size(), &status), 0U);
  EXPECT_EQ(status, p::EncodeStatus::invalid_frame);
}

// A DECISION of kMaxDecisionValues values is read whole; one of a value more (its payload
// holding them all) is malformed, and the encoder refuses it.
TEST(DecoderChecks, ADecisionOfTheLargestNumberOfValuesIsReadAndOneMoreIsMalformed) {
  p::Frame f;
  f.type = p::FrameType::decision;
  f.decision.label = 2;
  f.decision.n_values = static_cast<std::uint8_t>(p::kMaxDecisionValues);
  for (std::size_t k = 0; k < p::kMaxDecisionValues; ++k)
    f.decision.values[k] = -1.0 + 0.125 * static_cast<double>(k);
  const Bytes e = encode(f);
  p::FrameDecoder dec(p::kMaxFrameSize, false);
  ASSERT_EQ(dec.feed(e.data(), e.size()), e.size());
  ASSERT_TRUE(dec.has_frame());
  ASSERT_EQ(dec.frame().decision.n_values, p::kMaxDecisionValues);
  EXPECT_EQ(dec.frame().decision.values, f.decision.values);
  const Bytes raw = serialize(f);
  const std::size_t count_at = p::kHeaderSize + p::kDecisionFixedSize - 1;
  ASSERT_EQ(raw[count_at], p::kMaxDecisionValues);
  Bytes more = raw;
  more[count_at] = static_cast<std::uint8_t>(p::kMaxDecisionValues + 1);
  more.insert(more.end() - 4, 8, 0x00);  // a 17th value, 0.0
  EXPECT_EQ(decode_raw(rechecked(more)), std::make_pair(0, std::uint64_t{1}));
  f.decision.n_values = static_cast<std::uint8_t>(p::kMaxDecisionValues + 1);
  Bytes out(p::kMaxFrameSize);
  p::EncodeStatus status = p::EncodeStatus::ok;
  EXPECT_EQ(p::serialize_frame(f, out.data(), out.size(), &status), 0U);
  EXPECT_EQ(status, p::EncodeStatus::invalid_frame);
}

// A COBS block decodes into an output of exactly its decoded size, and is refused by one a
// byte smaller: a run that fills the output to its end, and a run followed by its implied zero.
TEST(Cobs, DecodesIntoExactlyItsSizeAndRefusesOneByteLess) {
  const Bytes run{0x05, 0x11, 0x22, 0x33, 0x44};
  const Bytes zero{0x02, 0x11, 0x01};  // 11 00
  for (const auto& [in, size] : {std::make_pair(run, 4), std::make_pair(zero, 2)}) {
    Bytes out(static_cast<std::size_t>(size) + 1, 0xEE);
    EXPECT_EQ(p::cobs_decode(in.data(), in.size(), out.data(), static_cast<std::size_t>(size)),
              size);
    EXPECT_EQ(out[static_cast<std::size_t>(size)], 0xEE);  // nothing written past it
    EXPECT_EQ(p::cobs_decode(in.data(), in.size(), out.data(), static_cast<std::size_t>(size - 1)),
              -1);
  }
  Bytes out(2);
  ASSERT_EQ(p::cobs_decode(zero.data(), zero.size(), out.data(), out.size()), 2);
  EXPECT_EQ(out, (Bytes{0x11, 0x00}));
}

// A frame of exactly the decoder's maximum size whose COBS block is as long as any of that size
// can be (a run of 254 non-zero bytes forces one more code byte): accepted; the same frame is
// refused by a decoder whose maximum is one byte less.
TEST(DecoderChecks, AFrameOfTheMaximumSizeWithTheLongestBlockIsAccepted) {
  const std::vector<std::int16_t> samples(127, 0x0101);  // 254 non-zero bytes
  p::Frame f;
  f.type = p::FrameType::data;
  f.data.first_sample = 1;
  f.data.rows = f.data.cols = 1;
  f.data.n_samples = 127;
  f.data.samples = samples.data();
  const std::size_t size = serialize(f).size();
  ASSERT_EQ(size, 282U);
  const Bytes block = cobs(serialize(f));
  ASSERT_EQ(block.size(), p::max_encoded_size(size) - 1);
  Bytes wire = block;
  wire.push_back(0);
  for (const std::size_t max : {size, size - 1}) {
    p::FrameDecoder dec(max, false);
    int n = 0;
    dec.feed_all(wire.data(), wire.size(), [&](const p::Frame& g) {
      ++n;
      EXPECT_EQ(g.data.n_samples, 127);
      EXPECT_EQ(g.data.samples[126], 0x0101);
    });
    EXPECT_EQ(n, max == size ? 1 : 0) << max;
  }
}

// The encoder writes into an output of exactly max_encoded_size(frame) bytes, and refuses one
// a byte smaller without writing.
TEST(Encoder, AnOutputOfExactlyTheEncodedBoundIsEnough) {
  p::Frame f;
  f.type = p::FrameType::ping;
  f.ping.token = 0x01020304;
  const std::size_t bound = p::max_encoded_size(serialize(f).size());
  p::FrameEncoder enc;
  Bytes out(bound, 0xAB);
  EXPECT_GT(enc.encode(f, out.data(), bound), 0U);
  EXPECT_EQ(enc.status(), p::EncodeStatus::ok);
  Bytes small(bound, 0xAB);
  EXPECT_EQ(enc.encode(f, small.data(), bound - 1), 0U);
  EXPECT_EQ(enc.status(), p::EncodeStatus::buffer_too_small);
  EXPECT_EQ(small, Bytes(bound, 0xAB));
}

// serialize_frame writes a frame of exactly kMaxFrameSize bytes and refuses one a byte larger
// (an INFO frame whose names fill it); into a buffer of exactly the frame's size, and not one
// a byte smaller.
TEST(Encoder, AFrameOfExactlyTheMaximumSizeFitsAndOneByteMoreIsInvalid) {
  const std::string names(p::kMaxFrameSize - p::kHeaderSize - p::kCrcSize - p::kInfoFixedSize,
                          'n');
  p::Frame f;
  f.type = p::FrameType::info;
  f.info.rows = f.info.cols = 1;
  f.info.class_names = names.data();
  Bytes raw(p::kMaxFrameSize + 1);
  for (const std::size_t len : {names.size(), names.size() + 1}) {
    f.info.names_len = static_cast<std::uint16_t>(len);
    p::EncodeStatus st = p::EncodeStatus::ok;
    const std::size_t n = p::serialize_frame(f, raw.data(), raw.size(), &st);
    if (len == names.size()) {
      EXPECT_EQ(n, p::kMaxFrameSize);
      EXPECT_EQ(st, p::EncodeStatus::ok);
    } else {
      EXPECT_EQ(n, 0U);
      EXPECT_EQ(st, p::EncodeStatus::invalid_frame);
    }
  }
  p::Frame ping;
  ping.type = p::FrameType::ping;
  const std::size_t size = p::kHeaderSize + p::kPingSize + p::kCrcSize;
  p::EncodeStatus st = p::EncodeStatus::invalid_frame;
  EXPECT_EQ(p::serialize_frame(ping, raw.data(), size, &st), size);
  EXPECT_EQ(st, p::EncodeStatus::ok);
  EXPECT_EQ(p::serialize_frame(ping, raw.data(), size - 1, &st), 0U);
  EXPECT_EQ(st, p::EncodeStatus::buffer_too_small);
}

// DATA frames that follow each other are no index reset; one that starts before the end of the
// last is one, and one that starts after it counts the samples between as lost.
TEST(Decoder, ContiguousDataIsNoIndexResetAndAStepBackIsOne) {
  const std::vector<std::int16_t> samples(10, 7);
  Bytes data{0};
  for (const std::uint64_t first : {0U, 10U, 20U, 15U, 25U, 40U}) {
    p::Frame f;
    f.type = p::FrameType::data;
    f.flags = p::flags::kSync;
    f.data.first_sample = first;
    f.data.rows = f.data.cols = 1;
    f.data.n_samples = 10;
    f.data.samples = samples.data();
    const Bytes e = encode(f);
    data.insert(data.end(), e.begin(), e.end());
  }
  p::FrameDecoder dec;
  decode_chunks(dec, data, {});
  EXPECT_EQ(dec.stats().data_frames, 6U);
  EXPECT_EQ(dec.stats().sample_index_resets, 1U);  // 15 after 20..29
  EXPECT_EQ(dec.stats().lost_samples, 5U);         // 35..39
}

// A STATUS payload one byte longer than the fixed STATUS size is malformed, not read.
TEST(DecoderChecks, AStatusOneByteLongerIsMalformed) {
  p::Frame f;
  f.type = p::FrameType::status;
  f.status.state = p::StreamState::streaming;
  const Bytes raw = serialize(f);
  EXPECT_EQ(decode_raw(raw), std::make_pair(1, std::uint64_t{0}));
  Bytes longer = raw;
  longer.insert(longer.end() - 4, 0);
  EXPECT_EQ(decode_raw(rechecked(longer)), std::make_pair(0, std::uint64_t{1}));
}

// One name exactly fills its output (no separator before the first name); a name list given as
// a null pointer, or a null output, is refused for one name as for many.
TEST(ClassNames, OneNameFillsExactlyAndNullPointersAreRefused) {
  using eskin::protocol::pack_class_names;
  const std::vector<std::string> one = {"brush"};
  char out[8];
  EXPECT_EQ(pack_class_names(one.data(), 1, out, 5), 5);
  EXPECT_EQ(std::string(out, 5), "brush");
  EXPECT_EQ(pack_class_names(one.data(), 1, out, 4), -1);
  EXPECT_EQ(pack_class_names(nullptr, 1, out, sizeof out), -1);
  EXPECT_EQ(pack_class_names(one.data(), 1, nullptr, sizeof out), -1);
}

namespace {

// A decoder whose buffers are heap blocks of exactly the sizes FrameDecoderBase documents, so
// that the sanitizer build (make test) sees any read or write past them.
struct HeapDecoder : p::FrameDecoderBase {
  explicit HeapDecoder(std::size_t capacity, std::vector<std::uint8_t> block,
                       std::vector<std::uint8_t> raw, std::vector<std::int16_t> samples)
      : p::FrameDecoderBase(block.data(), raw.data(), samples.data(), capacity, capacity, false),
        block_(std::move(block)), raw_(std::move(raw)), samples_(std::move(samples)) {}
  static HeapDecoder of(std::size_t capacity) {
    return HeapDecoder(capacity, std::vector<std::uint8_t>(p::max_encoded_size(capacity) - 1),
                       std::vector<std::uint8_t>(capacity),
                       std::vector<std::int16_t>(capacity / 2));
  }
  // moved vectors keep their heap blocks, which the base points into
  std::vector<std::uint8_t> block_, raw_;
  std::vector<std::int16_t> samples_;
};

}  // namespace

// A frame shorter than its type's fixed fields is refused before they are read: in a decoder of
// the smallest capacity (header and CRC), a DATA, DECISION, STATUS or INFO frame of no payload
// would be read far past its raw buffer (a heap block of 8 bytes here) otherwise.
TEST(DecoderChecks, AShortFrameIsRefusedBeforeItsFixedFieldsAreRead) {
  for (const auto t : {p::FrameType::data, p::FrameType::decision, p::FrameType::status,
                       p::FrameType::info}) {
    Bytes raw = {static_cast<std::uint8_t>(t), 0, 0, 0, 0, 0, 0, 0};
    raw = rechecked(raw);
    Bytes e = cobs(raw);
    e.push_back(0);
    HeapDecoder dec = HeapDecoder::of(p::kHeaderSize + p::kCrcSize);
    int n = 0;
    dec.feed_all(e.data(), e.size(), [&](const p::Frame&) { ++n; });
    EXPECT_EQ(n, 0) << int(t);
    EXPECT_EQ(dec.stats().malformed, 1U) << int(t);
  }
}
