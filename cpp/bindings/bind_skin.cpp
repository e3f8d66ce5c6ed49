// Bindings for the skin concern: the multi-patch engine (eskin::SkinEngine).
// Thin: converts arrays and errors; the work is in cpp/src/skin.cpp.
#include <pybind11/numpy.h>
#include <pybind11/stl.h>

#include <limits>
#include <memory>
#include <string>
#include <vector>

#include "bindings.hpp"
#include "eskin/model.hpp"
#include "eskin/skin.hpp"

namespace py = pybind11;

namespace eskin::bindings {

namespace {

using Codes = py::array_t<std::int16_t, py::array::c_style>;

// Collects the decisions of one call (the binding may allocate; the engine does not).
struct Rows : SkinSink {
  std::vector<SkinDecision> d;
  std::vector<std::vector<double>> values;
  void on_decision(const SkinDecision& x) noexcept override {
    d.push_back(x);
    values.emplace_back(x.values, x.values + x.n_machines);
  }
};

// The decisions as columns: patch, model, label, dont_know, confidence, window (n, 2), sample,
// event, position (n, 3; NaN without a layout), values (n, largest machine count; NaN padded).
py::dict columns(const Rows& r, std::size_t width) {
  const auto n = static_cast<py::ssize_t>(r.d.size());
  py::array_t<std::int32_t> patch(n), model(n), label(n);
  py::array_t<bool> dont_know(n);
  py::array_t<double> confidence(n), position({n, py::ssize_t{3}}),
      values({n, static_cast<py::ssize_t>(width)});
  py::array_t<std::int64_t> window({n, py::ssize_t{2}}), sample(n), event(n);
  const double nan = std::numeric_limits<double>::quiet_NaN();
  for (py::ssize_t i = 0; i < n; ++i) {
    const SkinDecision& d = r.d[static_cast<std::size_t>(i)];
    patch.mutable_at(i) = d.patch;
    model.mutable_at(i) = d.model;
    label.mutable_at(i) = d.label;
    dont_know.mutable_at(i) = d.dont_know;
    confidence.mutable_at(i) = d.confidence;
    window.mutable_at(i, 0) = d.window_start;
    window.mutable_at(i, 1) = d.window_stop;
    sample.mutable_at(i) = d.sample;
    event.mutable_at(i) = d.event;
    for (py::ssize_t z = 0; z < 3; ++z)
      position.mutable_at(i, z) = d.has_position ? d.position[static_cast<std::size_t>(z)] : nan;
    const auto& v = r.values[static_cast<std::size_t>(i)];
    for (std::size_t k = 0; k < width; ++k)
      values.mutable_at(i, static_cast<py::ssize_t>(k)) = k < v.size() ? v[k] : nan;
  }
  py::dict out;
  out["patch"] = patch;
  out["model"] = model;
  out["label"] = label;
  out["dont_know"] = dont_know;
  out["confidence"] = confidence;
  out["window"] = window;
  out["sample"] = sample;
  out["event"] = event;
  out["position"] = position;
  out["values"] = values;
  return out;
}

// The engine and the Python models it reads (kept alive as long as the engine).
class PySkinEngine {
 public:
  PySkinEngine(const py::list& models, std::vector<int> patch_model, int n_patches, int position_dims,
               std::vector<double> positions, std::vector<std::array<int, 2>> adjacency,
               std::int64_t chunk_samples, std::int64_t window_buffers,
               std::int64_t window_chunk_samples) {
    SkinConfig c;
    for (const py::handle h : models) {
      c.models.push_back(&h.cast<const Model&>());
      owners_.push_back(py::reinterpret_borrow<py::object>(h));
      width_ = std::max(width_, c.models.back()->machines().size());
    }
    c.patch_model = std::move(patch_model);
    c.n_patches = n_patches;
    c.position_dims = position_dims;
    c.positions = std::move(positions);
    c.adjacency = std::move(adjacency);
    c.chunk_samples = chunk_samples;
    c.window_buffers = window_buffers;
    c.window_chunk_samples = window_chunk_samples;
    engine_ = std::make_unique<SkinEngine>(c);
  }

  py::dict push(int patch, const Codes& samples) {
    this->patch(patch);
    const std::int64_t K = engine_->patch_taxels(patch);
    check(samples, K, "samples of patch " + std::to_string(patch));
    Rows r;
    {
      py::gil_scoped_release release;
      engine_->push_block(patch, samples.data(), samples.shape(0), &r);
    }
    return columns(r, width_);
  }

