// The .npy header reader; see eskin/npy.hpp and the NumPy format description
// (numpy.lib.format): magic "\x93NUMPY", major and minor version bytes, a little-endian header
// length (u16 in version 1, u32 in versions 2 and 3), then a Python dict literal padded with
// spaces and ended by '\n'.
#include "eskin/npy.hpp"

#include <cstring>

namespace eskin {

namespace {

constexpr std::uint8_t kMagic[6] = {0x93, 'N', 'U', 'M', 'P', 'Y'};

[[noreturn]] void fail(const std::string& what, const std::string& msg) {
  throw NpyError(what + ": " + msg);
}

// A printable excerpt of header text for error messages.
std::string excerpt(const std::string& s, std::size_t at) {
  std::string out;
  for (std::size_t i = at; i < s.size() && out.size() < 24; ++i) {
    const unsigned char c = static_cast<unsigned char>(s[i]);
    out += (c >= 0x20 && c < 0x7F) ? static_cast<char>(c) : '?';
  }
  return "'" + out + "'";
}

// The header dictionary, e.g. {'descr': '<i2', 'fortran_order': False, 'shape': (3, 900), }:
// a restricted Python literal (quoted keys, and as values a quoted string, True/False or a tuple
// of non-negative integers).
class DictParser {
 public:
  DictParser(std::string text, std::string what) : s_(std::move(text)), what_(std::move(what)) {}

  NpyHeader parse() {
    NpyHeader h;
    bool have_descr = false, have_order = false, have_shape = false;
    skip_ws();
    expect('{', "a dictionary");
    skip_ws();
    while (peek() != '}') {
      const std::string key = quoted("a key");
      skip_ws();
      expect(':', "':' after key '" + key + "'");
      skip_ws();
      if (key == "descr") {
        if (have_descr) fail(what_, ".npy header: key 'descr' repeated");
        have_descr = true;
        h.dtype = dtype(quoted("the value of 'descr'"));
      } else if (key == "fortran_order") {
        if (have_order) fail(what_, ".npy header: key 'fortran_order' repeated");
        have_order = true;
        if (word("False")) {
        } else if (word("True")) {
          fail(what_, ".npy array must be in C order (fortran_order is True)");
        } else {
          fail(what_, ".npy header: 'fortran_order' must be True or False, got " + excerpt(s_, i_));
        }
      } else if (key == "shape") {
        if (have_shape) fail(what_, ".npy header: key 'shape' repeated");
        have_shape = true;
        h.shape = shape();
      } else {
        fail(what_, ".npy header: unknown key '" + key + "'");
      }
      skip_ws();
      if (peek() == ',') {
        ++i_;
        skip_ws();
      } else if (peek() != '}') {
        fail(what_, ".npy header: expected ',' or '}' at " + excerpt(s_, i_));
      }
    }
    ++i_;
    skip_ws();
    if (i_ != s_.size()) fail(what_, ".npy header: unexpected text after the dictionary " + excerpt(s_, i_));
    if (!have_descr) fail(what_, ".npy header has no 'descr'");
    if (!have_order) fail(what_, ".npy header has no 'fortran_order'");
    if (!have_shape) fail(what_, ".npy header has no 'shape'");
    return h;
  }

 private:
  char peek() const { return i_ < s_.size() ? s_[i_] : '\0'; }
  void skip_ws() {
    while (i_ < s_.size() && (s_[i_] == ' ' || s_[i_] == '\t' || s_[i_] == '\n' || s_[i_] == '\r')) ++i_;
  }
  void expect(char c, const std::string& why) {
    if (peek() != c) fail(what_, ".npy header: expected " + why + ", got " + excerpt(s_, i_));
    ++i_;
  }
  bool word(const char* w) {
    const std::size_t n = std::strlen(w);
    if (s_.compare(i_, n, w) != 0) return false;
    i_ += n;
    return true;
  }
  std::string quoted(const std::string& what) {
    const char q = peek();
    if (q != '\'' && q != '"') fail(what_, ".npy header: expected " + what + " in quotes at " + excerpt(s_, i_));
    const std::size_t end = s_.find(q, i_ + 1);
    if (end == std::string::npos) fail(what_, ".npy header: unterminated string at " + excerpt(s_, i_));
    std::string out = s_.substr(i_ + 1, end - i_ - 1);
    if (out.find('\\') != std::string::npos) fail(what_, ".npy header: escapes in " + what + " are not supported");
    i_ = end + 1;
    return out;
  }
  NpyDtype dtype(const std::string& d) {
    if (d == "<i2") return NpyDtype::kInt16;
    if (d == "<f4") return NpyDtype::kFloat32;
    if (d == "<f8") return NpyDtype::kFloat64;
    std::string shown;
    for (const char c : d.substr(0, 24)) shown += (c >= 0x20 && c < 0x7F) ? c : '?';
    fail(what_, ".npy dtype '" + shown + "' not supported (int16, float32, float64 little-endian: "
                "'<i2', '<f4', '<f8')");
  }
  std::vector<std::uint64_t> shape() {
    expect('(', "a tuple as 'shape'");
    std::vector<std::uint64_t> dims;
    skip_ws();
    while (peek() != ')') {
      if (dims.size() == kNpyMaxDims)
        fail(what_, ".npy 'shape' has more than " + std::to_string(kNpyMaxDims) + " dimensions");
      if (peek() < '0' || peek() > '9')
        fail(what_, ".npy 'shape' entry " + std::to_string(dims.size()) + " is not a non-negative integer: " +
                        excerpt(s_, i_));
      std::uint64_t v = 0;
      const std::size_t start = i_;
      while (peek() >= '0' && peek() <= '9') {
        const auto digit = static_cast<std::uint64_t>(peek() - '0');
        if (v > (std::uint64_t{1} << 62) / 10) {  // keeps every entry below 2^63
          std::size_t end = start;
          while (end < s_.size() && end - start < 24 && s_[end] >= '0' && s_[end] <= '9') ++end;
          fail(what_, ".npy 'shape' entry " + std::to_string(dims.size()) + " = " +
                          s_.substr(start, end - start) + "... is too large");
        }
        v = v * 10 + digit;
        ++i_;
      }
      if (peek() == 'L') ++i_;  // written by Python 2
      dims.push_back(v);
      skip_ws();
      if (peek() == ',') {
        ++i_;
        skip_ws();
      } else if (peek() != ')') {
        fail(what_, ".npy 'shape': expected ',' or ')' at " + excerpt(s_, i_));
      }
    }
    ++i_;
    return dims;
  }

