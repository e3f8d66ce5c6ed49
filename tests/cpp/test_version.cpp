#include <gtest/gtest.h>

#include <algorithm>
#include <string>

#include "eskin/version.hpp"

TEST(Version, IsSemver) {
  const std::string v = eskin::kVersion;
  EXPECT_EQ(std::count(v.begin(), v.end(), '.'), 2);
}
