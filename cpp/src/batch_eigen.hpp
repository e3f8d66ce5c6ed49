// Private to the tensor kernel: symmetric eigen-decomposition of kEigenLanes small matrices at
// once, one matrix per SIMD lane (Householder tridiagonalisation + implicit QL, after the
// public-domain JAMA/EISPACK tred2/tql2).
//
// Why lanes: a 16 x 16 solve is bound by the latency of its serial steps (each QL rotation waits
// for a square root and a division), not by arithmetic. Solving eight patterns' matrices side by
// side shares that latency among them; the arithmetic of the eigenvector updates then fills the
// vector units. Every lane computes exactly what it would compute alone (no cross-lane
// operation, no lane-dependent step count), so a pattern's result does not depend on its batch
// mates or on its lane: the single-pattern path and the batch path give identical bits.
//
// Differences from the scalar EISPACK tql2: no search for a split point (every sweep runs from
// the bottom of the matrix; an exactly zero subdiagonal entry gives an identity rotation), and
// each lane deflates at its own index l: a sweep runs up to the smallest l of the lanes still
// iterating, and a lane's rotations above its own l are identities. Eigenvalues are not sorted;
// the caller sorts each lane.
// No allocation, no exception.
#pragma once

#include <cstddef>

namespace eskin {

/// Matrices solved together (one per lane).
constexpr std::size_t kEigenLanes = 8;

/// Lane-interleaved layout: entry (r, c) of lane l's n x n matrix at a[(r * n + c) * kEigenLanes
/// + l]. On entry lanes 0..used-1 of `a` hold symmetric matrices; the other lanes may hold
/// anything (they are not solved, and cost nothing when they are NaN). On exit row j of lane l's matrix (entries (j, 0..n-1)) is the unit
/// eigenvector of eigenvalue d[j * kEigenLanes + l]; eigenvalues are in no particular order.
/// `e` is scratch of 3 * n * kEigenLanes doubles. Returns a bit mask of the lanes whose QL
/// iteration did not converge or met a non-finite value (0 on success).
/// `level` picks the instruction set (2 AVX-512, 1 AVX2+FMA, 0 baseline), capped by what the CPU
/// has and by ESKIN_KERNEL_ISA=generic|avx2 (isa_level(), tensor_kernel_tile.hpp); -1: the best
/// one. Only lanes 0..used-1 are solved (the others are reported as not failed; their contents
/// on exit are unspecified): a single matrix takes a narrow lane group. A lane's result does not
/// depend on `used` either.
unsigned batch_symmetric_eigen(std::size_t n, double* a, double* d, double* e, int level = -1,
                               std::size_t used = kEigenLanes) noexcept;

}  // namespace eskin
