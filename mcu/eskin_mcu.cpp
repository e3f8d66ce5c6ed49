// The eskin MCU test program (bare metal, Cortex-M4F, QEMU mps2-an386; docs/mcu.md).
//
// The model is compiled in (a header from tools/mcu_case.py: the .eskin bytes as a const,
// 8-byte aligned array, so in flash) and loaded by the status-code loader Model::parse with its
// bases read in place (they stay in flash); a truncated copy must be refused with kTruncated.
// The held-out recordings stream from a file on the host through semihosting, one multi-taxel
// int16 sample at a time, into a StreamClassifier; every decision is checked against the host's
// float64 decision for the same model and samples (same window, same label, decision values
// within the stated tolerance), and the instructions of the push that made it are counted
// (SysTick at the processor clock under QEMU -icount shift=0: one tick = 40 instructions).
// The whole malloc family is wrapped and counted (alloc_count.c): an allocation inside a push()
// or flush() fails the run. The heap is bounded by the stack reserve (startup.c's _sbrk): a model
// whose stream classifier would need more is refused at construction (heap_guard.cpp: exit
// status MCU_EXIT_HEAP); a case built for that (MCU_CASE_EXPECT_NO_FIT) checks it.
#include <cinttypes>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <unistd.h>

#include "eskin/model.hpp"
#include "mcu_board.h"

#ifdef ESKIN_MCU_MODEL_HEADER
#include ESKIN_MCU_MODEL_HEADER
#else
#error "configure with -DESKIN_MCU_MODEL_HEADER=<header from tools/mcu_case.py>"
#endif

namespace {
unsigned long g_late_mallocs = 0;  // malloc-family calls inside push() and flush()
}

namespace eskin::detail {
// Builds without exceptions report construction errors here (cpp/src/raise.hpp).
[[noreturn]] void fatal_error(const char* what) noexcept {
  std::printf("FATAL: %s\n", what);
  std::exit(2);
}
}  // namespace eskin::detail

namespace {

constexpr std::uint64_t kInstrPerTick = 40;  // 1 ns per instruction, SysTick at 25 MHz
constexpr int kChunk = 64;                   // samples read from the host per semihosting call
std::int16_t g_chunk[kChunk * MCU_CASE_TAXELS];
std::uint32_t g_decision_ticks[MCU_CASE_MAX_DECISIONS];

std::uint32_t median(std::uint32_t* v, int n) {
  for (int i = 1; i < n; ++i)  // insertion sort (n is small)
    for (int j = i; j > 0 && v[j - 1] > v[j]; --j) {
      const std::uint32_t t = v[j];
      v[j] = v[j - 1];
      v[j - 1] = t;
    }
  return n == 0 ? 0 : v[n / 2];
}

}  // namespace

