// Private to the model classifier: the subspace-overlap micro-kernel of the inference path,
//   ov = sum_{k < alpha, l < alpha} (b_k . x_l)^2,
// with b_k, x_l the columns of two N x alpha_stride column-major basis blocks (only their first
// alpha columns are used). Kept in its own translation unit (model_overlap.cpp), free of Eigen
// and std templates, so that its AVX2/FMA variant (a function-level target attribute, not
// -march) cannot leak wider instructions into code shared with the rest of the library.
#pragma once

#include <cstddef>
#include <cstdint>

namespace eskin::detail {

using OverlapF32 = double (*)(const float* b, const float* x, std::size_t n,
                              std::size_t alpha) noexcept;
using OverlapF64 = double (*)(const double* b, const double* x, std::size_t n,
                              std::size_t alpha) noexcept;

/// Plain dot products sum_i a_i b_i (float products accumulated as in the overlap kernels).
using DotF32 = double (*)(const float* a, const float* b, std::size_t n) noexcept;
using DotF64 = double (*)(const double* a, const double* b, std::size_t n) noexcept;

/// The controller's overlap (the device build's choice): float sums over register tiles of up
/// to 4 x 4 dot products (model_overlap.cpp); on any build, for the tests.
double overlap_f32_tiled(const float* b, const float* x, std::size_t n,
                         std::size_t alpha) noexcept;

/// The overlaps of `count` support vectors with one input (the host's path of a mode without
/// projections): support vector sv[t]'s N x alpha_stride block at bases + sv[t] * block, its
/// overlap into out[t]. The same dot products as the single overlap of this CPU, bit for bit
/// (their squares summed in double in another order); one call per mode, and the AVX2 variant
/// reads each stored column once per decision and prefetches the blocks ahead.
using OverlapsF32 = void (*)(const float* bases, std::size_t block, const std::uint32_t* sv,
                             std::size_t count, const float* x, std::size_t n,
                             std::size_t alpha, double* out) noexcept;

/// Best variants for this CPU (AVX2+FMA on x86 when available; ESKIN_KERNEL_ISA=generic forces
/// the portable ones).
OverlapF32 select_overlap_f32() noexcept;
OverlapF64 select_overlap_f64() noexcept;
DotF32 select_dot_f32() noexcept;
#if !defined(ESKIN_DEVICE)
OverlapsF32 select_overlaps_f32() noexcept;
#endif
DotF64 select_dot_f64() noexcept;
const char* overlap_kernel_name() noexcept;

}  // namespace eskin::detail
