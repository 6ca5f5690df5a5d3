#pragma once
// TLS on the farm's gRPC channels. The coordinator presents a certificate (--tls-cert,
// --tls-key) and may require one from every client (--tls-client-ca: signed by that CA);
// workers and `pbgi` check the coordinator's certificate against a CA (--tls-ca) and may
// present their own (--tls-cert, --tls-key). Without these files the farm speaks plaintext,
// as before. The farm token is required either way (farm_auth.h).
// deploy/tls/make-certs.sh makes a CA, a server and a worker certificate.
#include <cstdint>
#include <memory>
#include <optional>
#include <string>

#include <absl/status/statusor.h>

namespace grpc {
class ChannelCredentials;
}

namespace pbgi::farm {

// The files one end names: its own certificate (chain) and key, and the CA it trusts to sign
// the other end's certificate.
struct TlsFiles {
  std::string cert;
  std::string key;
  std::string ca;
};

// PEM text read from TlsFiles and checked: each parses, and the key is the certificate's.
struct TlsPem {
  std::string cert;  // empty for a client without a certificate of its own
  std::string key;
  std::string ca;  // a server's: the clients' CA (empty: no client certificates asked)
};

// The coordinator's: nullopt (plaintext) when no file is named. InvalidArgument naming the
// flag for a certificate without its key, a client CA without a certificate, a file that
// cannot be read or is not PEM, a key that is not the certificate's. A certificate that has
// expired (or is not valid yet) is only logged: clients will refuse it, and say so.
absl::StatusOr<std::optional<TlsPem>> readServerTls(const TlsFiles& files);
// A client's: nullopt when no file is named; a certificate needs its key and the CA.
absl::StatusOr<std::optional<TlsPem>> readClientTls(const TlsFiles& files);

// A client channel's credentials: TLS with `tls`, plaintext without.
std::shared_ptr<grpc::ChannelCredentials> channelCredentials(const std::optional<TlsPem>& tls);

// Why a connection to `address` ("host:port") fails at TLS, found by a handshake of our own
// with the same trust and certificate (gRPC says only "certificate verify failed" or "Socket
// closed"): the coordinator speaks TLS to a plaintext client, or plaintext to a TLS one; its
// certificate has expired, is not signed by the CA, does not name the host; it asks for a
// client certificate and there is none, or it refused the one sent. nullopt when the
// handshake shows nothing wrong or the coordinator cannot be reached.
std::optional<std::string> diagnoseTls(const std::string& address,
                                       const std::optional<TlsPem>& tls);

// Server-side TLS handshakes that failed in this process: a plaintext client, a client that
// refused the certificate (a wrong CA, an expired certificate), a missing or refused client
// certificate. gRPC 1.51 reports them only in its log, so watchTlsHandshakes() routes gRPC's
// log through ours (at gRPC's own verbosity, GRPC_VERBOSITY) and counts its server
// transport's "Handshaking failed" lines. Process-wide; idempotent.
void watchTlsHandshakes();
uint64_t tlsHandshakeFailures();

}  // namespace pbgi::farm