int main() {
  std::setvbuf(stdout, nullptr, _IONBF, 0);
  int bad = 0;
  {
    // the status-code loader refuses a damaged model without exceptions: here the first
    // 1000 bytes of the real one (the header says more)
    eskin::Model truncated;
    eskin::ModelLoadError err;
    const bool ok = eskin::Model::parse(mcu_model_data, 1000, &truncated, &err, true);
    std::printf("a truncated model: %s (%s)\n", ok ? "accepted" : "refused", err.message.c_str());
    if (ok || err.code != eskin::ModelError::kTruncated) ++bad;
  }
#ifdef MCU_CASE_EXPECT_NO_FIT
  std::printf("a model whose stream classifier needs more RAM than the heap has (%u bytes up to "
              "the stack reserve): construction must be refused\n",
              static_cast<unsigned>(mcu_heap_capacity()));
#endif
  const std::uint64_t c0 = mcu_ticks();
  eskin::Model model;
  eskin::ModelLoadError err;
  if (!eskin::Model::parse(mcu_model_data, mcu_model_size, &model, &err, /*in_place=*/true)) {
    std::printf("the model is refused: %s\n", err.message.c_str());
    return 1;
  }
  eskin::StreamClassifier sc(model);
#ifdef MCU_CASE_EXPECT_NO_FIT
  std::printf("MCU: the stream classifier was constructed (heap %u bytes): it should not fit\n",
              static_cast<unsigned>(mcu_heap_used()));
  return 1;
#endif
  const std::uint64_t c1 = mcu_ticks();
  const std::size_t heap = mcu_heap_used();
  std::printf("model: %d support vectors, %d machines, D=%d, %u bytes in flash; "
              "load + construction %" PRIu32 " instructions, heap %u bytes\n",
              model.n_support(), static_cast<int>(model.machines().size()), model.D(),
              static_cast<unsigned>(sizeof(mcu_model_data)),
              static_cast<std::uint32_t>((c1 - c0) * kInstrPerTick), static_cast<unsigned>(heap));

  std::FILE* f = std::fopen(MCU_CASE_STREAM, "rb");
  if (f == nullptr) {
    std::printf("cannot open %s\n", MCU_CASE_STREAM);
    return 1;
  }
  int n_dec = 0;
  double worst = 0.0;
  std::uint64_t other_ticks = 0, samples = 0;
  auto check = [&](eskin::ClassifyStatus st, std::uint64_t ticks) {
    if (st != eskin::ClassifyStatus::kDecision) {
      if (st != eskin::ClassifyStatus::kOk) {
        std::printf("sample %" PRIu32 ": status %s\n", static_cast<std::uint32_t>(samples),
                    eskin::to_string(st));
        ++bad;
      }
      other_ticks += ticks;
      return;
    }
    const eskin::Decision& d = sc.decision();
    const int k = n_dec++;
    if (k >= MCU_CASE_N_DECISIONS) {
      std::printf("decision %d: the host made only %d\n", k, MCU_CASE_N_DECISIONS);
      ++bad;
      return;
    }
    g_decision_ticks[k] = static_cast<std::uint32_t>(ticks);
    const McuCaseDecision& want = mcu_case_decisions[k];
    double diff = 0.0;
    for (int m = 0; m < d.n_machines; ++m) diff = std::fmax(diff, std::fabs(d.values[m] - want.values[m]));
    worst = std::fmax(worst, diff);
    const bool ok = d.window_start == want.start && d.window_stop == want.stop &&
                    d.label == want.label && diff <= MCU_CASE_TOLERANCE;
    if (!ok) ++bad;
    std::printf("decision %2d: window [%ld, %ld) label %d (host %d) max |value - host| %.2e "
                "%" PRIu32 " instructions%s\n",
                k, static_cast<long>(d.window_start), static_cast<long>(d.window_stop), d.label,
                want.label, diff, static_cast<std::uint32_t>(ticks * kInstrPerTick),
                ok ? "" : "  MISMATCH");
  };
  for (;;) {
    const std::size_t n = std::fread(g_chunk, sizeof(std::int16_t) * MCU_CASE_TAXELS, kChunk, f);
    if (n == 0) break;
    for (std::size_t i = 0; i < n; ++i) {
      const unsigned long a0 = mcu_alloc_calls();
      const std::uint64_t t0 = mcu_ticks();
      const eskin::ClassifyStatus st = sc.push(g_chunk + i * MCU_CASE_TAXELS);
      const std::uint64_t t1 = mcu_ticks();
      g_late_mallocs += mcu_alloc_calls() - a0;
      ++samples;
      check(st, t1 - t0);
    }
  }
  std::fclose(f);
  {
    const unsigned long a0 = mcu_alloc_calls();
    const std::uint64_t t0 = mcu_ticks();
    const eskin::ClassifyStatus st = sc.flush();
    const std::uint64_t t1 = mcu_ticks();
    g_late_mallocs += mcu_alloc_calls() - a0;
    check(st, t1 - t0);
  }
  if (samples != MCU_CASE_N_SAMPLES) {
    std::printf("read %" PRIu32 " samples, expected %d\n", static_cast<std::uint32_t>(samples),
                MCU_CASE_N_SAMPLES);
    ++bad;
  }
  if (n_dec != MCU_CASE_N_DECISIONS) {
    std::printf("%d decisions, the host made %d\n", n_dec, MCU_CASE_N_DECISIONS);
    ++bad;
  }
  if (g_late_mallocs != 0) {
    std::printf("%u heap allocations after construction\n", static_cast<unsigned>(g_late_mallocs));
    ++bad;
  }
  extern std::uint32_t _sidata[], _sdata[], _edata[], _ebss[];
  const std::size_t flash = reinterpret_cast<std::uintptr_t>(_sidata) +
                            (reinterpret_cast<std::uintptr_t>(_edata) - reinterpret_cast<std::uintptr_t>(_sdata));
  const std::size_t statics = reinterpret_cast<std::uintptr_t>(_ebss) - reinterpret_cast<std::uintptr_t>(_sdata);
  const std::size_t heap_total = mcu_heap_used();
  const std::size_t stack = mcu_stack_used();
  const std::size_t ram = statics + heap_total + stack;
  const int n_med = n_dec < MCU_CASE_MAX_DECISIONS ? n_dec : MCU_CASE_MAX_DECISIONS;
  const std::uint64_t med = std::uint64_t{median(g_decision_ticks, n_med)} * kInstrPerTick;
  std::printf("other samples: %" PRIu32 " instructions per sample on average (detector)\n",
              static_cast<std::uint32_t>(samples ? other_ticks * kInstrPerTick / samples : 0));
  std::printf("largest |decision value - host| %.3g (tolerance %.3g); RAM: static %u + heap %u "
              "+ stack %u bytes; heap allocations after construction: %u\n",
              worst, MCU_CASE_TOLERANCE, static_cast<unsigned>(statics),
              static_cast<unsigned>(heap_total), static_cast<unsigned>(stack),
              static_cast<unsigned>(g_late_mallocs));
  std::printf("heap bound: %u of %u bytes up to the stack reserve\n",
              static_cast<unsigned>(heap_total), static_cast<unsigned>(mcu_heap_capacity()));
  std::printf("MCU: board=mps2-an386 decisions=%d parity=%s instr_per_decision=%" PRIu32
              " flash=%u ram=%u\n",
              n_dec, bad == 0 ? "ok" : "FAIL", static_cast<std::uint32_t>(med),
              static_cast<unsigned>(flash), static_cast<unsigned>(ram));
  return bad == 0 ? 0 : 1;
}
