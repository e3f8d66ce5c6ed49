// The skin controller's logic, once for every port: the wire protocol's state machine (START,
// STOP, PING, INFO_REQUEST; stream start and host connection announcements), the stream of
// DATA frames, the on-board classification with its DECISION frames, and the STATUS counters
// (docs/wire-protocol.md). `eskin-fw-sim` runs it on a pseudo-terminal, the firmware
// (mcu/eskin_fw.cpp) on the Cortex-M4F's UART; each gives it a ControllerPort.
//
// Heap-free, exception-free and portable: no POSIX, no iostreams, no containers. The controller
// never blocks and never waits: the port decides what to do with a frame that does not fit.
//
// Nothing is lost without a count. A frame's place in the port's output goes by priority:
// DECISION first (it may take the last byte), then STATUS, INFO and PONG (they leave room for
// one DECISION), then DATA (it leaves `control_reserve`). A decision that finds no room waits
// in a small queue of its own and goes out before any later DATA frame; one that cannot wait
// (the queue is full, or no host is there) is counted in `decisions_dropped`, samples that are
// not sent in `dropped_samples`, and the other frames that do not fit in `frames_dropped`:
// all three in STATUS.
#pragma once

#include <cstddef>
#include <cstdint>

#include "eskin/protocol.hpp"

namespace eskin {

class StreamClassifier;

/// What the controller needs from its link and clock. Times are nanoseconds since the
/// controller's origin (its DATA and STATUS timestamps are in microseconds of that clock).
class ControllerPort {
 public:
  /// False while the port knows that no host is there (frames are then not queued, and the
  /// samples they carried count as dropped). A port that cannot tell returns true.
  virtual bool host_connected() const = 0;
  /// Queues one frame (the port assigns its sequence number and encodes it) if it fits with
  /// `reserve` bytes to spare: never a partial frame. False when it does not fit.
  virtual bool send(protocol::Frame& frame, std::size_t reserve) = 0;
  /// Queues a lone delimiter (a stream starts: the host's decoder resynchronises).
  virtual void send_delimiter() = 0;
  virtual std::int64_t now_ns() const = 0;
  /// The port's own counters for STATUS: rx_errors, faults_injected and the pacing lateness.
  virtual void fill_status(protocol::StatusPayload& status) const = 0;
  /// The stream starts (at start-up or on START; `again` when START came after the end):
  /// the sample source re-anchors its clock and, with `again`, rewinds.
  virtual void on_stream_start(bool again) { (void)again; }
  /// A DECISION frame was queued with this latency.
  virtual void on_decision_sent(std::uint32_t latency_us) { (void)latency_us; }
  /// A decision could not be queued and never will be (counted in `decisions_dropped`).
  virtual void on_decision_dropped(const protocol::DecisionPayload& decision) { (void)decision; }

 protected:
  ~ControllerPort() = default;
};

struct ControllerConfig {
  std::uint8_t rows = 4;
  std::uint8_t cols = 4;
  /// Samples per DATA frame; `frame_samples` holds samples_per_frame * rows * cols codes.
  std::uint16_t samples_per_frame = 10;
  std::int16_t* frame_samples = nullptr;
  double sample_rate_hz = 3000.0;
  double volts_per_count = 0.0;
  double speed = 1.0;  // INFO's replay speed (0 = unpaced)
  /// INFO's class names: names_len bytes, names separated by '\n' (may be null when 0).
  const char* class_names = nullptr;
  std::uint16_t names_len = 0;
  std::uint8_t n_classes = 0;
  /// Period of the STATUS frames (0: only when asked for by the owner's loop).
  std::int64_t status_period_ns = 250000000;
  /// Queue bytes DATA frames leave free for control frames (DECISION, STATUS, INFO, PONG).
  std::size_t control_reserve = 1024;
  /// Queue bytes STATUS, INFO and PONG frames leave free for a DECISION.
  std::size_t decision_reserve = protocol::kMaxEncodedDecisionSize;
};

class Controller {
 public:
  /// `classifier` may be null (no on-board classification); it must outlive the controller.
  Controller(const ControllerConfig& config, ControllerPort& port,
             StreamClassifier* classifier = nullptr);

