// The .eskin loader (every bad-file case gives its error, fuzzed files never crash or hang).
#include <gtest/gtest.h>

#include <cstdint>
#include <cstdio>
#include <fstream>
#include <iterator>
#include <random>
#include <string>
#include <vector>

#include "eskin/model.hpp"

namespace {

using eskin::Model;
using eskin::ModelError;
using eskin::ModelFormatError;
using Bytes = std::vector<std::uint8_t>;

Bytes read_file(const std::string& path) {
  std::ifstream f(path, std::ios::binary);
  EXPECT_TRUE(f.good()) << path;
  return Bytes(std::istreambuf_iterator<char>(f), std::istreambuf_iterator<char>());
}

Bytes fixture(const char* dtype) {
  return read_file(std::string(ESKIN_TEST_DATA_DIR) + "/model_small_" + dtype + ".eskin");
}

void put_u32(Bytes& b, std::size_t off, std::uint32_t v) {
  for (int i = 0; i < 4; ++i) b[off + static_cast<std::size_t>(i)] = static_cast<std::uint8_t>(v >> (8 * i));
}
std::uint32_t get_u32(const Bytes& b, std::size_t off) {
  std::uint32_t v = 0;
  for (int i = 3; i >= 0; --i) v = (v << 8) | b[off + static_cast<std::size_t>(i)];
  return v;
}
// Recompute the CRC-32 trailer after an edit, so that the structural checks are reached.
void fix_crc(Bytes& b) {
  if (b.size() < 4) return;
  put_u32(b, b.size() - 4, eskin::model_format::crc32(b.data(), b.size() - 4));
}

// Offset of a section's payload, by tag.
std::size_t section_offset(const Bytes& b, const char* tag) {
  std::size_t pos = 32;
  while (pos + 8 <= b.size() - 4) {
    const std::uint32_t bytes = get_u32(b, pos + 4);
    if (std::equal(tag, tag + 4, b.begin() + static_cast<std::ptrdiff_t>(pos))) return pos + 8;
    pos += 8 + (bytes + 7) / 8 * 8;
  }
  ADD_FAILURE() << "section " << tag << " not found";
  return 0;
}

ModelError load_error(const Bytes& b) {
  try {
    Model::from_bytes(b.data(), b.size());
  } catch (const ModelFormatError& e) {
    return e.code();
  }
  return static_cast<ModelError>(0);
}

std::string load_message(const Bytes& b) {
  try {
    Model::from_bytes(b.data(), b.size());
  } catch (const ModelFormatError& e) {
    return e.what();
  }
  return "";
}

}  // namespace

TEST(ModelCrc, MatchesZlib) {
  const std::string s = "123456789";
  EXPECT_EQ(eskin::model_format::crc32(reinterpret_cast<const std::uint8_t*>(s.data()), s.size()),
            0xCBF43926u);
  EXPECT_EQ(eskin::model_format::crc32(nullptr, 0), 0u);
}

TEST(ModelLoad, ReadsTheFixtureInBothPrecisions) {
  for (const char* dtype : {"float32", "float64"}) {
    const Bytes b = fixture(dtype);
    const Model m = Model::from_bytes(b.data(), b.size());
    EXPECT_EQ(m.is_float64(), std::string(dtype) == "float64");
    EXPECT_EQ(m.rows(), 4);
    EXPECT_EQ(m.cols(), 4);
    EXPECT_EQ(m.D(), 8);
    EXPECT_EQ(m.rule(), eskin::DecisionRule::kOneVsAll);
    ASSERT_EQ(m.class_names().size(), 3u);
    EXPECT_EQ(m.class_names()[1], "finger");
    ASSERT_EQ(m.machines().size(), 3u);
    EXPECT_EQ(m.machines()[2].positive, 2);
    EXPECT_EQ(m.machines()[2].negative, -1);
    EXPECT_EQ(m.machines()[0].alpha[2], 4);
    EXPECT_DOUBLE_EQ(m.machines()[0].sigma[1], 0.5);
    EXPECT_LE(m.n_support(), 9);
    EXPECT_EQ(m.basis_rows(0), 32);
    EXPECT_EQ(m.basis_rows(2), 16);
    EXPECT_EQ(m.file_bytes(), b.size());
  }
}

TEST(ModelLoad, FromPathAndMissingPath) {
  const Bytes b = fixture("float32");
  const std::string path = ::testing::TempDir() + "/eskin_model_test.eskin";
  {
    std::ofstream f(path, std::ios::binary);
    f.write(reinterpret_cast<const char*>(b.data()), static_cast<std::streamsize>(b.size()));
  }
  EXPECT_EQ(Model::load(path).n_support(), Model::from_bytes(b.data(), b.size()).n_support());
  std::remove(path.c_str());
  try {
    Model::load(path);
    FAIL() << "no error for a missing file";
  } catch (const ModelFormatError& e) {
    EXPECT_EQ(e.code(), ModelError::kIo);
    EXPECT_NE(std::string(e.what()).find(path), std::string::npos);
  }
}

