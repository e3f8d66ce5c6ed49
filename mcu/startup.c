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
 * ends the program with MCU_EXIT_HEAP (heap_guard.cpp).
 * The stack: painted at reset (its high-water mark, mcu_stack_used), and guarded: the MPU's
 * region 0 makes its lowest MCU_STACK_GUARD_BYTES inaccessible, so a push or a frame's store
 * that reaches them faults, and the MemManage handler (on a fresh stack) says so and ends the
 * program with MCU_EXIT_STACK; the painted words just above the guard are a canary
 * (mcu_stack_intact) the program checks at each decision and at the end. */
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
#define SCB_SHCSR (*(volatile uint32_t*)0xE000ED24u)
#define SCB_CFSR (*(volatile uint32_t*)0xE000ED28u)
#define SCB_MMFAR (*(volatile uint32_t*)0xE000ED34u)
#define MPU_CTRL (*(volatile uint32_t*)0xE000ED94u)
#define MPU_RNR (*(volatile uint32_t*)0xE000ED98u)
#define MPU_RBAR (*(volatile uint32_t*)0xE000ED9Cu)
#define MPU_RASR (*(volatile uint32_t*)0xE000EDA0u)

#define STACK_PAINT 0xDEADBEEFu
#define CANARY_WORDS 8u /* painted words above the guard that must stay painted */

/* The decision's stack need in bytes (tools/mcu_stack.py --write stores it here, in flash,
 * after the link; 0: not measured, and the test program then refuses every model). */
__attribute__((used)) const volatile uint32_t mcu_decision_stack_need = 0;

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

/* the lowest word the stack may use: above the MPU guard */
static const volatile uint32_t* stack_floor(void) {
  return (const volatile uint32_t*)((uintptr_t)_sstack + MCU_STACK_GUARD_BYTES);
}

size_t mcu_stack_used(void) {
  const volatile uint32_t* p = stack_floor();
  while ((uintptr_t)p < (uintptr_t)_estack && *p == STACK_PAINT) ++p;
  return (size_t)((uintptr_t)_estack - (uintptr_t)p);
}

size_t mcu_stack_size(void) { return (size_t)((uintptr_t)_estack - (uintptr_t)_sstack); }

size_t mcu_stack_free(void) {
  uintptr_t sp;
  __asm volatile("mov %0, sp" : "=r"(sp));
  const uintptr_t floor = (uintptr_t)stack_floor() + CANARY_WORDS * 4u;
  return sp > floor ? (size_t)(sp - floor) : 0;
}

int mcu_stack_intact(void) {
  const volatile uint32_t* p = stack_floor();
  for (unsigned i = 0; i < CANARY_WORDS; ++i)
    if (p[i] != STACK_PAINT) return 0;
  return 1;
}

size_t mcu_decision_stack(void) { return (size_t)mcu_decision_stack_need; }

/* Semihosting SYS_WRITE0 (no library call: the fault paths use it). */
static void say(const char* msg) {
  register int op __asm("r0") = 0x04;
  register const char* arg __asm("r1") = msg;
  __asm volatile("bkpt 0xab" : : "r"(op), "r"(arg) : "memory");
}

__attribute__((noinline)) static char* put_uint(char* out, uint32_t v, int base) {
  char tmp[12];
  int n = 0;
  do {
    tmp[n++] = "0123456789abcdef"[v % (uint32_t)base];
    v /= (uint32_t)base;
  } while (v);
  while (n) *out++ = tmp[--n];
  return out;
}

__attribute__((noinline)) static char* put_str(char* out, const char* s) {
  while (*s) *out++ = *s++;
  return out;
}

void mcu_stack_refused(size_t need, size_t left) {
  static char msg[200];
  char* p = msg;
  p = put_str(p, "eskin-mcu: stack: a decision needs ");
  p = put_uint(p, (uint32_t)need, 10);
  p = put_str(p, need ? " bytes of stack, " : " bytes of stack (not measured: tools/mcu_stack.py "
                                              "--write), ");
  p = put_uint(p, (uint32_t)left, 10);
  p = put_str(p, " are left below the classifier's caller (");
  p = put_uint(p, (uint32_t)mcu_stack_size(), 10);
  p = put_str(p, "-byte stack): the classifier is not constructed\n");
  *p = 0;
  say(msg);
}

