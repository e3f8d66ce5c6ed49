// Bindings for the preprocess concern (placeholder until its issue lands).
#include "bindings.hpp"

namespace eskin::bindings {
void bind_preprocess(pybind11::module_& /*m*/) {}
}  // namespace eskin::bindings
