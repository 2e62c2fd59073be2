// The JSON body of a REST upload, read as it is parsed.
//
// nlohmann's SAX interface drives a small state machine instead of building a DOM:
// coordinates go straight into one float64 array, nesting is refused past the three
// levels an upload has (the object, "points", a point), and the first error stops the
// parse. So a hostile body costs at most its own size plus the coordinates it holds
// (no DOM of 50-100 bytes per number, no recursion on deep nesting: a body nested
// 60,000 levels deep once crashed the server through the DOM's recursive dump).
//
// Accepted bodies:
//   {"points": [[x, y, ...], ...], "display_name": "..."}
//   {"dimension": d, "coordinates": [x0, y0, ..., x1, y1, ...], "display_name": "..."}
// either with "weights": [w0, w1, ...] (one power weight per point) and
// "periodic_box": [LO_1, .., LO_d, HI_1, .., HI_d].
// Unknown keys are ignored if their values are scalars or shallow.
//
// Thread safety: a function; no shared state.
#pragma once

#include <cstddef>
#include <string>
#include <string_view>
#include <vector>

#include "engine.hpp"

namespace spokemesh::service {

// The deepest nesting an upload body may have: object -> "points" -> point.
inline constexpr int kMaxUploadJsonDepth = 3;

// Reads `body` into header (dimension, count, display_name, weighted, periodic_box),
// coords (row-major) and weights (empty unless given; charged with the coordinates).
// The limits' point count (and point count times dimension limit for "coordinates")
// stop an oversized upload as soon as it is known to be one.
// Errors: INVALID_ARGUMENT naming the field and index (e.g. "points[3][1]: expected a
// number, got \"x\""), or the byte offset of a syntax error; RESOURCE_EXHAUSTED past
// the limits. `charge`, if given, grows with coords' capacity: RESOURCE_EXHAUSTED
// (reason OVER_BUDGET) when the server's memory budget cannot take it.
Status read_upload_json(std::string_view body, const Limits& limits, UploadHeader& header, std::vector<double>& coords,
                        std::vector<double>& weights, MemoryBudget::Charge* charge = nullptr,
                        const MemoryBudget* budget = nullptr);

}  // namespace spokemesh::service
