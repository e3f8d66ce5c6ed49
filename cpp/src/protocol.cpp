#include "eskin/protocol.hpp"

#include <cstring>

namespace eskin::protocol {

namespace {

// ---- little-endian field access (portable: shifts, no type punning)
struct Writer {
  std::uint8_t* p;
  void u8(std::uint8_t v) { *p++ = v; }
  void u16(std::uint16_t v) {
    *p++ = static_cast<std::uint8_t>(v);
    *p++ = static_cast<std::uint8_t>(v >> 8);
  }
  void u32(std::uint32_t v) {
    for (int i = 0; i < 4; ++i) *p++ = static_cast<std::uint8_t>(v >> (8 * i));
  }
  void u64(std::uint64_t v) {
    for (int i = 0; i < 8; ++i) *p++ = static_cast<std::uint8_t>(v >> (8 * i));
  }
  void i16(std::int16_t v) { u16(static_cast<std::uint16_t>(v)); }
  void f64(double v) {
    std::uint64_t bits;
    std::memcpy(&bits, &v, sizeof bits);
    u64(bits);
  }
  void bytes(const void* src, std::size_t n) {
    if (n > 0) std::memcpy(p, src, n);
    p += n;
  }
};

struct Reader {
  const std::uint8_t* p;
  std::uint8_t u8() { return *p++; }
  std::uint16_t u16() {
    const std::uint16_t v = static_cast<std::uint16_t>(p[0] | (p[1] << 8));
    p += 2;
    return v;
  }
  std::uint32_t u32() {
    std::uint32_t v = 0;
    for (int i = 0; i < 4; ++i) v |= static_cast<std::uint32_t>(p[i]) << (8 * i);
    p += 4;
    return v;
  }
  std::uint64_t u64() {
    std::uint64_t v = 0;
    for (int i = 0; i < 8; ++i) v |= static_cast<std::uint64_t>(p[i]) << (8 * i);
    p += 8;
    return v;
  }
  std::int16_t i16() { return static_cast<std::int16_t>(u16()); }
  double f64() {
    const std::uint64_t bits = u64();
    double v;
    std::memcpy(&v, &bits, sizeof v);
    return v;
  }
};


/// Payload size of a frame as it will be serialised; 0 with ok=false if invalid.
std::size_t payload_size(const Frame& f, bool& ok) {
  ok = true;
  switch (f.type) {
    case FrameType::data: {
      const std::size_t taxels = static_cast<std::size_t>(f.data.rows) * f.data.cols;
      if (taxels == 0 || f.data.n_samples == 0 || f.data.samples == nullptr) break;
      return kDataFixedSize + static_cast<std::size_t>(f.data.n_samples) * taxels * 2;
    }
    case FrameType::decision:
      if (f.decision.n_values > kMaxDecisionValues) break;
      return kDecisionFixedSize + static_cast<std::size_t>(f.decision.n_values) * 8;
    case FrameType::status:
      return kStatusSize;
    case FrameType::info:
      if (f.info.names_len > 0 && f.info.class_names == nullptr) break;
      return kInfoFixedSize + f.info.names_len;
    case FrameType::ping:
    case FrameType::pong:
      return kPingSize;
    case FrameType::start:
    case FrameType::stop:
    case FrameType::info_request:
      return 0;
  }
  ok = false;
  return 0;
}

}  // namespace

bool is_known_type(std::uint8_t type) {
  switch (static_cast<FrameType>(type)) {
    case FrameType::data:
    case FrameType::decision:
    case FrameType::status:
    case FrameType::info:
    case FrameType::pong:
    case FrameType::start:
    case FrameType::stop:
    case FrameType::ping:
    case FrameType::info_request:
      return true;
  }
  return false;
}

const char* frame_type_name(FrameType type) {
  switch (type) {
    case FrameType::data: return "DATA";
    case FrameType::decision: return "DECISION";
    case FrameType::status: return "STATUS";
    case FrameType::info: return "INFO";
    case FrameType::pong: return "PONG";
    case FrameType::start: return "START";
    case FrameType::stop: return "STOP";
    case FrameType::ping: return "PING";
    case FrameType::info_request: return "INFO_REQUEST";
  }
  return "UNKNOWN";
}

std::ptrdiff_t fixed_payload_size(FrameType type) {
  switch (type) {
    case FrameType::data: return kDataFixedSize;
    case FrameType::decision: return kDecisionFixedSize;
    case FrameType::status: return kStatusSize;
    case FrameType::info: return kInfoFixedSize;
    case FrameType::ping:
    case FrameType::pong: return kPingSize;
    case FrameType::start:
    case FrameType::stop:
    case FrameType::info_request: return 0;
  }
  return -1;
}

std::size_t cobs_encode(const std::uint8_t* in, std::size_t size, std::uint8_t* out,
                        std::size_t cap) {
  if (cap < max_encoded_size(size) - 1) return 0;
  std::size_t code_at = 0;
  std::size_t o = 1;
  std::uint8_t code = 1;
  for (std::size_t i = 0; i < size; ++i) {
    if (in[i] == 0) {
      out[code_at] = code;
      code_at = o++;
      code = 1;
    } else {
      out[o++] = in[i];
      if (++code == 0xFF && i + 1 < size) {
        out[code_at] = code;
        code_at = o++;
        code = 1;
      }
    }
  }
  out[code_at] = code;
  return o;
}

std::ptrdiff_t cobs_decode(const std::uint8_t* in, std::size_t size, std::uint8_t* out,
                           std::size_t cap) {
  std::size_t o = 0;
  std::size_t i = 0;
  while (i < size) {
    const std::uint8_t code = in[i++];
    if (code == 0) return -1;
    const std::size_t run = static_cast<std::size_t>(code) - 1;
    if (run > size - i || run > cap - o) return -1;
    for (std::size_t k = 0; k < run; ++k) {
      if (in[i] == 0) return -1;
      out[o++] = in[i++];
    }
    if (code != 0xFF && i < size) {
      if (o >= cap) return -1;
      out[o++] = 0;
    }
  }
  return static_cast<std::ptrdiff_t>(o);
}

const char* encode_status_message(EncodeStatus status) {
  switch (status) {
    case EncodeStatus::ok: return "ok";
    case EncodeStatus::buffer_too_small: return "output buffer too small for the frame";
    case EncodeStatus::invalid_frame:
      return "invalid frame (unknown type, empty or oversized payload, too many values)";
  }
  return "unknown encode status";
}

std::size_t serialize_frame(const Frame& f, std::uint8_t* raw, std::size_t cap,
                            EncodeStatus* status) {
  auto fail = [status](EncodeStatus s) {
    if (status) *status = s;
    return std::size_t{0};
  };
  bool ok = false;
  const std::size_t payload = payload_size(f, ok);
  if (!ok) return fail(EncodeStatus::invalid_frame);
  const std::size_t total = kHeaderSize + payload + kCrcSize;
  if (total > kMaxFrameSize) return fail(EncodeStatus::invalid_frame);
  if (total > cap) return fail(EncodeStatus::buffer_too_small);

  Writer w{raw};
  w.u8(static_cast<std::uint8_t>(f.type));
  w.u8(f.flags);
  w.u16(f.seq);
  switch (f.type) {
    case FrameType::data: {
      const auto& d = f.data;
      w.u64(d.first_sample);
      w.u64(d.timestamp_us);
      w.u8(d.rows);
      w.u8(d.cols);
      w.u16(d.n_samples);
      const std::size_t n = static_cast<std::size_t>(d.n_samples) * d.rows * d.cols;
      for (std::size_t i = 0; i < n; ++i) w.i16(d.samples[i]);
      break;
    }
    case FrameType::decision: {
      const auto& d = f.decision;
      w.u64(d.onset_sample);
      w.u64(d.offset_sample);
      w.u64(d.decided_sample);
      w.u64(d.timestamp_us);
      w.u32(d.latency_us);
      w.i16(d.label);
      w.u8(d.dont_know);
      w.u8(d.n_values);
      for (std::size_t i = 0; i < d.n_values; ++i) w.f64(d.values[i]);
      break;
    }
    case FrameType::status: {
      const auto& s = f.status;
      w.u64(s.uptime_us);
      w.u64(s.next_sample);
      w.u64(s.samples_sent);
      w.u64(s.dropped_samples);
      w.u32(s.overrun_events);
      w.u32(s.rx_errors);
      w.u32(s.faults_injected);
      w.u32(s.decisions_sent);
      w.u32(s.pacing_p50_ns);
      w.u32(s.pacing_p99_ns);
      w.u32(s.pacing_max_ns);
      w.u8(static_cast<std::uint8_t>(s.state));
      w.u8(s.host_connected);
      w.u16(s.connections);
      w.u32(s.decisions_dropped);
      w.u32(s.frames_dropped);
      break;
    }
    case FrameType::info: {
      const auto& s = f.info;
      w.u8(s.rows);
      w.u8(s.cols);
      w.u16(s.samples_per_frame);
      w.u16(s.protocol_version);
      w.u8(s.n_classes);
      w.u8(s.has_model);
      w.f64(s.sample_rate_hz);
      w.f64(s.volts_per_count);
      w.f64(s.speed);
      w.u16(s.names_len);
      w.bytes(s.class_names, s.names_len);
      break;
    }
    case FrameType::ping:
    case FrameType::pong:
      w.u32(f.ping.token);
      w.u64(f.ping.timestamp_us);
      break;
    case FrameType::start:
    case FrameType::stop:
    case FrameType::info_request:
      break;
  }
  const std::uint32_t crc = crc32(raw, kHeaderSize + payload);
  w.u32(crc);
  if (status) *status = EncodeStatus::ok;
  return total;
}

std::size_t FrameEncoderBase::encode(const Frame& frame, std::uint8_t* out, std::size_t cap) {
  const std::size_t n = serialize_frame(frame, raw_, cap_, &status_);
  if (n == 0) return 0;
  if (cap < max_encoded_size(n)) {
    status_ = EncodeStatus::buffer_too_small;
    return 0;
  }
  const std::size_t e = cobs_encode(raw_, n, out, cap);
  out[e] = kDelimiter;
  status_ = EncodeStatus::ok;
  return e + 1;
}

// ---- decoder -------------------------------------------------------------------------------

FrameDecoderBase::FrameDecoderBase(std::uint8_t* block, std::uint8_t* raw, std::int16_t* samples,
                                   std::size_t capacity, std::size_t max_frame_size,
                                   bool wait_for_delimiter)
    : block_(block),
      raw_(raw),
      samples_(samples),
      max_frame_size_(max_frame_size < kHeaderSize + kCrcSize
                          ? kHeaderSize + kCrcSize
                          : (max_frame_size > capacity ? capacity : max_frame_size)),
      max_block_(max_encoded_size(max_frame_size_) - 1),
      wait_for_delimiter_(wait_for_delimiter),
      synced_(!wait_for_delimiter) {}

void FrameDecoderBase::reset(bool reset_stats) {
  // the input resumes anywhere (a reopened port): skip to the next delimiter again, or the tail
  // of a frame would be decoded as a frame and counted as corrupted
  synced_ = !wait_for_delimiter_;
  fill_ = 0;
  discarding_ = false;
  has_frame_ = false;
  have_seq_ = false;
  have_sample_ = false;
  if (reset_stats) stats_ = DecoderStats{};
}

std::size_t FrameDecoderBase::feed(const std::uint8_t* data, std::size_t size) {
  has_frame_ = false;
  std::size_t i = 0;
  while (i < size) {
    const std::uint8_t b = data[i++];
    ++stats_.bytes;
    if (!synced_) {
      if (b == kDelimiter) {
        synced_ = true;
      } else {
        ++stats_.skipped_bytes;
      }
      continue;
    }
    if (b == kDelimiter) {
      if (discarding_) {
        discarding_ = false;
        fill_ = 0;
        continue;
      }
      if (fill_ == 0) continue;  // repeated delimiters are idle fill
      finish_block();
      fill_ = 0;
      if (has_frame_) return i;
      continue;
    }
    if (discarding_) continue;
    if (fill_ == max_block_) {
      ++stats_.oversize;
      discarding_ = true;  // up to the next delimiter, which empties the block
      continue;
    }
    block_[fill_++] = b;
  }
  return i;
}

void FrameDecoderBase::finish_block() {
  const std::ptrdiff_t len = cobs_decode(block_, fill_, raw_, max_frame_size_);
  if (len < 0) {
    // Not valid COBS, or decodes to more than max_frame_size bytes.
    ++stats_.malformed;
    return;
  }
  const auto n = static_cast<std::size_t>(len);
  if (n < kHeaderSize + kCrcSize) {
    ++stats_.malformed;
    return;
  }
  const std::uint8_t* t = raw_ + n - kCrcSize;
  const std::uint32_t want = static_cast<std::uint32_t>(t[0]) |
                             (static_cast<std::uint32_t>(t[1]) << 8) |
                             (static_cast<std::uint32_t>(t[2]) << 16) |
                             (static_cast<std::uint32_t>(t[3]) << 24);
  if (crc32(raw_, n - kCrcSize) != want) {
    ++stats_.crc_errors;
    return;
  }
  if (!parse(n)) {
    ++stats_.malformed;
    return;
  }
  has_frame_ = true;
  ++stats_.frames;
  if (have_seq_ && !(frame_.flags & flags::kSync) && frame_.seq != next_seq_) {
    ++stats_.sequence_gaps;
    stats_.lost_frames += static_cast<std::uint16_t>(frame_.seq - next_seq_);
  }
  have_seq_ = true;
  next_seq_ = static_cast<std::uint16_t>(frame_.seq + 1);
  if (frame_.type == FrameType::data) {
    const auto& d = frame_.data;
    ++stats_.data_frames;
    stats_.samples += d.n_samples;
    if (have_sample_) {
      if (d.first_sample > next_sample_) {
        stats_.lost_samples += d.first_sample - next_sample_;
      } else if (d.first_sample < next_sample_) {
        ++stats_.sample_index_resets;
      }
    }
    have_sample_ = true;
    next_sample_ = d.first_sample + d.n_samples;
  }
}

bool FrameDecoderBase::parse(std::size_t len) {
  Reader r{raw_};
  const std::uint8_t type = r.u8();
  if (!is_known_type(type)) return false;
  Frame& f = frame_;
  f.type = static_cast<FrameType>(type);
  f.flags = r.u8();
  f.seq = r.u16();
  const std::size_t payload = len - kHeaderSize - kCrcSize;
  const std::ptrdiff_t fixed = fixed_payload_size(f.type);
  if (fixed < 0 || payload < static_cast<std::size_t>(fixed)) return false;
  switch (f.type) {
    case FrameType::data: {
      auto& d = f.data;
      d.first_sample = r.u64();
      d.timestamp_us = r.u64();
      d.rows = r.u8();
      d.cols = r.u8();
      d.n_samples = r.u16();
      const std::size_t n = static_cast<std::size_t>(d.n_samples) * d.rows * d.cols;
      if (n == 0 || payload != kDataFixedSize + 2 * n) return false;
      for (std::size_t i = 0; i < n; ++i) samples_[i] = r.i16();
      d.samples = samples_;
      return true;
    }
    case FrameType::decision: {
      auto& d = f.decision;
      d.onset_sample = r.u64();
      d.offset_sample = r.u64();
      d.decided_sample = r.u64();
      d.timestamp_us = r.u64();
      d.latency_us = r.u32();
      d.label = r.i16();
      d.dont_know = r.u8();
      d.n_values = r.u8();
      if (d.n_values > kMaxDecisionValues || payload != kDecisionFixedSize + 8U * d.n_values)
        return false;
      d.values.fill(0.0);
      for (std::size_t i = 0; i < d.n_values; ++i) d.values[i] = r.f64();
      return true;
    }
    case FrameType::status: {
      if (payload != kStatusSize) return false;
      auto& s = f.status;
      s.uptime_us = r.u64();
      s.next_sample = r.u64();
      s.samples_sent = r.u64();
      s.dropped_samples = r.u64();
      s.overrun_events = r.u32();
      s.rx_errors = r.u32();
      s.faults_injected = r.u32();
      s.decisions_sent = r.u32();
      s.pacing_p50_ns = r.u32();
      s.pacing_p99_ns = r.u32();
      s.pacing_max_ns = r.u32();
      const std::uint8_t state = r.u8();
      if (state > static_cast<std::uint8_t>(StreamState::finished)) return false;
      s.state = static_cast<StreamState>(state);
      s.host_connected = r.u8();
      s.connections = r.u16();
      s.decisions_dropped = r.u32();
      s.frames_dropped = r.u32();
      return true;
    }
    case FrameType::info: {
      auto& s = f.info;
      s.rows = r.u8();
      s.cols = r.u8();
      s.samples_per_frame = r.u16();
      s.protocol_version = r.u16();
      s.n_classes = r.u8();
      s.has_model = r.u8();
      s.sample_rate_hz = r.f64();
      s.volts_per_count = r.f64();
      s.speed = r.f64();
      s.names_len = r.u16();
      if (payload != kInfoFixedSize + s.names_len) return false;
      s.class_names = reinterpret_cast<const char*>(r.p);
      return true;
    }
    case FrameType::ping:
    case FrameType::pong:
      if (payload != kPingSize) return false;
      f.ping.token = r.u32();
      f.ping.timestamp_us = r.u64();
      return true;
    case FrameType::start:
    case FrameType::stop:
    case FrameType::info_request:
      return payload == 0;
  }
  return false;  // every known type has returned above
}

std::ptrdiff_t pack_class_names(const std::string* names, std::size_t n, char* out,
                                std::size_t capacity) noexcept {
  if (n > 255 || (n > 0 && (names == nullptr || out == nullptr))) return -1;
  std::size_t len = 0;
  for (std::size_t i = 0; i < n; ++i) {
    const std::string& c = names[i];
    if (c.find('\n') != std::string::npos) return -1;
    const std::size_t need = c.size() + (i ? 1 : 0);
    if (need > capacity - len) return -1;
    if (i) out[len++] = '\n';
    for (char ch : c) out[len++] = ch;
  }
  return static_cast<std::ptrdiff_t>(len);
}

}  // namespace eskin::protocol
