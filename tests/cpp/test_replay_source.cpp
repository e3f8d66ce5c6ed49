// The simulator's replay reader (firmware_sim/replay_source.cpp): a valid .eskr or .npy image
// opens; a bad rate, volts-per-count, declared size or segment is refused with a message naming
// the field, before any sample is touched.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <string>
#include <vector>

#include "eskin/protocol.hpp"
#include "replay_source.hpp"

namespace {

using Bytes = std::vector<std::uint8_t>;
using eskin::fwsim::ReplaySource;

void put(Bytes& b, std::size_t off, std::uint64_t v, int n) {
  for (int i = 0; i < n; ++i) b[off + static_cast<std::size_t>(i)] = static_cast<std::uint8_t>(v >> (8 * i));
}
void put_f64(Bytes& b, std::size_t off, double v) {
  std::uint64_t u;
  std::memcpy(&u, &v, 8);
  put(b, off, u, 8);
}

struct Eskr {
  std::uint64_t n_samples = 100;
  std::uint64_t rows = 2, cols = 3;
  double rate = 3000.0, vpc = 10.0 / 32768;
  std::vector<std::pair<std::uint64_t, std::uint64_t>> segments = {{10, 50}};
  std::string names = "brush\nfinger";
  std::int64_t sample_bytes = -1;  // bytes of samples written; -1: as n_samples implies

  // The image as eskin.replay.write_replay_file lays it out (docs/wire-protocol.md).
  Bytes bytes() const {
    const std::size_t table = 56 + 48 * segments.size() + names.size();
    const std::size_t offset = (table + 7) / 8 * 8;
    const std::uint64_t data = sample_bytes >= 0 ? static_cast<std::uint64_t>(sample_bytes)
                                                 : n_samples * rows * cols * 2;
    Bytes b(offset + data, 0);
    std::memcpy(b.data(), "ESKREPLY", 8);
    put(b, 8, 1, 4);
    put(b, 12, offset, 4);
    put(b, 16, n_samples, 8);
    put(b, 24, rows, 2);
    put(b, 26, cols, 2);
    put(b, 28, segments.size(), 4);
    put_f64(b, 32, rate);
    put_f64(b, 40, vpc);
    put(b, 48, names.size(), 4);
    for (std::size_t i = 0; i < segments.size(); ++i) {
      put(b, 56 + 48 * i, segments[i].first, 8);
      put(b, 56 + 48 * i + 8, segments[i].second, 8);
      put(b, 56 + 48 * i + 32, 0, 4);
    }
    std::memcpy(b.data() + 56 + 48 * segments.size(), names.data(), names.size());
    for (std::size_t i = offset; i < b.size(); ++i) b[i] = static_cast<std::uint8_t>(i * 7);
    const std::uint8_t zero[4] = {0, 0, 0, 0};
    std::uint32_t c = eskin::protocol::crc32(b.data(), 52);
    c = eskin::protocol::crc32(zero, 4, c);
    c = eskin::protocol::crc32(b.data() + 56, offset - 56, c);
    put(b, 52, c, 4);
    return b;
  }
};

std::string open_error(const Bytes& b, int grid_rows = 0, int grid_cols = 0) {
  ReplaySource src;
  std::string error;
  if (src.open_bytes(b.data(), b.size(), grid_rows, grid_cols, error)) return "";
  return error;
}

Bytes npy_int16(const std::string& shape, std::size_t data_bytes, const std::string& descr = "<i2") {
  std::string text = "{'descr': '" + descr + "', 'fortran_order': False, 'shape': " + shape + ", }";
  text.append((10 + text.size() + 1 + 63) / 64 * 64 - 10 - text.size() - 1, ' ');
  text += '\n';
  Bytes b = {0x93, 'N', 'U', 'M', 'P', 'Y', 1, 0, static_cast<std::uint8_t>(text.size()), 0};
  for (const char c : text) b.push_back(static_cast<std::uint8_t>(c));
  b.resize(b.size() + data_bytes, 1);
  return b;
}

}  // namespace

TEST(ReplaySource, OpensAValidReplayImage) {
  const Eskr e;
  const Bytes b = e.bytes();
  ReplaySource src;
  std::string error;
  ASSERT_TRUE(src.open_bytes(b.data(), b.size(), 0, 0, error)) << error;
  EXPECT_EQ(src.n_samples(), 100u);
  EXPECT_EQ(src.rows(), 2);
  EXPECT_EQ(src.cols(), 3);
  EXPECT_EQ(src.sample_rate_hz(), 3000.0);
  EXPECT_EQ(src.class_names(), (std::vector<std::string>{"brush", "finger"}));
  ASSERT_EQ(src.segments().size(), 1u);
  EXPECT_EQ(src.segments()[0].length, 50u);
  std::int16_t last;
  std::memcpy(&last, b.data() + b.size() - 2, 2);
  EXPECT_EQ(src.sample(99)[5], last);
}

