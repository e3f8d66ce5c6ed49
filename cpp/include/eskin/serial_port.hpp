// A serial port over plain POSIX termios, with a libserialport-like API.
//
// libserialport cannot open a pseudo-terminal, which is what the firmware simulator publishes;
// this class opens any tty (USB-CDC /dev/ttyACM*, /dev/ttyUSB*, a pty slave) in raw mode and
// reads and writes it through poll(). Errors are status codes with a message, never
// exceptions. A closed peer (POLLHUP, EIO on a pty, end of file) is reported as
// PortStatus::peer_closed, never mistaken for silence (PortStatus::timeout).
#pragma once

#include <cstddef>
#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

namespace eskin::serial {

enum class PortStatus : std::uint8_t {
  ok = 0,
  timeout,           // a blocking call ran out of time (IoResult::bytes may be partial)
  peer_closed,       // the other end hung up (POLLHUP, EIO on a pty, read() == 0)
  not_open,          // the port is not open
  invalid_argument,  // bad baud rate, null buffer, ...
  open_failed,       // open(2) failed (no such file, permission, busy)
  not_a_tty,         // the path is not a terminal device
  config_failed,     // tcgetattr/tcsetattr/cfsetspeed failed
  io_error,          // any other read/write/poll/ioctl failure
};

/// Short fixed name of a status ("ok", "timeout", "peer_closed", ...).
const char* port_status_name(PortStatus status);

/// Result of a transfer: how many bytes moved, and why it stopped.
struct IoResult {
  std::size_t bytes = 0;
  PortStatus status = PortStatus::ok;
  bool ok() const { return status == PortStatus::ok; }
};

enum class Buffers : std::uint8_t { input = 1, output = 2, both = 3 };

class SerialPort {
 public:
  SerialPort() = default;
  ~SerialPort();
  SerialPort(const SerialPort&) = delete;
  SerialPort& operator=(const SerialPort&) = delete;
  SerialPort(SerialPort&& other) noexcept;
  SerialPort& operator=(SerialPort&& other) noexcept;

  /// Opens a tty by path (O_NOCTTY, non-blocking under the hood), puts it in raw mode
  /// (8N1, no echo, no flow control, no line editing) and sets the baud rate (a pty ignores
  /// it, but it is set). Closes a previously open port first.
  PortStatus open(const std::string& path, std::uint32_t baud = 115200);
  /// Takes ownership of an already open tty file descriptor (e.g. a pty master) and puts it in
  /// raw mode; `name` is used in messages.
  PortStatus adopt(int fd, const std::string& name);
  PortStatus close();
  bool is_open() const { return fd_ >= 0; }
  int fd() const { return fd_; }
  const std::string& path() const { return path_; }
  std::uint32_t baud() const { return baud_; }
  PortStatus set_baud(std::uint32_t baud);

  /// Reads exactly `size` bytes unless the timeout expires (status timeout, bytes partial) or
  /// the peer closes. timeout_ms < 0 waits forever.
  IoResult blocking_read(std::uint8_t* buf, std::size_t size, int timeout_ms);
  /// Waits up to timeout_ms for input, then returns what is there (1..size bytes).
  IoResult blocking_read_next(std::uint8_t* buf, std::size_t size, int timeout_ms);
  /// Returns immediately with what is there (possibly 0 bytes, status ok).
  IoResult nonblocking_read(std::uint8_t* buf, std::size_t size);
  /// Writes all `size` bytes unless the timeout expires or the peer closes.
  IoResult blocking_write(const std::uint8_t* buf, std::size_t size, int timeout_ms);
  /// Writes what the driver accepts right now (possibly 0 bytes, status ok).
  IoResult nonblocking_write(const std::uint8_t* buf, std::size_t size);

  /// Bytes received and not yet read (FIONREAD) / written and not yet sent (TIOCOUTQ).
  IoResult input_waiting();
  IoResult output_waiting();
  /// Discards unread input and/or unsent output (tcflush).
  PortStatus flush(Buffers which = Buffers::both);
  /// Waits until the output queue is empty, or the timeout (ms, < 0 forever) expires.
  PortStatus drain(int timeout_ms);

  /// Human-readable description of the last failure (path, call, errno text).
  const std::string& last_error() const { return last_error_; }
  int last_errno() const { return last_errno_; }

