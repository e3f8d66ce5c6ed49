// Private to the core: how construction and batch code report a bad argument. The host build
// throws the standard exception named (std::invalid_argument -> ValueError in Python, ...). A
// build without exceptions (the Cortex-M device build, -fno-exceptions) cannot throw: there the
// same call hands the message to eskin::detail::fatal_error, which does not return (its default
// calls std::abort; a firmware defines its own to report the message and reset). The per-sample
// and per-decision paths never get here: they return status codes.
#pragma once

#include <string>

namespace eskin::detail {

/// Builds without exceptions only: report `what` and stop. Weak default: std::abort().
[[noreturn]] void fatal_error(const char* what) noexcept;

template <class E>
[[noreturn]] inline void raise(const std::string& what) {
#if defined(__cpp_exceptions)
  throw E(what);
#else
  fatal_error(what.c_str());
#endif
}

}  // namespace eskin::detail
