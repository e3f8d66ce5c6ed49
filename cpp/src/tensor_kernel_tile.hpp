// Private to the tensor kernel: the 8 x 8 tile micro-kernel used by the batched mode distances.
// Kept in its own translation unit (tensor_kernel_tile.cpp) with no Eigen or std templates, so
// that the AVX2/FMA and AVX-512 variants (compiled with function-level target attributes, not
// -march) can never leak wider instructions into inline functions shared with the library.
#pragma once

#include <cstddef>

namespace eskin {

constexpr std::size_t kTileWidth = 8;

/// C[r * 8 + s] = (sum_k A[k * 8 + r] * B[k * 8 + s])^2  (A, B: K x 8 row-major panels): the
/// squared entries of the 8 x 8 block A^T B.
using TileFn = void (*)(const double* a, const double* b, std::size_t k, double* c);

/// C[r * 8 + s] = sum_k A[k * 8 + r] * B[k * 8 + s]: the 8 x 8 block A^T B itself (same
/// signature as TileFn, not squared).
using TileDotFn = TileFn;

/// Sum of the 64 squared entries of A^T B (the whole tile belongs to one pattern pair).
using TileSumFn = double (*)(const double* a, const double* b, std::size_t k);

/// Portable versions (any CPU).
void tile_generic(const double* a, const double* b, std::size_t k, double* c) noexcept;
void tile_dot_generic(const double* a, const double* b, std::size_t k, double* c) noexcept;

/// Instruction set the kernel's run-time dispatch may use: 2 AVX-512 (the x86-64-v4 set),
/// 1 AVX2+FMA, 0 baseline; what this CPU has, capped by ESKIN_KERNEL_ISA=generic|avx2 (read at
/// each call). Shared by the tile micro-kernels and the eigen-solver.
int isa_level() noexcept;

/// Best version for this CPU (x86 with GCC/Clang): AVX-512F, else AVX2+FMA, else generic.
/// The environment variable ESKIN_KERNEL_ISA=generic|avx2 caps the choice (read at each call).
TileFn select_tile_kernel() noexcept;
TileSumFn select_tile_sum_kernel() noexcept;
TileDotFn select_tile_dot_kernel() noexcept;

/// Name of the variant select_tile_kernel() returns ("avx512", "avx2-fma" or "generic").
const char* tile_kernel_name() noexcept;

}  // namespace eskin
