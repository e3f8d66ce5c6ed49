#include "replay_source.hpp"

#include <fcntl.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <regex>

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
  const auto* p = static_cast<const std::uint8_t*>(map_);
  bool ok;
  if (map_size_ >= 8 && std::memcmp(p, "ESKREPLY", 8) == 0) {
    ok = open_eskr(p, map_size_, error);
  } else if (map_size_ >= 6 && std::memcmp(p, "\x93NUMPY", 6) == 0) {
    ok = open_npy(p, map_size_, grid_rows, grid_cols, error);
  } else {
    error = "not an eskin replay file (magic ESKREPLY) nor a .npy file";
    ok = false;
  }
  if (!ok) error = path + ": " + error;
  return ok;
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
    error = "bad data offset " + std::to_string(data_offset);
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
    error = "bad grid " + std::to_string(rows) + "x" + std::to_string(cols);
    return false;
  }
  if (!(rate > 0.0)) {
    error = "bad sample rate";
    return false;
  }
  const std::uint64_t expected = data_offset + total * rows * cols * 2;
  if (expected != size) {
    error = "size " + std::to_string(size) + " bytes, expected " + std::to_string(expected);
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
  if (size < 10) {
    error = "truncated .npy header";
    return false;
  }
  const int major = p[6];
  std::size_t header_len, start;
  if (major == 1) {
    header_len = rd_u(p + 8, 2);
    start = 10;
  } else if (major == 2 || major == 3) {
    if (size < 12) {
      error = "truncated .npy header";
      return false;
    }
    header_len = rd_u(p + 8, 4);
    start = 12;
  } else {
    error = ".npy version " + std::to_string(major) + " not supported";
    return false;
  }
  if (start + header_len > size) {
    error = "truncated .npy header";
    return false;
  }
  const std::string h(reinterpret_cast<const char*>(p + start), header_len);
  std::smatch m;
  if (!std::regex_search(h, m, std::regex("'descr':\\s*'([<>|=]?)i2'")) ||
      m[1].str() == ">") {
    error = ".npy must hold little-endian int16 ('<i2'), header: " + h;
    return false;
  }
  if (h.find("'fortran_order': False") == std::string::npos) {
    error = ".npy must be C-ordered (fortran_order False)";
    return false;
  }
  if (!std::regex_search(h, m, std::regex("'shape':\\s*\\(([^)]*)\\)"))) {
    error = ".npy header has no shape";
    return false;
  }
  std::vector<std::uint64_t> dims;
  const std::string shape = m[1].str();
  const std::regex num("\\d+");
  for (auto it = std::sregex_iterator(shape.begin(), shape.end(), num); it != std::sregex_iterator();
       ++it)
    dims.push_back(std::stoull(it->str()));
  if (dims.size() == 3) {
    rows_ = static_cast<int>(dims[1]);
    cols_ = static_cast<int>(dims[2]);
  } else if (dims.size() == 2) {
    if (static_cast<std::uint64_t>(grid_rows) * grid_cols != dims[1]) {
      error = ".npy shape (" + std::to_string(dims[0]) + ", " + std::to_string(dims[1]) +
              ") does not match --grid " + std::to_string(grid_rows) + "x" +
              std::to_string(grid_cols);
      return false;
    }
    rows_ = grid_rows;
    cols_ = grid_cols;
  } else {
    error = ".npy must be (n_samples, rows, cols) or (n_samples, taxels), got " +
            std::to_string(dims.size()) + " dimensions";
    return false;
  }
  if (rows_ < 1 || rows_ > 255 || cols_ < 1 || cols_ > 255) {
    error = "bad grid " + std::to_string(rows_) + "x" + std::to_string(cols_);
    return false;
  }
  n_samples_ = dims[0];
  const std::size_t data_start = start + header_len;
  if (data_start + n_samples_ * taxels() * 2 != size) {
    error = ".npy data size does not match its shape";
    return false;
  }
  if (data_start % 2 != 0) {
    error = ".npy data is not 2-byte aligned";
    return false;
  }
  if (n_samples_ == 0) {
    error = "no samples";
    return false;
  }
  data_ = reinterpret_cast<const std::int16_t*>(p + data_start);
  return true;
}

}  // namespace eskin::fwsim
