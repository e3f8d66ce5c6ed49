// Bindings for the model concern (placeholder until its issue lands).
#include "bindings.hpp"

namespace eskin::bindings {
void bind_model(pybind11::module_& /*m*/) {}
}  // namespace eskin::bindings
