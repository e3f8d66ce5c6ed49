// The core's one CRC-32 (eskin/crc32.hpp): zlib's check values, continuation, and the wire
// protocol and the model format using that same function.
#include <gtest/gtest.h>

#include <cstring>
#include <string>

#include "eskin/crc32.hpp"
#include "eskin/model.hpp"
#include "eskin/protocol.hpp"

namespace {

std::uint32_t crc_of(const std::string& s, std::uint32_t crc = 0) {
  return eskin::crc32(reinterpret_cast<const std::uint8_t*>(s.data()), s.size(), crc);
}

TEST(Crc32, MatchesZlibCheckValues) {
  EXPECT_EQ(crc_of("123456789"), 0xCBF43926u);  // the ISO-HDLC check value
  EXPECT_EQ(crc_of("The quick brown fox jumps over the lazy dog"), 0x414FA339u);
  EXPECT_EQ(crc_of(std::string(1, '\0')), 0xD202EF8Du);
  EXPECT_EQ(crc_of(std::string(4, '\xFF')), 0xFFFFFFFFu);
  EXPECT_EQ(eskin::crc32(nullptr, 0), 0u);
}

TEST(Crc32, ContinuesARunningChecksum) {
  const std::string a = "tactile ", b = "skin";
  EXPECT_EQ(crc_of(b, crc_of(a)), crc_of(a + b));
  EXPECT_EQ(crc_of("", crc_of(a)), crc_of(a));
}

TEST(Crc32, OneFunctionForFramesAndModelFiles) {
  using Fn = std::uint32_t (*)(const std::uint8_t*, std::size_t, std::uint32_t) noexcept;
  const Fn core = &eskin::crc32, wire = &eskin::protocol::crc32,
           model = &eskin::model_format::crc32;
  EXPECT_EQ(wire, core);
  EXPECT_EQ(model, core);
}

}  // namespace
