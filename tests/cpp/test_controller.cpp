// The controller (eskin/controller.hpp) with a starved transmitter: every decision it makes is
// either received by the host or counted in STATUS's decisions_dropped, and every sample either
// received or counted in dropped_samples; a decision keeps its room in the output ahead of
// STATUS, INFO, PONG and DATA, and no DATA frame overtakes a decision waiting for room.
//
// The port is a byte queue of a given capacity, drained into the host's real FrameDecoder at a
// rate the test sets (a UART and its host); the controller, the classifier (the model fixture
// of tests/data) and both codecs are the shipped ones.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <fstream>
#include <iterator>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include "eskin/controller.hpp"
#include "eskin/model.hpp"
#include "eskin/protocol.hpp"

namespace {

namespace proto = eskin::protocol;
constexpr std::int64_t kPeriodNs = 333333;  // 3 kSps

eskin::Model load_model() {
  std::ifstream f(std::string(ESKIN_TEST_DATA_DIR) + "/model_small_float64.eskin",
                  std::ios::binary);
  EXPECT_TRUE(f.good());
  const std::vector<std::uint8_t> b((std::istreambuf_iterator<char>(f)),
                                    std::istreambuf_iterator<char>());
  return eskin::Model::from_bytes(b.data(), b.size());
}

/// `n` recordings of 12000 samples of 4x4 taxels, each with one touch at 4000..7000 (a burst of
/// sines on every taxel over noise), back to back, sample-major.
std::vector<std::int16_t> touches(int n, unsigned seed) {
  constexpr std::int64_t T = 12000;
  std::mt19937 rng(seed);
  std::normal_distribution<double> noise(0.0, 15.0);
  std::vector<std::int16_t> x(static_cast<std::size_t>(16 * T * n));
  for (int r = 0; r < n; ++r) {
    for (std::int64_t t = 0; t < T; ++t) {
      for (int k = 0; k < 16; ++k) {
        const double f = 40.0 + 13.0 * k + 3.0 * (r % 3), amp = 800.0 + 90.0 * ((k * 7 + r) % 16);
        double v = noise(rng);
        if (t >= 4000 && t < 7000) v += amp * std::sin(2 * 3.14159265358979 * f * t / 3000.0);
        x[static_cast<std::size_t>(((r * T) + t) * 16 + k)] = static_cast<std::int16_t>(std::lround(v));
      }
    }
  }
  return x;
}

struct HostDecision {
  std::uint64_t onset, offset, decided;
  std::int16_t label;
};

/// The transmitter: a queue of `capacity` bytes, drained into the host's decoder by `drain`.
class TestTransmitter final : public eskin::ControllerPort {
 public:
  explicit TestTransmitter(std::size_t capacity) : capacity_(capacity) {}

  bool host_connected() const override { return connected; }
  bool send(proto::Frame& f, std::size_t reserve) override {
    f.seq = seq_;
    const std::size_t n = encoder_.encode(f, buf_.data(), buf_.size());
    if (n == 0 || queue_.size() + n + reserve > capacity_) return false;
    seq_ = static_cast<std::uint16_t>(seq_ + 1);
    queue_.insert(queue_.end(), buf_.begin(), buf_.begin() + static_cast<std::ptrdiff_t>(n));
    return true;
  }
  void send_delimiter() override {
    if (queue_.size() < capacity_) queue_.push_back(proto::kDelimiter);
  }
  std::int64_t now_ns() const override { return now; }
  void fill_status(proto::StatusPayload&) const override {}

  /// The transmitter moves up to `n` queued bytes to the host.
  void drain(std::size_t n) {
    n = std::min(n, queue_.size());
    host_.feed_all(queue_.data(), n, [this](const proto::Frame& f) { on_frame(f); });
    queue_.erase(queue_.begin(), queue_.begin() + static_cast<std::ptrdiff_t>(n));
  }
  std::size_t queued() const { return queue_.size(); }

  bool connected = true;
  std::int64_t now = 0;
  // what the host received
  std::vector<HostDecision> decisions;
  std::uint64_t samples = 0;
  std::uint64_t data_after_pending = 0;  // DATA frames that overtook a decision made before them
  std::uint64_t max_data_end = 0;        // end of the DATA frames received so far
  bool have_status = false;
  proto::StatusPayload status;
  const proto::DecoderStats& stats() const { return host_.stats(); }

