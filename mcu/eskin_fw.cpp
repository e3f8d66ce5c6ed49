// The eskin controller firmware (bare metal, Cortex-M4F, QEMU mps2-an386; docs/mcu.md, "The
// controller on the wire").
//
// The controller of docs/wire-protocol.md on UART0: eskin::Controller (the code eskin-fw-sim
// runs) with this file's port. A timer interrupt takes the samples at the sample rate into a
// ring (sampler.hpp); the main loop drains the ring into the controller, which frames DATA,
// classifies each sample with the StreamClassifier and sends a DECISION when a touch ends; the
// UART's interrupts move the bytes (cmsdk_uart.hpp). A decision that takes longer than a
// sample period delays the main loop, not the sampling: the samples wait in the ring.
//
// What QEMU loads before reset, next to this image (tools/mcu_link.py):
//  * the model, in a flash slot at kModelSlot: u32 magic "ESKM", u32 size, u32 flags (bit 0:
//    profile, see board_irq.hpp), u32 reserved, then the .eskin bytes (read in place, as
//    `make mcu`'s program does with its compiled-in model);
//  * the recording, an eskin replay file (.eskr), at kReplayAddress in the board's PSRAM: the
//    stand-in for the ADC.
// The controller waits for the host's first START (eskin listen sends START and INFO_REQUEST
// when it opens the port): QEMU's pty discards what the board sends while no host has it open,
// and notices a host only by polling it.
//
// The semihosting console (QEMU's stdout) gets start-up errors and, at the end of the
// recording, one line of measurements ("FW: ...").
#include <cinttypes>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <unistd.h>

#include "board_irq.hpp"
#include "cmsdk_uart.hpp"
#include "eskin/controller.hpp"
#include "eskin/model.hpp"
#include "eskin/protocol.hpp"
#include "eskin/replay_format.hpp"
#include "mcu_board.h"
#include "sampler.hpp"

extern "C" {
// startup.c's handlers, reused in the firmware's vector table
void Reset_Handler(void);
void NMI_Handler(void);
void HardFault_Handler(void);
void MemManage_Handler(void);
void BusFault_Handler(void);
void UsageFault_Handler(void);
void SysTick_Handler(void);
void mcu_uart0_rx_irq(void);
void mcu_uart0_tx_irq(void);
void mcu_timer0_irq(void);
extern std::uint32_t _estack[], _sidata[], _sdata[], _edata[];
extern char end;  // linker script: the heap starts here
void* __real_malloc(std::size_t n);
// Construction is the only time the firmware allocates; a request the heap cannot meet is
// said on the console before the caller gives up.
void* __wrap_malloc(std::size_t n) {
  void* p = __real_malloc(n);
  if (p == nullptr) {
    std::printf("eskin-fw: out of heap: %u bytes asked for, %u in use\n",
                static_cast<unsigned>(n),
                static_cast<unsigned>(static_cast<char*>(sbrk(0)) - &end));
  }
  return p;
}
}

namespace eskin::detail {
// Builds without exceptions report construction errors here (cpp/src/raise.hpp).
[[noreturn]] void fatal_error(const char* what) noexcept {
  std::printf("eskin-fw: %s\n", what);
  std::exit(2);
}
}  // namespace eskin::detail

