// The .eskin loader (every bad-file case gives its error, fuzzed files never crash or hang).
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <new>
#include <fstream>
#include <initializer_list>
#include <iterator>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include "eskin/model.hpp"

// ---- allocation counting: this test executable replaces the global operator new.
namespace {
std::atomic<bool> g_counting{false};
std::atomic<long> g_allocations{0};
void* counted_alloc(std::size_t n) {
  if (g_counting.load(std::memory_order_relaxed)) g_allocations.fetch_add(1);
  if (void* p = std::malloc(n ? n : 1)) return p;
  throw std::bad_alloc();
}
void* counted_alloc_aligned(std::size_t n, std::size_t al) {
  if (g_counting.load(std::memory_order_relaxed)) g_allocations.fetch_add(1);
  const std::size_t sz = (n + al - 1) / al * al;
  if (void* p = std::aligned_alloc(al, sz ? sz : al)) return p;
  throw std::bad_alloc();
}
}  // namespace
void* operator new(std::size_t n) { return counted_alloc(n); }
void* operator new[](std::size_t n) { return counted_alloc(n); }
void* operator new(std::size_t n, const std::nothrow_t&) noexcept {
  try { return counted_alloc(n); } catch (...) { return nullptr; }
}
void* operator new[](std::size_t n, const std::nothrow_t&) noexcept {
  try { return counted_alloc(n); } catch (...) { return nullptr; }
}
void* operator new(std::size_t n, std::align_val_t al) { return counted_alloc_aligned(n, static_cast<std::size_t>(al)); }
void* operator new[](std::size_t n, std::align_val_t al) { return counted_alloc_aligned(n, static_cast<std::size_t>(al)); }
void operator delete(void* p) noexcept { std::free(p); }
void operator delete[](void* p) noexcept { std::free(p); }
void operator delete(void* p, std::size_t) noexcept { std::free(p); }
void operator delete[](void* p, std::size_t) noexcept { std::free(p); }
void operator delete(void* p, std::align_val_t) noexcept { std::free(p); }
void operator delete[](void* p, std::align_val_t) noexcept { std::free(p); }
void operator delete(void* p, std::size_t, std::align_val_t) noexcept { std::free(p); }
void operator delete[](void* p, std::size_t, std::align_val_t) noexcept { std::free(p); }

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

void append_u32(Bytes& b, std::uint32_t v) {
  for (int i = 0; i < 4; ++i) b.push_back(static_cast<std::uint8_t>(v >> (8 * i)));
}
void append_f64(Bytes& b, double v) {
  std::uint64_t u;
  std::memcpy(&u, &v, 8);
  for (int i = 0; i < 8; ++i) b.push_back(static_cast<std::uint8_t>(u >> (8 * i)));
}

// The AMPL payload (format version 2): counts, then the support vectors' log energies and the
// machines' amplitude widths.
Bytes ampl_payload(const std::vector<double>& energy, const std::vector<double>& widths) {
  Bytes p;
  append_u32(p, static_cast<std::uint32_t>(energy.size()));
  append_u32(p, static_cast<std::uint32_t>(widths.size()));
  for (const double e : energy) append_f64(p, e);
  for (const double w : widths) append_f64(p, w);
  return p;
}

// A version-1 file with a section `tag` inserted right after MACH, as `version`; the header's
// sizes and the CRC fixed.
Bytes with_section_after_mach(const Bytes& v1, const char* tag, const Bytes& payload,
                              std::uint16_t version = 2) {
  const std::size_t mach = section_offset(v1, "MACH");
  const std::size_t after = mach + (get_u32(v1, mach - 4) + 7) / 8 * 8;
  Bytes sec(tag, tag + 4);
  append_u32(sec, static_cast<std::uint32_t>(payload.size()));
  sec.insert(sec.end(), payload.begin(), payload.end());
  sec.resize((sec.size() + 7) / 8 * 8, 0);
  Bytes b(v1.begin(), v1.begin() + static_cast<std::ptrdiff_t>(after));
  b.insert(b.end(), sec.begin(), sec.end());
  b.insert(b.end(), v1.begin() + static_cast<std::ptrdiff_t>(after), v1.end());
  b[8] = static_cast<std::uint8_t>(version);
  b[9] = static_cast<std::uint8_t>(version >> 8);
  put_u32(b, 16, static_cast<std::uint32_t>(b.size()));
  put_u32(b, 20, get_u32(b, 20) + 1);
  fix_crc(b);
  return b;
}

