#include "services/farm/farm_tls.h"

#include <atomic>
#include <cerrno>
#include <cstdlib>
#include <fstream>
#include <mutex>
#include <sstream>
#include <string_view>
#include <vector>

#include <arpa/inet.h>
#include <fcntl.h>
#include <netdb.h>
#include <poll.h>
#include <sys/socket.h>
#include <sys/time.h>
#include <unistd.h>

#include <fmt/format.h>
#include <grpc/support/log.h>
#include <grpcpp/security/credentials.h>
#include <openssl/err.h>
#include <openssl/pem.h>
#include <openssl/ssl.h>
#include <openssl/x509.h>
#include <openssl/x509v3.h>

#include "core/util/log.h"
#include "core/util/status.h"

namespace pbgi::farm {

namespace {

template <auto Free>
struct Freer {
  template <typename T>
  void operator()(T* p) const {
    Free(p);
  }
};
using Bio = std::unique_ptr<BIO, Freer<BIO_free>>;
using Cert = std::unique_ptr<X509, Freer<X509_free>>;
using Key = std::unique_ptr<EVP_PKEY, Freer<EVP_PKEY_free>>;
using SslContext = std::unique_ptr<SSL_CTX, Freer<SSL_CTX_free>>;
using Ssl = std::unique_ptr<SSL, Freer<SSL_free>>;

absl::StatusOr<std::string> readFile(const std::string& path, std::string_view flag) {
  std::ifstream in(path, std::ios::binary);
  if (!in)
    return absl::InvalidArgumentError(fmt::format("{} {}: cannot read the file", flag, path));
  std::stringstream text;
  text << in.rdbuf();
  return text.str();
}

// Every certificate of a PEM text, in order; InvalidArgument when there is none.
absl::StatusOr<std::vector<Cert>> certificates(const std::string& pem, const std::string& path,
                                               std::string_view flag) {
  Bio bio(BIO_new_mem_buf(pem.data(), static_cast<int>(pem.size())));
  std::vector<Cert> certs;
  while (X509* c = PEM_read_bio_X509(bio.get(), nullptr, nullptr, nullptr)) certs.emplace_back(c);
  ERR_clear_error();  // the end of the text reads as an error
  if (certs.empty()) {
    return absl::InvalidArgumentError(fmt::format(
        "{} {}: expected PEM certificates (-----BEGIN CERTIFICATE-----), found none", flag, path));
  }
  return certs;
}

std::string nameText(const X509_NAME* name) {
  Bio bio(BIO_new(BIO_s_mem()));
  X509_NAME_print_ex(bio.get(), name, 0, XN_FLAG_RFC2253);
  char* data = nullptr;
  const long size = BIO_get_mem_data(bio.get(), &data);
  return std::string(data, static_cast<size_t>(size));
}

std::string timeText(const ASN1_TIME* time) {
  Bio bio(BIO_new(BIO_s_mem()));
  ASN1_TIME_print(bio.get(), time);
  char* data = nullptr;
  const long size = BIO_get_mem_data(bio.get(), &data);
  return std::string(data, static_cast<size_t>(size));
}

// "CN=pbgi-coordinator, issued by CN=pbgi farm CA"
std::string describe(X509* cert) {
  return fmt::format("{}, issued by {}", nameText(X509_get_subject_name(cert)),
                     nameText(X509_get_issuer_name(cert)));
}

// The key in `pem` is `cert`'s.
absl::StatusOr<Key> keyOf(X509* cert, const std::string& pem, const TlsFiles& files,
                          std::string_view keyFlag, std::string_view certFlag) {
  Bio bio(BIO_new_mem_buf(pem.data(), static_cast<int>(pem.size())));
  Key key(PEM_read_bio_PrivateKey(bio.get(), nullptr, nullptr, nullptr));
  ERR_clear_error();
  if (key == nullptr) {
    return absl::InvalidArgumentError(fmt::format(
        "{} {}: expected a PEM private key without a passphrase, found none", keyFlag, files.key));
  }
  if (X509_check_private_key(cert, key.get()) != 1) {
    ERR_clear_error();
    return absl::InvalidArgumentError(fmt::format("{} {} is not the key of {} {} ({})", keyFlag,
                                                  files.key, certFlag, files.cert, describe(cert)));
  }
  return key;
}

void warnUnlessValidNow(X509* cert, const std::string& path, std::string_view whose,
                        std::string_view consequence) {
  if (X509_cmp_current_time(X509_get0_notAfter(cert)) < 0) {
    log::warn("{} {} ({}) expired on {}: {}", whose, path, describe(cert),
              timeText(X509_get0_notAfter(cert)), consequence);
  } else if (X509_cmp_current_time(X509_get0_notBefore(cert)) > 0) {
    log::warn("{} {} ({}) is not valid until {}: {}", whose, path, describe(cert),
              timeText(X509_get0_notBefore(cert)), consequence);
  }
}

// ---- diagnosis ----

struct HostPort {
  std::string host;
  std::string port;
};

std::optional<HostPort> splitAddress(std::string_view address) {
  for (const std::string_view scheme : {"dns:///", "ipv4:", "ipv6:"}) {
    if (address.starts_with(scheme)) address.remove_prefix(scheme.size());
  }
  if (address.starts_with("[")) {
    const size_t close = address.find(']');
    if (close == std::string_view::npos || close + 1 >= address.size() ||
        address[close + 1] != ':') {
      return std::nullopt;
    }
    return HostPort{std::string(address.substr(1, close - 1)),
                    std::string(address.substr(close + 2))};
  }
  const size_t colon = address.rfind(':');
  if (colon == std::string_view::npos) return std::nullopt;
  return HostPort{std::string(address.substr(0, colon)), std::string(address.substr(colon + 1))};
}

bool isIpAddress(const std::string& host) {
  unsigned char buffer[sizeof(in6_addr)];
  return inet_pton(AF_INET, host.c_str(), buffer) == 1 ||
         inet_pton(AF_INET6, host.c_str(), buffer) == 1;
}

// A connected TCP socket whose reads and writes give up after `seconds`; -1 when none.
int connectTcp(const HostPort& to, int seconds) {
  addrinfo hints{};
  hints.ai_socktype = SOCK_STREAM;
  addrinfo* found = nullptr;
  if (::getaddrinfo(to.host.c_str(), to.port.c_str(), &hints, &found) != 0) return -1;
  int connected = -1;
  for (addrinfo* a = found; a != nullptr && connected < 0; a = a->ai_next) {
    const int fd =
        ::socket(a->ai_family, a->ai_socktype | SOCK_NONBLOCK | SOCK_CLOEXEC, a->ai_protocol);
    if (fd < 0) continue;
    bool ok = ::connect(fd, a->ai_addr, a->ai_addrlen) == 0;
    if (!ok && errno == EINPROGRESS) {
      pollfd p{fd, POLLOUT, 0};
      int error = 0;
      socklen_t length = sizeof error;
      ok = ::poll(&p, 1, seconds * 1000) == 1 &&
           ::getsockopt(fd, SOL_SOCKET, SO_ERROR, &error, &length) == 0 && error == 0;
    }
    if (!ok) {
      ::close(fd);
      continue;
    }
    ::fcntl(fd, F_SETFL, ::fcntl(fd, F_GETFL) & ~O_NONBLOCK);
    const timeval timeout{seconds, 0};
    ::setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &timeout, sizeof timeout);
    ::setsockopt(fd, SOL_SOCKET, SO_SNDTIMEO, &timeout, sizeof timeout);
    connected = fd;
  }
  ::freeaddrinfo(found);
  return connected;
}

// What one handshake showed.
struct Probe {
  Cert cert;  // ours, offered when the server asks
  Key key;
  bool serverCertSeen = false;
  Cert serverCert;  // the server's own (the chain's first)
  bool certRequested = false;
  int verifyError = X509_V_OK;  // the first one
  Cert badCert;                 // the certificate it was about
};

int onVerify(int ok, X509_STORE_CTX* store) {
  SSL* ssl =
      static_cast<SSL*>(X509_STORE_CTX_get_ex_data(store, SSL_get_ex_data_X509_STORE_CTX_idx()));
  Probe* probe = static_cast<Probe*>(SSL_get_app_data(ssl));
  probe->serverCertSeen = true;
  if (probe->serverCert == nullptr) {
    if (X509* leaf = X509_STORE_CTX_get0_cert(store); leaf != nullptr) {
      X509_up_ref(leaf);
      probe->serverCert.reset(leaf);
    }
  }
  if (ok == 0 && probe->verifyError == X509_V_OK) {
    probe->verifyError = X509_STORE_CTX_get_error(store);
    if (X509* c = X509_STORE_CTX_get_current_cert(store); c != nullptr) {
      X509_up_ref(c);
      probe->badCert.reset(c);
    }
  }
  return 1;  // go on: what the server does next is part of the diagnosis
}

int onCertificateRequest(SSL* ssl, X509** cert, EVP_PKEY** key) {
  Probe* probe = static_cast<Probe*>(SSL_get_app_data(ssl));
  probe->certRequested = true;
  if (probe->cert == nullptr) return 0;
  X509_up_ref(probe->cert.get());
  EVP_PKEY_up_ref(probe->key.get());
  *cert = probe->cert.get();
  *key = probe->key.get();
  return 1;
}

std::string verifyProblem(const Probe& probe, const HostPort& to) {
  // The server's certificate, or the one of its chain that is wrong (an expired CA, say).
  X509* leaf = probe.serverCert.get();
  X509* cert = probe.badCert != nullptr ? probe.badCert.get() : leaf;
  std::string who = leaf != nullptr ? fmt::format(" ({})", describe(leaf)) : "";
  if (cert != nullptr && cert != leaf && X509_cmp(cert, leaf) != 0) {
    who = fmt::format(" ({}; the trouble is {} in its chain)", describe(leaf), describe(cert));
  }
  switch (probe.verifyError) {
    case X509_V_ERR_CERT_HAS_EXPIRED:
      return fmt::format("its certificate{} expired on {}", who,
                         cert != nullptr ? timeText(X509_get0_notAfter(cert)) : "?");
    case X509_V_ERR_CERT_NOT_YET_VALID:
      return fmt::format("its certificate{} is not valid until {}", who,
                         cert != nullptr ? timeText(X509_get0_notBefore(cert)) : "?");
    case X509_V_ERR_HOSTNAME_MISMATCH:
    case X509_V_ERR_IP_ADDRESS_MISMATCH:
      return fmt::format(
          "its certificate{} does not name {} (make one that does: "
          "deploy/tls/make-certs.sh DIR {})",
          who, to.host, to.host);
    default:
      return fmt::format("its certificate{} does not verify against the CA of --tls-ca: {}", who,
                         X509_verify_cert_error_string(probe.verifyError));
  }
}

// Reads --tls-cert and --tls-key into pem, checks that the key is the certificate's, and warns
// when the certificate is not valid now (`whose`, and who then refuses it).
absl::Status readCertificateAndKey(const TlsFiles& files, const char* whose,
                                   const char* refusedBy, TlsPem* pem) {
  PBGI_ASSIGN_OR_RETURN(pem->cert, readFile(files.cert, "--tls-cert"));
  PBGI_ASSIGN_OR_RETURN(pem->key, readFile(files.key, "--tls-key"));
  PBGI_ASSIGN_OR_RETURN(const std::vector<Cert> chain,
                        certificates(pem->cert, files.cert, "--tls-cert"));
  PBGI_RETURN_IF_ERROR(keyOf(chain[0].get(), pem->key, files, "--tls-key", "--tls-cert").status());
  warnUnlessValidNow(chain[0].get(), files.cert, whose, refusedBy);
  return absl::OkStatus();
}

}  // namespace

