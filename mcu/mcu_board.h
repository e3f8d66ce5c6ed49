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

#ifdef __cplusplus
}
#endif
