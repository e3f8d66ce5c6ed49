// Bindings for the preprocessing concern: array conversion and GIL release only; the
// algorithm lives in cpp/src/preprocess.cpp. The public API is python/eskin/preprocess.py.
#include <pybind11/numpy.h>
#include <pybind11/stl.h>

#include <cstring>
#include <stdexcept>
#include <string>
#include <vector>

#include "bindings.hpp"
#include "eskin/preprocess.hpp"

namespace py = pybind11;

namespace eskin::bindings {
namespace {

using F64 = py::array_t<double, py::array::c_style | py::array::forcecast>;
using I16 = py::array_t<int16_t, py::array::c_style>;
using I64 = py::array_t<int64_t, py::array::c_style | py::array::forcecast>;

WindowConfig config_from(const F64& a) {
  if (a.ndim() != 1) throw std::invalid_argument("config array must be 1-D");
  return window_config_from_array(a.data(), static_cast<std::size_t>(a.shape(0)));
}

// (n, 7) int64 [start, stop, onset, offset, truncated, found, stride] and (n,) energy
py::tuple windows_to_arrays(const std::vector<TouchWindow>& ws) {
  const auto n = static_cast<py::ssize_t>(ws.size());
  py::array_t<int64_t> info({n, py::ssize_t{7}});
  py::array_t<double> energy(n);
  auto I = info.mutable_unchecked<2>();
  auto E = energy.mutable_unchecked<1>();
  for (py::ssize_t i = 0; i < n; ++i) {
    const TouchWindow& w = ws[static_cast<std::size_t>(i)];
    I(i, 0) = w.start;
    I(i, 1) = w.stop;
    I(i, 2) = w.onset;
    I(i, 3) = w.offset;
    I(i, 4) = w.truncated ? 1 : 0;
    I(i, 5) = w.found ? 1 : 0;
    I(i, 6) = w.stride;
    E(i) = w.energy;
  }
  return py::make_tuple(info, energy);
}

struct Batch {
  int64_t n, K, T;
  const int64_t* lengths;
};

Batch batch_shape(const py::array& a, const py::object& lengths, I64& len_arr) {
  if (a.ndim() != 3) throw std::invalid_argument("signals must be (n, n_taxels, T)");
  Batch b{a.shape(0), a.shape(1), a.shape(2), nullptr};
  if (!lengths.is_none()) {
    len_arr = I64::ensure(lengths);
    if (!len_arr || len_arr.ndim() != 1 || len_arr.shape(0) != b.n) {
      throw std::invalid_argument("lengths must be a 1-D array of " + std::to_string(b.n) +
                                  " integers");
    }
    b.lengths = len_arr.data();
  }
  return b;
}

bool is_int16(const py::array& a) { return a.dtype().is(py::dtype::of<int16_t>()); }

py::tuple detect_windows_py(const py::array& signals, const py::object& lengths, double rate,
                            const F64& config, int n_threads) {
  const WindowConfig cfg = config_from(config);
  I64 len_arr;
  const Batch b = batch_shape(signals, lengths, len_arr);
  std::vector<TouchWindow> ws;
  if (is_int16(signals)) {
    I16 x = I16::ensure(signals);
    py::gil_scoped_release release;
    ws = detect_windows(x.data(), b.n, b.K, b.T, b.lengths, rate, cfg, n_threads);
  } else {
    F64 x = F64::ensure(signals);
    py::gil_scoped_release release;
    ws = detect_windows(x.data(), b.n, b.K, b.T, b.lengths, rate, cfg, n_threads);
  }
  return windows_to_arrays(ws);
}

py::tuple preprocess_py(const py::array& signals, const py::object& lengths, int64_t D,
                        int window, int method, int short_policy, double rate, const F64& config,
                        const py::object& given, int n_threads) {
  PreprocessOptions opt;
  opt.D = D;
  if (window < 0 || window > 2) throw std::invalid_argument("window mode out of range");
  if (method < 0 || method > 1) throw std::invalid_argument("subsample method out of range");
  if (short_policy < 0 || short_policy > 1) {
    throw std::invalid_argument("short policy out of range");
  }
  opt.window = static_cast<WindowMode>(window);
  opt.method = static_cast<SubsampleMethod>(method);
  opt.short_policy = static_cast<ShortPolicy>(short_policy);
  opt.sample_rate_hz = rate;
  opt.config = config_from(config);
  opt.n_threads = n_threads;
  I64 len_arr;
  const Batch b = batch_shape(signals, lengths, len_arr);
  if (D < 1 || D > kMaxD) {  // before the output is allocated
    throw std::invalid_argument("D = " + std::to_string(D) + ": must be in [1, " +
                                std::to_string(kMaxD) + "]");
  }
  I64 given_arr;
  const int64_t* given_ptr = nullptr;
  if (!given.is_none()) {
    given_arr = I64::ensure(given);
    if (!given_arr || given_arr.ndim() != 2 || given_arr.shape(0) != b.n ||
        (given_arr.shape(1) != 2 && given_arr.shape(1) != 3)) {
      throw std::invalid_argument(
          "windows must be an (n, 2) [start, stop) or (n, 3) [start, stop, stride] integer array");
    }
    opt.given_strides = given_arr.shape(1) == 3;
    given_ptr = given_arr.data();
  }
  py::array_t<double> out({static_cast<py::ssize_t>(b.n), static_cast<py::ssize_t>(b.K),
                           static_cast<py::ssize_t>(D)});
  std::vector<TouchWindow> ws(static_cast<std::size_t>(b.n));
  double* o = out.mutable_data();
  if (is_int16(signals)) {
    I16 x = I16::ensure(signals);
    py::gil_scoped_release release;
    preprocess(x.data(), b.n, b.K, b.T, b.lengths, opt, o, ws.data(), given_ptr);
  } else {
    F64 x = F64::ensure(signals);
    py::gil_scoped_release release;
    preprocess(x.data(), b.n, b.K, b.T, b.lengths, opt, o, ws.data(), given_ptr);
  }
  py::tuple w = windows_to_arrays(ws);
  return py::make_tuple(out, w[0], w[1]);
}

// The streaming detector, with the subsampling settings used for each window's tensor.
class PyTouchDetector {
 public:
  PyTouchDetector(int64_t n_taxels, double rate, const F64& config, int64_t D, int method,
                  int short_policy)
      : det_(n_taxels, rate, config_from(config), true), D_(D),
        method_(static_cast<SubsampleMethod>(method)),
        short_(static_cast<ShortPolicy>(short_policy)) {
    if (method < 0 || method > 1) throw std::invalid_argument("subsample method out of range");
    if (short_policy < 0 || short_policy > 1) {
      throw std::invalid_argument("short policy out of range");
    }
    if (D < 0 || D > kMaxD) {  // 0: no tensors
      throw std::invalid_argument("D = " + std::to_string(D) + ": must be in [0, " +
                                  std::to_string(kMaxD) + "]");
    }
  }