namespace eskin::mcu {

bool g_profile = false;

namespace {

namespace proto = eskin::protocol;

constexpr std::uintptr_t kModelSlot = 0x00040000u;   // 256 KB into the 1 MB of flash
constexpr std::uintptr_t kFlashEnd = 0x00100000u;
constexpr std::uint32_t kModelMagic = 0x4D4B5345u;   // "ESKM"
constexpr std::uintptr_t kReplayAddress = 0x21000000u;  // PSRAM
constexpr std::size_t kReplaySize = 16u << 20;            // the 16 MB of PSRAM
constexpr std::uint64_t kNsPerTick = 40;             // SysTick at the 25 MHz processor clock
constexpr std::uint16_t kSamplesPerFrame = 10;

// Frames this controller sends: DATA of 10 samples of 16 taxels (348 bytes), INFO with class
// names, DECISION with 16 values (176), STATUS (72). It receives only host commands (<= 20).
constexpr std::size_t kMaxTxFrame = 512;
constexpr std::size_t kMaxRxFrame = 32;
constexpr std::size_t kMaxNames = kMaxTxFrame - proto::kHeaderSize - proto::kCrcSize -
                                  proto::kInfoFixedSize;

typedef void (*vector_t)(void);
constexpr int kVectors = 16 + 16;
__attribute__((aligned(128))) const vector_t g_vectors[kVectors] = {
    reinterpret_cast<vector_t>(_estack), Reset_Handler, NMI_Handler, HardFault_Handler,
    MemManage_Handler, BusFault_Handler, UsageFault_Handler, nullptr, nullptr, nullptr, nullptr,
    nullptr /* SVCall */, nullptr /* DebugMon */, nullptr, nullptr /* PendSV */, SysTick_Handler,
    // the board's lines (mps2-an386): 0 UART0 RX, 1 UART0 TX, 8 TIMER0
    mcu_uart0_rx_irq, mcu_uart0_tx_irq, nullptr, nullptr, nullptr, nullptr, nullptr, nullptr,
    mcu_timer0_irq, nullptr, nullptr, nullptr, nullptr, nullptr, nullptr, nullptr};

[[noreturn]] void fail(const char* what) {
  std::printf("eskin-fw: %s\n", what);
  std::exit(2);
}

std::uint32_t le32(const std::uint8_t* p) {
  return static_cast<std::uint32_t>(p[0]) | (static_cast<std::uint32_t>(p[1]) << 8) |
         (static_cast<std::uint32_t>(p[2]) << 16) | (static_cast<std::uint32_t>(p[3]) << 24);
}
/// The replay file QEMU loaded (docs/wire-protocol.md, "Replay file"), checked by the core's
/// reader of the format (eskin/replay_format.hpp: the rules of every reader) against the PSRAM
/// that holds it: a bad file is refused with one line on the console, never streamed.
struct Replay {
  SampleSource source;
  int rows = 0, cols = 0;
  double rate_hz = 0.0, volts_per_count = 0.0;
};

Replay read_replay() {
  const auto* p = reinterpret_cast<const std::uint8_t*>(kReplayAddress);
  if (std::memcmp(p, "ESKREPLY", 8) != 0)
    fail("no replay file (.eskr) at 0x21000000: load one with -device loader");
  replay::ReplayHeader h;
  replay::ReplayError e;
  if (replay::check_replay(p, kReplaySize, replay::SizeRule::at_most, &h, &e) !=
      replay::ReplayStatus::ok) {
    char line[200];
    std::printf("eskin-fw: the replay at 0x21000000 is refused: %s\n",
                replay::format_error(e, line, sizeof line));
    std::exit(2);
  }
  Replay r;
  r.source.n_samples = h.n_samples;
  r.rows = h.rows;
  r.cols = h.cols;
  r.rate_hz = h.sample_rate_hz;
  r.volts_per_count = h.volts_per_count;
  r.source.taxels = static_cast<std::size_t>(r.rows) * static_cast<std::size_t>(r.cols);
  if (r.source.taxels > kMaxTaxels)
    fail("replay: the grid has more taxels than the firmware's ESKIN_FW_MAX_TAXELS");
  if (h.n_samples == 0) fail("replay: n_samples = 0: no samples to stream");
  r.source.samples = h.samples;
  return r;
}

/// The model in its flash slot; the image itself must end below the slot.
const std::uint8_t* model_slot(std::size_t* size) {
  const std::uintptr_t image_end = reinterpret_cast<std::uintptr_t>(_sidata) +
                                   (reinterpret_cast<std::uintptr_t>(_edata) -
                                    reinterpret_cast<std::uintptr_t>(_sdata));
  if (image_end > kModelSlot) fail("the image runs into the model slot at 0x40000");
  const auto* p = reinterpret_cast<const std::uint8_t*>(kModelSlot);
  if (le32(p) != kModelMagic) fail("no model in the flash slot at 0x40000 (magic ESKM)");
  *size = le32(p + 4);
  if (*size == 0 || *size > kFlashEnd - kModelSlot - 16) fail("model slot: size out of range");
  g_profile = (le32(p + 8) & 1u) != 0;
  return p + 16;
}

/// The controller's port on UART0: frames are encoded into the transmit ring whole or not at
/// all; the clock is SysTick.
class UartPort final : public ControllerPort {
 public:
  explicit UartPort(Uart& uart) : uart_(uart) {}
  bool host_connected() const override { return true; }  // a UART cannot tell
  bool send(proto::Frame& frame, std::size_t reserve) override {
    frame.seq = seq_;
    const std::size_t n = encoder_.encode(frame, out_, sizeof out_);
    if (n == 0) {
      ++encode_errors_;
      return false;
    }
    if (uart_.tx_free() < n + reserve || !uart_.write(out_, n)) return false;
    seq_ = static_cast<std::uint16_t>(seq_ + 1);
    return true;
  }
  void send_delimiter() override {
    const std::uint8_t d = proto::kDelimiter;
    uart_.write(&d, 1);
  }
  std::int64_t now_ns() const override { return static_cast<std::int64_t>(mcu_ticks() * kNsPerTick); }
  void fill_status(proto::StatusPayload& s) const override {
    const auto& st = rx_.stats();
    s.rx_errors = static_cast<std::uint32_t>(st.crc_errors + st.malformed + st.oversize) +
                  uart_.rx_overruns();
  }
  void on_stream_start(bool again) override { start_pending_ = true, rewind_ = rewind_ || again; }
  void on_decision_sent(std::uint32_t) override {}