/* The guard: MPU region 0, MCU_STACK_GUARD_BYTES at _sstack, no access, never executed; the
 * default memory map everywhere else (PRIVDEFENA); MemManage faults enabled (not escalated). */
static void guard_stack(void) {
  MPU_RNR = 0;
  MPU_RBAR = (uint32_t)(uintptr_t)_sstack;
  uint32_t log2 = 0;
  while ((1u << log2) < MCU_STACK_GUARD_BYTES) ++log2;
  MPU_RASR = (1u << 28) /* XN */ | (0u << 24) /* AP: no access */ | ((log2 - 1u) << 1) | 1u;
  MPU_CTRL = 4u /* PRIVDEFENA */ | 1u /* ENABLE */;
  SCB_SHCSR |= 1u << 16; /* MEMFAULTENA */
  __asm volatile("dsb\n isb" ::: "memory");
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
  for (size_t i = 0; i < n_paint; ++i) ((volatile uint32_t*)_sstack)[i] = STACK_PAINT;
  guard_stack();
  SYST_RVR = 0xFFFFFFu;
  SYST_CVR = 0;
  SYST_CSR = 7u; /* enable, interrupt on wrap, processor clock */
  initialise_monitor_handles();
  __libc_init_array();
  exit(main());
}

/* A fault: say so on the semihosting console (SYS_WRITE0, no library call) and stop. */
static void fault(void) {
  say("eskin-mcu: processor fault\n");
  _Exit(3);
}

/* A memory-protection fault: the stack guard's (a store or an exception's stacking into it), or
 * another. Entered on a fresh stack (MemManage_Handler): the old one may be the fault. */
__attribute__((noreturn, used)) void mcu_memory_fault(void) {
  const uint32_t cfsr = SCB_CFSR;
  const uint32_t addr = SCB_MMFAR;
  const uint32_t lo = (uint32_t)(uintptr_t)_sstack;
  const int stacking = (cfsr & (1u << 4)) != 0; /* MSTKERR */
  const int in_guard = (cfsr & (1u << 7)) && addr >= lo && addr < lo + MCU_STACK_GUARD_BYTES;
  char msg[160];
  char* p = msg;
  if (stacking || in_guard) {
    p = put_str(p, "eskin-mcu: stack overflow: ");
    p = put_str(p, stacking ? "an exception's stacking" : "a store at 0x");
    if (!stacking) p = put_uint(p, addr, 16);
    p = put_str(p, " reached the guard below the ");
    p = put_uint(p, (uint32_t)mcu_stack_size(), 10);
    p = put_str(p, "-byte stack\n");
    *p = 0;
    say(msg);
    _Exit(MCU_EXIT_STACK);
  }
  p = put_str(p, "eskin-mcu: memory protection fault (CFSR 0x");
  p = put_uint(p, cfsr, 16);
  p = put_str(p, ")\n");
  *p = 0;
  say(msg);
  _Exit(3);
}

void NMI_Handler(void) { fault(); }
void HardFault_Handler(void) { fault(); }
__attribute__((naked)) void MemManage_Handler(void) {
  __asm volatile(
      "ldr r0, =_estack\n" /* a fresh stack: the old one may be what faulted */
      "mov sp, r0\n"
      "b mcu_memory_fault\n");
}
void BusFault_Handler(void) { fault(); }
void UsageFault_Handler(void) { fault(); }

typedef void (*vector_t)(void);
__attribute__((section(".isr_vector"), used)) const vector_t mcu_vectors[16] = {
    (vector_t)_estack, Reset_Handler,     NMI_Handler, HardFault_Handler,
    MemManage_Handler,  BusFault_Handler,  UsageFault_Handler, 0, 0, 0, 0,
    0 /* SVCall */,     0 /* DebugMon */,  0,           0 /* PendSV */, SysTick_Handler};
