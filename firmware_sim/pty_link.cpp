#include "pty_link.hpp"

#include <fcntl.h>
#include <poll.h>
#include <stdlib.h>
#include <sys/ioctl.h>
#include <sys/stat.h>
#include <time.h>
#include <termios.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

namespace eskin::fwsim {

PtyLink::PtyLink(std::size_t tx_capacity, const FaultConfig& faults)
    : tx_(tx_capacity),
      capacity_(tx_capacity),
      scratch_(protocol::kMaxEncodedFrameSize),
      rx_(protocol::kMaxFrameSize, /*wait_for_delimiter=*/false),
      faults_(faults),
      rng_(faults.seed) {
  if (faults_.burst_len < 1) faults_.burst_len = 1;
  extra_ = faults_.burst_rate > 0 ? static_cast<std::size_t>(faults_.burst_len) : 0;
  faulted_.resize(protocol::kMaxEncodedFrameSize + extra_ + 1);
}

PtyLink::~PtyLink() {
  port_.close();
  if (!link_path_.empty()) {
    struct stat st {};
    if (lstat(link_path_.c_str(), &st) == 0 && S_ISLNK(st.st_mode)) unlink(link_path_.c_str());
  }
}

bool PtyLink::open(const std::string& link_path, std::string& error) {
  const int fd = posix_openpt(O_RDWR | O_NOCTTY | O_CLOEXEC);
  if (fd < 0) {
    error = std::string("posix_openpt: ") + std::strerror(errno);
    return false;
  }
  if (grantpt(fd) != 0 || unlockpt(fd) != 0) {
    error = std::string("grantpt/unlockpt: ") + std::strerror(errno);
    ::close(fd);
    return false;
  }
  const char* name = ptsname(fd);
  if (name == nullptr) {
    error = "ptsname failed";
    ::close(fd);
    return false;
  }
  slave_path_ = name;
  if (port_.adopt(fd, "pty master of " + slave_path_) != serial::PortStatus::ok) {
    error = port_.last_error();
    return false;
  }
  // Raw mode on the slave side too, so a host that does not configure the port (cat, a plain
  // open()) still gets the bytes unaltered.
  const int sfd = ::open(slave_path_.c_str(), O_RDWR | O_NOCTTY | O_CLOEXEC);
  if (sfd >= 0) {
    termios tio{};
    if (tcgetattr(sfd, &tio) == 0) {
      cfmakeraw(&tio);
      tcsetattr(sfd, TCSANOW, &tio);
    }
    ::close(sfd);
    host_connected_ = false;  // we opened and closed the slave: POLLHUP until a host opens it
  }
  if (!link_path.empty()) {
    struct stat st {};
    if (lstat(link_path.c_str(), &st) == 0) {
      if (!S_ISLNK(st.st_mode)) {
        error = "--link " + link_path + " exists and is not a symlink; not replacing it";
        return false;
      }
      unlink(link_path.c_str());
    }
    if (symlink(slave_path_.c_str(), link_path.c_str()) != 0) {
      error = "--link " + link_path + ": " + std::strerror(errno);
      return false;
    }
    link_path_ = link_path;
  }
  return true;
}

bool PtyLink::update_host(bool& reconnected, bool& disconnected) {
  reconnected = disconnected = false;
  pollfd p{port_.fd(), 0, 0};
  if (::poll(&p, 1, 0) < 0) return host_connected_;
  const bool now = !(p.revents & POLLHUP);
  if (now && !host_connected_) reconnected = true;
  if (!now && host_connected_) disconnected = true;
  host_connected_ = now;
  if (disconnected) {
    clear_tx();  // nobody is listening; what was queued can never arrive intact
    rx_.reset();
  }
  return host_connected_;
}

bool PtyLink::push_bytes(const std::uint8_t* p, std::size_t n) {
  if (capacity_ - size_ < n) return false;
  if (begin_ + size_ + n > capacity_) {
    std::memmove(tx_.data(), tx_.data() + begin_, size_);
    begin_ = 0;
  }
  std::memcpy(tx_.data() + begin_ + size_, p, n);
  size_ += n;
  return true;
}

std::size_t PtyLink::apply_faults(const std::uint8_t* in, std::size_t n, std::uint8_t* out) {
  std::size_t o = 0;
  if (faults_.burst_rate > 0 && rng_.uniform() < faults_.burst_rate) {
    const std::size_t len = 1 + rng_.next() % static_cast<std::uint64_t>(faults_.burst_len);
    for (std::size_t i = 0; i < len; ++i) out[o++] = static_cast<std::uint8_t>(rng_.next());
    ++faults_injected_;
  }
  std::size_t body = n;
  if (faults_.truncate_rate > 0 && n > 2 && rng_.uniform() < faults_.truncate_rate) {
    body = 1 + rng_.next() % (n - 2);  // keep 1..n-2 bytes, then the delimiter
    ++faults_injected_;
    std::memcpy(out + o, in, body);
    o += body;
    out[o++] = in[n - 1];
  } else {
    std::memcpy(out + o, in, n);
    o += n;
  }
  if (faults_.flip_rate > 0 || faults_.drop_rate > 0) {
    std::size_t w = 0;
    for (std::size_t i = 0; i < o; ++i) {
      std::uint8_t b = out[i];
      if (faults_.drop_rate > 0 && rng_.uniform() < faults_.drop_rate) {
        ++faults_injected_;
        continue;
      }
      if (faults_.flip_rate > 0 && rng_.uniform() < faults_.flip_rate) {
        b ^= static_cast<std::uint8_t>(1U << (rng_.next() % 8));
        ++faults_injected_;
      }
      out[w++] = b;
    }
    o = w;
  }
  return o;
}

bool PtyLink::send(protocol::Frame& frame, std::size_t reserve) {
  frame.seq = seq_;
  const std::size_t n = encoder_.encode(frame, scratch_.data(), scratch_.size());
  if (n == 0 || !fits(n + reserve)) return false;
  seq_ = static_cast<std::uint16_t>(seq_ + 1);
  if (!faults_.any()) return push_bytes(scratch_.data(), n);
  const std::size_t m = apply_faults(scratch_.data(), n, faulted_.data());
  return push_bytes(faulted_.data(), m);
}

bool PtyLink::send_delimiter() {
  const std::uint8_t d = protocol::kDelimiter;
  return push_bytes(&d, 1);
}

bool PtyLink::flush_tx() {
  while (size_ > 0) {
    const auto r = port_.nonblocking_write(tx_.data() + begin_, size_);
    if (r.status == serial::PortStatus::peer_closed) return false;
    if (r.bytes == 0) break;
    bytes_written_ += r.bytes;
    begin_ += r.bytes;
    size_ -= r.bytes;
  }
  if (size_ == 0) begin_ = 0;
  return true;
}

void PtyLink::wait_io(int timeout_ms, bool want_output) {
  if (!host_connected_) {
    // No host: the master reports a hang-up (POLLHUP) on every poll, so poll would return at
    // once and the caller would spin. Sleep instead; a host that opens the port is seen at the
    // next update_host().
    const timespec nap{timeout_ms / 1000, static_cast<long>(timeout_ms % 1000) * 1000000L};
    nanosleep(&nap, nullptr);
    return;
  }
  pollfd p{port_.fd(), static_cast<short>(POLLIN | (want_output ? POLLOUT : 0)), 0};
  ::poll(&p, 1, timeout_ms);
}

void PtyLink::wait_writable(int timeout_ms) {
  pollfd p{port_.fd(), POLLOUT, 0};
  ::poll(&p, 1, timeout_ms);
}

void PtyLink::drain(int timeout_ms) {
  const int sfd = ::open(slave_path_.c_str(), O_RDONLY | O_NOCTTY | O_NONBLOCK | O_CLOEXEC);
  if (sfd < 0) return;
  timespec start{}, now{};
  clock_gettime(CLOCK_MONOTONIC, &start);
  int quiet = 0;
  for (;;) {
    int n = 0;
    if (ioctl(sfd, FIONREAD, &n) != 0) break;
    quiet = n == 0 ? quiet + 1 : 0;
    if (quiet >= 50) break;  // empty for 50 ms: nothing left in flight (flip buffers) either
    clock_gettime(CLOCK_MONOTONIC, &now);
    const long long ms = (now.tv_sec - start.tv_sec) * 1000LL + (now.tv_nsec - start.tv_nsec) / 1000000;
    if (ms >= timeout_ms) break;
    timespec nap{0, 1000000};
    nanosleep(&nap, nullptr);
  }
  ::close(sfd);
}

}  // namespace eskin::fwsim
