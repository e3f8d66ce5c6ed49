// Bindings for the protocol concern (placeholder until its issue lands).
#include "bindings.hpp"

namespace eskin::bindings {
void bind_protocol(pybind11::module_& /*m*/) {}
}  // namespace eskin::bindings
