// libFuzzer harness of eskin-fw-sim's replay reader (firmware_sim/replay_source.cpp): .eskr
// replay images and .npy arrays from memory. Whatever it accepts is read in full (every sample,
// segment and name), so ASan sees any size that the checks let past the bytes present.
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <string>

#include "replay_source.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  eskin::fwsim::ReplaySource src;
  std::string error;
  // (n, taxels) .npy arrays need a grid: 4x4, the demo's
  if (!src.open_bytes(data, size, 4, 4, error)) {
    if (error.empty()) std::abort();  // a refusal always says why
    return 0;
  }
  std::uint64_t h = 0;
  for (std::uint64_t i = 0; i < src.n_samples(); ++i)
    for (std::size_t k = 0; k < src.taxels(); ++k) h += static_cast<std::uint16_t>(src.sample(i)[k]);
  for (const auto& s : src.segments()) {
    if (s.start + s.length > src.n_samples()) std::abort();
    h += s.length;
  }
  for (const auto& n : src.class_names()) h += n.size();
  if (h == 0x9E3779B97F4A7C15ull) std::abort();  // keeps the reads
  return 0;
}
