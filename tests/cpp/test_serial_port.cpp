// SerialPort on a real pseudo-terminal pair: the slave opened by path like a host opens a
// USB-CDC device, the master adopted like the firmware simulator does.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <stdlib.h>
#include <unistd.h>

#include <algorithm>
#include <ctime>
#include <string>
#include <vector>

#include "eskin/serial_port.hpp"

using eskin::serial::Buffers;
using eskin::serial::IoResult;
using eskin::serial::PortStatus;
using eskin::serial::SerialPort;

namespace {

struct PtyPair {
  SerialPort master;
  SerialPort slave;
  std::string slave_path;

  PtyPair() {
    const int fd = posix_openpt(O_RDWR | O_NOCTTY);
    EXPECT_GE(fd, 0);
    EXPECT_EQ(grantpt(fd), 0);
    EXPECT_EQ(unlockpt(fd), 0);
    slave_path = ptsname(fd);
    EXPECT_EQ(master.adopt(fd, "pty master"), PortStatus::ok) << master.last_error();
    EXPECT_EQ(slave.open(slave_path, 115200), PortStatus::ok) << slave.last_error();
  }
};

std::vector<std::uint8_t> pattern(std::size_t n) {
  std::vector<std::uint8_t> v(n);
  for (std::size_t i = 0; i < n; ++i) v[i] = static_cast<std::uint8_t>(i * 7 + 3);
  return v;
}

}  // namespace

TEST(SerialPort, OpenErrorsAreCodesWithMessages) {
  SerialPort p;
  EXPECT_EQ(p.open("/nonexistent/tty"), PortStatus::open_failed);
  EXPECT_NE(p.last_error().find("/nonexistent/tty"), std::string::npos);
  EXPECT_NE(p.last_errno(), 0);
  EXPECT_FALSE(p.is_open());
  EXPECT_EQ(p.open("/dev/null"), PortStatus::not_a_tty);
  EXPECT_FALSE(p.is_open());
  PtyPair pty;
  EXPECT_EQ(p.open(pty.slave_path, 12345), PortStatus::invalid_argument);
  EXPECT_NE(p.last_error().find("12345"), std::string::npos);
  std::uint8_t b[4];
  EXPECT_EQ(p.nonblocking_read(b, 4).status, PortStatus::not_open);
  EXPECT_EQ(p.blocking_write(b, 4, 10).status, PortStatus::not_open);
  EXPECT_EQ(p.flush(), PortStatus::not_open);
  EXPECT_STREQ(eskin::serial::port_status_name(PortStatus::peer_closed), "peer_closed");
}

TEST(SerialPort, RawModeRoundTripsEveryByteBothWays) {
  PtyPair pty;
  EXPECT_EQ(pty.slave.baud(), 115200U);
  EXPECT_EQ(pty.slave.set_baud(921600), PortStatus::ok);  // set, though a pty ignores it
  const auto data = pattern(3000);  // every byte value, incl. 0x00, 0x03 (^C), 0x0A, 0x11 (XON)
  IoResult w = pty.master.blocking_write(data.data(), data.size(), 1000);
  ASSERT_EQ(w.status, PortStatus::ok);
  ASSERT_EQ(w.bytes, data.size());
  std::vector<std::uint8_t> got(data.size());
  IoResult r = pty.slave.blocking_read(got.data(), got.size(), 1000);
  ASSERT_EQ(r.status, PortStatus::ok) << pty.slave.last_error();
  EXPECT_EQ(got, data);

  w = pty.slave.blocking_write(data.data(), 500, 1000);
  ASSERT_EQ(w.bytes, 500U);
  std::vector<std::uint8_t> back(600);
  std::size_t n = 0;
  while (n < 500) {
    r = pty.master.blocking_read_next(back.data() + n, back.size() - n, 1000);
    ASSERT_EQ(r.status, PortStatus::ok);
    n += r.bytes;
  }
  EXPECT_EQ(n, 500U);
  EXPECT_TRUE(std::equal(back.begin(), back.begin() + 500, data.begin()));
}