  std::string s_;
  std::string what_;
  std::size_t i_ = 0;
};

}  // namespace

std::size_t npy_item_bytes(NpyDtype dtype) noexcept {
  switch (dtype) {
    case NpyDtype::kInt16: return 2;
    case NpyDtype::kFloat32: return 4;
    case NpyDtype::kFloat64: return 8;
  }
  return 0;
}

const char* npy_descr(NpyDtype dtype) noexcept {
  switch (dtype) {
    case NpyDtype::kInt16: return "<i2";
    case NpyDtype::kFloat32: return "<f4";
    case NpyDtype::kFloat64: return "<f8";
  }
  return "?";
}

bool is_npy(const std::uint8_t* p, std::size_t size) noexcept {
  return p != nullptr && size >= sizeof kMagic && std::memcmp(p, kMagic, sizeof kMagic) == 0;
}

std::size_t npy_data_offset(const std::uint8_t* p, std::size_t size, const std::string& what) {
  if (!is_npy(p, size)) fail(what, "not a .npy file (magic \\x93NUMPY missing)");
  if (size < 10) fail(what, "truncated .npy header (" + std::to_string(size) + " bytes)");
  const int major = p[6], minor = p[7];
  std::size_t len, start;
  if (major == 1) {
    len = std::size_t{p[8]} | (std::size_t{p[9]} << 8);
    start = 10;
  } else if (major == 2 || major == 3) {
    if (size < 12) fail(what, "truncated .npy header (" + std::to_string(size) + " bytes)");
    const std::uint64_t l = std::uint64_t{p[8]} | (std::uint64_t{p[9]} << 8) |
                            (std::uint64_t{p[10]} << 16) | (std::uint64_t{p[11]} << 24);
    if (l > kNpyMaxHeaderBytes)
      fail(what, ".npy header_len = " + std::to_string(l) + " is larger than the limit " +
                     std::to_string(kNpyMaxHeaderBytes));
    len = static_cast<std::size_t>(l);
    start = 12;
  } else {
    fail(what, ".npy format version " + std::to_string(major) + "." + std::to_string(minor) +
                   " is not supported (1.0, 2.0, 3.0)");
  }
  return start + len;
}

NpyHeader parse_npy_header(const std::uint8_t* p, std::size_t size, const std::string& what) {
  const std::size_t end = npy_data_offset(p, size, what);
  if (end > size)
    fail(what, "truncated .npy header (" + std::to_string(size) + " bytes, the header needs " +
                   std::to_string(end) + ")");
  const std::size_t start = p[6] == 1 ? 10 : 12;
  std::string text(reinterpret_cast<const char*>(p + start), end - start);
  if (p[6] == 1 || p[6] == 2) {  // latin-1 text; version 3 allows UTF-8, which only keys would use
    for (const char c : text)
      if (static_cast<unsigned char>(c) >= 0x80) fail(what, ".npy header is not ASCII");
  }
  NpyHeader h = DictParser(std::move(text), what).parse();
  h.major_version = p[6];
  h.data_offset = end;
  const std::uint64_t item = h.item_bytes();
  const std::uint64_t limit = kNpyMaxDataBytes / item;
  h.count = 1;
  bool zero = false;
  for (const std::uint64_t d : h.shape) zero = zero || d == 0;
  if (!zero) {
    for (const std::uint64_t d : h.shape) {
      if (d > limit || h.count > limit / d)
        fail(what, ".npy shape " + npy_shape_string(h.shape) + " of " + npy_descr(h.dtype) +
                       " declares more than the limit of " + std::to_string(kNpyMaxDataBytes) +
                       " bytes of data");
      h.count *= d;
    }
  } else {
    h.count = 0;
  }
  h.data_bytes = h.count * item;
  return h;
}

void check_npy_file_size(const NpyHeader& h, std::uint64_t file_bytes, const std::string& what) {
  const std::uint64_t want = h.data_offset + h.data_bytes;
  if (file_bytes < want)
    fail(what, ".npy data truncated: shape " + npy_shape_string(h.shape) + " of " +
                   npy_descr(h.dtype) + " needs " + std::to_string(h.data_bytes) + " bytes, the file has " +
                   std::to_string(file_bytes < h.data_offset ? 0 : file_bytes - h.data_offset));
  if (file_bytes > want)
    fail(what, std::to_string(file_bytes - want) + " unexpected bytes after the .npy data (shape " +
                   npy_shape_string(h.shape) + ")");
}

std::string npy_shape_string(const std::vector<std::uint64_t>& shape) {
  std::string s = "(";
  for (std::size_t i = 0; i < shape.size(); ++i) {
    if (i) s += ", ";
    s += std::to_string(shape[i]);
  }
  if (shape.size() == 1) s += ",";
  return s + ")";
}

}  // namespace eskin
