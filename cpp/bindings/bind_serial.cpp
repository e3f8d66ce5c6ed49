// Bindings for the serial concern (placeholder until its issue lands).
#include "bindings.hpp"

namespace eskin::bindings {
void bind_serial(pybind11::module_& /*m*/) {}
}  // namespace eskin::bindings
