// The core's reader of the replay format (eskin/replay_format.hpp): a file written by the Python
// writer (tests/data/replay_small.eskr, tests/data/make_replay_fixture.py) is read field by
// field; each rule of the Python reader refuses its own corruption with its own status, naming
// the value; the buffer's size is exact for a file and an upper bound for a board's memory.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <cstring>
#include <fstream>
#include <iterator>
#include <limits>
#include <string>
#include <vector>

#include "eskin/crc32.hpp"
#include "eskin/replay_format.hpp"

namespace {

namespace rp = eskin::replay;
using Bytes = std::vector<std::uint8_t>;

Bytes fixture() {
  std::ifstream f(std::string(ESKIN_TEST_DATA_DIR) + "/replay_small.eskr", std::ios::binary);
  EXPECT_TRUE(f.good());
  return Bytes((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
}

std::uint32_t rd32(const Bytes& b, std::size_t off) {
  std::uint32_t v = 0;
  for (int i = 0; i < 4; ++i) v |= static_cast<std::uint32_t>(b[off + static_cast<std::size_t>(i)]) << (8 * i);
  return v;
}
void put(Bytes& b, std::size_t off, std::uint64_t v, int n) {
  for (int i = 0; i < n; ++i) b[off + static_cast<std::size_t>(i)] = static_cast<std::uint8_t>(v >> (8 * i));
}
void put_f64(Bytes& b, std::size_t off, double v) {
  std::uint64_t u;
  std::memcpy(&u, &v, 8);
  put(b, off, u, 8);
}
/// The header's CRC recomputed, so that only the edited field is wrong.
void fix_crc(Bytes& b) {
  const std::uint32_t off = rd32(b, 12);
  put(b, 52, 0, 4);
  put(b, 52, eskin::crc32(b.data(), off), 4);
}

struct Result {
  rp::ReplayStatus status;
  rp::ReplayError error;
  std::string message;
};
Result check(const Bytes& b, rp::SizeRule rule = rp::SizeRule::exact) {
  Result r;
  rp::ReplayHeader h;
  r.status = rp::check_replay(b.data(), b.size(), rule, &h, &r.error);
  char line[256];
  r.message = rp::format_error(r.error, line, sizeof line);
  return r;
}

constexpr std::size_t kSeg1 = 56 + 48;  // the second segment

}  // namespace

TEST(ReplayFormat, ReadsTheFileThePythonWriterWrote) {
  const Bytes b = fixture();
  rp::ReplayHeader h;
  rp::ReplayError e;
  ASSERT_EQ(rp::check_replay(b.data(), b.size(), rp::SizeRule::exact, &h, &e), rp::ReplayStatus::ok);
  EXPECT_EQ(h.version, 1u);
  EXPECT_EQ(h.n_samples, 190u);
  EXPECT_EQ(h.rows, 2);
  EXPECT_EQ(h.cols, 3);
  EXPECT_EQ(h.sample_rate_hz, 3000.0);
  EXPECT_EQ(h.volts_per_count, 2.5e-4);
  EXPECT_EQ(h.n_segments, 2u);
  EXPECT_EQ(h.n_class_names, 2u);
  EXPECT_EQ(std::string(h.class_names, h.names_len), "brush\nfinger");
  const rp::ReplaySegment s0 = rp::segment(h, 0), s1 = rp::segment(h, 1);
  EXPECT_EQ(s0.start, 30u);
  EXPECT_EQ(s0.length, 40u);
  EXPECT_EQ(s0.contact_onset, 1);
  EXPECT_EQ(s0.contact_offset, 30);
  EXPECT_EQ(s0.label, 0);
  EXPECT_EQ(s1.start, 100u);
  EXPECT_EQ(s1.length, 60u);
  EXPECT_EQ(s1.label, 1);
  EXPECT_EQ(s1.recording, 1u);
  EXPECT_EQ(reinterpret_cast<const std::uint8_t*>(h.samples), b.data() + h.data_offset);
  EXPECT_EQ(h.data_offset + 190u * 6 * 2, b.size());
  // a board's memory holding the file (and more after it)
  Bytes bigger = b;
  bigger.resize(b.size() + 4096, 0xAB);
  EXPECT_EQ(check(bigger, rp::SizeRule::at_most).status, rp::ReplayStatus::ok);
  EXPECT_EQ(check(bigger).status, rp::ReplayStatus::bad_size);
}

TEST(ReplayFormat, EachRuleRefusesItsCorruptionNamingTheValue) {
  const Bytes good = fixture();
  struct Case {
    const char* what;
    void (*edit)(Bytes&);
    rp::ReplayStatus status;
    const char* message;
  };
  const Case cases[] = {
      {"magic", [](Bytes& b) { b[0] = 'X'; }, rp::ReplayStatus::bad_magic, "magic: "},
      {"short", [](Bytes& b) { b.resize(40); }, rp::ReplayStatus::bad_magic, "magic: "},
      {"version", [](Bytes& b) { put(b, 8, 2, 4); fix_crc(b); }, rp::ReplayStatus::bad_version,
       "version = 2: this reader reads replay version 1"},
      {"data_offset odd", [](Bytes& b) { put(b, 12, rd32(b, 12) + 4, 4); },
       rp::ReplayStatus::bad_data_offset, "data_offset = "},
      {"n_segments huge", [](Bytes& b) { put(b, 28, 0xFFFFFFFFu, 4); },
       rp::ReplayStatus::bad_data_offset, "data_offset = "},
      {"crc", [](Bytes& b) { b[60] ^= 1; }, rp::ReplayStatus::bad_crc, "crc = 0x"},
      {"grid", [](Bytes& b) { put(b, 24, 4096, 2); fix_crc(b); }, rp::ReplayStatus::bad_grid,
       "grid = 4096x3: not within 1..255 x 1..255"},
      {"grid 0", [](Bytes& b) { put(b, 26, 0, 2); fix_crc(b); }, rp::ReplayStatus::bad_grid,
       "grid = 2x0"},
      {"rate 0.05", [](Bytes& b) { put_f64(b, 32, 0.05); fix_crc(b); },
       rp::ReplayStatus::bad_sample_rate, "sample_rate_hz = 0.050000000000000003: not a rate of "
       "0.1 to 1e+06 Hz"},
      {"rate 1e300", [](Bytes& b) { put_f64(b, 32, 1e300); fix_crc(b); },
       rp::ReplayStatus::bad_sample_rate, "sample_rate_hz = 1.0000000000000001e+300"},
      {"rate nan", [](Bytes& b) { put_f64(b, 32, std::nan("")); fix_crc(b); },
       rp::ReplayStatus::bad_sample_rate, "sample_rate_hz = nan"},
      {"vpc 0", [](Bytes& b) { put_f64(b, 40, 0.0); fix_crc(b); },
       rp::ReplayStatus::bad_volts_per_count, "volts_per_count = 0: not a finite number > 0"},
      {"vpc inf", [](Bytes& b) { put_f64(b, 40, std::numeric_limits<double>::infinity()); fix_crc(b); },
       rp::ReplayStatus::bad_volts_per_count, "volts_per_count = inf"},
      {"one byte short", [](Bytes& b) { b.pop_back(); }, rp::ReplayStatus::bad_size,
       "size = 2447 bytes: n_samples = 190 declares 2448 bytes"},
      {"n_samples wraps", [](Bytes& b) { put(b, 16, (std::uint64_t{1} << 62) + 190, 8); fix_crc(b); },
       rp::ReplayStatus::bad_size,
       "size = 2448 bytes: n_samples = 4611686018427388094 declares more than 2^64 bytes"},
      {"names utf-8", [](Bytes& b) { b[56 + 2 * 48 + 1] = 0xFF; fix_crc(b); },
       rp::ReplayStatus::bad_class_names, "class_names: not valid UTF-8 at byte 1"},
      {"names surrogate", [](Bytes& b) { b[56 + 96] = 0xED; b[56 + 97] = 0xA0; b[56 + 98] = 0x80; fix_crc(b); },
       rp::ReplayStatus::bad_class_names, "class_names: not valid UTF-8 at byte 0"},
      {"empty segment", [](Bytes& b) { put(b, kSeg1 + 8, 0, 8); fix_crc(b); },
       rp::ReplayStatus::bad_segment, "segment 1: length = 0 (1 bad segments)"},
      {"segment past the end", [](Bytes& b) { put(b, kSeg1, std::uint64_t{1} << 63, 8); fix_crc(b); },
       rp::ReplayStatus::bad_segment,
       "segment 1: start 9223372036854775808 + length 60 runs past the end of the stream (190 samples)"},
      {"huge length", [](Bytes& b) { put(b, kSeg1 + 8, ~std::uint64_t{0}, 8); fix_crc(b); },
       rp::ReplayStatus::bad_segment, "segment 1: start 100 + length 18446744073709551615 runs past"},
      {"label 7", [](Bytes& b) { put(b, kSeg1 + 32, 7, 4); fix_crc(b); },
       rp::ReplayStatus::bad_segment, "segment 1: label = 7: neither -1 nor a class index (< 2)"},
      {"label -2", [](Bytes& b) { put(b, kSeg1 + 32, 0xFFFFFFFEu, 4); fix_crc(b); },
       rp::ReplayStatus::bad_segment, "segment 1: label = -2"},
      {"contact past length", [](Bytes& b) { put(b, kSeg1 + 24, 61, 8); fix_crc(b); },
       rp::ReplayStatus::bad_segment, "segment 1: contact interval = [0, 61): neither -1/-1 nor "
       "within [0, length 60]"},
      {"contact reversed", [](Bytes& b) { put(b, 56 + 16, 20, 8); put(b, 56 + 24, 10, 8); fix_crc(b); },
       rp::ReplayStatus::bad_segment, "segment 0: contact interval = [20, 10)"},
  };
  for (const Case& c : cases) {
    Bytes b = good;
    c.edit(b);
    const Result r = check(b);
    EXPECT_EQ(r.status, c.status) << c.what << ": " << r.message;
    EXPECT_EQ(r.message.rfind(c.message, 0), 0u) << c.what << ": " << r.message;
    EXPECT_EQ(r.message.find('\n'), std::string::npos);
    EXPECT_EQ(std::string(rp::field_name(r.status)).empty(), false);
  }
  // a contact of -1/-1 is "unknown", not a problem
  Bytes b = good;
  put(b, kSeg1 + 16, ~std::uint64_t{0}, 8);
  put(b, kSeg1 + 24, ~std::uint64_t{0}, 8);
  fix_crc(b);
  EXPECT_EQ(check(b).status, rp::ReplayStatus::ok);
  // the rates at both ends of the range are accepted
  for (const double rate : {0.1, 1e6}) {
    Bytes r = good;
    put_f64(r, 32, rate);
    fix_crc(r);
    EXPECT_EQ(check(r).status, rp::ReplayStatus::ok) << rate;
  }
}