  // block: (n, n_taxels) int16 or float64. Returns a list of completed windows, each a tuple
  // (start, stop, onset, offset, energy, truncated, tensor (n_taxels, D) or None).
  py::list push(const py::array& block) {
    if (block.ndim() != 2 || block.shape(1) != det_.n_taxels()) {
      throw std::invalid_argument("samples must be (n, " + std::to_string(det_.n_taxels()) + ")");
    }
    py::list found;
    if (is_int16(block)) {
      I16 x = I16::ensure(block);
      run(x.data(), x.shape(0), found);
    } else {
      F64 x = F64::ensure(block);
      run(x.data(), x.shape(0), found);
    }
    return found;
  }

  py::list flush() {
    py::list found;
    if (det_.flush() == Status::kWindow) found.append(window_tuple());
    return found;
  }

  void reset() { det_.reset(); }
  const TouchDetector& det() const { return det_; }

 private:
  template <class T>
  void run(const T* data, int64_t n, py::list& found) {
    int64_t done = 0;
    while (done < n) {
      int64_t consumed = 0;
      Status st;
      {
        py::gil_scoped_release release;
        st = det_.push_block(data + done * det_.n_taxels(), n - done, &consumed);
      }
      done += consumed;
      if (st == Status::kWindow) {
        found.append(window_tuple());
      } else if (st == Status::kNonFiniteSample) {
        throw std::invalid_argument("samples[" + std::to_string(done - 1) +
                                    "] has a non-finite value (NaN or inf)");
      } else if (st != Status::kOk) {
        throw std::runtime_error(std::string("TouchDetector: ") + status_name(st));
      }
    }
  }

