#include "eskin/version.hpp"
