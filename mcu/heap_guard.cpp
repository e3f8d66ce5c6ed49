// operator new of the device programs (-fno-exceptions): malloc, bounded by startup.c's _sbrk,
// and on failure mcu_heap_exhausted (one line on the console, exit status MCU_EXIT_HEAP) instead
// of the library's abort without a word. A model whose stream classifier would need more heap
// than lies between .bss and the stack reserve is thereby refused at construction, before any
// allocation can run into the stack.
#include <cstddef>
#include <cstdlib>
#include <new>

#include "mcu_board.h"

namespace {
void* allocate(std::size_t n) noexcept {
  void* p = std::malloc(n == 0 ? 1 : n);
  if (p == nullptr) mcu_heap_exhausted(n);
  return p;
}
}  // namespace

void* operator new(std::size_t n) { return allocate(n); }
void* operator new[](std::size_t n) { return allocate(n); }
void* operator new(std::size_t n, const std::nothrow_t&) noexcept { return std::malloc(n == 0 ? 1 : n); }
void* operator new[](std::size_t n, const std::nothrow_t&) noexcept { return std::malloc(n == 0 ? 1 : n); }
void operator delete(void* p) noexcept { std::free(p); }
void operator delete[](void* p) noexcept { std::free(p); }
void operator delete(void* p, std::size_t) noexcept { std::free(p); }
void operator delete[](void* p, std::size_t) noexcept { std::free(p); }