  py::tuple window_tuple() {
    const TouchWindow& w = det_.last_window();
    py::object tensor = py::none();
    if (D_ > 0) {
      py::array_t<double> t({static_cast<py::ssize_t>(det_.n_taxels()),
                             static_cast<py::ssize_t>(D_)});
      const Status st = det_.subsample_last_window(D_, method_, short_, t.mutable_data());
      if (st == Status::kOk) tensor = t;
    }
    return py::make_tuple(w.start, w.stop, w.onset, w.offset, w.energy, w.truncated, tensor,
                          w.stride);
  }

  TouchDetector det_;
  int64_t D_;
  SubsampleMethod method_;
  ShortPolicy short_;
};

}  // namespace

void bind_preprocess(py::module_& m) {
  m.attr("WINDOW_CONFIG_FIELDS") = [] {
    py::list names;
    for (const char* s : window_config_field_names()) names.append(s);
    return names;
  }();
  m.def("window_config_defaults", [] {
    const auto a = window_config_to_array(WindowConfig{});
    py::array_t<double> out(static_cast<py::ssize_t>(a.size()));
    std::memcpy(out.mutable_data(), a.data(), a.size() * sizeof(double));
    return out;
  });
  m.def(
      "window_config_resolve",
      [](const F64& config, double rate) {
        const DetectorParams p = resolve_window_config(config_from(config), rate);
        py::dict d;
        d["frame_len"] = p.frame_len;
        d["dc_alpha"] = p.dc_alpha;
        d["noise_frames"] = p.noise_frames;
        d["warmup_frames"] = p.warmup_frames;
        d["hold_frames"] = p.hold_frames;
        d["lookback_frames"] = p.lookback_frames;
        d["min_duration"] = p.min_duration;
        d["pad_before"] = p.pad_before;
        d["pad_after"] = p.pad_after;
        d["max_window"] = p.max_window;
        d["window_capacity"] = p.window_capacity;
        return d;
      },
      py::arg("config"), py::arg("sample_rate_hz"));
  m.def("detect_windows", &detect_windows_py, py::arg("signals"), py::arg("lengths"),
        py::arg("sample_rate_hz"), py::arg("config"), py::arg("n_threads") = 0);
  m.def("preprocess", &preprocess_py, py::arg("signals"), py::arg("lengths"), py::arg("D"),
        py::arg("window"), py::arg("method"), py::arg("short_policy"),
        py::arg("sample_rate_hz"), py::arg("config"), py::arg("windows") = py::none(),
        py::arg("n_threads") = 0);
  m.def(
      "subsample_indices",
      [](int64_t S, int64_t D, int method) {
        if (D < 1 || S < D) {
          throw std::invalid_argument("subsample_indices needs 1 <= D <= S (S = " +
                                      std::to_string(S) + ", D = " + std::to_string(D) + ")");
        }
        py::array_t<int64_t> out(static_cast<py::ssize_t>(D));
        subsample_indices(S, D, static_cast<SubsampleMethod>(method), out.mutable_data());
        return out;
      },
      py::arg("S"), py::arg("D"), py::arg("method"));

  py::class_<PyTouchDetector>(m, "TouchDetector")
      .def(py::init<int64_t, double, const F64&, int64_t, int, int>(), py::arg("n_taxels"),
           py::arg("sample_rate_hz"), py::arg("config"), py::arg("D") = 0,
           py::arg("method") = 0, py::arg("short_policy") = 0)
      .def("push", &PyTouchDetector::push, py::arg("samples"))
      .def("flush", &PyTouchDetector::flush)
      .def("reset", &PyTouchDetector::reset)
      .def_property_readonly("samples_seen",
                             [](const PyTouchDetector& d) { return d.det().samples_seen(); })
      .def_property_readonly("in_touch",
                             [](const PyTouchDetector& d) { return d.det().in_touch(); })
      .def_property_readonly("ready", [](const PyTouchDetector& d) { return d.det().ready(); })
      .def_property_readonly("noise_floor",
                             [](const PyTouchDetector& d) { return d.det().noise_floor(); })
      .def_property_readonly("n_taxels",
                             [](const PyTouchDetector& d) { return d.det().n_taxels(); });
}

}  // namespace eskin::bindings
