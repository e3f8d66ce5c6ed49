#include "eskin/serial_port.hpp"

#include <fcntl.h>
#include <poll.h>
#include <pthread.h>
#include <sched.h>
#include <sys/ioctl.h>
#include <termios.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cstring>
#include <ctime>
#include <utility>

namespace eskin::serial {

namespace {

long long now_ns() {
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return static_cast<long long>(ts.tv_sec) * 1000000000LL + ts.tv_nsec;
}

long long deadline_after(int timeout_ms) {
  return timeout_ms < 0 ? -1 : now_ns() + static_cast<long long>(timeout_ms) * 1000000LL;
}

/// Milliseconds left until the deadline for poll() (-1: forever), rounded up.
int remaining_ms(long long deadline_ns) {
  if (deadline_ns < 0) return -1;
  const long long left = deadline_ns - now_ns();
  if (left <= 0) return 0;
  const long long ms = (left + 999999) / 1000000;
  return ms > 1000000 ? 1000000 : static_cast<int>(ms);
}

bool baud_constant(std::uint32_t baud, speed_t& out) {
  switch (baud) {
#define ESKIN_BAUD(n) \
  case n:             \
    out = B##n;       \
    return true;
    ESKIN_BAUD(1200)
    ESKIN_BAUD(2400)
    ESKIN_BAUD(4800)
    ESKIN_BAUD(9600)
    ESKIN_BAUD(19200)
    ESKIN_BAUD(38400)
    ESKIN_BAUD(57600)
    ESKIN_BAUD(115200)
    ESKIN_BAUD(230400)
#ifdef B460800
    ESKIN_BAUD(460800)
#endif
#ifdef B921600
    ESKIN_BAUD(921600)
#endif
#ifdef B1000000
    ESKIN_BAUD(1000000)
#endif
#ifdef B2000000
    ESKIN_BAUD(2000000)
#endif
#ifdef B3000000
    ESKIN_BAUD(3000000)
#endif
#ifdef B4000000
    ESKIN_BAUD(4000000)
#endif
#undef ESKIN_BAUD
    default:
      return false;
  }
}

}  // namespace

const char* port_status_name(PortStatus status) {
  switch (status) {
    case PortStatus::ok: return "ok";
    case PortStatus::timeout: return "timeout";
    case PortStatus::peer_closed: return "peer_closed";
    case PortStatus::not_open: return "not_open";
    case PortStatus::invalid_argument: return "invalid_argument";
    case PortStatus::open_failed: return "open_failed";
    case PortStatus::not_a_tty: return "not_a_tty";
    case PortStatus::config_failed: return "config_failed";
    case PortStatus::io_error: return "io_error";
  }
  return "unknown";
}

SerialPort::~SerialPort() { close(); }

SerialPort::SerialPort(SerialPort&& other) noexcept { *this = std::move(other); }

SerialPort& SerialPort::operator=(SerialPort&& other) noexcept {
  if (this != &other) {
    close();
    fd_ = std::exchange(other.fd_, -1);
    path_ = std::move(other.path_);
    baud_ = other.baud_;
    last_error_ = std::move(other.last_error_);
    last_errno_ = other.last_errno_;
  }
  return *this;
}

PortStatus SerialPort::fail(PortStatus status, const char* what, int err) {
  last_errno_ = err;
  last_error_ = std::string(port_status_name(status)) + ": " + what + " (" +
                (path_.empty() ? std::string("<no port>") : path_) + ")";
  if (err != 0) last_error_ += ": " + std::string(std::strerror(err));
  return status;
}

PortStatus SerialPort::open(const std::string& path, std::uint32_t baud) {
  close();
  path_ = path;
  speed_t unused;
  if (!baud_constant(baud, unused))
    return fail(PortStatus::invalid_argument, ("unsupported baud rate " + std::to_string(baud)).c_str(), 0);
  const int fd = ::open(path.c_str(), O_RDWR | O_NOCTTY | O_NONBLOCK | O_CLOEXEC);
  if (fd < 0) return fail(PortStatus::open_failed, "open", errno);
  if (!isatty(fd)) {
    const int err = errno;
    ::close(fd);
    return fail(PortStatus::not_a_tty, "not a terminal device", err == ENOTTY ? 0 : err);
  }
  fd_ = fd;
  const PortStatus s = configure_raw(baud);
  if (s != PortStatus::ok) {
    ::close(fd_);
    fd_ = -1;
  }
  return s;
}

PortStatus SerialPort::adopt(int fd, const std::string& name) {
  close();
  path_ = name;
  if (fd < 0) return fail(PortStatus::invalid_argument, "adopt: negative file descriptor", 0);
  if (!isatty(fd)) return fail(PortStatus::not_a_tty, "adopt: not a terminal device", 0);
  const int fl = fcntl(fd, F_GETFL);
  if (fl < 0 || fcntl(fd, F_SETFL, fl | O_NONBLOCK) < 0)
    return fail(PortStatus::config_failed, "fcntl O_NONBLOCK", errno);
  fd_ = fd;
  return configure_raw(115200);
}

PortStatus SerialPort::configure_raw(std::uint32_t baud) {
  termios tio{};
  if (tcgetattr(fd_, &tio) != 0) return fail(PortStatus::config_failed, "tcgetattr", errno);
  cfmakeraw(&tio);
  tio.c_cflag |= CLOCAL | CREAD;
  tio.c_cflag &= ~static_cast<tcflag_t>(CSTOPB | PARENB | CRTSCTS);
  tio.c_iflag &= ~static_cast<tcflag_t>(IXON | IXOFF | IXANY);
  tio.c_cc[VMIN] = 0;
  tio.c_cc[VTIME] = 0;
  speed_t speed;
  baud_constant(baud, speed);
  if (cfsetispeed(&tio, speed) != 0 || cfsetospeed(&tio, speed) != 0)
    return fail(PortStatus::config_failed, "cfsetspeed", errno);
  if (tcsetattr(fd_, TCSANOW, &tio) != 0) return fail(PortStatus::config_failed, "tcsetattr", errno);
  baud_ = baud;
  return PortStatus::ok;
}

PortStatus SerialPort::set_baud(std::uint32_t baud) {
  if (fd_ < 0) return fail(PortStatus::not_open, "set_baud", 0);
  speed_t speed;
  if (!baud_constant(baud, speed))
    return fail(PortStatus::invalid_argument, ("unsupported baud rate " + std::to_string(baud)).c_str(), 0);
  termios tio{};
  if (tcgetattr(fd_, &tio) != 0) return fail(PortStatus::config_failed, "tcgetattr", errno);
  if (cfsetispeed(&tio, speed) != 0 || cfsetospeed(&tio, speed) != 0)
    return fail(PortStatus::config_failed, "cfsetspeed", errno);
  if (tcsetattr(fd_, TCSANOW, &tio) != 0) return fail(PortStatus::config_failed, "tcsetattr", errno);
  baud_ = baud;
  return PortStatus::ok;
}

PortStatus SerialPort::close() {
  if (fd_ < 0) return PortStatus::ok;
  const int fd = std::exchange(fd_, -1);
  if (::close(fd) != 0 && errno != EINTR) return fail(PortStatus::io_error, "close", errno);
  return PortStatus::ok;
}

PortStatus SerialPort::wait_for(short events, long long deadline_ns) {
  for (;;) {
    pollfd p{fd_, events, 0};
    const int r = ::poll(&p, 1, remaining_ms(deadline_ns));
    if (r < 0) {
      if (errno == EINTR) continue;
      return fail(PortStatus::io_error, "poll", errno);
    }
    if (r == 0) return PortStatus::timeout;
    if (p.revents & events) return PortStatus::ok;
    if (p.revents & POLLNVAL) return fail(PortStatus::io_error, "poll: invalid descriptor", 0);
    if (p.revents & (POLLHUP | POLLERR)) return fail(PortStatus::peer_closed, "peer hung up", 0);
  }
}

IoResult SerialPort::nonblocking_read(std::uint8_t* buf, std::size_t size) {
  IoResult res;
  if (fd_ < 0) return {0, fail(PortStatus::not_open, "read", 0)};
  if (size == 0) return res;
  if (buf == nullptr) return {0, fail(PortStatus::invalid_argument, "read: null buffer", 0)};
  for (;;) {
    const ssize_t n = ::read(fd_, buf, size);
    if (n > 0) {
      res.bytes = static_cast<std::size_t>(n);
      return res;
    }
    if (n == 0) {
      // A tty in raw mode with VMIN = VTIME = 0 returns 0 for "nothing there"; tell that from
      // end of file (the peer closed) with a zero-timeout poll.
      pollfd p{fd_, POLLIN, 0};
      if (::poll(&p, 1, 0) > 0 && (p.revents & (POLLHUP | POLLERR)))
        res.status = fail(PortStatus::peer_closed, "read: peer hung up", 0);
      return res;
    }
    if (errno == EINTR) continue;
    if (errno == EAGAIN || errno == EWOULDBLOCK) return res;
    if (errno == EIO) {
      res.status = fail(PortStatus::peer_closed, "read: peer hung up", EIO);
      return res;
    }
    res.status = fail(PortStatus::io_error, "read", errno);
    return res;
  }
}

IoResult SerialPort::blocking_read_next(std::uint8_t* buf, std::size_t size, int timeout_ms) {
  if (fd_ < 0) return {0, fail(PortStatus::not_open, "read", 0)};
  if (size == 0) return {};
  const long long deadline = deadline_after(timeout_ms);
  for (;;) {
    const PortStatus w = wait_for(POLLIN, deadline);
    if (w != PortStatus::ok) return {0, w};
    IoResult r = nonblocking_read(buf, size);
    if (r.bytes > 0 || r.status != PortStatus::ok) return r;
    if (remaining_ms(deadline) == 0) return {0, PortStatus::timeout};
  }
}

IoResult SerialPort::blocking_read(std::uint8_t* buf, std::size_t size, int timeout_ms) {
  if (fd_ < 0) return {0, fail(PortStatus::not_open, "read", 0)};
  const long long deadline = deadline_after(timeout_ms);
  IoResult total;
  while (total.bytes < size) {
    const PortStatus w = wait_for(POLLIN, deadline);
    if (w != PortStatus::ok) {
      total.status = w;
      return total;
    }
    const IoResult r = nonblocking_read(buf + total.bytes, size - total.bytes);
    total.bytes += r.bytes;
    if (r.status != PortStatus::ok) {
      total.status = r.status;
      return total;
    }
    if (r.bytes == 0 && remaining_ms(deadline) == 0) {
      total.status = PortStatus::timeout;
      return total;
    }
  }
  return total;
}

IoResult SerialPort::nonblocking_write(const std::uint8_t* buf, std::size_t size) {
  IoResult res;
  if (fd_ < 0) return {0, fail(PortStatus::not_open, "write", 0)};
  if (size == 0) return res;
  if (buf == nullptr) return {0, fail(PortStatus::invalid_argument, "write: null buffer", 0)};
  for (;;) {
    const ssize_t n = ::write(fd_, buf, size);
    if (n >= 0) {
      res.bytes = static_cast<std::size_t>(n);
      return res;
    }
    if (errno == EINTR) continue;
    if (errno == EAGAIN || errno == EWOULDBLOCK) return res;
    if (errno == EIO || errno == EPIPE) {
      res.status = fail(PortStatus::peer_closed, "write: peer hung up", errno);
      return res;
    }
    res.status = fail(PortStatus::io_error, "write", errno);
    return res;
  }
}

IoResult SerialPort::blocking_write(const std::uint8_t* buf, std::size_t size, int timeout_ms) {
  if (fd_ < 0) return {0, fail(PortStatus::not_open, "write", 0)};
  const long long deadline = deadline_after(timeout_ms);
  IoResult total;
  while (total.bytes < size) {
    const IoResult r = nonblocking_write(buf + total.bytes, size - total.bytes);
    total.bytes += r.bytes;
    if (r.status != PortStatus::ok) {
      total.status = r.status;
      return total;
    }
    if (total.bytes == size) break;
    const PortStatus w = wait_for(POLLOUT, deadline);
    if (w != PortStatus::ok) {
      total.status = w;
      return total;
    }
  }
  return total;
}

IoResult SerialPort::input_waiting() {
  if (fd_ < 0) return {0, fail(PortStatus::not_open, "input_waiting", 0)};
  int n = 0;
  if (ioctl(fd_, FIONREAD, &n) != 0) return {0, fail(PortStatus::io_error, "ioctl FIONREAD", errno)};
  return {static_cast<std::size_t>(n < 0 ? 0 : n), PortStatus::ok};
}

IoResult SerialPort::output_waiting() {
  if (fd_ < 0) return {0, fail(PortStatus::not_open, "output_waiting", 0)};
  int n = 0;
  if (ioctl(fd_, TIOCOUTQ, &n) != 0) return {0, fail(PortStatus::io_error, "ioctl TIOCOUTQ", errno)};
  return {static_cast<std::size_t>(n < 0 ? 0 : n), PortStatus::ok};
}

PortStatus SerialPort::flush(Buffers which) {
  if (fd_ < 0) return fail(PortStatus::not_open, "flush", 0);
  const int q = which == Buffers::input ? TCIFLUSH : which == Buffers::output ? TCOFLUSH : TCIOFLUSH;
  if (tcflush(fd_, q) != 0) return fail(PortStatus::io_error, "tcflush", errno);
  return PortStatus::ok;
}

PortStatus SerialPort::drain(int timeout_ms) {
  if (fd_ < 0) return fail(PortStatus::not_open, "drain", 0);
  // tcdrain() can block forever on a pty whose peer does not read; poll TIOCOUTQ instead.
  const long long deadline = deadline_after(timeout_ms);
  for (;;) {
    const IoResult q = output_waiting();
    if (q.status != PortStatus::ok) return q.status;
    if (q.bytes == 0) return PortStatus::ok;
    if (remaining_ms(deadline) == 0) return PortStatus::timeout;
    timespec ts{0, 200000};  // 0.2 ms
    nanosleep(&ts, nullptr);
  }
}

// -- PortReader ----------------------------------------------------------------------------

PortReader::PortReader(const SerialPort& port, std::size_t capacity, std::size_t trickle_bytes,
                       int trickle_wait_ms, int realtime_priority)
    : fd_(port.fd()),
      path_(port.path()),
      capacity_(capacity),
      trickle_bytes_(trickle_bytes),
      trickle_wait_ms_(trickle_wait_ms),
      realtime_priority_(realtime_priority) {}

PortReader::~PortReader() { stop(); }

PortStatus PortReader::start() {
  if (fd_ < 0) return PortStatus::not_open;
  if (thread_.joinable()) return PortStatus::ok;
  thread_ = std::thread([this] { run(); });
  pthread_setname_np(thread_.native_handle(), "eskin-port");  // for top -H, ps -L, perf
  if (realtime_priority_ > 0) {  // refused (EPERM) without the privilege: the ordinary policy
    sched_param sp{};
    sp.sched_priority = std::min(realtime_priority_, sched_get_priority_max(SCHED_FIFO));
    realtime_ = pthread_setschedparam(thread_.native_handle(), SCHED_FIFO, &sp) == 0;
  }
  return PortStatus::ok;
}

void PortReader::stop() {
  stop_.store(true);
  if (thread_.joinable()) thread_.join();
}

void PortReader::push(const std::uint8_t* data, std::size_t n) {
  {
    std::lock_guard<std::mutex> lock(mu_);
    bytes_read_ += n;
    if (queued_ + n > capacity_) {
      overflow_ += n;
      return;
    }
    chunks_.emplace_back(data, data + n);
    queued_ += n;
    if (queued_ > peak_) peak_ = queued_;
  }
  ready_.notify_one();
}

void PortReader::end(PortStatus status, const std::string& why, int err) {
  {
    std::lock_guard<std::mutex> lock(mu_);
    end_ = status;
    error_ = path_ + ": " + why + (err ? std::string(": ") + std::strerror(err) : std::string());
  }
  ready_.notify_all();
}

void PortReader::run() {
  std::vector<std::uint8_t> buf(65536);
  while (!stop_.load()) {
    pollfd p{fd_, POLLIN, 0};
    const int r = ::poll(&p, 1, 50);  // wakes to notice stop()
    if (r < 0) {
      if (errno == EINTR) continue;
      return end(PortStatus::io_error, "poll", errno);
    }
    if (r == 0) continue;
    if (!(p.revents & POLLIN)) {  // a hang-up with nothing left to read
      if (p.revents & (POLLHUP | POLLERR)) return end(PortStatus::peer_closed, "peer hung up", 0);
      if (p.revents & POLLNVAL) return end(PortStatus::io_error, "poll: not an open port", 0);
      continue;
    }
    const ssize_t n = ::read(fd_, buf.data(), buf.size());
    if (n == 0) return end(PortStatus::peer_closed, "read: end of file", 0);
    if (n < 0) {
      if (errno == EAGAIN || errno == EWOULDBLOCK || errno == EINTR) continue;
      if (errno == EIO) return end(PortStatus::peer_closed, "read: peer hung up", 0);
      return end(PortStatus::io_error, "read", errno);
    }
    push(buf.data(), static_cast<std::size_t>(n));
    if (static_cast<std::size_t>(n) < trickle_bytes_ && trickle_wait_ms_ > 0) {
      const timespec ts{0, static_cast<long>(trickle_wait_ms_) * 1000000L};
      nanosleep(&ts, nullptr);
    }
  }
}

IoResult PortReader::take(std::uint8_t* buf, std::size_t size, int timeout_ms) {
  std::unique_lock<std::mutex> lock(mu_);
  const auto has_input = [this] { return queued_ > 0 || end_ != PortStatus::ok; };
  if (timeout_ms < 0) {
    ready_.wait(lock, has_input);
  } else if (!ready_.wait_for(lock, std::chrono::milliseconds(timeout_ms), has_input)) {
    return {0, PortStatus::timeout};
  }
  IoResult res;
  while (res.bytes < size && !chunks_.empty()) {
    const std::vector<std::uint8_t>& c = chunks_.front();
    const std::size_t n = std::min(size - res.bytes, c.size() - front_used_);
    std::memcpy(buf + res.bytes, c.data() + front_used_, n);
    res.bytes += n;
    front_used_ += n;
    if (front_used_ == c.size()) {
      chunks_.pop_front();
      front_used_ = 0;
    }
  }
  queued_ -= res.bytes;
  if (res.bytes == 0) res.status = end_;
  return res;
}

std::size_t PortReader::queued() const {
  std::lock_guard<std::mutex> lock(mu_);
  return queued_;
}

std::size_t PortReader::peak() const {
  std::lock_guard<std::mutex> lock(mu_);
  return peak_;
}

std::uint64_t PortReader::overflow() const {
  std::lock_guard<std::mutex> lock(mu_);
  return overflow_;
}

std::uint64_t PortReader::bytes_read() const {
  std::lock_guard<std::mutex> lock(mu_);
  return bytes_read_;
}

std::string PortReader::last_error() const {
  std::lock_guard<std::mutex> lock(mu_);
  return error_;
}

}  // namespace eskin::serial
