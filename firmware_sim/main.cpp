// eskin-fw-sim: the skin controller, simulated. It publishes a pseudo-terminal and streams a
// replay of recorded (or simulated) taxel signals over it in the eskin wire protocol, at the
// real sample rate, optionally classifying touches on board. See `eskin-fw-sim --help`.
#include <sched.h>
#include <signal.h>
#include <time.h>

#include <cerrno>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <exception>
#include <memory>
#include <new>
#include <stdexcept>
#include <string>
#include <vector>

#include "eskin/controller.hpp"
#include "eskin/protocol.hpp"
#include "eskin/version.hpp"
#include "pty_link.hpp"
#include "replay_source.hpp"

#if __has_include("eskin/model.hpp")
#include "eskin/model.hpp"
#define ESKIN_FWSIM_HAS_MODEL 1
#else
#define ESKIN_FWSIM_HAS_MODEL 0
#endif

namespace eskin::fwsim {
namespace {

namespace proto = eskin::protocol;

volatile sig_atomic_t g_stop = 0;
bool realtime_granted = false;
void on_signal(int) { g_stop = 1; }

std::int64_t now_ns() {
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return static_cast<std::int64_t>(ts.tv_sec) * 1000000000LL + ts.tv_nsec;
}

void sleep_until(std::int64_t deadline_ns) {
  timespec ts{};
  ts.tv_sec = deadline_ns / 1000000000LL;
  ts.tv_nsec = deadline_ns % 1000000000LL;
  while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, nullptr) == EINTR && !g_stop) {
  }
}

const char* kUsage = R"(usage: eskin-fw-sim INPUT [options]

Simulates the e-skin controller: creates a pseudo-terminal (raw mode), prints
"PTY <slave path>" as the first line of stdout, and streams INPUT over it in the eskin wire
protocol (docs/wire-protocol.md) at the real sample rate.

INPUT: an eskin replay file (.eskr, written by `eskin replay CAMPAIGN -o FILE.eskr`, or from
Python by eskin.data.replay.write_replay_file) or a .npy little-endian int16 array
(n_samples, rows, cols) / (n_samples, taxels) with --grid.

options:
  --link PATH          also publish the port as a symlink PATH (replaced if it is a symlink)
  --speed X            replay speed (1 = real time, 0 = unpaced: as fast as the host reads,
                       waiting while no host has the port open)
  --rate HZ            sample rate (default: the file's, else 3000)
  --samples-per-frame N  samples per DATA frame (default 10)
  --tick N             wake up every N samples (default: 1 with --model, else samples-per-frame)
  --loop               repeat the replay forever
  --hold S             keep the port open S seconds after the replay (default 0)
  --wait-start         stream only after the host sends START (default: stream at once)
  --status-ms MS       STATUS period in wall-clock ms (default 250)
  --tx-buffer BYTES    transmit queue size (default 16384); when full, samples are dropped
                       and decisions wait (at most 4), every loss counted in STATUS
  --model MODEL        run the streaming classifier (.eskin model file) and send DECISION frames
  --grid RxC           grid of a 2-d .npy input (default 4x4)
  --drop-rate P        fault injection: drop each byte with probability P
  --flip-rate P        fault injection: flip one bit of each byte with probability P
  --burst P            fault injection: precede each frame by random garbage with probability P
  --burst-len N        longest garbage burst (default 32)
  --truncate-rate P    fault injection: cut each frame short with probability P
  --seed N             fault-injection seed (default 1)
  --realtime           ask for SCHED_FIFO scheduling (steadier pacing on a busy machine; the
                       simulator sleeps between samples and while it waits for a host or for
                       START, so it does not hog a core)
  --quiet              no progress on stderr
  --version            print the version and exit

On exit it prints "STATS {json}" on stdout (pacing, drops, decisions, latencies).
)";

struct Options {
  std::string input;
  std::string link;
  std::string model;
  double speed = 1.0;
  double rate = 0.0;
  int samples_per_frame = 10;
  int tick = 0;
  bool loop = false;
  double hold_s = 0.0;
  bool wait_start = false;
  int status_ms = 250;
  std::size_t tx_buffer = 16384;
  int grid_rows = 4, grid_cols = 4;
  FaultConfig faults;
  bool quiet = false;
  bool realtime = false;
};

