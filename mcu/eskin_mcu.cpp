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
// The stack: a decision needs at most mcu_decision_stack() bytes (the linked image's deepest
// chain of frames from push/flush plus an interrupt's, tools/mcu_stack.py --write); the
// classifier is constructed only where that much is left below the frame that will push
// (otherwise exit status MCU_EXIT_STACK), the canary above the stack's guard is checked after
// each decision and at the end, and the high-water mark is printed as stack=used/size. A case
// built with MCU_CASE_DEEP_CALLER=N runs the classifier below an N-byte frame (a deep caller):
// it must be refused at construction; with MCU_CASE_SKIP_STACK_RULE too it is not, and its
// decision must trip the guard (MCU_EXIT_STACK).
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

extern std::uint32_t _sidata[], _sdata[], _edata[], _ebss[];  // the linker script's symbols

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
// samples read from the host per semihosting call: 1024 taxel values (2 KB) whatever the grid
constexpr int kChunk = (1024 + MCU_CASE_TAXELS - 1) / MCU_CASE_TAXELS;
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

namespace {
int run(const eskin::Model& model, int bad, std::uint64_t c0);

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
  return run(model, bad, c0);
}

namespace {
__attribute__((noinline)) int run(const eskin::Model& model, int bad, std::uint64_t c0) {
#ifdef MCU_CASE_DEEP_CALLER
  {
    // a deep caller: hold all but 64 bytes less than a decision needs, for the rest of run()
    const std::size_t want = mcu_decision_stack() - 64, have = mcu_stack_free();
    if (have > want) {
      auto* hold = static_cast<volatile unsigned char*>(__builtin_alloca(have - want));
      hold[0] = 1;
      hold[have - want - 1] = 1;
    }
  }
#endif
  {
    // the stack rule: the decision's need must fit what is left below this frame (said without
    // printf, whose own frames may not fit what is left)
    const std::size_t need = mcu_decision_stack(), left = mcu_stack_free();
#if !defined(MCU_CASE_SKIP_STACK_RULE) && !defined(MCU_CASE_EXPECT_NO_FIT)
    // (the heap-bound case never decides: its image has no decision to measure)
    if (need == 0 || need > left) {
      mcu_stack_refused(need, left);
      return MCU_EXIT_STACK;
    }
#endif
#ifndef MCU_CASE_EXPECT_NO_FIT
    std::printf("stack rule: a decision needs %u bytes, %u are left below the caller\n",
                static_cast<unsigned>(need), static_cast<unsigned>(left));
#endif
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
  int n_dec = 0, stack_bad = 0;
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
    if (!mcu_stack_intact()) {
      std::printf("decision %d: the stack's canary above its guard was overwritten\n", k);
      ++stack_bad;
    }
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
  const std::size_t flash = reinterpret_cast<std::uintptr_t>(_sidata) +
                            (reinterpret_cast<std::uintptr_t>(_edata) - reinterpret_cast<std::uintptr_t>(_sdata));
  const std::size_t statics = reinterpret_cast<std::uintptr_t>(_ebss) - reinterpret_cast<std::uintptr_t>(_sdata);
  const std::size_t heap_total = mcu_heap_used();
  const std::size_t stack = mcu_stack_used();
  if (!mcu_stack_intact()) {
    std::printf("eskin-mcu: stack overflow: the canary above the guard was overwritten\n");
    ++stack_bad;
  }
  const std::size_t ram = statics + heap_total + stack;
  const int n_med = n_dec < MCU_CASE_MAX_DECISIONS ? n_dec : MCU_CASE_MAX_DECISIONS;
  const std::uint64_t med = std::uint64_t{median(g_decision_ticks, n_med)} * kInstrPerTick;
  const std::uint64_t largest = n_med ? std::uint64_t{g_decision_ticks[n_med - 1]} * kInstrPerTick : 0;
  std::printf("instructions per decision: median %" PRIu32 ", largest %" PRIu32 "\n",
              static_cast<std::uint32_t>(med), static_cast<std::uint32_t>(largest));
  std::printf("other samples: %" PRIu32 " instructions per sample on average (detector)\n",
              static_cast<std::uint32_t>(samples ? other_ticks * kInstrPerTick / samples : 0));
  std::printf("largest |decision value - host| %.3g (tolerance %.3g); RAM: static %u + heap %u "
              "+ stack %u bytes; heap allocations after construction: %u\n",
              worst, MCU_CASE_TOLERANCE, static_cast<unsigned>(statics),
              static_cast<unsigned>(heap_total), static_cast<unsigned>(stack),
              static_cast<unsigned>(g_late_mallocs));
  std::printf("heap bound: %u of %u bytes up to the stack reserve\n",
              static_cast<unsigned>(heap_total), static_cast<unsigned>(mcu_heap_capacity()));
  std::printf("stack: %u of %u bytes used (high-water mark; the lowest %u are the guard)\n",
              static_cast<unsigned>(stack), static_cast<unsigned>(mcu_stack_size()),
              static_cast<unsigned>(MCU_STACK_GUARD_BYTES));
  std::printf("MCU: board=mps2-an386 decisions=%d parity=%s instr_per_decision=%" PRIu32
              " flash=%u ram=%u stack=%u/%u\n",
              n_dec, bad == 0 ? "ok" : "FAIL", static_cast<std::uint32_t>(med),
              static_cast<unsigned>(flash), static_cast<unsigned>(ram),
              static_cast<unsigned>(stack), static_cast<unsigned>(mcu_stack_size()));
  if (stack_bad) return MCU_EXIT_STACK;
  return bad == 0 ? 0 : 1;
}
}  // namespace
