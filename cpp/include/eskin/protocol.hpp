// The eskin wire protocol between the skin controller and its host (docs/wire-protocol.md).
//
// A frame on the wire is COBS-encoded and ends with one 0x00 delimiter. Decoded, a frame is
//   u8 type | u8 flags | u16 seq | payload (depends on type) | u32 CRC-32
// all little-endian; the CRC is the zlib / ISO-HDLC CRC-32 of every byte before it.
//
// Everything here is heap-free: the encoder writes into caller buffers, the decoder owns
// fixed-size buffers allocated with the object, and no function throws on the byte path.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <string>

#include "eskin/crc32.hpp"

namespace eskin::protocol {

inline constexpr std::uint16_t kProtocolVersion = 2;
inline constexpr std::uint8_t kDelimiter = 0x00;

/// Size of the common header (type, flags, seq) and of the CRC trailer.
inline constexpr std::size_t kHeaderSize = 4;
inline constexpr std::size_t kCrcSize = 4;
/// Largest decoded frame (header + payload + CRC) any party may send.
inline constexpr std::size_t kMaxFrameSize = 4096;
/// Most decision values one DECISION frame carries (one per binary machine).
inline constexpr std::size_t kMaxDecisionValues = 16;
/// Most taxels (rows * cols) one DATA frame may describe.
inline constexpr std::size_t kMaxTaxels = 255 * 255;

/// Worst-case COBS encoding of n bytes, plus the trailing delimiter.
constexpr std::size_t max_encoded_size(std::size_t n) { return n + n / 254 + 2; }
inline constexpr std::size_t kMaxEncodedFrameSize = max_encoded_size(kMaxFrameSize);

enum class FrameType : std::uint8_t {
  // controller -> host
  data = 0x01,
  decision = 0x02,
  status = 0x03,
  info = 0x04,
  pong = 0x13,
  // host -> controller
  start = 0x10,
  stop = 0x11,
  ping = 0x12,
  info_request = 0x14,
};

/// Bits of the header's flags byte.
namespace flags {
/// The sender dropped samples (output full or no host) since its previous DATA frame.
inline constexpr std::uint8_t kOverrun = 0x01;
/// First frame of a stream (after start or a host (re)connection): the receiver does not count
/// a sequence gap on this frame.
inline constexpr std::uint8_t kSync = 0x02;
/// DATA: the replay wrapped around (--loop) at or before this frame.
inline constexpr std::uint8_t kLoop = 0x04;
}  // namespace flags

/// Fixed payload sizes (bytes after the 4-byte header, before the CRC).
inline constexpr std::size_t kDataFixedSize = 20;      // + n_samples * rows * cols * 2
inline constexpr std::size_t kDecisionFixedSize = 40;  // + n_values * 8
inline constexpr std::size_t kStatusSize = 72;
inline constexpr std::size_t kInfoFixedSize = 34;      // + names_len
inline constexpr std::size_t kPingSize = 12;           // PING and PONG
/// Bytes on the wire of the largest DECISION frame (16 values), COBS and delimiter included:
/// what a controller's other frames leave free so that a decision always finds room.
inline constexpr std::size_t kMaxEncodedDecisionSize = max_encoded_size(
    kHeaderSize + kDecisionFixedSize + 8 * kMaxDecisionValues + kCrcSize);

/// Largest number of samples of `taxels` taxels that fits one DATA frame.
constexpr std::size_t max_samples_per_frame(std::size_t taxels) {
  return taxels == 0 ? 0
                     : (kMaxFrameSize - kHeaderSize - kCrcSize - kDataFixedSize) / (2 * taxels);
}

struct DataPayload {
  std::uint64_t first_sample = 0;  // stream index of the first sample in this frame
  std::uint64_t timestamp_us = 0;  // sender clock when the last sample was acquired
  std::uint8_t rows = 0;
  std::uint8_t cols = 0;
  std::uint16_t n_samples = 0;
  /// n_samples * rows * cols raw ADC codes, sample-major, taxel (r, c) at r * cols + c.
  /// Encoder: caller's array. Decoder: points into the decoder (valid until the next feed).
  const std::int16_t* samples = nullptr;
};

struct DecisionPayload {
  std::uint64_t onset_sample = 0;    // first sample of the touch window
  std::uint64_t offset_sample = 0;   // one past the last sample of the touch window
  std::uint64_t decided_sample = 0;  // index of the last sample consumed before deciding
  std::uint64_t timestamp_us = 0;    // sender clock when the decision was made
  std::uint32_t latency_us = 0;      // from acquisition of decided_sample to the frame queued
  std::int16_t label = -1;           // class index; -1 = none
  std::uint8_t dont_know = 0;        // 1 when no machine or several machines claimed the touch
  std::uint8_t n_values = 0;         // <= kMaxDecisionValues
  std::array<double, kMaxDecisionValues> values{};  // one per binary machine
};

enum class StreamState : std::uint8_t { stopped = 0, streaming = 1, finished = 2 };

struct StatusPayload {
  std::uint64_t uptime_us = 0;
  std::uint64_t next_sample = 0;      // samples produced so far (index of the next sample)
  std::uint64_t samples_sent = 0;     // samples handed to the link
  std::uint64_t dropped_samples = 0;  // samples produced but never sent (overrun or no host)
  std::uint32_t overrun_events = 0;   // times the sender started dropping
  std::uint32_t rx_errors = 0;        // bad frames received from the host
  std::uint32_t faults_injected = 0;  // test fault injection (0 in normal use)
  std::uint32_t decisions_sent = 0;
  std::uint32_t pacing_p50_ns = 0;    // lateness of the sender's wake-ups vs absolute deadlines
  std::uint32_t pacing_p99_ns = 0;
  std::uint32_t pacing_max_ns = 0;
  StreamState state = StreamState::stopped;
  std::uint8_t host_connected = 0;
  std::uint16_t connections = 0;     // host connections so far, this one included (0: unknown)
  std::uint32_t decisions_dropped = 0;  // decisions made but never queued (no room, or no host)
  std::uint32_t frames_dropped = 0;     // STATUS, INFO, PONG frames not queued (no room)
};

struct InfoPayload {
  std::uint8_t rows = 0;
  std::uint8_t cols = 0;
  std::uint16_t samples_per_frame = 0;
  std::uint16_t protocol_version = kProtocolVersion;
  std::uint8_t n_classes = 0;
  std::uint8_t has_model = 0;
  double sample_rate_hz = 0.0;
  double volts_per_count = 0.0;
  double speed = 1.0;                // replay speed (0 = unpaced)
  std::uint16_t names_len = 0;       // bytes of class names
  const char* class_names = nullptr; // names_len bytes, UTF-8, names separated by '\n'
};

/// INFO's class-name field: `n` names joined by '\n' into out[0, capacity). Returns the bytes
/// written, or -1 (nothing announced) when they cannot all be sent as they are: more than 255
/// names, a name holding '\n', or more than `capacity` bytes. One packing for every controller
/// (eskin-fw-sim, the device firmware): a model whose names do not fit is refused, never
/// announced with a shortened list. No allocation, no exceptions.
std::ptrdiff_t pack_class_names(const std::string* names, std::size_t n, char* out,
                                std::size_t capacity) noexcept;

struct PingPayload {
  std::uint32_t token = 0;
  std::uint64_t timestamp_us = 0;  // PING: host clock; PONG: controller clock
};

/// One frame. Only the payload member matching `type` is meaningful.
struct Frame {
  FrameType type = FrameType::ping;
  std::uint8_t flags = 0;
  std::uint16_t seq = 0;
  DataPayload data;
  DecisionPayload decision;
  StatusPayload status;
  InfoPayload info;
  PingPayload ping;  // PING and PONG
};

bool is_known_type(std::uint8_t type);
const char* frame_type_name(FrameType type);

// ---- checksum and byte stuffing -------------------------------------------------------------

/// The frames' CRC-32: the core's one (eskin/crc32.hpp, zlib's).
using eskin::crc32;

/// COBS-encodes `in` into `out` (no delimiter). Returns the encoded length, or 0 if `cap` is
/// smaller than max_encoded_size(size) - 1 would need (nothing useful is written then).
std::size_t cobs_encode(const std::uint8_t* in, std::size_t size, std::uint8_t* out,
                        std::size_t cap);
/// Decodes one COBS block (no delimiter inside). Returns the decoded length, or -1 when the
/// input is not valid COBS (a zero byte, a code running past the end) or does not fit `cap`.
std::ptrdiff_t cobs_decode(const std::uint8_t* in, std::size_t size, std::uint8_t* out,
                           std::size_t cap);

// ---- encoder ----------------------------------------------------------------------------------

enum class EncodeStatus : std::uint8_t {
  ok = 0,
  buffer_too_small,  // `out` cannot hold the encoded frame
  invalid_frame,     // unknown type, too many values/samples, frame over kMaxFrameSize
};
const char* encode_status_message(EncodeStatus status);

/// Serialises a frame (header + payload + CRC, not yet COBS-encoded) into `raw`.
/// Returns the number of bytes, or 0 with *status set when it cannot.
std::size_t serialize_frame(const Frame& frame, std::uint8_t* raw, std::size_t cap,
                            EncodeStatus* status = nullptr);

/// Frame encoder: serialises into a scratch buffer of its own, then COBS-encodes. encode()
/// writes the encoded frame and its trailing 0x00 delimiter into `out` and returns the number
/// of bytes (0 on failure, with status() telling why). No heap, no exceptions. The scratch
/// buffer is the derived BasicFrameEncoder's, sized by its user (a device that only sends
/// short frames holds only what they need).
class FrameEncoderBase {
 public:
  FrameEncoderBase(const FrameEncoderBase&) = delete;
  FrameEncoderBase& operator=(const FrameEncoderBase&) = delete;

