// Bindings for the tensor kernel (eskin/tensor_kernel.hpp): array conversion and GIL release only.
#include <pybind11/numpy.h>
#include <pybind11/stl.h>

#include <memory>
#include <string>
#include <vector>

#include "bindings.hpp"
#include "eskin/tensor_kernel.hpp"

namespace py = pybind11;

namespace eskin::bindings {
namespace {

using CArray = py::array_t<double, py::array::c_style | py::array::forcecast>;

std::vector<std::size_t> pattern_dims(const CArray& x) {
  if (x.ndim() < 1) throw std::invalid_argument("X must have a leading pattern axis");
  std::vector<std::size_t> dims;
  for (py::ssize_t i = 1; i < x.ndim(); ++i) dims.push_back(std::size_t(x.shape(i)));
  return dims;
}

std::shared_ptr<PatternBases> compute_bases(const CArray& x, const std::vector<std::size_t>& alphas,
                                            int n_threads) {
  BasisLayout layout(pattern_dims(x), alphas);
  const double* data = x.data();
  const std::size_t n = std::size_t(x.shape(0));
  py::gil_scoped_release release;
  return std::make_shared<PatternBases>(compute_pattern_bases(data, n, layout, n_threads));
}

py::array_t<double> mode_bases(const PatternBases& pb, std::size_t z) {
  const BasisLayout& L = pb.layout;
  if (z >= L.n_modes()) throw py::index_error("mode " + std::to_string(z) + " out of range");
  const std::size_t nn = L.cols(z), a = L.alpha(z);
  py::array_t<double> out({pb.count, nn, a});
  double* o = out.mutable_data();
  for (std::size_t i = 0; i < pb.count; ++i) {
    const double* src = pb.bases.data() + i * L.bases_size() + L.offset(z);
    for (std::size_t c = 0; c < a; ++c)
      for (std::size_t k = 0; k < nn; ++k) o[(i * nn + k) * a + c] = src[c * nn + k];
  }
  return out;
}

}  // namespace

void bind_kernel(py::module_& m) {
  py::class_<PatternBases, std::shared_ptr<PatternBases>>(
      m, "PatternBases", "Per-pattern, per-mode subspace bases of a set of tensor patterns")
      .def_property_readonly("count", [](const PatternBases& p) { return p.count; })
      .def_property_readonly("shape", [](const PatternBases& p) { return p.layout.dims(); })
      .def_property_readonly("alphas", [](const PatternBases& p) { return p.layout.alphas(); })
      .def_property_readonly("ranks",
                             [](const PatternBases& p) {
                               py::array_t<int> r({p.count, p.layout.n_modes()});
                               std::copy(p.ranks.begin(), p.ranks.end(), r.mutable_data());
                               return r;
                             })
      .def("mode_bases", &mode_bases, py::arg("mode"),
           "(n, N_z, alpha_z) array: the orthonormal bases of mode z, zero columns beyond the rank")
      .def("__len__", [](const PatternBases& p) { return p.count; });

  m.def("compute_pattern_bases", &compute_bases, py::arg("X"), py::arg("alphas"),
        py::arg("n_threads") = 0);
  m.def(
      "mode_distances",
      [](const PatternBases& a, const PatternBases* b, int n_threads, std::size_t max_bytes) {
        const std::size_t mm = b ? b->count : a.count;
        // the plan first: a limit too small is an error before the output is allocated
        plan_distances(a.layout, a.count, mm, b == nullptr, max_bytes);
        py::array_t<double> out({a.layout.n_modes(), a.count, mm});
        double* o = out.mutable_data();
        {
          py::gil_scoped_release release;
          mode_distances(a, b, o, n_threads, max_bytes);
        }
        return out;
      },
      py::arg("a"), py::arg("b") = nullptr, py::arg("n_threads") = 0, py::arg("max_bytes") = 0);
  m.def(
      "plan_distances",
      [](const std::vector<std::size_t>& dims, const std::vector<std::size_t>& alphas,
         std::size_t n, std::size_t mm, bool self, std::size_t max_bytes) {
        const DistancePlan p = plan_distances(BasisLayout(dims, alphas), n, mm, self, max_bytes);
        py::dict d;
        d["block"] = p.block;
        d["row_blocks"] = p.row_blocks;
        d["col_blocks"] = p.col_blocks;
        d["pack_bytes"] = p.pack_bytes;
        d["pattern_bytes"] = p.pattern_bytes;
        d["bases_only"] = p.bases_only;
        return d;
      },
      py::arg("dims"), py::arg("alphas"), py::arg("n"), py::arg("m"), py::arg("self"),
      py::arg("max_bytes") = 0,
      "The scratch-memory plan of mode_distances (blocks of patterns packed at once).");
  m.def(
      "tensor_kernel",
      [](const PatternBases& a, const PatternBases* b, const std::vector<double>& sigmas,
         int n_threads) {
        const std::size_t mm = b ? b->count : a.count;
        py::array_t<double> out({a.count, mm});
        double* o = out.mutable_data();
        {
          py::gil_scoped_release release;
          tensor_kernel(a, b, sigmas, o, n_threads);
        }
        return out;
      },
      py::arg("a"), py::arg("b").none(true), py::arg("sigmas"), py::arg("n_threads") = 0);
  m.def("full_alphas", &full_alphas, py::arg("dims"));
  m.def("half_alphas", &half_alphas, py::arg("dims"));
  m.def(
      "unfold",
      [](const CArray& x, std::size_t mode) {
        std::vector<std::size_t> dims(x.shape(), x.shape() + x.ndim());
        std::size_t size = 1;
        for (auto d : dims) size *= d;
        if (mode >= dims.size())
          throw std::invalid_argument("mode " + std::to_string(mode) + " out of range");
        const std::size_t rows = dims[mode];
        py::array_t<double> out({rows, rows ? size / rows : 0});
        unfold(x.data(), dims, mode, out.mutable_data());
        return out;
      },
      py::arg("x"), py::arg("mode"));
  m.def("tensor_kernel_isa", &tensor_kernel_isa);
  m.def("default_threads", &default_threads);

  // The heap-free single-pattern path, exposed so that tests can check parity with the batch path.
  py::class_<BasisWorkspace>(m, "BasisWorkspace")
      .def(py::init([](const std::vector<std::size_t>& dims, const std::vector<std::size_t>& alphas) {
             return BasisWorkspace(BasisLayout(dims, alphas));
           }),
           py::arg("dims"), py::arg("alphas"))
      .def("compute", [](BasisWorkspace& ws, const CArray& x) {
        const BasisLayout& L = ws.layout();
        if (std::size_t(x.size()) != L.tensor_size())
          throw std::invalid_argument("x has " + std::to_string(x.size()) + " values, expected " +
                                      std::to_string(L.tensor_size()));
        py::array_t<double> bases(py::ssize_t(L.bases_size()));
        py::array_t<int> ranks(py::ssize_t(L.n_modes()));
        const KernelStatus st = ws.compute(x.data(), bases.mutable_data(), ranks.mutable_data());
        return py::make_tuple(bases, ranks, std::string(to_string(st)));
      });
}

}  // namespace eskin::bindings
