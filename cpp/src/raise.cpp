// The default fatal-error handler of builds without exceptions (see raise.hpp).
#include "raise.hpp"

#include <cstdlib>

namespace eskin::detail {

__attribute__((weak)) void fatal_error(const char* /*what*/) noexcept { std::abort(); }

}  // namespace eskin::detail
