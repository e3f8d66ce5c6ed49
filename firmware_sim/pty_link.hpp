// The simulator's end of the serial link: a pseudo-terminal master, a bounded transmit queue
// written without ever blocking, host-presence detection (POLLHUP), and test fault injection.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "eskin/protocol.hpp"
#include "eskin/serial_port.hpp"

namespace eskin::fwsim {

struct FaultConfig {
  double drop_rate = 0.0;      // per byte: the byte is lost
  double flip_rate = 0.0;      // per byte: one bit flips
  double burst_rate = 0.0;     // per frame: a burst of random bytes precedes it
  int burst_len = 32;          // longest burst
  double truncate_rate = 0.0;  // per frame: cut short (its delimiter still follows)
  std::uint64_t seed = 1;
  bool any() const { return drop_rate > 0 || flip_rate > 0 || burst_rate > 0 || truncate_rate > 0; }
};

/// xorshift64* generator: deterministic per seed, no allocation.
class Rng {
 public:
  explicit Rng(std::uint64_t seed) : s_(seed ? seed * 0x9E3779B97F4A7C15ULL : 0x2545F4914F6CDD1DULL) {}
  std::uint64_t next() {
    s_ ^= s_ >> 12;
    s_ ^= s_ << 25;
    s_ ^= s_ >> 27;
    return s_ * 0x2545F4914F6CDD1DULL;
  }
  double uniform() { return static_cast<double>(next() >> 11) * (1.0 / 9007199254740992.0); }

 private:
  std::uint64_t s_;
};

class PtyLink {
 public:
  PtyLink(std::size_t tx_capacity, const FaultConfig& faults);
  ~PtyLink();

  /// Creates the pty (raw mode) and, when `link_path` is not empty, a symlink to its slave.
  bool open(const std::string& link_path, std::string& error);
  const std::string& slave_path() const { return slave_path_; }

  /// Polls for a hang-up: false while no host has the slave open (after one closed it).
  /// Returns true on a not-connected -> connected transition through `reconnected`.
  bool update_host(bool& reconnected, bool& disconnected);
  bool host_connected() const { return host_connected_; }

  /// Frame queueing. Assigns the sequence number, encodes, applies faults, and queues the
  /// bytes if they all fit with `reserve` bytes to spare (never a partial frame). Returns false
  /// when the queue is too full. DATA keeps a reserve so that control frames (DECISION,
  /// STATUS, INFO, PONG) still fit when samples are being dropped.
  bool send(protocol::Frame& frame, std::size_t reserve = 0);
  /// Queues a lone delimiter (stream start). False when full.
  bool send_delimiter();
  bool fits(std::size_t encoded_bytes) const { return capacity_ - size_ >= encoded_bytes + extra_; }
  std::size_t capacity() const { return capacity_; }
  /// Writes as much queued data as the pty takes now (non-blocking). False if the peer closed.
  bool flush_tx();
  std::size_t queued() const { return size_; }
  void clear_tx() { begin_ = size_ = 0; }
  /// Waits (poll) until the pty can take more output, input arrives, or timeout_ms passes.
  /// While no host is connected it sleeps timeout_ms (a hung-up pty would wake poll at once).
  void wait_io(int timeout_ms, bool want_output);
  /// Waits (poll) until the pty can take more output, or timeout_ms passes.
  void wait_writable(int timeout_ms);
  /// Waits until the host has read everything written (or the timeout): closing the master
  /// discards what the slave has not read yet.
  /// (The master's own output queue is always empty: the bytes sit in the slave's input queue,
  /// which is measured through a slave descriptor.)
  void drain(int timeout_ms);

  /// Reads host bytes (non-blocking) and feeds them to the command decoder; calls
  /// on_frame(const Frame&) for each accepted host frame.
  template <class Fn>
  void poll_commands(Fn&& on_frame) {
    std::uint8_t buf[512];
    for (int i = 0; i < 16; ++i) {
      const auto r = port_.nonblocking_read(buf, sizeof buf);
      if (r.bytes == 0) break;
      rx_.feed_all(buf, r.bytes, on_frame);
    }
  }
  std::uint32_t rx_errors() const {
    const auto& s = rx_.stats();
    return static_cast<std::uint32_t>(s.crc_errors + s.malformed + s.oversize);
  }
  std::uint64_t faults_injected() const { return faults_injected_; }
  std::uint64_t bytes_written() const { return bytes_written_; }

 private:
  std::size_t apply_faults(const std::uint8_t* in, std::size_t n, std::uint8_t* out);
  bool push_bytes(const std::uint8_t* p, std::size_t n);

  serial::SerialPort port_;
  std::string slave_path_;
  std::string link_path_;
  bool host_connected_ = true;  // a fresh pty shows no hang-up until a host has come and gone
  std::vector<std::uint8_t> tx_;
  std::size_t capacity_;
  std::size_t begin_ = 0;
  std::size_t size_ = 0;
  std::size_t extra_ = 0;  // worst-case growth of a frame by fault injection
  protocol::FrameEncoder encoder_;
  std::vector<std::uint8_t> scratch_;
  std::vector<std::uint8_t> faulted_;
  protocol::FrameDecoder rx_;
  std::uint16_t seq_ = 0;
  FaultConfig faults_;
  Rng rng_;
  std::uint64_t faults_injected_ = 0;
  std::uint64_t bytes_written_ = 0;
};

}  // namespace eskin::fwsim
