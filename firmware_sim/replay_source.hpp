// The firmware simulator's input: a replay file (.eskr, docs/wire-protocol.md) or a .npy
// int16 array, memory-mapped and exposed as one sample-major int16 stream.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

namespace eskin::fwsim {

struct ReplaySegment {
  std::uint64_t start = 0;
  std::uint64_t length = 0;
  std::int32_t label = -1;
};

class ReplaySource {
 public:
  ReplaySource() = default;
  ~ReplaySource();
  ReplaySource(const ReplaySource&) = delete;
  ReplaySource& operator=(const ReplaySource&) = delete;

  /// Opens `path` (.eskr replay file, or .npy int16 (n, rows, cols) / (n, taxels) with the
  /// grid given). Returns false with `error` naming the file and the problem.
  bool open(const std::string& path, int grid_rows, int grid_cols, std::string& error);

  /// The same from bytes in memory (they must outlive the source): a replay image or a .npy
  /// image. Every declared size is checked against `size` first.
  bool open_bytes(const std::uint8_t* p, std::size_t size, int grid_rows, int grid_cols,
                  std::string& error);

  /// Sample i (rows * cols codes, taxel (r, c) at r * cols + c).
  const std::int16_t* sample(std::uint64_t i) const { return data_ + i * taxels(); }
  std::uint64_t n_samples() const { return n_samples_; }
  int rows() const { return rows_; }
  int cols() const { return cols_; }
  std::size_t taxels() const { return static_cast<std::size_t>(rows_) * cols_; }
  double sample_rate_hz() const { return sample_rate_hz_; }
  double volts_per_count() const { return volts_per_count_; }
  const std::vector<std::string>& class_names() const { return class_names_; }
  const std::vector<ReplaySegment>& segments() const { return segments_; }

 private:
  bool open_eskr(const std::uint8_t* p, std::size_t size, std::string& error);
  bool open_npy(const std::uint8_t* p, std::size_t size, int grid_rows, int grid_cols,
                std::string& error);

  void* map_ = nullptr;
  std::size_t map_size_ = 0;
  const std::int16_t* data_ = nullptr;
  std::uint64_t n_samples_ = 0;
  int rows_ = 0;
  int cols_ = 0;
  double sample_rate_hz_ = 3000.0;
  double volts_per_count_ = 0.0;
  std::vector<std::string> class_names_;
  std::vector<ReplaySegment> segments_;
};

}  // namespace eskin::fwsim
