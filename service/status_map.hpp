// The one place where core/engine status codes become transport codes.
#pragma once

#include "spokemesh/status.hpp"

namespace spokemesh::service {

// spokemesh::Code values are gRPC's canonical codes, so gRPC needs only a cast
// (grpc::StatusCode(static_cast<int>(code))). HTTP follows Google's published
// mapping (google.rpc.Code).
inline int http_status(Code code) {
  switch (code) {
    case Code::kOk:
      return 200;
    case Code::kCancelled:
      return 499;
    case Code::kInvalidArgument:
      return 400;
    case Code::kFailedPrecondition:
      return 400;
    case Code::kOutOfRange:
      return 400;
    case Code::kDeadlineExceeded:
      return 504;
    case Code::kNotFound:
      return 404;
    case Code::kAlreadyExists:
      return 409;
    case Code::kResourceExhausted:
      return 429;
    case Code::kUnimplemented:
      return 501;
    case Code::kUnavailable:
      return 503;
    case Code::kUnauthenticated:
      return 401;
    case Code::kInternal:
      return 500;
  }
  return 500;
}

// The HTTP status of a whole Status: its code, refined by its reason where HTTP has a
// more specific status (507 Insufficient Storage for a full data volume, 503 with
// Retry-After when the memory budget is spent).
inline int http_status(const Status& s) {
  if (s.code() == Code::kResourceExhausted && s.reason() == "STORAGE_FULL") return 507;
  // The memory budget is the server's state, not the client's quota: retry later.
  if (s.code() == Code::kResourceExhausted && s.reason() == "OVER_BUDGET") return 503;
  return http_status(s.code());
}

}  // namespace spokemesh::service