TEST(ModelLoad, ForeignFile) {
  const std::string text = "PK\x03\x04 this is a zip file, not a model";
  const Bytes b(text.begin(), text.end());
  EXPECT_EQ(load_error(b), ModelError::kNotAModel);
  EXPECT_NE(load_message(b).find("not an eskin model"), std::string::npos);
  EXPECT_EQ(load_error(Bytes{}), ModelError::kNotAModel);
}

TEST(ModelLoad, WrongVersion) {
  Bytes b = fixture("float32");
  b[8] = 2;  // version 2, CRC left stale: the version is reported, not the checksum
  EXPECT_EQ(load_error(b), ModelError::kVersion);
  EXPECT_NE(load_message(b).find("version 2"), std::string::npos);
}

TEST(ModelLoad, BadChecksum) {
  Bytes b = fixture("float32");
  b[b.size() / 2] ^= 0x10;
  EXPECT_EQ(load_error(b), ModelError::kChecksum);
  EXPECT_NE(load_message(b).find("checksum"), std::string::npos);
}

TEST(ModelLoad, Truncated) {
  const Bytes b = fixture("float32");
  EXPECT_EQ(load_error(Bytes(b.begin(), b.begin() + 20)), ModelError::kTruncated);
  EXPECT_EQ(load_error(Bytes(b.begin(), b.end() - 1)), ModelError::kTruncated);
  Bytes longer = b;
  longer.push_back(0);
  EXPECT_EQ(load_error(longer), ModelError::kLayout);
}

TEST(ModelLoad, InconsistentSizes) {
  const Bytes good = fixture("float32");
  {  // D in PREP no longer matches the tensor dims of SVBS
    Bytes b = good;
    put_u32(b, section_offset(b, "PREP") + 8, 9);
    fix_crc(b);
    EXPECT_EQ(load_error(b), ModelError::kValue);
    EXPECT_NE(load_message(b).find("differ from the preprocessing"), std::string::npos);
  }
  {  // more support vectors than the section holds
    Bytes b = good;
    put_u32(b, section_offset(b, "SVBS") + 4, 1000);
    fix_crc(b);
    EXPECT_EQ(load_error(b), ModelError::kLayout);
    EXPECT_NE(load_message(b).find("n_sv=1000"), std::string::npos);
  }
  {  // a section length that runs past the end
    Bytes b = good;
    put_u32(b, section_offset(b, "CLAS") - 4, 1u << 30);
    fix_crc(b);
    EXPECT_EQ(load_error(b), ModelError::kLayout);
  }
  {  // alpha of a machine above the stored basis width
    Bytes b = good;
    put_u32(b, section_offset(b, "MACH") + 8 + 24, 7);
    fix_crc(b);
    EXPECT_EQ(load_error(b), ModelError::kValue);
    EXPECT_NE(load_message(b).find("alpha[0]=7"), std::string::npos);
  }
  {  // unknown class rule
    Bytes b = good;
    put_u32(b, section_offset(b, "CLAS") + 4, 5);
    fix_crc(b);
    EXPECT_NE(load_message(b).find("rule=5"), std::string::npos);
  }
  {  // sections out of order: rename PREP
    Bytes b = good;
    b[section_offset(b, "PREP") - 8] = 'X';
    fix_crc(b);
    EXPECT_EQ(load_error(b), ModelError::kLayout);
    EXPECT_NE(load_message(b).find("unexpected section 'XREP'"), std::string::npos);
  }
}

// Thousands of truncated and bit-flipped files: each either loads or throws ModelFormatError;
// nothing else (no crash, no other exception, no hang). With stale CRCs the checksum catches the
// flips; with recomputed CRCs the structural validation is exercised.
TEST(ModelFuzz, TruncatedAndBitFlippedFiles) {
  std::mt19937 rng(12345);
  int loaded = 0, rejected = 0;
  for (const char* dtype : {"float32", "float64"}) {
    const Bytes good = fixture(dtype);
    for (std::size_t n = 0; n < good.size(); n += (n < 400 ? 1 : 37)) {
      Bytes b(good.begin(), good.begin() + static_cast<std::ptrdiff_t>(n));
      EXPECT_NE(load_error(b), static_cast<ModelError>(0)) << "truncated to " << n;
      fix_crc(b);
      try {
        Model::from_bytes(b.data(), b.size());
        ++loaded;
      } catch (const ModelFormatError&) {
        ++rejected;
      }
    }
    for (int trial = 0; trial < 3000; ++trial) {
      Bytes b = good;
      const int flips = 1 + static_cast<int>(rng() % 4);
      for (int f = 0; f < flips; ++f) {
        // bias the flips towards the header and section headers, where the sizes live
        const std::size_t limit = (trial % 2) ? b.size() : std::min<std::size_t>(b.size(), 256);
        b[rng() % limit] ^= static_cast<std::uint8_t>(1u << (rng() % 8));
      }
      if (b == good) continue;
      if (trial % 3 == 0) {
        EXPECT_NE(load_error(b), static_cast<ModelError>(0));
        continue;
      }
      fix_crc(b);
      try {
        const Model m = Model::from_bytes(b.data(), b.size());
        EXPECT_GE(m.n_support(), 1);
        ++loaded;
      } catch (const ModelFormatError&) {
        ++rejected;
      }
    }
  }
  EXPECT_GT(rejected, 1000);
  RecordProperty("loaded", loaded);
}
