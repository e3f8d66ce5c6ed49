// The module definition only: one bind_<concern>() call per concern.
#include "bindings.hpp"

#ifndef ESKIN_VERSION
#define ESKIN_VERSION "dev"
#endif

PYBIND11_MODULE(_core, m) {
  m.doc() = "eskin compiled core (C++17/Eigen); use the public API in the eskin package";
  m.attr("__version__") = ESKIN_VERSION;
  eskin::bindings::bind_kernel(m);
  eskin::bindings::bind_preprocess(m);
  eskin::bindings::bind_model(m);
  eskin::bindings::bind_protocol(m);
  eskin::bindings::bind_serial(m);
  eskin::bindings::bind_skin(m);
}
