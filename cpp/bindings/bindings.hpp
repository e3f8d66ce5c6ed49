// Declarations of the per-concern binding functions; each lives in its own bind_<concern>.cpp.
// Binding code is thin: it converts arrays and errors, and holds no algorithm.
#pragma once
#include <pybind11/pybind11.h>

namespace eskin::bindings {
void bind_kernel(pybind11::module_& m);
void bind_preprocess(pybind11::module_& m);
void bind_model(pybind11::module_& m);
void bind_protocol(pybind11::module_& m);
void bind_serial(pybind11::module_& m);
void bind_skin(pybind11::module_& m);
}  // namespace eskin::bindings