  std::size_t encode(const Frame& frame, std::uint8_t* out, std::size_t cap);
  EncodeStatus status() const { return status_; }
  /// Largest decoded frame this encoder can serialise.
  std::size_t max_frame_size() const { return cap_; }

 protected:
  FrameEncoderBase(std::uint8_t* raw, std::size_t cap) : raw_(raw), cap_(cap) {}
  ~FrameEncoderBase() = default;

 private:
  std::uint8_t* raw_;
  std::size_t cap_;
  EncodeStatus status_ = EncodeStatus::ok;
};

namespace detail {
/// Buffers of the sized encoder and decoder: a base class constructed before the codec that
/// points into it.
template <std::size_t MaxFrame>
struct EncoderStorage {
  std::array<std::uint8_t, MaxFrame> raw{};
};
template <std::size_t MaxFrame>
struct DecoderStorage {
  std::array<std::uint8_t, max_encoded_size(MaxFrame) - 1> block{};
  std::array<std::uint8_t, MaxFrame> raw{};
  std::array<std::int16_t, MaxFrame / 2> samples{};
};
}  // namespace detail

/// An encoder for frames of at most MaxFrame decoded bytes (header + payload + CRC).
template <std::size_t MaxFrame = kMaxFrameSize>
class BasicFrameEncoder : private detail::EncoderStorage<MaxFrame>, public FrameEncoderBase {
  static_assert(MaxFrame >= kHeaderSize + kCrcSize && MaxFrame <= kMaxFrameSize,
                "MaxFrame must hold a header and a CRC and be at most kMaxFrameSize");