// A bad input or model file (not a usage mistake): one line, exit status 2.
[[noreturn]] void input_error(const std::string& msg) {
  std::fprintf(stderr, "eskin-fw-sim: %s\n", msg.c_str());
  std::exit(2);
}

[[noreturn]] void usage_error(const std::string& msg) {
  std::fprintf(stderr, "eskin-fw-sim: %s\n(see eskin-fw-sim --help)\n", msg.c_str());
  std::exit(2);
}

double parse_double(const std::string& opt, const char* v, double lo, double hi) {
  char* end = nullptr;
  const double x = std::strtod(v, &end);
  if (end == v || *end != '\0' || !std::isfinite(x) || x < lo || x > hi)
    usage_error(opt + " " + v + ": expected a number in [" + std::to_string(lo) + ", " +
                std::to_string(hi) + "]");
  return x;
}

Options parse(int argc, char** argv) {
  Options o;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto val = [&]() -> const char* {
      if (i + 1 >= argc) usage_error(a + " needs a value");
      return argv[++i];
    };
    if (a == "-h" || a == "--help") {
      std::fputs(kUsage, stdout);
      std::exit(0);
    } else if (a == "--version") {
      std::printf("eskin-fw-sim %s\n", eskin::kVersion);
      std::exit(0);
    } else if (a == "--link") o.link = val();
    else if (a == "--model") o.model = val();
    else if (a == "--speed") o.speed = parse_double(a, val(), 0.0, 1e6);
    else if (a == "--rate") o.rate = parse_double(a, val(), 1.0, 1e7);
    else if (a == "--samples-per-frame") o.samples_per_frame = static_cast<int>(parse_double(a, val(), 1, 65535));
    else if (a == "--tick") o.tick = static_cast<int>(parse_double(a, val(), 1, 65535));
    else if (a == "--loop") o.loop = true;
    else if (a == "--hold") o.hold_s = parse_double(a, val(), 0.0, 1e7);
    else if (a == "--wait-start") o.wait_start = true;
    else if (a == "--status-ms") o.status_ms = static_cast<int>(parse_double(a, val(), 1, 1e7));
    else if (a == "--tx-buffer") o.tx_buffer = static_cast<std::size_t>(parse_double(a, val(), 1024, 1 << 28));
    else if (a == "--grid") {
      const std::string g = val();
      if (std::sscanf(g.c_str(), "%dx%d", &o.grid_rows, &o.grid_cols) != 2 || o.grid_rows < 1 ||
          o.grid_cols < 1 || o.grid_rows > 255 || o.grid_cols > 255)
        usage_error("--grid " + g + ": expected RxC, e.g. 4x4");
    } else if (a == "--drop-rate") o.faults.drop_rate = parse_double(a, val(), 0.0, 1.0);
    else if (a == "--flip-rate") o.faults.flip_rate = parse_double(a, val(), 0.0, 1.0);
    else if (a == "--burst") o.faults.burst_rate = parse_double(a, val(), 0.0, 1.0);
    else if (a == "--burst-len") o.faults.burst_len = static_cast<int>(parse_double(a, val(), 1, 4096));
    else if (a == "--truncate-rate") o.faults.truncate_rate = parse_double(a, val(), 0.0, 1.0);
    else if (a == "--seed") o.faults.seed = static_cast<std::uint64_t>(parse_double(a, val(), 0, 9e15));
    else if (a == "--quiet") o.quiet = true;
    else if (a == "--realtime") o.realtime = true;
    else if (!a.empty() && a[0] == '-') usage_error("unknown option " + a);
    else if (o.input.empty()) o.input = a;
    else usage_error("more than one INPUT: " + o.input + " and " + a);
  }
  if (o.input.empty()) usage_error("missing INPUT (a .eskr replay file or a .npy array)");
  return o;
}

/// Wake-up lateness histogram: 1 us bins up to 50 ms, exact maximum.
class PacingStats {
 public:
  void add(std::int64_t late_ns) {
    if (late_ns < 0) late_ns = 0;
    const std::size_t bin = static_cast<std::size_t>(late_ns / 1000);
    ++bins_[std::min(bin, bins_.size() - 1)];
    max_ = std::max(max_, late_ns);
    ++n_;
  }
  std::int64_t percentile_ns(double q) const {
    if (n_ == 0) return 0;
    const auto target = static_cast<std::uint64_t>(std::ceil(q * static_cast<double>(n_)));
    std::uint64_t acc = 0;
    for (std::size_t i = 0; i < bins_.size(); ++i) {
      acc += bins_[i];
      if (acc >= std::max<std::uint64_t>(target, 1)) return static_cast<std::int64_t>(i) * 1000 + 500;
    }
    return max_;
  }
  std::int64_t max_ns() const { return max_; }
  std::uint64_t count() const { return n_; }

