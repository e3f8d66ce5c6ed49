// The .npy header reader: headers as NumPy writes them (versions 1, 2, 3), and every bad header
// or declared size gives an NpyError naming the field, before any data is touched.
#include <gtest/gtest.h>

#include <cstdint>
#include <string>
#include <vector>

#include "eskin/npy.hpp"

namespace {

using Bytes = std::vector<std::uint8_t>;
using eskin::NpyDtype;
using eskin::NpyError;

// A .npy image as numpy.lib.format writes it: the dictionary padded with spaces and ended by
// '\n' so that the data starts on a multiple of 64 bytes, then `data_bytes` zero bytes.
Bytes npy(const std::string& dict, int major = 1, std::size_t data_bytes = 0) {
  const std::size_t pre = major == 1 ? 10 : 12;
  std::string text = dict;
  const std::size_t total = (pre + text.size() + 1 + 63) / 64 * 64;
  text.append(total - pre - text.size() - 1, ' ');
  text += '\n';
  Bytes b = {0x93, 'N', 'U', 'M', 'P', 'Y', static_cast<std::uint8_t>(major), 0};
  const std::size_t n = text.size();
  b.push_back(static_cast<std::uint8_t>(n & 0xFF));
  b.push_back(static_cast<std::uint8_t>((n >> 8) & 0xFF));
  if (major != 1) {
    b.push_back(static_cast<std::uint8_t>((n >> 16) & 0xFF));
    b.push_back(static_cast<std::uint8_t>((n >> 24) & 0xFF));
  }
  b.insert(b.end(), text.begin(), text.end());
  b.resize(b.size() + data_bytes, 0);
  return b;
}

std::string dict(const std::string& descr, const std::string& shape, const std::string& order = "False") {
  return "{'descr': '" + descr + "', 'fortran_order': " + order + ", 'shape': " + shape + ", }";
}

std::string error_of(const Bytes& b) {
  try {
    eskin::parse_npy_header(b.data(), b.size(), "x.npy");
  } catch (const NpyError& e) {
    return e.what();
  }
  return "";
}

}  // namespace

TEST(Npy, ReadsHeadersAsNumpyWritesThem) {
  for (const int major : {1, 2, 3}) {
    const Bytes b = npy(dict("<i2", "(3, 4, 4, 900)"), major, 3 * 4 * 4 * 900 * 2);
    ASSERT_TRUE(eskin::is_npy(b.data(), b.size()));
    const eskin::NpyHeader h = eskin::parse_npy_header(b.data(), b.size(), "x.npy");
    EXPECT_EQ(h.major_version, major);
    EXPECT_EQ(h.dtype, NpyDtype::kInt16);
    EXPECT_EQ(h.shape, (std::vector<std::uint64_t>{3, 4, 4, 900}));
    EXPECT_EQ(h.count, 3u * 4 * 4 * 900);
    EXPECT_EQ(h.data_bytes, h.count * 2);
    EXPECT_EQ(h.data_offset, 128u);  // NumPy aligns the data to 64 bytes
    EXPECT_EQ(h.data_offset, eskin::npy_data_offset(b.data(), 12, "x.npy"));
    EXPECT_NO_THROW(eskin::check_npy_file_size(h, b.size(), "x.npy"));
  }
  const Bytes f = npy(dict("<f8", "(5,)"));
  const auto h = eskin::parse_npy_header(f.data(), f.size(), "x.npy");
  EXPECT_EQ(h.dtype, NpyDtype::kFloat64);
  EXPECT_EQ(h.shape, (std::vector<std::uint64_t>{5}));
  EXPECT_EQ(eskin::npy_shape_string(h.shape), "(5,)");
  // a scalar, an empty array, double quotes, Python 2's long suffix, keys in another order
  const Bytes s = npy(dict("<f4", "()"));
  EXPECT_EQ(eskin::parse_npy_header(s.data(), s.size(), "x").count, 1u);
  const Bytes e = npy(dict("<f4", "(0, 7)"));
  EXPECT_EQ(eskin::parse_npy_header(e.data(), e.size(), "x").data_bytes, 0u);
  const Bytes q = npy("{\"shape\": (2L, 3L), \"fortran_order\": False, \"descr\": \"<i2\"}");
  const auto hq = eskin::parse_npy_header(q.data(), q.size(), "x");
  EXPECT_EQ(eskin::npy_shape_string(hq.shape), "(2, 3)");
  EXPECT_EQ(hq.data_bytes, 12u);
}

