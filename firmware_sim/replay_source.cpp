#include "replay_source.hpp"

#include <fcntl.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

#include "eskin/npy.hpp"
#include "eskin/protocol.hpp"
#include "eskin/replay_format.hpp"

namespace eskin::fwsim {

namespace {

bool host_is_little_endian() {
  const std::uint16_t one = 1;
  std::uint8_t b;
  std::memcpy(&b, &one, 1);
  return b == 1;
}

}  // namespace

ReplaySource::~ReplaySource() {
  if (map_ != nullptr) munmap(map_, map_size_);
}

bool ReplaySource::open(const std::string& path, int grid_rows, int grid_cols, std::string& error) {
  if (!host_is_little_endian()) {
    error = "eskin-fw-sim maps little-endian int16 samples directly; this host is big-endian";
    return false;
  }
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) {
    error = path + ": cannot open: " + std::strerror(errno);
    return false;
  }
  struct stat st {};
  if (fstat(fd, &st) != 0 || st.st_size <= 0) {
    error = path + ": empty or unreadable file";
    ::close(fd);
    return false;
  }
  map_size_ = static_cast<std::size_t>(st.st_size);
  map_ = mmap(nullptr, map_size_, PROT_READ, MAP_PRIVATE, fd, 0);
  ::close(fd);
  if (map_ == MAP_FAILED) {
    map_ = nullptr;
    error = path + ": mmap failed: " + std::strerror(errno);
    return false;
  }
  const bool ok = open_bytes(static_cast<const std::uint8_t*>(map_), map_size_, grid_rows,
                             grid_cols, error);
  if (!ok) error = path + ": " + error;
  return ok;
}

bool ReplaySource::open_bytes(const std::uint8_t* p, std::size_t size, int grid_rows,
                              int grid_cols, std::string& error) {
  data_ = nullptr;
  n_samples_ = 0;
  rows_ = cols_ = 0;
  class_names_.clear();
  segments_.clear();
  if (p == nullptr || size == 0) {
    error = "empty input";
    return false;
  }
  if (size >= 8 && std::memcmp(p, "ESKREPLY", 8) == 0) return open_eskr(p, size, error);
  if (is_npy(p, size)) return open_npy(p, size, grid_rows, grid_cols, error);
  if (size >= 8 && std::memcmp(p, "\x89HDF\r\n\x1a\n", 8) == 0) {
    error = "an HDF5 file (an eskin campaign?), not a replay: `eskin replay CAMPAIGN -o FILE.eskr` "
            "writes one from a campaign";
    return false;
  }
  error = "not an eskin replay file (magic ESKREPLY) nor a .npy file";
  return false;
}

bool ReplaySource::open_eskr(const std::uint8_t* p, std::size_t size, std::string& error) {
  // the core's reader of the format: the rules of every reader (eskin/replay_format.hpp)
  replay::ReplayHeader h;
  replay::ReplayError e;
  if (replay::check_replay(p, size, replay::SizeRule::exact, &h, &e) != replay::ReplayStatus::ok) {
    char line[256];
    error = replay::format_error(e, line, sizeof line);
    return false;
  }
  if (h.n_samples == 0) {
    error = "n_samples = 0: no samples to stream";
    return false;
  }
  rows_ = h.rows;
  cols_ = h.cols;
  n_samples_ = h.n_samples;
  sample_rate_hz_ = h.sample_rate_hz;
  volts_per_count_ = h.volts_per_count;
  for (std::uint32_t i = 0; i < h.n_segments; ++i) {
    const replay::ReplaySegment s = replay::segment(h, i);
    ReplaySegment seg;
    seg.start = s.start;
    seg.length = s.length;
    seg.label = s.label;
    segments_.push_back(seg);
  }
  if (h.names_len > 0) {
    std::string cur;
    for (std::uint32_t i = 0; i < h.names_len; ++i) {
      const char ch = h.class_names[i];
      if (ch == '\n') {
        class_names_.push_back(cur);
        cur.clear();
      } else {
        cur += ch;
      }
    }
    class_names_.push_back(cur);
  }
  data_ = h.samples;
  return true;
}

bool ReplaySource::open_npy(const std::uint8_t* p, std::size_t size, int grid_rows, int grid_cols,
                            std::string& error) {
  NpyHeader h;
  try {
    h = parse_npy_header(p, size, ".npy");
    check_npy_file_size(h, size, ".npy");
  } catch (const NpyError& e) {
    error = e.what();
    return false;
  }
  if (h.dtype != NpyDtype::kInt16) {
    error = ".npy must hold little-endian int16 ('<i2'), not '" + std::string(npy_descr(h.dtype)) + "'";
    return false;
  }
  const auto& dims = h.shape;
  if (dims.size() == 3) {
    if (dims[1] < 1 || dims[1] > 255 || dims[2] < 1 || dims[2] > 255) {
      error = ".npy shape " + npy_shape_string(dims) + ": bad grid (1..255 each)";
      return false;
    }
    rows_ = static_cast<int>(dims[1]);
    cols_ = static_cast<int>(dims[2]);
  } else if (dims.size() == 2) {
    if (static_cast<std::uint64_t>(grid_rows) * static_cast<std::uint64_t>(grid_cols) != dims[1]) {
      error = ".npy shape " + npy_shape_string(dims) + " does not match --grid " +
              std::to_string(grid_rows) + "x" + std::to_string(grid_cols);
      return false;
    }
    if (grid_rows < 1 || grid_rows > 255 || grid_cols < 1 || grid_cols > 255) {
      error = "bad grid " + std::to_string(grid_rows) + "x" + std::to_string(grid_cols) + " (1..255 each)";
      return false;
    }
    rows_ = grid_rows;
    cols_ = grid_cols;
  } else {
    error = ".npy must be (n_samples, rows, cols) or (n_samples, taxels), got shape " +
            npy_shape_string(dims);
    return false;
  }
  if (h.data_offset % 2 != 0) {
    error = ".npy data is not 2-byte aligned";
    return false;
  }
  if (dims[0] == 0) {
    error = "no samples";
    return false;
  }
  n_samples_ = dims[0];
  data_ = reinterpret_cast<const std::int16_t*>(p + h.data_offset);
  return true;
}

}  // namespace eskin::fwsim