  /// The stream starts now (a controller that streams without waiting for START).
  void start();
  /// The port saw a host open the link: counts the connection and announces (delimiter, INFO).
  void host_connected();
  /// One frame from the host.
  void on_command(const protocol::Frame& frame);

  /// One sample (rows * cols codes) acquired at `acquired_ns`: classified, appended to the
  /// DATA frame being filled, which goes out when full.
  void push(const std::int16_t* sample, std::int64_t acquired_ns);
  /// `n` samples were lost before they reached the controller (the acquisition ring was full):
  /// they count as dropped, and their stream indices are skipped (the host sees the hole); the
  /// classifier sees the last sample in their place, so its windows stay in stream indices.
  void lost(std::uint64_t n, std::int64_t now_ns);
  /// The replay ended at `acquired_ns`: the last partial DATA frame goes out; with `loop` the
  /// stream goes on (the next DATA frame carries LOOP), otherwise a touch in progress is
  /// decided and a STATUS (state finished) follows every DATA frame.
  void end_of_replay(std::int64_t acquired_ns, bool loop);
  /// Periodic work: the decisions waiting for room first, then a STATUS when its period has
  /// passed.
  void poll();
  /// Queues a STATUS (false when it did not fit, counted in `frames_dropped`).
  bool send_status();
  /// The controller stops for good (its owner exits): the decisions still waiting for room
  /// get a last chance, the rest count as dropped, and a final STATUS is queued.
  void shutdown();

  bool streaming() const { return streaming_; }
  bool finished() const { return finished_; }
  std::uint64_t next_sample() const { return next_sample_; }
  std::uint64_t samples_sent() const { return samples_sent_; }
  std::uint64_t dropped_samples() const { return dropped_samples_; }
  std::uint32_t overrun_events() const { return overrun_events_; }
  std::uint32_t connections() const { return connections_; }
  std::uint64_t decisions_made() const { return decisions_made_; }
  std::uint64_t decisions_sent() const { return decisions_sent_; }
  std::uint64_t decisions_dropped() const { return decisions_dropped_; }
  /// Decisions made but not yet queued (waiting for room in the port's output).
  std::size_t decisions_pending() const { return pending_count_; }
  std::uint64_t frames_dropped() const { return frames_dropped_; }
  std::uint64_t classify_errors() const { return classify_errors_; }
  std::uint64_t unexpected_frames() const { return unexpected_frames_; }

 private:
  void start_stream(bool from_command);
  void announce();
  void send_info();
  void send_data(std::int64_t acquired_ns);
  void send_decision(std::int64_t acquired_ns);
  bool flush_pending();
  void drop_decision(const protocol::DecisionPayload& p);
  bool queue(protocol::Frame& f, std::size_t reserve = 0);
  bool queue_control(protocol::Frame& f);
  std::uint64_t us_since_origin(std::int64_t t_ns) const;

  ControllerConfig cfg_;
  ControllerPort& port_;
  StreamClassifier* classifier_;
  std::size_t taxels_;
  bool streaming_ = false;
  bool finished_ = false;
  bool sync_pending_ = false;
  bool loop_flag_ = false;
  bool dropping_ = false;
  bool dropped_since_data_ = false;
  bool dropped_since_status_ = false;
  std::size_t frame_fill_ = 0;
  std::uint64_t frame_first_ = 0;
  const std::int16_t* last_sample_ = nullptr;  // in frame_samples: the last one pushed
  std::uint64_t next_sample_ = 0;
  std::int64_t last_status_ns_ = 0;
  std::uint64_t samples_sent_ = 0;
  std::uint64_t dropped_samples_ = 0;
  std::uint32_t overrun_events_ = 0;
  std::uint32_t connections_ = 0;
  std::uint64_t unexpected_frames_ = 0;
  std::uint64_t decisions_made_ = 0;
  std::uint64_t decisions_sent_ = 0;
  std::uint64_t classify_errors_ = 0;
  std::uint64_t decisions_dropped_ = 0;
  std::uint64_t frames_dropped_ = 0;
  // decisions waiting for room, oldest first (a ring)
  static constexpr std::size_t kPendingDecisions = 4;
  protocol::DecisionPayload pending_[kPendingDecisions];
  std::size_t pending_head_ = 0;
  std::size_t pending_count_ = 0;
};

}  // namespace eskin
