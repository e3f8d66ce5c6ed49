// Private to the tensor kernel: the 8 x 8 tile micro-kernel used by the batched mode distances.
// Kept in its own translation unit (tensor_kernel_tile.cpp) with no Eigen or std templates, so
// that the AVX2/FMA variant (compiled with a function-level target attribute, not -march) can
// never leak wider instructions into inline functions shared with the rest of the library.
#pragma once

#include <cstddef>

namespace eskin {

constexpr std::size_t kTileWidth = 8;

/// C[r * 8 + s] = sum_k A[k * 8 + r] * B[k * 8 + s]  (A, B: K x 8 row-major panels).
using TileFn = void (*)(const double* a, const double* b, std::size_t k, double* c);

/// Portable version (any CPU).
void tile_generic(const double* a, const double* b, std::size_t k, double* c) noexcept;

/// Best version for this CPU: AVX2+FMA when the CPU has them (x86, GCC/Clang), else generic.
/// The environment variable ESKIN_KERNEL_ISA=generic forces the portable version.
TileFn select_tile_kernel() noexcept;

/// Name of the variant select_tile_kernel() returns ("avx2-fma" or "generic").
const char* tile_kernel_name() noexcept;

}  // namespace eskin
