#pragma once
// Who may call the coordinator: every call carries the farm token ("authorization: Bearer
// <token>"), checked in one place, an auth metadata processor on the server's credentials
// (plaintext or TLS). gRPC runs it on a call's metadata before any handler, so a refused call
// reaches no RPC (it gets UNAUTHENTICATED, is counted and logged).
//
// Why not a server interceptor (grpc::experimental::ServerInterceptorFactoryInterface): in
// gRPC 1.51 an interceptor can rewrite the status a call ends with, but the handler runs
// anyway (a refused SubmitJob would still submit; tried). And grpc::AuthMetadataProcessor
// through ServerCredentials::SetAuthMetadataProcessor aborts on InsecureServerCredentials
// ("assertion failed" in insecure_server_credentials.cc), while plaintext farms stay. So the
// processor is installed with gRPC's C API on the core credentials, TLS or insecure, which
// both support it; coordinatorCredentials() hands them to the ServerBuilder.
#include <memory>
#include <optional>
#include <string>

#include "services/coordinator/metrics.h"
#include "services/farm/farm_tls.h"

namespace grpc {
class ServerCredentials;
}

namespace pbgi::farm {

// "authorization: Bearer <token>" with this token; tokens of equal length compare in a time
// that does not depend on where they differ.
bool bearsToken(std::string_view authorization, std::string_view token);
// `token` equal to `expected`, in a time that does not depend on where they differ.
bool sameToken(std::string_view token, std::string_view expected);

// The calls that only read (GetStatus, GetLogs, ListWorkers), by their gRPC path.
bool isReadCall(std::string_view path);

// The coordinator's listening credentials: TLS with `tls` (client certificates required when
// it names a CA), plaintext without; either way every call must bear `token`, but reads
// (isReadCall) when `openReads`. A refused call adds one to `refused` (shared: gRPC may hold
// the credentials after the coordinator).
std::shared_ptr<grpc::ServerCredentials> coordinatorCredentials(
    const std::optional<TlsPem>& tls, std::string token, bool openReads,
    std::shared_ptr<metrics::Counter> refused);

}  // namespace pbgi::farm
