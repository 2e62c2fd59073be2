// spokemesh interpolate (interpolate.cpp): values at any point, locally.
#pragma once

#include <cmath>
#include <limits>
#include <string>

#include "commands.hpp"

namespace spokemesh::cli {

struct InterpolateFlags {
  std::string points, values, queries, output, method = "natural", grid;
  double fill = std::numeric_limits<double>::quiet_NaN();
  unsigned threads = 0;
  bool quiet = false;
};

int run_interpolate(const InterpolateFlags& flags);

}  // namespace spokemesh::cli