 private:
  void on_frame(const proto::Frame& f) {
    if (f.type == proto::FrameType::data) {
      samples += f.data.n_samples;
      max_data_end = std::max<std::uint64_t>(max_data_end, f.data.first_sample + f.data.n_samples);
    } else if (f.type == proto::FrameType::decision) {
      // a DATA frame holding samples after the decided one was queued after the decision was
      // made: it must not have arrived first
      if (max_data_end > f.decision.decided_sample + 1) ++data_after_pending;
      decisions.push_back({f.decision.onset_sample, f.decision.offset_sample,
                           f.decision.decided_sample, f.decision.label});
    } else if (f.type == proto::FrameType::status) {
      have_status = true;
      status = f.status;
    }
  }

  std::size_t capacity_;
  std::vector<std::uint8_t> queue_;
  std::vector<std::uint8_t> buf_ = std::vector<std::uint8_t>(proto::kMaxEncodedFrameSize);
  proto::FrameEncoder encoder_;
  proto::FrameDecoder host_{proto::kMaxFrameSize, /*wait_for_delimiter=*/true};
  std::uint16_t seq_ = 0;
};

/// The decisions the model makes on the stream, by a classifier of its own.
std::vector<HostDecision> reference_decisions(const eskin::Model& m,
                                              const std::vector<std::int16_t>& x) {
  eskin::StreamClassifier sc(m);
  std::vector<HostDecision> out;
  const std::size_t n = x.size() / 16;
  for (std::size_t i = 0; i < n; ++i) {
    if (sc.push(x.data() + 16 * i) == eskin::ClassifyStatus::kDecision) {
      const auto& d = sc.decision();
      out.push_back({static_cast<std::uint64_t>(d.window_start),
                     static_cast<std::uint64_t>(d.window_stop), i,
                     static_cast<std::int16_t>(d.label)});
    }
  }
  if (sc.flush() == eskin::ClassifyStatus::kDecision) {
    const auto& d = sc.decision();
    out.push_back({static_cast<std::uint64_t>(d.window_start),
                   static_cast<std::uint64_t>(d.window_stop), n - 1,
                   static_cast<std::int16_t>(d.label)});
  }
  return out;
}

struct Link {
  std::size_t capacity = 2048;        // the firmware's transmit ring
  std::size_t control_reserve = 512;  // what DATA leaves to the other frames (the firmware's)
  std::size_t bytes_per_sample = 36;  // what the transmitter drains per sample period
  std::uint64_t stall_from = 0, stall_to = 0;  // samples during which it drains nothing
  std::int64_t status_period_ns = 250000000;
};

/// Streams `x` through a controller whose transmitter follows `r`, ends the replay, lets the
/// transmitter drain everything, shuts the controller down and drains again.
eskin::Controller& stream(const Link& r, TestTransmitter& port, eskin::StreamClassifier& sc,
                          const std::vector<std::int16_t>& x, std::vector<std::int16_t>& frame,
                          std::unique_ptr<eskin::Controller>& holder) {
  eskin::ControllerConfig cfg;
  cfg.samples_per_frame = 10;
  frame.assign(10 * 16, 0);
  cfg.frame_samples = frame.data();
  cfg.status_period_ns = r.status_period_ns;
  cfg.control_reserve = r.control_reserve;
  holder = std::make_unique<eskin::Controller>(cfg, port, &sc);
  eskin::Controller& ctl = *holder;
  ctl.start();
  const std::uint64_t n = x.size() / 16;
  for (std::uint64_t i = 0; i < n; ++i) {
    port.now = static_cast<std::int64_t>(i) * kPeriodNs;
    ctl.push(x.data() + 16 * i, port.now);
    ctl.poll();
    if (i < r.stall_from || i >= r.stall_to) port.drain(r.bytes_per_sample);
  }
  ctl.end_of_replay(port.now, /*loop=*/false);
  for (int k = 0; k < 10000 && port.queued() > 0; ++k) {
    port.now += kPeriodNs;
    port.drain(r.bytes_per_sample);
    ctl.poll();
  }
  ctl.shutdown();
  port.drain(port.queued());
  return ctl;
}

/// Every decision made was received or counted dropped, every sample received or counted
/// dropped: the host's counts and the final STATUS add up to the controller's.
void expect_accounted(const eskin::Controller& ctl, const TestTransmitter& port,
                      std::size_t made, std::uint64_t n_samples) {
  ASSERT_TRUE(port.have_status);
  const proto::StatusPayload& s = port.status;
  EXPECT_EQ(ctl.decisions_made(), made);
  EXPECT_EQ(ctl.decisions_pending(), 0u);
  EXPECT_EQ(port.decisions.size() + s.decisions_dropped, made);
  EXPECT_EQ(s.decisions_sent, port.decisions.size());
  EXPECT_EQ(s.decisions_dropped, ctl.decisions_dropped());
  EXPECT_EQ(s.next_sample, n_samples);
  EXPECT_EQ(s.samples_sent, port.samples);
  EXPECT_EQ(port.samples + s.dropped_samples, n_samples);
  // the host's own count: the holes between DATA frames, plus the tail after the last one
  // (STATUS finished follows every DATA frame)
  EXPECT_EQ(port.samples + port.stats().lost_samples + (n_samples - port.max_data_end),
            n_samples);
  EXPECT_EQ(port.stats().crc_errors + port.stats().malformed + port.stats().lost_frames, 0u);
  EXPECT_EQ(port.data_after_pending, 0u);
}

TEST(ControllerLosses, ATransmitterThatAcceptsNothingCountsEveryDecisionAndSample) {
  const eskin::Model m = load_model();
  const auto x = touches(3, 1);
  const auto ref = reference_decisions(m, x);
  ASSERT_EQ(ref.size(), 3u);
  eskin::StreamClassifier sc(m);
  TestTransmitter port(0);
  std::vector<std::int16_t> frame;
  std::unique_ptr<eskin::Controller> holder;
  Link r;
  r.bytes_per_sample = 0;
  const eskin::Controller& ctl = stream(r, port, sc, x, frame, holder);
  EXPECT_EQ(ctl.decisions_made(), 3u);
  EXPECT_EQ(ctl.decisions_sent(), 0u);
  EXPECT_EQ(ctl.decisions_dropped(), 3u);  // they waited for room, then the controller stopped
  EXPECT_EQ(ctl.decisions_pending(), 0u);
  EXPECT_EQ(ctl.samples_sent(), 0u);
  EXPECT_EQ(ctl.dropped_samples(), x.size() / 16);
  EXPECT_GT(ctl.frames_dropped(), 0u);  // INFO and the STATUS frames
  EXPECT_TRUE(port.decisions.empty());
}

// The reported failure: the host stops reading for 4 s while a touch ends. The STATUS frames of
// the stall (every 250 ms) no longer eat the room a decision needs: the decision goes out the
// moment it is made (or, at worst, as soon as the transmitter moves), never dropped.
TEST(ControllerLosses, AStalledTransmitterStillCarriesTheDecision) {
  const eskin::Model m = load_model();
  const auto x = touches(3, 2);
  const auto ref = reference_decisions(m, x);
  ASSERT_EQ(ref.size(), 3u);
  eskin::StreamClassifier sc(m);
  TestTransmitter port(2048);
  std::vector<std::int16_t> frame;
  std::unique_ptr<eskin::Controller> holder;
  Link r;
  r.stall_from = 1000;
  r.stall_to = 13000;  // 4 s, across the first decision
  // more than 8 STATUS periods (750 samples) into the stall: 8 STATUS frames (74 bytes on the
  // wire) fill more than the 512 bytes DATA leaves free
  ASSERT_GT(ref[0].decided, r.stall_from + 8 * 750);
  ASSERT_LT(ref[0].decided, r.stall_to);
  const eskin::Controller& ctl = stream(r, port, sc, x, frame, holder);
  expect_accounted(ctl, port, ref.size(), x.size() / 16);
  EXPECT_EQ(ctl.decisions_dropped(), 0u);
  ASSERT_EQ(port.decisions.size(), ref.size());
  for (std::size_t i = 0; i < ref.size(); ++i) {
    EXPECT_EQ(port.decisions[i].onset, ref[i].onset);
    EXPECT_EQ(port.decisions[i].offset, ref[i].offset);
    EXPECT_EQ(port.decisions[i].decided, ref[i].decided);
    EXPECT_EQ(port.decisions[i].label, ref[i].label);
  }
  EXPECT_GT(ctl.dropped_samples(), 0u);  // the stall cost DATA frames, counted
  EXPECT_GT(ctl.frames_dropped(), 0u);   // and STATUS frames, counted
}

// A stall across more decisions than the output and the waiting queue hold: the later ones are
// dropped and counted, the rest arrive in order, none overtaken by DATA.
TEST(ControllerLosses, ALongStallDropsDecisionsOnlyWithACount) {
  const eskin::Model m = load_model();
  const auto x = touches(10, 3);
  const auto ref = reference_decisions(m, x);
  ASSERT_EQ(ref.size(), 10u);
  for (const std::size_t capacity : {std::size_t{600}, std::size_t{2048}, std::size_t{16384}}) {
    eskin::StreamClassifier sc(m);
    TestTransmitter port(capacity);
    std::vector<std::int16_t> frame;
    std::unique_ptr<eskin::Controller> holder;
    Link r;
    r.capacity = capacity;
    r.control_reserve = std::min<std::size_t>(512, capacity / 2);
    r.stall_from = 1000;
    r.stall_to = 12000 * 9 + 1000;  // 9 touches end while the transmitter is stalled
    const eskin::Controller& ctl = stream(r, port, sc, x, frame, holder);
    expect_accounted(ctl, port, ref.size(), x.size() / 16);
    EXPECT_GT(ctl.decisions_dropped(), 0u) << capacity;
    EXPECT_GE(port.decisions.size(), 5u) << capacity;  // at least the 4 waiting and the last
    // the ones received are the model's, in order
    std::size_t j = 0;
    for (const auto& d : port.decisions) {
      while (j < ref.size() && ref[j].decided != d.decided) ++j;
      ASSERT_LT(j, ref.size()) << capacity;
      EXPECT_EQ(d.onset, ref[j].onset);
      EXPECT_EQ(d.label, ref[j].label);
    }
  }
}

TEST(ControllerLosses, WithoutAHostDecisionsAreDroppedAndCounted) {
  const eskin::Model m = load_model();
  const auto x = touches(2, 4);
  eskin::StreamClassifier sc(m);
  TestTransmitter port(1 << 20);
  port.connected = false;
  std::vector<std::int16_t> frame;
  std::unique_ptr<eskin::Controller> holder;
  const eskin::Controller& ctl = stream(Link{}, port, sc, x, frame, holder);
  EXPECT_EQ(ctl.decisions_made(), 2u);
  EXPECT_EQ(ctl.decisions_dropped(), 2u);
  EXPECT_EQ(ctl.dropped_samples(), x.size() / 16);
  EXPECT_EQ(ctl.frames_dropped(), 0u);  // nobody to send a STATUS to is no loss
  EXPECT_EQ(port.queued(), 0u);
}

// STATUS, INFO and PONG leave room for one DECISION: with the output filled up to that room
// they are refused (and counted), and the decision still fits.
TEST(ControllerLosses, ControlFramesLeaveRoomForADecision) {
  const std::size_t status_bytes = proto::max_encoded_size(proto::kHeaderSize +
                                                           proto::kStatusSize + proto::kCrcSize);
  TestTransmitter port(proto::kMaxEncodedDecisionSize + status_bytes - 1);
  std::vector<std::int16_t> frame(160);
  eskin::ControllerConfig cfg;
  cfg.frame_samples = frame.data();
  cfg.status_period_ns = 0;
  eskin::Controller ctl(cfg, port, nullptr);
  EXPECT_FALSE(ctl.send_status());
  EXPECT_EQ(ctl.frames_dropped(), 1u);
  proto::Frame ping;
  ping.type = proto::FrameType::ping;
  ctl.on_command(ping);  // its PONG (14 bytes) fits beside the decision's room
  EXPECT_EQ(ctl.frames_dropped(), 1u);
  EXPECT_GT(port.queued(), 0u);
  TestTransmitter roomy(proto::kMaxEncodedDecisionSize + status_bytes);
  eskin::Controller ctl2(cfg, roomy, nullptr);
  EXPECT_TRUE(ctl2.send_status());
  EXPECT_EQ(ctl2.frames_dropped(), 0u);
}

}  // namespace