TEST(SerialPort, TimeoutsAndNonBlockingReads) {
  PtyPair pty;
  std::uint8_t buf[16];
  IoResult r = pty.slave.nonblocking_read(buf, sizeof buf);
  EXPECT_EQ(r.status, PortStatus::ok);
  EXPECT_EQ(r.bytes, 0U);
  r = pty.slave.blocking_read_next(buf, sizeof buf, 20);
  EXPECT_EQ(r.status, PortStatus::timeout);  // silence is a timeout, not a closed peer
  EXPECT_EQ(r.bytes, 0U);
  const auto data = pattern(5);
  ASSERT_EQ(pty.master.blocking_write(data.data(), 5, 100).bytes, 5U);
  r = pty.slave.blocking_read(buf, 10, 50);  // asks for 10, only 5 come
  EXPECT_EQ(r.status, PortStatus::timeout);
  EXPECT_EQ(r.bytes, 5U);
  ASSERT_EQ(pty.master.blocking_write(data.data(), 5, 100).bytes, 5U);
  r = pty.slave.blocking_read_next(buf, 3, 1000);  // returns as soon as something is there
  EXPECT_EQ(r.status, PortStatus::ok);
  EXPECT_EQ(r.bytes, 3U);
  IoResult waiting = pty.slave.input_waiting();
  EXPECT_EQ(waiting.status, PortStatus::ok);
  EXPECT_EQ(waiting.bytes, 2U);
  r = pty.slave.nonblocking_read(buf, sizeof buf);
  EXPECT_EQ(r.bytes, 2U);
}

TEST(SerialPort, NonBlockingWriteStopsWhenFullAndBlockingWriteTimesOut) {
  PtyPair pty;
  const auto chunk = pattern(4096);
  std::size_t total = 0;
  for (int i = 0; i < 1000; ++i) {
    const IoResult w = pty.master.nonblocking_write(chunk.data(), chunk.size());
    ASSERT_EQ(w.status, PortStatus::ok);
    total += w.bytes;
    if (w.bytes == 0) break;
  }
  EXPECT_GT(total, 0U);
  EXPECT_LT(total, 1000U * 4096U);  // the kernel buffer filled up: no block, 0 bytes
  const IoResult w = pty.master.blocking_write(chunk.data(), chunk.size(), 30);
  EXPECT_EQ(w.status, PortStatus::timeout);
  // flushing the reader's input makes room again
  EXPECT_EQ(pty.slave.flush(Buffers::input), PortStatus::ok);
  EXPECT_EQ(pty.slave.input_waiting().bytes, 0U);
  EXPECT_EQ(pty.master.blocking_write(chunk.data(), 100, 1000).bytes, 100U);
  EXPECT_EQ(pty.master.drain(1000), PortStatus::ok);
}

TEST(SerialPort, ClosedMasterIsReportedAfterPendingData) {
  PtyPair pty;
  const auto data = pattern(10);
  ASSERT_EQ(pty.master.blocking_write(data.data(), 10, 100).bytes, 10U);
  ASSERT_EQ(pty.master.close(), PortStatus::ok);
  std::uint8_t buf[64];
  std::size_t n = 0;
  IoResult r;
  for (int i = 0; i < 10; ++i) {
    r = pty.slave.blocking_read_next(buf + n, sizeof buf - n, 200);
    n += r.bytes;
    if (r.status != PortStatus::ok) break;
  }
  // data written before the hang-up may or may not survive the close; the hang-up is reported
  EXPECT_LE(n, 10U);
  EXPECT_EQ(r.status, PortStatus::peer_closed) << pty.slave.last_error();
  r = pty.slave.nonblocking_read(buf, sizeof buf);
  EXPECT_EQ(r.status, PortStatus::peer_closed);
  const IoResult w = pty.slave.blocking_write(data.data(), 10, 100);
  EXPECT_EQ(w.status, PortStatus::peer_closed);
}

TEST(SerialPort, ClosedSlaveIsReportedToTheMaster) {
  PtyPair pty;
  ASSERT_EQ(pty.slave.close(), PortStatus::ok);
  std::uint8_t buf[8];
  IoResult r = pty.master.blocking_read_next(buf, sizeof buf, 200);
  EXPECT_EQ(r.status, PortStatus::peer_closed);
  r = pty.master.nonblocking_read(buf, sizeof buf);
  EXPECT_EQ(r.status, PortStatus::peer_closed);
  // the host reopens the port: the link works again
  SerialPort again;
  ASSERT_EQ(again.open(pty.slave_path), PortStatus::ok) << again.last_error();
  const auto data = pattern(4);
  ASSERT_EQ(again.blocking_write(data.data(), 4, 100).bytes, 4U);
  r = pty.master.blocking_read_next(buf, sizeof buf, 1000);
  EXPECT_EQ(r.status, PortStatus::ok);
  EXPECT_EQ(r.bytes, 4U);
}