absl::StatusOr<std::optional<TlsPem>> readServerTls(const TlsFiles& files) {
  if (files.cert.empty() && files.key.empty() && files.ca.empty()) return std::nullopt;
  if (files.cert.empty() || files.key.empty()) {
    return absl::InvalidArgumentError(
        "TLS: --tls-cert and --tls-key go together (the coordinator's certificate and its key), "
        "and --tls-client-ca needs them");
  }
  TlsPem pem;
  PBGI_RETURN_IF_ERROR(readCertificateAndKey(files, "the coordinator's certificate",
                                             "clients will refuse it", &pem));
  if (!files.ca.empty()) {
    PBGI_ASSIGN_OR_RETURN(pem.ca, readFile(files.ca, "--tls-client-ca"));
    PBGI_RETURN_IF_ERROR(certificates(pem.ca, files.ca, "--tls-client-ca").status());
  }
  return pem;
}

absl::StatusOr<std::optional<TlsPem>> readClientTls(const TlsFiles& files) {
  if (files.cert.empty() && files.key.empty() && files.ca.empty()) return std::nullopt;
  if (files.ca.empty()) {
    return absl::InvalidArgumentError(
        "TLS: --tls-cert and --tls-key need --tls-ca (the CA that signed the coordinator's "
        "certificate)");
  }
  if (files.cert.empty() != files.key.empty()) {
    return absl::InvalidArgumentError(
        "TLS: --tls-cert and --tls-key go together (this client's certificate and its key)");
  }
  TlsPem pem;
  PBGI_ASSIGN_OR_RETURN(pem.ca, readFile(files.ca, "--tls-ca"));
  PBGI_RETURN_IF_ERROR(certificates(pem.ca, files.ca, "--tls-ca").status());
  if (!files.cert.empty()) {
    PBGI_RETURN_IF_ERROR(readCertificateAndKey(files, "this client's certificate",
                                               "the coordinator will refuse it", &pem));
  }
  return pem;
}

