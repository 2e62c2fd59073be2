// Values as people type them on command lines and in query strings: durations
// ("500ms", "30s", "2m", "1h"), byte sizes ("512M", "4G", "1Gi") and lists of numbers
// ("0,0,1.5"), shared by the CLI and the server.
//
// Thread safety: pure functions.
#pragma once

#include <chrono>
#include <cstdint>
#include <string>
#include <vector>

#include "spokemesh/status.hpp"

namespace spokemesh {

// A positive duration: a number with an optional unit ms (the default), s, m or h.
// `flag` names the option in the error.
Result<std::chrono::milliseconds> parse_duration(const std::string& text, const std::string& flag);

// A positive size: a number with an optional unit K, M, G or T (powers of 1024; "Ki",
// "MB", "GiB" and lower case also accepted).
Result<std::uint64_t> parse_bytes(const std::string& text, const std::string& flag);

// Comma-separated finite numbers ("0,0,1.5"); errors name `what` and the value's index.
Result<std::vector<double>> parse_number_list(const std::string& text, const std::string& what, std::size_t max_count);

}  // namespace spokemesh
