// libFuzzer harness of the core's .npy reader (cpp/src/npy.cpp): header parsing, the declared
// sizes against the limits, and the file size check. For an accepted header the declared data
// is read in full, so ASan sees any size that got past the checks.
#include <cstddef>
#include <cstdint>
#include <cstdlib>

#include "eskin/npy.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  try {
    const eskin::NpyHeader h = eskin::parse_npy_header(data, size, "fuzz.npy");
    if (h.data_offset > size || h.data_bytes > eskin::kNpyMaxDataBytes) std::abort();
    eskin::check_npy_file_size(h, size, "fuzz.npy");
    std::uint64_t sum = 0;
    for (std::uint64_t i = 0; i < h.data_bytes; ++i) sum += data[h.data_offset + i];
    if (sum == 0x9E3779B97F4A7C15ull) std::abort();  // keeps the reads
  } catch (const eskin::NpyError&) {
  }
  return 0;
}
