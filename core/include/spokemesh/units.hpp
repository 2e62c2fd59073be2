// Durations and byte sizes as people type them on command lines ("500ms", "30s",
// "2m", "1h"; "512M", "4G", "1Gi"), shared by the CLI and the server.
//
// Thread safety: pure functions.
#pragma once

#include <chrono>
#include <cstdint>
#include <string>

#include "spokemesh/status.hpp"

namespace spokemesh {

// A positive duration: a number with an optional unit ms (the default), s, m or h.
// `flag` names the option in the error.
Result<std::chrono::milliseconds> parse_duration(const std::string& text, const std::string& flag);

// A positive size: a number with an optional unit K, M, G or T (powers of 1024; "Ki",
// "MB", "GiB" and lower case also accepted).
Result<std::uint64_t> parse_bytes(const std::string& text, const std::string& flag);

}  // namespace spokemesh