std::shared_ptr<grpc::ChannelCredentials> channelCredentials(const std::optional<TlsPem>& tls) {
  if (!tls) return grpc::InsecureChannelCredentials();
  grpc::SslCredentialsOptions options;
  options.pem_root_certs = tls->ca;
  options.pem_private_key = tls->key;
  options.pem_cert_chain = tls->cert;
  return grpc::SslCredentials(options);
}

std::optional<std::string> diagnoseTls(const std::string& address,
                                       const std::optional<TlsPem>& tls) {
  const std::optional<HostPort> to = splitAddress(address);
  if (!to) return std::nullopt;
  SslContext context(SSL_CTX_new(TLS_client_method()));
  if (context == nullptr) return std::nullopt;
  Probe probe;
  if (tls) {
    Bio bio(BIO_new_mem_buf(tls->ca.data(), static_cast<int>(tls->ca.size())));
    X509_STORE* store = SSL_CTX_get_cert_store(context.get());
    while (X509* c = PEM_read_bio_X509(bio.get(), nullptr, nullptr, nullptr)) {
      X509_STORE_add_cert(store, c);
      X509_free(c);
    }
    if (!tls->cert.empty()) {
      Bio certBio(BIO_new_mem_buf(tls->cert.data(), static_cast<int>(tls->cert.size())));
      Bio keyBio(BIO_new_mem_buf(tls->key.data(), static_cast<int>(tls->key.size())));
      probe.cert.reset(PEM_read_bio_X509(certBio.get(), nullptr, nullptr, nullptr));
      probe.key.reset(PEM_read_bio_PrivateKey(keyBio.get(), nullptr, nullptr, nullptr));
    }
  }
  ERR_clear_error();
  SSL_CTX_set_verify(context.get(), SSL_VERIFY_PEER, onVerify);
  SSL_CTX_set_client_cert_cb(context.get(), onCertificateRequest);
  const int fd = connectTcp(*to, 3);
  if (fd < 0) return std::nullopt;  // not there: nothing to say about TLS
  Ssl ssl(SSL_new(context.get()));
  SSL_set_fd(ssl.get(), fd);
  SSL_set_app_data(ssl.get(), &probe);
  static constexpr unsigned char kAlpn[] = {2, 'h', '2'};  // as gRPC offers
  SSL_set_alpn_protos(ssl.get(), kAlpn, sizeof kAlpn);
  if (isIpAddress(to->host)) {
    X509_VERIFY_PARAM_set1_ip_asc(SSL_get0_param(ssl.get()), to->host.c_str());
  } else {
    SSL_set_tlsext_host_name(ssl.get(), to->host.c_str());
    X509_VERIFY_PARAM_set1_host(SSL_get0_param(ssl.get()), to->host.c_str(), 0);
  }
  const bool handshake = SSL_connect(ssl.get()) == 1;
  std::optional<std::string> problem;
  if (!tls) {
    if (probe.serverCertSeen) {
      problem = fmt::format(
          "the coordinator speaks TLS and this client plaintext: pass --tls-ca with the CA that "
          "signed its certificate ({})",
          probe.serverCert != nullptr ? describe(probe.serverCert.get()) : "?");
    }
  } else if (!probe.serverCertSeen) {
    if (!handshake) {
      problem =
          "the coordinator does not answer TLS (a plaintext coordinator?): leave out "
          "--tls-ca, or start it with --tls-cert and --tls-key";
    }
  } else if (probe.verifyError != X509_V_OK) {
    problem = "the coordinator is not trusted: " + verifyProblem(probe, *to);
  } else if (probe.certRequested && probe.cert == nullptr) {
    problem =
        "the coordinator asks every client for a certificate (it runs with "
        "--tls-client-ca): pass --tls-cert and --tls-key";
  } else if (handshake && probe.cert != nullptr) {
    // TLS 1.3: the server judges our certificate after the handshake and hangs up when it
    // refuses it; a server that accepted it waits for our first bytes.
    const timeval patience{1, 0};
    ::setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &patience, sizeof patience);
    char byte = 0;
    const int read = SSL_read(ssl.get(), &byte, 1);
    const int error = SSL_get_error(ssl.get(), read);
    const bool timedOut = error == SSL_ERROR_SYSCALL && (errno == EAGAIN || errno == EWOULDBLOCK);
    if (read <= 0 && !timedOut) {
      problem = fmt::format(
          "the coordinator refused this client's certificate ({}): it must be signed by the "
          "CA of the coordinator's --tls-client-ca",
          describe(probe.cert.get()));
    }
  }
  ERR_clear_error();
  ::close(fd);
  return problem;
}