 public:
  BasicFrameEncoder() : FrameEncoderBase(this->raw.data(), MaxFrame) {}
};

/// The encoder for any frame of the protocol (4 KiB of scratch).
using FrameEncoder = BasicFrameEncoder<kMaxFrameSize>;

// ---- streaming decoder --------------------------------------------------------------------------

struct DecoderStats {
  std::uint64_t bytes = 0;           // bytes fed
  std::uint64_t skipped_bytes = 0;   // bytes discarded before the first delimiter
  std::uint64_t frames = 0;          // frames accepted (valid COBS, CRC and layout)
  std::uint64_t data_frames = 0;
  std::uint64_t samples = 0;         // samples received in accepted DATA frames
  std::uint64_t crc_errors = 0;      // well-formed COBS block whose CRC does not match
  std::uint64_t malformed = 0;       // bad COBS, too short, unknown type, wrong payload size
  std::uint64_t oversize = 0;        // blocks longer than the decoder's limit (dropped)
  std::uint64_t sequence_gaps = 0;   // accepted frames whose seq was not the expected one
  std::uint64_t lost_frames = 0;     // frames missing according to seq
  std::uint64_t lost_samples = 0;    // samples missing according to DATA sample indices
  std::uint64_t sample_index_resets = 0;  // DATA first_sample went backwards (sender restart)
};

/// Streaming frame decoder. Feed it bytes as they arrive, in any split; it stops after each
/// accepted frame so the caller can read it:
///
///   while (n > 0) {
///     std::size_t used = dec.feed(p, n); p += used; n -= used;
///     if (dec.has_frame()) handle(dec.frame());
///   }
///
/// It never throws, holds at most `max_frame_size` decoded bytes, and after any damage resyncs
/// at the next delimiter. A frame is accepted only when its COBS block, CRC-32 and payload layout
/// are all valid. Bytes before the first delimiter are skipped (the sender starts every stream
/// with a delimiter), unless constructed with wait_for_delimiter = false.
///
/// Its buffers are the derived BasicFrameDecoder's, sized by its user: a controller that only
/// receives host commands (at most 20 bytes) holds a few dozen bytes, a host 12 KiB.
class FrameDecoderBase {
 public:
  FrameDecoderBase(const FrameDecoderBase&) = delete;
  FrameDecoderBase& operator=(const FrameDecoderBase&) = delete;

