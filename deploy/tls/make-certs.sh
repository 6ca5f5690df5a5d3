#!/bin/sh
# make-certs.sh DIR [HOSTNAME...]: the certificates of a farm with TLS, made with `openssl`.
#
#   DIR/ca.crt, ca.key          the farm's CA (kept when DIR already has one, so that the
#                               certificates it signed before stay valid)
#   DIR/server.crt, server.key  the coordinator's: subjectAltName localhost, 127.0.0.1, ::1
#                               and every HOSTNAME (a name or an IP address)
#   DIR/worker.crt, worker.key  a client certificate for workers and `pbgi` (when the
#                               coordinator runs with --tls-client-ca DIR/ca.crt)
#
# pbgi-coordinator --tls-cert DIR/server.crt --tls-key DIR/server.key [--tls-client-ca DIR/ca.crt]
# pbgi-worker --tls-ca DIR/ca.crt [--tls-cert DIR/worker.crt --tls-key DIR/worker.key]
#
# Keys are ECDSA P-256, written mode 0600. Copy ca.key nowhere: it signs new certificates.
# Environment: PBGI_CERT_DAYS (825) how long the server and worker certificates are valid,
# PBGI_CA_DAYS (3650) the CA's.
set -eu

if [ $# -lt 1 ] || [ "$1" = "-h" ] || [ "$1" = "--help" ]; then
  sed -n '2,17s/^# \{0,1\}//p' "$0" >&2
  exit 2
fi
command -v openssl >/dev/null || { echo "make-certs.sh: openssl is not installed" >&2; exit 1; }
dir=$1
shift
days=${PBGI_CERT_DAYS:-825}
ca_days=${PBGI_CA_DAYS:-3650}
mkdir -p "$dir"
umask 077
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT

# subjectAltName: the loopback names always (a farm on one machine, the tests), then the
# coordinator's names as workers will dial them.
san="DNS:localhost,IP:127.0.0.1,IP:::1"
for host in "$@"; do
  case $host in
    *[!0-9.]*) case $host in *:*) san="$san,IP:$host" ;; *) san="$san,DNS:$host" ;; esac ;;
    *) san="$san,IP:$host" ;;
  esac
done

newkey() { openssl genpkey -algorithm EC -pkeyopt ec_paramgen_curve:P-256 -out "$1" 2>/dev/null; }
serial() { echo "0x$(openssl rand -hex 16)"; }

if [ -f "$dir/ca.key" ] && [ -f "$dir/ca.crt" ]; then
  echo "make-certs.sh: keeping the CA in $dir" >&2
else
  newkey "$dir/ca.key"
  # A name of its own: a client that trusts another farm's CA is told which one it met.
  openssl req -x509 -new -key "$dir/ca.key" -sha256 -days "$ca_days" \
    -subj "/CN=pbgi farm CA $(openssl rand -hex 4)" \
    -addext "basicConstraints=critical,CA:TRUE" \
    -addext "keyUsage=critical,keyCertSign,cRLSign" \
    -set_serial "$(serial)" -out "$dir/ca.crt"
fi

# sign NAME SUBJECT EXTENSIONS: DIR/NAME.key and DIR/NAME.crt, signed by the CA.
sign() {
  newkey "$dir/$1.key"
  openssl req -new -key "$dir/$1.key" -subj "$2" -out "$work/$1.csr"
  printf '%s\n' "$3" >"$work/$1.ext"
  openssl x509 -req -in "$work/$1.csr" -CA "$dir/ca.crt" -CAkey "$dir/ca.key" -sha256 \
    -days "$days" -set_serial "$(serial)" -extfile "$work/$1.ext" -out "$dir/$1.crt" 2>/dev/null
}
sign server "/CN=pbgi-coordinator" "basicConstraints=CA:FALSE
keyUsage=critical,digitalSignature,keyEncipherment
extendedKeyUsage=serverAuth
subjectAltName=$san"
sign worker "/CN=pbgi-worker" "basicConstraints=CA:FALSE
keyUsage=critical,digitalSignature
extendedKeyUsage=clientAuth"
chmod 644 "$dir/ca.crt" "$dir/server.crt" "$dir/worker.crt"
echo "make-certs.sh: $dir/{ca,server,worker}.{crt,key} (server names $san)" >&2
