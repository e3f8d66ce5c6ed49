// The .eskin loader: every byte is bounds-checked, every size is checked against the ones it
// implies, and every value is validated before a Model is returned (docs/model-format.md).
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#if !defined(ESKIN_DEVICE)
#include <fstream>
#endif
#include <iterator>
#include <limits>

#include "eskin/model.hpp"
#include "decision_tables.hpp"
#include "raise.hpp"

namespace eskin {

namespace {

// Limits that keep every product of sizes far from overflow and every allocation sane.
constexpr std::uint32_t kMaxGrid = 256;      // rows, cols
// rows * cols * D: the classifier's workspace (8 input copies for the batched eigen-solver, the
// mode Gram matrices) grows with the tensor; this bounds it to about 150 MB.
constexpr std::uint64_t kMaxTensor = 1u << 20;
// sigma of every mode: 1 / (2 sigma^2) stays a normal, finite double, so that no decision value
// can be NaN (a zero distance times an infinite weight) whatever the distances.
constexpr double kMinSigma = 1e-6;
constexpr double kMaxSigma = 1e6;
// sum_t |coef_t| + |intercept| of a machine: bounds every decision value (the kernel is <= 1),
// so that no sum can overflow to inf (and inf - inf to NaN).
constexpr double kMaxDecisionBound = 1e300;
constexpr std::uint32_t kMaxClasses = 1024;
// AMPL (format version 2): support-vector log energies within [-1e4, 1e4] (a finite double
// pattern has e in [log 1e-12, log DBL_MAX] = [-27.6, 709.8]) and widths 0 or in [1e-6, 1e6], so
// that (e(x) - e_i)^2 / (2 w^2) is finite for every finite e(x) and never 0 * inf.
constexpr double kMaxLogEnergy = 1e4;
constexpr double kMinAmplitudeWidth = 1e-6;
constexpr double kMaxAmplitudeWidth = 1e6;
constexpr std::uint64_t kMaxFileBytes = 1ull << 31;

// As `std::ostream << std::setprecision(17) << v`, without iostreams (not in a controller build).
std::string fmt_double(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.17g", v);
  return buf;
}

// The throwing API's end of a failed parse: ModelFormatError on the host; without exceptions
// (the device build) the message goes to detail::fatal_error.
[[noreturn]] void fail(ModelError code, const std::string& msg) {
#if defined(__cpp_exceptions)
  throw ModelFormatError(code, msg);
#else
  (void)code;
  detail::fatal_error(msg.c_str());
#endif
}

// The first error of a parse. The parser returns at every failed check (`return err.set(...)`);
// a read past the end of a section records its error and yields zeros, so that nothing after
// the first error can read out of bounds or size an allocation from garbage.
struct ParseError {
  bool failed = false;
  ModelError code = ModelError::kIo;
  std::string message;
  bool set(ModelError c, const std::string& msg) {
    if (!failed) {
      failed = true;
      code = c;
      message = msg;
    }
    return false;
  }
};

// Index of the first byte of s[0, n) that does not start a well-formed UTF-8 sequence (RFC 3629:
// no overlong forms, no surrogates, nothing above U+10FFFF), or n when all of it is valid.
std::size_t utf8_error_at(const char* s, std::size_t n) {
  const auto* u = reinterpret_cast<const unsigned char*>(s);
  std::size_t i = 0;
  while (i < n) {
    const unsigned c = u[i];
    std::size_t len;
    unsigned lo = 0x80, hi = 0xBF;  // allowed range of the second byte
    if (c < 0x80) len = 1;
    else if (c >= 0xC2 && c <= 0xDF) len = 2;
    else if (c >= 0xE0 && c <= 0xEF) {
      len = 3;
      if (c == 0xE0) lo = 0xA0;       // overlong
      else if (c == 0xED) hi = 0x9F;  // surrogates
    } else if (c >= 0xF0 && c <= 0xF4) {
      len = 4;
      if (c == 0xF0) lo = 0x90;       // overlong
      else if (c == 0xF4) hi = 0x8F;  // above U+10FFFF
    } else {
      return i;
    }
    if (len > n - i) return i;
    for (std::size_t k = 1; k < len; ++k) {
      const unsigned b = u[i + k];
      if (k == 1 ? (b < lo || b > hi) : (b < 0x80 || b > 0xBF)) return i;
    }
    i += len;
  }
  return n;
}

// Little-endian reads from a bounded byte range. Every read says whether it succeeded and is
// [[nodiscard]] (the targets that build this file turn -Wunused-result into an error): a parser
// cannot read a field and go on as if it had read it. The first failure is the one reported.
static_assert(sizeof(float) == sizeof(std::uint32_t) && sizeof(double) == sizeof(std::uint64_t),
              "the format's reals are IEEE-754 binary32 and binary64");

class Reader {
 public:
  Reader(const std::uint8_t* data, std::size_t size, std::string what, ParseError& err)
      : p_(data), n_(size), what_(std::move(what)), err_(err) {}
  std::size_t remaining() const { return n_ - pos_; }
  [[nodiscard]] bool need(std::size_t k, const char* field) {
    if (err_.failed) return false;
    if (k <= n_ - pos_) return true;
    const std::size_t left = n_ - pos_;
    pos_ = n_;
    return err_.set(ModelError::kLayout, what_ + ": field '" + field + "' runs past the end of the section (" +
                                    std::to_string(left) + " bytes left, " +
                                    std::to_string(k) + " needed)");
  }
  [[nodiscard]] bool u32(const char* field, std::uint32_t& out) {
    if (!need(4, field)) return false;
    std::uint32_t v = 0;
    for (int i = 3; i >= 0; --i) v = (v << 8) | p_[pos_ + static_cast<std::size_t>(i)];
    pos_ += 4;
    out = v;
    return true;
  }
  [[nodiscard]] bool f64(const char* field, double& out) {
    if (!need(8, field)) return false;
    std::uint64_t v = 0;
    for (int i = 7; i >= 0; --i) v = (v << 8) | p_[pos_ + static_cast<std::size_t>(i)];
    pos_ += 8;
    std::memcpy(&out, &v, sizeof out);
    return true;
  }
  // A 4-byte field read as the bits of another 4-byte type (a signed index, a float).
  template <class T>
  [[nodiscard]] bool bits32(const char* field, T& out) {
    static_assert(sizeof(T) == 4, "a 4-byte field");
    std::uint32_t u;
    if (!u32(field, u)) return false;
    std::memcpy(&out, &u, sizeof out);
    return true;
  }
  [[nodiscard]] bool name(const char* field, std::string& out) {
    if (!need(model_format::kNameBytes, field)) return false;
    const char* s = reinterpret_cast<const char*>(p_ + pos_);
    const std::size_t len = strnlen(s, model_format::kNameBytes);
    if (len == 0 || len == model_format::kNameBytes)
      return err_.set(ModelError::kValue, what_ + ": field '" + field + "' must be a non-empty name of at most " +
                                          std::to_string(model_format::kNameBytes - 1) +
                                          " bytes, NUL padded");
    for (std::size_t i = len; i < model_format::kNameBytes; ++i)
      if (s[i] != 0) return err_.set(ModelError::kValue, what_ + ": field '" + field + "' has non-zero padding");
    for (std::size_t i = 0; i < len; ++i) {
      const unsigned char c = static_cast<unsigned char>(s[i]);
      if (c < 0x20 || c == 0x7F)
        return err_.set(ModelError::kValue, what_ + ": field '" + field + "' contains control characters");
    }
    const std::size_t bad = utf8_error_at(s, len);
    if (bad != len)
      return err_.set(ModelError::kValue, what_ + ": field '" + field + "' is not valid UTF-8 (byte " +
                                              std::to_string(bad) + ")");
    out.assign(s, len);
    pos_ += model_format::kNameBytes;
    return true;
  }
  // Zero padding up to the next multiple of 8 (relative to the section start).
  [[nodiscard]] bool pad8(const char* field) {
    const std::size_t k = (8 - (pos_ % 8)) % 8;
    if (!need(k, field)) return false;
    for (std::size_t i = 0; i < k; ++i)
      if (p_[pos_ + i] != 0)
        return err_.set(ModelError::kValue, what_ + ": non-zero padding after '" + field + "'");
    pos_ += k;
    return true;
  }
  [[nodiscard]] bool zero_u32(const char* field) {
    std::uint32_t v;
    if (!u32(field, v)) return false;
    if (v != 0) return err_.set(ModelError::kValue, what_ + ": reserved field '" + field + "' is not 0");
    return true;
  }
  // k bytes to read in place (nullptr when the section is shorter).
  [[nodiscard]] const std::uint8_t* raw(std::size_t k, const char* field) {
    if (!need(k, field)) return nullptr;
    const std::uint8_t* r = p_ + pos_;
    pos_ += k;
    return r;
  }
  [[nodiscard]] bool expect_end() {
    if (err_.failed) return false;
    if (pos_ != n_)
      return err_.set(ModelError::kLayout, what_ + ": " + std::to_string(n_ - pos_) +
                                           " unexpected trailing bytes in the section");
    return true;
  }
  const std::string& what() const { return what_; }