TEST(SerialPort, MoveKeepsTheDescriptor) {
  PtyPair pty;
  SerialPort moved(std::move(pty.slave));
  EXPECT_FALSE(pty.slave.is_open());
  EXPECT_TRUE(moved.is_open());
  EXPECT_EQ(moved.path(), pty.slave_path);
  const auto data = pattern(3);
  ASSERT_EQ(pty.master.blocking_write(data.data(), 3, 100).bytes, 3U);
  std::uint8_t buf[3];
  EXPECT_EQ(moved.blocking_read(buf, 3, 1000).bytes, 3U);
}

namespace {

/// Polls `done` every 2 ms for up to 5 s (the reading thread's progress is seen from outside).
template <class Fn>
bool eventually(Fn&& done) {
  for (int i = 0; i < 2500 && !done(); ++i) {
    const timespec ts{0, 2000000L};
    nanosleep(&ts, nullptr);
  }
  return done();
}

}  // namespace

TEST(PortReader, HoldsFarMoreThanThePtyWhileNobodyTakesThenHandsItOverInOrder) {
  PtyPair pty;
  eskin::serial::PortReader reader(pty.slave, 1 << 20);
  ASSERT_EQ(reader.start(), PortStatus::ok);
  // a pty holds about 20 KiB: this write completes only because the reader empties it
  const auto data = pattern(300000);
  ASSERT_EQ(pty.master.blocking_write(data.data(), data.size(), 5000).bytes, data.size());
  ASSERT_TRUE(eventually([&] { return reader.queued() == data.size(); }));
  EXPECT_EQ(reader.peak(), data.size());
  std::vector<std::uint8_t> got(data.size());
  std::size_t n = 0;
  while (n < got.size()) {
    const IoResult r = reader.take(got.data() + n, std::min<std::size_t>(7777, got.size() - n), 100);
    ASSERT_EQ(r.status, PortStatus::ok);
    n += r.bytes;
  }
  EXPECT_EQ(got, data);
  EXPECT_EQ(reader.queued(), 0U);
  EXPECT_EQ(reader.overflow(), 0U);
  std::uint8_t b[4];
  EXPECT_EQ(reader.take(b, 4, 20).status, PortStatus::timeout);
  reader.stop();
  reader.stop();
}

TEST(PortReader, CountsWhatOverflowsItsQueueAndReportsTheHangUpAfterTheData) {
  PtyPair pty;
  eskin::serial::PortReader reader(pty.slave, 4096);
  ASSERT_EQ(reader.start(), PortStatus::ok);
  const auto data = pattern(65536);
  ASSERT_EQ(pty.master.blocking_write(data.data(), data.size(), 5000).bytes, data.size());
  ASSERT_TRUE(eventually([&] { return reader.bytes_read() == data.size(); }));
  EXPECT_LE(reader.queued(), 4096U);
  EXPECT_EQ(reader.queued() + reader.overflow(), data.size());
  // what was queued is the stream's beginning, in order
  std::vector<std::uint8_t> got(reader.queued());
  ASSERT_EQ(reader.take(got.data(), got.size(), 100).bytes, got.size());
  EXPECT_TRUE(std::equal(got.begin(), got.end(), data.begin()));
  ASSERT_EQ(pty.master.close(), PortStatus::ok);
  std::uint8_t b[4];
  IoResult r;
  for (int i = 0; i < 50 && r.status != PortStatus::peer_closed; ++i) r = reader.take(b, 4, 100);
  EXPECT_EQ(r.status, PortStatus::peer_closed);
  EXPECT_NE(reader.last_error().find(pty.slave_path), std::string::npos);
}

TEST(PortReader, RefusesAPortThatIsNotOpen) {
  SerialPort closed;
  eskin::serial::PortReader reader(closed, 1024);
  EXPECT_EQ(reader.start(), PortStatus::not_open);
}