  /// Host bytes received so far, through the command decoder.
  template <class Fn>
  void poll_commands(Fn&& fn) {
    std::uint8_t buf[32];
    for (;;) {
      const std::size_t n = uart_.read(buf, sizeof buf);
      if (n == 0) break;
      rx_.feed_all(buf, n, fn);
    }
  }
  /// A START was handled since the last call (and whether the recording starts over).
  bool take_start(bool* rewind) {
    const bool s = start_pending_;
    *rewind = rewind_;
    start_pending_ = rewind_ = false;
    return s;
  }
  std::uint32_t encode_errors() const { return encode_errors_; }

 private:
  Uart& uart_;
  proto::BasicFrameEncoder<kMaxTxFrame> encoder_;
  proto::BasicFrameDecoder<kMaxRxFrame> rx_{kMaxRxFrame, /*wait_for_delimiter=*/false};
  std::uint8_t out_[proto::max_encoded_size(kMaxTxFrame)];
  std::uint16_t seq_ = 0;
  bool start_pending_ = false;
  bool rewind_ = false;
  std::uint32_t encode_errors_ = 0;
};

std::int16_t g_frame[kSamplesPerFrame * kMaxTaxels];
char g_names[kMaxNames];

/// Measurements of the main loop (processor clock ticks).
struct LoopStats {
  std::uint64_t idle_ticks = 0;     // in WFI
  std::uint64_t start_ticks = 0;    // stream start
  std::uint64_t longest_push = 0;   // one sample through the controller (a decision's, at most)
  std::uint64_t pushes = 0;
};

}  // namespace

void install_vectors() {
  *reinterpret_cast<volatile std::uint32_t*>(0xE000ED08u) =
      static_cast<std::uint32_t>(reinterpret_cast<std::uintptr_t>(g_vectors));  // VTOR
  __asm volatile("dsb\n isb" ::: "memory");
}

int run() {
  install_vectors();
  // SysTick (the clock, startup.c) above the sampling timer: a clock read in the timer's
  // handler never misses a wrap-around
  *reinterpret_cast<volatile std::uint8_t*>(0xE000ED23u) = 0x00;  // SHPR3: SysTick
  std::size_t model_size = 0;
  const std::uint8_t* model_bytes = model_slot(&model_size);
  const Replay replay = read_replay();

  static eskin::Model model;
  eskin::ModelLoadError err;
  if (!eskin::Model::parse(model_bytes, model_size, &model, &err, /*in_place=*/true)) {
    std::printf("eskin-fw: the model is refused: %s\n", err.message.c_str());
    return 2;
  }
  if (model.rows() != replay.rows || model.cols() != replay.cols) {
    std::printf("eskin-fw: the model expects a %dx%d grid, the replay has %dx%d\n", model.rows(),
                model.cols(), replay.rows, replay.cols);
    return 2;
  }
  static eskin::StreamClassifier classifier(model);

  const auto& names = model.class_names();
  const std::ptrdiff_t names_len =
      proto::pack_class_names(names.data(), names.size(), g_names, kMaxNames);
  if (names_len < 0) {
    std::printf("eskin-fw: the model's %u class names do not fit one INFO frame (%u bytes, at "
                "most 255 names, none holding a newline)\n",
                static_cast<unsigned>(names.size()), static_cast<unsigned>(kMaxNames));
    return 2;
  }
  const std::size_t n_classes = names.size();

  Uart& uart = uart0();
  uart.init();
  Sampler& smp = sampler();
  smp.init(replay.source, replay.rate_hz);

  static UartPort port(uart);
  ControllerConfig cfg;
  cfg.rows = static_cast<std::uint8_t>(replay.rows);
  cfg.cols = static_cast<std::uint8_t>(replay.cols);
  cfg.samples_per_frame = kSamplesPerFrame;
  cfg.frame_samples = g_frame;
  cfg.sample_rate_hz = smp.timer_rate_hz();
  cfg.volts_per_count = replay.volts_per_count;
  cfg.speed = 1.0;
  cfg.class_names = g_names;
  cfg.names_len = static_cast<std::uint16_t>(names_len);
  cfg.n_classes = static_cast<std::uint8_t>(n_classes);
  cfg.status_period_ns = 250000000;
  cfg.control_reserve = 512;
  static Controller ctl(cfg, port, &classifier);

  const std::size_t heap = static_cast<std::size_t>(static_cast<char*>(sbrk(0)) - &end);
  std::printf("eskin-fw: model %d support vectors, %u bytes in the flash slot; replay %" PRIu32
              " samples of %dx%d at %.2f Hz; heap %u bytes; waiting for START on UART0\n",
              model.n_support(), static_cast<unsigned>(model_size),
              static_cast<std::uint32_t>(replay.source.n_samples), replay.rows, replay.cols,
              smp.timer_rate_hz(), static_cast<unsigned>(heap));

  // what one pair of clock reads costs (the handlers' own accounting, subtracted by the
  // measurement tool): 256 pairs
  std::uint64_t clock_pairs = 0;
  for (int i = 0; i < 256; ++i) {
    const std::uint64_t a = mcu_ticks();
    clock_pairs += mcu_ticks() - a;
  }

  LoopStats ls;
  bool reported = false;
  for (;;) {
    port.poll_commands([&](const proto::Frame& f) { ctl.on_command(f); });
    bool rewind = false;
    if (port.take_start(&rewind)) {
      if (rewind) reported = false;
      if (ls.start_ticks == 0) {  // the measurements cover the stream, not the wait for a host
        ls.start_ticks = mcu_ticks();
        ls.idle_ticks = 0;
      }
      smp.start(rewind);
    }
    if (!ctl.streaming() && smp.running()) smp.stop();

    // drain the sample ring into the controller
    if (!smp.empty()) {
      // the slots keep the clock's low 32 bits (171 s): their samples are younger than that
      const std::uint64_t now = mcu_ticks();
      while (const SampleSlot* s = smp.front()) {
        // (a sample taken after `now` was read is a few ticks younger: a signed difference)
        const std::int32_t age = static_cast<std::int32_t>(static_cast<std::uint32_t>(now) -
                                                           s->acquired_ticks);
        const std::uint64_t taken = now - static_cast<std::uint64_t>(static_cast<std::int64_t>(age));
        const std::int64_t at = static_cast<std::int64_t>(taken * kNsPerTick);
        if (s->lost_before) ctl.lost(s->lost_before, at);
        if (g_profile) {
          const std::uint64_t t0 = mcu_ticks();
          ctl.push(s->codes, at);
          const std::uint64_t dt = mcu_ticks() - t0;
          if (dt < (1u << 24) && dt > ls.longest_push) ls.longest_push = dt;
        } else {
          ctl.push(s->codes, at);
        }
        ++ls.pushes;
        smp.pop();
      }
    }
    if (ctl.streaming() && !ctl.finished() && smp.done()) {
      if (const std::uint32_t n = smp.take_trailing_lost()) ctl.lost(n, port.now_ns());
      ctl.end_of_replay(port.now_ns(), /*loop=*/false);
      if (!reported) {
        reported = true;
        const std::uint64_t total = mcu_ticks() - ls.start_ticks;
        const std::uint64_t busy = total - ls.idle_ticks;
        std::printf("FW: samples=%" PRIu32 " lost=%" PRIu32 " dropped=%" PRIu32
                    " ring_high_water=%" PRIu32 " decisions=%" PRIu32
                    " decisions_made=%" PRIu32 " decisions_dropped=%" PRIu32
                    " frames_dropped=%" PRIu32
                    " longest_push_ticks=%" PRIu32 " busy_ticks=%" PRIu32
                    " total_ticks=%" PRIu32 " sampler_isr_ticks=%" PRIu32
                    " uart_isr_ticks=%" PRIu32 " uart_tx_irqs=%" PRIu32 " uart_bytes=%" PRIu32
                    " encode_errors=%" PRIu32
                    " clock_pair_ticks_x256=%" PRIu32 " profile=%d ticks_per_s=25000000\n",
                    static_cast<std::uint32_t>(ctl.next_sample()),
                    static_cast<std::uint32_t>(smp.lost()),
                    static_cast<std::uint32_t>(ctl.dropped_samples()), smp.high_water(),
                    static_cast<std::uint32_t>(ctl.decisions_sent()),
                    static_cast<std::uint32_t>(ctl.decisions_made()),
                    static_cast<std::uint32_t>(ctl.decisions_dropped()),
                    static_cast<std::uint32_t>(ctl.frames_dropped()),
                    static_cast<std::uint32_t>(ls.longest_push),
                    static_cast<std::uint32_t>(busy), static_cast<std::uint32_t>(total),
                    smp.isr_ticks(), uart.isr_ticks(), uart.tx_interrupts(),
                    static_cast<std::uint32_t>(uart.bytes_sent()), port.encode_errors(),
                    static_cast<std::uint32_t>(clock_pairs), g_profile ? 1 : 0);
      }
    }
    ctl.poll();

    // Sleep until an interrupt brings work (a sample, a host byte, a SysTick). Profiling, the
    // time in WFI, less the interrupt handlers that ran meanwhile, is idle.
    if (g_profile) {
      // (every handler counted between the two accumulator reads ran between t0 and t1)
      const std::uint64_t t0 = mcu_ticks();
      const std::uint32_t isr0 = smp.isr_ticks() + uart.isr_ticks();
      wait_for_interrupt_unless([&] { return !smp.empty() || uart.rx_pending(); });
      const std::uint32_t isr1 = smp.isr_ticks() + uart.isr_ticks();
      const std::uint64_t t1 = mcu_ticks();
      const std::uint64_t in_handlers = static_cast<std::uint32_t>(isr1 - isr0);
      if (t1 - t0 < (1u << 24) && t1 - t0 > in_handlers) ls.idle_ticks += (t1 - t0) - in_handlers;
    } else {
      wait_for_interrupt_unless([&] { return !smp.empty() || uart.rx_pending(); });
    }
  }
}

}  // namespace eskin::mcu

int main() {
  std::setvbuf(stdout, nullptr, _IONBF, 0);
  return eskin::mcu::run();
}