 private:
  const std::uint8_t* p_;
  std::size_t n_;
  std::size_t pos_ = 0;
  std::string what_;
  ParseError& err_;
};

std::string tag_str(std::uint32_t tag) {
  std::string s(4, '?');
  for (int i = 0; i < 4; ++i) {
    const char c = static_cast<char>((tag >> (8 * i)) & 0xFF);
    s[static_cast<std::size_t>(i)] = (c >= 0x20 && c < 0x7F) ? c : '?';
  }
  return s;
}

constexpr std::uint32_t tag_of(const char (&s)[5]) {
  return static_cast<std::uint32_t>(static_cast<unsigned char>(s[0])) |
         (static_cast<std::uint32_t>(static_cast<unsigned char>(s[1])) << 8) |
         (static_cast<std::uint32_t>(static_cast<unsigned char>(s[2])) << 16) |
         (static_cast<std::uint32_t>(static_cast<unsigned char>(s[3])) << 24);
}

}  // namespace

// Friend of Model: fills its private fields.
namespace {
#if defined(__BYTE_ORDER__) && defined(__ORDER_LITTLE_ENDIAN__)
constexpr bool kLittleEndian = __BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__;
#else
constexpr bool kLittleEndian = false;  // unknown: always copy
#endif
}  // namespace

class ModelParser {
 public:
  /// borrow: keep the bases in `data` instead of copying them (see Model::view_bytes).
  static bool parse(const std::uint8_t* data, std::size_t size, const std::string& origin,
                    bool borrow, Model& m, ParseError& err);

