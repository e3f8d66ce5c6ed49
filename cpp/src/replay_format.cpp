#include "eskin/replay_format.hpp"

#include <cmath>
#include <cstdio>
#include <cstring>

#include "eskin/crc32.hpp"

namespace eskin::replay {

namespace {

std::uint64_t rd(const std::uint8_t* p, int n) {
  std::uint64_t v = 0;
  for (int i = 0; i < n; ++i) v |= static_cast<std::uint64_t>(p[i]) << (8 * i);
  return v;
}

double rd_f64(const std::uint8_t* p) {
  const std::uint64_t bits = rd(p, 8);
  double v;
  std::memcpy(&v, &bits, sizeof v);
  return v;
}

/// Offset of the first byte that is not strict UTF-8 (RFC 3629: no overlong forms, no
/// surrogates, nothing above U+10FFFF, as Python decodes it), or n when all of it is.
std::size_t utf8_error_at(const std::uint8_t* s, std::size_t n) {
  std::size_t i = 0;
  while (i < n) {
    const std::uint8_t c = s[i];
    if (c < 0x80) {
      ++i;
      continue;
    }
    int len = 0;
    std::uint8_t lo = 0x80, hi = 0xBF;  // range of the second byte
    if (c >= 0xC2 && c <= 0xDF) len = 2;
    else if (c == 0xE0) len = 3, lo = 0xA0;
    else if (c == 0xED) len = 3, hi = 0x9F;
    else if (c >= 0xE1 && c <= 0xEF) len = 3;
    else if (c == 0xF0) len = 4, lo = 0x90;
    else if (c >= 0xF1 && c <= 0xF3) len = 4;
    else if (c == 0xF4) len = 4, hi = 0x8F;
    else return i;
    if (i + static_cast<std::size_t>(len) > n) return i;
    if (s[i + 1] < lo || s[i + 1] > hi) return i;
    for (int k = 2; k < len; ++k)
      if (s[i + static_cast<std::size_t>(k)] < 0x80 || s[i + static_cast<std::size_t>(k)] > 0xBF)
        return i;
    i += static_cast<std::size_t>(len);
  }
  return n;
}

ReplayStatus fail(ReplayError* e, ReplayStatus s) {
  if (e != nullptr) e->status = s;
  return s;
}

}  // namespace

ReplayStatus check_replay(const std::uint8_t* p, std::size_t size, SizeRule rule,
                          ReplayHeader* header, ReplayError* error) noexcept {
  ReplayError scratch;
  ReplayError* e = error != nullptr ? error : &scratch;
  *e = ReplayError{};
  if (p == nullptr || size < kHeaderSize || std::memcmp(p, kMagic, 8) != 0)
    return fail(e, ReplayStatus::bad_magic);
  ReplayHeader h;
  h.version = static_cast<std::uint32_t>(rd(p + 8, 4));
  h.data_offset = static_cast<std::uint32_t>(rd(p + 12, 4));
  h.n_samples = rd(p + 16, 8);
  h.rows = static_cast<std::uint16_t>(rd(p + 24, 2));
  h.cols = static_cast<std::uint16_t>(rd(p + 26, 2));
  h.n_segments = static_cast<std::uint32_t>(rd(p + 28, 4));
  h.sample_rate_hz = rd_f64(p + 32);
  h.volts_per_count = rd_f64(p + 40);
  h.names_len = static_cast<std::uint32_t>(rd(p + 48, 4));
  h.crc = static_cast<std::uint32_t>(rd(p + 52, 4));
  if (h.version != kVersion) {
    e->value = h.version;
    e->expected = kVersion;
    return fail(e, ReplayStatus::bad_version);
  }
  // 64-bit sums of 32-bit fields: no wrap-around
  const std::uint64_t table_end = kHeaderSize + std::uint64_t{h.n_segments} * kSegmentSize +
                                  h.names_len;
  if (h.data_offset < table_end || h.data_offset > size || h.data_offset % 8 != 0) {
    e->value = h.data_offset;
    e->expected = table_end;
    return fail(e, ReplayStatus::bad_data_offset);
  }
  const std::uint8_t zero[4] = {0, 0, 0, 0};
  std::uint32_t c = eskin::crc32(p, 52);
  c = eskin::crc32(zero, 4, c);
  c = eskin::crc32(p + kHeaderSize, h.data_offset - kHeaderSize, c);
  if (c != h.crc) {
    e->value = h.crc;
    e->expected = c;
    return fail(e, ReplayStatus::bad_crc);
  }
  if (h.rows < 1 || h.rows > kMaxGrid || h.cols < 1 || h.cols > kMaxGrid) {
    e->value = h.rows;
    e->expected = h.cols;
    return fail(e, ReplayStatus::bad_grid);
  }
  // (NaN fails both comparisons)
  if (!(h.sample_rate_hz >= kMinSampleRateHz && h.sample_rate_hz <= kMaxSampleRateHz)) {
    e->real = h.sample_rate_hz;
    return fail(e, ReplayStatus::bad_sample_rate);
  }
  if (!(std::isfinite(h.volts_per_count) && h.volts_per_count > 0.0)) {
    e->real = h.volts_per_count;
    return fail(e, ReplayStatus::bad_volts_per_count);
  }
  // n_samples against the bytes after data_offset, by division first (no product can wrap)
  const std::uint64_t per_sample = std::uint64_t{h.rows} * h.cols * 2;
  const std::uint64_t room = size - h.data_offset;
  const bool fits = h.n_samples <= room / per_sample;
  const bool size_ok = rule == SizeRule::exact ? fits && h.n_samples * per_sample == room : fits;
  if (!size_ok) {
    e->value = size;
    // what the header declares, saturated
    e->expected = h.n_samples > (~std::uint64_t{0} - h.data_offset) / per_sample
                      ? ~std::uint64_t{0}
                      : h.data_offset + h.n_samples * per_sample;
    e->index = h.n_samples;
    return fail(e, ReplayStatus::bad_size);
  }
  h.segments = p + kHeaderSize;
  h.class_names = reinterpret_cast<const char*>(p + kHeaderSize + std::size_t{h.n_segments} * kSegmentSize);
  const auto* names = reinterpret_cast<const std::uint8_t*>(h.class_names);
  const std::size_t bad = utf8_error_at(names, h.names_len);
  if (bad < h.names_len) {
    e->value = bad;
    e->expected = 0;
    return fail(e, ReplayStatus::bad_class_names);
  }
  std::uint32_t n_names = 0;
  if (h.names_len > 0) {
    n_names = 1;
    for (std::size_t i = 0; i < h.names_len; ++i) n_names += names[i] == '\n';
  }
  if (n_names > kMaxClassNames) {
    e->value = n_names;
    e->expected = 1;  // too many (not a UTF-8 error)
    return fail(e, ReplayStatus::bad_class_names);
  }
  h.n_class_names = n_names;
  h.samples = reinterpret_cast<const std::int16_t*>(p + h.data_offset);
  // segments: the first bad one of the first problem found, problem by problem (as the Python
  // reader reports), with the count of segments sharing that problem
  for (int problem = 1; problem <= 4; ++problem) {
    std::uint64_t first = 0, count = 0;
    for (std::uint32_t i = 0; i < h.n_segments; ++i) {
      const ReplaySegment s = segment(h, i);
      bool is_bad = false;
      switch (static_cast<SegmentProblem>(problem)) {
        case SegmentProblem::empty: is_bad = s.length == 0; break;
        case SegmentProblem::past_end:
          is_bad = s.start > h.n_samples || s.length > h.n_samples - s.start;
          break;
        case SegmentProblem::label:
          is_bad = s.label < -1 || s.label >= static_cast<std::int64_t>(n_names);
          break;
        case SegmentProblem::contact: {
          const bool unknown = s.contact_onset == -1 && s.contact_offset == -1;
          is_bad = !unknown && (s.contact_onset < 0 || s.contact_offset < s.contact_onset ||
                                static_cast<std::uint64_t>(s.contact_offset) > s.length);
          break;
        }
        case SegmentProblem::none: break;
      }
      if (is_bad && count++ == 0) first = i;
    }
    if (count > 0) {
      const ReplaySegment s = segment(h, static_cast<std::size_t>(first));
      e->segment_problem = static_cast<SegmentProblem>(problem);
      e->index = first;
      e->bad_count = count;
      switch (e->segment_problem) {
        case SegmentProblem::empty: e->value = s.length; break;
        case SegmentProblem::past_end:
          e->value = s.start;
          e->expected = s.length;
          e->value2 = static_cast<std::int64_t>(h.n_samples);
          break;
        case SegmentProblem::label:
          e->value2 = s.label;
          e->expected = n_names;
          break;
        case SegmentProblem::contact:
          e->value2 = s.contact_offset;
          e->onset = s.contact_onset;
          e->value = s.length;
          break;
        case SegmentProblem::none: break;
      }
      return fail(e, ReplayStatus::bad_segment);
    }
  }
  if (header != nullptr) *header = h;
  return ReplayStatus::ok;
}

ReplaySegment segment(const ReplayHeader& h, std::size_t i) noexcept {
  const std::uint8_t* s = h.segments + i * kSegmentSize;
  ReplaySegment seg;
  seg.start = rd(s, 8);
  seg.length = rd(s + 8, 8);
  seg.contact_onset = static_cast<std::int64_t>(rd(s + 16, 8));
  seg.contact_offset = static_cast<std::int64_t>(rd(s + 24, 8));
  seg.label = static_cast<std::int32_t>(static_cast<std::uint32_t>(rd(s + 32, 4)));
  seg.recording = static_cast<std::uint32_t>(rd(s + 36, 4));
  return seg;
}

const char* field_name(ReplayStatus status) noexcept {
  switch (status) {
    case ReplayStatus::ok: return "";
    case ReplayStatus::bad_magic: return "magic";
    case ReplayStatus::bad_version: return "version";
    case ReplayStatus::bad_data_offset: return "data_offset";
    case ReplayStatus::bad_crc: return "crc";
    case ReplayStatus::bad_grid: return "grid";
    case ReplayStatus::bad_sample_rate: return "sample_rate_hz";
    case ReplayStatus::bad_volts_per_count: return "volts_per_count";
    case ReplayStatus::bad_size: return "size";
    case ReplayStatus::bad_class_names: return "class_names";
    case ReplayStatus::bad_segment: return "segment";
  }
  return "?";
}

const char* format_error(const ReplayError& e, char* out, std::size_t cap) noexcept {
  if (out == nullptr || cap == 0) return out;
  using ull = unsigned long long;
  using ll = long long;
  switch (e.status) {
    case ReplayStatus::ok: std::snprintf(out, cap, "ok"); break;
    case ReplayStatus::bad_magic:
      std::snprintf(out, cap, "magic: not an eskin replay file (no ESKREPLY header of %u bytes)",
                    static_cast<unsigned>(kHeaderSize));
      break;
    case ReplayStatus::bad_version:
      std::snprintf(out, cap, "version = %llu: this reader reads replay version %llu",
                    static_cast<ull>(e.value), static_cast<ull>(e.expected));
      break;
    case ReplayStatus::bad_data_offset:
      std::snprintf(out, cap,
                    "data_offset = %llu: not a multiple of 8 at or after the segment table and "
                    "class names (byte %llu) and inside the file",
                    static_cast<ull>(e.value), static_cast<ull>(e.expected));
      break;
    case ReplayStatus::bad_crc:
      std::snprintf(out, cap,
                    "crc = 0x%08llx: the header's checksum is 0x%08llx (corrupted file)",
                    static_cast<ull>(e.value), static_cast<ull>(e.expected));
      break;
    case ReplayStatus::bad_grid:
      std::snprintf(out, cap, "grid = %llux%llu: not within 1..255 x 1..255",
                    static_cast<ull>(e.value), static_cast<ull>(e.expected));
      break;
    case ReplayStatus::bad_sample_rate:
      std::snprintf(out, cap, "sample_rate_hz = %.17g: not a rate of %g to %g Hz", e.real,
                    kMinSampleRateHz, kMaxSampleRateHz);
      break;
    case ReplayStatus::bad_volts_per_count:
      std::snprintf(out, cap, "volts_per_count = %.17g: not a finite number > 0", e.real);
      break;
    case ReplayStatus::bad_size:
      if (e.expected == ~std::uint64_t{0})
        std::snprintf(out, cap,
                      "size = %llu bytes: n_samples = %llu declares more than 2^64 bytes",
                      static_cast<ull>(e.value), static_cast<ull>(e.index));
      else
        std::snprintf(out, cap,
                      "size = %llu bytes: n_samples = %llu declares %llu bytes with the header",
                      static_cast<ull>(e.value), static_cast<ull>(e.index),
                      static_cast<ull>(e.expected));
      break;
    case ReplayStatus::bad_class_names:
      if (e.expected == 1)
        std::snprintf(out, cap, "class_names = %llu names: at most 255",
                      static_cast<ull>(e.value));
      else
        std::snprintf(out, cap, "class_names: not valid UTF-8 at byte %llu",
                      static_cast<ull>(e.value));
      break;
    case ReplayStatus::bad_segment:
      switch (e.segment_problem) {
        case SegmentProblem::empty:
          std::snprintf(out, cap, "segment %llu: length = 0 (%llu bad segments)",
                        static_cast<ull>(e.index), static_cast<ull>(e.bad_count));
          break;
        case SegmentProblem::past_end:
          std::snprintf(out, cap,
                        "segment %llu: start %llu + length %llu runs past the end of the stream "
                        "(%lld samples) (%llu bad segments)",
                        static_cast<ull>(e.index), static_cast<ull>(e.value),
                        static_cast<ull>(e.expected), static_cast<ll>(e.value2),
                        static_cast<ull>(e.bad_count));
          break;
        case SegmentProblem::label:
          std::snprintf(out, cap,
                        "segment %llu: label = %lld: neither -1 nor a class index (< %llu) "
                        "(%llu bad segments)",
                        static_cast<ull>(e.index), static_cast<ll>(e.value2),
                        static_cast<ull>(e.expected), static_cast<ull>(e.bad_count));
          break;
        case SegmentProblem::contact:
          std::snprintf(out, cap,
                        "segment %llu: contact interval = [%lld, %lld): neither -1/-1 nor "
                        "within [0, length %llu] with onset <= offset (%llu bad segments)",
                        static_cast<ull>(e.index), static_cast<ll>(e.onset),
                        static_cast<ll>(e.value2), static_cast<ull>(e.value),
                        static_cast<ull>(e.bad_count));
          break;
        case SegmentProblem::none: std::snprintf(out, cap, "segment %llu", static_cast<ull>(e.index)); break;
      }
      break;
  }
  return out;
}

}  // namespace eskin::replay
