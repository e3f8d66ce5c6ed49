// Bindings for the kernel concern (placeholder until its issue lands).
#include "bindings.hpp"

namespace eskin::bindings {
void bind_kernel(pybind11::module_& /*m*/) {}
}  // namespace eskin::bindings