 private:
  static bool parse_prep(Reader& r, Model& m, ParseError& err);
  static bool parse_clas(Reader& r, Model& m, ParseError& err);
  static bool parse_svbs(Reader& r, Model& m, ParseError& err);
  static bool read_svbs_shape(Reader& r, Model& m, ParseError& err,
                              std::array<std::uint32_t, 3>& astore, std::uint32_t& n_sv);
  static bool read_ranks(Reader& r, Model& m, ParseError& err,
                         const std::array<std::uint32_t, 3>& astore, std::uint32_t n_sv);
  static bool read_bases(Reader& r, Model& m, ParseError& err, int z);
  static bool check_orthonormal(Reader& r, Model& m, ParseError& err, int z);
  static bool parse_mach(Reader& r, Model& m, ParseError& err);
  static bool parse_ampl(Reader& r, Model& m, ParseError& err);
  static bool parse_calb(Reader& r, Model& m, ParseError& err);
  static bool parse_required(int which, Reader& r, Model& m, ParseError& err);
  static bool parse_sections(const std::uint8_t* data, std::size_t end, std::uint32_t n_sections,
                             const std::string& origin, Model& m, ParseError& err);
  static bool check_machines(Model& m, const std::string& origin, ParseError& err);
};

bool ModelParser::parse_prep(Reader& r, Model& m, ParseError& err) {
  const std::string& w = r.what();
  std::uint32_t rows, cols, D, window, sub, short_policy, n_fields;
  double rate;
  if (!r.u32("rows", rows) || !r.u32("cols", cols) || !r.u32("D", D) || !r.u32("window_mode", window) ||
      !r.u32("subsample", sub) || !r.u32("short_policy", short_policy) ||
      !r.u32("n_window_fields", n_fields) || !r.zero_u32("reserved") || !r.f64("sample_rate_hz", rate))
    return false;
  if (rows < 1 || rows > kMaxGrid || cols < 1 || cols > kMaxGrid)
    return err.set(ModelError::kValue, w + ": grid shape rows=" + std::to_string(rows) + " cols=" +
                                 std::to_string(cols) + " out of range [1, " +
                                 std::to_string(kMaxGrid) + "]");
  if (D < 2 || D > kMaxD)
    return err.set(ModelError::kValue, w + ": D=" + std::to_string(D) + " out of range [2, " +
                                 std::to_string(kMaxD) + "]");
  if (std::uint64_t{rows} * cols * D > kMaxTensor)
    return err.set(ModelError::kValue, w + ": rows*cols*D = " + std::to_string(rows) + "*" +
                                 std::to_string(cols) + "*" + std::to_string(D) + " = " +
                                 std::to_string(std::uint64_t{rows} * cols * D) +
                                 " exceeds the limit " + std::to_string(kMaxTensor));
  if (window > 1)
    return err.set(ModelError::kValue, w + ": window_mode=" + std::to_string(window) + " (0 energy, 1 none)");
  if (sub > 1)
    return err.set(ModelError::kValue, w + ": subsample=" + std::to_string(sub) + " (0 algorithm2, 1 even)");
  if (short_policy > 1)
    return err.set(ModelError::kValue, w + ": short_policy=" + std::to_string(short_policy) +
                                 " (0 interpolate, 1 error)");
  if (!(std::isfinite(rate) && rate > 0 && rate <= 1e7))
    return err.set(ModelError::kValue, w + ": sample_rate_hz=" + fmt_double(rate) + " must be in (0, 1e7]");
  const auto& names = window_config_field_names();
  // format version 3 adds the bounded window's field (window_samples, the last); an older file
  // has the others and leaves it 0 (every sample up to max_window_s)
  const std::size_t n_expected =
      m.format_version_ >= model_format::kVersionBoundedWindow ? kWindowConfigSize : kWindowConfigSizeV2;
  if (n_fields != n_expected)
    return err.set(ModelError::kValue, w + ": n_window_fields=" + std::to_string(n_fields) + ", expected " +
                                 std::to_string(n_expected) + " (the WindowConfig fields of format version " +
                                 std::to_string(m.format_version_) + ")");
  std::array<double, kWindowConfigSize> values{};
  std::array<bool, kWindowConfigSize> seen{};
  for (std::uint32_t i = 0; i < n_fields; ++i) {
    std::string name;
    double value;
    if (!r.name("window field name", name) || !r.f64("window field value", value)) return false;
    std::size_t k = 0;
    while (k < kWindowConfigSize && name != names[k]) ++k;
    if (k >= n_expected)
      return err.set(ModelError::kValue, w + ": unknown window field '" + name + "'" +
                                   (k < kWindowConfigSize ? " (it needs format version 3)" : ""));
    if (seen[k]) return err.set(ModelError::kValue, w + ": window field '" + name + "' repeated");
    if (!std::isfinite(value))
      return err.set(ModelError::kValue, w + ": window field '" + name + "' = " + fmt_double(value) +
                                   " is not finite");
    // times (seconds) and frequencies are bounded so that seconds * rate stays far inside
    // int64 in the detector's conversions to samples
    const bool converted = name.size() > 2 && (name.compare(name.size() - 2, 2, "_s") == 0 ||
                                               name.compare(name.size() - 3, 3, "_hz") == 0);
    if (converted && std::fabs(value) > 1e6)
      return err.set(ModelError::kValue, w + ": window field '" + name + "' = " + fmt_double(value) +
                                   " is outside [-1e6, 1e6]");
    seen[k] = true;
    values[k] = value;
  }
  if (!r.expect_end()) return false;
  const WindowConfig cfg = window_config_from_array(values.data(), values.size());
#if defined(__cpp_exceptions)
  try {
    // the detector's own validation, and the sample buffers of a stream classifier
    const DetectorParams p = resolve_window_config(cfg, rate);
    check_detector_buffers(p, cfg, std::int64_t{rows} * cols);
  } catch (const std::exception& e) {
    return err.set(ModelError::kValue, w + ": " + e.what());
  }
#else
  // without exceptions, settings the detector rejects end in detail::fatal_error
  check_detector_buffers(resolve_window_config(cfg, rate), cfg, std::int64_t{rows} * cols);
#endif
  m.rows_ = static_cast<int>(rows);
  m.cols_ = static_cast<int>(cols);
  m.D_ = static_cast<int>(D);
  m.window_mode_ = static_cast<WindowMode>(window);
  m.subsample_ = static_cast<SubsampleMethod>(sub);
  m.short_policy_ = static_cast<ShortPolicy>(short_policy);
  m.sample_rate_hz_ = rate;
  m.window_config_ = cfg;
  return true;
}

bool ModelParser::parse_clas(Reader& r, Model& m, ParseError& err) {
  const std::string& w = r.what();
  std::uint32_t n, rule;
  if (!r.u32("n_classes", n) || !r.u32("rule", rule)) return false;
  if (n < 2 || n > kMaxClasses)
    return err.set(ModelError::kValue, w + ": n_classes=" + std::to_string(n) + " out of range [2, " +
                                 std::to_string(kMaxClasses) + "]");
  if (rule > 1) return err.set(ModelError::kValue, w + ": rule=" + std::to_string(rule) + " (0 binary, 1 one_vs_all)");
  if (rule == 0 && n != 2)
    return err.set(ModelError::kValue, w + ": the binary rule needs 2 classes, got " + std::to_string(n));
  m.rule_ = static_cast<DecisionRule>(rule);
  if (!r.need(static_cast<std::size_t>(n) * model_format::kNameBytes, "class names")) return false;
  m.class_names_.clear();
  for (std::uint32_t i = 0; i < n; ++i) {
    std::string s;
    if (!r.name("class name", s)) return false;
    for (const auto& g : m.class_names_)
      if (g == s) return err.set(ModelError::kValue, w + ": class name '" + s + "' repeated");
    m.class_names_.push_back(std::move(s));
  }
  return r.expect_end();
}

// SVBS in four named steps: the table's shape, the ranks, each mode's bases (borrowed or
// copied, every entry in [-1, 1]), and their orthonormality up to each rank.
bool ModelParser::parse_svbs(Reader& r, Model& m, ParseError& err) {
  std::array<std::uint32_t, 3> astore{};
  std::uint32_t n_sv;
  if (!read_svbs_shape(r, m, err, astore, n_sv) || !read_ranks(r, m, err, astore, n_sv))
    return false;
  for (int z = 0; z < 3; ++z)
    if (!read_bases(r, m, err, z) || !check_orthonormal(r, m, err, z)) return false;
  return r.expect_end();
}

// n_modes, n_sv, the tensor dims (those of PREP), alpha_store per mode; the section must hold
// the ranks and bases they imply (checked before anything is allocated).
bool ModelParser::read_svbs_shape(Reader& r, Model& m, ParseError& err,
                                  std::array<std::uint32_t, 3>& astore, std::uint32_t& n_sv) {
  const std::string& w = r.what();
  std::uint32_t Z = 0;
  if (!r.u32("n_modes", Z) || !r.u32("n_sv", n_sv)) return false;
  if (Z != 3) return err.set(ModelError::kValue, w + ": n_modes=" + std::to_string(Z) + ", expected 3 (rows, cols, D)");
  std::array<std::uint32_t, 3> dims{};
  for (auto& d : dims)
    if (!r.u32("dims", d)) return false;
  for (auto& a : astore)
    if (!r.u32("alpha_store", a)) return false;
  const std::array<std::uint32_t, 3> expect{static_cast<std::uint32_t>(m.rows_),
                                            static_cast<std::uint32_t>(m.cols_),
                                            static_cast<std::uint32_t>(m.D_)};
  if (dims != expect)
    return err.set(ModelError::kValue, w + ": tensor dims (" + std::to_string(dims[0]) + ", " +
                                 std::to_string(dims[1]) + ", " + std::to_string(dims[2]) +
                                 ") differ from the preprocessing's (rows, cols, D) = (" +
                                 std::to_string(expect[0]) + ", " + std::to_string(expect[1]) + ", " +
                                 std::to_string(expect[2]) + ")");
  const std::uint64_t total = std::uint64_t{dims[0]} * dims[1] * dims[2];
  std::size_t bytes_needed = 0;
  const std::size_t real_bytes = m.float64_ ? 8 : 4;
  for (int z = 0; z < 3; ++z) {
    const std::uint64_t N = total / dims[z];
    const std::uint64_t Q = std::min<std::uint64_t>(dims[z], N);
    if (astore[z] < 1 || astore[z] > Q)
      return err.set(ModelError::kValue, w + ": alpha_store[" + std::to_string(z) + "]=" +
                                   std::to_string(astore[z]) + " out of range [1, Q=" +
                                   std::to_string(Q) + "]");
    m.alpha_store_[z] = static_cast<int>(astore[z]);
    m.basis_rows_[z] = static_cast<int>(N);
    bytes_needed += static_cast<std::size_t>(N * astore[z] * real_bytes);
  }
  if (n_sv < 1) return err.set(ModelError::kValue, w + ": n_sv=0: a model needs at least one support vector");
  const std::uint64_t rank_bytes = (std::uint64_t{n_sv} * 3 * 4 + 7) / 8 * 8;
  if (std::uint64_t{n_sv} * bytes_needed + rank_bytes > r.remaining())
    return err.set(ModelError::kLayout, w + ": n_sv=" + std::to_string(n_sv) + " needs " +
                                  std::to_string(std::uint64_t{n_sv} * bytes_needed + rank_bytes) +
                                  " bytes of ranks and bases, the section has " +
                                  std::to_string(r.remaining()));
  m.n_sv_ = static_cast<int>(n_sv);
  return true;
}

// The rank of every support vector in every mode: at most its stored basis width.
bool ModelParser::read_ranks(Reader& r, Model& m, ParseError& err,
                             const std::array<std::uint32_t, 3>& astore, std::uint32_t n_sv) {
  const std::string& w = r.what();
  m.ranks_.resize(static_cast<std::size_t>(n_sv) * 3);
  for (std::uint32_t i = 0; i < n_sv; ++i)
    for (int z = 0; z < 3; ++z) {
      std::uint32_t rk;
      if (!r.u32("ranks", rk)) return false;
      if (rk > astore[z])
        return err.set(ModelError::kValue, w + ": rank of support vector " + std::to_string(i) + " in mode " +
                                     std::to_string(z) + " is " + std::to_string(rk) +
                                     " > alpha_store " + std::to_string(astore[z]));
      m.ranks_[static_cast<std::size_t>(i) * 3 + static_cast<std::size_t>(z)] = static_cast<int>(rk);
    }
  return r.pad8("ranks");
}

// The mode-z bases of every support vector. Borrowed (Model::view_bytes): used in place when
// the bytes are the machine's own floats (little-endian) and aligned for them; copied
// otherwise. Every entry must be finite and in [-1, 1] (entries of orthonormal columns).
bool ModelParser::read_bases(Reader& r, Model& m, ParseError& err, int z) {
  const std::string& w = r.what();
  const std::size_t real_bytes = m.float64_ ? 8 : 4;
  const std::size_t count = static_cast<std::size_t>(m.n_sv_) *
                            static_cast<std::size_t>(m.alpha_store_[z]) *
                            static_cast<std::size_t>(m.basis_rows_[z]);
  const std::uint8_t* p = r.raw(count * real_bytes, "bases");
  if (p == nullptr) return false;
  const bool in_place = m.borrow_ && kLittleEndian &&
                        reinterpret_cast<std::uintptr_t>(p) % real_bytes == 0;
  if (in_place) {
    if (m.float64_) m.b64_[z] = reinterpret_cast<const double*>(p);
    else m.b32_[z] = reinterpret_cast<const float*>(p);
  } else if (m.float64_) {
    m.bases64_[z].resize(count);
  } else {
    m.bases32_[z].resize(count);
  }
  for (std::size_t j = 0; j < count; ++j) {
    double v;
    if (m.float64_) {
      std::uint64_t u = 0;
      for (int b = 7; b >= 0; --b) u = (u << 8) | p[j * 8 + static_cast<std::size_t>(b)];
      std::memcpy(&v, &u, sizeof v);
      if (!in_place) m.bases64_[z][j] = v;
    } else {
      std::uint32_t u = 0;
      for (int b = 3; b >= 0; --b) u = (u << 8) | p[j * 4 + static_cast<std::size_t>(b)];
      float f;
      std::memcpy(&f, &u, sizeof f);
      if (!in_place) m.bases32_[z][j] = f;
      v = f;
    }
    if (!std::isfinite(v) || std::fabs(v) > 1.0 + 1e-5)
      return err.set(ModelError::kValue, w + ": basis entry " + std::to_string(j) + " of mode " +
                                   std::to_string(z) + " is " + fmt_double(v) +
                                   " (entries of orthonormal columns lie in [-1, 1])");
  }
  return true;
}

// Orthonormal columns up to each support vector's rank, zero columns beyond it (to 1e-8 in
// float64, 1e-4 in float32).
bool ModelParser::check_orthonormal(Reader& r, Model& m, ParseError& err, int z) {
  const std::string& w = r.what();
  const std::size_t N = static_cast<std::size_t>(m.basis_rows_[z]);
  const std::size_t A = static_cast<std::size_t>(m.alpha_store_[z]);
  const double tol = m.float64_ ? 1e-8 : 1e-4;
  for (std::size_t i = 0; i < static_cast<std::size_t>(m.n_sv_); ++i) {
    const int rk = m.ranks_[i * 3 + static_cast<std::size_t>(z)];
    for (std::size_t k = 0; k < A; ++k)
      for (std::size_t l = 0; l <= k; ++l) {
        double dot = 0;
        for (std::size_t n = 0; n < N; ++n) {
          const std::size_t a = (i * A + k) * N + n, b = (i * A + l) * N + n;
          dot += m.float64_ ? m.bases_f64(z)[a] * m.bases_f64(z)[b]
                            : double{m.bases_f32(z)[a]} * double{m.bases_f32(z)[b]};
        }
        const double want = (k == l && static_cast<int>(k) < rk) ? 1.0 : 0.0;
        if (std::fabs(dot - want) > tol)
          return err.set(ModelError::kValue, w + ": basis of support vector " + std::to_string(i) +
                                       " in mode " + std::to_string(z) + " is not orthonormal " +
                                       "up to its rank " + std::to_string(rk) + " (columns " +
                                       std::to_string(l) + "," + std::to_string(k) + ": " +
                                       fmt_double(dot) + ")");
      }
  }
  return true;
}

bool ModelParser::parse_mach(Reader& r, Model& m, ParseError& err) {
  const std::string& w = r.what();
  std::uint32_t n;
  if (!r.u32("n_machines", n) || !r.zero_u32("reserved")) return false;
  const std::size_t real_bytes = m.float64_ ? 8 : 4;
  // A machine takes at least 24 + 3*16 bytes: bound n before reserving.
  if (n < 1 || std::uint64_t{n} * 72 > r.remaining())
    return err.set(ModelError::kValue, w + ": n_machines=" + std::to_string(n) + " impossible for a section of " +
                                 std::to_string(r.remaining()) + " bytes");
  m.machines_.clear();
  m.machines_.reserve(n);
  for (std::uint32_t k = 0; k < n; ++k) {
    const std::string mw = w + ": machine " + std::to_string(k);
    ModelMachine mm;
    std::int32_t positive, negative;
    std::uint32_t n_terms;
    if (!r.bits32("positive_class", positive) || !r.bits32("negative_class", negative) ||
        !r.u32("n_terms", n_terms) || !r.zero_u32("reserved") || !r.f64("intercept", mm.intercept))
      return false;
    mm.positive = positive;
    mm.negative = negative;
    if (!std::isfinite(mm.intercept))
      return err.set(ModelError::kValue, mw + ": intercept=" + fmt_double(mm.intercept) + " is not finite");
    for (int z = 0; z < 3; ++z) {
      std::uint32_t a;
      double s;
      if (!r.u32("alpha", a) || !r.zero_u32("reserved") || !r.f64("sigma", s)) return false;
      if (a < 1 || a > static_cast<std::uint32_t>(m.alpha_store_[z]))
        return err.set(ModelError::kValue, mw + ": alpha[" + std::to_string(z) + "]=" + std::to_string(a) +
                                     " out of range [1, alpha_store=" +
                                     std::to_string(m.alpha_store_[z]) + "]");
      if (!(s >= kMinSigma && s <= kMaxSigma))
        return err.set(ModelError::kValue, mw + ": sigma[" + std::to_string(z) + "]=" + fmt_double(s) +
                                     " out of range [1e-06, 1e+06]");
      mm.alpha[static_cast<std::size_t>(z)] = static_cast<int>(a);
      mm.sigma[static_cast<std::size_t>(z)] = s;
    }
    if (n_terms < 1 || n_terms > static_cast<std::uint32_t>(m.n_sv_))
      return err.set(ModelError::kValue, mw + ": n_terms=" + std::to_string(n_terms) + " out of range [1, n_sv=" +
                                   std::to_string(m.n_sv_) + "]");
    if (!r.need(std::size_t{n_terms} * (4 + real_bytes), "support-vector indices and coefficients"))
      return false;
    mm.sv_index.resize(n_terms);
    for (std::uint32_t t = 0; t < n_terms; ++t) {
      std::uint32_t i;
      if (!r.u32("sv_index", i)) return false;
      if (i >= static_cast<std::uint32_t>(m.n_sv_))
        return err.set(ModelError::kValue, mw + ": sv_index[" + std::to_string(t) + "]=" + std::to_string(i) +
                                     " >= n_sv=" + std::to_string(m.n_sv_));
      if (t > 0 && i <= mm.sv_index[t - 1])
        return err.set(ModelError::kValue, mw + ": sv_index must be strictly increasing (entry " +
                                     std::to_string(t) + ")");
      mm.sv_index[t] = i;
    }
    if (!r.pad8("sv_index")) return false;
    mm.coef.resize(n_terms);
    for (std::uint32_t t = 0; t < n_terms; ++t) {
      double c;
      if (m.float64_) {
        if (!r.f64("coef", c)) return false;
      } else {
        float c32;
        if (!r.bits32("coef", c32)) return false;
        c = static_cast<double>(c32);
      }
      if (!std::isfinite(c))
        return err.set(ModelError::kValue, mw + ": coef[" + std::to_string(t) + "]=" + fmt_double(c) + " is not finite");
      mm.coef[t] = c;
    }
    double bound = std::fabs(mm.intercept);
    for (const double c : mm.coef) bound += std::fabs(c);
    if (!(bound <= kMaxDecisionBound))
      return err.set(ModelError::kValue, mw + ": |intercept| + sum |coef| = " + fmt_double(bound) +
                                   " exceeds 1e+300 (decision values would overflow)");
    if (!r.pad8("coef")) return false;
    m.machines_.push_back(std::move(mm));
  }
  return r.expect_end();
}

bool ModelParser::parse_ampl(Reader& r, Model& m, ParseError& err) {
  const std::string& w = r.what();
  std::uint32_t n_sv, n_machines;
  if (!r.u32("n_sv", n_sv) || !r.u32("n_machines", n_machines)) return false;
  if (n_sv != static_cast<std::uint32_t>(m.n_sv_))
    return err.set(ModelError::kValue, w + ": n_sv=" + std::to_string(n_sv) + " differs from SVBS's n_sv=" +
                                 std::to_string(m.n_sv_));
  if (n_machines != m.machines_.size())
    return err.set(ModelError::kValue, w + ": n_machines=" + std::to_string(n_machines) +
                                 " differs from MACH's n_machines=" + std::to_string(m.machines_.size()));
  // both counts are those of sections already read: the sizes below are bounded by them
  if (!r.need((std::size_t{n_sv} + n_machines) * 8, "log energies and widths")) return false;
  std::vector<double> energy(n_sv);
  for (std::uint32_t i = 0; i < n_sv; ++i) {
    double e;
    if (!r.f64("sv_log_energy", e)) return false;
    if (!(std::fabs(e) <= kMaxLogEnergy))
      return err.set(ModelError::kValue, w + ": sv_log_energy[" + std::to_string(i) + "]=" + fmt_double(e) +
                                   " is not finite or outside [-1e+04, 1e+04]");
    energy[i] = e;
  }
  bool any = false;
  for (std::uint32_t k = 0; k < n_machines; ++k) {
    double a;
    if (!r.f64("amplitude_width", a)) return false;
    if (!(a == 0.0 || (a >= kMinAmplitudeWidth && a <= kMaxAmplitudeWidth)))
      return err.set(ModelError::kValue, w + ": machine " + std::to_string(k) + ": amplitude_width=" +
                                   fmt_double(a) + " must be 0 (no amplitude factor) or within [1e-06, 1e+06]");
    m.machines_[k].amplitude_width = a;
    any = any || a > 0.0;
  }
  if (!r.expect_end()) return false;
  if (!any)
    return err.set(ModelError::kValue, w + ": every amplitude_width is 0 (a model without the amplitude "
                                 "factor is written as format version 1)");
  m.sv_log_energy_ = std::move(energy);
  return true;
}

bool ModelParser::parse_calb(Reader& r, Model& m, ParseError& err) {
  namespace mf = model_format;
  const std::string& w = r.what();
  std::uint32_t rule, n_machines;
  double threshold;
  if (!r.u32("rule", rule) || !r.u32("n_machines", n_machines) || !r.f64("threshold", threshold))
    return false;
  if (rule != mf::kCalibratedRule)
    return err.set(ModelError::kValue, w + ": rule=" + std::to_string(rule) + " is unknown (1: calibrated; a "
                                 "model with the paper's rule has no CALB section)");
  if (n_machines != m.machines_.size())
    return err.set(ModelError::kValue, w + ": n_machines=" + std::to_string(n_machines) +
                                 " differs from MACH's n_machines=" + std::to_string(m.machines_.size()));
  if (!(threshold >= 0.0 && threshold <= 1.0))
    return err.set(ModelError::kValue, w + ": threshold=" + fmt_double(threshold) + " must be within [0, 1]");
  if (!r.need(std::size_t{n_machines} * 16, "slopes and offsets")) return false;
  for (std::uint32_t k = 0; k < n_machines; ++k) {
    double a, b;
    if (!r.f64("slope", a) || !r.f64("offset", b)) return false;
    if (!(a >= 0.0 && a <= mf::kMaxCalibration))
      return err.set(ModelError::kValue, w + ": machine " + std::to_string(k) + ": slope=" + fmt_double(a) +
                                   " must be within [0, 1e+06]");
    if (!(std::fabs(b) <= mf::kMaxCalibration))
      return err.set(ModelError::kValue, w + ": machine " + std::to_string(k) + ": offset=" + fmt_double(b) +
                                   " must be finite and within [-1e+06, 1e+06]");
    m.machines_[k].calib_slope = a;
    m.machines_[k].calib_offset = b;
  }
  if (!r.expect_end()) return false;
  m.calibrated_ = true;
  m.reject_threshold_ = threshold;
  return true;
}

bool ModelParser::check_machines(Model& m, const std::string& origin, ParseError& err) {
  const int nc = static_cast<int>(m.class_names_.size());
  const int nm = static_cast<int>(m.machines_.size());
  if (m.rule_ == DecisionRule::kBinary) {
    if (nm != 1)
      return err.set(ModelError::kValue, origin + ": the binary rule needs 1 machine, got " + std::to_string(nm));
    const auto& mm = m.machines_[0];
    if (!((mm.positive == 1 && mm.negative == 0) || (mm.positive == 0 && mm.negative == 1)))
      return err.set(ModelError::kValue, origin + ": binary machine classes (" + std::to_string(mm.positive) +
                                   ", " + std::to_string(mm.negative) + ") must be (1, 0) or (0, 1)");
  } else {
    if (nm != nc)
      return err.set(ModelError::kValue, origin + ": one_vs_all needs one machine per class (" +
                                   std::to_string(nc) + "), got " + std::to_string(nm));
    for (int k = 0; k < nm; ++k)
      if (m.machines_[static_cast<std::size_t>(k)].positive != k ||
          m.machines_[static_cast<std::size_t>(k)].negative != -1)
        return err.set(ModelError::kValue, origin + ": one_vs_all machine " + std::to_string(k) +
                                     " must have positive_class=" + std::to_string(k) +
                                     " and negative_class=-1");
  }
  std::vector<char> used(static_cast<std::size_t>(m.n_sv_), 0);
  for (const auto& mm : m.machines_)
    for (auto i : mm.sv_index) used[i] = 1;
  for (int i = 0; i < m.n_sv_; ++i)
    if (!used[static_cast<std::size_t>(i)])
      return err.set(ModelError::kValue, origin + ": support vector " + std::to_string(i) +
                                   " is used by no machine");
  return true;
}

namespace {
// The required sections in their order: version 1 has the first four, versions 2 and 3 AMPL
// too (optional in 3), version 4 CALB after them.
constexpr std::uint32_t kRequired[6] = {tag_of("PREP"), tag_of("CLAS"), tag_of("SVBS"),
                                        tag_of("MACH"), tag_of("AMPL"), tag_of("CALB")};
}  // namespace

bool ModelParser::parse_required(int which, Reader& r, Model& m, ParseError& err) {
  switch (which) {
    case 0: return parse_prep(r, m, err);
    case 1: return parse_clas(r, m, err);
    case 2: return parse_svbs(r, m, err);
    case 3: return parse_mach(r, m, err);
    case 4: return parse_ampl(r, m, err);
    default: return parse_calb(r, m, err);
  }
}

// The sections between the header and the checksum (`end`): the required ones in order,
// ancillary ones skipped.
bool ModelParser::parse_sections(const std::uint8_t* data, std::size_t end, std::uint32_t n_sections,
                                 const std::string& origin, Model& m, ParseError& err) {
  namespace mf = model_format;
  const int version = m.format_version_;
  const int n_required = version >= mf::kVersionCalibration ? 6 : version >= mf::kVersionAmplitude ? 5 : 4;
  // version 3 and later: AMPL when some machine has the amplitude factor, else absent
  const bool ampl_optional = version >= mf::kVersionBoundedWindow;
  int next = 0;
  std::size_t pos = mf::kHeaderBytes;
  for (std::uint32_t s = 0; s < n_sections; ++s) {
    if (end - pos < 8)
      return err.set(ModelError::kLayout, origin + ": section " + std::to_string(s) + " header runs past the end");
    Reader sh(data + pos, 8, origin + ": section header", err);
    std::uint32_t tag, bytes;
    if (!sh.u32("tag", tag) || !sh.u32("payload_bytes", bytes)) return false;
    pos += 8;
    const std::size_t padded = (std::size_t{bytes} + 7) / 8 * 8;
    if (padded > end - pos)
      return err.set(ModelError::kLayout, origin + ": section '" + tag_str(tag) + "' (" + std::to_string(bytes) +
                                    " bytes) runs past the end of the file");
    for (std::size_t i = bytes; i < padded; ++i)
      if (data[pos + i] != 0)
        return err.set(ModelError::kValue, origin + ": non-zero padding after section '" + tag_str(tag) + "'");
    Reader r(data + pos, bytes, origin + ": section " + tag_str(tag), err);
    const char first = static_cast<char>(tag & 0xFF);
    if (ampl_optional && next == 4 && n_required == 6 && tag == kRequired[5]) next = 5;  // no AMPL
    if (first >= 'a' && first <= 'z') {
      // ancillary section (e.g. "meta"): skipped
    } else if (next < n_required && tag == kRequired[next]) {
      if (!parse_required(next, r, m, err)) return false;
      ++next;
    } else if (tag == kRequired[4] && n_required == 4) {
      return err.set(ModelError::kLayout, origin + ": section 'AMPL' (the amplitude factor) is not allowed "
                                    "in format version " + std::to_string(version) +
                                    " (it needs version 2)");
    } else if (tag == kRequired[5] && n_required < 6) {
      return err.set(ModelError::kLayout, origin + ": section 'CALB' (the calibrated decision rule) is not "
                                    "allowed in format version " + std::to_string(version) +
                                    " (it needs version 4)");
    } else {
      return err.set(ModelError::kLayout, origin + ": unexpected section '" + tag_str(tag) + "' (expected '" +
                                    (next < n_required ? tag_str(kRequired[next]) : std::string("end")) + "')");
    }
    pos += padded;
  }
  if (next < n_required && !(ampl_optional && next == 4 && n_required == 5)) {
    const int missing = (ampl_optional && next == 4) ? 5 : next;
    return err.set(ModelError::kLayout, origin + ": required section '" + tag_str(kRequired[missing]) + "' missing" +
                                  (missing == 4 ? " (format version 2 has an amplitude factor)" : "") +
                                  (missing == 5 ? " (format version 4 has the calibrated rule)" : ""));
  }
  if (pos != end)
    return err.set(ModelError::kLayout, origin + ": " + std::to_string(end - pos) +
                                  " bytes after the last section, before the checksum");
  return true;
}

bool ModelParser::parse(const std::uint8_t* data, std::size_t size, const std::string& origin,
                        bool borrow, Model& m, ParseError& err) {
  namespace mf = model_format;
  if (data == nullptr && size > 0) return err.set(ModelError::kIo, origin + ": null data");
  if (size < 8 || std::memcmp(data, mf::kMagic, 8) != 0)
    return err.set(ModelError::kNotAModel, origin + ": not an eskin model file (magic bytes \\x89ESKIN\\r\\n missing)");
  if (size < mf::kHeaderBytes + 4)
    return err.set(ModelError::kTruncated, origin + ": truncated: " + std::to_string(size) +
                                     " bytes, shorter than the 36-byte header and checksum");
  Reader h(data, mf::kHeaderBytes, origin + ": header", err);
  std::uint32_t vh, flags, file_bytes, n_sections;
  if (h.raw(8, "magic") == nullptr || !h.u32("version/header_bytes", vh) || !h.u32("flags", flags) ||
      !h.u32("file_bytes", file_bytes) || !h.u32("section_count", n_sections))
    return false;
  const std::uint32_t version = vh & 0xFFFFu, header_bytes = vh >> 16;
  if (version < mf::kMinVersion || version > mf::kVersion)
    return err.set(ModelError::kVersion, origin + ": model format version " + std::to_string(version) +
                                   " is not supported (this library reads versions " +
                                   std::to_string(mf::kMinVersion) + " to " +
                                   std::to_string(mf::kVersion) + ")");
  if (header_bytes != mf::kHeaderBytes)
    return err.set(ModelError::kLayout, origin + ": header_bytes=" + std::to_string(header_bytes) + ", expected 32");
  if (file_bytes > size)
    return err.set(ModelError::kTruncated, origin + ": truncated: the header says " + std::to_string(file_bytes) +
                                     " bytes, only " + std::to_string(size) + " present");
  if (file_bytes < size)
    return err.set(ModelError::kLayout, origin + ": " + std::to_string(size - file_bytes) +
                                  " unexpected bytes after the end of the model (file_bytes=" +
                                  std::to_string(file_bytes) + ")");
  if (file_bytes < mf::kHeaderBytes + 4 || file_bytes > kMaxFileBytes || file_bytes % 4 != 0)
    return err.set(ModelError::kLayout, origin + ": file_bytes=" + std::to_string(file_bytes) + " is impossible");
  std::uint32_t stored_crc = 0;
  for (int i = 3; i >= 0; --i) stored_crc = (stored_crc << 8) | data[file_bytes - 4 + static_cast<std::uint32_t>(i)];
  const std::uint32_t crc = mf::crc32(data, file_bytes - 4);
  if (crc != stored_crc) {
    char buf[96];
    std::snprintf(buf, sizeof buf, ": checksum mismatch (stored CRC-32 0x%lx, computed 0x%lx): the "
                  "file is corrupted", static_cast<unsigned long>(stored_crc),
                  static_cast<unsigned long>(crc));
    return err.set(ModelError::kChecksum, origin + buf);
  }
  // Checksum good: now the structure.
  if (flags & ~mf::kFlagFloat64)
    return err.set(ModelError::kValue, origin + ": unknown flags 0x" + std::to_string(flags));
  if (!h.zero_u32("reserved") || !h.zero_u32("reserved")) return false;
  m.borrow_ = borrow;
  m.float64_ = (flags & mf::kFlagFloat64) != 0;
  m.file_bytes_ = file_bytes;
  m.format_version_ = static_cast<int>(version);
  if (!parse_sections(data, file_bytes - 4, n_sections, origin, m, err)) return false;
  if (!check_machines(m, origin, err)) return false;
  m.tables_ = detail::build_decision_tables(m);
  return true;
}

bool Model::parse(const std::uint8_t* data, std::size_t size, Model* out, ModelLoadError* error,
                  bool in_place) {
  ParseError err;
  Model m;
  if (out == nullptr) err.set(ModelError::kIo, "model: no Model to fill");
  else if (ModelParser::parse(data, size, "model", in_place, m, err)) *out = std::move(m);
  if (err.failed && error != nullptr) {
    error->code = err.code;
    error->message = std::move(err.message);
  }
  return !err.failed;
}

namespace {
Model parse_or_fail(const std::uint8_t* data, std::size_t size, const std::string& origin,
                    bool borrow) {
  ParseError err;
  Model m;
  if (!ModelParser::parse(data, size, origin, borrow, m, err)) fail(err.code, err.message);
  return m;
}
}  // namespace

Model Model::from_bytes(const std::uint8_t* data, std::size_t size) {
  return parse_or_fail(data, size, "model", /*borrow=*/false);
}

Model Model::view_bytes(const std::uint8_t* data, std::size_t size) {
  return parse_or_fail(data, size, "model", /*borrow=*/true);
}

#if !defined(ESKIN_DEVICE)  // a controller has no file system (and no iostreams)
Model Model::load(const std::string& path) {
  std::ifstream f(path, std::ios::binary);
  if (!f) fail(ModelError::kIo, path + ": cannot open the model file");
  f.seekg(0, std::ios::end);
  const std::streamoff n = f.tellg();
  if (n < 0) fail(ModelError::kIo, path + ": cannot read the model file");
  if (static_cast<std::uint64_t>(n) > kMaxFileBytes)
    fail(ModelError::kLayout, path + ": " + std::to_string(n) + " bytes, too large for a model file");
  f.seekg(0);
  std::vector<std::uint8_t> buf(static_cast<std::size_t>(n));
  if (n > 0 && !f.read(reinterpret_cast<char*>(buf.data()), n))
    fail(ModelError::kIo, path + ": cannot read the model file");
  return parse_or_fail(buf.data(), buf.size(), path, /*borrow=*/false);
}

#endif  // !ESKIN_DEVICE

}  // namespace eskin
