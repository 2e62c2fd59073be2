// gRPC server interceptors: the checks that must run where no handler of ours does.
//
// ReflectionGuard: gRPC reflection describes the whole API, so with keys configured it
// needs one too. Its handler is gRPC's own, so a call without a valid key is cancelled
// when its metadata arrives, before the handler reads a message.
//
// DecodeGuard: a request whose bytes are not a valid protobuf encoding of the method's
// message never reaches our handler; gRPC answers INTERNAL with an empty message. The
// guard turns that answer into INVALID_ARGUMENT naming the method, as for any other bad
// request (every INTERNAL of ours carries a message, so an empty one is gRPC's decode
// failure). Found by tests/fuzz/fuzz_grpc_requests.cpp.
//
// Thread safety: the factories are shared by all calls and hold only immutable state;
// each interceptor belongs to one call.
#pragma once

#include <grpcpp/server_context.h>
#include <grpcpp/support/server_interceptor.h>

#include <memory>

#include "auth.hpp"

namespace spokemesh::service {

class ReflectionGuardFactory final : public grpc::experimental::ServerInterceptorFactoryInterface {
 public:
  explicit ReflectionGuardFactory(std::shared_ptr<const Authenticator> auth) : auth_(std::move(auth)) {}
  grpc::experimental::Interceptor* CreateServerInterceptor(grpc::experimental::ServerRpcInfo* info) override;

 private:
  std::shared_ptr<const Authenticator> auth_;
};

class DecodeGuardFactory final : public grpc::experimental::ServerInterceptorFactoryInterface {
 public:
  grpc::experimental::Interceptor* CreateServerInterceptor(grpc::experimental::ServerRpcInfo* info) override;
};

}  // namespace spokemesh::service
