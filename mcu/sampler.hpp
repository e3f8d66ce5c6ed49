// The firmware's acquisition: a CMSDK APB timer (TIMER0 of mps2-an386, 0x40000000, 25 MHz)
// interrupts at the sample rate; its handler takes the multi-taxel samples due by the processor
// clock (one per interrupt when interrupts come on time; those of the periods a late or merged
// interrupt missed as well, each with its own acquisition time, so that the stream keeps the
// clock's rate) and puts them into a ring that the main loop drains (into the controller and its
// StreamClassifier). The ring decouples the two: while a decision runs in the main loop, the
// samples wait in the ring; one that finds the ring full is lost and counted, and its stream
// index is skipped, so the host sees the hole.
//
// Under QEMU the samples come from a recording in memory (an eskin replay file, .eskr, that
// QEMU loads before reset: the stand-in for the ADC); on a board, the handler would read the
// ADC's conversion of the same instant instead.
#pragma once

#include <cstddef>
#include <cstdint>

namespace eskin::mcu {

/// Most taxels of one sample (a 4 x 4 patch) and the ring's length in samples (a power of
/// two): 256 samples are 85 ms at 3 kSps, the longest the main loop may be away.
#ifndef ESKIN_FW_MAX_TAXELS
#define ESKIN_FW_MAX_TAXELS 16
#endif
#ifndef ESKIN_FW_SAMPLE_RING
#define ESKIN_FW_SAMPLE_RING 256
#endif
inline constexpr std::size_t kMaxTaxels = ESKIN_FW_MAX_TAXELS;
inline constexpr std::size_t kSampleRing = ESKIN_FW_SAMPLE_RING;
static_assert((kSampleRing & (kSampleRing - 1)) == 0, "the sample ring's length is a power of two");

struct SampleSlot {
  std::uint32_t acquired_ticks;  // processor clock (mcu_ticks, low 32 bits) at the sample
  std::uint32_t lost_before;     // samples lost (ring full) just before this one
  std::int16_t codes[kMaxTaxels];
};

/// A recording in memory: `n_samples` samples of `taxels` int16 codes, sample-major.
struct SampleSource {
  const std::int16_t* samples = nullptr;
  std::uint64_t n_samples = 0;
  std::size_t taxels = 0;
};

class Sampler {
 public:
  /// Timer reload for `rate_hz` at the 25 MHz timer clock; the real rate is timer_rate_hz().
  void init(const SampleSource& source, double rate_hz);
  double timer_rate_hz() const { return rate_hz_; }
  /// Starts (or resumes) the timer; `rewind` starts the recording over.
  void start(bool rewind);
  void stop();
  bool running() const { return running_; }
  /// The recording is over and every sample taken has left the ring.
  bool done() const { return done_ && empty(); }
  bool empty() const { return head_ == tail_; }
  /// The oldest sample in the ring (valid until pop()), or null.
  const SampleSlot* front() const;
  void pop();
  /// Samples lost after the last one in the ring (reported with the next one, or at the end).
  std::uint32_t take_trailing_lost();
  std::uint64_t taken() const { return taken_; }
  std::uint64_t lost() const { return lost_; }
  /// Most samples ever waiting in the ring at once.
  std::uint32_t high_water() const { return high_water_; }

  /// Processor clock ticks spent in the timer's handler (wraps at 2^32: take differences).
  std::uint32_t isr_ticks() const { return isr_ticks_; }

  void on_timer_interrupt();

 private:
  void take(std::uint64_t now);
  SampleSource src_;
  std::uint64_t period_ticks_ = 0;          // one sample period in processor clock ticks
  volatile std::uint64_t next_due_ = 0;     // processor clock tick of the next sample
  double rate_hz_ = 0.0;
  std::uint32_t reload_ = 0;
  volatile bool running_ = false;
  volatile bool done_ = false;
  volatile std::uint64_t pos_ = 0;  // next sample of the recording
  SampleSlot ring_[kSampleRing];
  volatile std::uint32_t head_ = 0;  // written by the timer interrupt
  volatile std::uint32_t tail_ = 0;  // written by the main loop
  volatile std::uint32_t pending_lost_ = 0;
  volatile std::uint64_t taken_ = 0;
  volatile std::uint64_t lost_ = 0;
  volatile std::uint32_t high_water_ = 0;
  volatile std::uint32_t isr_ticks_ = 0;
};

Sampler& sampler();

}  // namespace eskin::mcu