  /// Consumes bytes up to and including the delimiter of the next accepted frame (or all of
  /// them). Returns how many bytes were consumed.
  std::size_t feed(const std::uint8_t* data, std::size_t size);
  bool has_frame() const { return has_frame_; }
  /// The last accepted frame; valid until the next feed().
  const Frame& frame() const { return frame_; }

  /// Calls fn(const Frame&) for every frame accepted from these bytes.
  template <class Fn>
  void feed_all(const std::uint8_t* data, std::size_t size, Fn&& fn) {
    while (size > 0) {
      const std::size_t used = feed(data, size);
      data += used;
      size -= used;
      if (has_frame_) fn(frame_);
    }
  }

  const DecoderStats& stats() const { return stats_; }
  std::size_t max_frame_size() const { return max_frame_size_; }
  /// Forgets partial input and sequence expectations (stats are kept unless reset_stats); a
  /// decoder that waits for a delimiter at the start waits for one again.
  void reset(bool reset_stats = false);

 protected:
  /// `block` holds max_encoded_size(capacity) - 1 bytes, `raw` capacity bytes, `samples`
  /// capacity / 2 values; max_frame_size is clamped to [8, capacity].
  FrameDecoderBase(std::uint8_t* block, std::uint8_t* raw, std::int16_t* samples,
                   std::size_t capacity, std::size_t max_frame_size, bool wait_for_delimiter);
  ~FrameDecoderBase() = default;

 private:
  void finish_block();
  bool parse(std::size_t len);

  std::uint8_t* block_;
  std::uint8_t* raw_;
  std::int16_t* samples_;
  std::size_t max_frame_size_;
  std::size_t max_block_;
  bool wait_for_delimiter_;
  bool synced_;
  bool discarding_ = false;
  bool has_frame_ = false;
  std::size_t fill_ = 0;
  Frame frame_;
  DecoderStats stats_;
  bool have_seq_ = false;
  std::uint16_t next_seq_ = 0;
  bool have_sample_ = false;
  std::uint64_t next_sample_ = 0;
};

/// A decoder whose buffers hold frames of at most MaxFrame decoded bytes; the constructor's
/// max_frame_size can lower that limit further at run time.
template <std::size_t MaxFrame = kMaxFrameSize>
class BasicFrameDecoder : private detail::DecoderStorage<MaxFrame>, public FrameDecoderBase {
  static_assert(MaxFrame >= kHeaderSize + kCrcSize && MaxFrame <= kMaxFrameSize,
                "MaxFrame must hold a header and a CRC and be at most kMaxFrameSize");

 public:
  explicit BasicFrameDecoder(std::size_t max_frame_size = MaxFrame, bool wait_for_delimiter = true)
      : FrameDecoderBase(this->block.data(), this->raw.data(), this->samples.data(), MaxFrame,
                         max_frame_size, wait_for_delimiter) {}
};

/// The decoder for any frame of the protocol (a host's: about 12 KiB of buffers).
using FrameDecoder = BasicFrameDecoder<kMaxFrameSize>;

/// Payload size a frame of this type must have (fixed part only for variable-size types), or
/// -1 for an unknown type.
std::ptrdiff_t fixed_payload_size(FrameType type);

}  // namespace eskin::protocol
