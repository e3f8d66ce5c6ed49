/* Counts the calls of the whole malloc family (mcu_alloc_calls, mcu_board.h), for the test
 * program's check that no allocation happens after construction. Each function is wrapped at
 * link time (-Wl,--wrap=NAME for every NAME below, mcu/CMakeLists.txt): the public ones and the
 * reentrant _r ones newlib builds them on, since a program or a library may call either. A call
 * is counted once: the nesting of a public function through its _r form (malloc -> _malloc_r,
 * calloc -> _calloc_r -> _malloc_r) is not counted again. */
#include <stddef.h>

#include "mcu_board.h"

struct _reent;

static volatile unsigned long calls;
static volatile int depth;

unsigned long mcu_alloc_calls(void) { return calls; }

static void enter(void) {
  if (depth++ == 0) ++calls;
}
static void leave(void) { --depth; }

#define WRAP(ret, name, params, args)                                                       \
  ret __real_##name params;                                                                 \
  ret __wrap_##name params;                                                                 \
  ret __wrap_##name params {                                                                \
    enter();                                                                                \
    ret out_ = __real_##name args;                                                           \
    leave();                                                                                \
    return out_;                                                                           \
  }

WRAP(void*, malloc, (size_t n), (n))
WRAP(void*, calloc, (size_t n, size_t m), (n, m))
WRAP(void*, realloc, (void* p, size_t n), (p, n))
WRAP(void*, reallocf, (void* p, size_t n), (p, n))
WRAP(void*, memalign, (size_t a, size_t n), (a, n))
WRAP(void*, aligned_alloc, (size_t a, size_t n), (a, n))
WRAP(void*, valloc, (size_t n), (n))
WRAP(void*, pvalloc, (size_t n), (n))
WRAP(void*, _malloc_r, (struct _reent* r, size_t n), (r, n))
WRAP(void*, _calloc_r, (struct _reent* r, size_t n, size_t m), (r, n, m))
WRAP(void*, _realloc_r, (struct _reent* r, void* p, size_t n), (r, p, n))
WRAP(void*, _reallocf_r, (struct _reent* r, void* p, size_t n), (r, p, n))
WRAP(void*, _memalign_r, (struct _reent* r, size_t a, size_t n), (r, a, n))
WRAP(void*, _valloc_r, (struct _reent* r, size_t n), (r, n))
WRAP(void*, _pvalloc_r, (struct _reent* r, size_t n), (r, n))