 private:
  std::array<std::uint64_t, 50001> bins_{};
  std::int64_t max_ = 0;
  std::uint64_t n_ = 0;
};

/// Queue bytes DATA frames leave free for control frames (DECISION, STATUS, INFO, PONG).
constexpr std::size_t kControlReserve = 1024;
// INFO's class-name field: the bytes the simulator announces at most
constexpr std::size_t kMaxNamesBytes = 2048;

// The class names a controller would announce, checked before it starts: names that INFO cannot
// carry as they are end the run with one line naming where they come from (exit status 2).
void check_class_names(const std::vector<std::string>& names, const std::string& where) {
  std::vector<char> buf(kMaxNamesBytes);
  if (proto::pack_class_names(names.data(), names.size(), buf.data(), buf.size()) < 0) {
    input_error(where + ": its " + std::to_string(names.size()) +
                " class names do not fit one INFO frame (" + std::to_string(kMaxNamesBytes) +
                " bytes, at most 255 names, none holding a newline)");
  }
}

std::uint32_t clamp_u32(std::int64_t v) {
  return static_cast<std::uint32_t>(std::clamp<std::int64_t>(v, 0, 0xFFFFFFFFLL));
}

/// The simulator: paces the replay against absolute deadlines and services the pty; the
/// controller's protocol and stream logic is eskin::Controller (eskin/controller.hpp), the
/// same code the firmware runs, to which this class is the port.
class Simulator final : public ControllerPort {
 public:
  Simulator(const Options& o, ReplaySource& src, PtyLink& link)
      : o_(o), src_(src), link_(link), taxels_(src.taxels()) {
    rate_ = o.rate > 0 ? o.rate : (src.sample_rate_hz() > 0 ? src.sample_rate_hz() : 3000.0);
    const std::size_t max_spf = proto::max_samples_per_frame(taxels_);
    spf_ = std::min<std::size_t>(static_cast<std::size_t>(o.samples_per_frame), max_spf);
    tick_ = o.tick > 0 ? static_cast<std::size_t>(o.tick) : (o.model.empty() ? spf_ : 1);
    class_names_ = src.class_names();
    frame_samples_.resize(spf_ * taxels_);
  }

#if ESKIN_FWSIM_HAS_MODEL
  void set_model(const Model* model) {
    stream_ = std::make_unique<StreamClassifier>(*model);
    class_names_ = model->class_names();
  }
#endif

  int run() {
    origin_ = steady_ns();
    anchor_ns_ = origin_;
    make_controller();
    std::printf("PTY %s\nORIGIN_NS %lld\n", link_.slave_path().c_str(),
                static_cast<long long>(origin_));
    std::fflush(stdout);
    if (!o_.quiet)
      std::fprintf(stderr, "eskin-fw-sim: %s, %llu samples of %dx%d taxels at %.0f Hz x %g%s\n",
                   link_.slave_path().c_str(), static_cast<unsigned long long>(src_.n_samples()),
                   src_.rows(), src_.cols(), rate_, o_.speed, o_.speed == 0 ? " (unpaced)" : "");
    service();
    if (!o_.wait_start) ctl_->start();
    std::int64_t finished_at = 0;
    while (!g_stop) {
      // Unpaced (--speed 0), the replay runs as fast as the host reads: with no host, it waits.
      if (ctl_->streaming() && !ctl_->finished() && (o_.speed > 0 || link_.host_connected())) {
        step();
        if (ctl_->finished()) {
          finished_at = steady_ns();
          link_.flush_tx();
        }
      } else {
        link_.wait_io(5, link_.queued() > 0);
        service();
        if (ctl_->finished() &&
            steady_ns() - finished_at >= static_cast<std::int64_t>(o_.hold_s * 1e9))
          break;
      }
    }
    // last words: what is queued goes out first (a bounded wait), then the decisions still
    // waiting for room, the rest of them counted as dropped, and a final STATUS; then a bounded
    // wait for the host to take it all
    std::int64_t give_up = steady_ns() + 1000000000LL;
    while (link_.queued() > 0 && link_.host_connected() && steady_ns() < give_up) {
      if (!link_.flush_tx()) break;
      link_.wait_io(5, true);
      bool rc, dc;
      link_.update_host(rc, dc);
    }
    ctl_->shutdown();
    give_up = steady_ns() + 1000000000LL;
    while (link_.queued() > 0 && link_.host_connected() && steady_ns() < give_up) {
      if (!link_.flush_tx()) break;
      link_.wait_io(5, true);
      bool rc, dc;
      link_.update_host(rc, dc);
    }
    if (link_.host_connected()) link_.drain(2000);
    print_stats();
    return 0;
  }