  py::dict push_interleaved(const Codes& block) {
    check(block, engine_->total_taxels(), "block");
    Rows r;
    {
      py::gil_scoped_release release;
      engine_->push_interleaved(block.data(), block.shape(0), &r);
    }
    return columns(r, width_);
  }

  py::dict flush() {
    Rows r;
    engine_->flush(&r);
    return columns(r, width_);
  }

  SkinEngine& engine() { return *engine_; }
  // a patch index checked for the per-patch getters
  int patch(int p) const {
    if (p < 0 || p >= engine_->n_patches())
      throw std::invalid_argument("patch = " + std::to_string(p) + ": must be in [0, " +
                                  std::to_string(engine_->n_patches()) + ")");
    return p;
  }

 private:
  static void check(const Codes& a, std::int64_t width, const std::string& what) {
    if (a.ndim() != 2 || a.shape(1) != width)
      throw std::invalid_argument(what + ": expected shape (n, " + std::to_string(width) +
                                  ") of int16 codes, got ndim " + std::to_string(a.ndim()) +
                                  (a.ndim() == 2 ? " width " + std::to_string(a.shape(1)) : ""));
  }
  std::vector<py::object> owners_;
  std::size_t width_ = 0;
  std::unique_ptr<SkinEngine> engine_;
};

}  // namespace

void bind_skin(py::module_& m) {
  py::class_<PySkinEngine>(m, "SkinEngine",
                           "Many patches, one host: per-patch detectors over shared models.")
      .def(py::init<const py::list&, std::vector<int>, int, int, std::vector<double>,
                    std::vector<std::array<int, 2>>, std::int64_t, std::int64_t, std::int64_t>(),
           py::arg("models"), py::arg("patch_model"), py::arg("n_patches"), py::arg("position_dims"),
           py::arg("positions"), py::arg("adjacency"), py::arg("chunk_samples"),
           py::arg("window_buffers") = 0, py::arg("window_chunk_samples") = 0)
      .def("push", &PySkinEngine::push, py::arg("patch"), py::arg("samples"),
           "Samples (n, taxels) int16 of one patch; returns the decisions as columns.")
      .def("push_interleaved", &PySkinEngine::push_interleaved, py::arg("block"),
           "Samples (n, total_taxels) int16 of every patch, patch after patch in each row.")
      .def("flush", &PySkinEngine::flush)
      .def("reset", [](PySkinEngine& e) { e.engine().reset(); })
      .def_property_readonly("n_patches", [](PySkinEngine& e) { return e.engine().n_patches(); })
      .def_property_readonly("total_taxels", [](PySkinEngine& e) { return e.engine().total_taxels(); })
      .def_property_readonly("bytes_per_patch", [](PySkinEngine& e) { return e.engine().bytes_per_patch(); })
      .def_property_readonly("dropped", [](PySkinEngine& e) { return e.engine().dropped(); })
      .def_property_readonly("unbuffered", [](PySkinEngine& e) { return e.engine().unbuffered(); })
      .def_property_readonly("window_buffers_peak",
                             [](PySkinEngine& e) { return e.engine().window_buffers_peak(); })
      .def_property_readonly("window_pool_size", [](PySkinEngine& e) { return e.engine().window_pool_size(); })
      .def_property_readonly("window_pool_in_use", [](PySkinEngine& e) { return e.engine().window_pool_in_use(); })
      .def_property_readonly("window_pool_samples",
                             [](PySkinEngine& e) { return e.engine().window_pool_samples(); })
      .def("patch_taxels", [](PySkinEngine& e, int p) { return e.engine().patch_taxels(e.patch(p)); }, py::arg("patch"))
      .def("taxel_offset", [](PySkinEngine& e, int p) { return e.engine().taxel_offset(e.patch(p)); }, py::arg("patch"))
      .def("patch_model", [](PySkinEngine& e, int p) { return e.engine().patch_model(e.patch(p)); }, py::arg("patch"))
      .def("samples_seen", [](PySkinEngine& e, int p) { return e.engine().samples_seen(e.patch(p)); }, py::arg("patch"))
      .def("in_touch", [](PySkinEngine& e, int p) { return e.engine().in_touch(e.patch(p)); }, py::arg("patch"));
}

}  // namespace eskin::bindings
