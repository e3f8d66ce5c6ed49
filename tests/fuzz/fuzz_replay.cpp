// libFuzzer harness of eskin-fw-sim's replay reader (firmware_sim/replay_source.cpp): .eskr
// replay images and .npy arrays from memory. Whatever it accepts is read in full (every sample,
// segment and name), so ASan sees any size that the checks let past the bytes present. The
// core's reader of the format (eskin/replay_format.hpp) is also run as the board runs it (the
// buffer an upper bound of the file), and every refusal is formatted.
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <string>

#include "eskin/replay_format.hpp"
#include "replay_source.hpp"

namespace {

void board_reader(const std::uint8_t* data, std::size_t size) {
  namespace rp = eskin::replay;
  rp::ReplayHeader h;
  rp::ReplayError e;
  if (rp::check_replay(data, size, rp::SizeRule::at_most, &h, &e) != rp::ReplayStatus::ok) {
    char line[256];
    if (rp::format_error(e, line, sizeof line)[0] == '\0') std::abort();
    return;
  }
  std::uint64_t sum = 0;
  const std::uint64_t n = h.n_samples * h.rows * h.cols;
  for (std::uint64_t i = 0; i < n; ++i) sum += static_cast<std::uint16_t>(h.samples[i]);
  for (std::uint32_t i = 0; i < h.n_segments; ++i) sum += rp::segment(h, i).length;
  for (std::uint32_t i = 0; i < h.names_len; ++i) sum += static_cast<unsigned char>(h.class_names[i]);
  if (sum == 0x9E3779B97F4A7C15ull) std::abort();
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  board_reader(data, size);
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