  // ---- ControllerPort
  bool host_connected() const override { return link_.host_connected(); }

  /// Queues a frame if it fits. Unpaced (--speed 0), it waits for room while the host is
  /// connected: the replay then runs as fast as the host reads. Paced, it never waits: the
  /// controller drops and counts.
  bool send(proto::Frame& f, std::size_t reserve) override {
    bool ok = link_.send(f, reserve);
    while (!ok && o_.speed == 0 && link_.host_connected() && !g_stop) {
      if (!link_.flush_tx()) break;
      link_.wait_writable(20);  // host commands wait until after (no re-entrant queueing)
      bool rc, dc;
      link_.update_host(rc, dc);
      ok = link_.send(f, reserve);
    }
    link_.flush_tx();
    return ok;
  }
  void send_delimiter() override { link_.send_delimiter(); }
  std::int64_t now_ns() const override { return steady_ns() - origin_; }
  void fill_status(proto::StatusPayload& s) const override {
    s.rx_errors = link_.rx_errors();
    s.faults_injected = clamp_u32(static_cast<std::int64_t>(link_.faults_injected()));
    s.pacing_p50_ns = clamp_u32(pacing_.percentile_ns(0.5));
    s.pacing_p99_ns = clamp_u32(pacing_.percentile_ns(0.99));
    s.pacing_max_ns = clamp_u32(pacing_.max_ns());
  }
  void on_stream_start(bool again) override {
    if (again) pos_ = 0;
    anchor_ns_ = steady_ns();
    anchor_sample_ = ctl_->next_sample();
  }
  void on_decision_sent(std::uint32_t latency_us) override { latencies_us_.push_back(latency_us); }
  void on_decision_dropped(const proto::DecisionPayload& d) override {
    if (o_.quiet) return;
    std::fprintf(stderr,
                 "eskin-fw-sim: decision on touch [%llu, %llu) dropped (%s); %llu dropped so far\n",
                 static_cast<unsigned long long>(d.onset_sample),
                 static_cast<unsigned long long>(d.offset_sample),
                 link_.host_connected() ? "the output is full" : "no host",
                 static_cast<unsigned long long>(ctl_->decisions_dropped()));
  }

 private:
  static std::int64_t steady_ns() { return eskin::fwsim::now_ns(); }

  void make_controller() {
    names_joined_.assign(kMaxNamesBytes, '\0');
    const std::ptrdiff_t len = eskin::protocol::pack_class_names(
        class_names_.data(), class_names_.size(), names_joined_.data(), names_joined_.size());
    if (len < 0) {
      throw std::runtime_error(
          std::to_string(class_names_.size()) + " class names do not fit one INFO frame (" +
          std::to_string(kMaxNamesBytes) + " bytes, at most 255 names, none holding a newline)");
    }
    names_joined_.resize(static_cast<std::size_t>(len));
    const std::size_t n = class_names_.size();
    ControllerConfig cfg;
    cfg.rows = static_cast<std::uint8_t>(src_.rows());
    cfg.cols = static_cast<std::uint8_t>(src_.cols());
    cfg.samples_per_frame = static_cast<std::uint16_t>(spf_);
    cfg.frame_samples = frame_samples_.data();
    cfg.sample_rate_hz = rate_;
    cfg.volts_per_count = src_.volts_per_count();
    cfg.speed = o_.speed;
    cfg.class_names = names_joined_.data();
    cfg.names_len = static_cast<std::uint16_t>(names_joined_.size());
    cfg.n_classes = static_cast<std::uint8_t>(n);
    cfg.status_period_ns = static_cast<std::int64_t>(o_.status_ms) * 1000000LL;
    cfg.control_reserve = kControlReserve;
#if ESKIN_FWSIM_HAS_MODEL
    ctl_ = std::make_unique<Controller>(cfg, *this, stream_.get());
#else
    ctl_ = std::make_unique<Controller>(cfg, *this, nullptr);
#endif
  }