TEST(Npy, BadPreambleNamesTheProblem) {
  const Bytes good = npy(dict("<i2", "(3,)"));
  EXPECT_NE(error_of(Bytes{'P', 'K', 3, 4}).find("x.npy: not a .npy file"), std::string::npos);
  EXPECT_NE(error_of(Bytes(good.begin(), good.begin() + 8)).find("truncated .npy header"), std::string::npos);
  ASSERT_EQ(good.size(), 128u);  // the dictionary is longer than 64 - 10 bytes
  EXPECT_NE(error_of(Bytes(good.begin(), good.begin() + 40)).find("40 bytes, the header needs 128"),
            std::string::npos);
  Bytes v = good;
  v[6] = 4;
  EXPECT_NE(error_of(v).find(".npy format version 4.0 is not supported"), std::string::npos);
  Bytes big = npy(dict("<i2", "(3,)"), 2);
  big[10] = 0x10;  // header_len = 2^20 + 128 - 12
  EXPECT_NE(error_of(big).find("header_len = 1048692 is larger than the limit 65536"), std::string::npos)
      << error_of(big);
}

TEST(Npy, BadDictionaryNamesTheField) {
  const std::vector<std::pair<std::string, std::string>> cases = {
      {dict(">i2", "(3,)"), "dtype '>i2' not supported"},
      {dict("<i4", "(3,)"), "dtype '<i4' not supported"},
      {dict("<i2", "(3,)", "True"), "must be in C order (fortran_order is True)"},
      {dict("<i2", "(3,)", "0"), "'fortran_order' must be True or False"},
      {"{'descr': '<i2', 'fortran_order': False}", "has no 'shape'"},
      {"{'fortran_order': False, 'shape': (3,)}", "has no 'descr'"},
      {"{'descr': '<i2', 'shape': (3,)}", "has no 'fortran_order'"},
      {"{'descr': '<i2', 'descr': '<i2', 'fortran_order': False, 'shape': (3,)}", "'descr' repeated"},
      {"{'descr': '<i2', 'fortran_order': False, 'shape': (3,), 'x': 1}", "unknown key 'x'"},
      {dict("<i2", "(-1, 3)"), "'shape' entry 0 is not a non-negative integer"},
      {dict("<i2", "(3, 1.5)"), "expected ',' or ')'"},
      {dict("<i2", "[3]"), "expected a tuple as 'shape'"},
      {dict("<i2", "(99999999999999999999,)"), "'shape' entry 0 = 99999999999999999999... is too large"},
      {dict("<i2", "(1, 2, 3, 4, 5, 6, 7, 8, 9)"), "more than 8 dimensions"},
      {dict("<i2", "(3,)") + " x", "unexpected text after the dictionary"},
      {"['descr']", "expected a dictionary"},
      {"{'descr: '<i2'", "expected ':' after key 'descr: '"},
      {"{'descr': '<i\\x32', 'fortran_order': False, 'shape': (3,)}", "escapes"},
  };
  for (const auto& [text, message] : cases) {
    const std::string m = error_of(npy(text));
    EXPECT_NE(m.find(message), std::string::npos) << text << " -> " << m;
    EXPECT_EQ(m.rfind("x.npy: ", 0), 0u) << m;
  }
}

// Declared sizes are checked against the limit before the caller allocates, and against the
// file's size: a 24-byte claim of 2^61 bytes never reaches an allocation.
TEST(Npy, DeclaredSizesAreBounded) {
  std::string m = error_of(npy(dict("<i2", "(1048576, 1048576, 1048576)")));
  EXPECT_NE(m.find("shape (1048576, 1048576, 1048576) of <i2 declares more than the limit of "
                   "1099511627776 bytes"),
            std::string::npos)
      << m;
  m = error_of(npy(dict("<f8", "(137438953473,)")));  // 2^37 + 1 doubles: 8 bytes over 1 TiB
  EXPECT_NE(m.find("declares more than the limit"), std::string::npos) << m;
  const Bytes ok = npy(dict("<f8", "(137438953472,)"));  // exactly 1 TiB: only the file is short
  const auto h = eskin::parse_npy_header(ok.data(), ok.size(), "x.npy");
  EXPECT_EQ(h.data_bytes, eskin::kNpyMaxDataBytes);
  try {
    eskin::check_npy_file_size(h, ok.size() + 10, "x.npy");
    ADD_FAILURE();
  } catch (const NpyError& e) {
    EXPECT_NE(std::string(e.what()).find("x.npy: .npy data truncated: shape (137438953472,) of <f8 "
                                         "needs 1099511627776 bytes, the file has 10"),
              std::string::npos)
        << e.what();
  }
  const Bytes small = npy(dict("<i2", "(2, 3)"), 1, 12);
  const auto hs = eskin::parse_npy_header(small.data(), small.size(), "x.npy");
  EXPECT_NO_THROW(eskin::check_npy_file_size(hs, small.size(), "x.npy"));
  EXPECT_THROW(eskin::check_npy_file_size(hs, small.size() - 1, "x.npy"), NpyError);
  try {
    eskin::check_npy_file_size(hs, small.size() + 3, "x.npy");
    ADD_FAILURE();
  } catch (const NpyError& e) {
    EXPECT_NE(std::string(e.what()).find("3 unexpected bytes after the .npy data"), std::string::npos);
  }
}
