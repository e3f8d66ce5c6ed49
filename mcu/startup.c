/* Reset and exception handlers of the eskin MCU test program (Cortex-M4F on QEMU's mps2-an386).
 * Reset: enable the FPU, copy .data to RAM, zero .bss, paint the stack (for its high-water mark),
 * open the semihosting console (newlib's librdimon), run the C++ constructors and main(), and
 * report main's return value to QEMU through semihosting exit.
 * SysTick runs from the processor clock with the longest reload; its wrap-arounds are counted
 * here, so mcu_ticks() is a 64-bit count of processor clock ticks.
 * The heap: _sbrk (below) grows it from the end of .bss up to the stack reserve (the linker
 * script's `end` and `_sstack`) and never further, for malloc and every allocation built on it;
 * librdimon's own _sbrk (a weak symbol, replaced by this one) stopped only at the stack pointer.
 * An allocation that would reach the stack reserve gets NULL (errno ENOMEM); operator new then
 * ends the program with MCU_EXIT_HEAP (heap_guard.cpp). */
#include <errno.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "mcu_board.h"

/* linker symbols (arrays, so that walking them is well-defined pointer arithmetic) */
extern uint32_t _sidata[], _sdata[], _edata[], _sbss[], _ebss[], _estack[], _sstack[];
extern char end[]; /* the heap's first byte */
extern void __libc_init_array(void);
extern void initialise_monitor_handles(void);
extern int main(void);

#define SCB_CPACR (*(volatile uint32_t*)0xE000ED88u)
#define SYST_CSR (*(volatile uint32_t*)0xE000E010u)
#define SYST_RVR (*(volatile uint32_t*)0xE000E014u)
#define SYST_CVR (*(volatile uint32_t*)0xE000E018u)

static volatile uint32_t systick_wraps;

/* no crtbegin.o (-nostartfiles): the handle that static destructors are registered with */
void* __dso_handle = &__dso_handle;
void _init(void) {} /* no crti.o (-nostartfiles): __libc_init_array calls these */
void _fini(void) {}

uint64_t mcu_ticks(void) {
  uint32_t w, v;
  do {
    w = systick_wraps;
    v = SYST_CVR;
  } while (w != systick_wraps);
  return ((uint64_t)w << 24) + (0xFFFFFFu - v);
}

void SysTick_Handler(void) { ++systick_wraps; }

static char* heap_top; /* 0 until the first _sbrk: then end + the bytes given out */

void* _sbrk(ptrdiff_t incr) {
  char* const base = end;
  char* const limit = (char*)_sstack;
  char* const top = heap_top ? heap_top : base;
  if (incr > 0 ? (size_t)incr > (size_t)(limit - top) : (size_t)(-incr) > (size_t)(top - base)) {
    errno = ENOMEM;
    return (void*)-1;
  }
  heap_top = top + incr;
  return top;
}

size_t mcu_heap_used(void) { return heap_top ? (size_t)(heap_top - end) : 0; }
size_t mcu_heap_capacity(void) { return (size_t)((char*)_sstack - end); }

void mcu_heap_exhausted(size_t request) {
  printf("eskin-mcu: out of memory: %u more bytes would reach the stack reserve (heap %u of %u "
         "bytes used)\n",
         (unsigned)request, (unsigned)mcu_heap_used(), (unsigned)mcu_heap_capacity());
  fflush(stdout);
  _Exit(MCU_EXIT_HEAP);
}

size_t mcu_stack_used(void) {
  const volatile uint32_t* p = _sstack;
  while ((uintptr_t)p < (uintptr_t)_estack && *p == 0xDEADBEEFu) ++p;
  return (size_t)((uintptr_t)_estack - (uintptr_t)p);
}

__attribute__((naked, noreturn)) void Reset_Handler(void) {
  __asm volatile(
      "ldr r0, =0xE000ED88\n" /* CPACR: full access to CP10 and CP11 (the FPU) */
      "ldr r1, [r0]\n"
      "orr r1, r1, #(0xF << 20)\n"
      "str r1, [r0]\n"
      "dsb\n"
      "isb\n"
      "b mcu_start\n");
}

__attribute__((noreturn, used)) void mcu_start(void) {
  const size_t n_data = (size_t)((uintptr_t)_edata - (uintptr_t)_sdata) / 4;
  for (size_t i = 0; i < n_data; ++i) _sdata[i] = _sidata[i];
  const size_t n_bss = (size_t)((uintptr_t)_ebss - (uintptr_t)_sbss) / 4;
  for (size_t i = 0; i < n_bss; ++i) _sbss[i] = 0;
  /* paint the stack below the current frame */
  uintptr_t sp;
  __asm volatile("mov %0, sp" : "=r"(sp));
  const size_t n_paint = (size_t)(sp - 256 - (uintptr_t)_sstack) / 4;
  for (size_t i = 0; i < n_paint; ++i) ((volatile uint32_t*)_sstack)[i] = 0xDEADBEEFu;
  SYST_RVR = 0xFFFFFFu;
  SYST_CVR = 0;
  SYST_CSR = 7u; /* enable, interrupt on wrap, processor clock */
  initialise_monitor_handles();
  __libc_init_array();
  exit(main());
}

/* A fault: say so on the semihosting console (SYS_WRITE0, no library call) and stop. */
static void fault(void) {
  static const char msg[] = "eskin-mcu: processor fault\n";
  register int op __asm("r0") = 0x04;
  register const char* arg __asm("r1") = msg;
  __asm volatile("bkpt 0xab" : : "r"(op), "r"(arg) : "memory");
  _Exit(3);
}
void NMI_Handler(void) { fault(); }
void HardFault_Handler(void) { fault(); }
void MemManage_Handler(void) { fault(); }
void BusFault_Handler(void) { fault(); }
void UsageFault_Handler(void) { fault(); }

typedef void (*vector_t)(void);
__attribute__((section(".isr_vector"), used)) const vector_t mcu_vectors[16] = {
    (vector_t)_estack, Reset_Handler,     NMI_Handler, HardFault_Handler,
    MemManage_Handler,  BusFault_Handler,  UsageFault_Handler, 0, 0, 0, 0,
    0 /* SVCall */,     0 /* DebugMon */,  0,           0 /* PendSV */, SysTick_Handler};
