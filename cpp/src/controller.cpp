#include "eskin/controller.hpp"

#include <cstring>

#include "eskin/model.hpp"

namespace eskin {

namespace proto = eskin::protocol;

namespace {

std::uint32_t clamp_u32(std::int64_t v) {
  if (v < 0) return 0;
  if (v > 0xFFFFFFFFLL) return 0xFFFFFFFFU;
  return static_cast<std::uint32_t>(v);
}

}  // namespace

Controller::Controller(const ControllerConfig& config, ControllerPort& port,
                       StreamClassifier* classifier)
    : cfg_(config),
      port_(port),
      classifier_(classifier),
      taxels_(static_cast<std::size_t>(config.rows) * config.cols) {
  if (cfg_.samples_per_frame == 0) cfg_.samples_per_frame = 1;
  last_status_ns_ = port_.now_ns();
}

std::uint64_t Controller::us_since_origin(std::int64_t t_ns) const {
  return t_ns <= 0 ? 0 : static_cast<std::uint64_t>(t_ns / 1000);
}

void Controller::start() { start_stream(false); }

void Controller::host_connected() {
  ++connections_;
  announce();  // a delimiter first, so the host's decoder syncs before our first frame
}

void Controller::start_stream(bool from_command) {
  const bool again = from_command && finished_;  // START after the end: play it again
  if (again) finished_ = false;
  streaming_ = true;
  port_.on_stream_start(again);
  announce();
}

/// Delimiter + INFO, with SYNC on the first frame after it.
void Controller::announce() {
  if (!port_.host_connected()) return;
  port_.send_delimiter();
  sync_pending_ = true;
  send_info();
}

/// Queues a frame if a host is there and it fits (keeping `reserve` bytes free); the first
/// frame after an announcement carries SYNC.
bool Controller::queue(proto::Frame& f, std::size_t reserve) {
  if (!port_.host_connected()) return false;
  if (sync_pending_) f.flags |= proto::flags::kSync;
  const bool ok = port_.send(f, reserve);
  if (ok) sync_pending_ = false;
  return ok;
}

/// STATUS, INFO and PONG: they leave room for a DECISION, and one that does not fit while a
/// host is there is counted.
bool Controller::queue_control(proto::Frame& f) {
  if (queue(f, cfg_.decision_reserve)) return true;
  if (port_.host_connected()) ++frames_dropped_;
  return false;
}

void Controller::send_info() {
  proto::Frame f;
  f.type = proto::FrameType::info;
  auto& p = f.info;
  p.rows = cfg_.rows;
  p.cols = cfg_.cols;
  p.samples_per_frame = cfg_.samples_per_frame;
  p.sample_rate_hz = cfg_.sample_rate_hz;
  p.volts_per_count = cfg_.volts_per_count;
  p.speed = cfg_.speed;
  p.has_model = classifier_ != nullptr ? 1 : 0;
  p.n_classes = cfg_.n_classes;
  p.names_len = cfg_.names_len;
  p.class_names = cfg_.class_names;
  queue_control(f);
}

void Controller::push(const std::int16_t* sample, std::int64_t acquired_ns) {
  std::memcpy(cfg_.frame_samples + frame_fill_ * taxels_, sample, taxels_ * sizeof(std::int16_t));
  if (frame_fill_ == 0) frame_first_ = next_sample_;
  last_sample_ = cfg_.frame_samples + frame_fill_ * taxels_;
  ++frame_fill_;
  ++next_sample_;
  if (classifier_ != nullptr) {
    const ClassifyStatus st = classifier_->push(sample);
    if (st == ClassifyStatus::kDecision) {
      send_decision(acquired_ns);
    } else if (st != ClassifyStatus::kOk) {
      ++classify_errors_;
    }
  }
  if (frame_fill_ == cfg_.samples_per_frame) send_data(acquired_ns);
}

void Controller::lost(std::uint64_t n, std::int64_t now_ns) {
  if (n == 0) return;
  if (frame_fill_ > 0) send_data(now_ns);  // DATA frames hold consecutive samples
  // The classifier's windows are in stream indices, so it sees the hole too: filled with the
  // last sample, as the host's listener fills a short hole before it classifies.
  if (classifier_ != nullptr && last_sample_ != nullptr) {
    for (std::uint64_t i = 0; i < n; ++i) {
      ++next_sample_;
      const ClassifyStatus st = classifier_->push(last_sample_);
      if (st == ClassifyStatus::kDecision) send_decision(now_ns);
      else if (st != ClassifyStatus::kOk) ++classify_errors_;
    }
    next_sample_ -= n;
  }
  next_sample_ += n;
  dropped_samples_ += n;
  dropped_since_data_ = dropped_since_status_ = true;
  if (!dropping_) ++overrun_events_;
  dropping_ = true;
}

void Controller::end_of_replay(std::int64_t acquired_ns, bool loop) {
  if (frame_fill_ > 0) send_data(acquired_ns);
  if (loop) {
    loop_flag_ = true;
    return;
  }
  finished_ = true;
  // The replay ended inside a touch: decide on it now. Its decided sample is the last one, so
  // the latency runs from that sample's acquisition and includes this classification.
  if (classifier_ != nullptr && classifier_->flush() == ClassifyStatus::kDecision)
    send_decision(acquired_ns);
  send_status();
}

void Controller::send_decision(std::int64_t acquired_ns) {
  const Decision& d = classifier_->decision();
  proto::DecisionPayload p;
  p.onset_sample = static_cast<std::uint64_t>(d.window_start > 0 ? d.window_start : 0);
  p.offset_sample = static_cast<std::uint64_t>(d.window_stop > 0 ? d.window_stop : 0);
  p.decided_sample = next_sample_ == 0 ? 0 : next_sample_ - 1;
  p.label = static_cast<std::int16_t>(d.label);
  p.dont_know = d.dont_know ? 1 : 0;
  const int n_values = d.n_machines < static_cast<int>(proto::kMaxDecisionValues)
                           ? d.n_machines
                           : static_cast<int>(proto::kMaxDecisionValues);
  p.n_values = static_cast<std::uint8_t>(n_values);
  for (int i = 0; i < n_values; ++i) p.values[i] = d.values[i];
  const std::int64_t t = port_.now_ns();
  p.timestamp_us = us_since_origin(t);
  p.latency_us = clamp_u32((t - acquired_ns) / 1000);
  ++decisions_made_;
  if (!port_.host_connected()) {  // nobody to tell: like the samples, it is dropped
    drop_decision(p);
    return;
  }
  // Decisions go out in the order they were made: behind the ones still waiting, if any. A
  // decision that finds the waiting queue full is dropped (the older ones keep their places).
  if (pending_count_ == kPendingDecisions) flush_pending();
  if (pending_count_ == kPendingDecisions) {
    drop_decision(p);
    return;
  }
  pending_[(pending_head_ + pending_count_) % kPendingDecisions] = p;
  ++pending_count_;
  flush_pending();
}

/// Queues the decisions waiting for room, oldest first, with no reserve: a decision may take
/// the last byte of the port's output. True when none is left waiting. Without a host they
/// are dropped.
bool Controller::flush_pending() {
  while (pending_count_ > 0) {
    const proto::DecisionPayload& p = pending_[pending_head_];
    if (!port_.host_connected()) {
      drop_decision(p);
    } else {
      proto::Frame f;
      f.type = proto::FrameType::decision;
      f.decision = p;
      if (!queue(f)) return false;
      ++decisions_sent_;
      port_.on_decision_sent(p.latency_us);
    }
    pending_head_ = (pending_head_ + 1) % kPendingDecisions;
    --pending_count_;
  }
  return true;
}

void Controller::drop_decision(const proto::DecisionPayload& p) {
  ++decisions_dropped_;
  port_.on_decision_dropped(p);
}

void Controller::send_data(std::int64_t acquired_ns) {
  proto::Frame f;
  f.type = proto::FrameType::data;
  f.data.first_sample = frame_first_;
  f.data.timestamp_us = us_since_origin(acquired_ns);
  f.data.rows = cfg_.rows;
  f.data.cols = cfg_.cols;
  f.data.n_samples = static_cast<std::uint16_t>(frame_fill_);
  f.data.samples = cfg_.frame_samples;
  f.flags = static_cast<std::uint8_t>((dropped_since_data_ ? proto::flags::kOverrun : 0) |
                                      (loop_flag_ ? proto::flags::kLoop : 0));
  const std::size_t n = frame_fill_;
  frame_fill_ = 0;
  // a decision still waiting for room goes first: no DATA frame overtakes it
  const bool room = pending_count_ == 0 || flush_pending();
  if (room && queue(f, cfg_.control_reserve)) {
    samples_sent_ += n;
    dropped_since_data_ = false;
    loop_flag_ = false;
    dropping_ = false;
  } else {
    const bool host = port_.host_connected();
    dropped_samples_ += n;
    dropped_since_data_ = dropped_since_status_ = true;
    if (!dropping_ && host) ++overrun_events_;
    dropping_ = host;
  }
}

bool Controller::send_status() {
  flush_pending();  // a STATUS follows the decisions it counts as sent when it can
  proto::Frame f;
  f.type = proto::FrameType::status;
  auto& s = f.status;
  const std::int64_t t = port_.now_ns();
  s.uptime_us = us_since_origin(t);
  s.next_sample = next_sample_;
  s.samples_sent = samples_sent_;
  s.dropped_samples = dropped_samples_;
  s.overrun_events = overrun_events_;
  s.decisions_sent = static_cast<std::uint32_t>(decisions_sent_);
  s.decisions_dropped = static_cast<std::uint32_t>(decisions_dropped_);
  s.frames_dropped = static_cast<std::uint32_t>(frames_dropped_);
  port_.fill_status(s);
  s.state = finished_ ? proto::StreamState::finished
            : streaming_ ? proto::StreamState::streaming
                         : proto::StreamState::stopped;
  s.host_connected = port_.host_connected() ? 1 : 0;
  s.connections = static_cast<std::uint16_t>(connections_ < 65535 ? connections_ : 65535);
  f.flags = dropped_since_status_ ? proto::flags::kOverrun : 0;
  last_status_ns_ = t;
  if (!queue_control(f)) return false;
  dropped_since_status_ = false;
  return true;
}

void Controller::shutdown() {
  flush_pending();
  while (pending_count_ > 0) {
    drop_decision(pending_[pending_head_]);
    pending_head_ = (pending_head_ + 1) % kPendingDecisions;
    --pending_count_;
  }
  send_status();
}

void Controller::poll() {
  if (pending_count_ > 0) flush_pending();
  if (cfg_.status_period_ns > 0 && port_.now_ns() - last_status_ns_ >= cfg_.status_period_ns)
    send_status();
}

void Controller::on_command(const proto::Frame& f) {
  switch (f.type) {
    case proto::FrameType::start:
      if (!streaming_ || finished_) start_stream(true);
      else announce();
      break;
    case proto::FrameType::stop:
      streaming_ = false;
      send_status();
      break;
    case proto::FrameType::ping: {
      proto::Frame r;
      r.type = proto::FrameType::pong;
      r.ping.token = f.ping.token;
      r.ping.timestamp_us = us_since_origin(port_.now_ns());
      queue_control(r);
      break;
    }
    case proto::FrameType::info_request:
      send_info();
      break;
    default:
      ++unexpected_frames_;  // a controller -> host frame sent to us
  }
}

}  // namespace eskin
