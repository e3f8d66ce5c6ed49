#pragma once

namespace eskin {
/// Library version, kept in step with pyproject.toml and CMakeLists.txt.
inline constexpr const char* kVersion = "0.1.0";
}  // namespace eskin
