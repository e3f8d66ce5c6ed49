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
  queue(f);
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
  proto::Frame f;
  f.type = proto::FrameType::decision;
  auto& p = f.decision;
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
  // DATA leaves room for control frames, so a decision is queued even while samples drop.
  if (!queue(f)) return;
  ++decisions_sent_;
  port_.on_decision_sent(p.latency_us);
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
  if (queue(f, cfg_.control_reserve)) {
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

void Controller::send_status() {
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
  port_.fill_status(s);
  s.state = finished_ ? proto::StreamState::finished
            : streaming_ ? proto::StreamState::streaming
                         : proto::StreamState::stopped;
  s.host_connected = port_.host_connected() ? 1 : 0;
  s.connections = static_cast<std::uint16_t>(connections_ < 65535 ? connections_ : 65535);
  f.flags = dropped_since_status_ ? proto::flags::kOverrun : 0;
  if (queue(f)) dropped_since_status_ = false;
  last_status_ns_ = t;
}

void Controller::poll() {
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
      queue(r);
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