  /// Acquisition deadline of the sample that ends at stream index `end` (exclusive).
  std::int64_t deadline_for(std::uint64_t end) const {
    return anchor_ns_ +
           static_cast<std::int64_t>(static_cast<double>(end - anchor_sample_) * 1e9 /
                                     (rate_ * o_.speed));
  }

  void step() {
    const std::uint64_t left = src_.n_samples() - pos_;
    const std::size_t n = static_cast<std::size_t>(std::min<std::uint64_t>(tick_, left));
    std::int64_t acquired = 0;
    if (o_.speed > 0) {
      const std::int64_t deadline = deadline_for(ctl_->next_sample() + n);
      sleep_until(deadline);
      const std::int64_t t = steady_ns();
      pacing_.add(t - deadline);
      acquired = deadline;
    } else {
      acquired = steady_ns();
    }
    // with tick > 1, sample k of this batch was acquired (n - 1 - k) periods before the last
    const double period_ns = o_.speed > 0 ? 1e9 / (rate_ * o_.speed) : 0.0;
    for (std::size_t k = 0; k < n; ++k) {
      const std::int64_t at =
          acquired - static_cast<std::int64_t>(static_cast<double>(n - 1 - k) * period_ns);
      ctl_->push(src_.sample(pos_), at - origin_);
      ++pos_;
    }
    if (pos_ == src_.n_samples()) {
      ctl_->end_of_replay(acquired - origin_, o_.loop);
      if (o_.loop) pos_ = 0;
    }
    service();
  }

  /// Host presence, host commands, periodic STATUS, and writing out the queue.
  void service() {
    bool reconnected = false, disconnected = false;
    link_.update_host(reconnected, disconnected);
    if (disconnected && !o_.quiet) std::fprintf(stderr, "eskin-fw-sim: host closed the port\n");
    if (reconnected) {
      if (!o_.quiet) std::fprintf(stderr, "eskin-fw-sim: host connected\n");
      ctl_->host_connected();
    }
    if (link_.host_connected())
      link_.poll_commands([this](const proto::Frame& f) { ctl_->on_command(f); });
    ctl_->poll();
    if (!link_.flush_tx()) {
      bool rc, dc;
      link_.update_host(rc, dc);
    }
  }

  void print_stats() {
    std::vector<std::uint32_t> lat = latencies_us_;
    std::sort(lat.begin(), lat.end());
    auto pct = [&](double q) -> double {
      if (lat.empty()) return 0.0;
      const std::size_t i = std::min(lat.size() - 1, static_cast<std::size_t>(q * (lat.size() - 1) + 0.5));
      return lat[i];
    };
    const Controller& c = *ctl_;
    std::printf(
        "STATS {\"samples_produced\": %llu, \"samples_sent\": %llu, \"dropped_samples\": %llu, "
        "\"overrun_events\": %u, \"faults_injected\": %llu, \"bytes_written\": %llu, "
        "\"rx_errors\": %u, \"connections\": %u, \"pacing_wakeups\": %llu, \"pacing_p50_ns\": %lld, "
        "\"pacing_p99_ns\": %lld, \"pacing_max_ns\": %lld, \"decisions_made\": %llu, "
        "\"decisions_sent\": %llu, \"decisions_dropped\": %llu, \"frames_dropped\": %llu, "
        "\"classify_errors\": %llu, \"latency_p50_us\": %.0f, "
        "\"latency_p99_us\": %.0f, \"latency_max_us\": %.0f, \"elapsed_s\": %.6f, "
        "\"origin_ns\": %lld, \"realtime\": %s}\n",
        static_cast<unsigned long long>(c.next_sample()),
        static_cast<unsigned long long>(c.samples_sent()),
        static_cast<unsigned long long>(c.dropped_samples()), c.overrun_events(),
        static_cast<unsigned long long>(link_.faults_injected()),
        static_cast<unsigned long long>(link_.bytes_written()), link_.rx_errors(), c.connections(),
        static_cast<unsigned long long>(pacing_.count()),
        static_cast<long long>(pacing_.percentile_ns(0.5)),
        static_cast<long long>(pacing_.percentile_ns(0.99)), static_cast<long long>(pacing_.max_ns()),
        static_cast<unsigned long long>(c.decisions_made()),
        static_cast<unsigned long long>(c.decisions_sent()),
        static_cast<unsigned long long>(c.decisions_dropped()),
        static_cast<unsigned long long>(c.frames_dropped()),
        static_cast<unsigned long long>(c.classify_errors()), pct(0.5), pct(0.99),
        lat.empty() ? 0.0 : static_cast<double>(lat.back()),
        static_cast<double>(steady_ns() - origin_) * 1e-9, static_cast<long long>(origin_),
        realtime_granted ? "true" : "false");
    std::fflush(stdout);
  }

