// Cortex-M4 interrupt control of the eskin firmware (NVIC and PRIMASK), and its vector table:
// the firmware moves the table (VTOR) to one that adds the board's interrupt lines to the
// exception handlers of startup.c.
#pragma once

#include <cstdint>

namespace eskin::mcu {

/// Profiling: the interrupt handlers and the main loop time themselves with the clock. Under
/// QEMU a clock read costs the host several microseconds, so this is on only for instruction
/// counts (QEMU -icount, where it costs the board only instructions); set at start-up.
extern bool g_profile;

inline void compiler_barrier() { __asm volatile("" ::: "memory"); }

/// Masks interrupts; returns the previous PRIMASK for irq_restore.
inline std::uint32_t irq_save() {
  std::uint32_t primask;
  __asm volatile("mrs %0, primask\n cpsid i" : "=r"(primask)::"memory");
  return primask;
}
inline void irq_restore(std::uint32_t primask) {
  __asm volatile("msr primask, %0" ::"r"(primask) : "memory");
}

inline void irq_enable(int irq) {
  reinterpret_cast<volatile std::uint32_t*>(0xE000E100u)[irq / 32] = 1u << (irq % 32);
}
inline void irq_disable(int irq) {
  reinterpret_cast<volatile std::uint32_t*>(0xE000E180u)[irq / 32] = 1u << (irq % 32);
}
/// Priority of an interrupt line (0 = most urgent; the top bits count).
inline void irq_set_priority(int irq, std::uint8_t priority) {
  reinterpret_cast<volatile std::uint8_t*>(0xE000E400u)[irq] = priority;
}

/// Installs the firmware's vector table (startup.c's exceptions + the board's lines).
void install_vectors();

/// Waits for an interrupt unless `ready` became true meanwhile (checked with interrupts
/// masked, so a wake-up between the check and the WFI is not missed).
template <class Ready>
void wait_for_interrupt_unless(Ready&& ready) {
  __asm volatile("cpsid i" ::: "memory");
  if (!ready()) __asm volatile("wfi" ::: "memory");
  __asm volatile("cpsie i" ::: "memory");
}

}  // namespace eskin::mcu
