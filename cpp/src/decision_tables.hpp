// Private to the model: the read-only tables of the decision path that depend only on the
// model, built once when a model is loaded and shared (std::shared_ptr) by every Classifier and
// StreamClassifier of that model and of its copies, instead of one copy per classifier.
//
// Machines are grouped by their alpha triple: the per-mode distances of a support vector depend
// only on it, so they are computed once per (group, support vector) and shared by the machines.
// Modes with few basis rows (N_z < alpha_z^2, e.g. the time mode: N = rows*cols = 16) use
// projections: ||V_i^T V_x||_F^2 = <P_i, P_x>_F with P = V V^T (N x N), precomputed here for the
// support vectors: one N^2 dot per support vector instead of alpha^2 N. A controller leaves them
// out (kProjectionCache): its RAM is the scarcer (they would double a small model's RAM).
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <vector>

namespace eskin {
class Model;
namespace detail {

#if defined(ESKIN_DEVICE)
inline constexpr bool kProjectionCache = false;
#else
inline constexpr bool kProjectionCache = true;
#endif

struct DecisionTables {
  struct Group {
    std::array<int, 3> alpha{};
    std::vector<std::uint32_t> svs;  // support vectors used by the group's machines (sorted)
    std::array<bool, 3> proj{};      // mode z uses the projections below
    std::array<std::vector<double>, 3> p64;  // n_support x N x N (float64 models)
    std::array<std::vector<float>, 3> p32;   // n_support x N x N (float32 models)
  };
  std::vector<Group> groups;
  std::vector<std::size_t> machine_group;  // machine k -> its group
};

// P = sum_{k < a} v_k v_k^T of the N x A column-major block `v` (first a columns).
template <typename T, typename Out>
void projection(const T* v, std::size_t N, std::size_t a, Out* P) noexcept {
  for (std::size_t r = 0; r < N; ++r)
    for (std::size_t c = 0; c < N; ++c) {
      double acc = 0.0;
      for (std::size_t k = 0; k < a; ++k)
        acc += static_cast<double>(v[k * N + r]) * static_cast<double>(v[k * N + c]);
      P[r * N + c] = static_cast<Out>(acc);
    }
}

// The tables of a parsed model (allocates; called by the loader once the model is valid).
std::shared_ptr<const DecisionTables> build_decision_tables(const Model& m);

}  // namespace detail
}  // namespace eskin
