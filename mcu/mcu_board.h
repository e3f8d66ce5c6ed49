/* The board services of the eskin MCU test program (startup.c). */
#pragma once
#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/** Processor clock ticks since reset (SysTick, 24-bit counter and counted wrap-arounds). */
uint64_t mcu_ticks(void);
/** Bytes of the stack ever used (from the pattern painted at reset, measured from the top). */
size_t mcu_stack_used(void);
/** The stack reserve at the top of RAM (bytes), its lowest MCU_STACK_GUARD_BYTES the guard. */
size_t mcu_stack_size(void);
/** The lowest bytes of the stack that no access may reach (MPU region 0; a push or a store there
 * faults and ends the program with MCU_EXIT_STACK). At least the largest frame of the image
 * (tools/mcu_stack.py checks it), so that no frame can step over it into the heap: a 32-byte
 * guard let a printf below a deep caller write into the heap without touching it. */
#define MCU_STACK_GUARD_BYTES 1024u
/** Bytes of stack left below the caller's frame, above the guard and its canary. */
size_t mcu_stack_free(void);
/** 1 while the canary words just above the guard are as painted at reset. */
int mcu_stack_intact(void);
/** The stack a decision (StreamClassifier::push or flush) needs at most, in bytes: the deepest
 * chain of static frames of the linked image (tools/mcu_stack.py --write); 0: not measured. */
size_t mcu_decision_stack(void);
/** Say on the console, without the C library (a few bytes of stack), that a decision needing
 * `need` bytes does not fit the `left` bytes below its caller: the classifier is not built. */
void mcu_stack_refused(size_t need, size_t left);
/** The program's exit status when the stack is too small: a decision that would not fit the
 * stack left to it (refused at construction), or the guard reached. */
#define MCU_EXIT_STACK 5

/** The heap (startup.c's _sbrk): bytes given out, and the most it can give (from the end of .bss
 * to the stack reserve at the top of RAM; it never grows into the reserve). */
size_t mcu_heap_used(void);
size_t mcu_heap_capacity(void);

/** The program's exit status when an allocation would reach the stack reserve. */
#define MCU_EXIT_HEAP 4
/** Say so on the console and end the program with MCU_EXIT_HEAP (operator new's failure path,
 * heap_guard.cpp: a model whose stream classifier does not fit is refused at construction). */
__attribute__((noreturn)) void mcu_heap_exhausted(size_t request);

/** Calls of the malloc family so far (malloc, calloc, realloc, memalign, aligned_alloc, valloc,
 * pvalloc, reallocf and their reentrant _r forms; a call counted once however it nests):
 * alloc_count.c, linked with -Wl,--wrap for each of them. */
unsigned long mcu_alloc_calls(void);

#ifdef __cplusplus
}
#endif