 private:
  PortStatus fail(PortStatus status, const char* what, int err);
  PortStatus configure_raw(std::uint32_t baud);
  /// poll() for `events` until the deadline; returns ok when ready, timeout, peer_closed or
  /// io_error. A hangup is reported only when `events` is not also ready.
  PortStatus wait_for(short events, long long deadline_ns);

  int fd_ = -1;
  std::string path_;
  std::uint32_t baud_ = 0;
  std::string last_error_;
  int last_errno_ = 0;
};

/// Reads an open port on a thread of its own into a bounded in-memory queue, and hands the
/// bytes over on demand (take). The reading thread does nothing else: it waits in poll(),
/// reads what the driver holds, appends it and waits again, so the driver's small buffers (a
/// pseudo-terminal holds about 20 KiB, a USB-CDC device a few KiB) are emptied as soon as the
/// thread is scheduled, whatever the consumer of the bytes is doing: a consumer that decodes,
/// classifies or draws may fall behind by up to `capacity` bytes and catch up later without
/// a byte being lost. Bytes that would overflow the queue are dropped and counted.
///
/// After a short read (fewer than `trickle_bytes`) the thread waits `trickle_wait_ms` before
/// the next one, so that a port written a byte at a time (QEMU's UART) is taken in chunks
/// instead of one wake-up per byte.
///
/// With `realtime_priority` > 0 the thread asks for the real-time policy SCHED_FIFO at that
/// priority (1..99), where the system allows it (root, CAP_SYS_NICE, or an RLIMIT_RTPRIO of
/// at least that priority), so that it runs as soon as the driver has bytes, ahead of every
/// program of the ordinary policy (a browser, a build): on a loaded machine such a program
/// keeps an ordinary thread waiting for tens of milliseconds, longer than the driver's and the
/// controller's buffers hold a fast stream. Its work is bounded by what arrives (it waits in
/// poll() otherwise). Where it is not allowed the thread runs under the ordinary policy;
/// realtime() says which.
///
/// The port must stay open while the reader runs (stop() before closing it); writing to the
/// port from another thread meanwhile is fine. Host only (a thread, heap buffers).
class PortReader {
 public:
  PortReader(const SerialPort& port, std::size_t capacity, std::size_t trickle_bytes = 0,
             int trickle_wait_ms = 0, int realtime_priority = 0);
  ~PortReader();
  PortReader(const PortReader&) = delete;
  PortReader& operator=(const PortReader&) = delete;

  /// Starts the reading thread (once); not_open when the port is not open.
  PortStatus start();
  /// Stops and joins the reading thread (idempotent); what was queued can still be taken.
  void stop();
  /// Waits up to timeout_ms (< 0: forever) for queued bytes and moves up to `size` of them to
  /// `buf`. Once the queue is empty: status peer_closed or io_error when the reading thread
  /// ended on one (last_error() says why), timeout when nothing came in time.
  IoResult take(std::uint8_t* buf, std::size_t size, int timeout_ms);

  /// True when the reading thread runs under SCHED_FIFO (see realtime_priority).
  bool realtime() const { return realtime_; }
  std::size_t queued() const;
  /// The most bytes ever queued at once (how far the consumer fell behind).
  std::size_t peak() const;
  /// Bytes read from the port and dropped because the queue was full.
  std::uint64_t overflow() const;
  std::uint64_t bytes_read() const;
  std::string last_error() const;

 private:
  void run();
  void push(const std::uint8_t* data, std::size_t n);
  void end(PortStatus status, const std::string& why, int err);

  int fd_;
  std::string path_;
  std::size_t capacity_;
  std::size_t trickle_bytes_;
  int trickle_wait_ms_;
  int realtime_priority_;
  bool realtime_ = false;
  std::thread thread_;
  std::atomic<bool> stop_{false};
  mutable std::mutex mu_;
  std::condition_variable ready_;
  std::deque<std::vector<std::uint8_t>> chunks_;
  std::size_t front_used_ = 0;  // bytes of chunks_.front() already taken
  std::size_t queued_ = 0;
  std::size_t peak_ = 0;
  std::uint64_t overflow_ = 0;
  std::uint64_t bytes_read_ = 0;
  PortStatus end_ = PortStatus::ok;  // why the reading thread ended (ok: it has not)
  std::string error_;
};

}  // namespace eskin::serial
