// Bindings for the model concern: the .eskin loader, the classifier and the stream classifier.
// Thin: converts arrays and errors; the work is in cpp/src/model*.cpp.
#include <pybind11/numpy.h>
#include <pybind11/stl.h>

#include <chrono>
#include <cstring>
#include <limits>
#include <tuple>
#include <string>
#include <vector>

#include "bindings.hpp"
#include "eskin/model.hpp"
#include "eskin/tensor_kernel.hpp"

namespace py = pybind11;

namespace eskin::bindings {

namespace {

const char* rule_name(DecisionRule r) { return r == DecisionRule::kBinary ? "binary" : "one_vs_all"; }

// Classify n recordings (n, rows, cols, T) of one dtype; the GIL is released for the loop.
template <typename Scalar>
py::tuple classify_batch(Classifier& clf, py::array_t<Scalar, py::array::c_style | py::array::forcecast> a,
                         py::object lengths_obj) {
  if (a.ndim() != 4)
    throw std::invalid_argument("signals: expected shape (n, rows, cols, T), got ndim " +
                                std::to_string(a.ndim()));
  const Model& m = clf.model();
  const py::ssize_t n = a.shape(0), rows = a.shape(1), cols = a.shape(2), T = a.shape(3);
  if (rows != m.rows() || cols != m.cols())
    throw std::invalid_argument("signals: grid " + std::to_string(rows) + "x" + std::to_string(cols) +
                                " does not match the model's " + std::to_string(m.rows()) + "x" +
                                std::to_string(m.cols()));
  std::vector<std::int64_t> lengths(static_cast<std::size_t>(n), static_cast<std::int64_t>(T));
  if (!lengths_obj.is_none()) {
    auto l = py::array_t<std::int64_t, py::array::c_style | py::array::forcecast>::ensure(lengths_obj);
    if (!l || l.ndim() != 1 || l.shape(0) != n)
      throw std::invalid_argument("lengths: expected shape (" + std::to_string(n) + ",)");
    for (py::ssize_t i = 0; i < n; ++i) {
      const std::int64_t v = l.at(i);
      if (v < 1 || v > T)
        throw std::invalid_argument("lengths[" + std::to_string(i) + "] = " + std::to_string(v) +
                                    ": must be in [1, " + std::to_string(T) + "]");
      lengths[static_cast<std::size_t>(i)] = v;
    }
  }
  const std::size_t nm = m.machines().size();
  py::array_t<std::int32_t> labels(n), status(n);
  py::array_t<bool> dont_know(n), found(n);
  py::array_t<double> values({n, static_cast<py::ssize_t>(nm)}), confidence(n);
  py::array_t<std::int64_t> windows({n, py::ssize_t{2}});
  auto conf = confidence.mutable_unchecked<1>();
  auto lab = labels.mutable_unchecked<1>();
  auto st = status.mutable_unchecked<1>();
  auto dk = dont_know.mutable_unchecked<1>();
  auto fd = found.mutable_unchecked<1>();
  auto val = values.mutable_unchecked<2>();
  auto win = windows.mutable_unchecked<2>();
  const Scalar* data = a.data();
  {
    py::gil_scoped_release release;
    for (py::ssize_t i = 0; i < n; ++i) {
      Decision d;
      const ClassifyStatus s = clf.classify(data + i * rows * cols * T, static_cast<int>(rows),
                                            static_cast<int>(cols), T,
                                            lengths[static_cast<std::size_t>(i)], &d);
      st(i) = static_cast<std::int32_t>(s);
      const bool ok = s == ClassifyStatus::kOk;
      lab(i) = ok ? d.label : -1;
      dk(i) = ok && d.dont_know;
      conf(i) = ok ? d.confidence : std::numeric_limits<double>::quiet_NaN();
      fd(i) = ok && d.window_found;
      win(i, 0) = d.window_start;
      win(i, 1) = d.window_stop;
      for (std::size_t k = 0; k < nm; ++k)
        val(i, static_cast<py::ssize_t>(k)) = ok ? d.values[k] : std::numeric_limits<double>::quiet_NaN();
    }
  }
  return py::make_tuple(labels, values, dont_know, status, windows, found, confidence);
}

}  // namespace

void bind_model(py::module_& m) {
  static py::exception<ModelFormatError> exc(m, "ModelFormatError", PyExc_ValueError);
  py::register_exception_translator([](std::exception_ptr p) {
    try {
      if (p) std::rethrow_exception(p);
    } catch (const ModelFormatError& e) {
      PyErr_SetString(exc.ptr(), e.what());
    }
  });

  m.def(
      "model_pattern_bases",
      [](py::array_t<double, py::array::c_style | py::array::forcecast> x, std::vector<std::size_t> alphas) {
        if (x.ndim() != 4)
          throw std::invalid_argument("tensors: expected shape (n, rows, cols, D), got ndim " +
                                      std::to_string(x.ndim()));
        const py::ssize_t n = x.shape(0);
        BasisLayout layout({static_cast<std::size_t>(x.shape(1)), static_cast<std::size_t>(x.shape(2)),
                            static_cast<std::size_t>(x.shape(3))},
                           alphas);
        BasisWorkspace ws(layout);
        py::array_t<std::int32_t> ranks({n, py::ssize_t{3}});
        std::vector<py::array_t<double>> bases;
        for (std::size_t z = 0; z < 3; ++z)
          bases.emplace_back(std::vector<py::ssize_t>{n, static_cast<py::ssize_t>(layout.alpha(z)),
                                                      static_cast<py::ssize_t>(layout.cols(z))});
        std::vector<double> buf(layout.bases_size());
        const double* xd = x.data();
        auto rk = ranks.mutable_unchecked<2>();
        std::vector<double*> out;
        for (auto& b : bases) out.push_back(b.mutable_data());
        std::string err;
        {
          py::gil_scoped_release release;
          for (py::ssize_t i = 0; i < n && err.empty(); ++i) {
            int r[3];
            const KernelStatus s = ws.compute(xd + i * layout.tensor_size(), buf.data(), r);
            if (s != KernelStatus::ok) {
              err = "tensors[" + std::to_string(i) + "]: basis computation failed (" + to_string(s) + ")";
              break;
            }
            for (std::size_t z = 0; z < 3; ++z) {
              rk(i, static_cast<py::ssize_t>(z)) = r[z];
              const std::size_t sz = layout.alpha(z) * layout.cols(z);
              std::memcpy(out[z] + static_cast<std::size_t>(i) * sz, buf.data() + layout.offset(z),
                          sz * sizeof(double));
            }
          }
        }
        if (!err.empty()) throw std::invalid_argument(err);
        return py::make_tuple(ranks, bases);
      },
      py::arg("tensors"), py::arg("alphas"),
      "Per-mode bases of (n, rows, cols, D) tensors as the model classifier computes them: "
      "(ranks (n, 3), [bases of mode z (n, alpha_z, N_z)]).");

  py::class_<Model>(m, "Model", "A loaded, validated .eskin model (C++ eskin::Model).")
      .def_static("load", &Model::load, py::arg("path"))
      .def_static(
          "from_bytes",
          [](py::bytes b) {
            const std::string s = b;
            return Model::from_bytes(reinterpret_cast<const std::uint8_t*>(s.data()), s.size());
          },
          py::arg("data"))
      .def_property_readonly("rows", &Model::rows)
      .def_property_readonly("cols", &Model::cols)
      .def_property_readonly("D", &Model::D)
      .def_property_readonly("window", [](const Model& mm) {
        return mm.window_mode() == WindowMode::kEnergy ? "energy" : "none";
      })
      .def_property_readonly("subsample", [](const Model& mm) {
        return mm.subsample() == SubsampleMethod::kAlgorithm2 ? "algorithm2" : "even";
      })
      .def_property_readonly("short", [](const Model& mm) {
        return mm.short_policy() == ShortPolicy::kInterpolate ? "interpolate" : "error";
      })
      .def_property_readonly("sample_rate_hz", &Model::sample_rate_hz)
      .def_property_readonly("window_config", [](const Model& mm) {
        py::dict d;
        const auto names = window_config_field_names();
        const auto vals = window_config_to_array(mm.window_config());
        for (std::size_t i = 0; i < kWindowConfigSize; ++i) d[names[i]] = vals[i];
        return d;
      })
      .def_property_readonly("rule", [](const Model& mm) { return rule_name(mm.rule()); })
      .def_property_readonly("class_names", &Model::class_names)
      .def_property_readonly("is_float64", &Model::is_float64)
      .def_property_readonly("n_support", &Model::n_support)
      .def_property_readonly("alpha_store", [](const Model& mm) {
        return py::make_tuple(mm.alpha_store(0), mm.alpha_store(1), mm.alpha_store(2));
      })
      .def_property_readonly("file_bytes", &Model::file_bytes)
      .def_property_readonly("format_version", &Model::format_version,
                             "1 to 4, the version the model was written in")
      .def_property_readonly("calibrated", &Model::calibrated,
                             "True: the calibrated rule (CALB); False: the paper's rule")
      .def_property_readonly("reject_threshold", &Model::reject_threshold,
                             "the calibrated rule's threshold on the confidence (0 without CALB)")
      .def_property_readonly("sv_log_energy", &Model::sv_log_energy,
                             "log energy of each support vector (format version 2), else []")
      .def_property_readonly("machines", [](const Model& mm) {
        py::list out;
        for (const auto& k : mm.machines()) {
          py::dict d;
          d["positive"] = k.positive;
          d["negative"] = k.negative;
          d["intercept"] = k.intercept;
          d["alphas"] = py::make_tuple(k.alpha[0], k.alpha[1], k.alpha[2]);
          d["sigmas"] = py::make_tuple(k.sigma[0], k.sigma[1], k.sigma[2]);
          d["sv_index"] = k.sv_index;
          d["coef"] = k.coef;
          d["amplitude_width"] = k.amplitude_width;
          d["calib_slope"] = k.calib_slope;
          d["calib_offset"] = k.calib_offset;
          out.append(d);
        }
        return out;
      });

  py::class_<Classifier>(m, "Classifier",
                         "Runs a Model on raw recordings (keeps a reference to the model).")
      .def(py::init<const Model&>(), py::arg("model"), py::keep_alive<1, 2>())
      .def(
          "classify",
          [](Classifier& c, py::array signals, py::object lengths) -> py::tuple {
            if (py::isinstance<py::array_t<std::int16_t>>(signals))
              return classify_batch<std::int16_t>(c, signals, lengths);
            if (py::isinstance<py::array_t<float>>(signals))
              return classify_batch<float>(c, signals, lengths);
            return classify_batch<double>(c, signals, lengths);
          },
          py::arg("signals"), py::arg("lengths") = py::none(),
          "signals (n, rows, cols, T) int16/float32/float64 -> (labels, values (n, n_machines), "
          "dont_know, status, windows (n, 2), window_found, confidence); status 0 = ok; confidence "
          "NaN under the paper's rule.")
      .def(
          "classify_tensors",
          [](Classifier& c, py::array_t<double, py::array::c_style | py::array::forcecast> x) {
            const Model& mm = c.model();
            if (x.ndim() != 4 || x.shape(1) != mm.rows() || x.shape(2) != mm.cols() || x.shape(3) != mm.D())
              throw std::invalid_argument("tensors: expected shape (n, " + std::to_string(mm.rows()) +
                                          ", " + std::to_string(mm.cols()) + ", " +
                                          std::to_string(mm.D()) + ")");
            const py::ssize_t n = x.shape(0);
            const std::size_t nm = mm.machines().size();
            const std::size_t sz = static_cast<std::size_t>(mm.rows()) * mm.cols() * mm.D();
            py::array_t<std::int32_t> labels(n), status(n);
            py::array_t<bool> dont_know(n);
            py::array_t<double> values({n, static_cast<py::ssize_t>(nm)}), confidence(n);
            auto conf = confidence.mutable_unchecked<1>();
            auto lab = labels.mutable_unchecked<1>();
            auto st = status.mutable_unchecked<1>();
            auto dk = dont_know.mutable_unchecked<1>();
            auto val = values.mutable_unchecked<2>();
            const double* xd = x.data();
            {
              py::gil_scoped_release release;
              for (py::ssize_t i = 0; i < n; ++i) {
                Decision d;
                const ClassifyStatus s = c.classify_tensor(xd + static_cast<std::size_t>(i) * sz, &d);
                const bool ok = s == ClassifyStatus::kOk;
                st(i) = static_cast<std::int32_t>(s);
                lab(i) = ok ? d.label : -1;
                dk(i) = ok && d.dont_know;
                conf(i) = ok ? d.confidence : std::numeric_limits<double>::quiet_NaN();
                for (std::size_t k = 0; k < nm; ++k)
                  val(i, static_cast<py::ssize_t>(k)) = ok ? d.values[k] : std::numeric_limits<double>::quiet_NaN();
              }
            }
            return py::make_tuple(labels, values, dont_know, status, confidence);
          },
          py::arg("tensors"))
      .def(
          "time_classify",
          [](Classifier& c, py::array_t<std::int16_t, py::array::c_style | py::array::forcecast> a,
             int repeats) {
            // Wall time of each classify() call (raw window -> label), in nanoseconds, measured
            // in C++ around the call alone: for benchmarks/bench_inference.py.
            const Model& mm = c.model();
            if (a.ndim() != 4 || a.shape(1) != mm.rows() || a.shape(2) != mm.cols())
              throw std::invalid_argument("signals: expected shape (n, rows, cols, T)");
            const py::ssize_t n = a.shape(0), T = a.shape(3);
            const std::size_t per = static_cast<std::size_t>(mm.rows() * mm.cols() * T);
            py::array_t<double> ns(n * repeats);
            auto out = ns.mutable_unchecked<1>();
            const std::int16_t* d = a.data();
            {
              py::gil_scoped_release release;
              for (int r = 0; r < repeats; ++r)
                for (py::ssize_t i = 0; i < n; ++i) {
                  Decision dec;
                  const auto t0 = std::chrono::steady_clock::now();
                  c.classify(d + static_cast<std::size_t>(i) * per, mm.rows(), mm.cols(), T, T, &dec);
                  const auto t1 = std::chrono::steady_clock::now();
                  out(r * n + i) = std::chrono::duration<double, std::nano>(t1 - t0).count();
                }
            }
            return ns;
          },
          py::arg("signals"), py::arg("repeats") = 1)
      .def(
          "time_classify_tensors",
          [](Classifier& c, py::array_t<double, py::array::c_style | py::array::forcecast> x,
             int repeats) {
            // Wall time of each classify_tensor() call (bases + machines), in nanoseconds;
            // each tensor is classified `repeats` times in a row (warm caches).
            const Model& mm = c.model();
            if (x.ndim() != 4 || x.shape(1) != mm.rows() || x.shape(2) != mm.cols() || x.shape(3) != mm.D())
              throw std::invalid_argument("tensors: expected shape (n, rows, cols, D)");
            const py::ssize_t n = x.shape(0);
            const std::size_t sz = static_cast<std::size_t>(mm.rows()) * mm.cols() * mm.D();
            py::array_t<double> ns(n * repeats);
            auto out = ns.mutable_unchecked<1>();
            const double* d = x.data();
            {
              py::gil_scoped_release release;
              for (py::ssize_t i = 0; i < n; ++i)
                for (int r = 0; r < repeats; ++r) {
                  Decision dec;
                  const auto t0 = std::chrono::steady_clock::now();
                  c.classify_tensor(d + static_cast<std::size_t>(i) * sz, &dec);
                  const auto t1 = std::chrono::steady_clock::now();
                  out(i * repeats + r) = std::chrono::duration<double, std::nano>(t1 - t0).count();
                }
            }
            return ns;
          },
          py::arg("tensors"), py::arg("repeats") = 1);

  py::class_<StreamClassifier>(m, "StreamClassifier",
                               "The controller's path: one multi-taxel sample at a time.")
      .def(py::init<const Model&>(), py::arg("model"), py::keep_alive<1, 2>())
      .def(
          "feed",
          [](StreamClassifier& sc, py::array_t<double, py::array::c_style | py::array::forcecast> a,
             bool flush, bool timed) {
            // a: (n_samples, n_taxels) sample-major
            if (a.ndim() != 2 || a.shape(1) != sc.detector().n_taxels())
              throw std::invalid_argument("samples: expected shape (n, " +
                                          std::to_string(sc.detector().n_taxels()) + ")");
            std::vector<std::tuple<std::int64_t, int, ClassifyStatus, Decision, std::vector<double>, double>> events;
            double push_ns = 0.0;
            const double* p = a.data();
            const py::ssize_t n = a.shape(0), nt = a.shape(1);
            {
              py::gil_scoped_release release;
              auto record = [&](ClassifyStatus s) {
                if (s == ClassifyStatus::kOk) return;
                const Decision& d = sc.decision();
                std::vector<double> v;
                if (s == ClassifyStatus::kDecision) v.assign(d.values, d.values + d.n_machines);
                events.emplace_back(sc.samples_seen(), static_cast<int>(s), s, d, std::move(v), push_ns);
              };
              for (py::ssize_t i = 0; i < n; ++i) {
                if (!timed) {
                  record(sc.push(p + i * nt));
                  continue;
                }
                const auto t0 = std::chrono::steady_clock::now();
                const ClassifyStatus s = sc.push(p + i * nt);
                push_ns = std::chrono::duration<double, std::nano>(std::chrono::steady_clock::now() - t0).count();
                record(s);
              }
              if (flush) record(sc.flush());
            }
            py::list out;
            for (const auto& e : events) {
              py::dict d;
              d["sample"] = std::get<0>(e);
              d["status"] = std::get<1>(e);
              d["status_name"] = to_string(std::get<2>(e));
              if (timed) d["push_ns"] = std::get<5>(e);
              const Decision& dec = std::get<3>(e);
              if (std::get<2>(e) == ClassifyStatus::kDecision) {
                d["label"] = dec.label;
                d["dont_know"] = dec.dont_know;
                d["confidence"] = dec.confidence;
                d["values"] = std::get<4>(e);
                d["window"] = py::make_tuple(dec.window_start, dec.window_stop);
              }
              out.append(d);
            }
            return out;
          },
          py::arg("samples"), py::arg("flush") = false, py::arg("timed") = false,
          "Push samples (n, n_taxels); returns the events (decisions and errors) as dicts "
          "(timed: with the wall time of the push that produced each event, push_ns).")
      .def("reset", &StreamClassifier::reset)
      .def_property_readonly("samples_seen", &StreamClassifier::samples_seen)
      .def_property_readonly("in_touch", &StreamClassifier::in_touch);

  m.attr("MODEL_FORMAT_VERSION") = model_format::kVersion;
  m.def("model_overlap_kernel", &overlap_kernel_name,
        "The overlap micro-kernel of the model classifier on this CPU.");
}

}  // namespace eskin::bindings
