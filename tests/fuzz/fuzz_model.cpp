// libFuzzer harness of the .eskin model loader (cpp/src/model_format.cpp), and of the classifiers
// built from whatever model it accepts.
//
// The input is a model file whose size field and CRC-32 the harness rewrites to match, so that
// mutations get past the checksum to the structural and value checks (a stale checksum is a
// one-line rejection, covered by tests/cpp/test_model.cpp). Anything but a ModelFormatError
// escaping, a sanitizer report, an allocation over libFuzzer's -malloc_limit_mb or a slow input
// is a finding, and so is a broken property of an accepted model (a trap):
// * the copy (from_bytes) and the view (view_bytes, bases left in the input) of the same bytes
//   decide the same, to the bit;
// * a decision names one of the model's classes (or is a don't-know of one-vs-all), has one
//   value per machine, and every value is finite.
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <vector>

#include "eskin/model.hpp"

namespace {

void require(bool ok) {
  if (!ok) __builtin_trap();
}

struct Outcome {
  eskin::ClassifyStatus status;
  eskin::Decision d;
  std::vector<double> values;
};

Outcome decide(const eskin::Model& m, eskin::Classifier& clf, const std::vector<std::int16_t>& x,
               std::int64_t T) {
  Outcome o{};
  o.status = clf.classify(x.data(), m.rows(), m.cols(), T, T, &o.d);
  if (o.d.values != nullptr && o.d.n_machines > 0) o.values.assign(o.d.values, o.d.values + o.d.n_machines);
  return o;
}

void check_decision(const eskin::Model& m, const eskin::Decision& d) {
  const int n_classes = static_cast<int>(m.class_names().size());
  require(d.n_machines == static_cast<int>(m.machines().size()));
  require(d.dont_know ? m.rule() == eskin::DecisionRule::kOneVsAll || d.label >= 0
                      : d.label >= 0 && d.label < n_classes);
  for (int i = 0; i < d.n_machines; ++i) require(std::isfinite(d.values[i]));
}

}  // namespace

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
    const eskin::Model view = eskin::Model::view_bytes(b.data(), b.size());  // accepted too
    // an accepted model must run: a batch decision on a short recording, and a stream
    eskin::Classifier clf(m), clf_view(view);
    const std::int64_t T = 2 * m.D() + 64;
    std::vector<std::int16_t> x(static_cast<std::size_t>(m.rows()) * m.cols() * T);
    for (std::size_t i = 0; i < x.size(); ++i) x[i] = static_cast<std::int16_t>((i * 2654435761u) >> 20);
    const Outcome a = decide(m, clf, x, T), v = decide(view, clf_view, x, T);
    require(a.status == v.status && a.d.label == v.d.label && a.d.dont_know == v.d.dont_know);
    require(a.values.size() == v.values.size() &&
            (a.values.empty() ||
             std::memcmp(a.values.data(), v.values.data(), a.values.size() * sizeof(double)) == 0));
    if (a.status == eskin::ClassifyStatus::kOk) check_decision(m, a.d);
    eskin::StreamClassifier stream(m);
    std::vector<std::int16_t> sample(static_cast<std::size_t>(m.rows()) * m.cols());
    for (int t = 0; t < 256; ++t) {
      for (std::size_t k = 0; k < sample.size(); ++k)
        sample[k] = static_cast<std::int16_t>(t % 7 == 0 ? 3000 : (t * 31 + static_cast<int>(k)) % 50);
      if (stream.push(sample.data()) == eskin::ClassifyStatus::kDecision)
        check_decision(m, stream.decision());
    }
    if (stream.flush() == eskin::ClassifyStatus::kDecision) check_decision(m, stream.decision());
  } catch (const eskin::ModelFormatError&) {
  }
  return 0;
}
