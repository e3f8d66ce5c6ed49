/* The board services of the eskin MCU test program (startup.c). */
#pragma once
#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/** Processor clock ticks since reset (SysTick, 24-bit counter and counted wrap-arounds). */
uint64_t mcu_ticks(void);
/** Bytes of the stack ever used (from the painted pattern). */
size_t mcu_stack_used(void);

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
