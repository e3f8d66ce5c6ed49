// libFuzzer harness of the .eskin model loader (cpp/src/model_format.cpp), and of the classifiers
// built from whatever model it accepts.
//
// The input is a model file whose size field and CRC-32 the harness rewrites to match, so that
// mutations get past the checksum to the structural and value checks (a stale checksum is a
// one-line rejection, covered by tests/cpp/test_model.cpp). Anything but a ModelFormatError
// escaping, a sanitizer report, an allocation over libFuzzer's -malloc_limit_mb or a slow input
// is a finding.
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <vector>

#include "eskin/model.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  std::vector<std::uint8_t> b(data, data + size);
  if (b.size() >= 36) {
    const auto n = static_cast<std::uint32_t>(b.size());
    for (int i = 0; i < 4; ++i) b[16 + i] = static_cast<std::uint8_t>(n >> (8 * i));
    const std::uint32_t crc = eskin::model_format::crc32(b.data(), b.size() - 4);
    for (int i = 0; i < 4; ++i) b[b.size() - 4 + i] = static_cast<std::uint8_t>(crc >> (8 * i));
  }
  try {
    const eskin::Model m = eskin::Model::from_bytes(b.data(), b.size());
    // an accepted model must run: a batch decision on a short recording, and a stream
    eskin::Classifier clf(m);
    const std::int64_t T = 2 * m.D() + 64;
    std::vector<std::int16_t> x(static_cast<std::size_t>(m.rows()) * m.cols() * T);
    for (std::size_t i = 0; i < x.size(); ++i) x[i] = static_cast<std::int16_t>((i * 2654435761u) >> 20);
    eskin::Decision d;
    (void)clf.classify(x.data(), m.rows(), m.cols(), T, T, &d);
    eskin::StreamClassifier stream(m);
    std::vector<std::int16_t> sample(static_cast<std::size_t>(m.rows()) * m.cols());
    for (int t = 0; t < 256; ++t) {
      for (std::size_t k = 0; k < sample.size(); ++k)
        sample[k] = static_cast<std::int16_t>(t % 7 == 0 ? 3000 : (t * 31 + static_cast<int>(k)) % 50);
      (void)stream.push(sample.data());
    }
    (void)stream.flush();
  } catch (const eskin::ModelFormatError&) {
  }
  return 0;
}
