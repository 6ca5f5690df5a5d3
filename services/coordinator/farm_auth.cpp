#include "services/coordinator/farm_auth.h"

#include <string_view>

#include <grpc/grpc_security.h>
#include <grpcpp/security/server_credentials.h>

#include "core/util/check.h"
#include "core/util/log.h"

namespace pbgi::farm {

namespace {

std::string_view view(const grpc_slice& slice) {
  return {reinterpret_cast<const char*>(GRPC_SLICE_START_PTR(slice)), GRPC_SLICE_LENGTH(slice)};
}

// Who called, as far as the handshake says: the client certificate's name, else the transport.
std::string caller(const grpc_auth_context* context) {
  std::string transport = "unknown";
  std::string name;
  grpc_auth_property_iterator it = grpc_auth_context_property_iterator(context);
  while (const grpc_auth_property* p = grpc_auth_property_iterator_next(&it)) {
    const std::string_view key(p->name);
    if (key == GRPC_TRANSPORT_SECURITY_TYPE_PROPERTY_NAME)
      transport.assign(p->value, p->value_length);
    if (key == GRPC_X509_CN_PROPERTY_NAME) name.assign(p->value, p->value_length);
  }
  if (!name.empty()) return "CN=" + name;
  if (transport == "ssl") return "a TLS client";
  return transport == "insecure" ? "a plaintext client" : "a client over " + transport;
}

struct TokenCheck {
  std::string token;
  bool openReads = false;
  std::shared_ptr<metrics::Counter> refused;
};

void checkToken(void* state, grpc_auth_context* context, const grpc_metadata* md, size_t count,
                grpc_process_auth_metadata_done_cb done, void* user) {
  const auto& check = *static_cast<const TokenCheck*>(state);
  std::string_view method = "?";
  bool ok = false;
  for (size_t i = 0; i < count; ++i) {
    const std::string_view key = view(md[i].key);
    if (key == "authorization") ok = bearsToken(view(md[i].value), check.token);
    if (key == ":path") method = view(md[i].value);
  }
  if (ok || (check.openReads && isReadCall(method))) {
    done(user, nullptr, 0, nullptr, 0, GRPC_STATUS_OK, nullptr);
    return;
  }
  check.refused->add();
  log::warn("refused peer={} call={}: missing or wrong farm token", caller(context), method);
  done(user, nullptr, 0, nullptr, 0, GRPC_STATUS_UNAUTHENTICATED,
       isReadCall(method)
           ? "this coordinator's reads need the farm token (it runs with --read-access token; "
             "pass --token-file FILE or set PBGI_TOKEN)"
           : "the farm token is missing or wrong (authorization: Bearer <token>)");
}

// A ServerCredentials over core credentials that carry the token check. gRPC 1.51's own
// ServerCredentials subclasses are private; this one only binds ports with the C API.
grpc_server_credentials* coreCredentials(const std::optional<TlsPem>& tls) {
  if (!tls) return grpc_insecure_server_credentials_create();
  grpc_ssl_pem_key_cert_pair pair{tls->key.c_str(), tls->cert.c_str()};
  return grpc_ssl_server_credentials_create_ex(
      tls->ca.empty() ? nullptr : tls->ca.c_str(), &pair, 1,
      tls->ca.empty() ? GRPC_SSL_DONT_REQUEST_CLIENT_CERTIFICATE
                      : GRPC_SSL_REQUEST_AND_REQUIRE_CLIENT_CERTIFICATE_AND_VERIFY,
      nullptr);
}

class CheckedCredentials final : public grpc::ServerCredentials {
 public:
  // The core credentials are made here, after the base class has initialised gRPC.
  CheckedCredentials(const std::optional<TlsPem>& tls, std::string token, bool openReads,
                     std::shared_ptr<metrics::Counter> refused)
      : core_(coreCredentials(tls)) {
    PBGI_CHECK(core_ != nullptr);
    auto* check = new TokenCheck{std::move(token), openReads, std::move(refused)};
    grpc_server_credentials_set_auth_metadata_processor(
        core_, {checkToken, [](void* state) { delete static_cast<TokenCheck*>(state); }, check});
  }
  ~CheckedCredentials() override { grpc_server_credentials_release(core_); }

  // The token check is the processor; there is no second one to add.
  void SetAuthMetadataProcessor(const std::shared_ptr<grpc::AuthMetadataProcessor>&) override {
    PBGI_CHECK(false);
  }

 private:
  int AddPortToServer(const std::string& address, grpc_server* server) override {
    return grpc_server_add_http2_port(server, address.c_str(), core_);
  }

  grpc_server_credentials* core_;
};

}  // namespace

bool sameToken(std::string_view given, std::string_view token) {
  if (token.empty() || given.size() != token.size()) return false;
  unsigned char diff = 0;
  for (size_t i = 0; i < given.size(); ++i) diff |= given[i] ^ token[i];
  return diff == 0;
}

bool bearsToken(std::string_view authorization, std::string_view token) {
  constexpr std::string_view kPrefix = "Bearer ";
  if (!authorization.starts_with(kPrefix)) return false;
  return sameToken(authorization.substr(kPrefix.size()), token);
}

bool isReadCall(std::string_view path) {
  constexpr std::string_view kService = "/pbgi.farm.v1.Coordinator/";
  if (!path.starts_with(kService)) return false;
  const std::string_view call = path.substr(kService.size());
  return call == "GetStatus" || call == "GetLogs" || call == "ListWorkers";
}

std::shared_ptr<grpc::ServerCredentials> coordinatorCredentials(
    const std::optional<TlsPem>& tls, std::string token, bool openReads,
    std::shared_ptr<metrics::Counter> refused) {
  return std::make_shared<CheckedCredentials>(tls, std::move(token), openReads, std::move(refused));
}

}  // namespace pbgi::farm