// ---- gRPC's log ----

namespace {

std::atomic<uint64_t> gHandshakeFailures{0};
// What gRPC itself would print (GRPC_VERBOSITY, default ERROR); the rest is dropped here.
gpr_log_severity gShown = GPR_LOG_SEVERITY_ERROR;
bool gShowNone = false;

// gRPC's error text without its nested detail: "{file:..., created_time:...}".
std::string_view firstPart(std::string_view text) { return text.substr(0, text.find(" {")); }

void onGrpcLog(gpr_log_func_args* args) {
  const std::string_view file = args->file != nullptr ? args->file : "";
  const std::string_view message = args->message != nullptr ? args->message : "";
  // The server transport's line for every connection whose handshake failed.
  if (file.ends_with("chttp2_server.cc") && message.starts_with("Handshaking failed")) {
    gHandshakeFailures.fetch_add(1, std::memory_order_relaxed);
    std::string_view why = message.substr(message.find(':') + 1);
    while (why.starts_with(' ')) why.remove_prefix(1);
    if (why.starts_with("UNKNOWN:")) why.remove_prefix(8);
    log::warn("refused a connection: the TLS handshake failed: {}", firstPart(why));
    return;
  }
  if (gShowNone || args->severity < gShown) return;
  // The handshaker's own line says the same as the one above (or the client's status).
  if (file.ends_with("ssl_transport_security.cc") && message.starts_with("Handshake failed")) {
    log::debug("grpc: {}", message);
    return;
  }
  switch (args->severity) {
    case GPR_LOG_SEVERITY_DEBUG:
      log::debug("grpc: {} ({}:{})", message, file, args->line);
      break;
    case GPR_LOG_SEVERITY_INFO:
      log::info("grpc: {} ({}:{})", message, file, args->line);
      break;
    default:
      log::error("grpc: {} ({}:{})", message, file, args->line);
      break;
  }
}

}  // namespace

void watchTlsHandshakes() {
  static std::once_flag once;
  std::call_once(once, [] {
    if (const char* v = std::getenv("GRPC_VERBOSITY"); v != nullptr) {
      const std::string_view level(v);
      if (level == "DEBUG" || level == "debug") gShown = GPR_LOG_SEVERITY_DEBUG;
      if (level == "INFO" || level == "info") gShown = GPR_LOG_SEVERITY_INFO;
      gShowNone = level == "NONE" || level == "none";
    }
    gpr_set_log_function(onGrpcLog);
    // The failed-handshake line is a DEBUG one: let every line through to onGrpcLog, which
    // drops what gRPC would not have printed (none per call in steady state, measured).
    gpr_set_log_verbosity(GPR_LOG_SEVERITY_DEBUG);
  });
}

uint64_t tlsHandshakeFailures() { return gHandshakeFailures.load(std::memory_order_relaxed); }

}  // namespace pbgi::farm
