// The replay file format (.eskr, docs/wire-protocol.md "Replay file"): one reader and validator
// of its header, segment table, class names and sizes, for every C++ reader (eskin-fw-sim's
// firmware_sim/replay_source.cpp and the board's mcu/eskin_fw.cpp). Its rules are those of the
// Python reader (eskin.data.replay.read_replay_file), check for check and in the same order:
// magic, version, data_offset, header CRC-32, grid, sample rate (0.1 Hz to 1 MHz), volts per
// count, size, class names, segments.
//
// Heap-free, exception-free, no POSIX: it reads a buffer in place and returns a status code
// naming the field, with the value that was refused.
#pragma once

#include <cstddef>
#include <cstdint>

namespace eskin::replay {

inline constexpr char kMagic[8] = {'E', 'S', 'K', 'R', 'E', 'P', 'L', 'Y'};
inline constexpr std::uint32_t kVersion = 1;
inline constexpr std::size_t kHeaderSize = 56;
inline constexpr std::size_t kSegmentSize = 48;
/// The rates a campaign may have (python/eskin/data/limits.py).
inline constexpr double kMinSampleRateHz = 0.1;
inline constexpr double kMaxSampleRateHz = 1e6;
inline constexpr std::uint16_t kMaxGrid = 255;
inline constexpr std::size_t kMaxClassNames = 255;

enum class ReplayStatus : std::uint8_t {
  ok = 0,
  bad_magic,          // shorter than the header, or not "ESKREPLY"
  bad_version,        // value: the version
  bad_data_offset,    // value: data_offset (before the table's end, past the buffer, not % 8)
  bad_crc,            // value: the stored CRC; expected: the computed one
  bad_grid,           // value: rows, expected: cols
  bad_sample_rate,    // real: sample_rate_hz
  bad_volts_per_count,  // real: volts_per_count
  bad_size,           // value: the buffer's bytes; expected: the bytes the header declares
  bad_class_names,    // value: byte offset of invalid UTF-8, or (too_many) the count
  bad_segment,        // index: the segment; value/expected: see SegmentProblem
};

/// How the buffer's size is checked: a file must be exactly what its header declares; a
/// board's memory region holding a loaded file may be larger.
enum class SizeRule : std::uint8_t { exact, at_most };

enum class SegmentProblem : std::uint8_t { none, empty, past_end, label, contact };

struct ReplaySegment {
  std::uint64_t start = 0;
  std::uint64_t length = 0;
  std::int64_t contact_onset = -1;
  std::int64_t contact_offset = -1;
  std::int32_t label = -1;
  std::uint32_t recording = 0;
};

/// The header of a checked replay, and where its parts are in the buffer.
struct ReplayHeader {
  std::uint32_t version = 0;
  std::uint32_t data_offset = 0;
  std::uint64_t n_samples = 0;
  std::uint16_t rows = 0;
  std::uint16_t cols = 0;
  std::uint32_t n_segments = 0;
  double sample_rate_hz = 0.0;
  double volts_per_count = 0.0;
  std::uint32_t names_len = 0;
  std::uint32_t crc = 0;
  std::uint32_t n_class_names = 0;
  const char* class_names = nullptr;  // names_len bytes, '\n'-separated, UTF-8
  const std::uint8_t* segments = nullptr;  // n_segments entries of kSegmentSize bytes
  const std::int16_t* samples = nullptr;   // n_samples * rows * cols codes, little-endian
};

/// What was refused, when the status is not ok.
struct ReplayError {
  ReplayStatus status = ReplayStatus::ok;
  SegmentProblem segment_problem = SegmentProblem::none;
  std::uint64_t index = 0;      // segment index
  std::uint64_t value = 0;
  std::uint64_t expected = 0;
  std::int64_t value2 = 0;      // segment: n_samples, label or contact offset
  std::int64_t onset = 0;       // segment: contact onset
  double real = 0.0;
  std::uint64_t bad_count = 0;  // segments with the same problem
};

/// Checks the replay image `data[0, size)` (see SizeRule) and fills `header`. No allocation;
/// every product is checked against the buffer by division first, so none wraps around.
ReplayStatus check_replay(const std::uint8_t* data, std::size_t size, SizeRule rule,
                          ReplayHeader* header, ReplayError* error) noexcept;

/// Segment i of a checked replay.
ReplaySegment segment(const ReplayHeader& header, std::size_t i) noexcept;

/// The field a status names ("version", "data_offset", "crc", "grid", "sample_rate_hz",
/// "volts_per_count", "size", "class_names", "segment").
const char* field_name(ReplayStatus status) noexcept;

/// One line naming the field and the value (no file name, no newline) into `out`; returns
/// `out`. snprintf only: no allocation.
const char* format_error(const ReplayError& error, char* out, std::size_t cap) noexcept;

}  // namespace eskin::replay
