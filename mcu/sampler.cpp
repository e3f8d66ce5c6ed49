#include "sampler.hpp"

#include <cstring>

#include "board_irq.hpp"
#include "mcu_board.h"

namespace eskin::mcu {

namespace {

constexpr std::uintptr_t kTimer0 = 0x40000000u;
constexpr std::uint32_t kCtrl = 0x00, kValue = 0x04, kReload = 0x08, kIntClear = 0x0C;
constexpr std::uint32_t kCtrlEnable = 1u << 0, kCtrlIrq = 1u << 3;
constexpr int kIrqTimer0 = 8;
constexpr double kTimerClockHz = 25e6;
/// Processor clock ticks (mcu_ticks: SysTick at the 25 MHz processor clock) per timer tick.
constexpr std::uint64_t kCpuTicksPerTimerTick = 1;

inline volatile std::uint32_t& reg(std::uint32_t off) {
  return *reinterpret_cast<volatile std::uint32_t*>(kTimer0 + off);
}

Sampler g_sampler;

}  // namespace

Sampler& sampler() { return g_sampler; }

void Sampler::init(const SampleSource& source, double rate_hz) {
  src_ = source;
  // the timer counts reload + 1 clock cycles per period
  const double cycles = kTimerClockHz / rate_hz;
  reload_ = static_cast<std::uint32_t>(cycles + 0.5) - 1;
  rate_hz_ = kTimerClockHz / (static_cast<double>(reload_) + 1.0);
  period_ticks_ = (static_cast<std::uint64_t>(reload_) + 1) * kCpuTicksPerTimerTick;
  reg(kCtrl) = 0;
  reg(kIntClear) = 1;
  irq_set_priority(kIrqTimer0, 0x20);  // above the UART: sampling is never late for the link
  irq_enable(kIrqTimer0);
}

void Sampler::start(bool rewind) {
  if (rewind) {
    pos_ = 0;
    done_ = false;
  }
  if (done_) return;
  reg(kReload) = reload_;
  reg(kValue) = reload_;
  // read before the timer starts: each of its interrupts then finds its own sample due
  next_due_ = mcu_ticks() + period_ticks_;
  running_ = true;
  reg(kCtrl) = kCtrlEnable | kCtrlIrq;
}

void Sampler::stop() {
  reg(kCtrl) = 0;
  running_ = false;
}

const SampleSlot* Sampler::front() const {
  if (head_ == tail_) return nullptr;
  return &ring_[tail_ & (kSampleRing - 1)];
}

void Sampler::pop() { tail_ = tail_ + 1; }

std::uint32_t Sampler::take_trailing_lost() {
  const std::uint32_t primask = irq_save();
  const std::uint32_t n = pending_lost_;
  pending_lost_ = 0;
  irq_restore(primask);
  return n;
}

void Sampler::on_timer_interrupt() {
  const std::uint64_t entry = mcu_ticks();
  reg(kIntClear) = 1;
  // The samples due by the clock: one on time; more when this interrupt came late or stood for
  // several periods (an emulator on a busy host). At most a ring's worth per interrupt: a longer
  // backlog is taken by the next interrupts.
  std::uint64_t due = next_due_;
  for (std::size_t n = 0; due <= entry && running_ && n < kSampleRing; ++n) {
    take(due);
    due += period_ticks_;
  }
  next_due_ = due;
  if (g_profile) {
    const std::uint64_t d = mcu_ticks() - entry;  // a reading that went backwards: not counted
    if (d < (1u << 24)) isr_ticks_ = isr_ticks_ + static_cast<std::uint32_t>(d);
  }
}

void Sampler::take(std::uint64_t now) {
  const std::uint64_t pos = pos_;
  if (pos >= src_.n_samples) {  // the recording is over
    reg(kCtrl) = 0;
    running_ = false;
    done_ = true;
    return;
  }
  pos_ = pos + 1;
  const std::uint32_t h = head_;
  const std::uint32_t waiting = h - tail_;
  if (waiting >= kSampleRing) {  // the main loop is too far behind: this sample is lost
    pending_lost_ = pending_lost_ + 1;
    lost_ = lost_ + 1;
    return;
  }
  SampleSlot& s = ring_[h & (kSampleRing - 1)];
  s.acquired_ticks = static_cast<std::uint32_t>(now);
  s.lost_before = pending_lost_;
  pending_lost_ = 0;
  std::memcpy(s.codes, src_.samples + pos * src_.taxels, src_.taxels * sizeof(std::int16_t));
  compiler_barrier();
  head_ = h + 1;
  taken_ = taken_ + 1;
  if (waiting + 1 > high_water_) high_water_ = waiting + 1;
}

}  // namespace eskin::mcu

extern "C" void mcu_timer0_irq(void) { eskin::mcu::sampler().on_timer_interrupt(); }
