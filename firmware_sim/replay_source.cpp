#include "replay_source.hpp"

#include <fcntl.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <cmath>
#include <sstream>

#include "eskin/npy.hpp"
#include "eskin/protocol.hpp"

namespace eskin::fwsim {

namespace {

std::uint64_t rd_u(const std::uint8_t* p, int n) {
  std::uint64_t v = 0;
  for (int i = 0; i < n; ++i) v |= static_cast<std::uint64_t>(p[i]) << (8 * i);
  return v;
}

double rd_f64(const std::uint8_t* p) {
  const std::uint64_t bits = rd_u(p, 8);
  double v;
  std::memcpy(&v, &bits, sizeof v);
  return v;
}

constexpr double kMaxSampleRate = 1e7;

std::string fmt_double(double v) {
  std::ostringstream os;
  os.precision(17);
  os << v;
  return os.str();
}

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
  constexpr std::size_t kHeader = 56, kSegment = 48;
  if (size < kHeader) {
    error = "truncated header";
    return false;
  }
  const auto version = rd_u(p + 8, 4);
  const auto data_offset = rd_u(p + 12, 4);
  const auto total = rd_u(p + 16, 8);
  const auto rows = rd_u(p + 24, 2), cols = rd_u(p + 26, 2);
  const auto n_seg = rd_u(p + 28, 4);
  const double rate = rd_f64(p + 32), vpc = rd_f64(p + 40);
  const auto names_len = rd_u(p + 48, 4);
  const auto crc = static_cast<std::uint32_t>(rd_u(p + 52, 4));
  if (version != 1) {
    error = "replay version " + std::to_string(version) + ", this simulator reads version 1";
    return false;
  }
  if (data_offset % 8 != 0 || data_offset > size ||
      data_offset < kHeader + n_seg * kSegment + names_len) {
    error = "bad data_offset " + std::to_string(data_offset) + " (n_segments " +
            std::to_string(n_seg) + ", names_len " + std::to_string(names_len) + ", file of " +
            std::to_string(size) + " bytes)";
    return false;
  }
  std::uint32_t c = protocol::crc32(p, 52);
  const std::uint8_t zero[4] = {0, 0, 0, 0};
  c = protocol::crc32(zero, 4, c);
  c = protocol::crc32(p + kHeader, data_offset - kHeader, c);
  if (c != crc) {
    error = "header checksum mismatch (corrupted file)";
    return false;
  }
  if (rows < 1 || rows > 255 || cols < 1 || cols > 255) {
    error = "bad grid " + std::to_string(rows) + "x" + std::to_string(cols) + " (1..255 each)";
    return false;
  }
  if (!(std::isfinite(rate) && rate > 0.0 && rate <= kMaxSampleRate)) {
    error = "sample_rate_hz = " + fmt_double(rate) + " must be in (0, 1e7]";
    return false;
  }
  if (!(std::isfinite(vpc) && vpc > 0.0)) {
    error = "volts_per_count = " + fmt_double(vpc) + " must be finite and > 0";
    return false;
  }
  // n_samples against the bytes present before any product (which could wrap around)
  const std::uint64_t bytes_per_sample = rows * cols * 2;
  if (total > (size - data_offset) / bytes_per_sample ||
      data_offset + total * bytes_per_sample != size) {
    error = "n_samples = " + std::to_string(total) + " of " + std::to_string(rows) + "x" +
            std::to_string(cols) + " taxels does not match the " + std::to_string(size - data_offset) +
            " bytes of samples in the file";
    return false;
  }
  rows_ = static_cast<int>(rows);
  cols_ = static_cast<int>(cols);
  n_samples_ = total;
  sample_rate_hz_ = rate;
  volts_per_count_ = vpc;
  for (std::uint64_t i = 0; i < n_seg; ++i) {
    const std::uint8_t* s = p + kHeader + i * kSegment;
    ReplaySegment seg;
    seg.start = rd_u(s, 8);
    seg.length = rd_u(s + 8, 8);
    seg.label = static_cast<std::int32_t>(rd_u(s + 32, 4));
    if (seg.start > total || seg.length > total - seg.start) {
      error = "segment " + std::to_string(i) + ": start " + std::to_string(seg.start) +
              " + length " + std::to_string(seg.length) + " runs past n_samples = " +
              std::to_string(total);
      return false;
    }
    segments_.push_back(seg);
  }
  const char* names = reinterpret_cast<const char*>(p + kHeader + n_seg * kSegment);
  if (names_len > 0) {
    std::string all(names, names_len), cur;
    for (char ch : all) {
      if (ch == '\n') {
        class_names_.push_back(cur);
        cur.clear();
      } else {
        cur += ch;
      }
    }
    class_names_.push_back(cur);
  }
  if (n_samples_ == 0) {
    error = "no samples";
    return false;
  }
  data_ = reinterpret_cast<const std::int16_t*>(p + data_offset);
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