  const Options& o_;
  ReplaySource& src_;
  PtyLink& link_;
  std::size_t taxels_;
  double rate_ = 3000.0;
  std::size_t spf_ = 10;
  std::size_t tick_ = 10;
  std::vector<std::string> class_names_;
  std::string names_joined_;
  std::vector<std::int16_t> frame_samples_;
  std::uint64_t pos_ = 0;
  std::int64_t origin_ = 0;
  std::int64_t anchor_ns_ = 0;
  std::uint64_t anchor_sample_ = 0;
  std::vector<std::uint32_t> latencies_us_;
  PacingStats pacing_;
#if ESKIN_FWSIM_HAS_MODEL
  std::unique_ptr<StreamClassifier> stream_;
#endif
  std::unique_ptr<Controller> ctl_;
};

int main_impl(int argc, char** argv) {
  const Options o = parse(argc, argv);
  ReplaySource src;
  std::string error;
  if (!src.open(o.input, o.grid_rows, o.grid_cols, error)) input_error(error);

#if ESKIN_FWSIM_HAS_MODEL
  std::unique_ptr<Model> model;
  if (!o.model.empty()) {
    try {
      model = std::make_unique<Model>(Model::load(o.model));
    } catch (const std::exception& e) {
      input_error(std::string("--model: ") + e.what());
    }
    if (model->rows() != src.rows() || model->cols() != src.cols())
      usage_error("--model " + o.model + " expects a " + std::to_string(model->rows()) + "x" +
                  std::to_string(model->cols()) + " grid, the input has " +
                  std::to_string(src.rows()) + "x" + std::to_string(src.cols()));
  }
  // the names INFO announces: the model's, else the input's
  if (model)
    check_class_names(model->class_names(), "--model " + o.model);
  else
    check_class_names(src.class_names(), o.input);
#else
  if (!o.model.empty())
    usage_error("--model: this build has no on-board classifier (eskin/model.hpp)");
  check_class_names(src.class_names(), o.input);
#endif

  PtyLink link(o.tx_buffer, o.faults);
  if (!link.open(o.link, error)) {
    std::fprintf(stderr, "eskin-fw-sim: %s\n", error.c_str());
    return 1;
  }
  struct sigaction sa {};
  sa.sa_handler = on_signal;
  sigemptyset(&sa.sa_mask);
  sigaction(SIGINT, &sa, nullptr);
  sigaction(SIGTERM, &sa, nullptr);
  sigaction(SIGHUP, &sa, nullptr);
  signal(SIGPIPE, SIG_IGN);
  if (o.realtime) {
    sched_param sp{};
    sp.sched_priority = 10;
    realtime_granted = sched_setscheduler(0, SCHED_FIFO, &sp) == 0;
    if (!realtime_granted && !o.quiet)
      std::fprintf(stderr, "eskin-fw-sim: --realtime: SCHED_FIFO refused (%s); normal scheduling\n",
                   std::strerror(errno));
  }

  auto sim = std::make_unique<Simulator>(o, src, link);
#if ESKIN_FWSIM_HAS_MODEL
  if (model) sim->set_model(model.get());
#endif
  return sim->run();
}

}  // namespace
}  // namespace eskin::fwsim

// Whatever escapes (an allocation that fails, an unexpected error) ends in one line on stderr
// and exit status 1, never in an abort.
int main(int argc, char** argv) {
  try {
    return eskin::fwsim::main_impl(argc, argv);
  } catch (const std::bad_alloc&) {
    std::fprintf(stderr, "eskin-fw-sim: out of memory\n");
  } catch (const std::exception& e) {
    std::fprintf(stderr, "eskin-fw-sim: %s\n", e.what());
  }
  return 1;
}