TEST(ReplaySource, RateAndVoltsPerCountMustBeFinitePositive) {
  const double inf = std::numeric_limits<double>::infinity(), nan = std::nan("");
  for (const double rate : {inf, nan, 0.0, -3000.0, 2e7, 0.05, 1.5e6}) {
    Eskr e;
    e.rate = rate;
    EXPECT_NE(open_error(e.bytes()).find("sample_rate_hz = "), std::string::npos) << rate;
    EXPECT_NE(open_error(e.bytes()).find("not a rate of 0.1 to 1e+06 Hz"), std::string::npos) << rate;
  }
  for (const double vpc : {nan, inf, 0.0, -1.0}) {
    Eskr e;
    e.vpc = vpc;
    EXPECT_NE(open_error(e.bytes()).find("volts_per_count = "), std::string::npos) << vpc;
  }
}

// n_samples * rows * cols * 2 can wrap around 2^64 and match the file size: the count is
// compared with the bytes present by division first.
TEST(ReplaySource, DeclaredSizesAreCheckedAgainstTheFile) {
  Eskr e;
  e.rows = e.cols = 1;
  e.n_samples = (std::uint64_t{1} << 63) + 50;  // 2 * n wraps to 100 bytes
  e.sample_bytes = 100;
  std::string m = open_error(e.bytes());
  EXPECT_NE(m.find("size = 220 bytes: n_samples = 9223372036854775858 declares more than 2^64"),
            std::string::npos)
      << m;
  e = Eskr{};
  e.sample_bytes = 100 * 2 * 3 * 2 - 2;  // one int16 short
  EXPECT_NE(open_error(e.bytes()).find("n_samples = 100 declares"), std::string::npos);
  e = Eskr{};
  e.segments = {{90, 11}};  // ends at 101 > 100
  m = open_error(e.bytes());
  EXPECT_NE(m.find("segment 0: start 90 + length 11 runs past the end of the stream (100 samples)"),
            std::string::npos) << m;
  e.segments = {{0, std::numeric_limits<std::uint64_t>::max()}};
  EXPECT_NE(open_error(e.bytes()).find("segment 0"), std::string::npos);
  Bytes b = Eskr{}.bytes();
  put(b, 28, 0xFFFFFFFFu, 4);  // n_segments: the table would run far past the file
  EXPECT_NE(open_error(b).find("data_offset = "), std::string::npos);
  EXPECT_NE(open_error(Bytes(b.begin(), b.begin() + 30)).find("magic: not an eskin replay file"),
            std::string::npos);
}

TEST(ReplaySource, NpyThroughTheCoreReader) {
  ReplaySource src;
  std::string error;
  const Bytes ok = npy_int16("(50, 2, 3)", 50 * 6 * 2);
  ASSERT_TRUE(src.open_bytes(ok.data(), ok.size(), 0, 0, error)) << error;
  EXPECT_EQ(src.n_samples(), 50u);
  EXPECT_EQ(src.cols(), 3);
  const Bytes flat = npy_int16("(50, 6)", 50 * 6 * 2);
  ASSERT_TRUE(src.open_bytes(flat.data(), flat.size(), 2, 3, error)) << error;
  EXPECT_EQ(src.rows(), 2);
  EXPECT_NE(open_error(flat, 3, 3).find("does not match --grid 3x3"), std::string::npos);
  EXPECT_NE(open_error(npy_int16("(50, 2, 3)", 50 * 6 * 4, "<f4")).find("must hold little-endian int16"),
            std::string::npos);
  EXPECT_NE(open_error(npy_int16("(50, 2, 3)", 50 * 6 * 2 - 1)).find(".npy data truncated"), std::string::npos);
  const std::string m = open_error(npy_int16("(4611686018427387904, 2, 3)", 64));
  EXPECT_NE(m.find("declares more than the limit"), std::string::npos) << m;
  EXPECT_NE(open_error(npy_int16("(50, 0, 3)", 0)).find("bad grid"), std::string::npos);
  EXPECT_NE(open_error(npy_int16("(0, 2, 3)", 0)).find("no samples"), std::string::npos);
  EXPECT_NE(open_error(Bytes{'x', 'y'}).find("not an eskin replay file"), std::string::npos);
}
