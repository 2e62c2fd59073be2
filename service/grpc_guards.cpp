#include "grpc_guards.hpp"

#include <string>
#include <string_view>

namespace spokemesh::service {
namespace {

using grpc::experimental::InterceptionHookPoints;

class ReflectionGuard final : public grpc::experimental::Interceptor {
 public:
  ReflectionGuard(grpc::experimental::ServerRpcInfo* info, const Authenticator& auth) : info_(info), auth_(auth) {}
  void Intercept(grpc::experimental::InterceptorBatchMethods* methods) override {
    if (methods->QueryInterceptionHookPoint(InterceptionHookPoints::POST_RECV_INITIAL_METADATA)) {
      std::string_view presented;
      if (auto* md = methods->GetRecvInitialMetadata()) {
        if (auto it = md->find("authorization"); it != md->end()) presented = {it->second.data(), it->second.size()};
      }
      if (!auth_.authenticate(presented, "'authorization' metadata").is_ok()) info_->server_context()->TryCancel();
    }
    methods->Proceed();
  }

 private:
  grpc::experimental::ServerRpcInfo* info_;
  const Authenticator& auth_;
};

class DecodeGuard final : public grpc::experimental::Interceptor {
 public:
  explicit DecodeGuard(grpc::experimental::ServerRpcInfo* info) : info_(info) {}
  void Intercept(grpc::experimental::InterceptorBatchMethods* methods) override {
    if (methods->QueryInterceptionHookPoint(InterceptionHookPoints::PRE_SEND_STATUS)) {
      const grpc::Status s = methods->GetSendStatus();
      if (s.error_code() == grpc::StatusCode::INTERNAL && s.error_message().empty()) {
        methods->ModifySendStatus(
            grpc::Status(grpc::StatusCode::INVALID_ARGUMENT,
                         std::string("request: the message is not a valid protobuf encoding of ") + info_->method() +
                             "'s request type (see proto/spokemesh/v1/mesher.proto)"));
      }
    }
    methods->Proceed();
  }

 private:
  grpc::experimental::ServerRpcInfo* info_;
};

}  // namespace

grpc::experimental::Interceptor* ReflectionGuardFactory::CreateServerInterceptor(
    grpc::experimental::ServerRpcInfo* info) {
  if (std::string_view(info->method()).rfind("/grpc.reflection.", 0) != 0) return nullptr;
  return new ReflectionGuard(info, *auth_);
}

grpc::experimental::Interceptor* DecodeGuardFactory::CreateServerInterceptor(grpc::experimental::ServerRpcInfo* info) {
  if (std::string_view(info->method()).rfind("/spokemesh.", 0) != 0) return nullptr;
  return new DecodeGuard(info);
}

}  // namespace spokemesh::service