// The fixture as format version 2: machines 0 and 2 with an amplitude factor (widths 0.5 and
// 2), machine 1 without; support vector i has log energy 0.25 i - 1.
std::vector<double> fixture_energies(const Bytes& v1) {
  const Model m = Model::from_bytes(v1.data(), v1.size());
  std::vector<double> e;
  for (int i = 0; i < m.n_support(); ++i) e.push_back(0.25 * i - 1.0);
  return e;
}
const std::vector<double> kFixtureWidths = {0.5, 0.0, 2.0};
Bytes fixture_amplitude(const char* dtype) {
  const Bytes v1 = fixture(dtype);
  return with_section_after_mach(v1, "AMPL", ampl_payload(fixture_energies(v1), kFixtureWidths));
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
  for (const std::uint8_t v : {0, 5, 200}) {
    Bytes b = fixture("float32");
    b[8] = v;  // CRC left stale: the version is reported, not the checksum
    EXPECT_EQ(load_error(b), ModelError::kVersion);
    EXPECT_NE(load_message(b).find("model format version " + std::to_string(v) +
                                   " is not supported (this library reads versions 1 to 4)"),
              std::string::npos)
        << load_message(b);
  }
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

namespace {

void put_f64(Bytes& b, std::size_t off, double v) {
  std::uint64_t u;
  std::memcpy(&u, &v, 8);
  for (int i = 0; i < 8; ++i) b[off + static_cast<std::size_t>(i)] = static_cast<std::uint8_t>(u >> (8 * i));
}

// Offset of the f64 value of a named PREP window field (40 bytes of fixed fields, then
// {name[32], f64} pairs).
std::size_t window_field_offset(const Bytes& b, const std::string& name) {
  const std::size_t prep = section_offset(b, "PREP");
  for (std::size_t k = 0; k < eskin::kWindowConfigSize; ++k) {
    const std::size_t at = prep + 40 + k * 40;
    if (name == reinterpret_cast<const char*>(&b[at])) return at + 32;
  }
  ADD_FAILURE() << "window field " << name << " not found";
  return 0;
}

// Offsets in machine 0 of MACH: its per-mode alpha and sigma, and its first coefficient.
std::size_t machine0_alpha(const Bytes& b, int z) { return section_offset(b, "MACH") + 8 + 24 + 16 * z; }
std::size_t machine0_sigma(const Bytes& b, int z) { return machine0_alpha(b, z) + 8; }
std::size_t machine0_coef(const Bytes& b) {
  const std::size_t m0 = section_offset(b, "MACH") + 8;
  const std::uint32_t n_terms = get_u32(b, m0 + 8);
  return m0 + 72 + (std::size_t{n_terms} * 4 + 7) / 8 * 8;
}

// The error a one-field edit gives (CRC recomputed so the edit reaches the value checks).
std::string edited_message(const char* dtype, void (*edit)(Bytes&)) {
  Bytes b = fixture(dtype);
  edit(b);
  fix_crc(b);
  EXPECT_EQ(load_error(b), ModelError::kValue);
  return load_message(b);
}

}  // namespace

// A machine alpha >= 2^31 once passed as a negative int and crashed every consumer.
TEST(ModelLimits, AlphaAtOrAbove2To31IsRefused) {
  for (const std::uint32_t a : {0x80000000u, 0xFFFFFFFFu, 0x7FFFFFFFu}) {
    Bytes b = fixture("float32");
    put_u32(b, machine0_alpha(b, 1), a);
    fix_crc(b);
    EXPECT_EQ(load_error(b), ModelError::kValue);
    const std::string m = load_message(b);
    EXPECT_NE(m.find("machine 0: alpha[1]=" + std::to_string(a) + " out of range"), std::string::npos) << m;
  }
}

// sigma so small that 1 / (2 sigma^2) is inf makes 0 * inf = NaN decision values; so large or
// non-positive ones are nonsense: the range is [1e-6, 1e6].
TEST(ModelLimits, SigmaOutsideItsRangeIsRefused) {
  for (const double s : {1e-300, 0.0, -1.0, 9.9e-7, 1.01e6, 1e300, std::nan("")}) {
    Bytes b = fixture("float64");
    put_f64(b, machine0_sigma(b, 2), s);
    fix_crc(b);
    EXPECT_EQ(load_error(b), ModelError::kValue) << s;
    const std::string m = load_message(b);
    EXPECT_NE(m.find("machine 0: sigma[2]="), std::string::npos) << m;
    EXPECT_NE(m.find("out of range [1e-06, 1e+06]"), std::string::npos) << m;
  }
  for (const double s : {1e-6, 1e6}) {  // the bounds themselves load
    Bytes b = fixture("float64");
    put_f64(b, machine0_sigma(b, 2), s);
    fix_crc(b);
    EXPECT_EQ(Model::from_bytes(b.data(), b.size()).machines()[0].sigma[2], s);
  }
}

// Coefficients whose sum overflows would give inf - inf = NaN decision values.
TEST(ModelLimits, CoefficientsThatCouldOverflowAreRefused) {
  const std::string m = edited_message("float64", [](Bytes& b) {
    put_f64(b, machine0_coef(b), 1e300);
    put_f64(b, machine0_coef(b) + 8, -1e300);
  });
  EXPECT_NE(m.find("machine 0: |intercept| + sum |coef| = 2"), std::string::npos) << m;
  EXPECT_NE(m.find("exceeds 1e+300"), std::string::npos) << m;
  // the bound itself loads: an intercept of -1e300 and coefficients of 0 (machine 0)
  Bytes b = fixture("float64");
  const std::size_t m0 = section_offset(b, "MACH") + 8;
  const std::uint32_t n_terms = get_u32(b, m0 + 8);
  put_f64(b, m0 + 16, -1e300);
  for (std::uint32_t t = 0; t < n_terms; ++t) put_f64(b, machine0_coef(b) + 8 * t, 0.0);
  fix_crc(b);
  EXPECT_EQ(load_message(b), "");
  EXPECT_EQ(Model::from_bytes(b.data(), b.size()).machines()[0].intercept, -1e300);
}

// Window settings inside the old [-1e6, 1e6] s range whose buffers are unbounded: a 1e6 s
// noise window (an idle-frame history of 1e8 frames) or a 1e6 s max window (3e9 samples per
// taxel) are refused at load, naming the field and the value.
TEST(ModelLimits, WindowFieldsWithUnboundedBuffersAreRefused) {
  std::string m = edited_message("float32", [](Bytes& b) {
    put_f64(b, window_field_offset(b, "noise_window_s"), 1e6);
  });
  EXPECT_NE(m.find("section PREP: WindowConfig.noise_window_s = 1e+06: too large"), std::string::npos) << m;
  m = edited_message("float32", [](Bytes& b) {
    put_f64(b, window_field_offset(b, "max_window_s"), 1e6);
  });
  EXPECT_NE(m.find("WindowConfig.max_window_s = 1e+06: too large"), std::string::npos) << m;
  // 1000 s at 3 kHz is within the per-taxel limit, but a stream classifier over the 16 taxels
  // of the model would store 4.8e7 samples
  m = edited_message("float32", [](Bytes& b) {
    put_f64(b, window_field_offset(b, "max_window_s"), 1000);
  });
  EXPECT_NE(m.find("WindowConfig.max_window_s = 1000: too large for 16 taxels"), std::string::npos) << m;
}

// A grid and D whose tensor would make the classifier's workspace huge.
TEST(ModelLimits, TensorSizeIsBounded) {
  const std::string m = edited_message("float32", [](Bytes& b) {
    const std::size_t prep = section_offset(b, "PREP");
    put_u32(b, prep, 256);
    put_u32(b, prep + 4, 256);
    put_u32(b, prep + 8, 100);
  });
  EXPECT_NE(m.find("rows*cols*D = 256*256*100 = 6553600 exceeds the limit 1048576"), std::string::npos) << m;
  // at the bound exactly (4*4*65536 = 2^20) PREP is accepted, and the file is refused later
  // (its SVBS dims are the fixture's); one sample more is over it
  const std::string at = edited_message("float32", [](Bytes& b) {
    put_u32(b, section_offset(b, "PREP") + 8, 65536);
  });
  EXPECT_EQ(at.find("rows*cols*D"), std::string::npos) << at;
  EXPECT_NE(at.find("SVBS"), std::string::npos) << at;
  const std::string over = edited_message("float32", [](Bytes& b) {
    put_u32(b, section_offset(b, "PREP") + 8, 65537);
  });
  EXPECT_NE(over.find("rows*cols*D = 4*4*65537 = 1048592 exceeds the limit 1048576"),
            std::string::npos) << over;
}

// Class names are UTF-8 (the Python side decodes them): malformed sequences are refused.
TEST(ModelLimits, ClassNamesMustBeValidUtf8) {
  const auto with_name = [](const std::string& name) {
    Bytes b = fixture("float32");
    const std::size_t at = section_offset(b, "CLAS") + 8;  // class 0
    std::fill(b.begin() + static_cast<std::ptrdiff_t>(at), b.begin() + static_cast<std::ptrdiff_t>(at + 32), 0);
    std::copy(name.begin(), name.end(), b.begin() + static_cast<std::ptrdiff_t>(at));
    fix_crc(b);
    return b;
  };
  for (const std::string bad : {"\xff\xfe", "a\x80", "\xc0\xaf", "\xe0\x80\xaf", "\xed\xa0\x80",
                                "\xf4\x90\x80\x80", "\xf5\x80\x80\x80", "ok\xe2\x82"}) {
    const Bytes b = with_name(bad);
    EXPECT_EQ(load_error(b), ModelError::kValue);
    const std::string m = load_message(b);
    EXPECT_NE(m.find("field 'class name' is not valid UTF-8"), std::string::npos) << m;
  }
  for (const std::string good : {"caf\xc3\xa9", "\xe2\x82\xac", "\xf0\x9f\x91\x86 tap", "\xed\x9f\xbf"}) {
    const Bytes b = with_name(good);
    EXPECT_EQ(Model::from_bytes(b.data(), b.size()).class_names()[0], good);
  }
}

// Thousands of truncated and bit-flipped files: each either loads or throws ModelFormatError;
// nothing else (no crash, no other exception, no hang). With stale CRCs the checksum catches the
// flips; with recomputed CRCs the structural validation is exercised.
TEST(ModelFuzz, TruncatedAndBitFlippedFiles) {
  std::mt19937 rng(12345);
  int loaded = 0, rejected = 0;
  for (const Bytes& good : {fixture("float32"), fixture("float64"), fixture_amplitude("float32"),
                            fixture_amplitude("float64")}) {
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
        // bias the flips towards the header and section headers, where the sizes live, and
        // (every fourth trial) towards the end: MACH, AMPL and meta
        const std::size_t limit = (trial % 2) ? b.size() : std::min<std::size_t>(b.size(), 256);
        const std::size_t at = (trial % 4 == 2) ? b.size() - 1 - rng() % std::min<std::size_t>(b.size(), 600)
                                                : rng() % limit;
        b[at] ^= static_cast<std::uint8_t>(1u << (rng() % 8));
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
  EXPECT_GT(rejected, 2000);
  RecordProperty("loaded", loaded);
}

// ---- classification

namespace {

// A 4x4 recording (taxel-major, C order (rows, cols, T)): noise, then a vibrating touch.
std::vector<std::int16_t> synthetic_recording(std::int64_t T, std::int64_t on, std::int64_t off,
                                              unsigned seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> noise(0.0, 15.0);
  std::vector<std::int16_t> x(static_cast<std::size_t>(16 * T));
  for (int k = 0; k < 16; ++k) {
    const double f = 40.0 + 13.0 * k, amp = 800.0 + 90.0 * ((k * 7) % 16);
    for (std::int64_t t = 0; t < T; ++t) {
      double v = noise(rng);
      if (t >= on && t < off) v += amp * std::sin(2 * 3.14159265358979 * f * t / 3000.0);
      x[static_cast<std::size_t>(k * T + t)] = static_cast<std::int16_t>(std::lround(v));
    }
  }
  return x;
}

}  // namespace

TEST(ModelClassify, RawWindowGivesALabelAndOneValuePerMachine) {
  const Bytes b = fixture("float32");
  const Model m = Model::from_bytes(b.data(), b.size());
  eskin::Classifier clf(m);
  const auto x = synthetic_recording(9000, 3000, 6000, 1);
  eskin::Decision d;
  ASSERT_EQ(clf.classify(x.data(), 4, 4, 9000, 9000, &d), eskin::ClassifyStatus::kOk);
  EXPECT_GE(d.label, 0);
  EXPECT_LT(d.label, 3);
  EXPECT_EQ(d.n_machines, 3);
  for (int k = 0; k < 3; ++k) EXPECT_TRUE(std::isfinite(d.values[k]));
  EXPECT_TRUE(d.window_found);
  EXPECT_NEAR(static_cast<double>(d.window_start), 3000.0, 300.0);
  EXPECT_NEAR(static_cast<double>(d.window_stop), 6000.0, 900.0);
  // the paper's rule
  int claims = 0;
  for (int k = 0; k < 3; ++k) claims += d.values[k] > 0;
  EXPECT_EQ(d.dont_know, claims != 1);
  EXPECT_EQ(clf.classify(x.data(), 4, 5, 9000, 9000, &d), eskin::ClassifyStatus::kBadShape);
  EXPECT_EQ(clf.classify(x.data(), 4, 4, 9000, 0, &d), eskin::ClassifyStatus::kBadShape);
  std::vector<float> bad(x.begin(), x.end());
  bad[100] = NAN;
  EXPECT_EQ(clf.classify(bad.data(), 4, 4, 9000, 9000, &d), eskin::ClassifyStatus::kNotFinite);
}

// The streaming classifier makes the same decision as the batch classifier on the same touch,
// and allocates nothing once constructed (counted through the replaced operator new).
TEST(ModelStream, AllocationCounterSeesAllocations) {
  g_allocations = 0;
  g_counting = true;
  std::vector<double>* v = new std::vector<double>(10);
  g_counting = false;
  delete v;
  EXPECT_EQ(g_allocations.load(), 2);  // the vector object and its buffer
}

TEST(ModelStream, SameDecisionAsBatchAndNoAllocation) {
  // the two precisions, each without and with the amplitude factor (format versions 1 and 2)
  for (const std::string dtype : {"float32", "float64", "float32+amplitude", "float64+amplitude"}) {
    const bool amplitude = dtype.find("+amplitude") != std::string::npos;
    const std::string real = dtype.substr(0, 7);
    const Bytes b = amplitude ? fixture_amplitude(real.c_str()) : fixture(real.c_str());
    const Model m = Model::from_bytes(b.data(), b.size());
    eskin::Classifier clf(m);
    eskin::StreamClassifier sc(m);
    const std::int64_t T = 12000;
    const auto x = synthetic_recording(T, 4000, 7000, 2);
    eskin::Decision batch;
    ASSERT_EQ(clf.classify(x.data(), 4, 4, T, T, &batch), eskin::ClassifyStatus::kOk);
    const std::vector<double> batch_values(batch.values, batch.values + batch.n_machines);

    std::int16_t sample[16];
    int decisions = 0;
    eskin::Decision got;
    std::vector<double> got_values(3);
    g_allocations = 0;
    g_counting = true;
    for (int rep = 0; rep < 2; ++rep) {  // the same recording twice, back to back
      for (std::int64_t t = 0; t < T; ++t) {
        for (int k = 0; k < 16; ++k) sample[k] = x[static_cast<std::size_t>(k * T + t)];
        const eskin::ClassifyStatus s = sc.push(sample);
        if (s == eskin::ClassifyStatus::kDecision) {
          ++decisions;
          got = sc.decision();
          for (int k = 0; k < 3; ++k) got_values[static_cast<std::size_t>(k)] = got.values[k];
          if (rep == 0) {
            EXPECT_EQ(got.window_start, batch.window_start);
            EXPECT_EQ(got.window_stop, batch.window_stop);
          }
        }
      }
    }
    g_counting = false;
    EXPECT_EQ(g_allocations.load(), 0) << dtype;
    EXPECT_EQ(decisions, 2) << dtype;
    EXPECT_EQ(got.label, batch.label);
    for (int k = 0; k < 3; ++k) EXPECT_NEAR(got_values[static_cast<std::size_t>(k)], batch_values[static_cast<std::size_t>(k)], 1e-12);

    // the batch classifier does not allocate per decision either
    g_allocations = 0;
    g_counting = true;
    for (int rep = 0; rep < 3; ++rep) clf.classify(x.data(), 4, 4, T, T, &batch);
    g_counting = false;
    EXPECT_EQ(g_allocations.load(), 0) << dtype;
    EXPECT_EQ(m.has_amplitude(), amplitude);
  }
}

// The status-code loader (Model::parse) is the throwing loader's core: on the same truncated and
// bit-flipped files it fails exactly when from_bytes throws, with the same code and message, and
// leaves its output untouched; on success it gives the same model.
TEST(ModelParse, StatusLoaderAgreesWithTheThrowingLoader) {
  std::mt19937 rng(777);
  int failed = 0, loaded = 0;
  for (const Bytes& good : {fixture("float32"), fixture("float64"), fixture_amplitude("float64")}) {
    for (int trial = 0; trial < 1500; ++trial) {
      Bytes b = good;
      if (trial % 5 == 0) {
        b.resize(rng() % good.size());
      } else {
        const std::size_t limit = (trial % 2) ? b.size() : std::min<std::size_t>(b.size(), 256);
        for (int f = 0; f < 1 + static_cast<int>(rng() % 3); ++f)
          b[rng() % limit] ^= static_cast<std::uint8_t>(1u << (rng() % 8));
      }
      if (trial % 3 != 0) fix_crc(b);
      Model out;
      eskin::ModelLoadError err;
      const bool ok = Model::parse(b.data(), b.size(), &out, &err);
      const std::string thrown = load_message(b);
      if (ok) {
        ++loaded;
        EXPECT_EQ(thrown, "") << "trial " << trial;
        EXPECT_EQ(out.n_support(), Model::from_bytes(b.data(), b.size()).n_support());
      } else {
        ++failed;
        EXPECT_EQ(err.message, thrown) << "trial " << trial;
        EXPECT_EQ(err.code, load_error(b)) << "trial " << trial;
        EXPECT_EQ(out.n_support(), 0) << "a failed parse leaves its output untouched";
      }
    }
  }
  EXPECT_GT(failed, 1000);
  EXPECT_GT(loaded, 10);
  EXPECT_FALSE(Model::parse(nullptr, 10, nullptr, nullptr));  // no output: a failure, no crash
}

// view_bytes keeps the bases where they are when they are aligned for their type, copies them
// otherwise; the model is the same either way.
TEST(ModelParse, ViewBytesReadsAlignedBasesInPlace) {
  for (const char* dtype : {"float32", "float64"}) {
    const Bytes good = fixture(dtype);
    std::vector<std::uint64_t> aligned((good.size() + 16) / 8);  // 8-byte aligned storage
    auto* base = reinterpret_cast<std::uint8_t*>(aligned.data());
    std::copy(good.begin(), good.end(), base);
    const Model in_place = Model::view_bytes(base, good.size());
    const auto* p = in_place.is_float64()
                        ? reinterpret_cast<const std::uint8_t*>(in_place.bases_f64(0))
                        : reinterpret_cast<const std::uint8_t*>(in_place.bases_f32(0));
    EXPECT_TRUE(p >= base && p < base + good.size()) << dtype;
    std::vector<std::uint8_t> shifted(good.size() + 1);
    std::copy(good.begin(), good.end(), shifted.begin() + 1);  // misaligned by one byte
    const Model copied = Model::view_bytes(shifted.data() + 1, good.size());
    const auto* q = copied.is_float64()
                        ? reinterpret_cast<const std::uint8_t*>(copied.bases_f64(0))
                        : reinterpret_cast<const std::uint8_t*>(copied.bases_f32(0));
    EXPECT_FALSE(q >= shifted.data() && q < shifted.data() + shifted.size()) << dtype;
    const std::size_t n = static_cast<std::size_t>(in_place.n_support()) *
                          static_cast<std::size_t>(in_place.alpha_store(0) * in_place.basis_rows(0));
    for (std::size_t i = 0; i < n; ++i) {
      if (in_place.is_float64()) ASSERT_EQ(in_place.bases_f64(0)[i], copied.bases_f64(0)[i]);
      else ASSERT_EQ(in_place.bases_f32(0)[i], copied.bases_f32(0)[i]);
    }
  }
}

// ---- format version 2: the amplitude factor (section AMPL)

namespace {

// What loading `b` says, and its code.
struct LoadResult {
  ModelError code;
  std::string message;
};
LoadResult load_result(const Bytes& b) { return {load_error(b), load_message(b)}; }

Bytes fixture_with_ampl(const std::vector<double>& energy, const std::vector<double>& widths,
                        const char* dtype = "float64") {
  return with_section_after_mach(fixture(dtype), "AMPL", ampl_payload(energy, widths));
}

}  // namespace

TEST(ModelAmplitude, VersionTwoLoadsItsWidthsAndEnergies) {
  for (const char* dtype : {"float32", "float64"}) {
    const Bytes b = fixture_amplitude(dtype);
    const Model m = Model::from_bytes(b.data(), b.size());
    EXPECT_EQ(m.format_version(), 2);
    ASSERT_TRUE(m.has_amplitude());
    EXPECT_EQ(m.sv_log_energy(), fixture_energies(fixture(dtype)));
    for (std::size_t k = 0; k < 3; ++k) EXPECT_EQ(m.machines()[k].amplitude_width, kFixtureWidths[k]);
    // the status-code loader and view_bytes read the same
    Model parsed;
    eskin::ModelLoadError err;
    ASSERT_TRUE(Model::parse(b.data(), b.size(), &parsed, &err, /*in_place=*/true)) << err.message;
    EXPECT_EQ(parsed.sv_log_energy(), m.sv_log_energy());
    EXPECT_EQ(parsed.machines()[2].amplitude_width, 2.0);
  }
}

TEST(ModelAmplitude, VersionOneIsUnchanged) {
  const Bytes b = fixture("float64");
  EXPECT_EQ(get_u32(b, 8) & 0xFFFFu, 1u);
  const Model m = Model::from_bytes(b.data(), b.size());
  EXPECT_EQ(m.format_version(), 1);
  EXPECT_FALSE(m.has_amplitude());
  EXPECT_TRUE(m.sv_log_energy().empty());
  for (const auto& mm : m.machines()) EXPECT_EQ(mm.amplitude_width, 0.0);
}

TEST(ModelAmplitude, BadAmplSectionsAreRefusedNamingFieldAndValue) {
  const Bytes v1 = fixture("float64");
  const std::vector<double> e = fixture_energies(v1);
  const std::size_t n_sv = e.size();
  const auto expect = [](const Bytes& b, ModelError code, const std::string& text) {
    const LoadResult r = load_result(b);
    EXPECT_EQ(r.code, code) << r.message;
    EXPECT_NE(r.message.find(text), std::string::npos) << r.message;
  };
  {  // counts that differ from SVBS's and MACH's
    Bytes p = ampl_payload(e, kFixtureWidths);
    put_u32(p, 0, static_cast<std::uint32_t>(n_sv + 1));
    expect(with_section_after_mach(v1, "AMPL", p), ModelError::kValue,
           "section AMPL: n_sv=" + std::to_string(n_sv + 1) + " differs from SVBS's n_sv=" +
               std::to_string(n_sv));
    p = ampl_payload(e, kFixtureWidths);
    put_u32(p, 4, 1000000);
    expect(with_section_after_mach(v1, "AMPL", p), ModelError::kValue,
           "section AMPL: n_machines=1000000 differs from MACH's n_machines=3");
  }
  {  // a payload too short for its counts, and one with trailing bytes
    Bytes p = ampl_payload(e, kFixtureWidths);
    p.resize(p.size() - 8);
    expect(with_section_after_mach(v1, "AMPL", p), ModelError::kLayout,
           "section AMPL: field 'log energies and widths' runs past the end of the section");
    p = ampl_payload(e, kFixtureWidths);
    p.resize(p.size() + 8, 0);
    expect(with_section_after_mach(v1, "AMPL", p), ModelError::kLayout,
           "section AMPL: 8 unexpected trailing bytes");
  }
  for (const double bad : {std::nan(""), HUGE_VAL, -HUGE_VAL, 1.0001e4, -2e4}) {
    std::vector<double> eb = e;
    eb[2] = bad;
    expect(fixture_with_ampl(eb, kFixtureWidths), ModelError::kValue,
           "section AMPL: sv_log_energy[2]=");
    expect(fixture_with_ampl(eb, kFixtureWidths), ModelError::kValue,
           "is not finite or outside [-1e+04, 1e+04]");
  }
  for (const double bad : {-1.0, 9.9e-7, 1e-300, 1.01e6, HUGE_VAL, std::nan("")}) {
    expect(fixture_with_ampl(e, {0.5, bad, 2.0}), ModelError::kValue,
           "section AMPL: machine 1: amplitude_width=");
    expect(fixture_with_ampl(e, {0.5, bad, 2.0}), ModelError::kValue,
           "must be 0 (no amplitude factor) or within [1e-06, 1e+06]");
  }
  {  // the range's ends load; version 2 without any factor does not
    const Bytes ends = fixture_with_ampl({e.begin(), e.end()}, {1e-6, 1e6, 0.0});
    EXPECT_EQ(Model::from_bytes(ends.data(), ends.size()).machines()[1].amplitude_width, 1e6);
    expect(fixture_with_ampl(e, {0.0, 0.0, 0.0}), ModelError::kValue,
           "section AMPL: every amplitude_width is 0");
  }
  // AMPL in a version-1 file; a version-2 file without AMPL
  expect(with_section_after_mach(v1, "AMPL", ampl_payload(e, kFixtureWidths), 1), ModelError::kLayout,
         "section 'AMPL' (the amplitude factor) is not allowed in format version 1");
  {
    Bytes b = v1;
    b[8] = 2;
    fix_crc(b);
    expect(b, ModelError::kLayout, "required section 'AMPL' missing");
  }
  // an ancillary section between MACH and AMPL is skipped, as anywhere
  {
    const Bytes b = with_section_after_mach(fixture_amplitude("float64"), "note", Bytes{'h', 'i'});
    EXPECT_TRUE(Model::from_bytes(b.data(), b.size()).has_amplitude());
  }
}

namespace {

// The decision values of a model, by hand from its stored bases (float64 or float32, read as
// stored): the input's bases by BasisWorkspace, each overlap ||V_i^T V_x||_F^2 summed entry by
// entry in double, the docs' formula.
std::vector<double> hand_decision(const Model& m, const std::vector<double>& x) {
  const std::size_t A[3] = {static_cast<std::size_t>(m.alpha_store(0)),
                            static_cast<std::size_t>(m.alpha_store(1)),
                            static_cast<std::size_t>(m.alpha_store(2))};
  eskin::BasisLayout layout({static_cast<std::size_t>(m.rows()), static_cast<std::size_t>(m.cols()),
                             static_cast<std::size_t>(m.D())},
                            {A[0], A[1], A[2]});
  eskin::BasisWorkspace ws(layout);
  std::vector<double> xb(layout.bases_size());
  int rx[3];
  EXPECT_EQ(ws.compute(x.data(), xb.data(), rx), eskin::KernelStatus::ok);
  double sq = 0;
  for (const double v : x) sq += v * v;
  const double ex = std::log(sq / static_cast<double>(x.size()) + 1e-12);
  std::vector<double> out;
  for (const auto& mm : m.machines()) {
    double f = mm.intercept;
    for (std::size_t t = 0; t < mm.sv_index.size(); ++t) {
      const std::size_t i = mm.sv_index[t];
      double exponent = 0;
      for (int z = 0; z < 3; ++z) {
        const std::size_t N = static_cast<std::size_t>(m.basis_rows(z));
        const std::size_t a = static_cast<std::size_t>(mm.alpha[static_cast<std::size_t>(z)]);
        const double* vi64 = m.bases_f64(z);
        const float* vi32 = m.bases_f32(z);
        const std::size_t vi = i * A[z] * N;
        const double* vx = xb.data() + layout.offset(static_cast<std::size_t>(z));
        double ov = 0;
        for (std::size_t k = 0; k < a; ++k)
          for (std::size_t l = 0; l < a; ++l) {
            double dot = 0;
            for (std::size_t n = 0; n < N; ++n) {
              const std::size_t at = vi + k * N + n;
              dot += (vi64 != nullptr ? vi64[at] : double(vi32[at])) * vx[l * N + n];
            }
            ov += dot * dot;
          }
        const int ri = std::min(m.rank(static_cast<int>(i), z), static_cast<int>(a));
        const int rxa = std::min(rx[z], static_cast<int>(a));
        const double d = std::max(0.0, ri + rxa - 2 * ov);
        const double s = mm.sigma[static_cast<std::size_t>(z)];
        exponent += d / (2 * s * s);
      }
      if (mm.amplitude_width > 0) {
        const double g = ex - m.sv_log_energy()[i];
        exponent += g * g / (2 * mm.amplitude_width * mm.amplitude_width);
      }
      f += mm.coef[t] * std::exp(-exponent);
    }
    out.push_back(f);
  }
  return out;
}

std::vector<double> random_tensor(const Model& m, double scale, unsigned seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> g(0.0, scale);
  std::vector<double> x(static_cast<std::size_t>(m.rows()) * m.cols() * m.D());
  for (double& v : x) v = g(rng);
  return x;
}

// The compiled classifier's decision values on a random tensor per seed equal hand_decision's,
// machine by machine, to 1e-12.
void expect_hand_decisions(const Model& m, std::initializer_list<unsigned> seeds) {
  eskin::Classifier clf(m);
  for (const unsigned seed : seeds) {
    const std::vector<double> x = random_tensor(m, 1.0, seed);
    eskin::Decision d;
    ASSERT_EQ(clf.classify_tensor(x.data(), &d), eskin::ClassifyStatus::kOk);
    const std::vector<double> want = hand_decision(m, x);
    for (std::size_t k = 0; k < m.machines().size(); ++k)
      EXPECT_NEAR(d.values[k], want[k], 1e-12) << "machine " << k << ", seed " << seed;
  }
}

}  // namespace

TEST(ModelAmplitude, HostDecisionEqualsTheHandComputation) {
  const Bytes b = fixture_amplitude("float64");
  const Model m = Model::from_bytes(b.data(), b.size());
  eskin::Classifier clf(m);
  for (const double scale : {0.3, 1.0, 4.0}) {  // log energies about -2.4, 0 and 2.8
    const std::vector<double> x = random_tensor(m, scale, 7);
    eskin::Decision d;
    ASSERT_EQ(clf.classify_tensor(x.data(), &d), eskin::ClassifyStatus::kOk);
    const std::vector<double> want = hand_decision(m, x);
    for (int k = 0; k < 3; ++k)
      EXPECT_NEAR(d.values[k], want[static_cast<std::size_t>(k)], 1e-12) << "scale " << scale;
  }
}

// The factor scales a machine's kernel terms and nothing else: when every support vector has
// the input's log energy it is 1 and the decision is the version-1 model's, machine 1 (w = 0)
// never depends on it, and the amplitude makes the other machines differ.
TEST(ModelAmplitude, FactorIsOneAtEqualEnergyAndOnlyOnItsMachines) {
  const Bytes v1 = fixture("float64");
  const Model m1 = Model::from_bytes(v1.data(), v1.size());
  const std::vector<double> x = random_tensor(m1, 2.0, 11);
  const double ex = eskin::tensor_log_energy(x.data(), x.size());
  eskin::Classifier c1(m1);
  eskin::Decision d1;
  ASSERT_EQ(c1.classify_tensor(x.data(), &d1), eskin::ClassifyStatus::kOk);
  const std::vector<double> v1_values(d1.values, d1.values + 3);

  const Bytes same = fixture_with_ampl(std::vector<double>(fixture_energies(v1).size(), ex), kFixtureWidths);
  const Model ms = Model::from_bytes(same.data(), same.size());
  eskin::Classifier cs(ms);
  eskin::Decision ds;
  ASSERT_EQ(cs.classify_tensor(x.data(), &ds), eskin::ClassifyStatus::kOk);
  for (int k = 0; k < 3; ++k) EXPECT_DOUBLE_EQ(ds.values[k], v1_values[static_cast<std::size_t>(k)]);

  const Bytes far = fixture_with_ampl(std::vector<double>(fixture_energies(v1).size(), ex + 3.0),
                                      kFixtureWidths);
  const Model mf = Model::from_bytes(far.data(), far.size());
  eskin::Classifier cf(mf);
  eskin::Decision df;
  ASSERT_EQ(cf.classify_tensor(x.data(), &df), eskin::ClassifyStatus::kOk);
  EXPECT_EQ(df.values[1], v1_values[1]);  // machine 1 has no factor
  // machine 0 (w = 0.5): each term times exp(-9 / 0.5); machine 2 (w = 2): exp(-9 / 8)
  const auto& mm = m1.machines();
  EXPECT_NEAR(df.values[0] - mm[0].intercept, (v1_values[0] - mm[0].intercept) * std::exp(-18.0), 1e-12);
  EXPECT_NEAR(df.values[2] - mm[2].intercept, (v1_values[2] - mm[2].intercept) * std::exp(-9.0 / 8.0), 1e-12);
}

// A tensor whose mean square overflows: the factor is 0, never NaN.
TEST(ModelAmplitude, OverflowingInputGivesNoNaN) {
  std::vector<double> huge(128, 1e200);
  EXPECT_EQ(eskin::tensor_log_energy(huge.data(), huge.size()), INFINITY);
  const std::vector<double> zero(128, 0.0);
  EXPECT_DOUBLE_EQ(eskin::tensor_log_energy(zero.data(), zero.size()), std::log(1e-12));
  for (const char* dtype : {"float32", "float64"}) {
    const Bytes b = fixture_amplitude(dtype);
    const Model m = Model::from_bytes(b.data(), b.size());
    eskin::Classifier clf(m);
    for (const double big : {1e150, 1e160, 1e200, 1e300}) {
      std::vector<double> x = random_tensor(m, 1.0, 5);
      for (double& v : x) v *= big;
      eskin::Decision d;
      const eskin::ClassifyStatus st = clf.classify_tensor(x.data(), &d);
      if (st != eskin::ClassifyStatus::kOk) continue;  // refused (not finite) is fine too
      for (int k = 0; k < 3; ++k) {
        EXPECT_FALSE(std::isnan(d.values[k])) << dtype << " " << big;
        if (m.machines()[static_cast<std::size_t>(k)].amplitude_width > 0 &&
            !std::isfinite(eskin::tensor_log_energy(x.data(), x.size())))
          EXPECT_EQ(d.values[k], m.machines()[static_cast<std::size_t>(k)].intercept) << big;
      }
    }
  }
}

// ---- the checks beside the loader's main job: each refusal below was once accepted by a
// mutant of cpp/src/model_format.cpp without a test failing (docs/testing.md).
namespace {

double get_f64(const Bytes& b, std::size_t off) {
  std::uint64_t u = 0;
  for (int i = 7; i >= 0; --i) u = (u << 8) | b[off + static_cast<std::size_t>(i)];
  double v;
  std::memcpy(&v, &u, 8);
  return v;
}

std::string refused(Bytes b) {
  fix_crc(b);
  return load_message(b);
}

bool says(const std::string& message, const std::string& part) {
  return message.find(part) != std::string::npos;
}

// Offset of the first basis entry of mode 0 (after the SVBS counts and the padded ranks).
std::size_t first_basis(const Bytes& b) {
  const std::size_t svbs = section_offset(b, "SVBS");
  const std::uint32_t n_sv = get_u32(b, svbs + 4);
  return svbs + 32 + (std::size_t{n_sv} * 12 + 7) / 8 * 8;
}

}  // namespace

TEST(ModelChecks, ClassNamesMustBePresentAndDistinct) {
  const Bytes good = fixture("float32");
  const std::size_t names = section_offset(good, "CLAS") + 8;
  Bytes empty = good;
  std::fill(empty.begin() + static_cast<std::ptrdiff_t>(names + 32),
            empty.begin() + static_cast<std::ptrdiff_t>(names + 64), 0);
  EXPECT_TRUE(says(refused(empty), "'class name' must be a non-empty name")) << refused(empty);
  Bytes repeated = good;
  std::copy(good.begin() + static_cast<std::ptrdiff_t>(names),
            good.begin() + static_cast<std::ptrdiff_t>(names + 32),
            repeated.begin() + static_cast<std::ptrdiff_t>(names + 64));
  EXPECT_TRUE(says(refused(repeated), "class name 'brush' repeated")) << refused(repeated);
}

TEST(ModelChecks, TheBinaryRuleNeedsTwoClasses) {
  Bytes b = fixture("float32");
  put_u32(b, section_offset(b, "CLAS") + 4, 0);  // three classes, binary rule
  EXPECT_TRUE(says(refused(b), "the binary rule needs 2 classes, got 3")) << refused(b);
}

TEST(ModelChecks, DMustBeAtLeastTwo) {
  Bytes b = fixture("float32");
  put_u32(b, section_offset(b, "PREP") + 8, 1);
  EXPECT_TRUE(says(refused(b), "D=1 out of range [2, ")) << refused(b);
  Bytes rows = fixture("float32");
  put_u32(rows, section_offset(rows, "PREP"), 0);
  EXPECT_TRUE(says(refused(rows), "rows=0 cols=4 out of range [1, 256]")) << refused(rows);
}

TEST(ModelChecks, BasesMustBeOrthonormalToTheFormatsTolerance) {
  // column 0 of support vector 0 in mode 0: 32 entries; its largest entry (at least 1/sqrt(32))
  // moved by delta changes the column's norm by about 2 * 0.18 * delta
  auto largest = [](const Bytes& b, std::size_t at, std::size_t width) {
    std::size_t best = at;
    double best_v = 0;
    for (std::size_t j = 0; j < 32; ++j) {
      double v;
      if (width == 8) {
        v = get_f64(b, at + 8 * j);
      } else {
        const std::uint32_t u = get_u32(b, at + 4 * j);
        float f;
        std::memcpy(&f, &u, 4);
        v = f;
      }
      if (std::fabs(v) > best_v) best_v = std::fabs(v), best = at + width * j;
    }
    return best;
  };
  {  // float64: tolerance 1e-8; a 1e-5 move is far above it (and far below 1e-2)
    Bytes b = fixture("float64");
    const std::size_t at = largest(b, first_basis(b), 8);
    const double v = get_f64(b, at);
    put_f64(b, at, v - std::copysign(1e-5, v));
    EXPECT_TRUE(says(refused(b), "is not orthonormal up to its rank")) << refused(b);
  }
  {  // float32: tolerance 1e-4; a 1e-3 move
    Bytes b = fixture("float32");
    const std::size_t at = largest(b, first_basis(b), 4);
    std::uint32_t u = get_u32(b, at);
    float f;
    std::memcpy(&f, &u, 4);
    f -= std::copysign(1e-3f, f);
    std::memcpy(&u, &f, 4);
    put_u32(b, at, u);
    EXPECT_TRUE(says(refused(b), "is not orthonormal up to its rank")) << refused(b);
  }
  {  // an entry exactly at the range bound 1 + 1e-5 passes the range check (strictly above is
     // refused there) and is refused as not orthonormal; just above the bound, by the range
    Bytes b = fixture("float64");
    const std::size_t at = largest(b, first_basis(b), 8);
    put_f64(b, at, 1.0 + 1e-5);
    EXPECT_TRUE(says(refused(b), "is not orthonormal up to its rank")) << refused(b);
    put_f64(b, at, std::nextafter(1.0 + 1e-5, 2.0));
    EXPECT_TRUE(says(refused(b), "(entries of orthonormal columns lie in [-1, 1])")) << refused(b);
  }
  {  // a column beyond the rank must be zero: rank 1 declared for support vector 1's basis of
     // 2 columns in mode 0
    Bytes b = fixture("float64");
    const std::size_t rank = section_offset(b, "SVBS") + 32 + 12;
    ASSERT_EQ(get_u32(b, rank), 2u);
    put_u32(b, rank, 1);
    EXPECT_TRUE(says(refused(b), "support vector 1 in mode 0 is not orthonormal up to its rank 1"))
        << refused(b);
  }
}

TEST(ModelChecks, SupportVectorIndicesStrictlyIncrease) {
  Bytes b = fixture("float32");
  const std::size_t m0 = section_offset(b, "MACH") + 8;
  put_u32(b, m0 + 72 + 4, get_u32(b, m0 + 72));  // machine 0's second term repeats its first
  EXPECT_TRUE(says(refused(b), "machine 0: sv_index must be strictly increasing (entry 1)"))
      << refused(b);
}

TEST(ModelChecks, HeaderFlagsAndFileSize) {
  Bytes flags = fixture("float32");
  put_u32(flags, 12, get_u32(flags, 12) | 2u);
  EXPECT_TRUE(says(refused(flags), "unknown flags 0x2")) << refused(flags);
  Bytes odd = fixture("float32");
  odd.insert(odd.end() - 4, {0, 0});
  put_u32(odd, 16, static_cast<std::uint32_t>(odd.size()));
  EXPECT_TRUE(says(refused(odd), " is impossible")) << refused(odd);
}

TEST(ModelChecks, NoDataWithALengthIsAnIoError) {
  // a null pointer with one byte claimed: refused before anything is read
  try {
    Model::from_bytes(nullptr, 1);
    FAIL() << "no error for null data";
  } catch (const ModelFormatError& e) {
    EXPECT_EQ(e.code(), ModelError::kIo);
    EXPECT_NE(std::string(e.what()).find("null data"), std::string::npos) << e.what();
  }
}

TEST(ModelChecks, TheMagicAloneIsATruncatedModel) {
  const Bytes good = fixture("float32");
  const Bytes magic(good.begin(), good.begin() + 8);
  EXPECT_EQ(load_error(magic), ModelError::kTruncated);
  EXPECT_TRUE(says(load_message(magic), "truncated: 8 bytes, shorter than the 36-byte header"));
  const Bytes seven(good.begin(), good.begin() + 7);
  EXPECT_EQ(load_error(seven), ModelError::kNotAModel);
}

TEST(ModelChecks, ANameFillingItsFieldIsRefusedNamingTheLimit) {
  Bytes b = fixture("float32");
  const std::size_t names = section_offset(b, "CLAS") + 8;
  std::fill(b.begin() + static_cast<std::ptrdiff_t>(names),
            b.begin() + static_cast<std::ptrdiff_t>(names + 32), 'x');  // no NUL left
  EXPECT_TRUE(says(refused(b), "'class name' must be a non-empty name of at most 31 bytes, NUL padded"))
      << refused(b);
}

TEST(ModelChecks, AFieldRunningPastItsSectionNamesTheBytesLeftAndNeeded) {
  // four class names declared in a CLAS section that holds three (96 bytes after the counts)
  Bytes b = fixture("float32");
  const std::size_t clas = section_offset(b, "CLAS");
  ASSERT_EQ(get_u32(b, clas), 3u);
  put_u32(b, clas, 4);
  EXPECT_TRUE(says(refused(b), "section CLAS: field 'class names' runs past the end of the section "
                               "(96 bytes left, 128 needed)"))
      << refused(b);
}

// tests/data/model_binary_float64.eskin (tests/data/make_model_fixture.py): two classes, the
// binary rule, one machine over all 4 support vectors.
TEST(ModelChecks, ABinaryModelLoadsAndItsRuleIsChecked) {
  const Bytes good = read_file(std::string(ESKIN_TEST_DATA_DIR) + "/model_binary_float64.eskin");
  {
    const Model m = Model::from_bytes(good.data(), good.size());
    EXPECT_EQ(m.rule(), eskin::DecisionRule::kBinary);
    EXPECT_EQ(m.class_names(), (std::vector<std::string>{"press", "tap"}));
    ASSERT_EQ(m.machines().size(), 1u);
    EXPECT_EQ(m.machines()[0].positive, 1);
    EXPECT_EQ(m.machines()[0].negative, 0);
    EXPECT_EQ(m.n_support(), 4);
    EXPECT_EQ(m.rows(), 2);
    EXPECT_EQ(m.cols(), 3);
    EXPECT_EQ(m.D(), 4);
  }
  const std::size_t m0 = section_offset(good, "MACH") + 8;
  {  // the classes the other way round: also a binary machine
    Bytes b = good;
    put_u32(b, m0, 0);
    put_u32(b, m0 + 4, 1);
    fix_crc(b);
    const Model m = Model::from_bytes(b.data(), b.size());
    EXPECT_EQ(m.machines()[0].positive, 0);
  }
  Bytes same = good;
  put_u32(same, m0 + 4, 1);  // (1, 1)
  EXPECT_TRUE(says(refused(same), "binary machine classes (1, 1) must be (1, 0) or (0, 1)")) << refused(same);
  Bytes ova = good;
  put_u32(ova, section_offset(ova, "CLAS") + 4, 1);  // one_vs_all with 2 classes and 1 machine
  EXPECT_TRUE(says(refused(ova), "one_vs_all needs one machine per class (2), got 1")) << refused(ova);
  Bytes one = good;
  put_u32(one, section_offset(one, "CLAS"), 1);  // one class
  EXPECT_TRUE(says(refused(one), "n_classes=1 out of range [2, ")) << refused(one);
  Bytes none = good;
  put_u32(none, m0 - 8, 0);  // no machine
  EXPECT_TRUE(says(refused(none), "n_machines=0 impossible")) << refused(none);
}

TEST(ModelChecks, EachOneVsAllMachineNamesItsOwnClassAgainstTheRest) {
  const Bytes good = fixture("float32");
  const std::size_t m0 = section_offset(good, "MACH") + 8;
  Bytes first = good;
  put_u32(first, m0, 1);  // machine 0 claims class 1
  EXPECT_TRUE(says(refused(first), "one_vs_all machine 0 must have positive_class=0 and negative_class=-1"))
      << refused(first);
  Bytes against = good;
  put_u32(against, m0 + 4, 2);  // machine 0 against class 2 only
  EXPECT_TRUE(says(refused(against), "one_vs_all machine 0 must have positive_class=0")) << refused(against);
}

// Each PREP field edited alone: at its limit the model loads, one past it is refused with the
// field, the value and the allowed values.
TEST(ModelChecks, PrepFieldsAtAndBeyondTheirLimits) {
  const Bytes good = fixture("float32");
  const std::size_t prep = section_offset(good, "PREP");
  auto edited = [&](std::size_t off, std::uint32_t v) {
    Bytes b = good;
    put_u32(b, prep + off, v);
    fix_crc(b);
    return b;
  };
  struct Case { std::size_t off; std::uint32_t ok, bad; const char* says; };
  for (const Case& c : {Case{12, 1, 2, "window_mode=2 (0 energy, 1 none)"},
                        Case{16, 1, 2, "subsample=2 (0 algorithm2, 1 even)"},
                        Case{20, 1, 2, "short_policy=2 (0 interpolate, 1 error)"},
                        Case{28, 0, 1, "section PREP: reserved field 'reserved' is not 0"}}) {
    const Bytes ok = edited(c.off, c.ok);
    EXPECT_NO_THROW(Model::from_bytes(ok.data(), ok.size())) << c.says;
    EXPECT_TRUE(says(load_message(edited(c.off, c.bad)), c.says)) << load_message(edited(c.off, c.bad));
  }
  {
    const Bytes b = edited(12, 1);
    EXPECT_EQ(Model::from_bytes(b.data(), b.size()).window_mode(), eskin::WindowMode::kNone);
    const Bytes e = edited(16, 1);
    EXPECT_EQ(Model::from_bytes(e.data(), e.size()).subsample(), eskin::SubsampleMethod::kEven);
    const Bytes s = edited(20, 1);
    EXPECT_EQ(Model::from_bytes(s.data(), s.size()).short_policy(), eskin::ShortPolicy::kError);
  }
  const std::uint32_t n_fields = get_u32(good, prep + 24);
  EXPECT_TRUE(says(load_message(edited(24, n_fields + 1)),
                   "n_window_fields=" + std::to_string(n_fields + 1) + ", expected " +
                       std::to_string(n_fields) + " (the WindowConfig fields of format version 1)"))
      << load_message(edited(24, n_fields + 1));
  for (const double rate : {0.0, -3000.0, 1.0000001e7, std::nan(""), HUGE_VAL}) {
    Bytes b = good;
    put_f64(b, prep + 32, rate);
    EXPECT_TRUE(says(refused(b), "section PREP: sample_rate_hz=")) << refused(b);
    EXPECT_TRUE(says(refused(b), " must be in (0, 1e7]")) << refused(b);
  }
  {  // the rate loads as written
    Bytes b = good;
    put_f64(b, prep + 32, 2500.0);
    fix_crc(b);
    EXPECT_EQ(Model::from_bytes(b.data(), b.size()).sample_rate_hz(), 2500.0);
  }
  {  // the range's top, 1e7 Hz, is in it (1.0000001e7 above is not): the fixture's detector
     // sped up to that rate (its durations shortened and its cutoff raised by the same factor)
    Bytes b = good;
    const double f = 1e7 / get_f64(b, prep + 32);
    put_f64(b, prep + 32, 1e7);
    for (const char* name : {"frame_s", "noise_window_s", "warmup_s", "lookback_s", "hold_s",
                             "min_duration_s", "pad_before_s", "pad_after_s", "max_window_s"}) {
      const std::size_t at = window_field_offset(b, name);
      put_f64(b, at, get_f64(b, at) / f);
    }
    const std::size_t cutoff = window_field_offset(b, "dc_cutoff_hz");
    put_f64(b, cutoff, get_f64(b, cutoff) * f);
    fix_crc(b);
    EXPECT_EQ(load_message(b), "") << load_message(b);
    EXPECT_EQ(Model::from_bytes(b.data(), b.size()).sample_rate_hz(), 1e7);
  }
}

TEST(ModelChecks, HeaderFieldsAreCheckedOneByOne) {
  const Bytes good = fixture("float32");
  Bytes old = good;
  old[8] = 0;  // version 0
  EXPECT_TRUE(says(refused(old), "model format version 0 is not supported (this library reads versions 1 to "))
      << refused(old);
  Bytes newer = good;
  newer[8] = 99;
  EXPECT_EQ(load_error([&] { fix_crc(newer); return newer; }()), ModelError::kVersion);
  Bytes hb = good;
  hb[10] = 40;  // header_bytes
  EXPECT_TRUE(says(refused(hb), "header_bytes=40, expected 32")) << refused(hb);
  for (const std::size_t off : {24u, 28u}) {
    Bytes r = good;
    put_u32(r, off, 5);
    EXPECT_TRUE(says(refused(r), ": header: reserved field 'reserved' is not 0")) << refused(r);
  }
  Bytes more = good;
  put_u32(more, 20, get_u32(more, 20) + 1);  // one section more than the file holds
  EXPECT_TRUE(says(refused(more), "section 5 header runs past the end")) << refused(more);
  Bytes fewer = good;
  put_u32(fewer, 20, get_u32(fewer, 20) - 1);  // the meta section left over
  EXPECT_TRUE(says(refused(fewer), "bytes after the last section, before the checksum")) << refused(fewer);
}

TEST(ModelChecks, AWindowFieldRunningPastPrepIsRefusedThere) {
  // PREP shortened by its last window field (a 32-byte name and an 8-byte value)
  Bytes b = fixture("float32");
  const std::size_t prep = section_offset(b, "PREP");
  put_u32(b, prep - 4, get_u32(b, prep - 4) - 40);
  EXPECT_TRUE(says(refused(b), "section PREP: field 'window field name' runs past the end of the "
                               "section (0 bytes left, 32 needed)"))
      << refused(b);
}

TEST(ModelChecks, DUpToItsLimitPassesThePrepCheck) {
  // the binary fixture's 2x3 grid: D = kMaxD keeps the tensor within its limit, so the file is
  // refused only later, where SVBS's dims differ; one more is out of range
  const Bytes good = read_file(std::string(ESKIN_TEST_DATA_DIR) + "/model_binary_float64.eskin");
  const std::size_t prep = section_offset(good, "PREP");
  Bytes at = good;
  put_u32(at, prep + 8, static_cast<std::uint32_t>(eskin::kMaxD));
  EXPECT_TRUE(says(refused(at), "differ from the preprocessing's (rows, cols, D) = (2, 3, " +
                                    std::to_string(eskin::kMaxD) + ")"))
      << refused(at);
  Bytes past = good;
  put_u32(past, prep + 8, static_cast<std::uint32_t>(eskin::kMaxD + 1));
  EXPECT_TRUE(says(refused(past), "D=" + std::to_string(eskin::kMaxD + 1) + " out of range [2, " +
                                      std::to_string(eskin::kMaxD) + "]"))
      << refused(past);
}

TEST(ModelChecks, AHeaderAndChecksumAloneAreNotTooShortToRead) {
  // 36 bytes: the header (it says 8500 bytes) and a checksum; read, then found truncated
  const Bytes good = fixture("float32");
  Bytes b(good.begin(), good.begin() + 36);
  EXPECT_EQ(load_error(b), ModelError::kTruncated);
  EXPECT_TRUE(says(load_message(b), "truncated: the header says 8500 bytes, only 36 present"))
      << load_message(b);
}

namespace {
// A version-1 file as format version 3: its window fields and the bounded window's
// (window_samples = 0), no AMPL section.
Bytes as_version3(const Bytes& v1) {
  const std::size_t prep = section_offset(v1, "PREP");
  const std::uint32_t bytes = get_u32(v1, prep - 4);
  EXPECT_EQ(bytes % 8, 0u);
  Bytes field(32, 0);
  const std::string name = "window_samples";
  std::copy(name.begin(), name.end(), field.begin());
  append_f64(field, 0.0);
  Bytes b(v1.begin(), v1.begin() + static_cast<std::ptrdiff_t>(prep + bytes));
  b.insert(b.end(), field.begin(), field.end());
  b.insert(b.end(), v1.begin() + static_cast<std::ptrdiff_t>(prep + bytes), v1.end());
  put_u32(b, prep - 4, bytes + 40);
  put_u32(b, prep + 24, get_u32(b, prep + 24) + 1);
  b[8] = 3;
  put_u32(b, 16, static_cast<std::uint32_t>(b.size()));
  fix_crc(b);
  return b;
}
}  // namespace

TEST(ModelChecks, VersionThreeLoadsWithoutAnAmplitudeSection) {
  const Bytes b = as_version3(fixture("float64"));
  const Model m = Model::from_bytes(b.data(), b.size());
  EXPECT_EQ(m.format_version(), 3);
  EXPECT_FALSE(m.has_amplitude());
  EXPECT_EQ(m.window_config().window_samples, 0);
  Bytes v2 = b;  // the same bytes as version 2 need their AMPL section (and a v1 window)
  v2[8] = 2;
  EXPECT_TRUE(says(refused(v2), "n_window_fields=")) << refused(v2);
}

// ---- the calibrated rule (format version 4, section CALB)

namespace {
Bytes calb_payload(std::uint32_t rule, double threshold, const std::vector<double>& slopes,
                   const std::vector<double>& offsets) {
  Bytes p;
  append_u32(p, rule);
  append_u32(p, static_cast<std::uint32_t>(slopes.size()));
  append_f64(p, threshold);
  for (std::size_t k = 0; k < slopes.size(); ++k) {
    append_f64(p, slopes[k]);
    append_f64(p, offsets[k]);
  }
  return p;
}
const std::vector<double> kSlopes = {2.0, 0.5, 1.5};
const std::vector<double> kOffsets = {-1.0, 0.25, 0.0};
Bytes fixture_calibrated(const char* dtype, double threshold = 0.6,
                         const std::vector<double>& slopes = kSlopes,
                         const std::vector<double>& offsets = kOffsets, std::uint32_t rule = 1,
                         std::uint16_t version = 4) {
  return with_section_after_mach(as_version3(fixture(dtype)), "CALB",
                                 calb_payload(rule, threshold, slopes, offsets), version);
}
}  // namespace

TEST(ModelCalibration, AnOldFileKeepsThePapersRule) {
  const Bytes b = fixture("float64");
  const Model m = Model::from_bytes(b.data(), b.size());
  EXPECT_FALSE(m.calibrated());
  eskin::Classifier clf(m);
  eskin::Decision d;
  const std::vector<double> x = random_tensor(m, 1.0, 3);
  ASSERT_EQ(clf.classify_tensor(x.data(), &d), eskin::ClassifyStatus::kOk);
  EXPECT_TRUE(std::isnan(d.confidence));
  int claims = 0;
  for (int k = 0; k < 3; ++k) claims += d.values[k] > 0;
  EXPECT_EQ(d.dont_know, claims != 1);
}

// Label, confidence and flag equal the rule computed the plain way (p_k, q_k = p_k / sum p).
// Steep sigmoids centred on the fixture's values spread the confidences of random tensors; the
// threshold is their median, so both sides of it are exercised.
TEST(ModelCalibration, DecisionEqualsTheFormula) {
  const std::vector<double> slopes = {1000.0, 1000.0, 1000.0}, offsets = {100.6, -0.4, -100.6};
  for (const char* dtype : {"float32", "float64"}) {
    std::vector<std::vector<double>> xs;
    for (unsigned seed = 0; seed < 40; ++seed) {
      const Bytes b0 = fixture(dtype);
      xs.push_back(random_tensor(Model::from_bytes(b0.data(), b0.size()), 0.5 + 0.1 * seed, seed));
    }
    std::vector<double> conf;
    {
      const Bytes b = fixture_calibrated(dtype, 0.5, slopes, offsets);
      const Model m = Model::from_bytes(b.data(), b.size());
      eskin::Classifier clf(m);
      for (const auto& x : xs) {
        eskin::Decision d;
        ASSERT_EQ(clf.classify_tensor(x.data(), &d), eskin::ClassifyStatus::kOk);
        conf.push_back(d.confidence);
      }
    }
    std::vector<double> sorted = conf;
    std::sort(sorted.begin(), sorted.end());
    const double t = sorted[sorted.size() / 2];
    const Bytes b = fixture_calibrated(dtype, t, slopes, offsets);
    const Model m = Model::from_bytes(b.data(), b.size());
    ASSERT_TRUE(m.calibrated());
    EXPECT_EQ(m.format_version(), 4);
    EXPECT_EQ(m.reject_threshold(), t);
    eskin::Classifier clf(m);
    int flagged = 0, decided = 0;
    std::vector<int> labels(3, 0);
    for (const auto& x : xs) {
      eskin::Decision d;
      ASSERT_EQ(clf.classify_tensor(x.data(), &d), eskin::ClassifyStatus::kOk);
      double p[3], sum = 0.0;
      int best = 0;
      for (int k = 0; k < 3; ++k) {
        const auto kk = static_cast<std::size_t>(k);
        p[k] = 1.0 / (1.0 + std::exp(-(slopes[kk] * d.values[k] + offsets[kk])));
        sum += p[k];
        if (p[k] > p[best]) best = k;
      }
      EXPECT_EQ(d.label, best) << dtype;
      EXPECT_NEAR(d.confidence, p[best] / sum, 1e-12);
      if (std::fabs(p[best] / sum - t) > 1e-12) EXPECT_EQ(d.dont_know, p[best] / sum < t);
      (d.dont_know ? flagged : decided) += 1;
      labels[static_cast<std::size_t>(best)] += 1;
    }
    EXPECT_EQ(flagged, 20) << dtype;  // below the median of 40 distinct confidences
    EXPECT_EQ(decided, 20) << dtype;
    EXPECT_GT(sorted.back() - sorted.front(), 0.05) << dtype;
  }
}

TEST(ModelCalibration, ThresholdZeroNeverFlagsAndOneAlwaysFlags) {
  for (const double t : {0.0, 1.0}) {
    const Bytes b = fixture_calibrated("float64", t);
    const Model m = Model::from_bytes(b.data(), b.size());
    eskin::Classifier clf(m);
    for (unsigned seed = 0; seed < 10; ++seed) {
      const std::vector<double> x = random_tensor(m, 1.0, seed);
      eskin::Decision d;
      ASSERT_EQ(clf.classify_tensor(x.data(), &d), eskin::ClassifyStatus::kOk);
      EXPECT_GE(d.confidence, 1.0 / 3.0 - 1e-15);
      EXPECT_LE(d.confidence, 1.0);
      // confidence 1 exactly would not be flagged by t = 1; these inputs never reach it
      EXPECT_EQ(d.dont_know, t == 1.0) << seed;
    }
  }
}

TEST(ModelCalibration, ExtremeSlopesGiveAFiniteConfidence) {
  const Bytes b = fixture_calibrated("float64", 0.5, {1e6, 1e6, 1e6}, {-1e6, -1e6, -1e6});
  const Model m = Model::from_bytes(b.data(), b.size());
  eskin::Classifier clf(m);
  const std::vector<double> x = random_tensor(m, 1.0, 5);
  eskin::Decision d;
  ASSERT_EQ(clf.classify_tensor(x.data(), &d), eskin::ClassifyStatus::kOk);
  EXPECT_TRUE(std::isfinite(d.confidence));
  EXPECT_GE(d.confidence, 1.0 / 3.0 - 1e-15);
}

TEST(ModelCalibration, StreamDecidesAsBatchWithoutAllocating) {
  const Bytes b = fixture_calibrated("float32", 0.5);
  const Model m = Model::from_bytes(b.data(), b.size());
  eskin::Classifier clf(m);
  eskin::StreamClassifier sc(m);
  const std::int64_t T = 12000;
  const auto x = synthetic_recording(T, 4000, 7000, 2);
  eskin::Decision batch;
  ASSERT_EQ(clf.classify(x.data(), 4, 4, T, T, &batch), eskin::ClassifyStatus::kOk);
  std::int16_t sample[16];
  int decisions = 0;
  g_allocations = 0;
  g_counting = true;
  for (std::int64_t t = 0; t < T; ++t) {
    for (int k = 0; k < 16; ++k) sample[k] = x[static_cast<std::size_t>(k * T + t)];
    if (sc.push(sample) == eskin::ClassifyStatus::kDecision) {
      ++decisions;
      EXPECT_EQ(sc.decision().label, batch.label);
      EXPECT_EQ(sc.decision().dont_know, batch.dont_know);
      EXPECT_NEAR(sc.decision().confidence, batch.confidence, 1e-12);
    }
  }
  g_counting = false;
  EXPECT_EQ(g_allocations.load(), 0);
  EXPECT_EQ(decisions, 1);
  EXPECT_TRUE(std::isfinite(batch.confidence));
}

TEST(ModelCalibration, BadCalbSectionsAreRefusedNamingFieldAndValue) {
  const double nan = std::numeric_limits<double>::quiet_NaN();
  struct Case {
    Bytes bytes;
    ModelError code;
    std::string part;
  };
  const std::vector<Case> cases = {
      {fixture_calibrated("float64", 1.5), ModelError::kValue, "section CALB: threshold=1.5 must be within [0, 1]"},
      {fixture_calibrated("float64", nan), ModelError::kValue, "section CALB: threshold=nan"},
      {fixture_calibrated("float64", 0.5, {2.0, nan, 1.0}), ModelError::kValue,
       "section CALB: machine 1: slope=nan must be within [0, 1e+06]"},
      {fixture_calibrated("float64", 0.5, {2.0, -1.0, 1.0}), ModelError::kValue,
       "section CALB: machine 1: slope=-1 must be within [0, 1e+06]"},
      {fixture_calibrated("float64", 0.5, kSlopes, {0.0, 0.0, 2e6}), ModelError::kValue,
       "section CALB: machine 2: offset=2000000 must be finite"},
      {fixture_calibrated("float64", 0.5, {1.0, 1.0}, {0.0, 0.0}), ModelError::kValue,
       "section CALB: n_machines=2 differs from MACH's n_machines=3"},
      {fixture_calibrated("float64", 0.5, kSlopes, kOffsets, 2), ModelError::kValue,
       "section CALB: rule=2 is unknown"},
      {fixture_calibrated("float64", 0.5, kSlopes, kOffsets, 1, 3), ModelError::kLayout,
       "section 'CALB' (the calibrated decision rule) is not allowed in format version 3"},
  };
  for (const Case& c : cases) {
    EXPECT_EQ(load_error(c.bytes), c.code) << load_message(c.bytes);
    EXPECT_TRUE(says(load_message(c.bytes), c.part)) << load_message(c.bytes);
  }
  Bytes v4 = as_version3(fixture("float64"));  // version 4 without its CALB section
  v4[8] = 4;
  EXPECT_TRUE(says(refused(v4), "required section 'CALB' missing")) << refused(v4);
}

// ---- machines of different alpha in one model: each machine's distances come from its own
// cut of the bases (the decision tables group machines by alpha)

namespace {
// Where machine `k` of a float64 model starts in its MACH section.
std::size_t machine_offset(const Bytes& b, std::size_t k) {
  std::size_t pos = section_offset(b, "MACH") + 8;  // machine 0
  for (std::size_t i = 0; i < k; ++i) {
    // a machine (docs/model-format.md, MACH): 24 bytes of fields (n_terms at 8, intercept at
    // 16), three {u32 alpha, u32 reserved, f64 sigma}, then its n_terms indices (u32, padded
    // to 8) and coefficients (f64 in a float64 model)
    const std::uint32_t n_terms = get_u32(b, pos + 8);
    pos += 24 + 48 + (n_terms * 4 + 7) / 8 * 8 + n_terms * 8;
  }
  return pos;
}

// The fixture with machine `k`'s alpha of mode `z` set to `a` (the CRC fixed).
Bytes with_machine_alpha(Bytes b, std::size_t k, int z, std::uint32_t a) {
  put_u32(b, machine_offset(b, k) + 24 + 16 * static_cast<std::size_t>(z), a);
  fix_crc(b);
  return b;
}
}  // namespace

TEST(ModelDecision, MachinesOfDifferentAlphaEachUseTheirOwn) {
  const Bytes base = fixture("float64");
  const Model m0 = Model::from_bytes(base.data(), base.size());
  ASSERT_EQ(m0.machines().size(), 3u);
  // machine 0: alpha (1, 2, 4); machine 1: (2, 2, 4) as stored; machine 2: (2, 2, 3)
  const Bytes b = with_machine_alpha(with_machine_alpha(base, 0, 0, 1), 2, 2, 3);
  const Model m = Model::from_bytes(b.data(), b.size());
  ASSERT_EQ(m.machines()[0].alpha[0], 1);
  ASSERT_EQ(m.machines()[1].alpha[0], 2);
  ASSERT_EQ(m.machines()[2].alpha[2], 3);
  expect_hand_decisions(m, {3u, 4u});
}

// ---- the calibrated rule of a binary model: one machine, z = a f + b; the label is its
// positive class when z > 0 and its negative class otherwise, the confidence sigmoid(|z|)

TEST(ModelCalibration, ABinaryModelsDecisionEqualsTheFormula) {
  const Bytes v1 = read_file(std::string(ESKIN_TEST_DATA_DIR) + "/model_binary_float64.eskin");
  const Model plain = Model::from_bytes(v1.data(), v1.size());
  ASSERT_EQ(plain.rule(), eskin::DecisionRule::kBinary);
  ASSERT_EQ(plain.machines().size(), 1u);
  const int positive = plain.machines()[0].positive, negative = plain.machines()[0].negative;
  ASSERT_NE(positive, negative);
  // the machine's values on random tensors; a steep sigmoid centred on their median
  std::vector<std::vector<double>> xs;
  std::vector<double> f;
  eskin::Classifier c0(plain);
  for (unsigned seed = 0; seed < 30; ++seed) {
    xs.push_back(random_tensor(plain, 0.5 + 0.1 * seed, 100 + seed));
    eskin::Decision d;
    ASSERT_EQ(c0.classify_tensor(xs.back().data(), &d), eskin::ClassifyStatus::kOk);
    f.push_back(d.values[0]);
  }
  std::vector<double> sorted = f;
  std::sort(sorted.begin(), sorted.end());
  const double centre = 0.5 * (sorted[14] + sorted[15]);
  const double slope = 20.0 / (sorted.back() - sorted.front()), offset = -slope * centre;
  const double threshold = 0.9;
  const Bytes b = with_section_after_mach(as_version3(v1), "CALB",
                                          calb_payload(1, threshold, {slope}, {offset}), 4);
  const Model m = Model::from_bytes(b.data(), b.size());
  ASSERT_TRUE(m.calibrated());
  eskin::Classifier clf(m);
  int pos = 0, neg = 0, flagged = 0;
  for (std::size_t i = 0; i < xs.size(); ++i) {
    eskin::Decision d;
    ASSERT_EQ(clf.classify_tensor(xs[i].data(), &d), eskin::ClassifyStatus::kOk);
    EXPECT_EQ(d.values[0], f[i]);
    const double z = slope * f[i] + offset;
    EXPECT_EQ(d.label, z > 0 ? positive : negative) << i;
    EXPECT_NEAR(d.confidence, 1.0 / (1.0 + std::exp(-std::fabs(z))), 1e-12) << i;
    EXPECT_EQ(d.dont_know, d.confidence < threshold) << i;
    (z > 0 ? pos : neg) += 1;
    flagged += d.dont_know;
  }
  EXPECT_EQ(pos, 15);  // both labels, and both sides of the threshold
  EXPECT_EQ(neg, 15);
  EXPECT_GT(flagged, 0);
  EXPECT_LT(flagged, 30);
}

// ---- the projection route: a time mode (N = 16 rows) cut to alpha 5 and 6 uses the cached
// projections P = V V^T on the host (N < alpha^2); tests/data/model_projection_*.eskin, two
// machines of different alpha

TEST(ModelDecision, TheProjectionRouteEqualsTheHandComputation) {
  const Bytes b = read_file(std::string(ESKIN_TEST_DATA_DIR) + "/model_projection_float64.eskin");
  const Model m = Model::from_bytes(b.data(), b.size());
  ASSERT_EQ(m.machines().size(), 2u);
  ASSERT_EQ(m.basis_rows(2), 16);
  ASSERT_EQ(m.machines()[0].alpha[2], 5);
  ASSERT_EQ(m.machines()[1].alpha[2], 6);
  expect_hand_decisions(m, {1u, 2u, 3u});
  eskin::Classifier clf(m);
  // the float32 model of the same description decides as the float64 one, to float precision
  const Bytes b32 = read_file(std::string(ESKIN_TEST_DATA_DIR) + "/model_projection_float32.eskin");
  const Model m32 = Model::from_bytes(b32.data(), b32.size());
  eskin::Classifier c32(m32);
  const std::vector<double> x = random_tensor(m, 1.0, 9);
  eskin::Decision d64, d32;
  ASSERT_EQ(clf.classify_tensor(x.data(), &d64), eskin::ClassifyStatus::kOk);
  ASSERT_EQ(c32.classify_tensor(x.data(), &d32), eskin::ClassifyStatus::kOk);
  for (int k = 0; k < 2; ++k) EXPECT_NEAR(d32.values[k], d64.values[k], 1e-4) << "machine " << k;
}

// An input that is not finite is refused as such (not as a kernel failure), and the classifier
// decides the next input as if it had not seen it.
TEST(ModelDecision, ANonFiniteInputIsRefusedAsNotFinite) {
  const Bytes b = fixture("float64");
  const Model m = Model::from_bytes(b.data(), b.size());
  eskin::Classifier clf(m);
  const std::vector<double> x = random_tensor(m, 1.0, 21);
  eskin::Decision want;
  ASSERT_EQ(clf.classify_tensor(x.data(), &want), eskin::ClassifyStatus::kOk);
  const std::vector<double> want_values(want.values, want.values + 3);
  const double inf = std::numeric_limits<double>::infinity();
  for (const double bad : {std::numeric_limits<double>::quiet_NaN(), inf, -inf}) {
    std::vector<double> y = x;
    y[y.size() / 2] = bad;
    eskin::Decision d;
    EXPECT_EQ(clf.classify_tensor(y.data(), &d), eskin::ClassifyStatus::kNotFinite) << bad;
    ASSERT_EQ(clf.classify_tensor(x.data(), &d), eskin::ClassifyStatus::kOk);
    for (int k = 0; k < 3; ++k) EXPECT_EQ(d.values[k], want_values[static_cast<std::size_t>(k)]);
  }
}

// The smallest recording is one sample (the subsampling pads it to the model's D): a decision,
// not a bad shape; a recording with no touch falls back to the whole recording (the fixture's
// fallback, "whole"), flagged window_found = false.
TEST(ModelClassify, ARecordingOfOneSampleIsDecided) {
  const Bytes b = fixture("float64");
  const Model m = Model::from_bytes(b.data(), b.size());
  eskin::Classifier clf(m);
  std::vector<double> one(16, 0.0);
  for (int k = 0; k < 16; ++k) one[static_cast<std::size_t>(k)] = 100.0 * k - 700.0;
  eskin::Decision d;
  ASSERT_EQ(clf.classify(one.data(), 4, 4, 1, 1, &d), eskin::ClassifyStatus::kOk);
  EXPECT_EQ(d.window_start, 0);
  EXPECT_EQ(d.window_stop, 1);
  // the first sample of a longer recording, as a recording of one sample
  const auto x = synthetic_recording(9000, 3000, 6000, 1);
  ASSERT_EQ(clf.classify(x.data(), 4, 4, 9000, 1, &d), eskin::ClassifyStatus::kOk);
  EXPECT_EQ(d.window_stop, 1);
  EXPECT_EQ(clf.classify(x.data(), 4, 4, 0, 0, &d), eskin::ClassifyStatus::kBadShape);
  EXPECT_EQ(clf.classify(x.data(), 4, 4, 9000, 9001, &d), eskin::ClassifyStatus::kBadShape);
}

TEST(ModelClassify, NoTouchFallsBackToTheWholeRecording) {
  const Bytes b = fixture("float64");
  const Model m = Model::from_bytes(b.data(), b.size());
  ASSERT_EQ(m.window_config().fallback, 0.0);  // "whole"
  eskin::Classifier clf(m);
  const std::vector<double> quiet(16 * 3000, 0.0);
  eskin::Decision d;
  ASSERT_EQ(clf.classify(quiet.data(), 4, 4, 3000, 3000, &d), eskin::ClassifyStatus::kOk);
  EXPECT_FALSE(d.window_found);
  EXPECT_EQ(d.window_start, 0);
  EXPECT_EQ(d.window_stop, 3000);
}

// "Don't know" is a confidence strictly below the threshold: a confidence equal to it, to the
// bit, is a decision.
TEST(ModelCalibration, AConfidenceEqualToTheThresholdIsDecided) {
  const std::vector<double> x = random_tensor(
      [] { const Bytes b0 = fixture("float64"); return Model::from_bytes(b0.data(), b0.size()); }(),
      1.0, 17);
  double c = 0.0;
  {
    const Bytes b = fixture_calibrated("float64", 0.0);
    const Model m = Model::from_bytes(b.data(), b.size());
    eskin::Classifier clf(m);
    eskin::Decision d;
    ASSERT_EQ(clf.classify_tensor(x.data(), &d), eskin::ClassifyStatus::kOk);
    c = d.confidence;
  }
  ASSERT_GT(c, 0.0);
  ASSERT_LT(c, 1.0);
  const Bytes at = fixture_calibrated("float64", c);
  const Model m = Model::from_bytes(at.data(), at.size());
  ASSERT_EQ(m.reject_threshold(), c);
  eskin::Classifier clf(m);
  eskin::Decision d;
  ASSERT_EQ(clf.classify_tensor(x.data(), &d), eskin::ClassifyStatus::kOk);
  EXPECT_EQ(d.confidence, c);
  EXPECT_FALSE(d.dont_know);
  const Bytes above = fixture_calibrated("float64", std::nextafter(c, 1.0));
  const Model ma = Model::from_bytes(above.data(), above.size());
  eskin::Classifier ca(ma);
  ASSERT_EQ(ca.classify_tensor(x.data(), &d), eskin::ClassifyStatus::kOk);
  EXPECT_TRUE(d.dont_know);
}

// The log energy of the first n values only: log(mean square + 1e-12).
TEST(ModelAmplitude, TheLogEnergyReadsExactlyItsValues) {
  const double x[4] = {1.0, 2.0, 3.0, 100.0};
  EXPECT_DOUBLE_EQ(eskin::tensor_log_energy(x, 3), std::log(14.0 / 3.0 + 1e-12));
  EXPECT_DOUBLE_EQ(eskin::tensor_log_energy(x + 3, 1), std::log(10000.0 + 1e-12));
  EXPECT_DOUBLE_EQ(eskin::tensor_log_energy(x, 0), std::log(1e-12));
}

// The paper's rule on a binary model: the machine's positive class when f > 0, its negative
// class otherwise, never "don't know", no confidence. The fixture's intercept is moved so that
// its values on random tensors fall on both sides of 0, some of them in (0, 1).
TEST(ModelClassify, ABinaryModelsPaperRuleIsTheSignOfItsMachine) {
  const Bytes b0 = read_file(std::string(ESKIN_TEST_DATA_DIR) + "/model_binary_float64.eskin");
  const Model m0 = Model::from_bytes(b0.data(), b0.size());
  ASSERT_FALSE(m0.calibrated());
  std::vector<std::vector<double>> xs;
  std::vector<double> f0;
  {
    eskin::Classifier c0(m0);
    for (unsigned seed = 0; seed < 40; ++seed) {
      xs.push_back(random_tensor(m0, 0.5 + 0.1 * seed, 200 + seed));
      eskin::Decision d;
      ASSERT_EQ(c0.classify_tensor(xs.back().data(), &d), eskin::ClassifyStatus::kOk);
      f0.push_back(d.values[0] - m0.machines()[0].intercept);
    }
  }
  std::vector<double> sorted = f0;
  std::sort(sorted.begin(), sorted.end());
  // intercept: minus the median, plus a quarter of the spread (values in (0, 1) when it is < 4)
  const double intercept = -0.5 * (sorted[19] + sorted[20]) + 0.25 * (sorted.back() - sorted.front());
  Bytes b = b0;
  const std::size_t at = section_offset(b, "MACH") + 8 + 16;  // machine 0's intercept
  std::uint64_t u;
  std::memcpy(&u, &intercept, 8);
  for (int k = 0; k < 8; ++k) b[at + static_cast<std::size_t>(k)] = static_cast<std::uint8_t>(u >> (8 * k));
  fix_crc(b);
  const Model m = Model::from_bytes(b.data(), b.size());
  ASSERT_EQ(m.machines()[0].intercept, intercept);
  eskin::Classifier clf(m);
  int pos = 0, neg = 0, small = 0;
  for (const auto& x : xs) {
    eskin::Decision d;
    ASSERT_EQ(clf.classify_tensor(x.data(), &d), eskin::ClassifyStatus::kOk);
    const double f = d.values[0];
    EXPECT_EQ(d.label, f > 0 ? 1 : 0) << f;
    EXPECT_FALSE(d.dont_know);
    EXPECT_TRUE(std::isnan(d.confidence));
    (f > 0 ? pos : neg) += 1;
    small += f > 0 && f < 1;
  }
  EXPECT_GT(pos, 0);
  EXPECT_GT(neg, 0);
  EXPECT_GT(small, 0);  // values in (0, 1): the sign decides, not a threshold of 1
}

// A model without the touch detector (window "none") checks every sample of every taxel itself:
// a NaN the subsampling would not pick is still refused.
TEST(ModelClassify, WithoutTheDetectorEveryTaxelsSamplesAreChecked) {
  const Bytes b = read_file(std::string(ESKIN_TEST_DATA_DIR) + "/model_binary_float64.eskin");
  const Model m = Model::from_bytes(b.data(), b.size());
  ASSERT_NE(m.window_mode(), eskin::WindowMode::kEnergy);
  eskin::Classifier clf(m);
  const std::int64_t T = 101;
  const std::size_t n_taxels = static_cast<std::size_t>(m.rows() * m.cols());
  std::vector<double> x(n_taxels * static_cast<std::size_t>(T));
  for (std::size_t i = 0; i < x.size(); ++i) x[i] = std::sin(0.37 * static_cast<double>(i));
  eskin::Decision d;
  ASSERT_EQ(clf.classify(x.data(), m.rows(), m.cols(), T, T, &d), eskin::ClassifyStatus::kOk);
  for (const std::size_t taxel : {std::size_t{0}, n_taxels - 1}) {
    for (const std::int64_t t : {std::int64_t{0}, std::int64_t{1}, T - 2, T - 1}) {
      std::vector<double> y = x;
      y[taxel * static_cast<std::size_t>(T) + static_cast<std::size_t>(t)] = NAN;
      EXPECT_EQ(clf.classify(y.data(), m.rows(), m.cols(), T, T, &d), eskin::ClassifyStatus::kNotFinite)
          << "taxel " << taxel << " sample " << t;
    }
  }
}

// The batch classifier's detector sees every sample from the first: a touch that starts on a
// frame boundary (10 ms = 30 samples at 3 kHz) is found at the same sample as by the stream
// classifier, which is handed the samples one by one.
TEST(ModelStream, ATouchOnAFrameBoundaryHasTheSameWindowInBatchAndStream) {
  const Bytes b = fixture("float64");
  const Model m = Model::from_bytes(b.data(), b.size());
  const std::int64_t T = 9000;
  for (const std::int64_t on : {std::int64_t{2970}, std::int64_t{3000}, std::int64_t{3030}}) {
    const auto x = synthetic_recording(T, on, on + 2400, 3);
    eskin::Classifier clf(m);
    eskin::Decision batch;
    ASSERT_EQ(clf.classify(x.data(), 4, 4, T, T, &batch), eskin::ClassifyStatus::kOk);
    ASSERT_TRUE(batch.window_found);
    eskin::StreamClassifier sc(m);
    std::int16_t sample[16];
    int decisions = 0;
    for (std::int64_t t = 0; t < T; ++t) {
      for (int k = 0; k < 16; ++k) sample[k] = x[static_cast<std::size_t>(k * T + t)];
      if (sc.push(sample) == eskin::ClassifyStatus::kDecision) {
        ++decisions;
        EXPECT_EQ(sc.decision().window_start, batch.window_start) << "touch at " << on;
        EXPECT_EQ(sc.decision().window_stop, batch.window_stop) << "touch at " << on;
      }
    }
    EXPECT_EQ(decisions, 1) << "touch at " << on;
  }
}

// With the fallback "error" (PREP field fallback = 1) a recording with no touch is refused.
TEST(ModelClassify, NoTouchWithTheFallbackErrorIsRefused) {
  Bytes b = fixture("float64");
  const std::string name = "fallback";
  const auto it = std::search(b.begin(), b.end(), name.begin(), name.end());
  ASSERT_NE(it, b.end());
  const std::size_t at = static_cast<std::size_t>(it - b.begin()) + 32;  // its f64 value
  const double one = 1.0;
  std::uint64_t u;
  std::memcpy(&u, &one, 8);
  for (int k = 0; k < 8; ++k) b[at + static_cast<std::size_t>(k)] = static_cast<std::uint8_t>(u >> (8 * k));
  fix_crc(b);
  const Model m = Model::from_bytes(b.data(), b.size());
  ASSERT_EQ(m.window_config().fallback, 1.0);
  eskin::Classifier clf(m);
  const std::vector<double> quiet(16 * 3000, 0.0);
  eskin::Decision d;
  EXPECT_EQ(clf.classify(quiet.data(), 4, 4, 3000, 3000, &d), eskin::ClassifyStatus::kNoTouch);
  const auto x = synthetic_recording(9000, 3000, 6000, 1);
  EXPECT_EQ(clf.classify(x.data(), 4, 4, 9000, 9000, &d), eskin::ClassifyStatus::kOk);
}

// Without the detector, only the first `length` samples of each taxel are checked: a NaN just
// past them is not the recording's.
TEST(ModelClassify, WithoutTheDetectorASamplePastTheLengthIsNotChecked) {
  const Bytes b = read_file(std::string(ESKIN_TEST_DATA_DIR) + "/model_binary_float64.eskin");
  const Model m = Model::from_bytes(b.data(), b.size());
  eskin::Classifier clf(m);
  const std::int64_t T = 101;
  const std::size_t n_taxels = static_cast<std::size_t>(m.rows() * m.cols());
  std::vector<double> x(n_taxels * static_cast<std::size_t>(T));
  for (std::size_t i = 0; i < x.size(); ++i) x[i] = std::sin(0.37 * static_cast<double>(i));
  for (std::size_t k = 0; k < n_taxels; ++k) x[k * static_cast<std::size_t>(T) + static_cast<std::size_t>(T - 1)] = NAN;
  eskin::Decision d;
  EXPECT_EQ(clf.classify(x.data(), m.rows(), m.cols(), T, T - 1, &d), eskin::ClassifyStatus::kOk);
  EXPECT_EQ(clf.classify(x.data(), m.rows(), m.cols(), T, T, &d), eskin::ClassifyStatus::kNotFinite);
}

// ---- the rules on exact values: every sigma at its smallest (1e-6) makes each kernel term
// exp(-d / 2e-12) underflow to 0 for a random input (its distances are far above 1e-9), so each
// machine's value is its intercept, exactly; the rules are then checked on values chosen by hand
// (docs/model-format.md, "Decision").

namespace {
// A float64 model whose machine k's value is intercepts[k] on a random input.
Bytes with_values(Bytes b, const std::vector<double>& intercepts) {
  for (std::size_t k = 0; k < intercepts.size(); ++k) {
    const std::size_t at = machine_offset(b, k);
    put_f64(b, at + 16, intercepts[k]);
    for (std::size_t z = 0; z < 3; ++z) put_f64(b, at + 24 + 16 * z + 8, 1e-6);
  }
  fix_crc(b);
  return b;
}
}  // namespace

// One-vs-all, paper's rule: exactly one f > 0 claims (0 is no claim); otherwise the largest f,
// the first of equal ones, flagged "don't know".
TEST(ModelClassify, ThePapersRuleOnExactValuesClaimsAboveZeroAndTakesTheFirstOfTies) {
  struct Case {
    std::vector<double> f;
    int label;
    bool dont_know;
  };
  const std::vector<Case> cases = {
      {{2.0, 2.0, 1.0}, 0, true},     // three claims, the first of the two largest
      {{1.0, 2.0, 2.0}, 1, true},
      {{0.0, 0.5, -1.0}, 1, false},   // f = 0 does not claim: machine 1 alone does
      {{0.5, 0.0, 0.0}, 0, false},
      {{0.0, 0.0, 0.0}, 0, true},     // no claim, all equal: the first
      {{-3.0, -1.0, -1.0}, 1, true},  // no claim: the largest, the first of two
  };
  for (const Case& c : cases) {
    const Bytes b = with_values(fixture("float64"), c.f);
    const Model m = Model::from_bytes(b.data(), b.size());
    ASSERT_FALSE(m.calibrated());
    eskin::Classifier clf(m);
    const std::vector<double> x = random_tensor(m, 1.0, 31);
    eskin::Decision d;
    ASSERT_EQ(clf.classify_tensor(x.data(), &d), eskin::ClassifyStatus::kOk);
    for (std::size_t k = 0; k < 3; ++k) ASSERT_EQ(d.values[k], c.f[k]) << "machine " << k;
    EXPECT_EQ(d.label, c.label) << c.f[0] << " " << c.f[1] << " " << c.f[2];
    EXPECT_EQ(d.dont_know, c.dont_know) << c.f[0] << " " << c.f[1] << " " << c.f[2];
  }
}

// Binary, paper's rule: f = 0 is the negative class, the smallest f > 0 the positive one.
TEST(ModelClassify, ABinaryModelsValueOfZeroIsItsNegativeClass) {
  const Bytes v = read_file(std::string(ESKIN_TEST_DATA_DIR) + "/model_binary_float64.eskin");
  for (const double f : {0.0, std::numeric_limits<double>::denorm_min(), -0.0}) {
    const Bytes b = with_values(v, {f});
    const Model m = Model::from_bytes(b.data(), b.size());
    eskin::Classifier clf(m);
    const std::vector<double> x = random_tensor(m, 1.0, 32);
    eskin::Decision d;
    ASSERT_EQ(clf.classify_tensor(x.data(), &d), eskin::ClassifyStatus::kOk);
    ASSERT_EQ(d.values[0], f);
    const auto& mm = m.machines()[0];
    EXPECT_EQ(d.label, f > 0 ? mm.positive : mm.negative) << f;
    EXPECT_FALSE(d.dont_know);
  }
}

// The calibrated rule on equal calibrated scores (slopes 0: l_k = ls(b_k) whatever f): the
// first of the largest; a binary model's z = 0 is its negative class with confidence 1/2.
TEST(ModelCalibration, EqualScoresGiveTheFirstClassAndZeroTheNegativeOne) {
  const auto sigmoid = [](double z) { return 1.0 / (1.0 + std::exp(-z)); };
  struct Case {
    std::vector<double> offsets;
    int label;
  };
  for (const Case& c : {Case{{1.0, 1.0, -1.0}, 0}, Case{{-1.0, 1.0, 1.0}, 1},
                        Case{{0.0, 0.0, 0.0}, 0}}) {
    const Bytes b = fixture_calibrated("float64", 0.4, {0.0, 0.0, 0.0}, c.offsets);
    const Model m = Model::from_bytes(b.data(), b.size());
    eskin::Classifier clf(m);
    const std::vector<double> x = random_tensor(m, 1.0, 33);
    eskin::Decision d;
    ASSERT_EQ(clf.classify_tensor(x.data(), &d), eskin::ClassifyStatus::kOk);
    EXPECT_EQ(d.label, c.label) << c.offsets[0];
    double sum = 0.0;
    for (const double o : c.offsets) sum += sigmoid(o);
    const double q = sigmoid(c.offsets[static_cast<std::size_t>(c.label)]) / sum;
    EXPECT_NEAR(d.confidence, q, 1e-15);
    EXPECT_EQ(d.dont_know, q < 0.4);
  }
  const Bytes v1 = read_file(std::string(ESKIN_TEST_DATA_DIR) + "/model_binary_float64.eskin");
  const Bytes b = with_section_after_mach(as_version3(v1), "CALB", calb_payload(1, 0.6, {0.0}, {0.0}), 4);
  const Model m = Model::from_bytes(b.data(), b.size());
  eskin::Classifier clf(m);
  const std::vector<double> x = random_tensor(m, 1.0, 34);
  eskin::Decision d;
  ASSERT_EQ(clf.classify_tensor(x.data(), &d), eskin::ClassifyStatus::kOk);
  EXPECT_EQ(d.label, m.machines()[0].negative);
  EXPECT_EQ(d.confidence, 0.5);
  EXPECT_TRUE(d.dont_know);
}

// A missing input or output is refused as such, by every entry point, whichever is missing.
TEST(ModelClassify, ANullInputOrOutputIsRefused) {
  const Bytes b = fixture("float64");
  const Model m = Model::from_bytes(b.data(), b.size());
  eskin::Classifier clf(m);
  const std::vector<double> x = random_tensor(m, 1.0, 35);
  const std::vector<double> raw(16 * 100, 1.0);
  const std::vector<float> raw32(raw.begin(), raw.end());
  const std::vector<std::int16_t> raw16(raw.size(), 1);
  eskin::Decision d;
  const auto null = eskin::ClassifyStatus::kNullPointer;
  EXPECT_EQ(clf.classify_tensor(nullptr, &d), null);
  EXPECT_EQ(clf.classify_tensor(x.data(), nullptr), null);
  EXPECT_EQ(clf.classify(static_cast<const double*>(nullptr), 4, 4, 100, 100, &d), null);
  EXPECT_EQ(clf.classify(raw.data(), 4, 4, 100, 100, nullptr), null);
  EXPECT_EQ(clf.classify(static_cast<const float*>(nullptr), 4, 4, 100, 100, &d), null);
  EXPECT_EQ(clf.classify(raw32.data(), 4, 4, 100, 100, nullptr), null);
  EXPECT_EQ(clf.classify(static_cast<const std::int16_t*>(nullptr), 4, 4, 100, 100, &d), null);
  EXPECT_EQ(clf.classify(raw16.data(), 4, 4, 100, 100, nullptr), null);
  ASSERT_EQ(clf.classify_tensor(x.data(), &d), eskin::ClassifyStatus::kOk);  // still usable
  eskin::StreamClassifier sc(m);
  EXPECT_EQ(sc.push(static_cast<const double*>(nullptr)), null);
  EXPECT_EQ(sc.push(static_cast<const float*>(nullptr)), null);
  EXPECT_EQ(sc.push(static_cast<const std::int16_t*>(nullptr)), null);
}

// Each shape check stands alone: a wrong row count, a wrong column count, no samples, a length
// of 0 or past T, each by itself, is a bad shape.
TEST(ModelClassify, EachShapeCheckRefusesOnItsOwn) {
  const Bytes b = fixture("float64");
  const Model m = Model::from_bytes(b.data(), b.size());
  eskin::Classifier clf(m);
  const std::vector<double> x(5 * 5 * 200, 1.0);
  eskin::Decision d;
  const auto bad = eskin::ClassifyStatus::kBadShape;
  EXPECT_EQ(clf.classify(x.data(), 5, 4, 200, 200, &d), bad);
  EXPECT_EQ(clf.classify(x.data(), 4, 5, 200, 200, &d), bad);
  EXPECT_EQ(clf.classify(x.data(), 4, 4, 0, 0, &d), bad);
  EXPECT_EQ(clf.classify(x.data(), 4, 4, 200, 0, &d), bad);
  EXPECT_EQ(clf.classify(x.data(), 4, 4, 200, -1, &d), bad);
  EXPECT_EQ(clf.classify(x.data(), 4, 4, 200, 201, &d), bad);
  EXPECT_EQ(clf.classify(x.data(), 4, 4, 200, 200, &d), eskin::ClassifyStatus::kOk);
}

// A grid that is not square, with each mode kept to its own alpha (stored 3, 4, 5): every
// mode's bases, the input's and the support vectors', are laid out by their own alpha
// (tests/data/model_uneven_float64.eskin).
TEST(ModelDecision, AnUnevenGridWithItsOwnAlphaPerModeEqualsTheHandComputation) {
  const Bytes b = read_file(std::string(ESKIN_TEST_DATA_DIR) + "/model_uneven_float64.eskin");
  const Model m = Model::from_bytes(b.data(), b.size());
  ASSERT_EQ(m.rows(), 3);
  ASSERT_EQ(m.cols(), 5);
  ASSERT_EQ(m.alpha_store(0), 3);
  ASSERT_EQ(m.alpha_store(1), 4);
  ASSERT_EQ(m.alpha_store(2), 5);
  expect_hand_decisions(m, {41u, 42u});
}

// A model whose short policy is "error" refuses a recording whose window is shorter than D
// (window mode "none": the window is the whole recording) as too short; one of D samples is
// decided. The default policy ("interpolate") decides both.
TEST(ModelClassify, AWindowShorterThanDIsTooShortUnderTheErrorPolicy) {
  const Bytes good = fixture("float64");
  const std::size_t prep = section_offset(good, "PREP");
  for (const std::uint32_t policy : {0u, 1u}) {
    Bytes b = good;
    put_u32(b, prep + 12, 1);  // window mode none
    put_u32(b, prep + 20, policy);
    fix_crc(b);
    const Model m = Model::from_bytes(b.data(), b.size());
    ASSERT_EQ(m.D(), 8);
    eskin::Classifier clf(m);
    std::mt19937 rng(5);
    std::normal_distribution<double> g(0.0, 100.0);
    std::vector<double> x(16 * 8);
    for (double& v : x) v = g(rng);
    eskin::Decision d;
    EXPECT_EQ(clf.classify(x.data(), 4, 4, 8, 8, &d), eskin::ClassifyStatus::kOk) << policy;
    EXPECT_EQ(clf.classify(x.data(), 4, 4, 8, 5, &d),
              policy == 1 ? eskin::ClassifyStatus::kTooShort : eskin::ClassifyStatus::kOk)
        << policy;
  }
}

namespace {

// The statuses other than kOk that a stream classifier reports for 3 s of noise (sd 5) at
// 3 kHz with a 1 s burst of `amplitude` on taxel 5 from t = 1 s.
std::vector<eskin::ClassifyStatus> burst_statuses(eskin::StreamClassifier& sc, double amplitude) {
  std::mt19937 rng(3);
  std::normal_distribution<double> g(0.0, 5.0);
  std::vector<eskin::ClassifyStatus> seen;
  double sample[16];
  for (int t = 0; t < 9000; ++t) {
    for (double& v : sample) v = g(rng);
    if (t >= 3000 && t < 4000) sample[5] += amplitude * std::sin(t / 3.0);
    const eskin::ClassifyStatus st = sc.push(sample);
    if (st != eskin::ClassifyStatus::kOk) seen.push_back(st);
  }
  return seen;
}

}  // namespace

// The stream classifier under a model whose short policy is "error": touch windows cut to at
// most 6 samples (max_window_s; frames of 2 samples, no lookback, no padding), shorter than
// D = 8, are reported too short, not decided; under "interpolate" the same touches are decided.
TEST(ModelStream, ATouchShorterThanDIsTooShortUnderTheErrorPolicy) {
  const Bytes good = fixture("float64");
  const std::size_t prep = section_offset(good, "PREP");
  for (const std::uint32_t policy : {0u, 1u}) {
    Bytes b = good;
    put_u32(b, prep + 20, policy);
    put_f64(b, window_field_offset(b, "frame_s"), 2.0 / 3000.0);
    put_f64(b, window_field_offset(b, "max_window_s"), 6.0 / 3000.0);
    for (const char* name : {"pad_before_s", "pad_after_s", "min_duration_s", "lookback_s"})
      put_f64(b, window_field_offset(b, name), 0.0);
    fix_crc(b);
    const Model m = Model::from_bytes(b.data(), b.size());
    ASSERT_EQ(m.D(), 8);
    eskin::StreamClassifier sc(m);
    const std::vector<eskin::ClassifyStatus> seen = burst_statuses(sc, 1e3);
    ASSERT_FALSE(seen.empty()) << policy;
    for (const auto st : seen)
      EXPECT_EQ(st, policy == 1 ? eskin::ClassifyStatus::kTooShort
                                : eskin::ClassifyStatus::kDecision) << policy;
    if (policy == 0) EXPECT_LE(sc.decision().window_stop - sc.decision().window_start, 6);
  }
}

// A touch whose tensor the kernel cannot take (a burst of 1e150: the pattern's energy
// overflows) is reported as not finite, not as a decision; the same burst at 1e3 is decided.
TEST(ModelStream, ATouchTheKernelCannotTakeIsReportedNotFiniteNotDecided) {
  const Bytes b = fixture("float64");
  const Model m = Model::from_bytes(b.data(), b.size());
  for (const double amplitude : {1e3, 1e150}) {
    eskin::StreamClassifier sc(m);
    const std::vector<eskin::ClassifyStatus> seen = burst_statuses(sc, amplitude);
    ASSERT_FALSE(seen.empty()) << amplitude;
    EXPECT_EQ(seen.front(), amplitude < 1e100 ? eskin::ClassifyStatus::kDecision
                                              : eskin::ClassifyStatus::kNotFinite)
        << amplitude;
  }
}

// A pattern at distance 0 from a support vector in every mode: the fixture's support vector 1
// (full rank in each mode) given the bases of a random tensor, which is then classified. Its
// term is its coefficient times exp(0), as the hand computation has it; every mode here takes
// the overlap route (N >= alpha^2), whose rounding can leave a distance just below 0. In a
// float32 model the bases are stored rounded to float (the hand computation reads the same
// stored values), and the overlaps are summed in float.
namespace {
void expect_a_support_vectors_bases_at_distance_zero(const char* dtype, double tol) {
  Bytes b = fixture(dtype);
  const bool f64 = std::string(dtype) == "float64";
  const std::size_t A[3] = {2, 2, 4};
  std::vector<double> x, xb;
  int rx[3];
  {
    const Model view = Model::view_bytes(b.data(), b.size());
    for (int z = 0; z < 3; ++z) {
      ASSERT_EQ(view.alpha_store(z), static_cast<int>(A[z]));
      ASSERT_EQ(view.rank(1, z), static_cast<int>(A[z]));
      ASSERT_GE(static_cast<std::size_t>(view.basis_rows(z)), A[z] * A[z]);  // no projection
    }
    x = random_tensor(view, 1.0, 61);
    eskin::BasisLayout layout({4, 4, static_cast<std::size_t>(view.D())}, {A[0], A[1], A[2]});
    eskin::BasisWorkspace ws(layout);
    xb.resize(layout.bases_size());
    ASSERT_EQ(ws.compute(x.data(), xb.data(), rx), eskin::KernelStatus::ok);
    for (int z = 0; z < 3; ++z) {
      ASSERT_EQ(rx[z], static_cast<int>(A[z]));
      const std::size_t N = static_cast<std::size_t>(view.basis_rows(z));
      // support vector 1's bases of mode z, in the file's bytes (view_bytes reads in place)
      const std::uint8_t* sv1 =
          f64 ? reinterpret_cast<const std::uint8_t*>(view.bases_f64(z) + A[z] * N)
              : reinterpret_cast<const std::uint8_t*>(view.bases_f32(z) + A[z] * N);
      const std::size_t at = static_cast<std::size_t>(sv1 - b.data());
      for (std::size_t k = 0; k < A[z] * N; ++k) {
        const double v = xb[layout.offset(static_cast<std::size_t>(z)) + k];
        if (f64) {
          put_f64(b, at + 8 * k, v);
        } else {
          const float f = static_cast<float>(v);
          std::uint32_t u;
          std::memcpy(&u, &f, sizeof u);
          put_u32(b, at + 4 * k, u);
        }
      }
    }
  }
  fix_crc(b);
  const Model m = Model::from_bytes(b.data(), b.size());
  const std::vector<double> want = hand_decision(m, x);
  eskin::Classifier clf(m);
  eskin::Decision d;
  ASSERT_EQ(clf.classify_tensor(x.data(), &d), eskin::ClassifyStatus::kOk);
  int with_sv1 = 0;
  for (std::size_t k = 0; k < m.machines().size(); ++k) {
    EXPECT_NEAR(d.values[k], want[k], tol) << dtype << " machine " << k;
    const auto& idx = m.machines()[k].sv_index;
    with_sv1 += std::find(idx.begin(), idx.end(), 1u) != idx.end();
  }
  EXPECT_GT(with_sv1, 0);  // some machine has the term
}
}  // namespace

TEST(ModelDecision, APatternWithASupportVectorsBasesIsAtDistanceZeroFromIt) {
  expect_a_support_vectors_bases_at_distance_zero("float64", 1e-12);
}

TEST(ModelDecision, APatternWithASupportVectorsFloatBasesIsAtDistanceZeroFromIt) {
  expect_a_support_vectors_bases_at_distance_zero("float32", 1e-4);
}

// ---- the loader on the edges of its layout: a machine of one term, an empty ancillary section
// last, a CALB section cut inside its fixed fields

namespace {
// The float64 fixture with machine `k` cut to its first `keep` terms (indices and coefficients),
// the MACH section, the file size and the CRC fixed.
Bytes with_machine_terms(const Bytes& b, std::size_t k, std::uint32_t keep) {
  const std::size_t at = machine_offset(b, k);
  const std::uint32_t n_terms = get_u32(b, at + 8);
  const std::size_t idx = at + 72, coef = idx + (std::size_t{n_terms} * 4 + 7) / 8 * 8;
  Bytes machine(b.begin() + static_cast<std::ptrdiff_t>(at), b.begin() + static_cast<std::ptrdiff_t>(idx));
  put_u32(machine, 8, keep);
  machine.insert(machine.end(), b.begin() + static_cast<std::ptrdiff_t>(idx),
                 b.begin() + static_cast<std::ptrdiff_t>(idx + 4 * keep));
  machine.resize((machine.size() + 7) / 8 * 8, 0);
  machine.insert(machine.end(), b.begin() + static_cast<std::ptrdiff_t>(coef),
                 b.begin() + static_cast<std::ptrdiff_t>(coef + 8 * keep));
  const std::size_t end = coef + 8 * std::size_t{n_terms};
  Bytes out(b.begin(), b.begin() + static_cast<std::ptrdiff_t>(at));
  out.insert(out.end(), machine.begin(), machine.end());
  out.insert(out.end(), b.begin() + static_cast<std::ptrdiff_t>(end), b.end());
  const std::size_t mach = section_offset(b, "MACH");
  put_u32(out, mach - 4, get_u32(b, mach - 4) - static_cast<std::uint32_t>(b.size() - out.size()));
  put_u32(out, 16, static_cast<std::uint32_t>(out.size()));
  fix_crc(out);
  return out;
}

// The file without its last section (the fixture's ancillary "meta"), so that the section
// before it ends the file: a parser that took a failed read as done would then find nothing
// after it to stop on.
Bytes without_last_section(const Bytes& b) {
  const std::size_t meta = section_offset(b, "meta");
  Bytes out(b.begin(), b.begin() + static_cast<std::ptrdiff_t>(meta - 8));
  out.insert(out.end(), b.end() - 4, b.end());
  put_u32(out, 16, static_cast<std::uint32_t>(out.size()));
  put_u32(out, 20, get_u32(out, 20) - 1);
  fix_crc(out);
  return out;
}

// The file with a section `tag` of `payload` appended after the last one (before the checksum).
Bytes with_last_section(const Bytes& b, const char* tag, const Bytes& payload) {
  Bytes out(b.begin(), b.end() - 4);
  out.insert(out.end(), tag, tag + 4);
  append_u32(out, static_cast<std::uint32_t>(payload.size()));
  out.insert(out.end(), payload.begin(), payload.end());
  out.resize((out.size() + 7) / 8 * 8 + 4, 0);
  put_u32(out, 16, static_cast<std::uint32_t>(out.size()));
  put_u32(out, 20, get_u32(out, 20) + 1);
  fix_crc(out);
  return out;
}
}  // namespace

// Machine 1 of the fixture (support vectors 1, 4, 5, 6, 7, each also used by machine 0 or 2) cut
// to its first term: a machine of exactly one term loads and decides as the hand computation;
// one of no term is refused naming the count.
TEST(ModelChecks, AMachineOfOneTermLoadsAndOneOfNoneIsRefused) {
  const Bytes good = fixture("float64");
  const Model full = Model::from_bytes(good.data(), good.size());
  const Bytes one = with_machine_terms(good, 1, 1);
  const Model m = Model::from_bytes(one.data(), one.size());
  ASSERT_EQ(m.machines().size(), 3u);
  EXPECT_EQ(m.machines()[1].sv_index, (std::vector<std::uint32_t>{1}));
  EXPECT_EQ(m.machines()[1].coef, (std::vector<double>{full.machines()[1].coef[0]}));
  EXPECT_EQ(m.machines()[2].sv_index, full.machines()[2].sv_index);
  EXPECT_EQ(m.machines()[2].coef, full.machines()[2].coef);
  expect_hand_decisions(m, {7u, 8u});
  const Bytes none = with_machine_terms(good, 1, 0);
  EXPECT_EQ(load_error(none), ModelError::kValue);
  EXPECT_TRUE(says(load_message(none), "section MACH: machine 1: n_terms=0 out of range [1, n_sv=9]"))
      << load_message(none);
}

// Every stored support vector must be used by some machine: each machine cut to its first term
// in turn, a file whose cut leaves support vectors unused is refused naming the first of them,
// one that leaves none unused loads.
TEST(ModelChecks, ASupportVectorNoMachineUsesIsRefused) {
  const Bytes good = fixture("float64");
  const Model full = Model::from_bytes(good.data(), good.size());
  int refused_files = 0;
  for (std::size_t k = 0; k < full.machines().size(); ++k) {
    std::vector<bool> used(9, false);
    for (std::size_t j = 0; j < full.machines().size(); ++j) {
      const auto& idx = full.machines()[j].sv_index;
      for (std::size_t t = 0; t < (j == k ? 1 : idx.size()); ++t) used[idx[t]] = true;
    }
    const auto first_unused = std::find(used.begin(), used.end(), false);
    const Bytes cut = with_machine_terms(good, k, 1);
    if (first_unused == used.end()) {
      EXPECT_EQ(load_message(cut), "") << "machine " << k;
    } else {
      ++refused_files;
      EXPECT_EQ(load_message(cut), "model: support vector " +
                                       std::to_string(first_unused - used.begin()) +
                                       " is used by no machine")
          << "machine " << k;
    }
  }
  EXPECT_GT(refused_files, 0);
}

// An ancillary section of no bytes ends exactly at the checksum: skipped. Half a section header
// there (4 of its 8 bytes) is refused.
TEST(ModelChecks, AnEmptyAncillarySectionLastIsSkippedAndHalfAHeaderRefused) {
  const Bytes good = fixture("float64");
  const Bytes empty = with_last_section(good, "note", Bytes{});
  ASSERT_EQ(empty.size(), good.size() + 8);
  const Model m = Model::from_bytes(empty.data(), empty.size());
  EXPECT_EQ(m.n_support(), 9);
  EXPECT_EQ(m.machines().size(), 3u);
  Bytes half(good.begin(), good.end() - 4);
  half.insert(half.end(), {'n', 'o', 't', 'e'});  // a tag, no payload_bytes
  half.insert(half.end(), 4, 0);                  // the checksum
  put_u32(half, 16, static_cast<std::uint32_t>(half.size()));
  put_u32(half, 20, get_u32(half, 20) + 1);
  fix_crc(half);
  EXPECT_EQ(load_error(half), ModelError::kLayout);
  EXPECT_EQ(load_message(half), "model: section 5 header runs past the end");
}

// A CALB section that ends inside its fixed fields (rule, n_machines, threshold) is refused
// naming the field, by the throwing loader and the status loader alike (which leaves its
// output as it was): between MACH and the ancillary section, and as the file's last section.
TEST(ModelCalibration, ACalbSectionCutInsideItsFixedFieldsIsRefused) {
  const Bytes v3 = as_version3(fixture("float64"));
  auto last_calb = [&](const Bytes& payload) {  // CALB the file's last section
    Bytes b = with_last_section(without_last_section(v3), "CALB", payload);
    b[8] = 4;
    fix_crc(b);
    return b;
  };
  Bytes two;  // rule and n_machines: no threshold
  append_u32(two, 1);
  append_u32(two, 3);
  Bytes one;  // the rule alone
  append_u32(one, 1);
  const std::pair<Bytes, std::string> cases[] = {
      {with_section_after_mach(v3, "CALB", two, 4),
       "model: section CALB: field 'threshold' runs past the end of the section (0 bytes left, 8 needed)"},
      {last_calb(two),
       "model: section CALB: field 'threshold' runs past the end of the section (0 bytes left, 8 needed)"},
      {last_calb(one),
       "model: section CALB: field 'n_machines' runs past the end of the section (0 bytes left, 4 needed)"},
  };
  for (const auto& [b, message] : cases) {
    EXPECT_EQ(load_error(b), ModelError::kLayout);
    EXPECT_EQ(load_message(b), message);
    Model out = Model::from_bytes(v3.data(), v3.size());
    eskin::ModelLoadError err;
    EXPECT_FALSE(Model::parse(b.data(), b.size(), &out, &err));
    EXPECT_EQ(err.message, message);
    EXPECT_EQ(out.format_version(), 3);
  }
}

// A float32 MACH section cut by its last 8 bytes (the last machine's padding and last
// coefficient): the indices and coefficients fit the size check made before them, and the
// read of that coefficient refuses it, naming the field.
TEST(ModelChecks, AFloat32MachineCutInsideItsLastCoefficientIsRefused) {
  const Bytes good = fixture("float32");
  const std::size_t mach = section_offset(good, "MACH");
  const std::uint32_t bytes = get_u32(good, mach - 4);
  ASSERT_EQ(bytes % 8, 0u);
  Bytes b(good.begin(), good.begin() + static_cast<std::ptrdiff_t>(mach + bytes - 8));
  b.insert(b.end(), good.begin() + static_cast<std::ptrdiff_t>(mach + bytes), good.end());
  put_u32(b, mach - 4, bytes - 8);
  put_u32(b, 16, static_cast<std::uint32_t>(b.size()));
  fix_crc(b);
  EXPECT_EQ(load_error(b), ModelError::kLayout);
  EXPECT_EQ(load_message(b),
            "model: section MACH: field 'coef' runs past the end of the section (0 bytes left, 4 needed)");
}

// MACH declaring a fourth machine for the three classes, the section holding three: the fourth
// machine's first field runs past the section's end; with that machine's 24 bytes of fields
// added, its first alpha does. Either is refused naming the field (the three machines read
// before would otherwise pass the machine count of the one-vs-all rule), MACH being the last
// section.
TEST(ModelChecks, AMachineCutInsideItsFixedFieldsIsRefused) {
  const Bytes good = without_last_section(fixture("float64"));  // MACH last
  const std::size_t mach = section_offset(good, "MACH");
  ASSERT_EQ(get_u32(good, mach), 3u);
  Bytes four = good;
  put_u32(four, mach, 4);
  EXPECT_EQ(load_error([&] { fix_crc(four); return four; }()), ModelError::kLayout);
  EXPECT_EQ(refused(four),
            "model: section MACH: field 'positive_class' runs past the end of the section (0 bytes left, 4 needed)");
  const std::uint32_t bytes = get_u32(good, mach - 4);
  Bytes fields;  // positive_class 3, negative_class -1, n_terms 1, reserved, intercept 0
  append_u32(fields, 3);
  append_u32(fields, 0xFFFFFFFFu);
  append_u32(fields, 1);
  append_u32(fields, 0);
  append_f64(fields, 0.0);
  Bytes b(good.begin(), good.begin() + static_cast<std::ptrdiff_t>(mach + bytes));
  b.insert(b.end(), fields.begin(), fields.end());
  b.insert(b.end(), good.begin() + static_cast<std::ptrdiff_t>(mach + bytes), good.end());
  put_u32(b, mach, 4);
  put_u32(b, mach - 4, bytes + 24);
  put_u32(b, 16, static_cast<std::uint32_t>(b.size()));
  fix_crc(b);
  EXPECT_EQ(load_error(b), ModelError::kLayout);
  EXPECT_EQ(load_message(b),
            "model: section MACH: field 'alpha' runs past the end of the section (0 bytes left, 4 needed)");
}

// Each bound of the grid's shape by itself, each refused naming both sizes.
TEST(ModelChecks, EachBoundOfTheGridShapeIsCheckedOnItsOwn) {
  const Bytes good = fixture("float32");
  const std::size_t prep = section_offset(good, "PREP");
  for (const auto& [rows, cols] : {std::pair<std::uint32_t, std::uint32_t>{0, 4}, {257, 4}, {4, 0}, {4, 257}}) {
    Bytes b = good;
    put_u32(b, prep, rows);
    put_u32(b, prep + 4, cols);
    fix_crc(b);
    EXPECT_EQ(load_error(b), ModelError::kValue);
    EXPECT_EQ(load_message(b), "model: section PREP: grid shape rows=" + std::to_string(rows) +
                                   " cols=" + std::to_string(cols) + " out of range [1, 256]");
  }
}

// A window field of another name is unknown; a field of format version 3 in an older file is
// unknown there, and the message says which version it needs.
TEST(ModelChecks, AnUnknownWindowFieldIsRefusedNamingIt) {
  const Bytes good = fixture("float32");
  const std::size_t at = window_field_offset(good, "max_window_s") - 32;
  const auto renamed = [&](const std::string& name) {
    Bytes b = good;
    std::fill(b.begin() + static_cast<std::ptrdiff_t>(at), b.begin() + static_cast<std::ptrdiff_t>(at + 32), 0);
    std::copy(name.begin(), name.end(), b.begin() + static_cast<std::ptrdiff_t>(at));
    fix_crc(b);
    return b;
  };
  EXPECT_EQ(load_message(renamed("longest_window_s")),
            "model: section PREP: unknown window field 'longest_window_s'");
  EXPECT_EQ(load_message(renamed("window_samples")),
            "model: section PREP: unknown window field 'window_samples' (it needs format version 3)");
}

// A sample rate of 1 Hz is inside the format's range (0, 1e7]: it passes that check and is
// refused by the detector's own (its DC cutoff must be below half the rate).
TEST(ModelChecks, ASampleRateOfOneHertzPassesTheRangeCheck) {
  Bytes b = fixture("float32");
  put_f64(b, section_offset(b, "PREP") + 32, 1.0);
  EXPECT_EQ(refused(b), "model: section PREP: WindowConfig.dc_cutoff_hz = 5: must be in [0, sample_rate_hz/2)");
}

// A missing required section is named; only the amplitude factor's and the calibrated rule's
// say which format version needs them.
TEST(ModelChecks, AMissingRequiredSectionIsNamedExactly) {
  Bytes no_mach = fixture("float64");
  const std::size_t mach = section_offset(no_mach, "MACH");
  std::copy_n("mach", 4, no_mach.begin() + static_cast<std::ptrdiff_t>(mach - 8));  // ancillary now
  EXPECT_EQ(refused(no_mach), "model: required section 'MACH' missing");
  Bytes v4 = as_version3(fixture("float64"));
  v4[8] = 4;
  EXPECT_EQ(refused(v4), "model: required section 'CALB' missing (format version 4 has the calibrated rule)");
  Bytes v2 = fixture("float64");
  v2[8] = 2;
  EXPECT_EQ(refused(v2), "model: required section 'AMPL' missing (format version 2 has an amplitude factor)");
}

// Without the detector, only the recording's own taxels are checked: NaNs in the memory just
// after the last taxel's samples are not the recording's.
TEST(ModelClassify, WithoutTheDetectorOnlyTheRecordingsTaxelsAreChecked) {
  const Bytes b = read_file(std::string(ESKIN_TEST_DATA_DIR) + "/model_binary_float64.eskin");
  const Model m = Model::from_bytes(b.data(), b.size());
  eskin::Classifier clf(m);
  const std::int64_t T = 101;
  const std::size_t n_taxels = static_cast<std::size_t>(m.rows() * m.cols());
  std::vector<double> x((n_taxels + 1) * static_cast<std::size_t>(T), NAN);  // one row more
  for (std::size_t i = 0; i < n_taxels * static_cast<std::size_t>(T); ++i)
    x[i] = std::sin(0.37 * static_cast<double>(i));
  eskin::Decision d;
  EXPECT_EQ(clf.classify(x.data(), m.rows(), m.cols(), T, T, &d), eskin::ClassifyStatus::kOk);
}

namespace {
// The fixture (MACH its last section) with a fourth machine declared and `machine` appended to
// MACH as its bytes (the section padded, the sizes and the CRC fixed).
Bytes with_fourth_machine(const char* dtype, const Bytes& machine) {
  const Bytes good = without_last_section(fixture(dtype));
  const std::size_t mach = section_offset(good, "MACH");
  const std::uint32_t bytes = get_u32(good, mach - 4);
  Bytes b(good.begin(), good.begin() + static_cast<std::ptrdiff_t>(mach + bytes));
  b.insert(b.end(), machine.begin(), machine.end());
  b.resize(mach + (bytes + machine.size() + 7) / 8 * 8, 0);
  b.insert(b.end(), good.begin() + static_cast<std::ptrdiff_t>(mach + bytes), good.end());
  put_u32(b, mach, 4);
  put_u32(b, mach - 4, bytes + static_cast<std::uint32_t>(machine.size()));
  put_u32(b, 16, static_cast<std::uint32_t>(b.size()));
  fix_crc(b);
  return b;
}
// A machine's fields up to its one support-vector index (0) and the index's padding.
Bytes one_term_machine_head() {
  Bytes m;
  append_u32(m, 3);            // positive_class
  append_u32(m, 0xFFFFFFFFu);  // negative_class -1
  append_u32(m, 1);            // n_terms
  append_u32(m, 0);            // reserved
  append_f64(m, 0.0);          // intercept
  for (int z = 0; z < 3; ++z) {
    append_u32(m, 1);    // alpha
    append_u32(m, 0);    // reserved
    append_f64(m, 1.0);  // sigma
  }
  append_u32(m, 0);  // sv_index
  append_u32(m, 0);  // padding
  return m;
}
}  // namespace

// A fourth machine (one more than the three classes) whose coefficient is cut, or whose
// coefficient's padding is not zero, in MACH as the file's last section: refused naming the
// field, not loaded as the three machines before it.
TEST(ModelChecks, AnExtraMachineCutInsideItsCoefficientsIsRefused) {
  Bytes cut = one_term_machine_head();
  cut.insert(cut.end(), 4, 0);  // 4 of the float64 coefficient's 8 bytes
  const Bytes b64 = with_fourth_machine("float64", cut);
  EXPECT_EQ(load_error(b64), ModelError::kLayout);
  EXPECT_EQ(load_message(b64),
            "model: section MACH: field 'coef' runs past the end of the section (4 bytes left, 8 needed)");
  Bytes padded = one_term_machine_head();
  append_u32(padded, 0x3F800000u);  // a float32 coefficient of 1
  append_u32(padded, 1);            // its padding, not zero
  const Bytes b32 = with_fourth_machine("float32", padded);
  EXPECT_EQ(load_error(b32), ModelError::kValue);
  EXPECT_EQ(load_message(b32), "model: section MACH: non-zero padding after 'coef'");
}

// Each machine's score takes its own slope and offset (kSlopes 2, 0.5, 1.5; kOffsets -1, 0.25,
// 0). Values set exactly (every sigma at 1e-6: each value its intercept) to 1.5, 2, 0 give scores
// 2, 1.25, 0: machine 0 wins, though with machine 1's slope its score would be -0.25 and lose.
TEST(ModelCalibration, EachMachinesScoreTakesItsOwnSlopeAndOffset) {
  const Bytes b = with_values(fixture_calibrated("float64", 0.5, kSlopes, kOffsets), {1.5, 2.0, 0.0});
  const Model m = Model::from_bytes(b.data(), b.size());
  eskin::Classifier clf(m);
  const std::vector<double> x = random_tensor(m, 1.0, 35);
  eskin::Decision d;
  ASSERT_EQ(clf.classify_tensor(x.data(), &d), eskin::ClassifyStatus::kOk);
  ASSERT_EQ(d.values[0], 1.5);
  ASSERT_EQ(d.values[1], 2.0);
  ASSERT_EQ(d.values[2], 0.0);
  const auto sigmoid = [](double z) { return 1.0 / (1.0 + std::exp(-z)); };
  EXPECT_EQ(d.label, 0);
  EXPECT_NEAR(d.confidence, sigmoid(2.0) / (sigmoid(2.0) + sigmoid(1.25) + sigmoid(0.0)), 1e-15);
}

// A section tag is named with each byte outside the printable ASCII range [0x20, 0x7E] as '?'.
TEST(ModelChecks, AnUnexpectedSectionIsNamedWithItsUnprintableBytesAsQuestionMarks) {
  const Bytes good = fixture("float32");
  const std::size_t tag = section_offset(good, "PREP") - 8;
  const std::pair<std::array<std::uint8_t, 4>, std::string> cases[] = {
      {{'Q', 0x1F, ' ', '~'}, "Q? ~"}, {{'Q', 0x7F, 'B', 0x80}, "Q?B?"}};
  for (const auto& [bytes, shown] : cases) {
    Bytes b = good;
    std::copy(bytes.begin(), bytes.end(), b.begin() + static_cast<std::ptrdiff_t>(tag));
    EXPECT_EQ(refused(b), "model: unexpected section '" + shown + "' (expected 'PREP')");
  }
}

// SVBS's tensor dims and stored widths, each checked and named exactly: dims that differ from
// PREP's in any one place, and an alpha_store of 0 or above Q = min(dim, product of the others).
TEST(ModelChecks, TheBasesShapeIsCheckedAgainstThePreprocessing) {
  const Bytes good = fixture("float32");
  const std::size_t svbs = section_offset(good, "SVBS");
  const std::string D = std::to_string(get_u32(good, section_offset(good, "PREP") + 8));
  for (std::size_t z = 0; z < 3; ++z) {
    Bytes b = good;
    put_u32(b, svbs + 8 + 4 * z, 3);
    std::string dims[3] = {"4", "4", D};
    dims[z] = "3";
    EXPECT_EQ(refused(b), "model: section SVBS: tensor dims (" + dims[0] + ", " + dims[1] + ", " + dims[2] +
                              ") differ from the preprocessing's (rows, cols, D) = (4, 4, " + D + ")");
  }
  for (const std::uint32_t a : {0u, 5u}) {
    Bytes b = good;
    put_u32(b, svbs + 20, a);
    EXPECT_EQ(refused(b), "model: section SVBS: alpha_store[0]=" + std::to_string(a) + " out of range [1, Q=4]");
  }
}

// A window field in seconds or hertz (its name ends in "_s" or "_hz") beyond 1e6 is refused by
// the format's own bound, before the detector's checks.
TEST(ModelChecks, ASecondsOrHertzWindowFieldBeyondAMillionIsRefused) {
  for (const char* name : {"max_window_s", "dc_cutoff_hz"}) {
    Bytes b = fixture("float32");
    put_f64(b, window_field_offset(b, name), -2e6);
    EXPECT_EQ(refused(b), std::string("model: section PREP: window field '") + name +
                              "' = -2000000 is outside [-1e6, 1e6]");
  }
}

// A 4x5 grid at D = 3, every mode at its full alpha (tests/data/model_wide_rows_float64.eskin):
// the row and column modes take the projection route, and the row mode's projection (15 x 15)
// is the larger one, which the input's projection buffer must hold (the sanitizer build sees a
// buffer sized for another mode's). The decision values are the hand computation's.
TEST(ModelDecision, TheInputsProjectionHoldsTheLargestModesProjection) {
  const Bytes b = read_file(std::string(ESKIN_TEST_DATA_DIR) + "/model_wide_rows_float64.eskin");
  const Model m = Model::from_bytes(b.data(), b.size());
  ASSERT_EQ(m.rows(), 4);
  ASSERT_EQ(m.cols(), 5);
  ASSERT_EQ(m.D(), 3);
  // the projection route: N <= 64 and N < alpha^2 (15 < 16, 12 < 25; not the time mode's 20)
  ASSERT_EQ(m.basis_rows(0), 15);
  ASSERT_EQ(m.basis_rows(1), 12);
  ASSERT_EQ(m.basis_rows(2), 20);
  for (const auto& mm : m.machines())
    ASSERT_EQ(mm.alpha, (std::array<int, eskin::model_format::kModes>{4, 5, 3}));
  eskin::Classifier clf(m);
  for (const unsigned seed : {3u, 4u}) {
    const std::vector<double> x = random_tensor(m, 1.0, seed);
    const std::vector<double> want = hand_decision(m, x);
    eskin::Decision d;
    ASSERT_EQ(clf.classify_tensor(x.data(), &d), eskin::ClassifyStatus::kOk);
    for (std::size_t k = 0; k < want.size(); ++k)
      EXPECT_NEAR(d.values[k], want[k], 1e-12) << "seed " << seed << " machine " << k;
  }
}

// An SVBS section 8 bytes short of the ranks (padded to 8 bytes) and bases its counts imply is
// refused by the size check before anything is read, with the count and the bytes it needs.
TEST(ModelChecks, AnSvbsSectionShortOfItsRanksAndBasesNamesTheBytesItNeeds) {
  for (const char* dtype : {"float32", "float64"}) {
    Bytes b = fixture(dtype);
    const std::size_t s = section_offset(b, "SVBS");
    const std::uint32_t len = get_u32(b, s - 4);
    b.erase(b.begin() + static_cast<std::ptrdiff_t>(s + len - 8),
            b.begin() + static_cast<std::ptrdiff_t>(s + len));
    put_u32(b, s - 4, len - 8);
    put_u32(b, 16, static_cast<std::uint32_t>(b.size()));
    fix_crc(b);
    const std::string m = refused(b);
    EXPECT_NE(m.find("section SVBS: n_sv="), std::string::npos) << dtype << ": " << m;
    EXPECT_NE(m.find(" needs "), std::string::npos) << dtype << ": " << m;
  }
}
